"""
Edges of the estimator's kernel that its other tests missed (no ROS): found by mutmut's samples.

In 9D the IMU samples come without a field (fields have their own calls, at
their own rate): a sample without one must not touch the field's state (a
kernel that ran the field's step on the zeros of a missing field would take
them as the references). A reset forgets the last field's verdict with the
rest. The gyro's increment is exact at any step size (at 100 Hz a wrong
half-angle is a third-order error no other test sees). A gyro at its range
is clipped on any axis, and one stuck from its first sample as one stuck
later. A field with no horizontal part has no heading. With the
calibration on: its turn is the gyro's rotation since its last field (a
clip restarts it), a calibration loaded while running sets the heading at
once, and after a calibration the heading follows with time constant t/2.
A rest updates the bias's covariance and nothing after it. After a clip the
inclination restarts from a mean of one sample. A calibration applied at a
start (loaded, or kept by a reset) calibrates its first field once.
Fast: part of ``make mutation``'s subset of the
kernel (docs/tests.md#mutmut).
"""

import math

import numpy as np
import pytest

from ext_observer.core.ahrs.ahrs_filters import rotate
from ext_observer.core.ahrs.ahrs_layout import (S_BIAS_P, S_CAL_TURN, S_HAS_REF, S_MAG_USED, S_REF,
                                                S_RLP)
from ext_observer.core.ahrs.estimator import AhrsObserver, AhrsParams

DT = 0.01
TILTED = (1.2, -0.8, 9.7)
FIELD = (1.5e-5, 1.0e-5, -3.5e-5)


def field_state(est):
    s = est.flat_state
    return [s[S_HAS_REF], s[S_REF], s[S_REF + 1], s[S_MAG_USED]]


def test_in_9d_samples_without_a_field_leave_the_fields_state_and_the_heading():
    est = AhrsObserver(AhrsParams(), use_mag=True)
    # None yet: no references from a field that never came.
    for _ in range(50):
        est.update((0.0, 0.0, 0.0), TILTED, None, DT)
    assert field_state(est) == [0.0, 0.0, 0.0, 0.0]
    for _ in range(20):
        est.update((0.0, 0.0, 0.0), TILTED, FIELD, DT)
    before, q = field_state(est), np.array(est.q)
    assert before[0] == 1.0 and before[1] > 0.0
    for _ in range(50):
        est.update((0.0, 0.0, 0.0), TILTED, None, DT)
    assert field_state(est) == before
    assert np.allclose(est.q, q, atol=1e-9)


def test_a_reset_forgets_that_the_last_field_was_disturbed():
    est = AhrsObserver(AhrsParams(), use_mag=True)
    for _ in range(20):
        est.update((0.0, 0.0, 0.0), TILTED, FIELD, DT)
    est.update((0.0, 0.0, 0.0), TILTED, tuple(3.0 * v for v in FIELD), DT)
    assert est.mag_disturbed is True
    est.reset()
    assert est.mag_disturbed is False


def test_the_gyros_increment_is_exact_for_any_step_size():
    # Level, turning about the vertical in 6D (nothing corrects the heading)
    # with a rate that changes a little each sample (never repeated: not a
    # stuck gyro), 10 Hz: up to 0.35 rad per step. The heading is the sum of
    # the steps' angles to rounding: the increment is the exact rotation of
    # the step (the exponential map), not an approximation good only for
    # small angles.
    est = AhrsObserver(AhrsParams(), use_mag=False)
    est.update((0.0, 0.0, 0.0), (0.0, 0.0, 9.81), None, 0.1)
    heading = 0.0
    for k in range(40):
        rate = 2.5 + 0.025 * k
        q = est.update((0.0, 0.0, rate), (0.0, 0.0, 9.81), None, 0.1)
        heading += rate * 0.1
        expected = (np.cos(0.5 * heading), 0.0, 0.0, np.sin(0.5 * heading))
        assert np.allclose(q, expected, atol=1e-9) or np.allclose(q, np.negative(expected),
                                                                  atol=1e-9), k


def test_a_gyro_at_its_range_is_counted_on_any_axis_and_adds_range_dt_squared_per_axis():
    # A known range of 4 rad/s: a sample at it on one axis, or on all three,
    # is clipped; its variance is (range dt)² per clipped axis (docstring of
    # _watch_clipping), zero again on the next good sample.
    for axes in ((0,), (1,), (2,), (0, 1, 2)):
        est = AhrsObserver(AhrsParams(gyro_range=4.0), use_mag=False)
        est.update((0.0, 0.0, 0.0), TILTED, None, DT)
        rate = [0.0, 0.0, 0.0]
        for i in axes:
            rate[i] = -4.0 if i == 1 else 4.0
        est.update(tuple(rate), TILTED, None, DT)
        assert est.clipped == 1, axes
        assert est.clip_variance == pytest.approx(len(axes) * (4.0 * DT) ** 2, rel=1e-12)
        est.update((0.0, 0.0, 0.0), TILTED, None, DT)
        assert est.clipped == 1 and est.clip_variance == 0.0


