"""
Holes in the stream: an IMU interval much longer than the usual one, bridged.

A driver that falls behind, a queue that overflows, a USB burst lost: the
sample after a hole closes an interval of many usual ones. The estimator
then integrates the rotation across the hole from the gyro samples on both
sides (as the usual steps would have, had the rate changed linearly
across the hole), keeps the coefficients of the usual interval (a one-off long
``dt`` would upset the Butterworth low-pass, whose states belong to its
coefficients; the hole's sample stands for the steps it closes in the
inclination instead, ``S_STEPS``), says how unsure the bridge is
(:func:`hole_variance`, which the covariance adds), corrects the bridge on
the next sample from the rate's slopes beside a short hole
(:func:`hole_end_fix`), and where the hole's variance is large starts the
inclination's mean again, from the running mean of the next specific forces
with the old one weighed (:func:`restart_weighted`; a clipped stretch's
error weighs it alike, :func:`clip_after`).
The heading keeps its mean of the fields, gyro-held across the hole (the
first fields after it would bring the inclination's error there, times
``tan(dip)``). The magnetometer calibration learns nothing across a hole it
cannot trust.
docs/raw_imu.md ("Holes in the stream") has the figures that chose the
constants. Plain Python that numba compiles, as
:mod:`~ext_observer.core.ahrs.ahrs_kernel`.
"""

import math

from .ahrs_layout import (C_DT, MC0, P_HAS_CAL, P_TAU_ACC, S_ACC_DEV, S_CAL_TURN, S_CLIP_LEFT, S_CAL_WAIT,
                          S_GYR_LAST, S_GYR_PREV, S_HOLE_END, S_HOLE_RUN, S_HOLE_T0, S_HOLE_VAR,
                          S_HOLES, S_INC_SIGMA, S_INIT, S_STEPS, S_LP,
                          S_Q, S_START, S_START_N, S_WAIT_N, S_WAIT_TURN)
from .magcal_kernel import mc_restart

# An interval longer than this many times the usual one is a hole (one
# sample lost makes it twice the usual).
HOLE_FACTOR = 1.5
# s: holes in a row for longer than this are not holes: the rate itself has
# changed, and the interval becomes the usual one (with 40 % of the samples
# lost at random, holes follow each other for a few tens of ms).
HOLE_RUN_TIME = 0.5
# The bridge's error across a hole of T seconds, per axis: this share of the
# rate's change across it times T, and a rate random walk of this intensity
# (rad²/s³, its Brownian bridge: q T³ / 12) for the holes whose rates on both
# sides happen to agree. Fitted on the even-numbered BROAD trials
# (docs/raw_imu.md#holes-in-the-stream).
HOLE_RATE_CHANGE = 0.26
HOLE_RATE_WALK = 1.0
# The walk's Brownian bridge: the integral over T of a rate pinned at both ends
# has the variance q T³ / HOLE_BRIDGE_DIVISOR (a property of the bridge, not a tuning).
HOLE_BRIDGE_DIVISOR = 12.0
# The cubic Hermite bridge's rotation beyond the chord's: T² (m₀ − m₁) / HOLE_HERMITE_DIVISOR.
HOLE_HERMITE_DIVISOR = 12.0
# rad²: above this hole variance the magnetometer calibration follows the
# field afresh (learns nothing across the hole).
HOLE_CALIBRATION = math.radians(0.5) ** 2
# s: how long a moving body's translational acceleration keeps its direction
# after a hole (shorter than a start's START_CORRELATION: on the even trials
# 0.3 s recovers the inclination of 200 ms holes faster than 1 s, 6.0° against
# 7.8° on the fast rotation), and over how long the estimator follows its
# size (acc_deviation).
HOLE_CORRELATION = 0.3
HOLE_DEVIATION_TIME = 1.0
# s: the longest hole whose bridge takes the end correction (hole_end_fix):
# on the even trials it cuts the error of 50 ms bursts and adds to 200 ms ones.
HOLE_END_TIME = 0.1
# The share of the linear bridge's error σ left after the end correction.
HOLE_END_SHARE = 0.5
# The share of the range's rotation per sample that a clipped axis is taken to
# miss, summed along a clipped stretch (the rate stays beyond the range): the
# clip's error σ that weighs the inclination's mean against new samples.
# Chosen on the even-numbered BROAD trials, gyro clipped at ±250 °/s
# (docs/raw_imu.md#wherever-the-robot-starts): 1 (the whole range) restarts the mean
# in fast translation too, where one sample's vertical is worse than the gyro's.
CLIP_SHARE = 0.2
# While the inclination's error σ from holes and clipped samples is above
# this share of acc_reject, the gyro has not carried the vertical: no
# acceleration rejection (the low-pass's force is the way back).
RECOVERING = 1.0 / 3.0
# Standard gravity, m/s².
GRAVITY = 9.80665


