"""
The three nodes as one pipeline, launch-free: gyro, observer and monitor in
one process, on one SingleThreadedExecutor with their own context, through
real topics; each estimate equals the core's step, in every gain mode. Each
node's own tests: nodes/test_gyro_node.py, test_observer_node.py,
test_monitor_node.py, test_node_parameters.py.
"""

from diagnostic_msgs.msg import DiagnosticStatus
import numpy as np
from numpy.testing import assert_allclose
import pytest

from ext_observer.core import (attitude_error, manifold_distance, multiply, norm,
                               quaternion_from_rotation_vector, SingleObserver)
from ext_observer.nodes.gyro_node import GyroNode
from ext_observer.nodes.monitor_node import DIAGNOSTIC_KEYS, ERROR_KEYS, MonitorNode, STATUS_NAME
from ext_observer.nodes.observer_node import ObserverNode
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


# The params file matches the code (the docs: test_docs.py) ----------------------
