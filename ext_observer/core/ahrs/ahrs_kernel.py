"""
The raw-IMU estimator's steps as functions on its state with names: the one source.

:class:`~ext_observer.core.ahrs.ahrs_observer.AhrsObserver` keeps the state of one
estimate in a record ``s`` (:data:`~ext_observer.core.ahrs.ahrs_state.STATE`:
``s.rest.time``, ``s.bias.rate[0]``; this module owns the coefficients
``COEF`` and the estimate ``EST``) and runs the functions of this module on
it. They are written in the part of Python that numba's ``nopython`` mode
compiles: float arithmetic, ``math``, attribute and index access, loops,
tuples and calls to each other. So the same source runs

- as it is, on a plain record (no compiler needed), and
- compiled, when numba is installed (:mod:`~ext_observer.core.ahrs.compiled`
  loads this file a second time and compiles every function), on a numpy
  structured record:

one estimator, not two copies to keep in sync; the two agree to the bit
(``test_compiled.py``). Flags are stored as 0.0 or 1.0 (``est.init``: the
estimate exists; ``field.has_ref``: the field references exist). What
Python calls takes the record's holder (the ``*_in`` functions at the end:
:mod:`~ext_observer.core.ahrs.record`).

The maths, step by step, is docs/raw_imu.md's ("The estimator, step by
step"); here each function says which step it is. Quaternions ``(w, x, y, z)``,
sensor → ENU.
"""

import math

from .ahrs_filters import (UNIFORM_ANGLE_VARIANCE, first_attitude, gain, quat_multiply, rotate,
                           rotation_matrix)
from .accel_rejection import acc_rejection_reset
from .clip_and_rest import clipped_variance, detect_rest, gyro_reset, rest_reset
from .gravity_kernel import ahrs_update_acc, inc_reset
from .hole_kernel import (HOLE_CALIBRATION, calibration_restart, clip_after, forget_wait,
                          hole_after, hole_end_fix, hole_ends, hole_rate, hole_slope,
                          hole_reset, hole_starts, hole_variance, restart_mean,
                          restart_weighted)
from .bias_kernel import bias_reset, bias_variance
from .magcal_kernel import mc_apply
from .field_kernel import (ahrs_update_mag, cal_feed_reset, field_back, field_clipped,
                           field_doubt, field_reset)
from .velocity_kernel import velocity_sample, velocity_step
from .record import Group

# The coefficients of the current intervals (NaN: not computed yet).
COEF = Group('coef', 'Coefficients of the current IMU and field intervals', [
    ('dt', 's', 'the IMU interval they are for'),
    ('bw', '', 'the Butterworth low-pass: b0, b1, b2, a1, a2', 5),
    ('k_acc', '', 'the inclination gain per sample'),
    ('k_rest', '', "the rest filters' gain per sample"),
    ('mag_dt', 's', 'the field interval they are for'),
    ('k_mag', '', 'the heading gain per field'),
    ('k_ref', '', "the field references' gain per field"),
    ('bias_q', 'rad²/s²', "the bias's random walk per sample"),
    ('bias_r', '(rad/s)²·s', 'noise density of a correction rate'),
])
EST = Group('est', 'The estimate', [
    ('init', '1', 'the estimate exists (the first accelerometer sample came)'),
    ('q', '', 'q̂ (w, x, y, z), sensor → world, in R⁴ near S³', 4),
])


_TINY = 1e-300
_SQRT2 = math.sqrt(2.0)
# The extended step's pull back to the unit sphere descends V(p) = (p̄p − 1)²,
# whose gradient is NORM_GRADIENT p (p̄p − 1): the derivative's factor, not a tuning.
NORM_GRADIENT = 4.0


# --- state -----------------------------------------------------------------------

def ahrs_reset(s):
    """Forget the estimate: the next accelerometer sample initializes."""
    # Each group by the code that owns it (what a group keeps across a
    # reset, its owner says: the rest filters and the field references'
    # values stay, the learned calibration stays).
    s.est.init = 0.0
    for i in range(4):
        s.est.q[i] = 0.0
    bias_reset(s)
    rest_reset(s)
    gyro_reset(s)
    inc_reset(s)
    hole_reset(s)
    acc_rejection_reset(s)
    field_reset(s)
    cal_feed_reset(s)