def restart_mean(s):
    """Start from a running mean of the vertical, as at a start (nothing of the old weighed)."""
    s[S_START] = 0.0
    s[S_START_N] = 0.0
    s[S_LP + 3] = 0.0
    s[S_LP + 4] = 0.0
    s[S_LP + 5] = 0.0


def forget_wait(s):
    """Forget the turn the fields of a wait for the calibration would have given the heading."""
    s[S_WAIT_TURN] = 0.0
    s[S_WAIT_N] = 0.0


def calibration_restart(s):
    """The magnetometer calibration follows the field afresh: it learns nothing across a gap."""
    if s[P_HAS_CAL] != 0.0:
        mc_restart(s, MC0)
        s[S_CAL_TURN] = 1.0
        for i in range(1, 4):
            s[S_CAL_TURN + i] = 0.0
        s[S_CAL_WAIT] = math.inf


def hole_starts(s, dt):
    """
    Whether the interval ``dt`` (s; not the coefficients' own) is a hole to bridge.

    A hole: more than :data:`HOLE_FACTOR` times the usual interval (the
    coefficients' ``C_DT``), an estimate to bridge, and holes in a row for
    less than :data:`HOLE_RUN_TIME` before. Otherwise the step is a usual
    one (:func:`hole_ends`) and the caller takes ``dt`` as the new interval.
    """
    if s[S_INIT] != 0.0 and dt > HOLE_FACTOR * s[C_DT] and s[S_HOLE_RUN] < HOLE_RUN_TIME:
        s[S_HOLE_RUN] += dt
        s[S_STEPS] = dt / s[C_DT]
        return True
    hole_ends(s)
    return False


def hole_ends(s):
    """A usual step: no hole in a row, nothing to add to the covariance."""
    s[S_HOLE_RUN] = 0.0
    s[S_HOLE_VAR] = 0.0
    s[S_STEPS] = 1.0


def hole_rate(s, gx, gy, gz, dt):
    """
    The rate to integrate across a hole of ``dt`` s (rad/s), from the samples on both sides.

    The step the usual ones would have made, had the samples lost lain on
    the straight line between the two: each usual step integrates its
    closing sample's rate, so ``L = dt / C_DT`` steps weigh the new sample
    ``(L + 1) / (2L)`` and the one before the hole the rest (one step: the
    usual step; a long hole: the trapezoid).
    """
    w = 0.5 + 0.5 * s[C_DT] / dt
    lx, ly, lz = s[S_GYR_LAST], s[S_GYR_LAST + 1], s[S_GYR_LAST + 2]
    return lx + w * (gx - lx), ly + w * (gy - ly), lz + w * (gz - lz)


def hole_variance(dx, dy, dz, dt):
    """The trapezoid's error variance per axis (rad²) over ``dt`` s, the rate changing by ``d``."""
    return (HOLE_RATE_CHANGE * HOLE_RATE_CHANGE * (dx * dx + dy * dy + dz * dz) * dt * dt
            + HOLE_RATE_WALK * dt * dt * dt / HOLE_BRIDGE_DIVISOR)


def acc_deviation(s, vx, vy, vz, dt):
    """
    Follow how far the world-frame specific force ``v`` (m/s²) strays from gravity.

    ``max(d_z², (d_x² + d_y²) / 2) / g²`` of its deviation ``d`` from
    ``(0, 0, g)``, averaged over about :data:`HOLE_DEVIATION_TIME`: one
    sample's variance per horizontal axis of the vertical it shows (a
    moving body's translational acceleration), which a hole's own is
    weighed against.
    """
    dz = vz - GRAVITY
    e = max(dz * dz, 0.5 * (vx * vx + vy * vy)) / (GRAVITY * GRAVITY)
    k = min(dt / HOLE_DEVIATION_TIME, 1.0)
    s[S_ACC_DEV] += k * (e - s[S_ACC_DEV])


def hole_after(s, var):
    """
    What a bridged hole of variance ``var`` (rad² per axis) leaves: counted, the means restarted.

    The inclination: the low-pass's mean of the specific force before the
    hole is off by the hole's error; the mean of ``t`` seconds of new
    samples by ``m c / (c + t)`` (``m`` one sample's variance,
    :func:`acc_deviation`; ``c`` :data:`HOLE_CORRELATION`). Where the old
    mean is worth less than ``tau_acc`` seconds of new ones,
    ``t0 = c (m / var − 1)``, the mean starts again with it weighed as
    ``t0`` seconds (as at a start, which has none). The heading keeps its
    mean of the fields, gyro-held across the hole: the first fields after it
    would bring the inclination's error there times ``tan(dip)``.
    """
    if s[S_HOLE_END] != 0.0:
        var *= HOLE_END_SHARE * HOLE_END_SHARE
    s[S_HOLE_VAR] = var
    s[S_HOLES] += 1.0
    if var > HOLE_CALIBRATION:
        calibration_restart(s)
    s[S_INC_SIGMA] = math.sqrt(s[S_INC_SIGMA] * s[S_INC_SIGMA] + var)
    s[S_HOLE_T0] = restart_weighted(s, var)


