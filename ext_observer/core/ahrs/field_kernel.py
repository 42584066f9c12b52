"""
The field step: the heading corrected from the magnetometer, disturbed fields rejected.

Functions on the estimator's flat state (:mod:`~ext_observer.core.ahrs.ahrs_layout`),
in the part of Python numba compiles, as :mod:`~ext_observer.core.ahrs.ahrs_kernel`,
whose sample step calls :func:`ahrs_update_mag` for each field. The field is
judged by its norm and dip against references that follow it (VQF's
magnetic disturbance rejection, Laidig & Seel 2023), taught to the
magnetometer calibration (:func:`field_calibrate`) and turns the heading
about the world vertical. The maths: docs/raw_imu.md ("The estimator, step
by step"). Quaternions ``(w, x, y, z)``, sensor → ENU.
"""

import math

from .ahrs_filters import gain, rotate, rotation_matrix
from .ahrs_layout import (C_BIAS_R, C_K_MAG, C_K_REF, C_MAG_DT, MC0, P_CAL_PERIOD, P_HAS_CAL,
                          P_MAG_DIP_TH, P_MAG_NEW_GYR, P_MAG_NEW_TIME, P_MAG_NORM_TH,
                          P_MOTION_BIAS, P_TAU_ACC, P_TAU_MAG, P_TAU_MAG_REF, P_USE_MAG,
                          S_CAL_LOADED, S_CAL_MOVED, S_CAL_RATE, S_CAL_SINCE, S_CAL_TURN,
                          S_CAL_WAIT, S_CAND, S_CAND_TIME, S_HAS_REF, S_LP, S_MAG_DIST,
                          S_MAG_USED, S_Q, S_REF, S_REF_AGE, S_REF_REST, S_REJECTED, S_REST,
                          S_REST_GYR, S_RZLP, S_START, S_WAIT_N, S_WAIT_TURN,
                          S_DOUBT_GAIN, S_FIELD_CLIPPED, S_HEAD_DOUBT, S_TILT_DOUBT,
                          P_TAU_ACC_GAIN)
from .bias_kernel import bias_measure
from .hole_kernel import forget_wait
from .magcal_kernel import MC_APPLIED, MC_READY, mc_apply, mc_field, mc_learn
from .small_matrix import vec3_at

# After a calibration is applied, the heading's time constant is this share
# of the time since, and at least this (s), until it reaches tau_mag.
_REFINE_SHARE = 0.5
_REFINE_SHORTEST = 1.0
# s: a field rejected as disturbed for longer than this is the field (VQF's
# maximum rejection time, Laidig & Seel 2023): the references follow it.
_MAX_REJECTION = 60.0
# A short undisturbed stretch takes back this many times its length of the
# rejection time (VQF's magnetic rejection factor); a field off a young
# candidate takes back as much of the candidate's time.
MAG_REJECTION_FACTOR = 2.0
# The heading's corrections teach the bias once the inclination's low-pass has
# settled from a start: this many tau_acc after it (as the accelerometer's).
_FIELD_SETTLED = 2.0
# rad·√s: the noise density of a field's heading in motion, undisturbed (a
# field's variance is its square over the field's interval).
FIELD_HEADING_NOISE = 0.02
# rad: the error of a field's heading that does not average out over fields
# (a bent field that passes the norm and dip tests, the calibration's error).
FIELD_HEADING_BIAS = 0.05
# s: how long a field's error that does not average out keeps its value (its
# variance counts once per this time, not once per field).
FIELD_CORRELATION = 1.0
# rad²: a heading this unsure is lost; the fields' running mean takes it again.
HEADING_LOST = math.radians(20.0) ** 2
# σ: a field whose heading is further from the estimate than this many of
# the doubt's and its own does not correct it (a disturbance).
FIELD_GATE = 3.0
# Where the Butterworth's two states (x, y, z each) start in S_LP.
LP_STATES = (0, 3)


def ahrs_mag_coefficients(s, dt):
    """The heading's and the field references' gains for the field interval ``dt``."""
    s[C_MAG_DT] = dt
    s[C_K_MAG] = gain(s[P_TAU_MAG], dt)
    s[C_K_REF] = gain(s[P_TAU_MAG_REF], dt)


