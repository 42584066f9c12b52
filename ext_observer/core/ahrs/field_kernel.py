"""
The field step: the heading corrected from the magnetometer, disturbed fields rejected.

Functions on the estimator's state (``FIELD`` and ``CAL_FEED``, declared here),
in the part of Python numba compiles, as :mod:`~ext_observer.core.ahrs.ahrs_kernel`,
whose sample step calls :func:`ahrs_update_mag` for each field. The field is
judged by its norm and dip against references that follow it (VQF's
magnetic disturbance rejection, Laidig & Seel 2023), taught to the
magnetometer calibration (:func:`field_calibrate`) and turns the heading
about the world vertical; while a clipped gyro or a hole leaves the
inclination in doubt, the field corrects the tilt too, as far as the doubts
say (:func:`_field_tilt`, :func:`_sideways_tilt`). The maths: docs/raw_imu.md
("The estimator, step by step"). Quaternions ``(w, x, y, z)``, sensor → ENU.
"""

import math

from .ahrs_filters import (UNIFORM_ANGLE_VARIANCE, gain, quat_multiply, rotate, rotation_matrix,
                           vertical_in_body)
from .bias_kernel import bias_measure
from .field_references import (FIELD_GATE, field_angles, first_references, follow_candidate,
                               follow_references, off_references, reject_or_accept)
from .hole_kernel import HOLE_CALIBRATION, calibration_restart, forget_wait, mean_sigma
from .magcal_kernel import mc_apply, mc_as_given, mc_field, mc_learn
from .magcal_layout import CAL_REFUSED_SHARE, CAL_TURNING2
from .small_matrix import vec3_at
from .record import Group

FIELD = Group('field', 'The heading from the field, its references and rejection', [
    ('mag_dist', '1', 'the latest field was rejected as disturbed'),
    ('has_ref', '1', 'the field references (norm, dip) exist'),
    ('ref', 'field unit, rad', "the field's reference norm and dip", 2),
    ('cand', 'field unit, rad', 'norm and dip of a new field', 2),
    ('cand_time', 's', 'the new field has lasted (while the body turned)'),
    ('mag_used', '1', 'the latest field corrected the heading'),
    ('ref_age', 's', 'of fields that confirmed the field references'),
    ('rejected', 's', 'the field has been rejected as disturbed without a break'),
    ('wait_turn', 'rad', 'the turn the fields would have given the heading while it waited '
     'for the calibration, had they been used as given'),
    ('wait_n', '', 'those fields, counted'),
    ('ref_rest', '1', 'fields at rest have confirmed the field references'),
    ('head_doubt', 'rad²', 'heading variance no field has corrected yet'),
    ('tilt_doubt', 'rad²', 'its share of tilt, as the accelerometer forgets it'),
    ('field_clipped', '1', 'the gyro clipped since the latest field'),
    ('doubt_gain', '', "the latest field's gain where the doubt raised it, else 0"),
])
CAL_FEED = Group('cal_feed', 'What the field step tells the calibration, and when', [
    ('turn', '', 'the body rotation since the field last learned from (quaternion)', 4),
    ('rate', 'rad/s', 'the latest angular rate, bias removed', 3),
    ('wait', 's', 'since the calibration last learned'),
    ('moved', '1', 'the body has turned since the start'),
    ('since', 's', 'since a calibration was applied (inf: never)'),
    ('loaded', '1', 'a loaded calibration waits to set the heading and references'),
    ('as_given', '1', 'share of the fields refused calibrated that fit as given, while turning'),
])

# After a calibration is applied, the heading's time constant is this share
# of the time since, and at least this (s), until it reaches tau_mag.
_REFINE_SHARE = 0.5
_REFINE_SHORTEST = 1.0
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
# The heading's loss along a clipped stretch, per sample and axis, as a share
# of the range's rotation: the rate beyond the range, uniform between none and
# the range itself, has the RMS range / √3.
CLIP_HEADING_SHARE = 1.0 / math.sqrt(3.0)
# Where the Butterworth's two states (x, y, z each) start in S_LP.
LP_STATES = (0, 3)


def ahrs_mag_coefficients(s, dt):
    """The heading's and the field references' gains for the field interval ``dt``."""
    s.coef.mag_dt = dt
    s.coef.k_mag = gain(s.par.tau_mag, dt)
    s.coef.k_ref = gain(s.par.tau_mag_ref, dt)


