"""
Holes in the stream (``hole_kernel``): known answers of its steps, and a burst-hole run.

An interval over ``HOLE_FACTOR`` times the usual one is a hole: bridged
with the rate the usual steps would have integrated had the lost samples
lain on the line between the two on both sides, with the usual interval's
coefficients kept (the low-pass's states belong to them), its variance
added to the covariance, and the means restarted where it is large. Plain
kernels: fast; the compiled ones are held equal in test_compiled.py.
"""

import copy
import math

import numpy as np
import pytest

from general_steps import general_step
from ext_observer.core.ahrs import hole_kernel
from ext_observer.core.ahrs.ahrs_filters import rotate, steady
from ext_observer.core.ahrs.ahrs_observer import AhrsObserver, AhrsParams
from ext_observer.core.ahrs.ahrs_state import STATE
from ext_observer.core.ahrs.hole_kernel import (HOLE_CALIBRATION, HOLE_CORRELATION, HOLE_FACTOR,
                                                HOLE_RATE_CHANGE, HOLE_RATE_WALK,
                                                HOLE_END_SHARE, HOLE_END_TIME, HOLE_RUN_TIME,
                                                CLIP_SHARE, RECOVERING, clip_after, hole_after,
                                                hole_end_fix, hole_rate, hole_slope, hole_starts,
                                                hole_variance)
from ext_observer.core.ahrs.gravity_kernel import ahrs_update_acc
from ext_observer.core.constants import STANDARD_GRAVITY
from ext_observer.recordings.recording import attitude_from_imu

DT = 0.01
UP = (0.0, 0.0, 9.81)
STILL = (0.0, 0.0, 0.0)


def _started(params=None, use_mag=False):
    est = AhrsObserver(params or AhrsParams(tau_bias=0.0), use_mag=use_mag, compiled=False)
    est.update(STILL, UP, None, DT)
    est.update(STILL, UP, None, DT)
    return est


def test_a_hole_is_an_interval_over_the_factor_and_a_run_of_them_ends():
    s = STATE.plain()
    s.coef.dt = DT
    assert not hole_starts(s, 3.0 * DT)  # no estimate yet: nothing to bridge
    s.est.init = 1.0
    assert not hole_starts(s, HOLE_FACTOR * DT)
    s.hole.var = 1.0
    assert hole_starts(s, 1.0001 * HOLE_FACTOR * DT) and s.hole.run == 1.0001 * HOLE_FACTOR * DT
    assert s.hole.var == 1.0  # the bridge sets it
    assert not hole_starts(s, 1.2 * DT) and s.hole.run == 0.0 and s.hole.var == 0.0
    # Longer intervals in a row than HOLE_RUN_TIME: the rate has changed.
    count = 0
    while hole_starts(s, 2.0 * DT):
        count += 1
    assert round(HOLE_RUN_TIME / (2.0 * DT)) <= count <= round(HOLE_RUN_TIME / (2.0 * DT)) + 1
    assert s.hole.run == 0.0


@pytest.mark.parametrize('steps, weight',
                         [(1.0, 1.0), (2.0, 0.75), (4.0, 0.625), (1e6, 0.5000005)])
def test_the_bridges_rate_is_what_the_usual_steps_would_have_integrated(steps, weight):
    s = STATE.plain()
    s.coef.dt = DT
    s.gyro.last[:] = [1.0, -2.0, 0.5]
    new = np.array([3.0, 2.0, -1.5])
    rate = hole_rate(s, *new, steps * DT)
    np.testing.assert_allclose(rate, (1.0 - weight) * np.array([1.0, -2.0, 0.5]) + weight * new,
                               rtol=1e-12)
    # Steps 1..L of a rate linear from the old to the new sample, each the closing sample's.
    if steps < 10:
        line = [np.array([1.0, -2.0, 0.5]) + (new - [1.0, -2.0, 0.5]) * k / steps
                for k in range(1, int(steps) + 1)]
        np.testing.assert_allclose(np.array(rate) * steps, np.sum(line, axis=0), rtol=1e-12)


def test_the_bridges_variance_is_the_rate_change_and_the_walk():
    v = hole_variance(3.0, 0.0, -4.0, 0.2)
    assert v == pytest.approx((HOLE_RATE_CHANGE * 5.0 * 0.2) ** 2 + HOLE_RATE_WALK * 0.008 / 12)