def ahrs_coefficients(s, dt):
    """The filters' coefficients for the IMU interval ``dt`` (checked by the caller)."""
    s.coef.dt = dt
    # Second-order Butterworth low-pass (bilinear, prewarped), cutoff 1/(2π τ).
    wc = math.tan(0.5 * dt / s.par.tau_acc)
    k = _SQRT2 * wc
    a0 = 1.0 + k + wc * wc
    b0 = wc * wc / a0
    s.coef.bw[0] = b0
    s.coef.bw[1] = 2.0 * b0
    s.coef.bw[2] = b0
    s.coef.bw[3] = 2.0 * (wc * wc - 1.0) / a0
    s.coef.bw[4] = (1.0 - k + wc * wc) / a0
    s.coef.k_acc = gain(s.par.tau_acc_gain, dt)
    s.coef.k_rest = gain(s.par.tau_rest, dt)
    # The bias in motion: its σ would grow to bias_sigma_motion in tau_bias
    # alone, and a correction rate's noise density makes that σ the steady
    # one (and tau_bias the steady time constant of the estimate).
    sm2 = s.par.bias_sigma_motion * s.par.bias_sigma_motion
    tb = s.par.tau_bias if s.par.tau_bias > 0.0 else 1.0
    s.coef.bias_q = sm2 * dt / tb
    s.coef.bias_r = sm2 * tb


# --- the three steps ---------------------------------------------------------------

def ahrs_update(s, gx, gy, gz, ax, ay, az, has_mag, mx, my, mz, dt):
    """One IMU sample: gyro, then accelerometer, then magnetometer (``has_mag``); the estimate."""
    hole = False
    if dt != s.coef.dt:
        # A hole keeps the usual interval's coefficients (hole_kernel).
        hole = hole_starts(s, dt)
        if not hole:
            ahrs_coefficients(s, dt)
    elif s.hole.run != 0.0:
        hole_ends(s)
    velocity_step(s, gx, gy, gz, dt)  # the velocity aid, where a fresh velocity is given
    if s.est.init == 0.0:
        fx, fy, fz = mx, my, mz
        if has_mag and s.par.has_cal != 0.0:
            # Identity until the calibration is converged or loaded (the
            # field step below calibrates the field as given: once).
            fx, fy, fz = mc_apply(s.cal, mx, my, mz)
        w, x, y, z = first_attitude(ax, ay, az, has_mag and s.par.use_mag != 0.0, fx, fy, fz,
                                    s.par.use_mag != 0.0)
        s.est.q[0] = w
        s.est.q[1] = x
        s.est.q[2] = y
        s.est.q[3] = z
        s.est.init = 1.0
        _init_filters(s, gx, gy, gz, ax, ay, az)
    elif hole:
        ahrs_bridge(s, gx, gy, gz, dt)
    else:
        if s.hole.end[0] != 0.0:
            hole_end_fix(s, gx, gy, gz)
        ahrs_update_gyr(s, gx, gy, gz)
    ahrs_update_acc(s, ax, ay, az)
    if has_mag and s.par.use_mag != 0.0:
        ahrs_update_mag(s, mx, my, mz, dt)
    return s.est.q[0], s.est.q[1], s.est.q[2], s.est.q[3]


def _init_filters(s, gx, gy, gz, ax, ay, az):
    vx, vy, vz = rotate(s.est.q[0], s.est.q[1], s.est.q[2], s.est.q[3], ax, ay, az)
    s.inc.lp[0] = vx
    s.inc.lp[1] = vy
    s.inc.lp[2] = vz
    restart_mean(s)
    r = rotation_matrix(s)
    for j in range(3):
        s.bias.rz_lp[j] = r[6 + j]
    # The last rate, the one before it (none yet: the same) and rest's mean.
    for i in range(3):
        g = gx if i == 0 else (gy if i == 1 else gz)
        s.gyro.last[i] = g
        s.gyro.prev[i] = g
        s.rest.gyr_lp[i] = g
    s.gyro.peak = max(abs(gx), max(abs(gy), abs(gz)))
    s.rest.acc_lp[0] = ax
    s.rest.acc_lp[1] = ay
    s.rest.acc_lp[2] = az


def _watch_clipping(s, gx, gy, gz):
    """
    A sample at the gyro's range (:func:`clipped_variance`): distrust the gyro, lean on the others.

    The inclination's mean of the specific force starts again where the
    stretch's error outweighs it (:func:`clip_after`); the heading's doubt
    grows with the stretch (:func:`field_clipped`), so that the next fields
    correct it with the Kalman gain of that doubt, and from their running
    mean once the heading is lost; the magnetometer calibration does not
    learn across the stretch.
    """
    var = clipped_variance(s, gx, gy, gz)
    clip_after(s, var)
    if var == 0.0:
        return
    field_clipped(s, var)
    forget_wait(s)
    calibration_restart(s, True)


