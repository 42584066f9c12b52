"""
The estimator's kernel (``ahrs_kernel.py``) step by step (no ROS): fast known answers.

Three parts: the gyro's and the accelerometer's steps, rest and reset; the
field's step and what each calibration step hands the calibration; the
edges (a sample without a field, any step size, a clip, a calibration
loaded while running). Written for the survivors of mutmut's whole run of ``ahrs_kernel.py``
(docs/tests.md#mutmut): the gyro's step is the exact increment of the
rate less the bias, then the extension term ``p (1 − 4α(|p|² − 1))`` (the
paper's ``−α∇V``), and it hands the calibration that rate and whether the
body has moved; after the start, the accelerometer's step low-passes the
world-frame specific force (``ahrs_filters.lowpass``, tested on its own)
and turns the estimate toward it; rest needs every axis of the specific
force still; a stuck gyro is found on any axis; after a clip the next field
sets the heading; and a reset leaves the state a new estimator's. Part of
``make mutation``'s subset of the kernel: about a second on the plain
kernels.
"""

import copy
import math

import numpy as np
import pytest

from ext_observer.core.ahrs.ahrs_filters import lowpass, rotate
from ext_observer.core.ahrs.ahrs_kernel import ahrs_update_acc, ahrs_update_gyr
from ext_observer.core.ahrs.ahrs_observer import AhrsObserver, AhrsParams
from ext_observer.core.ahrs.ahrs_state import STATE
from ext_observer.core.ahrs.clip_and_rest import _REST_BIAS_SIGMA, detect_rest

DT = 0.01
TILTED = (1.2, -0.8, 9.7)
STILL = (0.0, 0.0, 0.0)
FIELD = (1.5e-5, 1.0e-5, -3.5e-5)


def record(est):
    """The estimate's state record, its fields by attribute (plain, or a view of the compiled)."""
    holder = est.state
    return holder.view(np.recarray)[0] if isinstance(holder, np.ndarray) else holder[0]


def snapshot(s):
    """A plain copy of a state record."""
    copied = STATE.plain()
    STATE.copy(s, copied)
    return copied


def qmul(a, b):
    aw, av = a[0], np.asarray(a[1:])
    bw, bv = b[0], np.asarray(b[1:])
    return np.concatenate(([aw * bw - av @ bv], aw * bv + bw * av + np.cross(av, bv)))


def qexp(v):
    """``exp(v / 2)``: the rotation of vector ``v`` (rad)."""
    t = float(np.linalg.norm(v))
    return np.concatenate(([math.cos(0.5 * t)], math.sin(0.5 * t) / t * np.asarray(v)))


@pytest.mark.parametrize('variant', ['extended', 'plain'])
def test_the_gyros_step_is_the_exact_increment_then_the_extension_term(variant):
    params = AhrsParams()
    est = AhrsObserver(params, use_mag=True, variant=variant)
    est.update(STILL, TILTED, FIELD, DT)
    s = record(est)
    q = 1.05 * np.array([0.6, -0.3, 0.5, 0.5385164807134504])   # not unit
    bias = np.array([0.02, -0.015, 0.01])
    s.est.q[:] = list(q)
    s.bias.rate[:] = list(bias)
    gyr = np.array([1.5, -4.0, 2.5])
    ahrs_update_gyr(s, *gyr)
    p = qmul(q, qexp((gyr - bias) * DT))
    if variant == 'extended':
        p = p * (1.0 - 4.0 * params.alpha * (p @ p - 1.0))
    assert np.allclose(s.est.q, p, rtol=0.0, atol=1e-14)
    # The calibration is handed the rate less the bias.
    assert np.allclose(s.cal_feed.rate, gyr - bias, rtol=0.0, atol=1e-15)


def test_the_body_has_moved_once_the_low_passed_rate_less_the_bias_reaches_rest_gyr():
    # The low-passed rate the check reads (set here), less the bias, just
    # above and just below rest_gyr, along a diagonal (every axis counts).
    params = AhrsParams()
    bias = np.array([0.03, -0.02, 0.025])
    diagonal = np.ones(3) / math.sqrt(3.0)
    for factor, moved in ((1.01, 1.0), (0.99, 0.0)):
        est = AhrsObserver(params, use_mag=True)
        est.update(STILL, TILTED, FIELD, DT)
        s = record(est)
        assert s.cal_feed.moved == 0.0
        s.bias.rate[:] = list(bias)
        s.rest.gyr_lp[:] = list(bias + factor * params.rest_gyr * diagonal)
        ahrs_update_gyr(s, *bias)
        assert s.cal_feed.moved == moved, factor