def ahrs_update_mag(s, mx, my, mz, dt):
    """Correct the heading from the magnetometer (interval ``dt``), rejecting disturbed fields."""
    if dt != s.coef.mag_dt:
        ahrs_mag_coefficients(s, dt)
    has_cal = s.par.has_cal != 0.0
    if has_cal:
        mx, my, mz = field_calibrate(s, mx, my, mz, dt)
    norm, dip, psi, valid = field_angles(s, mx, my, mz)
    if s.field.has_ref == 0.0:
        first_references(s, norm, dip)
    tilt = mean_sigma(s)  # the inclination's doubt
    disturbed = off_references(s, norm, dip, tilt)
    follow_candidate(s, norm, dip, dt)
    disturbed = reject_or_accept(s, disturbed, dt)
    use = valid and not disturbed and s.par.use_mag != 0.0
    follow_references(s, norm, dip, use, dt)
    s.field.mag_dist = 1.0 if disturbed else 0.0
    if use and tilt != 0.0:
        _field_tilt(s, tilt, dip, psi, dt)
    if has_cal:
        use, psi = _calibration_wait(s, psi, use)
    kap = _heading_gain(s, use, has_cal, dt)
    s.field.doubt_gain = 0.0
    if s.field.head_doubt != 0.0 and valid and s.par.use_mag != 0.0:
        kap = _doubt_gain(s, kap, norm, dip, psi, dt)
    if tilt != 0.0 and kap > 0.0 and valid:
        # A tilt in doubt takes its share of the field's sideways error.
        kap = _sideways_tilt(s, tilt, kap, psi)
    # y = R_z(ψ) ⊗ q̂; q̂ ← (1 − κ) q̂ + κ y, r = (1 − κ + κ cos(ψ/2), 0, 0, κ sin(ψ/2)).
    half = 0.5 * psi
    rw, rz = 1.0 - kap + kap * math.cos(half), kap * math.sin(half)
    _turn_heading(s, rw, rz)
    if s.par.motion_bias != 0.0:
        _heading_bias(s, kap, rw, rz, dt)


# --- the heading's correction ----------------------------------------------------------

def _waits(s):
    """Whether the heading waits for the calibration (the body has moved, none is ready)."""
    return s.cal.ready == 0.0 and s.cal_feed.moved != 0.0 and s.field.mag_used != 0.0


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
    if s.field.wait_n != 0.0:
        if s.cal.applied == 0.0:
            half = 0.5 * s.field.wait_turn
            _turn_heading(s, math.cos(half), math.sin(half))
            d = psi - s.field.wait_turn
            psi = math.atan2(math.sin(d), math.cos(d))
            s.field.mag_used += s.field.wait_n
        forget_wait(s)
    return use, psi


def _heading_gain(s, use, has_cal, dt):
    """
    The heading's gain κ for this field (0 where unused); counts the fields used.

    A running mean of the first fields, then ``k_mag``; with a calibration
    applied ``t`` s ago, at least that of the time constant ``t/2`` (at
    least :data:`_REFINE_SHORTEST`) while the calibration still improves.
    """
    used = s.field.mag_used + (1.0 if use else 0.0)
    s.field.mag_used = used
    k_mag = s.coef.k_mag
    if not has_cal:
        # κ = max(k_mag, 1/n)
        return max(k_mag, 1.0 / max(used, 1.0)) if use else 0.0
    since = s.cal_feed.since + dt
    s.cal_feed.since = since
    # κ = max(k_mag, 1/n, 1 − exp(−dt / max(t_min, t/2)))
    follow = 1.0 - math.exp(-dt / max(_REFINE_SHORTEST, _REFINE_SHARE * since))
    return max(max(k_mag, 1.0 / max(used, 1.0)), follow) if use else 0.0


def field_reset(s):
    """A new estimate: no field judged yet, no references (their values stay), nothing waiting."""
    s.field.mag_dist = 0.0
    s.field.has_ref = 0.0
    s.field.cand_time = 0.0
    s.field.mag_used = 0.0
    s.field.rejected = 0.0
    forget_wait(s)
    field_forget(s)


def cal_feed_reset(s):
    """The calibration follows the field afresh (what it learned stays); none turned or applied."""
    calibration_restart(s)
    if s.par.has_cal != 0.0:
        for i in range(3):
            s.cal_feed.rate[i] = 0.0
        s.cal_feed.moved = 0.0  # the body has not turned yet
        s.cal_feed.since = math.inf  # time since a calibration was applied
        s.cal_feed.loaded = 0.0
        s.cal_feed.as_given = 0.0