def ahrs_update_gyr(s, gx, gy, gz):
    """Propagate with ``exp((ω − b̂) dt / 2)`` and apply the extension term."""
    _watch_clipping(s, gx, gy, gz)
    _propagate(s, gx, gy, gz, gx, gy, gz, s.coef.dt)
    detect_rest(s, gx, gy, gz)


def ahrs_bridge(s, gx, gy, gz, dt):
    """
    The gyro step across a hole of ``dt`` s (:mod:`~ext_observer.core.ahrs.hole_kernel`).

    The rotation from the mean rate of the samples on both sides; the
    sample's own rate for the rest (clipping, rest detection, the
    calibration), with the usual interval's coefficients.
    """
    hole_slope(s, dt)
    rx, ry, rz = hole_rate(s, gx, gy, gz, dt)
    var = hole_variance(gx - s.gyro.last[0], gy - s.gyro.last[1], gz - s.gyro.last[2], dt)
    _watch_clipping(s, gx, gy, gz)
    _propagate(s, rx, ry, rz, gx, gy, gz, dt)
    detect_rest(s, gx, gy, gz)
    hole_after(s, var)
    field_doubt(s, s.hole.var)


# rad² per axis: the most a rotation nobody saw can leave, that of an angle
# uniform on (−π, π] (σ 104°).
UNSEEN_ROTATION = UNIFORM_ANGLE_VARIANCE
# An unseen rotation's square, shared alike by the three axes.
UNSEEN_AXES = 3.0


def ahrs_unbridged(s, gx, gy, gz, dt):
    """
    A hole of ``dt`` s too long to bridge (over ``max_dt``): the estimate holds, its doubt grows.

    The rotation across it is not integrated (past about 2 s the straight
    line between the rates beside it is worse than nothing); what it may
    have been is the variance the hole leaves per axis: the mean of the two
    rates (less the bias) over ``dt``, a third per axis, and the bridge's own
    error, at most :data:`UNSEEN_ROTATION`. As after a bridged hole, the
    inclination's mean restarts weighed against it, the field gets it as its
    doubt, the calibration learns nothing across it. The sample after the
    hole is the next step's start: its rate is the last one. Returns the
    variance and the weight ``t0`` the inclination's mean restarted with
    (−1.0: kept).
    """
    lx, ly, lz = s.gyro.last[0], s.gyro.last[1], s.gyro.last[2]
    mx = 0.5 * (lx + gx) - s.bias.rate[0]
    my = 0.5 * (ly + gy) - s.bias.rate[1]
    mz = 0.5 * (lz + gz) - s.bias.rate[2]
    var = (mx * mx + my * my + mz * mz) * dt * dt / UNSEEN_AXES
    var = min(var + hole_variance(gx - lx, gy - ly, gz - lz, dt), UNSEEN_ROTATION)
    for i in range(3):
        g = gx if i == 0 else (gy if i == 1 else gz)
        s.gyro.prev[i] = g
        s.gyro.last[i] = g
    s.hole.end[0] = 0.0
    if var > HOLE_CALIBRATION:
        calibration_restart(s)
    s.inc.sigma = math.sqrt(s.inc.sigma * s.inc.sigma + var)
    t0 = restart_weighted(s, var)
    field_doubt(s, var)
    return var, t0


