"""
The raw-IMU estimator's steps as functions on one flat state: the one source.

:class:`~ext_observer.core.ahrs.ahrs_observer.AhrsObserver` keeps the state of one
estimate in a flat container ``s`` (the slots below, then the magnetometer
calibration's block, :mod:`~ext_observer.core.ahrs.magcal_kernel`) and runs the
functions of this module on it. They are written in the part of Python that
numba's ``nopython`` mode compiles: float arithmetic, ``math``, indexing,
loops, tuples and calls to each other. So the same source runs

- as it is, on a Python ``list`` of floats (no compiler needed), and
- compiled, when numba is installed (:mod:`~ext_observer.core.ahrs.compiled`
  loads this file a second time and compiles every function), on a float64
  numpy array:

one estimator, not two copies to keep in sync; the two agree to rounding
(``test_compiled.py``). Flags are stored as 0.0 or 1.0, ``None`` as a flag
of its own (``S_INIT``: the estimate exists; ``S_HAS_REF``: the field
references exist).

The maths, step by step, is docs/raw_imu.md's ("The estimator, step by
step"); here each function says which step it is. Quaternions ``(w, x, y, z)``,
sensor → ENU.
"""

import math

from .ahrs_filters import first_attitude, gain, rotate, rotation_matrix
# The layout's names (and bias_variance) are read from this module too: the
# wrapper, the covariance and the tests see one module, plain or compiled.
from .ahrs_layout import (  # noqa: F401
                          AHRS, A_SIZE, C_BIAS_Q, C_BIAS_R, C_BW, C_DT, C_K_ACC, C_K_MAG, C_K_REF,
                          C_K_REST, C_MAG_DT, MC0, PARAMETERS, P_ALPHA, P_BIAS_MAX,
                          P_BIAS_SIGMA_MOTION, P_CAL_PERIOD, P_EXTENDED, P_GYRO_RANGE, P_HAS_CAL,
                          P_MAG_DIP_TH, P_MAG_NEW_GYR, P_MAG_NEW_TIME, P_MAG_NORM_TH,
                          P_MOTION_BIAS, P_REST_ACC, P_REST_GYR, P_REST_TIME, P_TAU_ACC,
                          P_TAU_ACC_GAIN, P_TAU_BIAS, P_TAU_MAG, P_TAU_MAG_REF, P_TAU_REST,
                          P_USE_MAG, S_ACC_STILL, S_BIAS, S_BIAS_P, S_CAL_LOADED, S_CAL_MOVED,
                          S_CAL_RATE, S_CAL_SINCE, S_CAL_TURN, S_CAL_WAIT, S_CAND, S_CAND_TIME,
                          S_CLIPPED, S_CLIPS, S_GYR_LAST, S_GYR_PEAK, S_GYR_PREV, S_HAS_REF,
                          S_INIT, S_LP, S_HOLE_END, S_MAG_DIST, S_MAG_USED, S_Q, S_REF, S_REF_AGE,
                          S_REJECTED, S_REST, S_REST_ACC, S_REST_GYR, S_REST_TIME, S_RZLP, S_START,
                          S_START_N, S_REF_REST, S_ACC_DEV, S_HOLE_RUN, S_HOLE_T0, S_HOLE_VAR,
                          S_HOLES, S_INC_SIGMA, S_CLIP_LEFT, S_STUCK, S_WAIT_N, S_ACC_REJ, S_WAIT_TURN)
from .accel_rejection import acc_rejection_reset
from .clip_and_rest import clipped_variance, detect_rest
from .gravity_kernel import ahrs_update_acc  # noqa: F401 (the steps' module serves it)
from .hole_kernel import (HOLE_CALIBRATION, calibration_restart, clip_after, forget_wait,
                          hole_after, hole_end_fix, hole_ends, hole_rate, hole_slope,
                          hole_starts, hole_variance, restart_mean, restart_weighted)
from .bias_kernel import bias_forget, bias_measure, bias_variance  # noqa: F401
from .magcal_kernel import mc_apply
# The field step (read from this module too: the wrapper and the tests see one module).
from .field_kernel import (ahrs_update_mag, field_clipped,  # noqa: F401
                           field_doubt, field_forget)
from .velocity_kernel import velocity_sample, velocity_step  # noqa: F401


