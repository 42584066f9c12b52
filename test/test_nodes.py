"""
Launch-free node tests: the node classes in one process, on one
SingleThreadedExecutor with their own context, through real topics.
"""

import math
import time

from diagnostic_msgs.msg import DiagnosticStatus
import numpy as np
from numpy.testing import assert_allclose
import pytest
import rclpy
from rclpy.parameter import Parameter

from conftest import CONFIG
from ext_observer.nodes.conversions import (nanoseconds_from_stamp, quaternion_stamped,
                                      vector_stamped)
from ext_observer.core import (attitude_error, certified_alpha_max, manifold_distance,
                               multiply, norm, quaternion_from_rotation_vector,
                               SingleObserver)
from ext_observer.nodes.gyro_node import GyroNode
from ext_observer.nodes.monitor_node import DIAGNOSTIC_KEYS, ERROR_KEYS, MonitorNode, STATUS_NAME
from ext_observer.nodes.node_common import ParameterError
from ext_observer.nodes.node_parameters import (GYRO_PARAMETERS, MONITOR_PARAMETERS,
                                                OBSERVER_PARAMETERS)
from ext_observer.nodes.observer_node import DROP_REASONS, ObserverNode
from ros_helpers import overrides, Probe, SECOND, unit, values_of, wait_for_subscribers

# A measurement_timeout no pair published together outlasts, s (the
# largest allowed is 60): a step is corrected whatever the load.
LATE = 30.0

# The whole pipeline -------------------------------------------------------