def test_a_recordings_run_in_one_call_is_its_samples_one_by_one():
    # AhrsObserver.run (the kernel's loop, ahrs_run) against update per
    # sample, 6D and 9D, a second of a turning, tilted, noisy body.
    rng = np.random.default_rng(31)
    gyr = rng.normal(0.0, 0.3, (100, 3)) + (0.2, -0.5, 1.0)
    acc = rng.normal(0.0, 0.3, (100, 3)) + TILTED
    mag = rng.normal(0.0, 1e-6, (100, 3)) + FIELD
    for use_mag in (False, True):
        whole = AhrsObserver(AhrsParams(), use_mag=use_mag).run(gyr, acc, mag if use_mag else None,
                                                                DT)
        one = AhrsObserver(AhrsParams(), use_mag=use_mag)
        each = [one.update(tuple(gyr[k]), tuple(acc[k]), tuple(mag[k]) if use_mag else None, DT)
                for k in range(100)]
        assert whole.shape == (100, 4)
        assert np.allclose(whole, each, rtol=0.0, atol=1e-12)
        assert np.ptp(whole, axis=0).min() > 0.01   # every component moved


def test_a_reset_is_a_fresh_start():
    # Without a calibration (whose learned part a reset keeps on purpose):
    # after a reset, the same samples give the estimates a new estimator
    # gives, in 6D and 9D, through a turn with a gyro bias that the field
    # must correct.
    rng = np.random.default_rng(27)
    gyr = rng.normal(0.0, 0.01, (300, 3)) + (0.0, 0.0, 0.3)
    acc = rng.normal(0.0, 0.05, (300, 3)) + TILTED
    mag = rng.normal(0.0, 1e-7, (300, 3)) + FIELD
    for use_mag in (False, True):
        params = AhrsParams(mag_cal=False)
        used = AhrsObserver(params, use_mag=use_mag)
        fresh = AhrsObserver(params, use_mag=use_mag)
        for k in range(150):
            used.update(tuple(gyr[k]), tuple(acc[k]), tuple(mag[k]) if use_mag else None, DT)
        used.reset()
        for k in range(150, 300):
            m = tuple(mag[k]) if use_mag else None
            q = used.update(tuple(gyr[k]), tuple(acc[k]), m, DT)
            assert q == pytest.approx(fresh.update(tuple(gyr[k]), tuple(acc[k]), m, DT),
                                      abs=1e-12), (use_mag, k)


LEVEL = (0.0, 0.0, 9.81)
STILL = (0.0, 0.0, 0.0)


def field_heading(q, field):
    """The heading (rad, from north) of a body-frame field in the estimate's world frame."""
    hx, hy, _ = rotate(*q, *field)
    return math.atan2(hx, hy)


def quat_mul(a, b):
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return np.array([aw * bw - ax * bx - ay * by - az * bz, aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx, aw * bz + ax * by - ay * bx + az * bw])


def quat_exp(v):
    """``exp(v / 2)``: the rotation of vector ``v`` (rad) as a unit quaternion."""
    t = float(np.linalg.norm(v))
    return np.concatenate(([math.cos(0.5 * t)], math.sin(0.5 * t) / t * np.asarray(v)))


def test_a_field_with_no_horizontal_part_says_nothing_of_the_heading():
    # Level and still, 9D without a calibration: an exactly vertical field
    # (dip -90 deg) has no heading and is not a field used; the first with a
    # horizontal part (dip -85 deg, within mag_dip_th of the references) then
    # sets the heading at once, as a first field does (a running mean of one).
    est = AhrsObserver(AhrsParams(mag_cal=False), use_mag=True)
    for _ in range(50):
        est.update(STILL, LEVEL, (0.0, 0.0, -4e-5), DT)
    assert est.flat_state[S_MAG_USED] == 0.0
    h, a = 4e-5 * math.cos(math.radians(85.0)), math.radians(60.0)
    field = (h * math.cos(a), h * math.sin(a), -4e-5 * math.sin(math.radians(85.0)))
    q = est.update(STILL, LEVEL, field, DT)
    assert abs(field_heading(q, field)) < 1e-9