def test_after_the_start_the_accelerometers_step_low_passes_the_world_frame_specific_force():
    # 6D, turning and accelerating, past the start (tau_acc): each step
    # filters f = R(q) a with the Butterworth (ahrs_filters.lowpass on the
    # states before it), turns q by r = (1 − κ) + κ δ toward the vertical
    # (δ taking the filtered f to it), and the states with r.
    params = AhrsParams(tau_acc=0.5)
    est = AhrsObserver(params, use_mag=False)
    s = record(est)
    checked = 0
    for k in range(120):
        rate = (0.4 * math.sin(0.1 * k), 0.3, -0.2)
        acc = (1.0 + 0.5 * math.sin(0.2 * k), -0.8, 9.7 + 0.3 * math.cos(0.15 * k))
        if k == 0:
            est.update(rate, acc, None, DT)
            continue
        ahrs_update_gyr(s, *rate)
        before = snapshot(s)
        ahrs_update_acc(s, *acc)
        if before.inc.start < params.tau_acc:
            continue
        shadow = copy.deepcopy(before)
        q = np.array(before.est.q)
        f = np.array(lowpass(shadow.coef.bw, shadow.inc.lp, 0, *rotate(*q, *acc)))
        u = f / np.linalg.norm(f)
        delta = np.array([1.0 + u[2], u[1], -u[0], 0.0])
        delta /= np.linalg.norm(delta)
        kap = 1.0 - math.exp(-DT / params.tau_acc_gain)
        assert before.coef.k_acc == pytest.approx(kap, rel=1e-12)
        r = np.array([1.0 - kap, 0.0, 0.0, 0.0]) + kap * delta
        assert np.allclose(s.est.q, qmul(r, q), rtol=0.0, atol=1e-13), k
        for i in (0, 3):
            assert np.allclose(s.inc.lp[i:i + 3], rotate(*r, *shadow.inc.lp[i:i + 3]), rtol=1e-12,
                               atol=1e-13), (k, i)
        checked += 1
    assert checked > 50


def first_rest(sample_of, seconds=3.0):
    """The first sample at which the estimator is at rest (``sample_of(t)``: gyro, acc)."""
    est = AhrsObserver(AhrsParams(), use_mag=False)
    for k in range(int(seconds / DT)):
        est.update(*sample_of(k * DT), None, DT)
        if est.rest:
            return k
    return None


def test_rest_is_found_rest_time_after_a_tilted_start_and_not_while_any_axis_shakes():
    # Tilted (every axis of gravity nonzero) and still: at rest rest_time
    # (1.5 s) after the first sample, give or take a sample. Shaking 0.8
    # m/s² on one axis of the accelerometer (beyond rest_acc, 0.5 m/s²), or
    # 0.2 rad/s on one of the gyro (beyond rest_gyr, 2 deg/s), at 5 Hz:
    # never at rest.
    k = first_rest(lambda t: (STILL, TILTED))
    assert k is not None and abs(k * DT - AhrsParams().rest_time) <= 2.5 * DT
    # Set down at another tilt after 0.5 s (3 m/s² away): at rest once the
    # mean (tau_rest 0.5 s) has followed every axis of it within rest_acc,
    # about 0.9 s, and rest_time has passed: about 2.9 s.
    k = first_rest(lambda t: (STILL, TILTED if t < 0.5 else (-0.9, 1.3, 9.6)), 4.0)
    assert k is not None and 2.7 <= k * DT <= 3.1
    for axis in range(3):
        shake = np.zeros(3)
        shake[axis] = 1.0

        def acc_of(t, shake=shake):
            return STILL, tuple(np.array(TILTED) + 0.8 * shake * math.sin(10.0 * math.pi * t))

        def gyr_of(t, shake=shake):
            return tuple(0.2 * shake * math.sin(10.0 * math.pi * t)), TILTED

        assert first_rest(acc_of) is None, axis
        assert first_rest(gyr_of) is None, axis


@pytest.mark.parametrize('axis', [None, 0, 1, 2])
def test_at_rest_the_bias_is_the_low_passed_rate_on_every_axis(axis):
    # Still from the start, or after turning 1 s about one axis: the rest's
    # low-passed rate follows every axis, so the body is at rest after
    # rest_time and the bias learned is the rate on each axis.
    est = AhrsObserver(AhrsParams(), use_mag=False)
    bias = np.array([0.01, -0.02, 0.015])
    if axis is not None:
        turn = bias.copy()
        turn[axis] += 0.5
        for _ in range(100):
            est.update(tuple(turn), TILTED, None, DT)
        assert not est.rest
    for _ in range(1000):
        est.update(tuple(bias), TILTED, None, DT)
    assert est.rest
    assert np.allclose(record(est).bias.rate, bias, rtol=0.0, atol=1e-6)


