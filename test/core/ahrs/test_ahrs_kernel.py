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

import math

import numpy as np
import pytest

from ext_observer.core.ahrs import magcal_kernel
from ext_observer.core.ahrs.ahrs_filters import lowpass, rotate
from ext_observer.core.ahrs.ahrs_kernel import (_turn_heading, ahrs_update_acc, ahrs_update_gyr,
                                                ahrs_update_mag)
from ext_observer.core.ahrs.ahrs_layout import (C_BIAS_R, C_K_ACC, MC0, S_BIAS, S_BIAS_P,
                                                S_CAL_LOADED, S_CAL_MOVED, S_CAL_RATE, S_CAL_SINCE,
                                                S_CAL_TURN, S_CAL_WAIT, S_CAND, S_CAND_TIME,
                                                S_CLIPPED, S_CLIPS, S_HAS_REF, S_LP, S_MAG_DIST,
                                                S_MAG_USED, S_Q, S_REF, S_REF_AGE, S_REF_REST,
                                                S_REJECTED, S_REST, S_REST_GYR, S_REST_TIME, S_RLP,
                                                S_RZLP, S_START, S_START_N, S_WAIT_N, S_WAIT_TURN)
from ext_observer.core.ahrs.bias_kernel import bias_measure
from ext_observer.core.ahrs.estimator import AhrsObserver, AhrsParams
from ext_observer.core.ahrs.gyro_watch import _REST_BIAS_SIGMA, detect_rest
from ext_observer.core.ahrs.magcal_layout import MAGCAL, MC_READY, MC_REFUSED, MC_USED

DT = 0.01
TILTED = (1.2, -0.8, 9.7)
STILL = (0.0, 0.0, 0.0)
FIELD = (1.5e-5, 1.0e-5, -3.5e-5)


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
    s = est.flat_state
    q = 1.05 * np.array([0.6, -0.3, 0.5, 0.5385164807134504])   # not unit
    bias = np.array([0.02, -0.015, 0.01])
    s[S_Q:S_Q + 4] = q
    s[S_BIAS:S_BIAS + 3] = bias
    gyr = np.array([1.5, -4.0, 2.5])
    ahrs_update_gyr(s, *gyr)
    p = qmul(q, qexp((gyr - bias) * DT))
    if variant == 'extended':
        p = p * (1.0 - 4.0 * params.alpha * (p @ p - 1.0))
    assert np.allclose(s[S_Q:S_Q + 4], p, rtol=0.0, atol=1e-14)
    # The calibration is handed the rate less the bias.
    assert np.allclose(s[S_CAL_RATE:S_CAL_RATE + 3], gyr - bias, rtol=0.0, atol=1e-15)


def test_the_body_has_moved_once_the_low_passed_rate_less_the_bias_reaches_rest_gyr():
    # The low-passed rate the check reads (set here), less the bias, just
    # above and just below rest_gyr, along a diagonal (every axis counts).
    params = AhrsParams()
    bias = np.array([0.03, -0.02, 0.025])
    diagonal = np.ones(3) / math.sqrt(3.0)
    for factor, moved in ((1.01, 1.0), (0.99, 0.0)):
        est = AhrsObserver(params, use_mag=True)
        est.update(STILL, TILTED, FIELD, DT)
        s = est.flat_state
        assert s[S_CAL_MOVED] == 0.0
        s[S_BIAS:S_BIAS + 3] = bias
        s[S_REST_GYR:S_REST_GYR + 3] = bias + factor * params.rest_gyr * diagonal
        ahrs_update_gyr(s, *bias)
        assert s[S_CAL_MOVED] == moved, factor


def up_of(q):
    w, x, y, z = np.asarray(q) / np.linalg.norm(q)
    return np.array([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)])