def field_forget(s):
    """A new estimate: nothing lost by the gyro yet, the calibration not waiting."""
    s.field.head_doubt = 0.0
    s.field.tilt_doubt = 0.0
    s.field.field_clipped = 0.0


def field_clipped(s, var):
    """
    A clipped gyro sample of variance ``var`` (rad² per axis): a doubt, and no calibration.

    The rate beyond the range stays beyond it along a clipped stretch, so the
    heading's losses add up as the inclination's do (``clip_after``): the
    doubt's σ grows by :data:`CLIP_HEADING_SHARE` of the σ of the part about
    the world's vertical (``gyro.clipped_vertical``; a body clipping about a
    horizontal axis loses its tilt, not its heading), the variance by the
    difference of the squares. The share of tilt that weighs the fields
    grows by that of all of it, as before: the vertical is the estimate's,
    and a field right after a clip about it is weighed by the tilt the
    estimate may have lost (with the horizontal part only, a field bent in
    heading right after a clip about the vertical took the heading).
    """
    s.field.field_clipped = 1.0
    up = s.gyro.clipped_vertical
    p, t = s.field.head_doubt, s.field.tilt_doubt
    # σ ← σ + c √var: the variance grows by (σ + c √var)² − σ²
    head = math.sqrt(p) + CLIP_HEADING_SHARE * math.sqrt(up)
    tilt = math.sqrt(t) + CLIP_HEADING_SHARE * math.sqrt(var)
    _add_doubt(s, head * head - p, tilt * tilt - t)


def field_doubt(s, var):
    """
    The gyro step lost ``var`` rad² per axis (a hole, unbridged samples): the field's to give back.

    Past :data:`HEADING_LOST` the heading is taken afresh from the running
    mean of the next fields, as at the start.
    """
    _add_doubt(s, var, var)


def _add_doubt(s, head, tilt):
    """The heading's doubt gains ``head`` rad², its share of tilt ``tilt``; lost past HEADING_LOST."""
    if s.par.use_mag == 0.0:
        return
    p = s.field.head_doubt + head
    if p < HEADING_LOST:
        s.field.head_doubt = p
        s.field.tilt_doubt += tilt
    else:
        s.field.head_doubt = 0.0
        s.field.tilt_doubt = 0.0
        s.field.mag_used = 0.0