_TINY = 1e-300
_SQRT2 = math.sqrt(2.0)
# The extended step's pull back to the unit sphere descends V(p) = (p̄p − 1)²,
# whose gradient is NORM_GRADIENT p (p̄p − 1): the derivative's factor, not a tuning.
NORM_GRADIENT = 4.0


# --- state -----------------------------------------------------------------------

def ahrs_reset(s):
    """Forget the estimate: the next accelerometer sample initializes."""
    s[S_INIT] = 0.0
    for i in range(4):
        s[S_Q + i] = 0.0
    for i in range(3):
        s[S_BIAS + i] = 0.0
    s[S_REST] = 0.0
    s[S_REST_TIME] = 0.0
    s[S_MAG_DIST] = 0.0
    s[S_HAS_REF] = 0.0
    s[S_CAND_TIME] = 0.0
    s[S_MAG_USED] = 0.0
    s[S_REJECTED] = 0.0
    forget_wait(s)
    bias_forget(s)
    s[S_START] = 0.0
    s[S_START_N] = 0.0
    s[S_CLIPPED] = 0.0
    s[S_ACC_DEV] = 0.0
    s[S_HOLE_T0] = 0.0
    s[S_INC_SIGMA] = 0.0
    s[S_CLIP_LEFT] = 0.0
    hole_ends(s)
    acc_rejection_reset(s)
    field_forget(s)
    # The learned calibration stays; the field is followed afresh.
    calibration_restart(s)
    if s[P_HAS_CAL] != 0.0:
        for i in range(3):
            s[S_CAL_RATE + i] = 0.0
        s[S_CAL_MOVED] = 0.0  # the body has not turned yet
        s[S_CAL_SINCE] = math.inf  # time since a calibration was applied
        s[S_CAL_LOADED] = 0.0


def ahrs_coefficients(s, dt):
    """The filters' coefficients for the IMU interval ``dt`` (checked by the caller)."""
    s[C_DT] = dt
    # Second-order Butterworth low-pass (bilinear, prewarped), cutoff 1/(2π τ).
    wc = math.tan(0.5 * dt / s[P_TAU_ACC])
    k = _SQRT2 * wc
    a0 = 1.0 + k + wc * wc
    b0 = wc * wc / a0
    s[C_BW] = b0
    s[C_BW + 1] = 2.0 * b0
    s[C_BW + 2] = b0
    s[C_BW + 3] = 2.0 * (wc * wc - 1.0) / a0
    s[C_BW + 4] = (1.0 - k + wc * wc) / a0
    s[C_K_ACC] = gain(s[P_TAU_ACC_GAIN], dt)
    s[C_K_REST] = gain(s[P_TAU_REST], dt)
    # The bias in motion: its σ would grow to bias_sigma_motion in tau_bias
    # alone, and a correction rate's noise density makes that σ the steady
    # one (and tau_bias the steady time constant of the estimate).
    sm2 = s[P_BIAS_SIGMA_MOTION] * s[P_BIAS_SIGMA_MOTION]
    tb = s[P_TAU_BIAS] if s[P_TAU_BIAS] > 0.0 else 1.0
    s[C_BIAS_Q] = sm2 * dt / tb
    s[C_BIAS_R] = sm2 * tb


# --- the three steps ---------------------------------------------------------------