def test_after_the_start_the_accelerometers_step_low_passes_the_world_frame_specific_force():
    # 6D, turning and accelerating, past the start (tau_acc): each step
    # filters f = R(q) a with the Butterworth (ahrs_filters.lowpass on the
    # states before it), turns q by r = (1 − κ) + κ δ toward the vertical
    # (δ taking the filtered f to it), and the states with r.
    params = AhrsParams(tau_acc=0.5)
    est = AhrsObserver(params, use_mag=False)
    s = est.flat_state
    checked = 0
    for k in range(120):
        rate = (0.4 * math.sin(0.1 * k), 0.3, -0.2)
        acc = (1.0 + 0.5 * math.sin(0.2 * k), -0.8, 9.7 + 0.3 * math.cos(0.15 * k))
        if k == 0:
            est.update(rate, acc, None, DT)
            continue
        ahrs_update_gyr(s, *rate)
        before = np.array(s, dtype=float)
        ahrs_update_acc(s, *acc)
        if before[S_START] < params.tau_acc:
            continue
        shadow = before.copy()
        q = before[S_Q:S_Q + 4]
        f = np.array(lowpass(shadow, S_LP, *rotate(*q, *acc)))
        u = f / np.linalg.norm(f)
        delta = np.array([1.0 + u[2], u[1], -u[0], 0.0])
        delta /= np.linalg.norm(delta)
        kap = 1.0 - math.exp(-DT / params.tau_acc_gain)
        assert before[C_K_ACC] == pytest.approx(kap, rel=1e-12)
        r = np.array([1.0 - kap, 0.0, 0.0, 0.0]) + kap * delta
        assert np.allclose(s[S_Q:S_Q + 4], qmul(r, q), rtol=0.0, atol=1e-13), k
        for i in (S_LP, S_LP + 3):
            assert np.allclose(s[i:i + 3], rotate(*r, *shadow[i:i + 3]), rtol=1e-12,
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
    assert np.allclose(est.flat_state[S_BIAS:S_BIAS + 3], bias, rtol=0.0, atol=1e-6)


def test_at_rest_the_bias_covariance_is_that_of_a_measurement_of_the_rests_sigma():
    # detect_rest at rest: P ← (1 − k)² P + 2 k σ² I, k the rest's low-pass
    # gain, σ its steady bias σ; off the diagonal only the shrink.
    est = AhrsObserver(AhrsParams(), use_mag=False)
    for _ in range(200):
        est.update(STILL, TILTED, None, DT)
    assert est.rest
    s = est.flat_state
    p = np.array([[4.0, 0.5, -0.3], [0.5, 3.0, 0.2], [-0.3, 0.2, 2.0]]) * 1e-6
    s[S_BIAS_P:S_BIAS_P + 6] = p[np.triu_indices(3)]
    detect_rest(s, 0.0, 0.0, 0.0)
    k = 1.0 - math.exp(-DT / AhrsParams().tau_rest)
    expected = (1.0 - k) ** 2 * p + 2.0 * k * _REST_BIAS_SIGMA ** 2 * np.eye(3)
    assert np.allclose(s[S_BIAS_P:S_BIAS_P + 6], expected[np.triu_indices(3)], rtol=1e-12,
                       atol=0.0)


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


def test_after_a_clip_the_next_field_sets_the_heading_at_once():
    # 9D without a calibration, level and still with a field; one sample
    # at the gyro's range about the vertical (0.2 rad in its step): the
    # heading's running mean starts again, so this sample's field sets the
    # heading exactly (a mean of one field).
    est = AhrsObserver(AhrsParams(mag_cal=False, gyro_range=20.0), use_mag=True)
    level = (0.0, 0.0, 9.81)
    for _ in range(100):
        est.update(STILL, level, FIELD, DT)
    q = est.update((0.0, 0.0, 20.0), level, FIELD, DT)
    assert est.clipped == 1
    hx, hy, _ = rotate(*q, *FIELD)
    assert abs(math.atan2(hx, hy)) < 1e-9


@pytest.mark.parametrize('mag_cal', [False, True])
def test_a_reset_leaves_the_state_a_new_estimators(mag_cal):
    # 9D: still with a gyro bias until at rest (a bias learned), a disturbed
    # field, a clip. After a reset and one sample, the whole flat state is
    # that of a new estimator after the same sample, but for the counts kept
    # on purpose (the clips counted since the node started) and the
    # calibration's own block (what it learned a reset keeps).
    params = AhrsParams(mag_cal=mag_cal, gyro_range=20.0)
    used, fresh = AhrsObserver(params, use_mag=True), AhrsObserver(params, use_mag=True)
    bias = (0.01, -0.02, 0.015)
    for _ in range(250):
        used.update(bias, TILTED, FIELD, DT)
    assert used.rest and np.all(np.abs(np.array(used.flat_state[S_BIAS:S_BIAS + 3])) > 1e-3)
    for _ in range(20):
        used.update(bias, TILTED, tuple(2.0 * np.array(FIELD)), DT)
    used.update((20.0, 0.0, 0.0), TILTED, FIELD, DT)
    used.reset()
    a = used.update(bias, TILTED, FIELD, DT)
    b = fresh.update(bias, TILTED, FIELD, DT)
    if not mag_cal:
        assert a == b
    x, y = np.array(used.flat_state, dtype=float), np.array(fresh.flat_state, dtype=float)
    x, y = x[:MC0], y[:MC0]
    differ = np.flatnonzero(~((x == y) | (np.isnan(x) & np.isnan(y))))
    assert list(differ) == [S_CLIPS], differ
    assert x[S_CLIPS] == 1.0 and y[S_CLIPS] == 0.0


def test_a_new_estimator_has_counted_nothing_and_its_calibration_turn_is_none():
    # A new estimator (and a reset one, which the test above compares with
    # it) starts with no time counted: no rejection, candidate, rest or
    # start time, no field used or waited for, no bias, no reference; with
    # the calibration, no turn or rate since a field, the first field
    # learned from at once (its wait infinite), the body not moved, no
    # calibration applied (its time infinite) and none loaded.
    est = AhrsObserver(AhrsParams(), use_mag=True)
    s = np.array(est.flat_state, dtype=float)
    zero = [S_REJECTED, S_CAND_TIME, S_REST_TIME, S_MAG_USED, S_WAIT_N, S_WAIT_TURN, S_START,
            S_START_N, S_CLIPPED, S_HAS_REF, S_MAG_DIST, S_REST, S_CAL_MOVED, S_CAL_LOADED]
    assert [s[i] for i in zero] == [0.0] * len(zero)
    assert list(s[S_BIAS:S_BIAS + 3]) == [0.0] * 3
    assert list(s[S_CAL_TURN:S_CAL_TURN + 4]) == [1.0, 0.0, 0.0, 0.0]
    assert list(s[S_CAL_RATE:S_CAL_RATE + 3]) == [0.0] * 3
    assert s[S_CAL_WAIT] == math.inf and s[S_CAL_SINCE] == math.inf


# The field's step (ahrs_update_mag) and what each calibration step hands the calibration ----
#
# What ahrs_update_mag keeps of the fields (the references' norm and dip, the candidate of a
# new field, their times), what the heading does while it waits for the calibration and when
# the calibration finds the sensor calibrated, and what _calibrate hands the calibration at
# each of its steps. Each expected value is computed here from the rule the docstrings state
# (a first-order low-pass of gain 1 − exp(−dt/τ), VQF's candidate timer with its factor of
# two, Laidig & Seel 2023; the world's vertical as R(q)ᵀ e_z), not read from the code. Level,
# the norm and dip of a field are those of the world's field whatever the heading, so the
# scenarios set them exactly.

LEVEL = (0.0, 0.0, 9.81)
NORM, DIP = 4.5e-5, math.radians(-60.0)


def world_field(norm, dip, heading=0.0):
    """A field of this norm and dip whose horizontal part points ``heading`` east of north."""
    h = norm * math.cos(dip)
    return np.array([h * math.sin(heading), h * math.cos(heading), norm * math.sin(dip)])


def body_field(field, yaw):
    """The world ``field`` seen by a level body turned ``yaw`` about the vertical."""
    c, s = math.cos(yaw), math.sin(yaw)
    return (c * field[0] + s * field[1], -s * field[0] + c * field[1], field[2])


def yaw_of(q):
    w, x, y, z = q
    assert abs(x) < 1e-12 and abs(y) < 1e-12   # level
    return 2.0 * math.atan2(z, w)


def wrap(a):
    return math.atan2(math.sin(a), math.cos(a))


def test_the_first_field_sets_the_references_and_the_candidate():
    est = AhrsObserver(AhrsParams(mag_cal=False), use_mag=True)
    est.update(STILL, LEVEL, body_field(world_field(NORM, DIP, 0.7), 0.0), DT)
    s = est.flat_state
    assert s[S_HAS_REF] == 1.0
    assert list(s[S_REF:S_REF + 2]) == pytest.approx([NORM, DIP], rel=1e-12)
    assert list(s[S_CAND:S_CAND + 2]) == pytest.approx([NORM, DIP], rel=1e-12)


@pytest.mark.parametrize('change', ['norm', 'dip'])
def test_a_new_field_is_followed_by_its_candidate_and_accepted_after_mag_new_time(change):
    # Level, turning at 1 rad/s (above mag_new_gyr once the low-passed rate
    # is), mag_new_time 1 s. 2 s of the first field make the references old;
    # then a field 30 % stronger (or 20 deg steeper), drifting slowly within
    # the candidate's band: rejected; the candidate follows it as a
    # low-pass of tau_mag_ref, its time counts the turning samples, the
    # rejection time every rejected one; after mag_new_time the field is
    # accepted: the references are the candidate's, the rejection time 0.
    params = AhrsParams(mag_cal=False, mag_new_time=1.0)
    est = AhrsObserver(params, use_mag=True)
    s = est.flat_state
    kr = 1.0 - math.exp(-DT / params.tau_mag_ref)
    rate, yaw = 1.0, 0.0
    for _ in range(200):
        yaw += rate * DT
        est.update((0.0, 0.0, rate), LEVEL, body_field(world_field(NORM, DIP), yaw), DT)
    assert not est.mag_disturbed and s[S_REF_AGE] > 1.0
    cand, cand_time, rejected, accepted = None, 0.0, 0.0, None
    for k in range(200):
        norm, dip = (1.3 * NORM * (1.0 + 1e-4 * k), DIP) if change == 'norm' else (
            NORM, DIP - math.radians(20.0) + 1e-4 * k)
        yaw += rate * DT
        est.update((0.0, 0.0, rate), LEVEL, body_field(world_field(norm, dip), yaw), DT)
        if cand is None:   # off the old candidate: it starts over here
            cand = np.array([norm, dip])
        else:
            cand += kr * (np.array([norm, dip]) - cand)
            cand_time += DT
        if est.mag_disturbed:
            rejected += DT
            assert list(s[S_CAND:S_CAND + 2]) == pytest.approx(list(cand), rel=1e-9), k
            assert s[S_CAND_TIME] == pytest.approx(cand_time, abs=1e-9), k
            assert s[S_REJECTED] == pytest.approx(rejected, abs=1e-9), k
            assert list(s[S_REF:S_REF + 2]) == pytest.approx([NORM, DIP], rel=1e-9), k
        else:
            accepted = k
            break
    assert accepted in (100, 101)
    assert s[S_REJECTED] == 0.0 and s[S_REF_REST] == 0.0
    # The references are the candidate's, then follow this field as any used.
    ref = cand + kr * (np.array([norm, dip]) - cand)
    assert list(s[S_REF:S_REF + 2]) == pytest.approx(list(ref), rel=1e-9)
    assert s[S_REF_AGE] == pytest.approx(cand_time + DT, abs=1e-9)


def test_while_the_references_are_young_a_field_off_the_candidate_takes_back_twice_its_time():
    # Still 0.5 s, then turning with the first field: the references are
    # younger than mag_new_time (2 s) and no rest confirmed them. A field
    # 30 % stronger: off the candidate, each sample takes 2 dt from the
    # candidate's time (the candidate kept) until it is 0, then the
    # candidate is the new field, whose time counts up; it is accepted once
    # that time reaches the references' age (not mag_new_time). Back to
    # the first field, the rejection time decays by 2 dt a sample.
    params = AhrsParams(mag_cal=False, mag_new_time=2.0)
    est = AhrsObserver(params, use_mag=True)
    s = est.flat_state
    first = world_field(NORM, DIP)
    for _ in range(50):
        est.update(STILL, LEVEL, body_field(first, 0.0), DT)
    rate, yaw = 1.0, 0.0
    for _ in range(40):
        yaw += rate * DT
        est.update((0.0, 0.0, rate), LEVEL, body_field(first, yaw), DT)
    cand_time, age = s[S_CAND_TIME], s[S_REF_AGE]
    taken_back = math.ceil(cand_time / (2.0 * DT) - 1e-9)
    assert 0.1 < cand_time < age < 1.0 and s[S_REF_REST] == 0.0
    strong = world_field(1.3 * NORM, DIP)
    n = 0
    while cand_time > 0.0:
        yaw += rate * DT
        est.update((0.0, 0.0, rate), LEVEL, body_field(strong, yaw), DT)
        cand_time = max(cand_time - 2.0 * DT, 0.0)
        n += 1
        assert s[S_CAND_TIME] == pytest.approx(cand_time, abs=1e-9), n
        assert est.mag_disturbed
        expected = [1.3 * NORM, DIP] if cand_time == 0.0 else [NORM, DIP]
        assert list(s[S_CAND:S_CAND + 2]) == pytest.approx(expected, rel=1e-9), n
    assert n == taken_back
    assert s[S_REF_AGE] == pytest.approx(age, abs=1e-12)   # fields not used do not age them
    steps = 0
    while est.mag_disturbed:
        yaw += rate * DT
        est.update((0.0, 0.0, rate), LEVEL, body_field(strong, yaw), DT)
        steps += 1
        assert steps < 200
    assert abs(steps * DT - age) <= 1.5 * DT
    rejected = s[S_REJECTED]
    assert rejected == 0.0
    # A stretch of the old field (now rejected) then the new one again.
    for _ in range(30):
        yaw += rate * DT
        est.update((0.0, 0.0, rate), LEVEL, body_field(first, yaw), DT)
    assert s[S_REJECTED] == pytest.approx(30 * DT, abs=1e-9)
    for k in range(1, 11):
        yaw += rate * DT
        est.update((0.0, 0.0, rate), LEVEL, body_field(strong, yaw), DT)
        assert s[S_REJECTED] == pytest.approx((30 - 2 * k) * DT, abs=1e-9)


@pytest.mark.parametrize('waited', [1, 40])
def test_fields_waited_for_are_applied_when_the_calibration_finds_the_sensor_calibrated(waited):
    # 9D with the calibration, learning every 5 s (its steps stay out of the
    # way). Still, the first fields set the heading; turning, the body has
    # moved and the calibration is not ready: the fields wait. They point
    # 0.4 rad east of the heading: the heading does not follow them, but
    # the turn it would have had is kept (a running mean over all the
    # fields used, then k_mag). The calibration then says ready and not
    # applied (as it does when it finds the sensor calibrated: here set in
    # its flat state, a converged calibration takes minutes): at the next
    # field the heading turns by the kept turn and corrects the rest of
    # the field's heading with the gain of all the fields used.
    params = AhrsParams(mag_cal_rate=0.2)
    est = AhrsObserver(params, use_mag=True)
    s = est.flat_state
    k_mag = 1.0 - math.exp(-DT / params.tau_mag)
    for _ in range(20):
        est.update(STILL, LEVEL, body_field(world_field(NORM, DIP), 0.0), DT)
    assert abs(yaw_of(est.q)) < 1e-12
    rate, yaw = 0.5, 0.0
    while s[S_CAL_MOVED] == 0.0:
        yaw += rate * DT
        est.update((0.0, 0.0, rate), LEVEL, None, DT)
        assert yaw < 1.0
    assert s[MC0 + MC_READY] == 0.0 and s[S_WAIT_N] == 0.0
    used = s[S_MAG_USED]
    assert used == 20.0
    turned = world_field(NORM, DIP, 0.4)
    turn = 0.0
    for k in range(waited):
        yaw += rate * DT
        q = est.update((0.0, 0.0, rate), LEVEL, body_field(turned, yaw), DT)
        assert yaw_of(q) == pytest.approx(wrap(yaw), abs=1e-9)    # not corrected
        kap = max(k_mag, 1.0 / (used + k + 1.0))
        turn += kap * (0.4 - turn)
        assert s[S_WAIT_N] == k + 1.0
        assert s[S_WAIT_TURN] == pytest.approx(turn, abs=1e-12)
    assert s[S_MAG_USED] == used
    s[MC0 + MC_READY] = 1.0
    yaw += rate * DT
    since = s[S_CAL_SINCE] + DT
    q = est.update((0.0, 0.0, rate), LEVEL, body_field(turned, yaw), DT)
    total = used + waited + 1.0
    assert s[S_MAG_USED] == total and s[S_WAIT_N] == 0.0 and s[S_WAIT_TURN] == 0.0
    kap = max(k_mag, 1.0 / total, 1.0 - math.exp(-DT / max(1.0, 0.5 * since)))
    rest = 0.4 - turn
    correction = 2.0 * math.atan2(kap * math.sin(0.5 * rest),
                                  1.0 - kap + kap * math.cos(0.5 * rest))
    assert yaw_of(q) == pytest.approx(wrap(yaw + turn + correction), abs=1e-9)


def test_each_calibration_step_hands_the_calibration_its_turn_time_rate_vertical_and_verdict():
    # 9D, a calibration loaded (so it is ready and its fields are checked
    # against the references), learning at 20 Hz (every 5th field). The
    # body turns about a tilted axis at a changing rate, tilted; every
    # third field of a calibration step is 40 % too strong. At each field
    # the kernel's calibration block is compared with one stepped here by
    # the calibration's own mc_learn, given what the kernel must hand it:
    # the gyro's rotation since the last step, the time since it, the
    # latest rate, the vertical R(q)ᵀ e_z, and whether the calibrated field
    # passes the references' norm and dip test. Between steps, nothing.
    params = AhrsParams(mag_cal_rate=20.0)
    est = AhrsObserver(params, use_mag=True)
    offset, soft = np.array([2e-5, -1e-5, 0.5e-5]), np.diag([1.1, 0.95, 1.0])
    est.load_calibration(tuple(offset), soft)
    s = est.flat_state
    field = world_field(NORM, DIP, 0.3)
    period = 1.0 / params.mag_cal_rate
    steps = refused = 0
    # Turned 2 rad about the vertical and rolled 0.4 rad: no component of
    # the attitude small, so a component read from the wrong slot shows.
    truth = np.array([math.cos(1.0) * math.cos(0.2), math.cos(1.0) * math.sin(0.2),
                      -math.sin(1.0) * math.sin(0.2), math.sin(1.0) * math.cos(0.2)])
    for k in range(240):
        rate = np.array([0.6 * math.sin(0.05 * k), 0.4 + 0.002 * k, -0.3])
        t = np.linalg.norm(rate) * DT
        w, v = truth[0], truth[1:]
        e = np.concatenate(([math.cos(0.5 * t)], math.sin(0.5 * t) / t * rate * DT))
        truth = np.concatenate(([w * e[0] - v @ e[1:]], w * e[1:] + e[0] * v + np.cross(v, e[1:])))
        est.update(tuple(rate), tuple(9.81 * up_of(truth)), None, DT)
        body = np.array(rotate(truth[0], -truth[1], -truth[2], -truth[3], *field))
        strong = steps % 3 == 2
        raw = soft @ (body * (1.4 if strong else 1.0)) + offset
        wait = s[S_CAL_WAIT] + DT
        if wait >= period:
            # The kernel's attitude need not be unit (the extension term
            # pulls it back): the vertical is that of its rotation.
            for i in range(4):
                s[S_Q + i] *= 1.03
        before = np.array(s, dtype=float)
        ahrs_update_mag(s, *raw, DT)
        if wait < period:
            assert s[S_CAL_WAIT] == pytest.approx(wait, abs=1e-15)
            assert np.array_equal(s[MC0:MC0 + MAGCAL.size], before[MC0:MC0 + MAGCAL.size])
            continue
        shadow = before.copy()
        c = np.array(magcal_kernel.mc_apply(shadow, MC0, *raw))
        w = rotate(*before[S_Q:S_Q + 4], *c)
        h = math.hypot(w[0], w[1])
        norm, dip = math.hypot(h, w[2]), math.atan2(w[2], h)
        ref_n, ref_d = before[S_REF], before[S_REF + 1]
        # (the first field's step: no references yet, nothing to check)
        allow = before[S_HAS_REF] == 0.0 or (abs(norm - ref_n) <= params.mag_norm_th * ref_n
                                             and abs(dip - ref_d) <= params.mag_dip_th)
        assert allow != strong, (k, norm / ref_n, dip - ref_d)
        magcal_kernel.mc_learn(shadow, MC0, *raw, *before[S_CAL_TURN:S_CAL_TURN + 4], wait,
                               *before[S_CAL_RATE:S_CAL_RATE + 3], 1.0,
                               *up_of(before[S_Q:S_Q + 4]), 1.0 if allow else 0.0)
        a, b = s[MC0:MC0 + MAGCAL.size], shadow[MC0:MC0 + MAGCAL.size]
        bad = ~np.isclose(a, b, rtol=1e-9, atol=0.0)
        assert not bad.any(), (k, np.flatnonzero(bad), a[bad], b[bad])
        assert list(s[S_CAL_TURN:S_CAL_TURN + 4]) == [1.0, 0.0, 0.0, 0.0]
        assert s[S_CAL_WAIT] == 0.0
        steps += 1
        refused += strong
    assert steps in (47, 48) and refused == steps // 3
    assert s[MC0 + MC_REFUSED] == refused and s[MC0 + MC_USED] >= 30.0


def test_a_calibration_applied_while_running_restarts_the_references_from_its_field():
    # Level and still, a raw field with an offset: the references are the
    # raw field's norm and dip. A calibration loaded while running is
    # applied at the next field (a calibration step): the references and
    # the candidate are then the calibrated field's, the candidate's time
    # 0, the refinement's time restarts (one field's dt after that field)
    # and the heading's running mean is over (no mean: the refinement).
    est = AhrsObserver(AhrsParams(), use_mag=True)
    s = est.flat_state
    field = world_field(NORM, DIP, 0.5)
    offset = np.array([2e-5, -1.5e-5, 1e-5])
    raw = tuple(np.asarray(body_field(field, 0.0)) + offset)
    for _ in range(50):
        est.update(STILL, LEVEL, raw, DT)
    n_raw = float(np.linalg.norm(raw))
    assert s[S_REF] == pytest.approx(n_raw, rel=1e-9)
    est.load_calibration(tuple(offset), np.eye(3))
    est.update(STILL, LEVEL, raw, DT)
    assert list(s[S_REF:S_REF + 2]) == pytest.approx([NORM, DIP], rel=1e-9)
    assert list(s[S_CAND:S_CAND + 2]) == pytest.approx([NORM, DIP], rel=1e-9)
    assert s[S_CAND_TIME] == 0.0
    assert s[S_CAL_SINCE] == DT and s[S_MAG_USED] == math.inf


def test_a_heading_turn_turns_the_estimate_and_its_low_passed_vertical_alike():
    # _turn_heading(r): q <- r ⊗ q for r = (rw, 0, 0, rz) of any norm, and
    # the acceleration's low-pass states (world frame, two of three
    # components each) turned by r's angle about the vertical, not scaled.
    est = AhrsObserver(AhrsParams(), use_mag=False)
    est.update(STILL, (1.2, -0.8, 9.7), None, DT)
    s = est.flat_state
    states = np.array([0.3, -0.2, 9.7, 0.1, 0.05, -0.4])
    s[S_LP:S_LP + 6] = states
    q0 = np.array(s[S_Q:S_Q + 4], dtype=float)
    a = 0.7
    rw, rz = 0.9 * math.cos(0.5 * a), 0.9 * math.sin(0.5 * a)
    _turn_heading(s, rw, rz)
    w, x, y, z = q0
    assert list(s[S_Q:S_Q + 4]) == pytest.approx(
        [rw * w - rz * z, rw * x - rz * y, rw * y + rz * x, rw * z + rz * w], abs=1e-15)
    turn = np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])
    expected = np.concatenate([turn @ states[0:2], states[2:3], turn @ states[3:5],
                               states[5:6]])
    assert np.allclose(s[S_LP:S_LP + 6], expected, rtol=0.0, atol=1e-14)


