"""
Known answers for faults the rest of the suite let through (issue 31), no ROS.

Each test here was written because a mutant of mutation/mutants.toml
survived the tests of its module (``make mutation-list`` names them): the
heading variance's growth with the gyro's noise, the interval bound of a
step, the step a measurement at a step's end belongs to.
"""

import copy
import math

import numpy as np
import pytest

from ext_observer.core.ahrs import uncertainty_kernel
from ext_observer.core.ahrs.estimator import AhrsObserver, AhrsParams
from ext_observer.core.ahrs.uncertainty import AttitudeUncertainty, GRAVITY, UncertaintyParams
from ext_observer.pipeline.pairing import BACKWARD_JUMP, StepPairer

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


def _rotation(q):
    """The rotation matrix of ``q`` (any nonzero norm), body → world."""
    w, x, y, z = np.asarray(q, dtype=float) / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def test_the_uncertainty_is_its_documented_model_in_matrix_form():
    # core/ahrs/uncertainty.py's model, written here as 2×2 matrices per axis
    # (x = [θ, β]: F P Fᵀ + Q between samples, the rest and the inclination
    # corrections as congruences plus their noise), against the kernel's
    # scalar arithmetic, over samples of changing intervals, rates,
    # attitudes and rest: equal to rounding. 6D: nothing corrects the heading.
    params = UncertaintyParams(gyro_noise=3e-3, gyro_rate_noise=2e-2, bias_std=4e-3,
                               bias_time=30.0, bias_init=1e-2, acc_noise=0.05,
                               inclination_floor=0.0, heading_floor=0.0, stamp_error=2e-3)
    tau_acc, tau_rest = 1.5, 0.7
    tracker = AttitudeUncertainty(params, tau_acc=tau_acc, tau_rest=tau_rest, use_mag=False)
    rng = np.random.default_rng(31)
    dt = 0.01
    tracker.start(dt)
    r_acc = (0.05 / GRAVITY) ** 2
    tilt = np.array([[r_acc / dt, 0.0], [0.0, 1e-2 ** 2]])
    heading = np.array([[3e-3 ** 2 * dt, 0.0], [0.0, 1e-2 ** 2]])
    for k in range(400):
        dt = (0.01, 0.005, 0.02)[k // 100 % 3]
        rate = rng.normal(0.0, 1.0, 3)
        q = rng.normal(0.0, 1.0, 4)
        rest = k % 50 < 20
        tracker.step(dt, tuple(rate), tuple(q), rest)
        phi = math.exp(-dt / 30.0)
        f = np.array([[1.0, dt], [0.0, phi]])
        noise = np.diag([(3e-3 ** 2 + (2e-2 * np.linalg.norm(rate)) ** 2) * dt,
                         4e-3 ** 2 * (1.0 - phi * phi)])
        tilt = f @ tilt @ f.T + noise
        heading = f @ heading @ f.T + noise
        if rest:
            kr = 1.0 - math.exp(-dt / tau_rest)
            g = np.diag([1.0, 1.0 - kr])
            learned = np.diag([0.0, kr * kr * 3e-3 ** 2 / dt])
            tilt = g @ tilt @ g.T + learned
            heading = g @ heading @ g.T + learned
        ka = 1.0 - math.exp(-dt / tau_acc)
        h = np.diag([1.0 - ka, 1.0])
        tilt = h @ tilt @ h.T + np.diag([ka * ka * r_acc / dt, 0.0])
        vertical = (_rotation(q) @ rate)[2]
        stamp2 = 2e-3 ** 2
        assert tracker.tilt_variance == pytest.approx(
            tilt[0, 0] + 0.5 * stamp2 * (rate @ rate - vertical ** 2), rel=1e-9)
        assert tracker.heading_variance == pytest.approx(
            heading[0, 0] + stamp2 * vertical ** 2, rel=1e-9)


ROLLED = (0.0, 6.9367, 6.9367)  # m/s²: gravity seen rolled by 45°


def _pair():
    """An estimator and its uncertainty, 6D, started from one still sample rolled 45° (100 Hz)."""
    est = AhrsObserver(AhrsParams(), use_mag=False)
    tracker = AttitudeUncertainty.for_estimator(est.params, use_mag=False)
    est.update((0.0, 0.0, 0.0), ROLLED, None, 0.01)
    tracker.start(0.01)
    return est, tracker


def test_the_one_call_sample_step_is_the_general_steps():
    # sample_step (the node's usual sample in one call) against the steps
    # one at a time: the estimate, and the covariance it writes (diag(V_t,
    # V_t, V_h), zeros elsewhere), through rest (the bias learned) and a turn
    # of 1.75 rad about the body's z (every component of the estimate large),
    # the interval changing now and then.
    one, one_tracker = _pair()
    general, tracker = _pair()
    cov = np.full(9, np.nan)
    rng = np.random.default_rng(5)
    for k in range(600):
        moving = k >= 300
        dt = (0.01, 0.005, 0.02)[k // 50 % 3]
        gyr = tuple(rng.normal(0.0, 0.002, 3) + (0.0, 0.0, 0.5 if moving else 0.0))
        acc = tuple(np.array(ROLLED) + rng.normal(0.0, 0.05, 3))
        outcome, *q = uncertainty_kernel.sample_step(
            one.flat_state, one_tracker.state, cov, *gyr, *acc, dt, 0.01)
        assert outcome == uncertainty_kernel.SAMPLE_OK
        expected = general.update(gyr, acc, None, dt)
        tracker.step(dt, gyr, expected, general.rest, general.bias_variance,
                     general.clip_variance)
        assert tuple(q) == tuple(expected)
        assert tuple(cov) == tuple(tracker.covariance)
        t, h = tracker.tilt_variance, tracker.heading_variance
        assert tuple(cov) == (t, 0.0, 0.0, 0.0, t, 0.0, 0.0, 0.0, h)
    assert general.rest is False and tracker.heading_variance > 0.0
    assert min(abs(v) for v in general.q) > 0.1


def test_the_one_call_sample_step_refuses_what_it_cannot_run():
    est = AhrsObserver(AhrsParams(), use_mag=False)
    tracker = AttitudeUncertainty.for_estimator(est.params, use_mag=False)
    cov = np.zeros(9)
    step = uncertainty_kernel.sample_step
    still = (0.0, 0.0, 0.0) + ROLLED
    assert step(est.flat_state, tracker.state, cov, *still, 0.01, 0.01)[0] == (
        uncertainty_kernel.SAMPLE_NOT_STARTED)
    est, tracker = _pair()
    for dt in (0.0, -0.01, math.inf, math.nan):
        assert step(est.flat_state, tracker.state, cov, *still, dt, 0.01)[0] == (
            uncertainty_kernel.SAMPLE_BAD_DT), dt
    assert not cov.any()  # nothing written
    # The guard: |q̂̄q̂ − 1| above max_residual fails, at it passes.
    turn = (3.0, -2.0, 1.0) + ROLLED
    _, *q = step(copy.copy(est.flat_state), copy.copy(tracker.state), cov, *turn, 0.01, 1.0)
    residual = abs(sum(v * v for v in q) - 1.0)
    assert residual > 0.0
    for max_residual, expected in ((residual, uncertainty_kernel.SAMPLE_OK),
                                   (0.5 * residual, uncertainty_kernel.SAMPLE_RESIDUAL)):
        outcome = step(copy.copy(est.flat_state), copy.copy(tracker.state), cov, *turn, 0.01,
                       max_residual)[0]
        assert outcome == expected


# The pairing rules at their edges (mutmut's survivors on pairing.py) --------------

def test_a_sample_the_caller_rejects_is_received_and_dropped_with_its_reason():
    pairer = StepPairer()
    for count in (1, 2):
        assert pairer.reject('increment', 'non_finite_increment') == 'non_finite_increment'
        assert pairer.received['increment'] == count
        assert pairer.drops['non_finite_increment'] == count
    assert pairer.received['measurement'] == 0
    assert pairer.accounted('increment') == 2


def test_a_sample_backward_by_backward_jump_is_stale_and_one_nanosecond_more_a_jump():
    pairer = StepPairer(timeout=0, backward_jump=1 * S)
    t = 10 * S
    pairer.add_angular_velocity(t, (0.1, 0.0, 0.0), 0)
    assert pairer.add_angular_velocity(t - 1 * S, (0.1, 0.0, 0.0), 0) == 'stale_increment'
    assert pairer.events['backward_jumps'] == 0
    for count in (1, 2):
        t -= 1 * S + 1
        assert pairer.add_angular_velocity(t, (0.1, 0.0, 0.0), 0) == BACKWARD_JUMP
        assert pairer.events['backward_jumps'] == count


def test_a_field_at_stamp_1_is_taken_and_one_backward_by_backward_jump_is_stale():
    pairer = StepPairer(timeout=0, backward_jump=1 * S)
    assert pairer.add_field(1, (2e-5, 0.0, -4e-5)) is None
    assert pairer.add_field(3 * S, (2e-5, 0.0, -4e-5)) is None
    assert pairer.add_field(2 * S, (2e-5, 0.0, -4e-5)) == 'stale_measurement'
    assert pairer.add_field(2 * S - 1, (2e-5, 0.0, -4e-5)) is None  # a jump back: taken
    assert pairer.field_stamp == 2 * S - 1


@pytest.mark.parametrize('constant_dt', [0.0, 0.005])
def test_arrival_order_takes_a_repeated_stamp_only_with_a_constant_dt(constant_dt):
    # imu_tools' constant_dt (i30): with arrival_order and a constant_dt > 0
    # every sample is taken in the order it comes; without a constant_dt the
    # stamps rule (a repeated one is a duplicate).
    pairer = StepPairer(timeout=0, constant_dt=constant_dt, arrival_order=True)
    pairer.add_angular_velocity(2 * S, (0.1, 0.0, 0.0), 0)
    outcome = pairer.add_angular_velocity(2 * S, (0.1, 0.0, 0.0), 0)
    assert outcome == (None if constant_dt > 0.0 else 'duplicate_increment')