def ahrs_update_mag(s, mx, my, mz, dt):
    """Correct the heading from the magnetometer (interval ``dt``), rejecting disturbed fields."""
    if dt != s[C_MAG_DT]:
        ahrs_mag_coefficients(s, dt)
    has_cal = s[P_HAS_CAL] != 0.0
    if has_cal:
        mx, my, mz = field_calibrate(s, mx, my, mz, dt)
    norm, dip, psi, valid = _field_angles(s, mx, my, mz)
    if s[S_HAS_REF] == 0.0:
        _first_references(s, norm, dip)
    disturbed = _off_references(s, norm, dip)
    _follow_candidate(s, norm, dip, dt)
    disturbed = _reject_or_accept(s, disturbed, dt)
    use = valid and not disturbed and s[P_USE_MAG] != 0.0
    _follow_references(s, norm, dip, use, dt)
    s[S_MAG_DIST] = 1.0 if disturbed else 0.0
    if has_cal:
        use, psi = _calibration_wait(s, psi, use)
    kap = _heading_gain(s, use, has_cal, dt)
    s[S_DOUBT_GAIN] = 0.0
    if s[S_HEAD_DOUBT] != 0.0 and valid and s[P_USE_MAG] != 0.0:
        kap = _doubt_gain(s, kap, norm, dip, psi, dt)
    # y = R_z(ψ) ⊗ q̂; q̂ ← (1 − κ) q̂ + κ y, r = (1 − κ + κ cos(ψ/2), 0, 0, κ sin(ψ/2)).
    half = 0.5 * psi
    rw, rz = 1.0 - kap + kap * math.cos(half), kap * math.sin(half)
    _turn_heading(s, rw, rz)
    if s[P_MOTION_BIAS] != 0.0:
        _heading_bias(s, kap, rw, rz, dt)


# --- the field in the world frame, and its references ------------------------------

def _field_angles(s, mx, my, mz):
    """The body field in the estimate's world frame: ``(norm, dip, heading ψ, valid)``."""
    mx, my, mz = rotate(s[S_Q], s[S_Q + 1], s[S_Q + 2], s[S_Q + 3], mx, my, mz)
    h = math.sqrt(mx * mx + my * my)
    norm = math.sqrt(h * h + mz * mz)
    return norm, math.atan2(mz, h), math.atan2(mx, my), (h > 0.0) and (norm > 0.0)


def _first_references(s, norm, dip):
    """The first field: the references and the candidate are its norm and dip."""
    s[S_REF] = norm
    s[S_REF + 1] = dip
    s[S_CAND] = norm
    s[S_CAND + 1] = dip
    s[S_HAS_REF] = 1.0
    s[S_REF_AGE] = 0.0
    s[S_REF_REST] = 0.0


def _off_references(s, norm, dip):
    """Whether a field's norm or dip is off the references (disturbed)."""
    ref_n = s[S_REF]
    return (abs(norm - ref_n) > s[P_MAG_NORM_TH] * ref_n) or (abs(dip - s[S_REF + 1])
                                                               > s[P_MAG_DIP_TH])


def _follow_candidate(s, norm, dip, dt):
    """
    A new field: its candidate norm and dip, and for how long the body has turned with it.

    VQF's candidate (Laidig & Seel 2023): its time counts whether or not the
    references reject the field. A field off it starts it over; while the
    references are young (fewer than ``mag_new_time`` s of fields, none at
    rest) it only takes back :data:`MAG_REJECTION_FACTOR` times its length,
    so that a moving body's spread does not keep one sample's references.
    """
    cand_n, cand_d = s[S_CAND], s[S_CAND + 1]
    th_n, th_d = s[P_MAG_NORM_TH], s[P_MAG_DIP_TH]
    consistent = (abs(norm - cand_n) < th_n * cand_n) and (abs(dip - cand_d) < th_d)
    gx, gy, gz = s[S_REST_GYR], s[S_REST_GYR + 1], s[S_REST_GYR + 2]
    turning = gx * gx + gy * gy + gz * gz > s[P_MAG_NEW_GYR] ** 2
    if consistent:
        if turning:
            s[S_CAND_TIME] += dt
    elif s[S_REF_REST] == 0.0 and s[S_REF_AGE] < s[P_MAG_NEW_TIME]:
        s[S_CAND_TIME] = max(s[S_CAND_TIME] - MAG_REJECTION_FACTOR * dt, 0.0)
    else:
        s[S_CAND_TIME] = 0.0
    kr = s[C_K_REF]
    if consistent:
        # c ← c + k_ref (m − c), norm and dip
        s[S_CAND] = cand_n + kr * (norm - cand_n)
        s[S_CAND + 1] = cand_d + kr * (dip - cand_d)
    elif s[S_CAND_TIME] == 0.0:
        s[S_CAND] = norm
        s[S_CAND + 1] = dip


