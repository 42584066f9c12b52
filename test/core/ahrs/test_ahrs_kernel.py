"""
The estimator's gyro and accelerometer steps, its rest and its reset (no ROS): fast known answers.

Written for the survivors of mutmut's whole run of ``ahrs_kernel.py``
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

from ext_observer.core.ahrs.ahrs_filters import lowpass, rotate
from ext_observer.core.ahrs.ahrs_kernel import ahrs_update_acc, ahrs_update_gyr
from ext_observer.core.ahrs.ahrs_layout import (C_K_ACC, MC0, S_BIAS, S_BIAS_P, S_CAL_LOADED,
                                                S_CAL_MOVED, S_CAL_RATE, S_CAL_SINCE, S_CAL_TURN,
                                                S_CAL_WAIT, S_CAND_TIME, S_CLIPPED, S_CLIPS,
                                                S_HAS_REF, S_LP, S_MAG_DIST, S_MAG_USED, S_Q,
                                                S_REJECTED, S_REST, S_REST_GYR, S_REST_TIME,
                                                S_START, S_START_N, S_WAIT_N, S_WAIT_TURN)
from ext_observer.core.ahrs.estimator import AhrsObserver, AhrsParams
from ext_observer.core.ahrs.gyro_watch import _REST_BIAS_SIGMA, detect_rest

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
    # (test_kernel_edges.py has it on x); on y and on z alike.
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