def _propagate(s, rx, ry, rz, gx, gy, gz, dt):
    """``q̂ ← q̂ ⊗ exp((r − b̂) dt / 2)``, the extension term; ``g`` the sample's rate."""
    bx, by, bz = s.bias.rate[0], s.bias.rate[1], s.bias.rate[2]
    ux = (rx - bx) * dt
    uy = (ry - by) * dt
    uz = (rz - bz) * dt
    # exp of the half increment: (cos(θ/2), sin(θ/2)/θ · u), θ = |u|; the
    # tiny term only keeps θ = 0 (then u = 0) from dividing by zero.
    t = math.sqrt(ux * ux + uy * uy + uz * uz)
    c = math.cos(0.5 * t)
    sn = math.sin(0.5 * t) / (t + _TINY)
    ex, ey, ez = ux * sn, uy * sn, uz * sn
    w, x, y, z = s.est.q[0], s.est.q[1], s.est.q[2], s.est.q[3]
    pw, px, py, pz = quat_multiply(w, x, y, z, c, ex, ey, ez)
    if s.par.has_cal != 0.0:
        turn = s.cal_feed.turn
        turn[0], turn[1], turn[2], turn[3] = quat_multiply(turn[0], turn[1], turn[2], turn[3],
                                                           c, ex, ey, ez)
        s.cal_feed.rate[0] = gx - bx
        s.cal_feed.rate[1] = gy - by
        s.cal_feed.rate[2] = gz - bz
        lx, ly, lz = s.rest.gyr_lp[0] - bx, s.rest.gyr_lp[1] - by, s.rest.gyr_lp[2] - bz
        if lx * lx + ly * ly + lz * lz >= s.par.rest_gyr ** 2:
            s.cal_feed.moved = 1.0
    if s.par.extended != 0.0:
        # p − α ∇V(p), ∇V(p) = 4 p (p̄p − 1) (NORM_GRADIENT).
        f = 1.0 - NORM_GRADIENT * s.par.alpha * (pw * pw + px * px + py * py + pz * pz - 1.0)
        pw, px, py, pz = pw * f, px * f, py * f, pz * f
    s.est.q[0] = pw
    s.est.q[1] = px
    s.est.q[2] = py
    s.est.q[3] = pz


# --- the bias in motion: a Kalman filter on the corrections ------------------------


# --- a whole recording -----------------------------------------------------------------

def ahrs_run_in(state, gyr, acc, mag, count, has_mag, dt, out):
    """
    ``count`` samples at one interval ``dt``: ``out[k]`` the estimate after sample ``k``.

    ``state`` is the estimate's holder (:mod:`~ext_observer.core.ahrs.record`).
    ``gyr``, ``acc``, ``mag`` and ``out`` are indexed ``[k][i]``: lists of
    lists on the plain path, (N, 3) and (N, 4) arrays compiled; ``mag`` any
    of them when ``has_mag`` is false.
    """
    s = state[0]
    for k in range(count):
        g = gyr[k]
        a = acc[k]
        m = mag[k]  # the caller passes any (N, 3) when has_mag is false
        ahrs_update(s, g[0], g[1], g[2], a[0], a[1], a[2], has_mag, m[0], m[1], m[2], dt)
        o = out[k]
        o[0] = s.est.q[0]
        o[1] = s.est.q[1]
        o[2] = s.est.q[2]
        o[3] = s.est.q[3]


# --- what Python calls: on a holder --------------------------------------------------
# numba takes a one-element array from Python in a fraction of a microsecond,
# a record in tens of microseconds (it types the record's dtype at every call:
# record.py); so the wrapper hands each step the holder, whose [0] is the record.

def ahrs_update_in(state, gx, gy, gz, ax, ay, az, has_mag, mx, my, mz, dt):
    """:func:`ahrs_update` on the record in ``state``."""
    return ahrs_update(state[0], gx, gy, gz, ax, ay, az, has_mag, mx, my, mz, dt)


def ahrs_reset_in(state):
    """:func:`ahrs_reset` on the record in ``state``."""
    ahrs_reset(state[0])


def ahrs_update_acc_in(state, ax, ay, az):
    """:func:`~ext_observer.core.ahrs.gravity_kernel.ahrs_update_acc` on ``state``'s record."""
    ahrs_update_acc(state[0], ax, ay, az)


def ahrs_update_mag_in(state, mx, my, mz, dt):
    """:func:`~ext_observer.core.ahrs.field_kernel.ahrs_update_mag` on the record in ``state``."""
    ahrs_update_mag(state[0], mx, my, mz, dt)


def field_back_in(state, var):
    """:func:`~ext_observer.core.ahrs.field_kernel.field_back` on the record in ``state``."""
    field_back(state[0], var)


def ahrs_unbridged_in(state, gx, gy, gz, dt):
    """:func:`ahrs_unbridged` on the record in ``state``."""
    return ahrs_unbridged(state[0], gx, gy, gz, dt)


def velocity_sample_in(state, vx, vy, vz, dt):
    """:func:`~ext_observer.core.ahrs.velocity_kernel.velocity_sample` on ``state``'s record."""
    velocity_sample(state[0], vx, vy, vz, dt)


def bias_variance_in(state, i, j):
    """:func:`~ext_observer.core.ahrs.bias_kernel.bias_variance` of the record in ``state``."""
    return bias_variance(state[0], i, j)
