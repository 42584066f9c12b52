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

from .ahrs_filters import gravity_deviation, quat_multiply
from .magcal_kernel import mc_restart
from .record import Group

HOLE = Group('hole', 'Holes in the stream: intervals much longer than the usual one', [
    ('run', 's', 'of holes in a row (longer: the rate changed)'),
    ('var', 'rad²', "per axis, what the last step's hole adds (0: none)"),
    ('count', '', 'holes bridged'),
    ('t0', 's', "the inclination's restarted mean weighs the old as (−1: kept)"),
    ('end', '', 'the end correction a hole leaves for the next usual sample: T²/12 over '
     "the usual interval (0: none), and the rate's change into the hole (rad/s, 3)", 4),
    ('steps', '', "the usual steps this sample stands for (a hole's: more than 1)"),
])

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
# sides happen to agree. Fitted on the tuning trials (docs/raw_imu.md#holes-in-the-stream).
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
# after a hole (shorter than a start's START_CORRELATION: a hole's restarted
# mean must trust new samples sooner; docs/broad_tuning.md, "Holes and a
# clipped gyro"), and over how long the estimator follows its size
# (acc_deviation).
HOLE_CORRELATION = 0.3
HOLE_DEVIATION_TIME = 1.0
# s: the longest hole whose bridge takes the end correction (hole_end_fix):
# it helps short holes and hurts long ones (docs/broad_tuning.md).
HOLE_END_TIME = 0.1
# The share of the linear bridge's error σ left after the end correction.
HOLE_END_SHARE = 0.5
# The share of the range's rotation per sample that a clipped axis is taken to
# miss, summed along a clipped stretch (the rate stays beyond the range): the
# clip's error σ that weighs the inclination's mean against new samples.
# Below 1 (the whole range), which would restart the mean in fast translation
# too, where one sample's vertical is worse than the gyro's (docs/broad_tuning.md).
CLIP_SHARE = 0.2
# While the inclination's error σ from holes and clipped samples is above
# this share of acc_reject, the gyro has not carried the vertical: no
# acceleration rejection (the low-pass's force is the way back).
RECOVERING = 1.0 / 3.0


def restart_mean(s):
    """Start from a running mean of the vertical, as at a start (nothing of the old weighed)."""
    s.inc.start = 0.0
    s.inc.start_n = 0.0
    s.inc.lp[3] = 0.0
    s.inc.lp[4] = 0.0
    s.inc.lp[5] = 0.0


def hole_reset(s):
    """No hole open, none being bridged (the count stays)."""
    s.hole.t0 = 0.0
    hole_ends(s)


def forget_wait(s):
    """Forget the turn the fields of a wait for the calibration would have given the heading."""
    s.field.wait_turn = 0.0
    s.field.wait_n = 0.0


def calibration_restart(s, keep_refused=False):
    """
    The magnetometer calibration follows the field afresh: it learns nothing across a gap.

    ``keep_refused``: the fields it refused before count on (a clipped gyro:
    the fields went on and were judged; only the turn across the stretch is
    not known); otherwise a fresh count (a hole, a field that comes back).
    """
    if s.par.has_cal != 0.0:
        mc_restart(s.cal, s.cal.refused_share if keep_refused else 0.0)
        s.cal_feed.turn[0] = 1.0
        for i in range(1, 4):
            s.cal_feed.turn[i] = 0.0
        s.cal_feed.wait = math.inf


def hole_starts(s, dt):
    """
    Whether the interval ``dt`` (s; not the coefficients' own) is a hole to bridge.

    A hole: more than :data:`HOLE_FACTOR` times the usual interval (the
    coefficients' ``C_DT``), an estimate to bridge, and holes in a row for
    less than :data:`HOLE_RUN_TIME` before. Otherwise the step is a usual
    one (:func:`hole_ends`) and the caller takes ``dt`` as the new interval.
    """
    if s.est.init != 0.0 and dt > HOLE_FACTOR * s.coef.dt and s.hole.run < HOLE_RUN_TIME:
        s.hole.run += dt
        s.hole.steps = dt / s.coef.dt
        return True
    hole_ends(s)
    return False


def hole_ends(s):
    """A usual step: no hole in a row, nothing to add to the covariance."""
    s.hole.run = 0.0
    s.hole.var = 0.0
    s.hole.steps = 1.0


def hole_rate(s, gx, gy, gz, dt):
    """
    The rate to integrate across a hole of ``dt`` s (rad/s), from the samples on both sides.

    The step the usual ones would have made, had the samples lost lain on
    the straight line between the two: each usual step integrates its
    closing sample's rate, so ``L = dt / C_DT`` steps weigh the new sample
    ``(L + 1) / (2L)`` and the one before the hole the rest (one step: the
    usual step; a long hole: the trapezoid).
    """
    w = 0.5 + 0.5 * s.coef.dt / dt
    lx, ly, lz = s.gyro.last[0], s.gyro.last[1], s.gyro.last[2]
    return lx + w * (gx - lx), ly + w * (gy - ly), lz + w * (gz - lz)


def hole_variance(dx, dy, dz, dt):
    """The trapezoid's error variance per axis (rad²) over ``dt`` s, the rate changing by ``d``."""
    return (HOLE_RATE_CHANGE * HOLE_RATE_CHANGE * (dx * dx + dy * dy + dz * dz) * dt * dt
            + HOLE_RATE_WALK * dt * dt * dt / HOLE_BRIDGE_DIVISOR)