@pytest.mark.parametrize('length', [0.05, HOLE_END_TIME, 0.2])
def test_the_end_correction_turns_by_the_slopes_at_both_ends(length):
    # About the vertical: T² (m₀ − m₁) / 12 with the slopes from the samples
    # beside the hole; a hole in a row, or longer than HOLE_END_TIME, none.
    s = STATE.plain()
    s.coef.dt, s.est.q[0], s.hole.run = DT, 1.0, length
    s.gyro.prev[2], s.gyro.last[2] = 1.0, 1.2  # m₀ = 20 rad/s²
    hole_slope(s, length)
    s.gyro.last[2] = 2.0  # the sample that closes the hole
    hole_end_fix(s, 0.0, 0.0, 1.7)  # m₁ = −30 rad/s²
    turn = 2.0 * math.atan2(s.est.q[3], s.est.q[0])
    want = length * length * 50.0 / 12.0 if length <= HOLE_END_TIME else 0.0
    assert turn == pytest.approx(want, rel=1e-12, abs=1e-15) and s.hole.end[0] == 0.0
    s.hole.run = 2.0 * length
    hole_slope(s, length)
    assert s.hole.end[0] == 0.0


def test_a_small_hole_keeps_the_means_a_large_one_restarts_the_inclinations_weighed():
    est = _started()
    s = est.state[0]
    s.inc.start, s.inc.start_n, s.field.mag_used = 10.0, 0.0, 50.0
    s.inc.acc_dev = 0.01  # a body that moves: its samples show the vertical to 0.1 rad
    small = 0.5 * HOLE_CALIBRATION
    hole_after(s, small)
    assert (s.inc.start, s.field.mag_used, s.hole.var, s.hole.count) == (10.0, 50.0, small, 1.0)
    # The old mean is worth t0 = c (m / var − 1) s of new samples.
    var = 0.005
    hole_after(s, var)
    t0 = HOLE_CORRELATION * (0.01 / var - 1.0)
    assert s.inc.start == pytest.approx(t0) and s.inc.start_n == pytest.approx(t0 / DT)
    assert s.field.mag_used == 50.0  # the heading keeps its mean, gyro-held
    # Worse than any sample: the mean starts from the next one (as a start).
    hole_after(s, 1.0)
    assert s.inc.start == 0.0 and s.inc.start_n == 0.0
    # A hole whose end correction waits: the share of the linear bridge's σ left.
    s.hole.end[0] = 1.0
    hole_after(s, 1.0)
    assert s.hole.var == HOLE_END_SHARE * HOLE_END_SHARE


def test_a_hole_keeps_the_usual_coefficients_and_integrates_its_whole_length():
    # About the vertical at a rate that changes linearly: the bridge is exact.
    est = _started()
    s = est.state[0]
    coefficients = list(s.coef.bw) + [s.coef.k_acc]
    rate = lambda t: 0.5 + 2.0 * t  # noqa: E731  rad/s about z
    t, heading = 0.0, 0.0
    for k in range(1, 60):
        dt = DT if k % 10 else 7 * DT  # a hole of six samples now and then
        t += dt
        steps = round(dt / DT)
        heading += sum(rate(t - (steps - 1 - j) * DT) for j in range(steps)) * DT
        est.update((0.0, 0.0, rate(t)), UP, None, dt)
        assert s.coef.dt == DT and list(s.coef.bw) + [s.coef.k_acc] == coefficients
    assert est.holes == 5
    w, z = s.est.q[0], s.est.q[3]
    assert 2.0 * math.atan2(z, w) == pytest.approx(heading, abs=1e-9)


def test_a_lasting_slower_rate_becomes_the_usual_one():
    est = _started()
    for _ in range(int(HOLE_RUN_TIME / (2 * DT)) + 2):
        est.update(STILL, UP, None, 2 * DT)
    assert est.state[0].coef.dt == 2 * DT and est.hole_variance == 0.0


def _turning(rate_hz, seconds, lost=None):
    """A body turning about a tilted axis at a rate that swings; 6D samples, their times."""
    t = np.arange(int(seconds * rate_hz)) / rate_hz
    axis = np.array([0.3, -0.2, 1.0]) / np.linalg.norm([0.3, -0.2, 1.0])
    speed = 1.5 * np.sin(2.0 * np.pi * 0.3 * t)
    gyr = speed[:, None] * axis
    # The specific force: gravity in the body frame, from the exact turn.
    angle = 1.5 * (1.0 - np.cos(2.0 * np.pi * 0.3 * t)) / (2.0 * np.pi * 0.3)
    c, s = np.cos(angle), np.sin(angle)
    up = np.array([0.0, 0.0, 9.81])
    # Rodrigues: R(−angle) up, the world's vertical seen from the body.
    acc = (up * c[:, None] - np.cross(axis, up)[None, :] * s[:, None]
           + np.outer(1.0 - c, axis * (axis @ up)))
    keep = np.ones(len(t), dtype=bool) if lost is None else lost(t)
    return gyr[keep], acc[keep], t[keep], angle[keep], axis