def restart_weighted(s, var):
    """
    Restart the inclination's mean where an error of ``var`` (rad²) makes it worth little.

    The mean of ``t`` seconds of new samples is off by ``m c / (c + t)``
    (:func:`hole_after`); where the old mean is worth less than ``tau_acc``
    seconds of them, ``t0 = c (m / var − 1)``, and less than the running
    mean's own weight, the mean starts again with the old weighed as ``t0``
    seconds. Returns ``t0``, or −1.0 where the mean is kept.
    """
    t0 = HOLE_CORRELATION * (s[S_ACC_DEV] / var - 1.0)
    if t0 >= s[P_TAU_ACC]:
        return -1.0
    t0 = max(t0, 0.0)
    if s[S_START] < s[P_TAU_ACC] and t0 >= s[S_START]:
        return -1.0
    s[S_START] = t0
    s[S_START_N] = t0 / s[C_DT]
    s[S_LP + 3] = 0.0
    s[S_LP + 4] = 0.0
    s[S_LP + 5] = 0.0
    return t0


def clip_after(s, var):
    """
    Each gyro step: a clipped sample's variance ``var`` (rad², 0: not clipped) reaches the mean.

    The rate beyond the range stays beyond it along a clipped stretch: the
    errors add up, :data:`CLIP_SHARE` of the range's σ per sample, into the
    inclination's σ (``S_INC_SIGMA``), which weighs the mean against new
    samples as a hole's does (:func:`restart_weighted`). Without a clip, that
    σ is forgotten at the low-pass's pace; the recovery (the health state)
    lasts ``tau_acc`` after the last clipped sample.
    """
    if var == 0.0:
        # (Most samples: nothing to forget, and the division skipped.)
        if s[S_INC_SIGMA] != 0.0:
            s[S_INC_SIGMA] *= 1.0 - s[C_DT] / s[P_TAU_ACC]
        if s[S_CLIP_LEFT] != 0.0:
            s[S_CLIP_LEFT] = max(s[S_CLIP_LEFT] - s[C_DT], 0.0)
        return
    s[S_CLIP_LEFT] = s[P_TAU_ACC]
    sigma = s[S_INC_SIGMA] + CLIP_SHARE * math.sqrt(var)
    s[S_INC_SIGMA] = sigma
    restart_weighted(s, sigma * sigma)


def hole_slope(s, dt):
    """
    Before the bridge of a hole of ``dt`` s: keep what its end correction needs.

    The rate's change into the hole (the last two samples before it), when
    the step before was a usual one; the correction
    (:func:`hole_end_fix`) waits for the rate's slope after it.
    """
    f = 0.0
    if s[S_HOLE_RUN] == dt and dt <= HOLE_END_TIME:
        f = dt * dt / (HOLE_HERMITE_DIVISOR * s[C_DT])
        for i in range(3):
            s[S_HOLE_END + 1 + i] = s[S_GYR_LAST + i] - s[S_GYR_PREV + i]
    s[S_HOLE_END] = f


def hole_end_fix(s, gx, gy, gz):
    """
    The first usual sample after a hole: the bridge's end correction, a body-frame turn.

    The straight line between the samples on both sides misses
    ``T² (m₀ − m₁) / 12`` of the rotation of a rate whose slopes at the two
    ends are ``m₀`` and ``m₁`` (the cubic through both samples with those
    slopes, a Hermite interpolation); the slopes are the differences of the
    samples next to the hole, known once the one after it is here.
    """
    f = s[S_HOLE_END]
    s[S_HOLE_END] = 0.0
    cx = f * (s[S_HOLE_END + 1] - (gx - s[S_GYR_LAST]))
    cy = f * (s[S_HOLE_END + 2] - (gy - s[S_GYR_LAST + 1]))
    cz = f * (s[S_HOLE_END + 3] - (gz - s[S_GYR_LAST + 2]))
    n = math.sqrt(cx * cx + cy * cy + cz * cz)
    if n == 0.0:
        return
    c = math.cos(0.5 * n)
    k = math.sin(0.5 * n) / n
    bx, by, bz = k * cx, k * cy, k * cz
    w, x, y, z = s[S_Q], s[S_Q + 1], s[S_Q + 2], s[S_Q + 3]
    s[S_Q] = w * c - x * bx - y * by - z * bz
    s[S_Q + 1] = w * bx + x * c + y * bz - z * by
    s[S_Q + 2] = w * by - x * bz + y * c + z * bx
    s[S_Q + 3] = w * bz + x * by - y * bx + z * c