def test_at_rest_the_bias_covariance_is_that_of_a_measurement_of_the_rests_sigma():
    # detect_rest at rest: P ← (1 − k)² P + 2 k σ² I, k the rest's low-pass
    # gain, σ its steady bias σ; off the diagonal only the shrink.
    est = AhrsObserver(AhrsParams(), use_mag=False)
    for _ in range(200):
        est.update(STILL, TILTED, None, DT)
    assert est.rest
    s = record(est)
    p = np.array([[4.0, 0.5, -0.3], [0.5, 3.0, 0.2], [-0.3, 0.2, 2.0]]) * 1e-6
    s.bias.p[:] = list(p[np.triu_indices(3)])
    detect_rest(s, 0.0, 0.0, 0.0)
    k = 1.0 - math.exp(-DT / AhrsParams().tau_rest)
    expected = (1.0 - k) ** 2 * p + 2.0 * k * _REST_BIAS_SIGMA ** 2 * np.eye(3)
    assert np.allclose(s.bias.p, expected[np.triu_indices(3)], rtol=1e-12, atol=0.0)


@pytest.mark.parametrize('stuck', [(0.5, 3.0, -1.0), (0.5, -1.0, -3.0)])
def test_a_gyro_stuck_from_its_first_sample_on_any_axis_is_clipped(stuck):
    # Unknown range: the second repeat of the largest rate seen is the range
    # (the edges below have it on x); on y and on z alike.
    est = AhrsObserver(AhrsParams(), use_mag=False)
    counts = []
    for _ in range(4):
        est.update(stuck, TILTED, None, DT)
        counts.append(est.clipped)
    assert counts == [0, 0, 1, 2]


def test_after_a_clip_the_field_takes_the_heading_back_as_the_clips_doubt_allows():
    # 9D without a calibration, level and still with a field; one sample
    # at the gyro's range about the vertical (0.2 rad in its step): the
    # clip's doubt weighs the next fields with its Kalman gain, so the
    # heading is not set at once from one field (a bent one would take it),
    # and is back within 20 % in 3 s, where tau_mag's gain alone would give
    # back 18 %.
    est = AhrsObserver(AhrsParams(mag_cal=False, gyro_range=20.0), use_mag=True)
    level = (0.0, 0.0, 9.81)
    for _ in range(100):
        est.update(STILL, level, FIELD, DT)

    def heading_error(q):
        hx, hy, _ = rotate(*q, *FIELD)
        return abs(math.atan2(hx, hy))

    lost = heading_error(est.update((0.0, 0.0, 20.0), level, FIELD, DT))
    assert est.clipped == 1
    assert lost > 0.15
    assert heading_error(est.update(STILL, level, FIELD, DT)) > 0.9 * lost
    for _ in range(299):
        q = est.update(STILL, level, FIELD, DT)
    assert heading_error(q) < 0.2 * lost


@pytest.mark.parametrize('mag_cal', [False, True])
def test_a_reset_leaves_the_state_a_new_estimators(mag_cal):
    # 9D: still with a gyro bias until at rest (a bias learned), a disturbed
    # field, a clip. After a reset and one sample, the whole state is
    # that of a new estimator after the same sample, but for the counts kept
    # on purpose (the clips counted since the node started) and the
    # calibration's own block (what it learned a reset keeps).
    params = AhrsParams(mag_cal=mag_cal, gyro_range=20.0)
    used, fresh = AhrsObserver(params, use_mag=True), AhrsObserver(params, use_mag=True)
    bias = (0.01, -0.02, 0.015)
    for _ in range(250):
        used.update(bias, TILTED, FIELD, DT)
    assert used.rest and np.all(np.abs(np.array(record(used).bias.rate)) > 1e-3)
    for _ in range(20):
        used.update(bias, TILTED, tuple(2.0 * np.array(FIELD)), DT)
    used.update((20.0, 0.0, 0.0), TILTED, FIELD, DT)
    used.reset()
    a = used.update(bias, TILTED, FIELD, DT)
    b = fresh.update(bias, TILTED, FIELD, DT)
    if not mag_cal:
        assert a == b
    x, y = record(used), record(fresh)
    differ = []
    for path, _, _, _ in STATE.fields():
        name = '.'.join(path)
        if path[0] != 'cal' and not np.array_equal(np.atleast_1d(STATE.get(x, name)),
                                                    np.atleast_1d(STATE.get(y, name)),
                                                    equal_nan=True):
            differ.append(name)
    assert differ == ['gyro.clips'], differ
    assert x.gyro.clips == 1.0 and y.gyro.clips == 0.0