def _bursts_lost(first, every, length=0.2):
    """The samples kept (a mask of times): ``length`` s lost every ``every`` s from ``first`` s."""
    def kept(t):
        keep = np.mod(t - first, every) >= length
        keep[:2] = True  # the start is never lost
        return keep
    return kept


def test_a_run_with_bursts_lost_turns_as_the_body_does():
    # 200 ms lost every 2 s while the body turns up to 1.5 rad/s: the turn
    # about the axis follows the body's (the rotation in each hole bridged),
    # and the covariance grows with each hole. Dropping the holes (an
    # interval over max_dt, what the estimator did before it bridged them)
    # loses the turn in each.
    gyr, acc, times, angle, axis = _turning(200.0, 20.0, _bursts_lost(0.7, 2.0))
    bridged = attitude_from_imu(gyr, acc, times=times, parameters={'use_mag': False})
    dropped = attitude_from_imu(gyr, acc, times=times,
                                parameters={'use_mag': False, 'max_dt': 0.05})
    assert bridged.drops['dt_too_large'] == 0 and dropped.drops['dt_too_large'] == 10

    def turn_error(rec):
        q = rec.quaternions[1:]
        turn = 2.0 * np.arctan2(q[:, 1:] @ axis, q[:, 0])
        return np.degrees(np.max(np.abs(np.angle(np.exp(1j * (turn - angle[1:]))))))

    assert turn_error(bridged) < 1.0 and turn_error(dropped) > 10.0
    holes = np.flatnonzero(np.diff(times) > 0.1) + 1
    assert np.all(bridged.heading_std[holes] > bridged.heading_std[holes - 1])


def test_the_general_steps_follow_a_hole_as_the_one_call_sample_does():
    # The node's one call (sample_step) and the steps one at a time (the
    # start, or a sample that failed the guard) bridge, grow and restart alike.
    from ext_observer.pipeline.raw_imu import RawImuPipeline
    from ext_observer.recordings.recording import node_settings

    gyr, acc, times, _, _ = _turning(200.0, 4.0, _bursts_lost(0.3, 1.0))
    runs = []
    for general in (False, True):
        pipeline = RawImuPipeline(node_settings({'use_mag': False}), compiled=False)
        est = pipeline.estimator
        out = []
        for g, a, t in zip(gyr.tolist(), acc.tolist(), times):
            stamp = 1_000_000_000 + round(t * 1e9)
            if general:
                for step in pipeline.pairer.add_sample(stamp, g, a)[1]:
                    state, _ = general_step(est, g, a, (step.end - step.stamp) * 1e-9)
                    out.append(tuple(state) + tuple(est.uncertainty.covariance))
            else:
                estimate = pipeline.imu(stamp, g, a)[1]
                if estimate is not None:
                    out.append(tuple(estimate.state) + tuple(estimate.covariance))
        runs.append(np.array(out))
    assert est.core.holes >= 3
    assert dict(est.key_values())['holes_bridged'] == est.core.holes  # in /diagnostics
    np.testing.assert_allclose(runs[1], runs[0], rtol=1e-12, atol=1e-15)


def _tilt(s):
    """The angle (rad) between the estimate's vertical and the world's."""
    w, x, y, z = s.est.q[0], s.est.q[1], s.est.q[2], s.est.q[3]
    return math.acos(min(1.0, (w * w - x * x - y * y + z * z) / (w * w + x * x + y * y + z * z)))


def test_a_holes_sample_corrects_the_inclination_as_the_steps_it_missed():
    # A settled estimate tilted by 5°, its low-pass steady at the tilted force.
    est = _started(AhrsParams(tau_bias=0.0, acc_reject=0.0))
    for _ in range(500):
        est.update(STILL, UP, None, DT)
    s = est.state[0]
    half = 0.5 * math.radians(5.0)
    s.est.q[0], s.est.q[1], s.est.q[2], s.est.q[3] = math.cos(half), math.sin(half), 0.0, 0.0
    tilted = rotate(s.est.q[0], s.est.q[1], s.est.q[2], s.est.q[3], *UP)
    steady(s.coef.bw, s.inc.lp, 0, *tilted)
    one, hole, usual = copy.deepcopy(s), copy.deepcopy(s), copy.deepcopy(s)
    ahrs_update_acc(one, *UP)
    hole.hole.steps = 3.0
    ahrs_update_acc(hole, *UP)
    for _ in range(3):
        ahrs_update_acc(usual, *UP)
    tilt0 = math.radians(5.0)
    assert _tilt(hole) == pytest.approx(_tilt(usual), rel=0.05)
    assert _tilt(hole) < (1.0 - s.coef.k_acc) ** 2 * tilt0 < _tilt(one)