def ahrs_update(s, gx, gy, gz, ax, ay, az, has_mag, mx, my, mz, dt):
    """One IMU sample: gyro, then accelerometer, then magnetometer (``has_mag``); the estimate."""
    hole = False
    if dt != s[C_DT]:
        # A hole keeps the usual interval's coefficients (hole_kernel).
        hole = hole_starts(s, dt)
        if not hole:
            ahrs_coefficients(s, dt)
    elif s[S_HOLE_RUN] != 0.0:
        hole_ends(s)
    velocity_step(s, gx, gy, gz, dt)  # the velocity aid, where a fresh velocity is given
    if s[S_INIT] == 0.0:
        fx, fy, fz = mx, my, mz
        if has_mag and s[P_HAS_CAL] != 0.0:
            # Identity until the calibration is converged or loaded (the
            # field step below calibrates the field as given: once).
            fx, fy, fz = mc_apply(s, MC0, mx, my, mz)
        w, x, y, z = first_attitude(ax, ay, az, has_mag and s[P_USE_MAG] != 0.0, fx, fy, fz,
                                    s[P_USE_MAG] != 0.0)
        s[S_Q] = w
        s[S_Q + 1] = x
        s[S_Q + 2] = y
        s[S_Q + 3] = z
        s[S_INIT] = 1.0
        _init_filters(s, gx, gy, gz, ax, ay, az)
    elif hole:
        ahrs_bridge(s, gx, gy, gz, dt)
    else:
        if s[S_HOLE_END] != 0.0:
            hole_end_fix(s, gx, gy, gz)
        ahrs_update_gyr(s, gx, gy, gz)
    ahrs_update_acc(s, ax, ay, az)
    if has_mag and s[P_USE_MAG] != 0.0:
        ahrs_update_mag(s, mx, my, mz, dt)
    return s[S_Q], s[S_Q + 1], s[S_Q + 2], s[S_Q + 3]


def _init_filters(s, gx, gy, gz, ax, ay, az):
    vx, vy, vz = rotate(s[S_Q], s[S_Q + 1], s[S_Q + 2], s[S_Q + 3], ax, ay, az)
    s[S_LP] = vx
    s[S_LP + 1] = vy
    s[S_LP + 2] = vz
    restart_mean(s)
    r = rotation_matrix(s)
    for j in range(3):
        s[S_RZLP + j] = r[6 + j]
    # The last rate, the one before it (none yet: the same) and rest's mean.
    for i in range(3):
        g = gx if i == 0 else (gy if i == 1 else gz)
        s[S_GYR_LAST + i] = g
        s[S_GYR_PREV + i] = g
        s[S_REST_GYR + i] = g
    s[S_GYR_PEAK] = max(abs(gx), max(abs(gy), abs(gz)))
    s[S_REST_ACC] = ax
    s[S_REST_ACC + 1] = ay
    s[S_REST_ACC + 2] = az


def _watch_clipping(s, gx, gy, gz):
    """
    A sample at the gyro's range (:func:`clipped_variance`): distrust the gyro, lean on the others.

    The inclination's mean of the specific force starts again where the
    stretch's error outweighs it (:func:`clip_after`), the heading from the
    running mean of the next fields, and the magnetometer calibration does
    not learn across the stretch.
    """
    var = clipped_variance(s, gx, gy, gz)
    clip_after(s, var)
    if var == 0.0:
        return
    field_clipped(s, var)
    s[S_MAG_USED] = 0.0
    forget_wait(s)
    calibration_restart(s)


def ahrs_update_gyr(s, gx, gy, gz):
    """Propagate with ``exp((ω − b̂) dt / 2)`` and apply the extension term."""
    _watch_clipping(s, gx, gy, gz)
    _propagate(s, gx, gy, gz, gx, gy, gz, s[C_DT])
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
    var = hole_variance(gx - s[S_GYR_LAST], gy - s[S_GYR_LAST + 1], gz - s[S_GYR_LAST + 2], dt)
    _watch_clipping(s, gx, gy, gz)
    _propagate(s, rx, ry, rz, gx, gy, gz, dt)
    detect_rest(s, gx, gy, gz)
    hole_after(s, var)
    field_doubt(s, s[S_HOLE_VAR])


# rad² per axis: the most a rotation nobody saw can leave, that of an angle
# uniform on (−π, π] (σ 104°).
UNSEEN_ROTATION = math.pi * math.pi / 3.0
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
    lx, ly, lz = s[S_GYR_LAST], s[S_GYR_LAST + 1], s[S_GYR_LAST + 2]
    mx = 0.5 * (lx + gx) - s[S_BIAS]
    my = 0.5 * (ly + gy) - s[S_BIAS + 1]
    mz = 0.5 * (lz + gz) - s[S_BIAS + 2]
    var = (mx * mx + my * my + mz * mz) * dt * dt / UNSEEN_AXES
    var = min(var + hole_variance(gx - lx, gy - ly, gz - lz, dt), UNSEEN_ROTATION)
    for i in range(3):
        g = gx if i == 0 else (gy if i == 1 else gz)
        s[S_GYR_PREV + i] = g
        s[S_GYR_LAST + i] = g
    s[S_HOLE_END] = 0.0
    if var > HOLE_CALIBRATION:
        calibration_restart(s)
    s[S_INC_SIGMA] = math.sqrt(s[S_INC_SIGMA] * s[S_INC_SIGMA] + var)
    t0 = restart_weighted(s, var)
    field_doubt(s, var)
    return var, t0