def _reject_or_accept(s, disturbed, dt):
    """
    Count a disturbed field's rejection; accept the candidate as the field: still disturbed?

    A new field is accepted once it has lasted ``mag_new_time``, or longer than
    fields have confirmed the references (those of a body that starts beside
    a magnet are not trusted longer than the true field has been seen), or
    after :data:`_MAX_REJECTION` s of rejection.
    """
    rejected = s[S_REJECTED] + dt if disturbed else max(s[S_REJECTED]
                                                        - MAG_REJECTION_FACTOR * dt, 0.0)
    s[S_REJECTED] = rejected
    accept = disturbed and (s[S_CAND_TIME] >= min(s[P_MAG_NEW_TIME], s[S_REF_AGE])
                            or rejected >= _MAX_REJECTION)
    if not accept:
        return disturbed
    s[S_REJECTED] = 0.0
    s[S_REF] = s[S_CAND]
    s[S_REF + 1] = s[S_CAND + 1]
    if s[S_REF_AGE] < s[P_MAG_NEW_TIME]:
        # The heading followed disturbed fields: its running mean starts again.
        s[S_MAG_USED] = 0.0
        forget_wait(s)
    s[S_REF_AGE] = s[S_CAND_TIME]
    s[S_REF_REST] = 0.0
    return False


def _follow_references(s, norm, dip, use, dt):
    """A field the heading may ``use`` confirms the references, and they follow it."""
    if use:
        s[S_REF_AGE] += dt
        if s[S_REST] != 0.0:
            s[S_REF_REST] = 1.0
        kr = s[C_K_REF]
        ref_n, ref_d = s[S_REF], s[S_REF + 1]
        # r ← r + k_ref (m − r), norm and dip
        s[S_REF] = ref_n + kr * (norm - ref_n)
        s[S_REF + 1] = ref_d + kr * (dip - ref_d)


# --- the heading's correction ----------------------------------------------------------

def _waits(s):
    """Whether the heading waits for the calibration (the body has moved, none is ready)."""
    return s[MC0 + MC_READY] == 0.0 and s[S_CAL_MOVED] != 0.0 and s[S_MAG_USED] != 0.0


def _calibration_wait(s, psi, use):
    """
    Where the heading waits for the calibration: ``(use, ψ)`` after the wait.

    Before the body has first moved the heading is the field's as given,
    averaged (the start), as is the first field after its running mean
    started over; once the calibration is ready, a wait whose calibration
    found the field right as given counts as if the heading had used it.
    """
    if _waits(s):
        if use:
            _wait(s, psi)
        return False, psi
    if s[S_WAIT_N] != 0.0:
        if s[MC0 + MC_APPLIED] == 0.0:
            half = 0.5 * s[S_WAIT_TURN]
            _turn_heading(s, math.cos(half), math.sin(half))
            d = psi - s[S_WAIT_TURN]
            psi = math.atan2(math.sin(d), math.cos(d))
            s[S_MAG_USED] += s[S_WAIT_N]
        forget_wait(s)
    return use, psi


def _heading_gain(s, use, has_cal, dt):
    """
    The heading's gain κ for this field (0 where unused); counts the fields used.

    A running mean of the first fields, then ``k_mag``; with a calibration
    applied ``t`` s ago, at least that of the time constant ``t/2`` (at
    least :data:`_REFINE_SHORTEST`) while the calibration still improves.
    """
    used = s[S_MAG_USED] + (1.0 if use else 0.0)
    s[S_MAG_USED] = used
    k_mag = s[C_K_MAG]
    if not has_cal:
        # κ = max(k_mag, 1/n)
        return max(k_mag, 1.0 / max(used, 1.0)) if use else 0.0
    since = s[S_CAL_SINCE] + dt
    s[S_CAL_SINCE] = since
    # κ = max(k_mag, 1/n, 1 − exp(−dt / max(t_min, t/2)))
    follow = 1.0 - math.exp(-dt / max(_REFINE_SHORTEST, _REFINE_SHARE * since))
    return max(max(k_mag, 1.0 / max(used, 1.0)), follow) if use else 0.0


def field_forget(s):
    """A new estimate: nothing lost by the gyro yet, the calibration not waiting."""
    s[S_HEAD_DOUBT] = 0.0
    s[S_TILT_DOUBT] = 0.0
    s[S_FIELD_CLIPPED] = 0.0


