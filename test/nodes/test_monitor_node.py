"""
The monitor node (``nodes/monitor_node.py``) through real topics: its levels
(STALE, OK, WARN, ERROR) and keys.
"""

from diagnostic_msgs.msg import DiagnosticStatus
import numpy as np
import pytest
from rclpy.parameter import Parameter

from ext_observer.nodes.conversions import quaternion_stamped
from ext_observer.core import quaternion_from_rotation_vector
from ext_observer.nodes.monitor_node import DIAGNOSTIC_KEYS, ERROR_KEYS, MonitorNode, STATUS_NAME
from ros_helpers import overrides, Probe, SECOND, values_of, wait_for_subscribers


# A measurement_timeout no pair published together outlasts, s (the
# largest allowed is 60): a step is corrected whatever the load.
LATE = 30.0


def test_monitor_levels_and_keys(ros_context, spinner):
    # A stale_timeout no pause of a loaded machine reaches while the levels are
    # checked; a short one at the end, to see STALE.
    monitor = spinner.add(MonitorNode(context=ros_context, parameter_overrides=overrides(
        diagnostic_period=0.1, stale_timeout=LATE, window=4, hardware_id='test_imu')))
    probe = spinner.add(Probe(ros_context))
    wait_for_subscribers(spinner, probe.estimate_publisher)
    wait_for_subscribers(spinner, probe.truth_publisher)
    stamp = [10 * SECOND]

    def send(estimates, truth=None):
        before = monitor.estimates_received
        for q in estimates:
            stamp[0] += SECOND // 10
            if truth is not None:
                probe.truth_publisher.publish(quaternion_stamped(truth, stamp[0], 'world'))
            probe.estimate_publisher.publish(quaternion_stamped(q, stamp[0], 'world'))
        spinner.spin_until(lambda: monitor.estimates_received == before + len(estimates),
                           5.0, 'the estimates')
        count = len(probe.statuses.get(STATUS_NAME, []))
        spinner.spin_until(lambda: len(probe.statuses.get(STATUS_NAME, [])) > count + 1,
                           5.0, 'a fresh status')
        return probe.last_status(STATUS_NAME)

    spinner.spin_until(lambda: probe.last_status(STATUS_NAME) is not None, 5.0, 'a status')
    first = probe.last_status(STATUS_NAME)
    assert first.level == DiagnosticStatus.STALE
    assert first.hardware_id == 'test_imu'

    # On S³, 0.3 rad about z away from the truth.
    q = tuple(quaternion_from_rotation_vector(np.array([0.0, 0.0, 0.3])))
    status = send([q] * 4, truth=(1.0, 0.0, 0.0, 0.0))
    assert status.level == DiagnosticStatus.OK, status.message
    values = values_of(status)
    assert set(DIAGNOSTIC_KEYS + ERROR_KEYS) <= set(values)
    assert float(values['distance']) == pytest.approx(0.0, abs=1e-9)
    assert float(values['constraint_residual']) == pytest.approx(0.0, abs=1e-9)
    assert float(values['attitude_error']) == pytest.approx(0.3, abs=1e-5)
    assert float(values['attitude_error_max']) == pytest.approx(0.3, abs=1e-5)
    assert float(values['last_estimate_age_s']) <= LATE
    assert values['window'] == '4'
    # The sign of a quaternion does not change the rotation.
    status = send([tuple(-v for v in q)], truth=(1.0, 0.0, 0.0, 0.0))
    assert float(values_of(status)['attitude_error']) == pytest.approx(0.3, abs=1e-5)

    # Off S³: the window mean crosses warn_distance (0.15), then error_distance (0.3).
    status = send([(1.2, 0.0, 0.0, 0.0)] * 4)
    assert status.level == DiagnosticStatus.WARN, status.message
    values = values_of(status)
    assert float(values['distance']) == pytest.approx(0.2)
    assert float(values['distance_mean']) == pytest.approx(0.2)
    assert float(values['distance_std']) == pytest.approx(0.0, abs=1e-9)
    assert float(values['constraint_residual']) == pytest.approx(0.44)
    status = send([(0.0, 1.5, 0.0, 0.0)] * 4)
    assert status.level == DiagnosticStatus.ERROR, status.message
    assert float(values_of(status)['distance_max']) == pytest.approx(0.5)
    assert probe.distances[-1] == pytest.approx(0.5)
    # A zero quaternion has no attitude: no error sample, and no crash.
    errors = len(monitor.errors)
    status = send([(0.0, 0.0, 0.0, 0.0)], truth=(1.0, 0.0, 0.0, 0.0))
    assert len(monitor.errors) == errors
    assert float(values_of(status)['distance']) == 1.0

    # Silence: STALE once the last estimate is older than stale_timeout.
    assert status.level == DiagnosticStatus.ERROR, status.message
    [result] = monitor.set_parameters([Parameter('stale_timeout', value=0.3)])
    assert result.successful, result.reason
    spinner.spin_until(
        lambda: probe.last_status(STATUS_NAME).level == DiagnosticStatus.STALE, 10.0,
        'STALE')
    stale = probe.last_status(STATUS_NAME)
    assert 'no estimate for' in stale.message
    assert float(values_of(stale)['last_estimate_age_s']) > 0.3
    # Each status's level agrees with the age it reports: STALE exactly when
    # the age is above the stale_timeout in force (LATE until the change).
    for status in probe.statuses[STATUS_NAME]:
        age = values_of(status).get('last_estimate_age_s')
        if age is not None and float(age) <= 0.3:
            assert status.level != DiagnosticStatus.STALE, status.message