def test_a_clipped_stretch_sums_its_error_and_weighs_the_inclinations_mean():
    est = _started()
    s = est.state[0]
    s.inc.start, s.inc.start_n = 10.0, 0.0
    s.inc.acc_dev = 0.01  # the samples show the vertical to 0.1 rad
    var = 1e-4  # each clipped sample: (range dt)², a σ of 0.01 rad
    clip_after(s, var)
    # One sample's share of the range's σ weighs little against the mean: kept.
    assert s.inc.sigma == pytest.approx(CLIP_SHARE * 0.01) and s.inc.start == 10.0
    assert s.gyro.clip_left == s.par.tau_acc
    # Along the stretch the σ adds up (the rate stays beyond the range) until
    # the old mean is worth less than tau_acc of new samples: restarted, weighed.
    count = 1
    while s.inc.start == 10.0:
        clip_after(s, var)
        count += 1
    sigma = count * CLIP_SHARE * 0.01
    assert s.inc.sigma == pytest.approx(sigma)
    t0 = HOLE_CORRELATION * (0.01 / sigma ** 2 - 1.0)
    assert 0.0 < t0 < s.par.tau_acc and s.inc.start == pytest.approx(t0)
    # After it, the σ is forgotten at the low-pass's pace; the recovery lasts tau_acc.
    clip_after(s, 0.0)
    assert s.inc.sigma == pytest.approx(sigma * (1.0 - DT / s.par.tau_acc))
    assert s.gyro.clip_left == pytest.approx(s.par.tau_acc - DT)


def test_within_a_running_mean_a_clipped_samples_sigma_is_at_most_the_means():
    # 1 s into a running mean of samples that show the vertical to 0.2 rad,
    # the estimate follows the mean, off by √(m c / (c + t)), whatever the
    # losses before its start: a clipped sample adds its share to that σ,
    # and the mean is weighed as a little under its second, not restarted
    # from nothing.
    est = _started()
    s = est.state[0]
    s.inc.start, s.inc.start_n = 1.0, 1.0 / DT
    s.inc.acc_dev = 0.04
    s.inc.sigma = 2.0  # the losses of a long stretch before the mean's start
    var = 1e-4
    clip_after(s, var)
    sigma = math.sqrt(0.04 * HOLE_CORRELATION / (HOLE_CORRELATION + 1.0)) + CLIP_SHARE * 0.01
    assert s.inc.sigma == pytest.approx(sigma)
    t0 = HOLE_CORRELATION * (0.04 / sigma ** 2 - 1.0)
    assert 0.9 < t0 < 1.0 and s.inc.start == pytest.approx(t0)


def test_no_acceleration_rejection_while_the_vertical_is_unsure():
    def rejected(sigma):
        est = _started()
        for _ in range(500):
            est.update(STILL, UP, None, DT)
        s = est.state[0]
        # The low-passed force 10° off the vertical the gyro carried.
        tilted = (0.0, 9.81 * math.sin(0.17), 9.81 * math.cos(0.17))
        steady(s.coef.bw, s.inc.lp, 0, *tilted)
        s.inc.sigma = sigma
        ahrs_update_acc(s, *tilted)
        return s.rej.time > 0.0
    assert rejected(0.0)
    assert not rejected(RECOVERING * AhrsParams().acc_reject * 1.01)