def test_in_motion_the_steady_heading_correction_teaches_the_bias_through_the_low_passed_vertical():
    # 9D without the calibration, tilted and turning (never at rest), a
    # gyro bias: the heading is corrected by each field. R(q)'s z row is
    # low-passed with k_mag at each field; once the heading's gain is the
    # steady k_mag (after 1/k_mag fields) and the start is over, each
    # correction is one measurement of the bias along that row: the rate
    # -2 rz / (rw dt) of the correction r = (rw, rz), of noise density
    # bias_r tau_mag / tau_acc (the bias filter's own update, tested in
    # test_bias_kernel.py). Before that (1/k_mag fields: 2 s; the start:
    # 2 tau_acc, 3 s, the later here), the field's step leaves the bias and
    # its covariance alone.
    params = AhrsParams(mag_cal=False, tau_mag=2.0, tau_acc=1.5)
    est = AhrsObserver(params, use_mag=True)
    s = est.flat_state
    k_mag = 1.0 - math.exp(-DT / params.tau_mag)
    field = world_field(NORM, DIP, 0.3)
    truth = np.array([math.cos(0.3), math.sin(0.3) * 0.6, math.sin(0.3) * 0.8, 0.0])
    bias = np.array([0.01, -0.02, 0.015])
    z_row = None
    learned = quiet = 0
    for k in range(600):
        rate = np.array([0.3 * math.sin(0.03 * k), 0.2 * math.cos(0.05 * k), 0.5])
        t = np.linalg.norm(rate) * DT
        e = np.concatenate(([math.cos(0.5 * t)], math.sin(0.5 * t) / t * rate * DT))
        w, v = truth[0], truth[1:]
        truth = np.concatenate(([w * e[0] - v @ e[1:]], w * e[1:] + e[0] * v + np.cross(v, e[1:])))
        est.update(tuple(rate + bias), tuple(9.81 * up_of(truth)), None, DT)
        if k == 0:   # the start: the low-passed row starts at R(q)'s
            assert np.allclose(s[S_RZLP:S_RZLP + 3], up_of(est.q), rtol=0.0, atol=1e-14)
        body = rotate(truth[0], -truth[1], -truth[2], -truth[3], *field)
        before = np.array(s, dtype=float)
        ahrs_update_mag(s, *body, DT)
        q = np.array(s[S_Q:S_Q + 4], dtype=float)
        row = up_of(q)      # R(q)'s z row is R(q)ᵀ e_z
        z_row = before[S_RZLP:S_RZLP + 3] + k_mag * (row - before[S_RZLP:S_RZLP + 3])
        assert np.allclose(s[S_RZLP:S_RZLP + 3], z_row, rtol=0.0, atol=1e-12), k
        used = before[S_MAG_USED] + 1.0
        kap = max(k_mag, 1.0 / used)
        steady = (kap == k_mag and used * k_mag > 1.0 and before[S_REST] == 0.0
                  and before[S_START] >= 2.0 * params.tau_acc)
        shadow = before.copy()
        if steady:
            h = rotate(*before[S_Q:S_Q + 4], *body)
            psi = math.atan2(h[0], h[1])
            rw, rz = 1.0 - kap + kap * math.cos(0.5 * psi), kap * math.sin(0.5 * psi)
            bias_measure(shadow, *z_row, -2.0 * rz / (rw * DT),
                         before[C_BIAS_R] * params.tau_mag / (params.tau_acc * DT))
            learned += 1
        else:
            quiet += 1
        assert np.allclose(s[S_BIAS:S_BIAS + 3], shadow[S_BIAS:S_BIAS + 3], rtol=1e-9,
                           atol=1e-15), k
        assert np.allclose(s[S_BIAS_P:S_BIAS_P + 6], shadow[S_BIAS_P:S_BIAS_P + 6], rtol=1e-9,
                           atol=0.0), k
    assert learned > 250 and quiet > 250


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