def test_pipeline_converges_and_matches_the_core(ros_context, spinner):
    rate, steps = 50.0, 120
    initial = [1.3, 0.0, 0.0, 0.0]
    # The gyro publishes a step's increment and measurement together; on a
    # loaded machine one may come long after the other: the increment waits
    # for it (a newer measurement would still end the wait).
    observer = spinner.add(ObserverNode(context=ros_context, parameter_overrides=overrides(
        initial_estimate=initial, step_period=1.0 / rate, diagnostic_period=0.25,
        measurement_timeout=LATE)))
    monitor = spinner.add(MonitorNode(context=ros_context, parameter_overrides=overrides(
        diagnostic_period=0.25, window=20)))
    probe = spinner.add(Probe(ros_context))
    wait_for_subscribers(spinner, probe.increment_publisher)
    gyro = spinner.add(GyroNode(context=ros_context, parameter_overrides=overrides(
        rate_hz=rate, steps=steps, seed=11)))
    spinner.spin_until(lambda: len(probe.estimates) >= steps and gyro.finished, 40.0,
                       f'{steps} estimates')
    spinner.spin_until(lambda: len(probe.distances) >= steps, 5.0, 'the distances')
    spinner.spin_until(
        lambda: (probe.last_status(STATUS_NAME) is not None
                 and values_of(probe.last_status(STATUS_NAME)).get(
                     'estimates_received') == str(steps)),
        5.0, 'a monitor status after the last estimate')

    # The gyro: three topics per step, one stamp each, on the grid 1/rate.
    stamps = sorted(probe.truths)
    assert len(stamps) == steps
    assert sorted(probe.increments) == stamps == sorted(probe.measurements)
    assert set(np.diff(stamps)) <= {SECOND // 50}
    # q_{k+1} = q_k ⊗ exp(θ_k / 2) through the messages: no field order slipped.
    for t0, t1 in zip(stamps[:5], stamps[1:6]):
        moved = multiply(np.array(probe.truths[t0]),
                         quaternion_from_rotation_vector(np.array(probe.increments[t0])))
        assert attitude_error(moved, np.array(probe.truths[t1])) < 1e-9

    # The observer: every step corrected, nothing dropped, and each estimate is
    # the core's, bit for bit (on the normalized measurement), stamped t_{k+1}.
    assert observer.counts['steps_corrected'] == steps
    assert observer.counts['steps_propagated'] == 0
    assert not any(observer.drops.values())
    reference = SingleObserver(initial=initial)
    period = round(SECOND / rate)
    for t in stamps:
        expected = reference.step(probe.increments[t], unit(probe.measurements[t]))
        assert probe.estimates[t + period] == expected
    for t, q in probe.units.items():
        assert norm(np.array(q)) == pytest.approx(1.0)
        assert_allclose(np.array(q) * norm(np.array(probe.estimates[t])),
                        probe.estimates[t], atol=1e-12)

    # It converges: attitude error and distance to S³ fall.
    paired = [t for t in stamps if t in probe.estimates]
    estimates = np.array([initial] + [probe.estimates[t] for t in paired])
    truths = np.array([probe.truths[stamps[0]]] + [probe.truths[t] for t in paired])
    errors = attitude_error(estimates, truths)
    distances = manifold_distance(estimates)
    assert np.mean(errors[-30:]) < 0.6
    assert np.mean(errors[-30:]) < 0.5 * np.mean(errors[:3])
    assert distances[0] == pytest.approx(0.3)
    assert np.mean(distances[-30:]) < 0.15

    # The monitor: one distance per estimate, and an OK status with every key.
    in_order = [probe.estimates[t] for t in sorted(probe.estimates)]
    assert_allclose(probe.distances[:steps], manifold_distance(np.array(in_order)),
                    atol=1e-12)
    status = probe.last_status(STATUS_NAME)
    assert status.level == DiagnosticStatus.OK, status.message
    assert status.hardware_id == '/monitor'
    values = values_of(status)
    assert set(DIAGNOSTIC_KEYS + ERROR_KEYS) <= set(values)
    assert int(values['estimates_received']) == monitor.estimates_received == steps
    # (The rate is measured from arrival times, which load bunches: only its sign.)
    assert float(values['estimate_rate_hz']) > 0.0
    assert float(values['attitude_error_mean']) < 1.0
    spinner.spin_until(
        lambda: values_of(probe.last_status('observer: inputs')).get(
            'steps_corrected') == str(steps), 5.0, 'an observer status after the last step')
    assert probe.last_status('observer: inputs').level == DiagnosticStatus.OK


@pytest.mark.parametrize('gain_mode, values', [
    ('rotating', dict(kappa=0.3, align_sign=True)),
    ('scheduled', dict(kappa_min=0.05, variant='plain')),
])
def test_gain_modes_on_a_gyro_with_errors_match_the_core(ros_context, spinner, gain_mode,
                                                         values):
    rate, steps = 100.0, 60
    observer = spinner.add(ObserverNode(context=ros_context, parameter_overrides=overrides(
        gain_mode=gain_mode, step_period=1.0 / rate, measurement_timeout=LATE, **values)))
    probe = spinner.add(Probe(ros_context))
    wait_for_subscribers(spinner, probe.increment_publisher)
    gyro = spinner.add(GyroNode(context=ros_context, parameter_overrides=overrides(
        rate_hz=rate, steps=steps, seed=4, gyro_noise_std=0.01,
        gyro_bias=[0.02, 0.0, -0.01], bias_walk_std=0.001)))
    spinner.spin_until(lambda: len(probe.estimates) >= steps and gyro.finished, 20.0,
                       f'{steps} estimates')
    config = observer.observer.config
    assert (config.gain_mode, config.kappa, config.kappa_min, config.align_sign) == (
        gain_mode, values.get('kappa', 0.05), values.get('kappa_min', 0.02),
        values.get('align_sign', False))
    # The reported increments carry the gyro's errors: the truth moves by others.
    stamps = sorted(probe.truths)
    moved = multiply(np.array(probe.truths[stamps[0]]),
                     quaternion_from_rotation_vector(np.array(probe.increments[stamps[0]])))
    assert 1e-4 < attitude_error(moved, np.array(probe.truths[stamps[1]])) < 0.2
    # The node's estimates are the core's with the same settings, bit for bit.
    reference = SingleObserver(gain_mode=gain_mode, **values)
    period = round(SECOND / rate)
    for t in stamps:
        expected = reference.step(probe.increments[t], unit(probe.measurements[t]))
        assert probe.estimates[t + period] == expected
    assert reference.measurements_used == observer.observer.measurements_used == steps


def test_unit_estimate_goes_out_only_while_subscribed(ros_context, spinner):
    from geometry_msgs.msg import QuaternionStamped, Vector3Stamped
    from rclpy.node import Node

    observer = spinner.add(ObserverNode(context=ros_context, parameter_overrides=overrides(
        step_period=0.01)))
    driver = spinner.add(Node('driver', context=ros_context))
    listener = spinner.add(Node('listener', context=ros_context))
    increments = driver.create_publisher(Vector3Stamped, 'gyro/increment', 10)
    measurements = driver.create_publisher(QuaternionStamped, 'attitude/measurement', 10)
    estimates, units = {}, {}
    driver.create_subscription(
        QuaternionStamped, 'attitude_estimate',
        lambda msg: estimates.setdefault(nanoseconds_from_stamp(msg.header.stamp), msg), 10)
    wait_for_subscribers(spinner, increments)
    wait_for_subscribers(spinner, measurements)
    # Every unit estimate the node hands to its publisher (the publisher still
    # sends it): the only record of one published while no one listens.
    handed = []
    publish = observer.unit_publisher.publish

    def counted(msg):
        handed.append(nanoseconds_from_stamp(msg.header.stamp))
        publish(msg)

    observer.unit_publisher.publish = counted
    y = (1.0, 0.0, 0.0, 0.0)

    def step(seconds):
        """One corrected step at ``seconds``; return the stamp of its estimate."""
        before = observer.counts['measurements']
        measurements.publish(quaternion_stamped(y, seconds * SECOND, 'world'))
        spinner.spin_until(lambda: observer.counts['measurements'] > before, 5.0,
                           'the measurement')
        increments.publish(vector_stamped((0.1, 0.0, 0.0), seconds * SECOND, 'base_link'))
        stamp = seconds * SECOND + SECOND // 100
        spinner.spin_until(lambda: stamp in estimates, 5.0, f'the estimate at {seconds} s')
        return stamp

    # No subscriber: the estimate goes out, its unit form does not.
    step(1)
    assert handed == []
    # A subscriber: the unit form of the next estimate reaches it.
    subscription = listener.create_subscription(
        QuaternionStamped, 'attitude_estimate/unit',
        lambda msg: units.setdefault(nanoseconds_from_stamp(msg.header.stamp), msg), 10)
    spinner.spin_until(lambda: observer._publish_unit, 5.0, 'the unit output switched on')
    stamp = step(2)
    spinner.spin_until(lambda: stamp in units, 5.0, 'the unit estimate')
    assert handed == [stamp] and list(units) == [stamp]
    q = estimates[stamp].quaternion
    n = math.sqrt(q.w ** 2 + q.x ** 2 + q.y ** 2 + q.z ** 2)
    assert units[stamp].quaternion.w == pytest.approx(q.w / n, abs=1e-15)
    # Gone again: not handed to the publisher any more.
    listener.destroy_subscription(subscription)
    spinner.spin_until(lambda: not observer._publish_unit, 5.0,
                       'the unit output switched off')
    step(3)
    assert handed == [stamp]


# The observer's pairing -----------------------------------------------------

def test_observer_pairs_by_stamp_waits_and_counts_drops(ros_context, spinner):
    observer = spinner.add(ObserverNode(context=ros_context, parameter_overrides=overrides(
        measurement_timeout=0.2, step_period=0.01, diagnostic_period=0.1)))
    probe = spinner.add(Probe(ros_context))
    wait_for_subscribers(spinner, probe.increment_publisher)
    wait_for_subscribers(spinner, probe.measurement_publisher)
    reference = SingleObserver()
    theta = (0.1, -0.2, 0.3)
    y = tuple(quaternion_from_rotation_vector(np.array([0.2, 0.1, 0.0])))

    def steps():
        return observer.counts['steps_corrected'] + observer.counts['steps_propagated']

    def received(kind, count):
        spinner.spin_until(lambda: observer.counts[kind] == count, 5.0, f'{count} {kind}')

    # Inputs on two topics arrive in either order: each input the order
    # matters for is sent once the one before it has arrived.

    # A pair: one corrected step, published at t + step_period.
    probe.send_measurement(1 * SECOND, y)
    received('measurements', 1)
    probe.send_increment(1 * SECOND, theta)
    spinner.spin_until(lambda: len(probe.estimates) == 1, 5.0, 'the first estimate')
    assert probe.estimates == {SECOND + SECOND // 100: reference.step(theta, y)}

    # An increment alone waits measurement_timeout (at least: load only
    # lengthens the wait), then propagates.
    sent = time.monotonic()
    probe.send_increment(2 * SECOND, theta)
    spinner.spin_until(lambda: steps() == 2, 5.0, 'the timeout')
    assert time.monotonic() - sent >= 0.2 * 0.99
    assert observer.counts['steps_propagated'] == 1
    spinner.spin_until(lambda: len(probe.estimates) == 2, 5.0, 'the second estimate')
    assert probe.estimates[2 * SECOND + SECOND // 100] == reference.step(theta)

    # From here on no step may wait out a timeout: what ends a wait is an input.
    [result] = observer.set_parameters([Parameter('measurement_timeout', value=LATE)])
    assert result.successful, result.reason

    # Duplicate and stale inputs are dropped and counted; so is a measurement
    # that comes after its step went on without it.
    probe.send_increment(2 * SECOND, theta)
    probe.send_measurement(SECOND + SECOND // 2, y)
    probe.send_measurement(2 * SECOND, y)
    spinner.spin_until(lambda: observer.counts['measurements'] == 3, 5.0, 'the inputs')
    received('increments', 3)
    assert observer.drops['duplicate_increment'] == 1
    assert observer.drops['stale_measurement'] == 2
    assert steps() == 2

    # A measurement may come first; one without increment is dropped as unpaired
    # once a newer step is processed.
    probe.send_measurement(3 * SECOND, y)
    probe.send_measurement(4 * SECOND, y)
    received('measurements', 5)
    probe.send_increment(4 * SECOND, theta)
    spinner.spin_until(lambda: steps() == 3, 5.0, 'the third step')
    assert observer.counts['steps_corrected'] == 2
    assert observer.drops['unpaired_measurement'] == 1
    # The measurement of a corrected step, again: a duplicate.
    probe.send_measurement(4 * SECOND, y)
    spinner.spin_until(lambda: observer.drops['duplicate_measurement'] == 1, 5.0,
                       'the duplicate measurement')

    # A newer measurement shows that an older one will not come: the step goes
    # on at once, long before its timeout (LATE).
    probe.send_increment(5 * SECOND, theta)
    received('increments', 5)
    assert steps() == 3
    probe.send_measurement(6 * SECOND, y)
    spinner.spin_until(lambda: steps() == 4, 5.0, 'step 5, released by the newer measurement')
    probe.send_increment(6 * SECOND, theta)
    spinner.spin_until(lambda: steps() == 5, 5.0, 'step 6')
    assert observer.counts['steps_propagated'] == 2
    assert observer.counts['steps_corrected'] == 3

    spinner.spin_until(
        lambda: values_of(probe.last_status('observer: inputs')).get('steps') == '5',
        5.0, 'an observer status after the last step')
    values = values_of(probe.last_status('observer: inputs'))
    assert {f'dropped_{reason}' for reason in DROP_REASONS} <= set(values)
    assert values['dropped_duplicate_increment'] == '1'
    assert values['dropped_stale_measurement'] == '2'
    assert values['dropped_unpaired_measurement'] == '1'
    assert values['dropped_duplicate_measurement'] == '1'
    warned = [s for s in probe.statuses['observer: inputs']
              if s.level == DiagnosticStatus.WARN]
    assert warned and 'dropping inputs' in warned[0].message


# The monitor's levels -------------------------------------------------------

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


# The gyro ---------------------------------------------------------------------

def test_gyro_publishes_its_steps_and_stops(ros_context, spinner):
    probe = spinner.add(Probe(ros_context))
    initial = [0.0, 0.0, 0.0, 2.0]
    gyro = spinner.add(GyroNode(context=ros_context, parameter_overrides=overrides(
        rate_hz=100.0, steps=5, seed=3, initial_attitude=initial, frame_id='map',
        increment_max=0.5)))
    # Its first status has measured no rate yet: NaN, not a stalled 0.
    assert values_of(gyro.status())['achieved_rate_hz'] == 'nan'
    spinner.spin_until(lambda: gyro.finished and len(probe.increments) == 5
                       and len(probe.truths) == 5, 10.0, 'five steps')
    # Stopped: ten more periods publish nothing (more time only makes a sixth
    # step likelier to show).
    spinner.spin_for(0.1)
    assert gyro.steps_published == 5 and len(probe.truths) == 5
    first = min(probe.truths)
    assert probe.truths[first] == (0.0, 0.0, 0.0, 1.0)
    assert all(0.0 <= v <= 0.5 for theta in probe.increments.values() for v in theta)


# Parameters -------------------------------------------------------------------

def write_params(path, text):
    path.write_text(text)
    return str(path)


def test_params_file_is_honoured(ros_domain_id, tmp_path):
    params = write_params(tmp_path / 'params.yaml', """
/**/observer:
  ros__parameters:
    variant: plain
    alpha: 0.05
    gain: [0.2, -0.1, -0.1, -0.1]
    initial_estimate: [0.0, 1.0, 0.0, 0.0]
    measurement_timeout: 0.5
gyro:
  ros__parameters:
    rate_hz: 40.0
    seed: 5
    initial_attitude: [0.0, 1.0, 0.0, 0.0]
monitor:
  ros__parameters:
    window: 7
    warn_distance: 0.2
    error_distance: 0.4
""")
    context = rclpy.context.Context()
    rclpy.init(args=['--ros-args', '--params-file', params], context=context,
               domain_id=ros_domain_id)
    nodes = []
    try:
        observer = ObserverNode(context=context, namespace='robot1')
        nodes.append(observer)
        assert observer.get_fully_qualified_name() == '/robot1/observer'
        assert observer.get_parameter('variant').value == 'plain'
        config = observer.observer.config
        assert (config.variant, config.alpha) == ('plain', 0.05)
        assert config.gain == (0.2, -0.1, -0.1, -0.1)
        assert observer.observer.state == (0.0, 1.0, 0.0, 0.0)
        assert observer.parameters.settings['measurement_timeout'] == 0.5
        gyro = GyroNode(context=context)
        nodes.append(gyro)
        assert gyro.get_parameter('rate_hz').value == 40.0
        assert gyro.get_parameter('seed').value == 5
        assert_allclose(gyro.gyro.attitude, [0.0, 1.0, 0.0, 0.0])
        monitor = MonitorNode(context=context)
        nodes.append(monitor)
        assert monitor.distances.maxlen == 7
        assert monitor.parameters.settings['error_distance'] == 0.4
    finally:
        for node in nodes:
            node.destroy_node()
        rclpy.try_shutdown(context=context)


def unset_scalar(spec):
    """A parameter without a default that YAML cannot list (e.g. align_sign)."""
    return (isinstance(spec.default, Parameter.Type)
            and not spec.default.name.endswith('_ARRAY'))


def test_shipped_params_file_loads_with_the_defaults(ros_domain_id):
    context = rclpy.context.Context()
    rclpy.init(args=['--ros-args', '--params-file', CONFIG], context=context,
               domain_id=ros_domain_id)
    nodes = []
    try:
        for node_class, specs in ((GyroNode, GYRO_PARAMETERS),
                                  (ObserverNode, OBSERVER_PARAMETERS),
                                  (MonitorNode, MONITOR_PARAMETERS)):
            node = node_class(context=context)
            nodes.append(node)
            # Every parameter comes from the file, none from the code's default
            # (but those unset by default: YAML has no "unset").
            assert set(node._parameter_overrides) == {
                spec.name for spec in specs if not unset_scalar(spec)}
            for spec in specs:
                value = node.parameters.values[spec.name]
                expected = None if isinstance(spec.default, Parameter.Type) else spec.default
                assert value == expected, spec.name
    finally:
        for node in nodes:
            node.destroy_node()
        rclpy.try_shutdown(context=context)


ALPHA_MAX = certified_alpha_max(0.5)


@pytest.mark.parametrize('node_class, values, reason', [
    (ObserverNode, dict(alpha=0.5), 'outside the range certified by Theorem 1'),
    (ObserverNode, dict(alpha=0.0), 'outside the range certified'),
    (ObserverNode, dict(alpha=0.0, allow_uncertified_alpha=True), 'alpha must be positive'),
    (ObserverNode, dict(alpha=2.0, allow_uncertified_alpha=True), 'out of range'),
    (ObserverNode, dict(variant='kalman'), "variant must be one of"),
    (ObserverNode, dict(gain_mode='adaptive'), 'gain_mode must be one of'),
    (ObserverNode, dict(gain=[0.1, 0.2, 0.3]), 'gain must have 4 elements'),
    (ObserverNode, dict(gain=[0.1, 0.2, 0.3, math.nan]), 'gain must be finite'),
    (ObserverNode, dict(initial_estimate=[0.0, 0.0, 0.0, 0.0]), 'nonzero'),
    (ObserverNode, dict(kappa=0.0), r'kappa must be in \(0, 1\]'),
    (ObserverNode, dict(kappa_min=0.0), r'kappa_min must be in \(0, 1\]'),
    (ObserverNode, dict(forward_gap_action='stop'), 'forward_gap_action must be one of'),
    (ObserverNode, dict(input_reliability='sometimes'), 'input_reliability must be one of'),
    (ObserverNode, dict(max_increment=0.0), 'max_increment must be positive'),
    (ObserverNode, dict(initial_estimate=[3.0, 0.0, 0.0, 0.0], divergence_max_residual=5.0),
     r'initial_estimate has \|q̂̄q̂ − 1\| = 8, above divergence_max_residual \(5\)'),
    (ObserverNode, dict(backward_jump_threshold=0.0), 'out of range'),
    (ObserverNode, dict(alpha=1), "expecting type 'DOUBLE'"),
    (GyroNode, dict(rate_hz=0.0), 'out of range'),
    (GyroNode, dict(gyro_noise_std=-0.1), 'out of range'),
    (GyroNode, dict(gyro_bias=[0.1, 0.0]), 'gyro_bias must have 3 elements'),
    (GyroNode, dict(gyro_bias=[0.1, math.inf, 0.0]), 'gyro_bias must be finite'),
    (GyroNode, dict(initial_attitude=[1.0, 0.0, 0.0]), 'initial_attitude must have 4 '
                                                       'elements'),
    (MonitorNode, dict(warn_distance=0.5, error_distance=0.4),
     r'error_distance \(0.4\) must not be below warn_distance \(0.5\)'),
])
def test_invalid_start_up_parameter_is_refused_with_its_reason(
        ros_context, node_class, values, reason):
    with pytest.raises(ParameterError, match=reason):
        node_class(context=ros_context, parameter_overrides=overrides(**values))


def test_uncertified_alpha_needs_the_switch(ros_context):
    node = ObserverNode(context=ros_context, parameter_overrides=overrides(
        alpha=0.5, allow_uncertified_alpha=True))
    try:
        assert node.observer.config.alpha == 0.5
    finally:
        node.destroy_node()
    assert 0.07 < ALPHA_MAX < 0.08


def test_invalid_runtime_change_is_refused_and_valid_one_applied(ros_context, spinner):
    node = spinner.add(ObserverNode(context=ros_context))
    node.observer.step((0.1, 0.2, 0.3), (0.0, 1.0, 0.0, 0.0))
    state = node.observer.state

    def refused(name, value, reason):
        [result] = node.set_parameters([Parameter(name, value=value)])
        assert not result.successful
        assert reason in result.reason
        return result

    refused('alpha', 0.5, 'outside the range certified by Theorem 1')
    refused('variant', 'kalman', 'variant must be one of')
    refused('gain', [1.0, 2.0], 'gain must have 4 elements')
    refused('initial_estimate', [0.5, 0.5, 0.5, 0.5], 'read-only')
    refused('queue_depth', 20, 'read-only')
    refused('measurement_timeout', -1.0, 'out of range')
    assert node.get_parameter('alpha').value == 0.01
    assert node.observer.config.alpha == 0.01

    # Both together: the switch and the value it allows.
    result = node.set_parameters_atomically([
        Parameter('allow_uncertified_alpha', value=True), Parameter('alpha', value=0.2)])
    assert result.successful, result.reason
    assert node.observer.config.alpha == 0.2
    # Another observer from the current estimate on, not a reset.
    [result] = node.set_parameters([Parameter('variant', value='projected')])
    assert result.successful, result.reason
    assert node.observer.config.variant == 'projected'
    assert node.observer.state == state
    # Switching the guard back off with an uncertified alpha in place is refused.
    refused('allow_uncertified_alpha', False, 'outside the range certified')


def test_gyro_and_monitor_refuse_runtime_changes_with_reasons(ros_context, spinner):
    gyro = spinner.add(GyroNode(context=ros_context))
    monitor = spinner.add(MonitorNode(context=ros_context))
    [result] = gyro.set_parameters([Parameter('seed', value=3)])
    assert not result.successful and 'read-only' in result.reason
    [result] = gyro.set_parameters([Parameter('rate_hz', value=200.0)])
    assert result.successful
    [result] = monitor.set_parameters([Parameter('warn_distance', value=0.9)])
    assert not result.successful and 'must not be below warn_distance' in result.reason
    [result] = monitor.set_parameters([Parameter('error_distance', value=0.9)])
    assert result.successful
    assert monitor.parameters.settings['error_distance'] == 0.9


def test_every_parameter_has_a_descriptor(ros_context):
    for node_class in (GyroNode, ObserverNode, MonitorNode):
        node = node_class(context=ros_context)
        try:
            for spec in node.parameters._specs:
                descriptor = node.describe_parameter(spec.name)
                assert descriptor.description == spec.description
                assert descriptor.read_only == spec.read_only
                if spec.range is not None:
                    ranges = list(descriptor.floating_point_range) + list(
                        descriptor.integer_range)
                    assert [(r.from_value, r.to_value) for r in ranges] == [spec.range]
        finally:
            node.destroy_node()


# The params file matches the code (the docs: test_docs.py) ----------------------

ALL_SPECS = (('gyro', GYRO_PARAMETERS), ('observer', OBSERVER_PARAMETERS),
             ('monitor', MONITOR_PARAMETERS))


def test_params_file_has_every_parameter_with_a_comment():
    import yaml

    from docgen.parameter_tables import render_config
    with open(CONFIG, encoding='utf-8') as config:
        text = config.read()
        lines = text.splitlines()
        config.seek(0)
        sections = yaml.safe_load(config)
    assert render_config(text) == text, (
        'config/ext_observer.yaml differs from the parameter specs: run  make docs')
    for name, specs in ALL_SPECS:
        values = sections[f'/**/{name}']['ros__parameters']
        # Every parameter has a value YAML can list (align_sign once had
        # none and was a comment line; the loop that checked such comments
        # never ran since, as the mutation tests found). A new one without: list it here.
        assert not any(map(unset_scalar, specs)), [s.name for s in specs if unset_scalar(s)]
        assert list(values) == [spec.name for spec in specs]
        for spec in specs:
            expected = [] if isinstance(spec.default, Parameter.Type) else spec.default
            assert values[spec.name] == expected, spec.name
    for index, line in enumerate(lines):
        if line.startswith('    ') and not line.lstrip().startswith('#'):
            assert lines[index - 1].lstrip().startswith('#'), f'no comment above {line!r}'