def test_a_new_estimator_has_counted_nothing_and_its_calibration_turn_is_none():
    # A new estimator (and a reset one, which the test above compares with
    # it) starts with no time counted: no rejection, candidate, rest or
    # start time, no field used or waited for, no bias, no reference; with
    # the calibration, no turn or rate since a field, the first field
    # learned from at once (its wait infinite), the body not moved, no
    # calibration applied (its time infinite) and none loaded; no clip to
    # recover from (the health's recovering state).
    est = AhrsObserver(AhrsParams(), use_mag=True)
    s = record(est)
    zero = [s.field.rejected, s.field.cand_time, s.rest.time, s.field.mag_used, s.field.wait_n,
            s.field.wait_turn, s.inc.start, s.inc.start_n, s.gyro.clipped, s.field.has_ref,
            s.field.mag_dist, s.rest.detected, s.cal_feed.moved, s.cal_feed.loaded,
            s.gyro.clip_left]
    assert zero == [0.0] * len(zero)
    assert list(s.bias.rate) == [0.0] * 3
    assert list(s.cal_feed.turn) == [1.0, 0.0, 0.0, 0.0]
    assert list(s.cal_feed.rate) == [0.0] * 3
    assert s.cal_feed.wait == math.inf and s.cal_feed.since == math.inf


LEVEL = (0.0, 0.0, 9.81)


# Edges: a sample without a field, a reset, any step size, a clip, a loaded calibration ---
#
# In 9D the IMU samples come without a field (fields have their own calls, at their own
# rate): a sample without one must not touch the field's state (a kernel that ran the field's
# step on the zeros of a missing field would take them as the references). A reset forgets
# the last field's verdict with the rest. The gyro's increment is exact at any step size (at
# 100 Hz a wrong half-angle is a third-order error no other test sees). A gyro at its range
# is clipped on any axis, and one stuck from its first sample as one stuck later. A field
# with no horizontal part has no heading. With the calibration on: its turn is the gyro's
# rotation since its last field (a clip restarts it), a calibration loaded while running sets
# the heading at once, and after a calibration the heading follows with time constant t/2. A
# rest updates the bias's covariance and nothing after it. After a clip the inclination
# restarts from a mean of one sample. A calibration applied at a start (loaded, or kept by a
# reset) calibrates its first field once.

def field_state(est):
    s = record(est)
    return [s.field.has_ref, s.field.ref[0], s.field.ref[1], s.field.mag_used]


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
    assert record(est).field.mag_used == 0.0
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
        turn = record(est).cal_feed.turn
        assert np.allclose(turn, quat_exp(rate * k * DT), rtol=0.0, atol=1e-12), k
    clip = np.array([20.0, 0.0, 0.0])
    est.update(tuple(clip), LEVEL, None, DT)
    assert est.clipped == 1
    for k in range(1, 11):
        est.update(tuple(rate), LEVEL, None, DT)
        turn = record(est).cal_feed.turn
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
    # that the bias learned in motion uses (bias.r_lp, beside the
    # covariance) is the same in both, to the bit.
    rest, never = (AhrsObserver(AhrsParams(rest_time=t), use_mag=False) for t in (1.5, 1000.0))
    for _ in range(400):
        rest.update(STILL, LEVEL, None, DT)
        never.update(STILL, LEVEL, None, DT)
    assert rest.rest and not never.rest
    a, b = record(rest), record(never)
    assert not np.array_equal(a.bias.p, b.bias.p)
    assert np.array_equal(a.bias.r_lp, b.bias.r_lp)
    assert np.ptp(a.bias.r_lp) > 0.5   # R's states are not all zero


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


def test_the_first_sample_starts_the_low_passed_vertical_at_the_estimates():
    # The heading's bias measurement low-passes R(q)'s z row (the world's
    # vertical in the body frame); it starts at the first attitude's, here
    # tilted and turned (6D: no field step moves it).
    est = AhrsObserver(AhrsParams(), use_mag=False)
    est.update(STILL, TILTED, None, DT)
    s = record(est)
    w, x, y, z = (float(v) for v in s.est.q)
    n2 = w * w + x * x + y * y + z * z
    row = [2.0 * (x * z - w * y) / n2, 2.0 * (y * z + w * x) / n2,
           (w * w - x * x - y * y + z * z) / n2]
    assert abs(row[0]) > 0.05 and abs(row[1]) > 0.05
    assert list(s.bias.rz_lp) == pytest.approx(row, abs=1e-12)