def test_the_calibrations_turn_is_the_gyros_rotation_since_its_last_field_and_a_clip_restarts_it():
    # 9D with the calibration (the default): IMU samples without a field,
    # turning at 8 rad/s about a tilted axis (0.08 rad per step: the turn
    # must be the exact rotation, not one right to first order). The turn
    # the calibration predicts its next field with is exp(w t / 2), the
    # gyro's rotation since the last field. A clipped sample restarts it:
    # from then on it is the rotation since that sample began.
    est = AhrsObserver(AhrsParams(gyro_range=20.0), use_mag=True)
    est.update(STILL, LEVEL, FIELD, DT)
    axis = np.array([0.3, -0.4, 0.866]) / np.linalg.norm([0.3, -0.4, 0.866])
    rate = 8.0 * axis
    for k in range(1, 31):
        est.update(tuple(rate), LEVEL, None, DT)
        turn = est.flat_state[S_CAL_TURN:S_CAL_TURN + 4]
        assert np.allclose(turn, quat_exp(rate * k * DT), rtol=0.0, atol=1e-12), k
    clip = np.array([20.0, 0.0, 0.0])
    est.update(tuple(clip), LEVEL, None, DT)
    assert est.clipped == 1
    for k in range(1, 11):
        est.update(tuple(rate), LEVEL, None, DT)
        turn = est.flat_state[S_CAL_TURN:S_CAL_TURN + 4]
        expected = quat_mul(quat_exp(clip * DT), quat_exp(rate * k * DT))
        assert np.allclose(turn, expected, rtol=0.0, atol=1e-12), k


def test_a_gyro_stuck_from_its_first_sample_is_clipped_as_one_stuck_later():
    # Unknown range (gyro_range 0): a rate of at least 2 rad/s repeated
    # exactly, at the largest magnitude seen, is the range (a stuck gyro)
    # from its second repeat on. The first sample of all is the first of
    # the repeats as any other.
    for lead in (0, 5):
        est = AhrsObserver(AhrsParams(), use_mag=False)
        for k in range(lead):
            est.update((0.1 * k, 0.0, 0.0), TILTED, None, DT)
        counts = []
        for _ in range(4):
            est.update((3.0, -1.0, 0.5), TILTED, None, DT)
            counts.append(est.clipped)
        assert counts == [0, 0, 1, 2], lead


def test_after_a_calibration_the_heading_follows_its_fields_with_time_constant_t_over_2():
    # Level and still, a calibration loaded while running (its true field's
    # heading taken at its next step); 2 s later the field's heading turns
    # by 0.2 rad. The heading follows the calibrated fields with the gain
    # max(k_mag, 1 - exp(-dt / max(1 s, t/2))), t since the calibration
    # was applied (ahrs_update_mag's refinement; no running mean after a
    # calibration): after 2 s more the residual is that rule's, about a
    # quarter of the turn (k_mag alone would leave 0.88 of it), to within
    # what the calibration, learning on, takes of the turn into its offset.
    est = AhrsObserver(AhrsParams(), use_mag=True)
    k_mag = 1.0 - math.exp(-DT / AhrsParams().tau_mag)
    offset = np.array([3e-5, -1e-5, 0.0])
    c, s = math.cos(0.2), math.sin(0.2)
    turned = (FIELD[0] * c - FIELD[1] * s, FIELD[0] * s + FIELD[1] * c, FIELD[2])
    for _ in range(100):
        est.update(STILL, LEVEL, tuple(np.array(FIELD) + offset), DT)
    est.load_calibration(tuple(offset), np.eye(3))
    # The next field is the calibration's step (its period passed long ago).
    for _ in range(200):
        q = est.update(STILL, LEVEL, tuple(np.array(FIELD) + offset), DT)
    assert abs(field_heading(q, FIELD)) < 1e-9
    e = field_heading(q, turned)
    assert abs(e) == pytest.approx(0.2)
    for n in range(201, 401):
        q = est.update(STILL, LEVEL, tuple(np.array(turned) + offset), DT)
        kap = max(k_mag, 1.0 - math.exp(-DT / max(1.0, 0.5 * n * DT)))
        e -= 2.0 * math.atan2(kap * math.sin(0.5 * e), 1.0 - kap + kap * math.cos(0.5 * e))
    assert field_heading(q, turned) == pytest.approx(e, abs=0.01)
    assert 0.15 < abs(field_heading(q, turned)) / 0.2 < 0.35