def acc_deviation(s, vx, vy, vz, dt):
    """
    Follow how far the world-frame specific force ``v`` (m/s²) strays from gravity.

    :func:`~ext_observer.core.ahrs.ahrs_filters.gravity_deviation`,
    averaged over about :data:`HOLE_DEVIATION_TIME`: what a hole's own
    variance is weighed against.
    """
    e = gravity_deviation(vx, vy, vz)
    k = min(dt / HOLE_DEVIATION_TIME, 1.0)
    s.inc.acc_dev += k * (e - s.inc.acc_dev)


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
    if s.hole.end[0] != 0.0:
        var *= HOLE_END_SHARE * HOLE_END_SHARE
    s.hole.var = var
    s.hole.count += 1.0
    if var > HOLE_CALIBRATION:
        calibration_restart(s)
    s.inc.sigma = math.sqrt(s.inc.sigma * s.inc.sigma + var)
    s.hole.t0 = restart_weighted(s, var)


def restart_weighted(s, var):
    """
    Restart the inclination's mean where an error of ``var`` (rad²) makes it worth little.

    The mean of ``t`` seconds of new samples is off by ``m c / (c + t)``
    (:func:`hole_after`); where the old mean is worth less than ``tau_acc``
    seconds of them, ``t0 = c (m / var − 1)``, and less than the running
    mean's own weight, the mean starts again with the old weighed as ``t0``
    seconds. Returns ``t0``, or −1.0 where the mean is kept.
    """
    t0 = HOLE_CORRELATION * (s.inc.acc_dev / var - 1.0)
    if t0 >= s.par.tau_acc:
        return -1.0
    t0 = max(t0, 0.0)
    if s.inc.start < s.par.tau_acc and t0 >= s.inc.start:
        return -1.0
    s.inc.start = t0
    s.inc.start_n = t0 / s.coef.dt
    s.inc.lp[3] = 0.0
    s.inc.lp[4] = 0.0
    s.inc.lp[5] = 0.0
    return t0


def clip_after(s, var):
    """
    Each gyro step: a clipped sample's variance ``var`` (rad², 0: not clipped) reaches the mean.

    The rate beyond the range stays beyond it along a clipped stretch: the
    errors add up, :data:`CLIP_SHARE` of the range's σ per sample, into the
    inclination's σ (``inc.sigma``; within a running mean at most the
    mean's, :func:`mean_sigma`), which weighs the mean against new
    samples as a hole's does (:func:`restart_weighted`). Without a clip, that
    σ is forgotten at the low-pass's pace; the recovery (the health state)
    lasts ``tau_acc`` after the last clipped sample.
    """
    if var == 0.0:
        # (Most samples: nothing to forget, and the division skipped.)
        if s.inc.sigma != 0.0:
            s.inc.sigma *= 1.0 - s.coef.dt / s.par.tau_acc
        if s.gyro.clip_left != 0.0:
            s.gyro.clip_left = max(s.gyro.clip_left - s.coef.dt, 0.0)
        return
    s.gyro.clip_left = s.par.tau_acc
    sigma = mean_sigma(s) + CLIP_SHARE * math.sqrt(var)
    s.inc.sigma = sigma
    restart_weighted(s, sigma * sigma)


def mean_sigma(s):
    """
    The inclination's error σ (rad) beyond the usual: at most what a running mean leaves.

    Within a running mean of ``t`` seconds (``inc.start`` below ``tau_acc``),
    the estimate follows the mean, whose error is ``m c / (c + t)``
    (:func:`hole_after`): the losses before its restart are weighed in it.
    """
    sigma = s.inc.sigma
    t = s.inc.start
    if t < s.par.tau_acc:
        sigma = min(sigma, math.sqrt(s.inc.acc_dev * HOLE_CORRELATION / (HOLE_CORRELATION + t)))
    return sigma


def hole_slope(s, dt):
    """
    Before the bridge of a hole of ``dt`` s: keep what its end correction needs.

    The rate's change into the hole (the last two samples before it), when
    the step before was a usual one; the correction
    (:func:`hole_end_fix`) waits for the rate's slope after it.
    """
    f = 0.0
    if s.hole.run == dt and dt <= HOLE_END_TIME:
        f = dt * dt / (HOLE_HERMITE_DIVISOR * s.coef.dt)
        for i in range(3):
            s.hole.end[1 + i] = s.gyro.last[i] - s.gyro.prev[i]
    s.hole.end[0] = f


def hole_end_fix(s, gx, gy, gz):
    """
    The first usual sample after a hole: the bridge's end correction, a body-frame turn.

    The straight line between the samples on both sides misses
    ``T² (m₀ − m₁) / 12`` of the rotation of a rate whose slopes at the two
    ends are ``m₀`` and ``m₁`` (the cubic through both samples with those
    slopes, a Hermite interpolation); the slopes are the differences of the
    samples next to the hole, known once the one after it is here.
    """
    f = s.hole.end[0]
    s.hole.end[0] = 0.0
    cx = f * (s.hole.end[1] - (gx - s.gyro.last[0]))
    cy = f * (s.hole.end[2] - (gy - s.gyro.last[1]))
    cz = f * (s.hole.end[3] - (gz - s.gyro.last[2]))
    n = math.sqrt(cx * cx + cy * cy + cz * cz)
    if n == 0.0:
        return
    c = math.cos(0.5 * n)
    k = math.sin(0.5 * n) / n
    bx, by, bz = k * cx, k * cy, k * cz
    q = s.est.q
    q[0], q[1], q[2], q[3] = quat_multiply(q[0], q[1], q[2], q[3], c, bx, by, bz)
