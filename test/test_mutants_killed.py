"""
Known answers for faults the rest of the suite let through (the mutation tests), no ROS.

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


def _pair(use_mag=False):
    """An estimator and its uncertainty, started from one still sample rolled 45° (100 Hz)."""
    est = AhrsObserver(AhrsParams(), use_mag=use_mag)
    tracker = AttitudeUncertainty.for_estimator(est.params, use_mag=use_mag)
    est.update((0.0, 0.0, 0.0), ROLLED, None, 0.01)
    tracker.start(0.01, ROLLED)
    return est, tracker


@pytest.mark.parametrize('use_mag', [False, True])
def test_the_one_call_sample_step_is_the_general_steps(use_mag):
    # sample_step (the node's usual sample in one call) against the steps
    # one at a time: the estimate, and the covariance it writes (diag(V_t,
    # V_t, V_h), zeros elsewhere), through rest (the bias learned) and a turn
    # of 1.75 rad about the body's z (every component of the estimate large),
    # the interval changing now and then.
    # In 9D the samples come without a field (fields have their own calls):
    # the whole state stays that of the general steps, the field's part too.
    one, one_tracker = _pair(use_mag)
    general, tracker = _pair(use_mag)
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
        # 0.005 s to 0.02 s is a hole: the step keeps the usual interval.
        hole, usual = general.hole_variance, general.step_interval
        tracker.step(usual, gyr, expected, general.rest, general.bias_variance,
                     general.clip_variance, acc,
                     (dt - usual, hole, general.hole_restart) if hole else None)
        assert tuple(q) == tuple(expected)
        assert tuple(cov) == tuple(tracker.covariance)
        t, h = tracker.tilt_variance, tracker.heading_variance
        assert tuple(cov) == (t, 0.0, 0.0, 0.0, t, 0.0, 0.0, 0.0, h)
        assert np.array_equal(np.array(one.flat_state, dtype=float),
                              np.array(general.flat_state, dtype=float), equal_nan=True)
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


# The pairing rules' edges that mutmut's run of pairing.py (docs/tests.md#mutmut)
# found untested: each is a documented rule, checked at its bound.

@pytest.mark.parametrize('axis', [0, 1, 2])
def test_a_rate_with_one_non_finite_component_is_dropped(axis):
    pairer = StepPairer(timeout=0)
    for value in (math.nan, math.inf):
        rate = [0.1, 0.2, 0.3]
        rate[axis] = value
        assert pairer.add_angular_velocity(2 * S, tuple(rate), 0) == 'non_finite_increment'
    assert pairer.drops['non_finite_increment'] == 2
    assert pairer.waiting('increment') == 0


def test_an_increment_beyond_max_increment_is_dropped_on_the_general_path():
    pairer = StepPairer(timeout=0, max_increment=0.01)
    pairer.add_angular_velocity(2 * S, (1.0, 0.0, 0.0), 0)
    # 10 ms at 1 rad/s: 0.01 rad, at the bound (kept); at 1.1 rad/s beyond it.
    assert pairer.add_angular_velocity(2 * S + 10 * MS, (1.0, 0.0, 0.0), 0) is None
    assert pairer.add_angular_velocity(2 * S + 20 * MS, (1.2, 0.0, 0.0), 0) == (
        'increment_too_large')
    assert [s.stamp for s in pairer.pop_ready(0)] == [2 * S]
    assert pairer.drops['increment_too_large'] == 1


def test_a_step_waits_for_its_measurement_until_now_reaches_timeout():
    pairer = StepPairer(timeout=10 * MS)
    pairer.add_angular_velocity(2 * S, (0.1, 0.0, 0.0), 0)
    pairer.add_angular_velocity(2 * S + 5 * MS, (0.1, 0.0, 0.0), 0)
    assert pairer.pop_ready(0) == []
    assert pairer.pop_ready(10 * MS - 1) == []
    [step] = pairer.pop_ready(10 * MS)
    assert (step.stamp, step.measurement) == (2 * S, None)


def test_a_sample_at_stamp_1_after_a_later_one_is_a_backward_jump():
    # Stamp 1 ns is a stamp (only 0 and below are refused), here 10 s back.
    pairer = StepPairer(timeout=0)
    pairer.add_angular_velocity(10 * S, (0.1, 0.0, 0.0), 0)
    assert pairer.add_angular_velocity(0, (0.1, 0.0, 0.0), 0) == 'zero_stamp_increment'
    assert pairer.add_angular_velocity(1, (0.1, 0.0, 0.0), 0) == BACKWARD_JUMP
    assert pairer.pending_stamp == 1
    fresh = StepPairer(timeout=0)
    assert fresh.add_angular_velocity(1, (0.1, 0.0, 0.0), 0) is None
    assert fresh.add_increment(2, (0.0, 0.0, 0.0), 0) is None
    assert fresh.add_measurement(0, Y) == 'zero_stamp_measurement'


def test_in_arrival_order_stamps_only_mark_jumps_back():
    # imu_tools' constant_dt: samples are taken as they come, the first one
    # whatever its stamp; a jump back beyond backward_jump starts over
    # (counted each time) from that sample; exactly backward_jump back is a
    # step like any other.
    pairer = StepPairer(timeout=0, constant_dt=0.005, arrival_order=True, backward_jump=1 * S)
    assert pairer.add_angular_velocity(0, (0.1, 0.0, 0.0), 0) is None
    assert pairer.add_angular_velocity(10 * S, (0.1, 0.0, 0.0), 0) is None
    assert pairer.add_angular_velocity(9 * S, (0.1, 0.0, 0.0), 0) is None
    assert [s.stamp for s in pairer.pop_ready(0)] == [0, 10 * S]
    t = 9 * S
    for count in (1, 2):
        t -= 1 * S + 1
        assert pairer.add_angular_velocity(t, (0.1, 0.0, 0.0), 0) == BACKWARD_JUMP
        assert pairer.events['backward_jumps'] == count
        assert pairer.pending_stamp == t
    assert pairer.add_angular_velocity(t + 1, (0.2, 0.0, 0.0), 0) is None
    [step] = pairer.pop_ready(0)
    assert step.stamp == t and step.increment[0] == pytest.approx(0.15 * 0.005)


def test_add_sample_in_arrival_order_restarts_at_a_jump_back():
    pairer = StepPairer(timeout=0, constant_dt=0.005, arrival_order=True, backward_jump=1 * S)
    acc = (0.0, 0.0, 9.8)
    pairer.add_sample(10 * S, (0.1, 0.0, 0.0), acc)
    assert pairer.add_sample(5 * S, (0.1, 0.0, 0.0), acc) == (BACKWARD_JUMP, ())
    assert pairer.events['backward_jumps'] == 1
    # Without a constant interval, arrival order does not apply: a repeated
    # stamp is a duplicate on the one-call path too.
    plain = StepPairer(timeout=0, arrival_order=True)
    plain.add_sample(2 * S, (0.1, 0.0, 0.0), acc)
    assert plain.add_sample(2 * S, (0.1, 0.0, 0.0), acc) == ('duplicate_increment', ())


def test_add_sample_refuses_an_infinite_acceleration_and_an_increment_too_large():
    pairer = StepPairer(timeout=0, max_increment=0.01)
    acc = (0.0, 0.0, 9.8)
    pairer.add_sample(2 * S, (0.1, 0.0, 0.0), acc)
    assert pairer.add_sample(2 * S + 5 * MS, (0.1, 0.0, 0.0), (math.inf, 0.0, 9.8)) == (
        'non_finite_acceleration', ())
    # Trapezoid over 5 ms: 0.3 rad/s on average, 0.0015 rad, kept; 2.75 rad/s
    # on average, 0.01375 rad, beyond 0.01.
    outcome, steps = pairer.add_sample(2 * S + 5 * MS, (0.5, 0.0, 0.0), acc)
    assert outcome is None and len(steps) == 1
    assert pairer.add_sample(2 * S + 10 * MS, (5.0, 0.0, 0.0), acc) == ('increment_too_large', ())


def test_add_sample_with_a_timeout_waits_as_the_general_path_does():
    # The one-call path is for steps that wait for nothing; with a timeout
    # a step waits for its measurement (or the deadline) as it would.
    pairer = StepPairer(timeout=50 * MS)
    acc = (0.0, 0.0, 9.8)
    assert pairer.add_sample(2 * S, (0.1, 0.0, 0.0), acc) == (None, ())
    assert pairer.add_sample(2 * S + 5 * MS, (0.1, 0.0, 0.0), acc) == (None, ())
    assert pairer.waiting('increment') == 2
    [step] = pairer.pop_ready(50 * MS)
    assert step.stamp == 2 * S


def test_after_a_one_call_step_a_measurement_inside_it_is_stale_and_at_its_end_taken():
    acc = (0.0, 0.0, 9.8)
    for at, outcome in ((2 * S + 5 * MS - 1, 'stale_measurement'), (2 * S + 5 * MS, None)):
        pairer = StepPairer(timeout=0)
        pairer.add_sample(2 * S, (0.1, 0.0, 0.0), acc)
        [step] = pairer.add_sample(2 * S + 5 * MS, (0.1, 0.0, 0.0), acc)[1]
        assert (step.stamp, step.end) == (2 * S, 2 * S + 5 * MS)
        assert pairer.add_measurement(at, Y) == outcome
        # The uncorrected last step's start is stale too (not a duplicate).
        assert pairer.add_measurement(2 * S, Y) == 'stale_measurement'


def test_a_measurement_jump_back_is_counted_each_time_and_its_edge_is_stale():
    pairer = StepPairer(timeout=0, backward_jump=1 * S)
    pairer.add_increment(10 * S, (0.0, 0.0, 0.0), 0)
    pairer.pop_ready(0)
    assert pairer.add_measurement(9 * S, Y) == 'stale_measurement'
    assert pairer.add_measurement(9 * S - 1, Y) == BACKWARD_JUMP
    assert pairer.add_increment(20 * S, (0.0, 0.0, 0.0), 0) is None
    pairer.pop_ready(1)
    assert pairer.add_measurement(19 * S - 1, Y) == BACKWARD_JUMP
    assert pairer.events['backward_jumps'] == 2


def test_restart_returns_everything_it_discards():
    pairer = StepPairer(timeout=1 * S)
    pairer.add_angular_velocity(2 * S, (0.1, 0.0, 0.0), 0)
    pairer.add_angular_velocity(2 * S + 5 * MS, (0.1, 0.0, 0.0), 0)
    pairer.add_measurement(3 * S, Y)
    pairer.add_measurement(4 * S, Y)
    assert pairer.restart() == 4   # one step and one sample waiting, two measurements
    assert pairer.drops['discarded_increment'] == 2
    assert pairer.drops['discarded_measurement'] == 2


def test_a_later_measurement_releases_a_step_at_once_from_its_edge_on():
    # A publisher sends in stamp order: a measurement at or after a step's
    # limit (its end, or its stamp + 1 for a given increment) shows the
    # step's own is not coming.
    pairer = StepPairer(timeout=1 * S)
    pairer.add_angular_velocity(2 * S, (0.1, 0.0, 0.0), 0)
    pairer.add_angular_velocity(2 * S + 5 * MS, (0.1, 0.0, 0.0), 0)
    pairer.add_measurement(2 * S + 5 * MS, Y)
    [step] = pairer.pop_ready(0)
    assert (step.stamp, step.measurement) == (2 * S, None)
    given = StepPairer(timeout=1 * S)
    given.add_increment(2 * S, (0.0, 0.0, 0.0), 0)
    given.add_measurement(2 * S - 1, Y)   # older: no sign
    assert given.pop_ready(0) == []
    given.add_measurement(2 * S + 1, Y)
    [step] = given.pop_ready(0)
    assert (step.stamp, step.measurement) == (2 * S, None)


def test_a_step_released_for_depth_is_marked_early():
    pairer = StepPairer(depth=1, timeout=1 * S)
    pairer.add_increment(2 * S, (0.0, 0.0, 0.0), 0)
    pairer.add_increment(3 * S, (0.0, 0.0, 0.0), 0)
    [step] = pairer.pop_ready(0)
    assert step.stamp == 2 * S and step.early is True
    assert pairer.events['early_releases'] == 1


def test_forward_gaps_are_counted_each_time():
    pairer = StepPairer(timeout=0, forward_gap=1 * S)
    for k, stamp in enumerate((2 * S, 4 * S, 6 * S)):
        pairer.add_increment(stamp, (0.0, 0.0, 0.0), 0)
        [step] = pairer.pop_ready(0)
        assert step.gap == (k > 0)
    assert pairer.events['forward_gaps'] == 2


def test_the_measurements_of_a_step_after_its_first_are_dropped_at_its_release():
    # Three inside one 10 ms interval: the first corrects it, the others
    # (the last at end - 1 ns) are unpaired; one at its end waits.
    pairer = StepPairer(timeout=1 * S)
    t0 = 2 * S
    pairer.add_angular_velocity(t0, (0.0, 0.0, 0.0), 0)
    pairer.add_angular_velocity(t0 + 10 * MS, (0.0, 0.0, 0.0), 0)
    for stamp in (t0, t0 + 3 * MS, t0 + 10 * MS - 1, t0 + 10 * MS):
        pairer.add_measurement(stamp, Y)
    [step] = pairer.pop_ready(0)
    assert step.measurement == Y
    assert pairer.drops['unpaired_measurement'] == 2
    assert pairer.waiting('measurement') == 1


@pytest.mark.parametrize('constant_dt', [0.0, 0.004])
def test_the_one_call_step_is_the_trapezoid_of_the_two_rates(constant_dt):
    # Slow rates, so that an increment off by any factor still passes the
    # bound and shows; over the stamps' 5 ms, or constant_dt when given.
    pairer = StepPairer(timeout=0, constant_dt=constant_dt)
    acc = (0.0, 0.0, 9.8)
    pairer.add_sample(2 * S, (0.001, -0.002, 0.0), acc)
    outcome, [step] = pairer.add_sample(2 * S + 5 * MS, (0.003, 0.0, 0.001), acc)
    dt = constant_dt or 0.005
    assert outcome is None
    assert step.increment == pytest.approx((0.002 * dt, -0.001 * dt, 0.0005 * dt), rel=1e-12)


def test_a_measurement_for_a_given_increment_already_released_is_stale():
    # The step of 2 s went on without one: its measurement, late, is stale
    # (not taken, not a duplicate); one for the next stamp is taken.
    pairer = StepPairer(timeout=0)
    pairer.add_increment(2 * S, (0.0, 0.0, 0.0), 0)
    [step] = pairer.pop_ready(0)
    assert step.measurement is None
    assert pairer.add_measurement(2 * S, Y) == 'stale_measurement'
    # The increment again, corrected or not, is a duplicate.
    assert pairer.add_increment(2 * S, (0.0, 0.0, 0.0), 0) == 'duplicate_increment'
    assert pairer.add_measurement(3 * S, Y) is None
    assert pairer.add_increment(3 * S, (0.0, 0.0, 0.0), 0) is None
    [step] = pairer.pop_ready(0)
    assert step.measurement == Y
    # Corrected, its stamp again is a duplicate.
    assert pairer.add_measurement(3 * S, Y) == 'duplicate_measurement'


def test_an_unknown_setting_is_refused_by_name():
    with pytest.raises(TypeError, match="unknown setting 'max_gap'"):
        StepPairer().configure(max_gap=1)


def test_a_default_pairer_refuses_a_measurement_off_unit_norm_by_more_than_10_percent():
    pairer = StepPairer()
    assert pairer.add_measurement(2 * S, (1.09, 0.0, 0.0, 0.0)) is None
    assert pairer.add_measurement(3 * S, (1.12, 0.0, 0.0, 0.0)) == 'norm_out_of_tolerance'


@pytest.mark.parametrize('first, then', [((3.0, 0.0, GRAVITY), (0.5, -0.3, GRAVITY + 0.2)),
                                         ((0.3, 0.0, GRAVITY), (3.0, -2.0, GRAVITY + 0.5))])
def test_a_starts_variance_is_its_documented_model_then_decays_sample_by_sample(first, then):
    # uncertainty_start's model (its docstring): until tau_acc, the running
    # mean m of e = max(dz², (fx² + fy²)/2)/g² (and the first sample's e, if
    # larger) owes atan(√max(m, e₁))² c/(c + t) per horizontal axis; then the
    # low-pass forgets it by (1 − k)² per sample, to zero below 1e-16. The
    # first sample's error larger than the rest's, then smaller (the mean
    # rules).
    tracker = AttitudeUncertainty.for_estimator(AhrsParams(tau_acc=0.2), use_mag=False)
    dt = 0.01
    tracker.start(dt)
    u = tracker.state
    K, C = uncertainty_kernel, uncertainty_kernel.START_CORRELATION
    u[K.U_START_T] = u[K.U_START_N] = u[K.U_START_M] = u[K.U_START_V] = u[K.U_START_F] = 0.0
    forces = [first] + [then] * 40
    errors = [max((fz - GRAVITY) ** 2, 0.5 * (fx * fx + fy * fy)) / GRAVITY ** 2
              for fx, fy, fz in forces]
    tau, k = u[K.U_TAU_ACC], u[K.U_K_ACC]   # the accelerometer's low-pass (0.25 s here)
    assert k == pytest.approx(1.0 - math.exp(-dt / tau), rel=1e-12)
    phases = []
    for n, f in enumerate(forces, start=1):
        t, before = u[K.U_START_T], u[K.U_START_V]
        K.uncertainty_start(u, dt, *f)
        if t < tau:
            a = math.atan(math.sqrt(max(np.mean(errors[:n]), errors[0])))
            assert u[K.U_START_V] == pytest.approx(a * a * C / (C + t), rel=1e-9), n
        else:
            assert u[K.U_START_V] == pytest.approx((1.0 - k) ** 2 * before, rel=1e-12), n
        phases.append(t < tau)
    assert abs(sum(phases) - round(tau / dt)) <= 1 and not phases[-1]
    assert u[K.U_START_V] > 1e-6


def test_the_published_variances_are_the_sum_of_their_parts_and_b_the_larger():
    # uncertainty_variances' sums, each part nonzero and distinct; the bias
    # variance B the larger of its own and the estimator's, exactly (also
    # when equal).
    K = uncertainty_kernel
    u = [0.0] * K.U_SIZE
    parts = dict(U_PT=1.0, U_START_V=2.0, U_TILT_FLOOR=4.0, U_STAMP2=8.0, U_WH2=16.0,
                 U_PH=32.0, U_UNKNOWN=64.0, U_HEADING_SET=1.0, U_HEADING_FLOOR=128.0,
                 U_CALIBRATION=256.0, U_WZ2=512.0, U_HS=3.0)
    for name, value in parts.items():
        u[getattr(K, name)] = value
    t, h = K.uncertainty_variances(u)
    assert t == 1.0 + 2.0 + 4.0 + 0.5 * 8.0 * 16.0
    assert h == 32.0 + 64.0 + 1.0 * (128.0 + 256.0) + 8.0 * 512.0 + 3.0 * 3.0
    for before, var, after in ((2e-6, 1e-6, 2e-6), (1e-6, 2e-6, 2e-6), (1e-6, 1e-6, 1e-6)):
        u[K.U_B] = before
        K.uncertainty_bias(u, var)
        assert u[K.U_B] == after