def test_a_calibration_loaded_while_running_sets_the_heading_at_the_next_calibration_step():
    # Level and still, a raw field with a hard-iron offset: the heading is
    # the raw field's. Loaded while running, the calibration gives the true
    # field, whose heading the estimate takes at once at the calibration's
    # next step (within 1/mag_cal_rate), not over the refinement's seconds.
    est = AhrsObserver(AhrsParams(), use_mag=True)
    offset = np.array([3e-5, -1e-5, 0.0])
    raw = tuple(np.array(FIELD) + offset)
    for _ in range(100):
        est.update(STILL, LEVEL, raw, DT)
    assert abs(field_heading(est.q, FIELD)) > 0.3
    est.load_calibration(tuple(offset), np.eye(3))
    steps = int(math.ceil(1.0 / AhrsParams().mag_cal_rate / DT)) + 1
    for _ in range(steps):
        q = est.update(STILL, LEVEL, raw, DT)
    assert abs(field_heading(q, FIELD)) < 1e-6


def test_a_rest_touches_the_bias_and_its_covariance_but_not_the_low_passed_attitude():
    # Level and still: one estimator detects the rest (rest_time 1.5 s, the
    # default), the other never (rest_time 1000 s). The rest learns the
    # bias (zero here) and updates its covariance; the low-passed R(q̂)
    # that the bias learned in motion uses (the flat state's slots after
    # the covariance's six) is the same in both, to the bit.
    rest, never = (AhrsObserver(AhrsParams(rest_time=t), use_mag=False) for t in (1.5, 1000.0))
    for _ in range(400):
        rest.update(STILL, LEVEL, None, DT)
        never.update(STILL, LEVEL, None, DT)
    assert rest.rest and not never.rest
    a, b = rest.flat_state, never.flat_state
    assert not np.array_equal(a[S_BIAS_P:S_BIAS_P + 6], b[S_BIAS_P:S_BIAS_P + 6])
    assert np.array_equal(a[S_RLP:S_RLP + 18], b[S_RLP:S_RLP + 18])
    assert np.ptp(a[S_RLP:S_RLP + 18]) > 0.5   # R's states are not all zero


def test_after_a_clip_the_inclination_restarts_from_a_mean_of_one_sample():
    # Level and still for 3 s (the low-pass full of the vertical), then one
    # sample at the gyro's range about x (0.2 rad in its step): the
    # inclination starts again from the running mean of the specific force,
    # so this very sample's correction is toward its own accelerometer
    # alone (a mean of one, whatever the low-pass held): q ← r ⊗ q_gyro,
    # r = (1 − κ) + κ δ, δ the rotation taking f = R(q_gyro) a to the
    # vertical, κ = 1 − exp(−dt / tau_acc_gain).
    params = AhrsParams(gyro_range=20.0)
    est = AhrsObserver(params, use_mag=False)
    for _ in range(300):
        est.update(STILL, LEVEL, None, DT)
    q0 = np.array(est.q)
    clip = np.array([20.0, 0.0, 0.0])
    acc = np.array([0.3, 1.1, 9.7])
    q = np.array(est.update(tuple(clip), tuple(acc), None, DT))
    assert est.clipped == 1
    q_gyro = quat_mul(q0, quat_exp(clip * DT))
    f = np.array(rotate(*q_gyro, *acc))
    u = f / np.linalg.norm(f)
    delta = np.array([1.0 + u[2], u[1], -u[0], 0.0])
    delta /= np.linalg.norm(delta)
    kap = 1.0 - math.exp(-DT / params.tau_acc_gain)
    r = np.array([1.0 - kap, 0.0, 0.0, 0.0]) + kap * delta
    assert np.allclose(q, quat_mul(r, q_gyro), rtol=0.0, atol=1e-12)

def test_the_first_field_of_a_start_is_calibrated_once():
    """
    A calibration applied at a start (loaded, or kept by a reset) calibrates its first field once.

    The start calibrated the field for the first attitude, then the field's
    step calibrated that again: after a reset with a calibration applied,
    the heading started 8° off on a synthetic run (found with
    test_magcal_kernel.py's loaded calibration, applied before any field).
    """
    soft = np.array([[1.1, 0.05, 0.0], [0.05, 0.9, 0.02], [0.0, 0.02, 1.0]])
    bias = np.array([2.0e-5, -1.5e-5, 1.0e-5])
    raw = tuple(soft @ np.array(FIELD) + bias)
    plain = AhrsObserver(AhrsParams(mag_cal=False))
    want = plain.update((0.0, 0.0, 0.0), TILTED, FIELD, DT)
    est = AhrsObserver(AhrsParams())
    est.load_calibration(bias, soft)
    for _ in range(2):
        got = est.update((0.0, 0.0, 0.0), TILTED, raw, DT)
        assert est.calibration.applied
        assert got == pytest.approx(want, abs=1e-9)
        est.reset()