def field_clipped(s, var):
    """A clipped gyro sample of variance ``var`` (rad² per axis): a doubt, and no calibration."""
    s[S_FIELD_CLIPPED] = 1.0
    field_doubt(s, var)


def field_doubt(s, var):
    """
    The gyro step lost ``var`` rad² per axis (a clipped sample, a hole): the field's to give back.

    Past :data:`HEADING_LOST` the heading is taken afresh from the running
    mean of the next fields, as at the start.
    """
    if s[P_USE_MAG] == 0.0:
        return
    p = s[S_HEAD_DOUBT] + var
    if p < HEADING_LOST:
        s[S_HEAD_DOUBT] = p
        s[S_TILT_DOUBT] += var
    else:
        s[S_HEAD_DOUBT] = 0.0
        s[S_TILT_DOUBT] = 0.0
        s[S_MAG_USED] = 0.0


def _doubt_gain(s, kap, norm, dip, psi, dt):
    """
    The heading gain while the gyro's losses are not corrected: at least the Kalman gain.

    ``P`` (``S_HEAD_DOUBT``) the heading variance the gyro lost, ``r`` the
    field heading's: its noise; the tilt error the gyro lost alike, which
    turns a field's heading by ``tan(dip)`` times it until the accelerometer
    has corrected it (``T``, forgotten with ``tau_acc``); and the field's
    deviation from the references as the size of a disturbance, over the
    horizontal share ``cos(dip)``. So a field whose dip the turned estimate
    shows off the references still counts (it is not locked out), by that
    size; a field of another norm is disturbed whatever the attitude. While
    the heading waits for the calibration, the field as given counts too
    (the wait starts again from it). Once ``P`` no longer moves the gain
    above the usual one, the usual path resumes.
    """
    tau = s[P_TAU_ACC] + s[P_TAU_ACC_GAIN]
    # T ← T exp(−2 dt / τ): the inclination's correction forgets the tilt error
    tilt = s[S_TILT_DOUBT] * math.exp(-2.0 * dt / tau)
    s[S_TILT_DOUBT] = tilt
    ref_n, ref_d = s[S_REF], s[S_REF + 1]
    dn = (norm - ref_n) / ref_n
    if abs(dn) > s[P_MAG_NORM_TH]:
        return kap
    c = math.cos(ref_d)
    t = math.tan(ref_d)
    dd = dip - ref_d
    # r_c = σ_b² + T tan²(dip) + (δn² + δdip²) / cos²(dip): what fields do not average out
    rc = FIELD_HEADING_BIAS * FIELD_HEADING_BIAS + tilt * t * t + (dn * dn + dd * dd) / (c * c)
    p = s[S_HEAD_DOUBT]
    if psi * psi > FIELD_GATE * FIELD_GATE * (p + rc):
        return kap  # the field's heading ψ is no heading the doubt allows
    r0 = FIELD_HEADING_NOISE * FIELD_HEADING_NOISE / dt
    # r = σ_f² / dt + r_c τ_c / dt: the fields of one correlation time share r_c
    r = r0 + rc * FIELD_CORRELATION / dt
    # κ = max(κ_usual, P / (P + r)); P ← (1 − κ)² P + κ² r
    k = max(kap, p / (p + r))
    p = (1.0 - k) * (1.0 - k) * p + k * k * r
    k_mag = s[C_K_MAG]
    if p * (1.0 - k_mag) <= r * k_mag:  # P / (P + r) ≤ k_mag: the usual gain again
        p = 0.0
        s[S_TILT_DOUBT] = 0.0
    s[S_HEAD_DOUBT] = p
    if k > kap:
        forget_wait(s)
        s[S_DOUBT_GAIN] = k
    return k


def _heading_bias(s, kap, rw, rz, dt):
    """
    The heading correction measures the bias: its rate follows the drift ``(R β)_z``.

    Through a low-pass of tau_mag (R's z row low-passed alike); only the steady
    gain's corrections teach, not at rest nor in a start, trusted
    ``tau_mag / tau_acc`` times less than the inclination's (a field is
    disturbed more often and longer than gravity's direction).
    """
    k_mag = s[C_K_MAG]
    r = rotation_matrix(s)
    for j in range(3):
        # z̄ ← z̄ + k_mag (R_z − z̄)
        s[S_RZLP + j] += k_mag * (r[6 + j] - s[S_RZLP + j])
    if (kap == k_mag and s[S_MAG_USED] * k_mag > 1.0 and s[S_REST] == 0.0
            and s[S_START] >= _FIELD_SETTLED * s[P_TAU_ACC]):
        # rate = −2 r_z / (r_w dt), its noise r_bias τ_mag / (τ_acc dt)
        bias_measure(s, s[S_RZLP], s[S_RZLP + 1], s[S_RZLP + 2], -2.0 * rz / (rw * dt),
                     s[C_BIAS_R] * s[P_TAU_MAG] / (s[P_TAU_ACC] * dt))