def test_the_end_correction_is_a_body_frame_turn_of_any_axis():
    # q <- q ⊗ exp(c / 2), c = T² (m₀ − m₁) / 12 per axis, the attitude tilted
    # and turned (every term of the product matters).
    s = STATE.plain()
    length = HOLE_END_TIME
    s.coef.dt, s.hole.run = DT, length
    q = np.array([0.8, 0.3, -0.4, 0.2])
    q /= np.linalg.norm(q)
    s.est.q[:] = list(q)
    before, last, after = [0.1, -0.3, 0.2], [0.5, -0.1, -0.4], [0.2, 0.6, -0.3]
    s.gyro.prev[:] = before
    s.gyro.last[:] = last
    hole_slope(s, length)
    s.gyro.last[:] = [1.0, 0.4, 0.7]  # the sample that closes the hole
    hole_end_fix(s, *after)
    f = length * length / (12.0 * DT)
    c = np.array([f * ((b - a) - (g - h)) for a, b, h, g in zip(
        before, last, [1.0, 0.4, 0.7], after)])
    n = np.linalg.norm(c)
    e = np.concatenate([[math.cos(0.5 * n)], math.sin(0.5 * n) * c / n])
    w, x, y, z = q
    want = [w * e[0] - x * e[1] - y * e[2] - z * e[3], w * e[1] + x * e[0] + y * e[3] - z * e[2],
            w * e[2] - x * e[3] + y * e[0] + z * e[1], w * e[3] + x * e[2] - y * e[1] + z * e[0]]
    assert n > 0.01
    assert s.est.q == pytest.approx(want, abs=1e-15)


def test_the_deviation_from_gravity_is_a_low_pass_of_the_larger_share():
    # d <- d + k (e - d), k = dt / HOLE_DEVIATION_TIME, e the larger of the
    # vertical deviation² and half the horizontal², over g².
    s = STATE.plain()
    g = STANDARD_GRAVITY
    s.inc.acc_dev = 0.02
    hole_kernel.acc_deviation(s, 0.3, -0.4, g + 0.1, 0.25)
    k = 0.25 / hole_kernel.HOLE_DEVIATION_TIME
    assert s.inc.acc_dev == pytest.approx(0.02 + k * (0.5 * 0.25 / (g * g) - 0.02), rel=1e-12)
    hole_kernel.acc_deviation(s, 0.0, 0.1, g - 2.0, 0.25)
    d = 0.02 + k * (0.5 * 0.25 / (g * g) - 0.02)
    assert s.inc.acc_dev == pytest.approx(d + k * (4.0 / (g * g) - d), rel=1e-12)


def test_a_hole_with_its_end_correction_counts_the_share_it_leaves():
    s = STATE.plain()
    s.coef.dt, s.par.tau_acc, s.inc.acc_dev = DT, 3.0, 1e-3
    s.hole.end[0] = 0.01
    hole_after(s, 4e-6)
    assert s.hole.var == pytest.approx(4e-6 * HOLE_END_SHARE * HOLE_END_SHARE, rel=1e-12)
    s.hole.end[0] = 0.0
    hole_after(s, 4e-6)
    assert s.hole.var == 4e-6


def test_the_recovery_from_a_clip_lasts_tau_acc_after_the_last_clipped_sample():
    s = STATE.plain()
    s.coef.dt, s.par.tau_acc, s.inc.acc_dev = 0.25, 1.0, 1e-3
    clip_after(s, 1e-4)
    assert s.gyro.clip_left == 1.0
    left = []
    for _ in range(5):
        clip_after(s, 0.0)
        left.append(s.gyro.clip_left)
    assert left == [0.75, 0.5, 0.25, 0.0, 0.0]


def test_a_mean_worth_more_than_tau_acc_is_kept_and_reported_kept():
    # t0 = c (m / var − 1) ≥ tau_acc: nothing restarts, and −1.0 tells the
    # uncertainty's hole step that the mean was kept (t0 ≥ 0 restarts it).
    s = STATE.plain()
    s.coef.dt, s.par.tau_acc, s.inc.start, s.inc.start_n = DT, 3.0, 10.0, 1000.0
    var = 1e-6
    s.inc.acc_dev = var * (1.0 + 2.0 * 3.0 / HOLE_CORRELATION)
    assert hole_kernel.restart_weighted(s, var) == -1.0
    assert (s.inc.start, s.inc.start_n) == (10.0, 1000.0)


def test_a_holes_variance_is_the_rate_change_across_it_on_every_axis():
    # var from the change of the rate across the hole, (ω₁ − ω₀) per axis.
    est = _started(AhrsParams(tau_bias=0.0))
    before, rate = (0.01, -0.02, 0.03), (0.03, -0.05, 0.08)
    for _ in range(10):
        est.update(before, UP, None, DT)
    s = est.state[0]
    est.update(rate, UP, None, 0.04)
    assert est.holes == 1
    share = HOLE_END_SHARE * HOLE_END_SHARE if s.hole.end[0] != 0.0 else 1.0
    change = [b - a for a, b in zip(before, rate)]
    assert s.hole.var == pytest.approx(hole_variance(*change, 0.04) * share, rel=1e-12)
