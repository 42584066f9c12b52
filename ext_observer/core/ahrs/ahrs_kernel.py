"""
The raw-IMU estimator's steps as functions on one flat state: the one source.

:class:`~ext_observer.core.ahrs.estimator.AhrsObserver` keeps the state of one
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
from .gyro_watch import clipped_variance, detect_rest
from .gravity_kernel import ahrs_update_acc  # noqa: F401 (the steps' module serves it)
from .hole_kernel import (calibration_restart, clip_after, forget_wait, hole_after,
                          hole_end_fix, hole_ends, hole_rate, hole_slope, hole_starts,
                          hole_variance, restart_mean)
from .bias_kernel import bias_forget, bias_measure, bias_variance  # noqa: F401
from .magcal_kernel import MC_APPLIED, MC_READY, mc_apply, mc_field, mc_learn
from .velocity_kernel import velocity_sample, velocity_step  # noqa: F401


_TINY = 1e-300
# After a calibration is applied, the heading's time constant is this share
# of the time since, and at least this (s), until it reaches tau_mag.
_REFINE_SHARE = 0.5
_REFINE_SHORTEST = 1.0
_SQRT2 = math.sqrt(2.0)
# s: a field rejected as disturbed for longer than this is the field (VQF's
# maximum rejection time, Laidig & Seel 2023): the references follow it.
_MAX_REJECTION = 60.0


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


def ahrs_mag_coefficients(s, dt):
    """The heading's and the field references' gains for the field interval ``dt``."""
    s[C_MAG_DT] = dt
    s[C_K_MAG] = gain(s[P_TAU_MAG], dt)
    s[C_K_REF] = gain(s[P_TAU_MAG_REF], dt)


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
        # p − α ∇V(p), ∇V(p) = 4 p (p̄p − 1).
        f = 1.0 - 4.0 * s[P_ALPHA] * (pw * pw + px * px + py * py + pz * pz - 1.0)
        pw, px, py, pz = pw * f, px * f, py * f, pz * f
    s[S_Q] = pw
    s[S_Q + 1] = px
    s[S_Q + 2] = py
    s[S_Q + 3] = pz


# --- the bias in motion: a Kalman filter on the corrections ------------------------


def ahrs_update_mag(s, mx, my, mz, dt):
    """Correct the heading from the magnetometer (interval ``dt``), rejecting disturbed fields."""
    if dt != s[C_MAG_DT]:
        ahrs_mag_coefficients(s, dt)
    has_cal = s[P_HAS_CAL] != 0.0
    if has_cal:
        mx, my, mz = _calibrate(s, mx, my, mz, dt)
    w, x, y, z = s[S_Q], s[S_Q + 1], s[S_Q + 2], s[S_Q + 3]
    mx, my, mz = rotate(w, x, y, z, mx, my, mz)
    h = math.sqrt(mx * mx + my * my)
    norm = math.sqrt(h * h + mz * mz)
    valid = (h > 0.0) and (norm > 0.0)
    dip = math.atan2(mz, h)
    psi = math.atan2(mx, my)

    if s[S_HAS_REF] == 0.0:
        s[S_REF] = norm
        s[S_REF + 1] = dip
        s[S_CAND] = norm
        s[S_CAND + 1] = dip
        s[S_HAS_REF] = 1.0
        s[S_REF_AGE] = 0.0
        s[S_REF_REST] = 0.0
    ref_n, ref_d = s[S_REF], s[S_REF + 1]
    th_n, th_d = s[P_MAG_NORM_TH], s[P_MAG_DIP_TH]
    disturbed = (abs(norm - ref_n) > th_n * ref_n) or (abs(dip - ref_d) > th_d)
    # A new field: consistent with the candidate while the body turns
    # (VQF's candidate, Laidig & Seel 2023: its time counts whether or not
    # the references reject the field, so that a field that passes the
    # references' test now and then is not started over each time). A field
    # off the candidate starts it over; while the references are young
    # (confirmed by fewer than mag_new_time seconds of fields, none at rest:
    # a start in motion takes them from one sample, while a rest shows the
    # place's field without the motion's spread) it only takes back twice
    # its length, as for the rejection time, so that the spread of a moving
    # body's field does not keep one sample's references for ever.
    cand_n, cand_d = s[S_CAND], s[S_CAND + 1]
    consistent = (abs(norm - cand_n) < th_n * cand_n) and (abs(dip - cand_d) < th_d)
    gx, gy, gz = s[S_REST_GYR], s[S_REST_GYR + 1], s[S_REST_GYR + 2]
    turning = gx * gx + gy * gy + gz * gz > s[P_MAG_NEW_GYR] ** 2
    if consistent:
        if turning:
            s[S_CAND_TIME] += dt
    elif s[S_REF_REST] == 0.0 and s[S_REF_AGE] < s[P_MAG_NEW_TIME]:
        s[S_CAND_TIME] = max(s[S_CAND_TIME] - 2.0 * dt, 0.0)
    else:
        s[S_CAND_TIME] = 0.0
    kr = s[C_K_REF]
    if consistent:
        s[S_CAND] = cand_n + kr * (norm - cand_n)
        s[S_CAND + 1] = cand_d + kr * (dip - cand_d)
    elif s[S_CAND_TIME] == 0.0:
        s[S_CAND] = norm
        s[S_CAND + 1] = dip
    # A new field is accepted once it has lasted mag_new_time, or longer
    # than fields have confirmed the references: those taken from the
    # first field of a body that starts beside a magnet are not trusted
    # longer than the true field has been seen.
    # A short undisturbed stretch takes back twice its length (VQF's rejection factor).
    s[S_REJECTED] = s[S_REJECTED] + dt if disturbed else max(s[S_REJECTED] - 2.0 * dt, 0.0)
    accept_new = disturbed and (s[S_CAND_TIME] >= min(s[P_MAG_NEW_TIME], s[S_REF_AGE])
                                or s[S_REJECTED] >= _MAX_REJECTION)
    if accept_new:
        s[S_REJECTED] = 0.0
    if accept_new:
        ref_n, ref_d = s[S_CAND], s[S_CAND + 1]
        if s[S_REF_AGE] < s[P_MAG_NEW_TIME]:
            # The fields the heading followed so far were the disturbed
            # ones: its running mean starts again from the new field.
            s[S_MAG_USED] = 0.0
            forget_wait(s)
        s[S_REF_AGE] = s[S_CAND_TIME]
        s[S_REF_REST] = 0.0
    disturbed = disturbed and not accept_new
    use = valid and not disturbed and s[P_USE_MAG] != 0.0
    if use:
        s[S_REF_AGE] += dt
        if s[S_REST] != 0.0:
            s[S_REF_REST] = 1.0
        s[S_REF] = ref_n + kr * (norm - ref_n)
        s[S_REF + 1] = ref_d + kr * (dip - ref_d)
    else:
        s[S_REF] = ref_n
        s[S_REF + 1] = ref_d
    s[S_MAG_DIST] = 1.0 if disturbed else 0.0
    if has_cal:
        # The heading waits for the calibration; before the body has
        # first moved it is the field's as given, averaged (the start), and
        # the first field after the running mean started over (the fields
        # it followed were disturbed ones) sets it as the first one did.
        if s[MC0 + MC_READY] == 0.0 and s[S_CAL_MOVED] != 0.0 and s[S_MAG_USED] != 0.0:
            if use:
                _wait(s, psi)
            use = False
        elif s[S_WAIT_N] != 0.0:
            if s[MC0 + MC_APPLIED] == 0.0:
                # The sensor looked calibrated: the fields of the wait were
                # right as given, and count as if the heading had used them.
                half = 0.5 * s[S_WAIT_TURN]
                _turn_heading(s, math.cos(half), math.sin(half))
                psi = math.atan2(math.sin(psi - s[S_WAIT_TURN]), math.cos(psi - s[S_WAIT_TURN]))
                s[S_MAG_USED] += s[S_WAIT_N]
            forget_wait(s)

    # Heading measurement y = R_z(ψ) ⊗ q̂; gain κ_m, a running average at first.
    used = s[S_MAG_USED] + (1.0 if use else 0.0)
    s[S_MAG_USED] = used
    k_mag = s[C_K_MAG]
    if not has_cal:
        kap = max(k_mag, 1.0 / max(used, 1.0)) if use else 0.0
    else:
        # A calibration applied t ago improves still: the heading follows
        # it with the time constant t/2 (at least 1 s) until that reaches
        # tau_mag; the fields of older calibrations weigh less.
        since = s[S_CAL_SINCE] + dt
        s[S_CAL_SINCE] = since
        follow = 1.0 - math.exp(-dt / max(_REFINE_SHORTEST, _REFINE_SHARE * since))
        kap = max(max(k_mag, 1.0 / max(used, 1.0)), follow) if use else 0.0
    half = 0.5 * psi
    rw, rz = 1.0 - kap + kap * math.cos(half), kap * math.sin(half)
    _turn_heading(s, rw, rz)
    if s[P_MOTION_BIAS] != 0.0:
        # The heading correction follows the drift (R β)_z through a
        # first-order low-pass of tau_mag: R's z row low-passed alike is
        # what it measures β through. Only the steady gain's corrections
        # teach (not the first fields' running mean, nor a calibration's
        # refinement), and not at rest or in a start. A field's heading is
        # disturbed far more often and for longer than gravity's direction:
        # its correction rate is trusted as much less as its loop is slower
        # (noise density times tau_mag / tau_acc).
        r = rotation_matrix(s)
        for j in range(3):
            s[S_RZLP + j] += k_mag * (r[6 + j] - s[S_RZLP + j])
        if (kap == k_mag and used * k_mag > 1.0 and s[S_REST] == 0.0
                and s[S_START] >= 2.0 * s[P_TAU_ACC]):
            bias_measure(s, s[S_RZLP], s[S_RZLP + 1], s[S_RZLP + 2], -2.0 * rz / (rw * dt),
                          s[C_BIAS_R] * s[P_TAU_MAG] / (s[P_TAU_ACC] * dt))


def _wait(s, psi):
    """
    A field while the heading waits for the calibration: what it would have done.

    Were the calibration to find the field right as given (the sensor looks
    calibrated), the heading should have followed this field as any other:
    the turn it would have had by now follows the field's heading ``psi``
    (rad, in the estimate's world frame) with the gain the heading would
    have had (a running mean of the fields used, then ``k_mag``). The turn
    is about the world vertical, which commutes with the body-frame
    increments of the gyro in between.
    """
    n = s[S_MAG_USED] + s[S_WAIT_N] + 1.0
    s[S_WAIT_N] += 1.0
    kap = max(s[C_K_MAG], 1.0 / n)
    d = psi - s[S_WAIT_TURN]
    s[S_WAIT_TURN] += kap * math.atan2(math.sin(d), math.cos(d))


def _turn_heading(s, rw, rz):
    """``q̂ ← r ⊗ q̂`` for ``r = (rw, 0, 0, rz)`` (not unit), the filter's states with it."""
    w, x, y, z = s[S_Q], s[S_Q + 1], s[S_Q + 2], s[S_Q + 3]
    s[S_Q] = rw * w - rz * z
    s[S_Q + 1] = rw * x - rz * y
    s[S_Q + 2] = rw * y + rz * x
    s[S_Q + 3] = rw * z + rz * w
    # The filter's states turn with it about the vertical: (c, s) of 2θ.
    n2 = rw * rw + rz * rz
    c, sn = (rw * rw - rz * rz) / n2, 2.0 * rw * rz / n2
    for i in (0, 3):
        a, b = s[S_LP + i], s[S_LP + i + 1]
        s[S_LP + i] = c * a - sn * b
        s[S_LP + i + 1] = sn * a + c * b


def _norm_dip(s, mx, my, mz):
    """Norm and dip angle of a body-frame field in the world frame."""
    mx, my, mz = rotate(s[S_Q], s[S_Q + 1], s[S_Q + 2], s[S_Q + 3], mx, my, mz)
    h = math.sqrt(mx * mx + my * my)
    return math.sqrt(h * h + mz * mz), math.atan2(mz, h)


def _calibrate(s, mx, my, mz, dt):
    """Teach the calibration this field; return the field the heading logic uses."""
    s[S_CAL_WAIT] += dt
    if s[S_CAL_WAIT] < s[P_CAL_PERIOD]:
        return mc_apply(s, MC0, mx, my, mz)  # learn at most at mag_cal_rate
    ready = s[MC0 + MC_READY] != 0.0
    applied = s[MC0 + MC_APPLIED] != 0.0
    allow = True
    has_ref = s[S_HAS_REF] != 0.0
    if has_ref and ready:
        # A field the norm/dip test rejects does not teach.
        cx, cy, cz = mc_apply(s, MC0, mx, my, mz)
        norm, dip = _norm_dip(s, cx, cy, cz)
        ref_n, ref_d = s[S_REF], s[S_REF + 1]
        disturbed = ((abs(norm - ref_n) > s[P_MAG_NORM_TH] * ref_n)
                     or (abs(dip - ref_d) > s[P_MAG_DIP_TH]))
        allow = not disturbed
    w, x, y, z = s[S_Q], s[S_Q + 1], s[S_Q + 2], s[S_Q + 3]
    n2 = w * w + x * x + y * y + z * z
    mc_learn(s, MC0, mx, my, mz, s[S_CAL_TURN], s[S_CAL_TURN + 1], s[S_CAL_TURN + 2],
             s[S_CAL_TURN + 3], s[S_CAL_WAIT], s[S_CAL_RATE], s[S_CAL_RATE + 1],
             s[S_CAL_RATE + 2], 1.0, 2.0 * (x * z - w * y) / n2, 2.0 * (y * z + w * x) / n2,
             (w * w - x * x - y * y + z * z) / n2, 1.0 if allow else 0.0)
    s[S_CAL_TURN] = 1.0
    for i in range(1, 4):
        s[S_CAL_TURN + i] = 0.0
    s[S_CAL_WAIT] = 0.0
    # A learned calibration applied: the heading is set once from the
    # calibrated field as the calibration tracks it (its noise averaged
    # over many fields); then it follows the calibrated fields.
    switched = s[MC0 + MC_APPLIED] != 0.0 and (not applied or s[S_CAL_LOADED] != 0.0)
    s[S_CAL_LOADED] = 0.0
    if switched and has_ref:
        fx, fy, fz = mc_field(s, MC0)
        hx, hy, hz = rotate(w, x, y, z, fx, fy, fz)
        half = 0.5 * math.atan2(hx, hy)
        _turn_heading(s, math.cos(half), math.sin(half))
        # No initial averaging: the refinement's gain follows.
        s[S_MAG_USED] = math.inf
        s[S_CAL_SINCE] = 0.0
        # The references become the calibrated field's norm and dip.
        h = math.sqrt(hx * hx + hy * hy)
        s[S_REF] = math.sqrt(h * h + hz * hz)
        s[S_REF + 1] = math.atan2(hz, h)
        s[S_CAND] = s[S_REF]
        s[S_CAND + 1] = s[S_REF + 1]
        s[S_CAND_TIME] = 0.0
    return mc_apply(s, MC0, mx, my, mz)


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