def field_back(s, var):
    """
    A field back after a loss: the gyro alone carried the heading, which gained ``var`` rad².

    What was learned before the loss still holds (the body carries its
    magnet and its calibration with it): the references and the calibration
    stay, and the returning fields are judged against them. The heading's
    doubt takes ``var`` (the tilt's none: the accelerometer went on
    correcting it), so the fields back correct the heading with the Kalman
    gain of that doubt (:func:`_doubt_gain`); past :data:`HEADING_LOST` the
    heading is taken afresh from their running mean, as after a hole. The
    calibration follows the field afresh, as across a hole whose rotation
    it cannot trust (more than
    :data:`~ext_observer.core.ahrs.hole_kernel.HOLE_CALIBRATION`): what it
    learned stays, the body's turn over the loss is not taught.
    """
    if s.par.use_mag == 0.0 or not var > 0.0:
        return
    if var > HOLE_CALIBRATION:
        calibration_restart(s)
    p = s.field.head_doubt + var
    if p < HEADING_LOST:
        s.field.head_doubt = p
    else:
        s.field.head_doubt = 0.0
        s.field.tilt_doubt = 0.0
        s.field.mag_used = 0.0


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
    above the usual one (and no clipped stretch's recovery
    runs, ``gyro.clip_left``), the usual path resumes.
    """
    tau = s.par.tau_acc + s.par.tau_acc_gain
    # T ← T exp(−2 dt / τ): the inclination's correction forgets the tilt error
    tilt = s.field.tilt_doubt * math.exp(-2.0 * dt / tau)
    s.field.tilt_doubt = tilt
    ref_n, ref_d = s.field.ref[0], s.field.ref[1]
    dn = (norm - ref_n) / ref_n
    if abs(dn) > s.par.mag_norm_th:
        return kap
    c = math.cos(ref_d)
    t = math.tan(ref_d)
    dd = dip - ref_d
    # r_c = σ_b² + T tan²(dip) + (δn² + δdip²) / cos²(dip): what fields do not average out
    rc = FIELD_HEADING_BIAS * FIELD_HEADING_BIAS + tilt * t * t + (dn * dn + dd * dd) / (c * c)
    p = s.field.head_doubt
    if psi * psi > FIELD_GATE * FIELD_GATE * (p + rc):
        return kap  # the field's heading ψ is no heading the doubt allows
    r0 = FIELD_HEADING_NOISE * FIELD_HEADING_NOISE / dt
    # r = σ_f² / dt + r_c τ_c / dt: the fields of one correlation time share r_c
    r = r0 + rc * FIELD_CORRELATION / dt
    # κ = max(κ_usual, P / (P + r)); P ← (1 − κ)² P + κ² r
    k = max(kap, p / (p + r))
    p = (1.0 - k) * (1.0 - k) * p + k * k * r
    k_mag = s.coef.k_mag
    # The doubt ends where an undisturbed field's Kalman gain is the usual
    # one, P / (P + r_u) ≤ k_mag (a field far off the references has a large
    # r and a small gain, and says nothing of whether the doubt is gone),
    # once no clipped stretch is still adding to P (its samples' losses add
    # up: clip_after).
    ru = r0 + FIELD_HEADING_BIAS * FIELD_HEADING_BIAS * FIELD_CORRELATION / dt
    if p * (1.0 - k_mag) <= ru * k_mag and s.gyro.clip_left == 0.0:
        p = 0.0
        s.field.tilt_doubt = 0.0
    s.field.head_doubt = p
    if k > kap:
        forget_wait(s)
        s.field.doubt_gain = k
    return k


def _field_tilt(s, tilt, dip, psi, dt):
    """
    The field's dip corrects the tilt the inclination's doubt leaves (a clipped gyro, a hole).

    A tilt error ``e`` about the horizontal axis across the field (``a``,
    world frame, the field's heading ``ψ`` turned a quarter) turns the
    field's dip by ``e``, whatever the body's acceleration: the field is
    the one measurement of that tilt while the accelerometer is off by the
    body's own motion. The Kalman gain of the inclination's doubt ``tilt``
    (:func:`~ext_observer.core.ahrs.hole_kernel.mean_sigma`), ``P = tilt²``,
    against a field's ``r``: the heading's (as in :func:`_doubt_gain`: its
    noise and the error fields share) times ``cos²(dip)``, for a heading's
    error is the field direction's over the horizontal share. ``P`` stays:
    the field says nothing of the tilt about its own horizontal direction,
    which only the accelerometer corrects (and the doubt is either
    horizontal axis's).
    """
    p = tilt * tilt
    # r = (σ_f² / dt + σ_b² τ_c / dt) cos²(dip): a heading's error is the
    # field direction's over the horizontal share cos(dip), the dip's is the direction's
    c = math.cos(s.field.ref[1])
    r = (FIELD_HEADING_NOISE * FIELD_HEADING_NOISE
         + FIELD_HEADING_BIAS * FIELD_HEADING_BIAS * FIELD_CORRELATION) * c * c / dt
    k = p / (p + r)
    d = dip - s.field.ref[1]
    half = -0.5 * k * d
    # The turn (cos θ/2, a sin θ/2), a = (cos ψ, −sin ψ, 0), turns the dip by θ = −k d
    sn = math.sin(half)
    _tilt_by(s, math.cos(half), sn * math.cos(psi), -sn * math.sin(psi))


def _sideways_tilt(s, tilt, kap, psi):
    """
    A field's sideways error shared by the heading and the tilt about north, as their doubts say.

    A field whose horizontal part lies ``ψ`` off north shows a heading error,
    or a tilt error about the north axis, which leans its vertical part
    sideways: ``h ψ ≈ h e_h − v e_t`` (``h``, ``v`` the field direction's
    horizontal and vertical shares, cos and sin of the dip). The Kalman gains
    of the two doubts share the field's correction ``κ``: the heading's
    ``P_h`` (its doubt and ``FIELD_HEADING_BIAS²``) takes
    ``w = h² P_h / (h² P_h + v² P_t)`` of it, the inclination's
    ``P_t = tilt²`` the rest, a turn about north that removes that share
    of the sideways part. While the fields' running mean sets the heading
    (after a start or a loss: κ above ``k_mag``) ``P_h`` is that of a heading
    known to be nothing better than uniform. Returns the heading's gain ``w κ``.
    """
    ph = s.field.head_doubt + FIELD_HEADING_BIAS * FIELD_HEADING_BIAS
    if s.field.mag_used * s.coef.k_mag < 1.0:
        ph = UNIFORM_ANGLE_VARIANCE
    pt = tilt * tilt
    h, v = math.cos(s.field.ref[1]), math.sin(s.field.ref[1])
    hp, vp = h * h * ph, v * v * pt
    w = hp / (hp + vp)
    if w >= 1.0:
        return kap
    # The sideways part h sin ψ, the vertical v: a turn b about north, tan b = −h sin ψ / v,
    # removes it; the tilt's share (1 − w) κ of it.
    half = 0.5 * (1.0 - w) * kap * math.atan(-h * math.sin(psi) / v)
    # q̂ ← (cos, 0, sin, 0) ⊗ q̂: about the world's north axis
    _tilt_by(s, math.cos(half), 0.0, math.sin(half))
    return w * kap


def _tilt_by(s, rw, rx, ry):
    """
    ``q̂ ← r ⊗ q̂`` for the unit ``r = (rw, rx, ry, 0)`` about a horizontal axis.

    The inclination's filter states follow the rotation, as its own correction's.
    """
    q = s.est.q
    q[0], q[1], q[2], q[3] = quat_multiply(rw, rx, ry, 0.0, q[0], q[1], q[2], q[3])
    for i in LP_STATES:
        s.inc.lp[i], s.inc.lp[i + 1], s.inc.lp[i + 2] = rotate(
            rw, rx, ry, 0.0, s.inc.lp[i], s.inc.lp[i + 1], s.inc.lp[i + 2])


def _heading_bias(s, kap, rw, rz, dt):
    """
    The heading correction measures the bias: its rate follows the drift ``(R β)_z``.

    Through a low-pass of tau_mag (R's z row low-passed alike); only the steady
    gain's corrections teach, not at rest nor in a start, trusted
    ``tau_mag / tau_acc`` times less than the inclination's (a field is
    disturbed more often and longer than gravity's direction).
    """
    k_mag = s.coef.k_mag
    r = rotation_matrix(s)
    for j in range(3):
        # z̄ ← z̄ + k_mag (R_z − z̄)
        s.bias.rz_lp[j] += k_mag * (r[6 + j] - s.bias.rz_lp[j])
    if (kap == k_mag and s.field.mag_used * k_mag > 1.0 and s.rest.detected == 0.0
            and s.inc.start >= _FIELD_SETTLED * s.par.tau_acc):
        # rate = −2 r_z / (r_w dt), its noise r_bias τ_mag / (τ_acc dt)
        bias_measure(s, s.bias.rz_lp[0], s.bias.rz_lp[1], s.bias.rz_lp[2], -2.0 * rz / (rw * dt),
                     s.coef.bias_r * s.par.tau_mag / (s.par.tau_acc * dt))


def _wait(s, psi):
    """
    A field while the heading waits for the calibration: what it would have done.

    Were the calibration to find the field right as given, the heading would
    have followed the field's heading ``psi`` (rad, world frame) with its usual
    gain; the turn is about the world vertical, which commutes with the gyro's
    body-frame increments in between.
    """
    n = s.field.mag_used + s.field.wait_n + 1.0
    s.field.wait_n += 1.0
    kap = max(s.coef.k_mag, 1.0 / n)
    d = psi - s.field.wait_turn
    # turn ← turn + κ wrap(ψ − turn)
    s.field.wait_turn += kap * math.atan2(math.sin(d), math.cos(d))


def _turn_heading(s, rw, rz):
    """``q̂ ← r ⊗ q̂`` for ``r = (rw, 0, 0, rz)`` (not unit), the filter's states with it."""
    w, x, y, z = s.est.q[0], s.est.q[1], s.est.q[2], s.est.q[3]
    s.est.q[0] = rw * w - rz * z
    s.est.q[1] = rw * x - rz * y
    s.est.q[2] = rw * y + rz * x
    s.est.q[3] = rw * z + rz * w
    # The filter's states turn with it about the vertical: (c, s) of 2θ.
    n2 = rw * rw + rz * rz
    c, sn = (rw * rw - rz * rz) / n2, 2.0 * rw * rz / n2
    for i in LP_STATES:
        a, b = s.inc.lp[i], s.inc.lp[i + 1]
        s.inc.lp[i] = c * a - sn * b
        s.inc.lp[i + 1] = sn * a + c * b


# --- the magnetometer calibration --------------------------------------------------------

def field_calibrate(s, mx, my, mz, dt):
    """Teach the calibration this field (at most every ``cal_period``); the field to use."""
    s.cal_feed.wait += dt
    if _after_clip(s) or s.cal_feed.wait < s.par.cal_period:
        return mc_apply(s.cal, mx, my, mz)  # learn at most at mag_cal_rate
    applied = s.cal.applied != 0.0
    allow = True
    has_ref = s.field.has_ref != 0.0
    if has_ref and s.cal.ready != 0.0:
        # A field the norm/dip test rejects does not teach.
        cx, cy, cz = mc_apply(s.cal, mx, my, mz)
        norm, dip, _, _ = field_angles(s, cx, cy, cz)
        allow = not off_references(s, norm, dip, 0.0)
        if applied and _taken_off(s, mx, my, mz, not allow):
            mc_as_given(s.cal)
            allow = True  # the fresh start learns from this field
    up = vertical_in_body(s)
    turn = (s.cal_feed.turn[0], s.cal_feed.turn[1], s.cal_feed.turn[2], s.cal_feed.turn[3])
    mc_learn(s.cal, (mx, my, mz), turn, s.cal_feed.wait, vec3_at(s.cal_feed.rate, 0), 1.0, up,
             1.0 if allow else 0.0)
    s.cal_feed.turn[0] = 1.0
    for i in range(1, 4):
        s.cal_feed.turn[i] = 0.0
    s.cal_feed.wait = 0.0
    switched = s.cal.applied != 0.0 and (not applied or s.cal_feed.loaded != 0.0)
    s.cal_feed.loaded = 0.0
    if switched and has_ref:
        _calibration_applied(s)
    return mc_apply(s.cal, mx, my, mz)


def _taken_off(s, mx, my, mz, refused):
    """
    Whether the fields fit as given where the applied calibration refuses them: its magnet is gone.

    A magnet or payload taken off the body leaves a calibration that
    subtracts an offset no longer there. Its refused share (CAL_REFUSED_TAU)
    tells after some 12 s of turning; the fields as given tell at once. The
    share of the fields learned from while the body turns that the
    calibration refuses and the references take as given, low-passed over
    FIELD_CORRELATION (the fields of one correlation time share their
    error: one bent field is no evidence), beyond CAL_REFUSED_SHARE: the
    calibration starts over from none (``mc_as_given``). A body that keeps
    its magnet does not fit as given, nor a field bent from outside.
    """
    rate = s.cal_feed.rate
    if rate[0] * rate[0] + rate[1] * rate[1] + rate[2] * rate[2] <= CAL_TURNING2:
        return False
    norm, dip, _, _ = field_angles(s, mx, my, mz)
    fits = refused and not off_references(s, norm, dip, 0.0)
    k = 1.0 - math.exp(-s.cal_feed.wait / FIELD_CORRELATION)
    share = s.cal_feed.as_given + k * ((1.0 if fits else 0.0) - s.cal_feed.as_given)
    gone = share > CAL_REFUSED_SHARE
    s.cal_feed.as_given = 0.0 if gone else share
    return gone


def _after_clip(s):
    """Whether the gyro clipped since the latest field: the calibration learns nothing from it."""
    if s.field.field_clipped == 0.0:
        return False
    s.field.field_clipped = 0.0
    return True


def _calibration_applied(s):
    """
    A learned calibration applied: the heading set once from its field, the references its.

    The calibration's field is the noise of many fields averaged; then the
    heading follows the calibrated fields, with the refinement's gain.
    """
    w, x, y, z = s.est.q[0], s.est.q[1], s.est.q[2], s.est.q[3]
    fx, fy, fz = mc_field(s.cal)
    hx, hy, hz = rotate(w, x, y, z, fx, fy, fz)
    half = 0.5 * math.atan2(hx, hy)
    _turn_heading(s, math.cos(half), math.sin(half))
    s.field.mag_used = math.inf
    s.cal_feed.since = 0.0
    h = math.sqrt(hx * hx + hy * hy)
    s.field.ref[0] = math.sqrt(h * h + hz * hz)
    s.field.ref[1] = math.atan2(hz, h)
    s.field.cand[0] = s.field.ref[0]
    s.field.cand[1] = s.field.ref[1]
    s.field.cand_time = 0.0