def _propagate(s, rx, ry, rz, gx, gy, gz, dt):
    """``q̂ ← q̂ ⊗ exp((r − b̂) dt / 2)``, the extension term; ``g`` the sample's rate."""
    bx, by, bz = s[S_BIAS], s[S_BIAS + 1], s[S_BIAS + 2]
    ux = (rx - bx) * dt
    uy = (ry - by) * dt
    uz = (rz - bz) * dt
    # exp of the half increment: (cos(θ/2), sin(θ/2)/θ · u), θ = |u|; the
    # tiny term only keeps θ = 0 (then u = 0) from dividing by zero.
    t = math.sqrt(ux * ux + uy * uy + uz * uz)
    c = math.cos(0.5 * t)
    sn = math.sin(0.5 * t) / (t + _TINY)
    ex, ey, ez = ux * sn, uy * sn, uz * sn
    w, x, y, z = s[S_Q], s[S_Q + 1], s[S_Q + 2], s[S_Q + 3]
    pw = w * c - x * ex - y * ey - z * ez
    px = w * ex + x * c + y * ez - z * ey
    py = w * ey - x * ez + y * c + z * ex
    pz = w * ez + x * ey - y * ex + z * c
    if s[P_HAS_CAL] != 0.0:
        tw, tx, ty, tz = s[S_CAL_TURN], s[S_CAL_TURN + 1], s[S_CAL_TURN + 2], s[S_CAL_TURN + 3]
        s[S_CAL_TURN] = tw * c - tx * ex - ty * ey - tz * ez
        s[S_CAL_TURN + 1] = tw * ex + tx * c + ty * ez - tz * ey
        s[S_CAL_TURN + 2] = tw * ey - tx * ez + ty * c + tz * ex
        s[S_CAL_TURN + 3] = tw * ez + tx * ey - ty * ex + tz * c
        s[S_CAL_RATE] = gx - bx
        s[S_CAL_RATE + 1] = gy - by
        s[S_CAL_RATE + 2] = gz - bz
        lx, ly, lz = s[S_REST_GYR] - bx, s[S_REST_GYR + 1] - by, s[S_REST_GYR + 2] - bz
        if lx * lx + ly * ly + lz * lz >= s[P_REST_GYR] ** 2:
            s[S_CAL_MOVED] = 1.0
    if s[P_EXTENDED] != 0.0:
        # p − α ∇V(p), ∇V(p) = 4 p (p̄p − 1) (NORM_GRADIENT).
        f = 1.0 - NORM_GRADIENT * s[P_ALPHA] * (pw * pw + px * px + py * py + pz * pz - 1.0)
        pw, px, py, pz = pw * f, px * f, py * f, pz * f
    s[S_Q] = pw
    s[S_Q + 1] = px
    s[S_Q + 2] = py
    s[S_Q + 3] = pz


# --- the bias in motion: a Kalman filter on the corrections ------------------------


# --- a whole recording -----------------------------------------------------------------

def ahrs_run(s, gyr, acc, mag, count, has_mag, dt, out):
    """
    ``count`` samples at one interval ``dt``: ``out[k]`` the estimate after sample ``k``.

    ``gyr``, ``acc``, ``mag`` and ``out`` are indexed ``[k][i]``: lists of
    lists on the plain path, (N, 3) and (N, 4) arrays compiled; ``mag`` any
    of them when ``has_mag`` is false.
    """
    for k in range(count):
        g = gyr[k]
        a = acc[k]
        m = mag[k]  # the caller passes any (N, 3) when has_mag is false
        ahrs_update(s, g[0], g[1], g[2], a[0], a[1], a[2], has_mag, m[0], m[1], m[2], dt)
        o = out[k]
        o[0] = s[S_Q]
        o[1] = s[S_Q + 1]
        o[2] = s[S_Q + 2]
        o[3] = s[S_Q + 3]