def _wait(s, psi):
    """
    A field while the heading waits for the calibration: what it would have done.

    Were the calibration to find the field right as given, the heading would
    have followed the field's heading ``psi`` (rad, world frame) with its usual
    gain; the turn is about the world vertical, which commutes with the gyro's
    body-frame increments in between.
    """
    n = s[S_MAG_USED] + s[S_WAIT_N] + 1.0
    s[S_WAIT_N] += 1.0
    kap = max(s[C_K_MAG], 1.0 / n)
    d = psi - s[S_WAIT_TURN]
    # turn ← turn + κ wrap(ψ − turn)
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
    for i in LP_STATES:
        a, b = s[S_LP + i], s[S_LP + i + 1]
        s[S_LP + i] = c * a - sn * b
        s[S_LP + i + 1] = sn * a + c * b


# --- the magnetometer calibration --------------------------------------------------------

def field_calibrate(s, mx, my, mz, dt):
    """Teach the calibration this field (at most every ``cal_period``); the field to use."""
    s[S_CAL_WAIT] += dt
    if _after_clip(s) or s[S_CAL_WAIT] < s[P_CAL_PERIOD]:
        return mc_apply(s, MC0, mx, my, mz)  # learn at most at mag_cal_rate
    applied = s[MC0 + MC_APPLIED] != 0.0
    allow = True
    has_ref = s[S_HAS_REF] != 0.0
    if has_ref and s[MC0 + MC_READY] != 0.0:
        # A field the norm/dip test rejects does not teach.
        cx, cy, cz = mc_apply(s, MC0, mx, my, mz)
        norm, dip, _, _ = _field_angles(s, cx, cy, cz)
        allow = not _off_references(s, norm, dip)
    w, x, y, z = s[S_Q], s[S_Q + 1], s[S_Q + 2], s[S_Q + 3]
    n2 = w * w + x * x + y * y + z * z
    # The world's vertical in the body frame: R(q̂)ᵀ e_z / |q̂|².
    up = (2.0 * (x * z - w * y) / n2, 2.0 * (y * z + w * x) / n2,
          (w * w - x * x - y * y + z * z) / n2)
    turn = (s[S_CAL_TURN], s[S_CAL_TURN + 1], s[S_CAL_TURN + 2], s[S_CAL_TURN + 3])
    mc_learn(s, MC0, (mx, my, mz), turn, s[S_CAL_WAIT], vec3_at(s, S_CAL_RATE), 1.0, up,
             1.0 if allow else 0.0)
    s[S_CAL_TURN] = 1.0
    for i in range(1, 4):
        s[S_CAL_TURN + i] = 0.0
    s[S_CAL_WAIT] = 0.0
    switched = s[MC0 + MC_APPLIED] != 0.0 and (not applied or s[S_CAL_LOADED] != 0.0)
    s[S_CAL_LOADED] = 0.0
    if switched and has_ref:
        _calibration_applied(s, w, x, y, z)
    return mc_apply(s, MC0, mx, my, mz)


def _after_clip(s):
    """Whether the gyro clipped since the latest field: the calibration learns nothing from it."""
    if s[S_FIELD_CLIPPED] == 0.0:
        return False
    s[S_FIELD_CLIPPED] = 0.0
    return True


def _calibration_applied(s, w, x, y, z):
    """
    A learned calibration applied: the heading set once from its field, the references its.

    The calibration's field is the noise of many fields averaged; then the
    heading follows the calibrated fields, with the refinement's gain.
    """
    fx, fy, fz = mc_field(s, MC0)
    hx, hy, hz = rotate(w, x, y, z, fx, fy, fz)
    half = 0.5 * math.atan2(hx, hy)
    _turn_heading(s, math.cos(half), math.sin(half))
    s[S_MAG_USED] = math.inf
    s[S_CAL_SINCE] = 0.0
    h = math.sqrt(hx * hx + hy * hy)
    s[S_REF] = math.sqrt(h * h + hz * hz)
    s[S_REF + 1] = math.atan2(hz, h)
    s[S_CAND] = s[S_REF]
    s[S_CAND + 1] = s[S_REF + 1]
    s[S_CAND_TIME] = 0.0
