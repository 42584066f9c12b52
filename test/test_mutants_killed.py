"""
Known answers for faults the rest of the suite let through (issue 31), no ROS.

Each test here was written because a mutant of mutation/mutants.toml
survived the tests of its module (``make mutation-list`` names them): the
heading variance's growth with the gyro's noise, the interval bound of a
step, the step a measurement at a step's end belongs to.
"""

import pytest

from ext_observer.core.ahrs.uncertainty import AttitudeUncertainty, UncertaintyParams
from ext_observer.pipeline.pairing import StepPairer

MS = 1_000_000
S = 1_000_000_000
Y = (1.0, 0.0, 0.0, 0.0)


@pytest.mark.parametrize('rate', [(0.0, 0.0, 0.0), (0.3, -0.4, 1.2)])
def test_the_heading_variance_grows_with_the_gyros_noise_in_6d(rate):
    # No bias (known to be zero) and no correction of the heading: each
    # sample adds the gyro's angle variance, (σ² + σ_r² |ω|²) dt: a random walk.
    params = UncertaintyParams(bias_std=0.0, bias_init=0.0, gyro_noise=2e-3,
                               gyro_rate_noise=1e-2, stamp_error=0.0)
    dt, count = 0.01, 1000
    tracker = AttitudeUncertainty(params, use_mag=False)
    tracker.start(dt)
    tracker.step(dt, rate, (1.0, 0.0, 0.0, 0.0), False)
    before = tracker.heading_variance
    for _ in range(count):
        tracker.step(dt, rate, (1.0, 0.0, 0.0, 0.0), False)
    w2 = sum(v * v for v in rate)
    expected = count * (2e-3 ** 2 + 1e-2 ** 2 * w2) * dt
    assert tracker.heading_variance - before == pytest.approx(expected, rel=1e-9)


def test_an_interval_of_max_dt_is_a_step_and_one_nanosecond_more_is_dropped():
    pairer = StepPairer(timeout=0, max_dt=50 * MS)
    pairer.add_angular_velocity(2 * S, (0.1, 0.0, 0.0), 0)
    assert pairer.add_angular_velocity(2 * S + 50 * MS, (0.1, 0.0, 0.0), 0) is None
    [step] = pairer.pop_ready(0)
    assert (step.stamp, step.end) == (2 * S, 2 * S + 50 * MS)
    assert pairer.add_angular_velocity(2 * S + 100 * MS + 1, (0.1, 0.0, 0.0), 0) == 'dt_too_large'
    assert pairer.add_angular_velocity(2 * S + 130 * MS, (0.1, 0.0, 0.0), 0) is None
    [step] = pairer.pop_ready(0)
    assert (step.stamp, step.end) == (2 * S + 100 * MS + 1, 2 * S + 130 * MS)


def test_a_measurement_at_a_steps_end_corrects_the_next_step():
    # Samples at 0, 10 and 20 ms; a measurement stamped 10 ms is the
    # attitude at the start of the second interval, not the end of the first.
    pairer = StepPairer(depth=4, timeout=100 * MS)
    t0 = 1 * S
    pairer.add_angular_velocity(t0, (0.1, 0.2, 0.3), 0)
    pairer.add_angular_velocity(t0 + 10 * MS, (0.1, 0.2, 0.3), 0)
    pairer.add_measurement(t0 + 10 * MS, Y)
    pairer.add_angular_velocity(t0 + 20 * MS, (0.1, 0.2, 0.3), 0)
    pairer.add_angular_velocity(t0 + 30 * MS, (0.1, 0.2, 0.3), 0)
    steps = pairer.pop_ready(1 * S)
    assert [(s.stamp, s.measurement) for s in steps] == [
        (t0, None), (t0 + 10 * MS, Y), (t0 + 20 * MS, None)]
