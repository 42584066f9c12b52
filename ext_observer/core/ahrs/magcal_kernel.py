"""
The maths of the online magnetometer calibration, as plain functions on the calibrator's record.

:class:`~ext_observer.core.ahrs.magcal.MagCalibrator` is a thin wrapper over
these functions. Each takes one calibrator's state, a record ``cal`` of
:data:`~ext_observer.core.ahrs.magcal_layout.CAL`'s fields (flags are
0.0/1.0), and reads and writes its fields by name. Written in the part of
Python numba compiles, so the same source runs plain on a plain record or
compiled on a structured one (:mod:`~ext_observer.core.ahrs.compiled`),
with no allocation in the hot path. The model, the gate, convergence and
when a calibration is applied: docs/calibration.md ("The filter, in
equations").
"""

import math

from .magcal_filter import mc_predict, mc_start, mc_update
from .magcal_layout import (CAL_D, CAL_HOLD, CAL_HOLD_TURN, CAL_INF, CAL_N,
                            CAL_NIS_EXPECTED, CAL_NY, CAL_REFUSED_SHARE, CAL_REFUSED_TAU,
                            CAL_SHIFT_SAMPLES, CAL_SIGNIFICANT, CAL_TINY, CAL_TURNING2,
                            CAL_WATCH, CAL_WILD, CAL_Z, CAL_ZD, CAL_ZDT, field_with_offset_of,
                            offset_of, soft_iron_of)
from .small_matrix import (col3_at, column3_into, copy_into, cross3, dot3, fill,
                           finite_or_zero, max_of, quad3_at, rows, store3, sub3, vec3_at,
                           vec5_at)


# --- state -------------------------------------------------------------------

def mc_init(cal, enabled, noise, field_rw, soft_iron, delay, heading, deadband, drift):
    """Set the parameters, clear the scratch, then :func:`mc_reset`."""
    cal.enabled = 1.0 if enabled else 0.0
    cal.noise = noise
    cal.field_rw = field_rw
    cal.soft_iron = soft_iron
    cal.delay = delay
    cal.heading = heading
    cal.deadband = deadband
    cal.drift = drift
    fill(cal.ai, 0, 9, 0.0)
    fill(cal.h, 0, 3 * CAL_N, 0.0)
    fill(cal.ah, 0, 3 * CAL_N, 0.0)
    fill(cal.ph, 0, 3 * CAL_N, 0.0)
    fill(cal.s, 0, 9, 0.0)
    fill(cal.si, 0, 9, 0.0)
    fill(cal.k, 0, 3 * CAL_N, 0.0)
    fill(cal.yy, 0, 3 * CAL_NY, 0.0)
    fill(cal.jp, 0, 3 * CAL_ZD, 0.0)
    fill(cal.c, 0, 9, 0.0)
    mc_reset(cal)


def mc_reset(cal):
    """Forget the calibration: learn from the next field on."""
    fill(cal.x, 0, CAL_N, 0.0)
    fill(cal.p, 0, CAL_N * CAL_N, 0.0)
    fill(cal.prior_x, 0, CAL_ZDT, 0.0)
    cal.prior_scale = 0.0
    fill(cal.prior_p, 0, CAL_ZDT * CAL_ZDT, 0.0)
    mc_forget(cal)
    cal.prior_cov = 0.0
    cal.scale = 1.0
    cal.quality = CAL_INF
    cal.stale = 0.0
    cal.learned = 0.0
    cal.nis = CAL_NIS_EXPECTED
    fill(cal.candidate, 0, CAL_ZD, 0.0)
    cal.held = -1.0
    cal.field_scale = 1.0
    cal.fields = 0.0
    cal.used = 0.0
    cal.gated = 0.0
    cal.refused = 0.0
    cal.invalid = 0.0
    cal.resets = 0.0
    fill(cal.seen_y, 0, 3, 0.0)
    fill(cal.seen_up, 0, 3, 0.0)
    cal.seen_has_up = 0.0
    cal.seen_live = 0.0
    cal.assessed = 0.0
    cal.watching = 0.0
    mc_cache(cal)


def mc_forget(cal):
    """
    A fresh start at the next field, nothing learned kept (no prior), not applied.

    The field as given is applied until the learned calibration turns the
    heading by more than the deadband (mean square, rad²).
    """
    cal.fresh = 1.0
    cal.loaded = 0.0
    cal.converged = 0.0
    cal.identity = 1.0
    cal.shift = 0.0
    cal.watched = 0.0
    cal.refused_share = 0.0
    cal.has_prior = 0.0


def mc_restart(cal, refused=0.0):
    """
    Keep what is learned, follow the field afresh from the next sample.

    ``refused``: the share of fields refused while turning that the restart
    starts from (its evidence that the calibration no longer fits,
    :func:`mc_lost`): 0 forgets it; a restart that nothing but the body's
    unknown turn called for (a clipped gyro) keeps it.
    """
    cal.refused_share = refused
    if cal.enabled != 0.0 and cal.fresh == 0.0:
        copy_into(cal.prior_x, rows(0, 1), cal.x, rows(CAL_Z, 1), CAL_ZDT, 1)
        cal.prior_scale = cal.scale
        copy_into(cal.prior_p, rows(0, CAL_ZDT), cal.p, rows((CAL_N + 1) * CAL_Z, CAL_N),
                  CAL_ZDT, CAL_ZDT)
        cal.has_prior = 1.0
        cal.prior_cov = 1.0
    cal.fresh = 1.0


def mc_as_given(cal):
    """
    Start over from no calibration, ready at once: the fields fit as given (a magnet taken off).

    The caller found the fields it refuses calibrated fitting as given: the
    offset the calibration learned is gone (a magnet or payload taken off
    the body). Counted as a reset; learned afresh from the next field, with
    a loaded calibration's prior about none (the lag kept: the sensor's);
    ready at once, so that the heading takes the fields as given without
    waiting for a convergence, and applied once what it learns turns the
    heading by more than the deadband, as any calibration.
    """
    cal.resets += 1.0
    mc_forget(cal)
    if cal.enabled != 0.0:
        copy_into(cal.prior_x, rows(0, 1), cal.x, rows(CAL_Z, 1), CAL_ZDT, 1)
        fill(cal.prior_x, 0, CAL_ZD, 0.0)  # no offset, no soft iron; τ as learned
        cal.prior_scale = 1.0
        cal.has_prior = 1.0
        cal.prior_cov = 0.0  # the loaded calibration's prior spread about it
        cal.converged = 1.0
    mc_cache(cal)


def mc_load_state(cal, x3, x4, x5, x6, x7, x8, x9, x10, x11, scale):
    """
    Start from a saved calibration: ``x[3:]`` and the scale (see ``MagCalibrator.load``).

    Nothing where the calibrator is off.
    """
    if cal.enabled != 0.0:
        p = cal.prior_x
        p[0] = x3
        p[1] = x4
        p[2] = x5
        p[3] = x6
        p[4] = x7
        p[5] = x8
        p[6] = x9
        p[7] = x10
        p[8] = x11
        cal.prior_scale = scale
        # Applied at once, before the next field starts the filter from it.
        copy_into(cal.x, rows(CAL_Z, 1), p, rows(0, 1), CAL_ZDT, 1)
        cal.scale = scale
        cal.has_prior = 1.0
        cal.prior_cov = 0.0
        cal.fresh = 1.0
        cal.refused_share = 0.0
        cal.loaded = 1.0
        cal.identity = 0.0
        cal.converged = 0.0
    mc_cache(cal)


# --- learning ------------------------------------------------------------------

def mc_learn(cal, y, r, dt, w, has_up, u, allow):
    """
    Learn from one field sample; 1.0 if it was used, else 0.0.

    ``y``: the raw field, body frame (a 3-tuple). ``r = (rw, rx, ry, rz)``:
    the body's rotation since the previous sample learned from, previous
    body frame → current one (any nonzero norm). ``dt``: seconds since that
    sample. ``w``: the angular rate now (a 3-tuple, rad/s, bias removed), for
    the lag. ``u``: the world's vertical in the body frame (a unit 3-tuple),
    for the quality, where ``has_up`` (nonzero); without it the error of the
    whole calibrated field counts. ``allow`` false: the caller refuses this
    sample (counted as refused).
    """
    fresh = cal.fresh != 0.0
    norm = math.sqrt(y[0] * y[0] + y[1] * y[1] + y[2] * y[2])
    valid, take = mc_admit(cal, norm, allow)
    valid = valid and not fresh
    if not take:
        y = (0.0, 0.0, 0.0)
    w = (finite_or_zero(w[0]), finite_or_zero(w[1]), finite_or_zero(w[2]))
    if not fresh:
        mc_predict(cal, r[0], r[1], r[2], r[3], dt)
    start = take and fresh
    if start:
        mc_start(cal, y[0], y[1], y[2], norm)
    live = take and not start
    use = mc_update(cal, y[0], y[1], y[2], w[0], w[1], w[2], live, norm)
    if use or start:
        cal.used += 1.0
    if live and not use:
        cal.gated += 1.0
    if mc_lost(cal, valid and (take or cal.applied != 0.0), use, live, w, dt):
        mc_start_over(cal)
    seen = mc_remember(cal, y, has_up, u, take)
    if seen and cal.loaded == 0.0 and (cal.converged == 0.0 or cal.identity != 0.0):
        # The convergence test, and the watch of a calibration not applied,
        # need the quality now.
        mc_assess(cal, dt)
        cal.assessed = 1.0
    else:
        cal.stale = 1.0  # computed when asked for
        cal.assessed = 0.0
    cal.watching = 0.0
    # Watched once the calibration is nearly good enough to be used.
    if has_up and seen and cal.identity != 0.0 and cal.quality < CAL_WATCH * cal.heading:
        mc_watch(cal, y[0], y[1], y[2], u[0], u[1], u[2])
        cal.watching = 1.0
    mc_cache(cal)
    return 1.0 if (use or start) else 0.0


def mc_admit(cal, norm, allow):
    """
    Count the field (given, invalid, refused): ``(valid, take)``.

    Valid: on, finite and nonzero; taken: valid and not refused by the caller.
    """
    on = cal.enabled != 0.0
    if on:
        cal.fields += 1.0
    take = on and math.isfinite(norm) and norm > 0.0
    if on and not take:
        cal.invalid += 1.0
    valid = take
    if not allow:
        if take:
            cal.refused += 1.0
        take = False
    return valid, take


def mc_lost(cal, watched, use, live, w, dt):
    """
    Whether the calibration no longer fits and must start over.

    Most fields refused while the body turns, by the gate or (where the
    calibration is applied, so that the caller tests calibrated fields) by
    the caller: the offset changed, or it was learned wrong. Or a soft iron
    far outside its prior: the filter has gone astray (a field that changed
    while it could not yet tell).
    """
    watched = watched and dot3(w, w) > CAL_TURNING2
    k_share = 1.0 - math.exp(-dt / CAL_REFUSED_TAU)
    share = cal.refused_share
    if watched:
        share = share + k_share * ((0.0 if use else 1.0) - share)  # a low-pass of "refused"
        cal.refused_share = share
    lost = watched and share > CAL_REFUSED_SHARE
    if live:
        wild = CAL_WILD * cal.soft_iron
        d = soft_iron_of(cal.x)
        for k in range(CAL_NY):
            if abs(d[k]) > wild:
                lost = True
    return lost


def mc_start_over(cal):
    """The calibration no longer fits: forget it (the counts kept), one more reset counted."""
    cal.resets += 1.0
    mc_forget(cal)


def mc_remember(cal, y, has_up, u, take):
    """The sample learned from, for the quality assessed lazily; whether it counts (seen)."""
    store3(cal.seen_y, 0, y)
    if has_up:
        store3(cal.seen_up, 0, u)
        cal.seen_has_up = 1.0
    else:
        cal.seen_has_up = 0.0
    seen = take and cal.fresh == 0.0
    cal.seen_live = 1.0 if seen else 0.0
    return seen


def mc_watch(cal, y0, y1, y2, u0, u1, u2):
    """How far the learned calibration turns the heading from the field as given."""
    f0, f1, f2 = mc_calibrated(cal.x, CAL_Z, y0, y1, y2)
    angle = mc_heading_between(u0, u1, u2, y0, y1, y2, f0, f1, f2)
    # A mean over the samples watched, then over the last CAL_SHIFT_SAMPLES.
    watched = cal.watched + 1.0
    cal.watched = watched
    n = watched
    if n < 1.0:
        n = 1.0
    if n > CAL_SHIFT_SAMPLES:
        n = CAL_SHIFT_SAMPLES
    k = 1.0 / n
    shift = cal.shift
    cal.shift = shift + k * (angle * angle - shift)
    mc_reconsider(cal)


def mc_reconsider(cal):
    """
    Apply the learned calibration once it turns the heading by more than the deadband.

    And by more than its own uncertainty could (3 σ): a sensor calibrated
    already is not recalibrated with a less certain calibration.
    """
    shift = cal.shift
    deadband = cal.deadband
    a = CAL_SIGNIFICANT * cal.quality
    if cal.converged != 0.0 and shift > deadband * deadband and shift > a * a:
        cal.identity = 0.0


def mc_assess(cal, dt):
    """The quality (heading error from the calibration's uncertainty) and convergence."""
    cal.stale = 0.0
    if cal.seen_live == 0.0:
        return
    y = vec3_at(cal.seen_y, 0)
    mc_field_covariance(cal, y)
    f = mc_calibrated(cal.x, CAL_Z, y[0], y[1], y[2])
    has_up = cal.seen_has_up != 0.0
    u = vec3_at(cal.seen_up, 0)
    quality = mc_heading_error(cal.c, f, has_up, u)
    cal.quality = quality
    # Converged once the quality has stayed below the threshold for CAL_HOLD s
    # of learning without the calibration turning the heading by more than
    # that meanwhile (a filter misled by a field that changes keeps moving).
    heading = cal.heading
    learning = cal.loaded == 0.0 and cal.converged == 0.0
    if learning and quality < heading:
        mc_hold(cal, y, f, has_up, u, dt)
    # The hold pauses while the quality is a little above the threshold (it
    # changes with the attitude), and ends well above it.
    if learning and quality > CAL_HOLD_TURN * heading:
        cal.held = -1.0


def mc_field_covariance(cal, y):
    """``C = J P[z d, z d] Jᵀ``, the calibrated field's covariance, ``J = [−I, Y(y)]``."""
    p, jp = cal.p, cal.jp
    at = (CAL_N + 1) * CAL_Z  # P[z, z]
    for j in range(CAL_ZD):  # J P
        z = col3_at(p, at + j, CAL_N)
        d = vec5_at(p, at + CAL_N * (CAL_D - CAL_Z) + j, CAL_N)
        column3_into(jp, j, CAL_ZD, mc_j_times(y, z, d))
    for r in range(3):  # (J P) Jᵀ, a row at a time
        a = CAL_ZD * r
        store3(cal.c, 3 * r, mc_j_times(y, vec3_at(jp, a), vec5_at(jp, a + 3, 1)))


def mc_j_times(y, z, d):
    """``J (z, d) = −z + Y(y) d``, the zeros of ``Y`` skipped."""
    return (-z[0] + y[0] * d[0] + y[1] * d[2] + y[2] * d[3],
            -z[1] + y[1] * d[1] + y[0] * d[2] + y[2] * d[4],
            -z[2] - y[2] * d[0] - y[2] * d[1] + y[0] * d[3] + y[1] * d[4])


def mc_heading_error(cc, f, has_up, u):
    """
    The quality: the calibrated field ``f``'s standard deviation across it, over its norm (rad).

    Across in the horizontal plane where the vertical ``u`` is known (the
    heading's error), else the whole field's (``C``: ``cc``, 3 × 3 row-major).
    """
    if not has_up:
        across = math.sqrt(cc[0] + cc[4] + cc[8])
        horizontal = math.sqrt(dot3(f, f))
    else:
        e = cross3(u, f)  # horizontal, across the field
        horizontal = math.sqrt(dot3(e, e))
        h = max_of(horizontal, CAL_TINY)
        v = quad3_at(cc, 0, (e[0] / h, e[1] / h, e[2] / h))  # eᵀ C e, e made unit
        across = math.sqrt(max_of(v, 0.0))
    return across / max_of(horizontal, CAL_TINY)


def mc_hold(cal, y, f, has_up, u, dt):
    """
    The quality is below the threshold: hold the calibration as it is, or start holding anew.

    Converged after ``CAL_HOLD`` s held; a calibration that turned the heading
    by more than ``CAL_HOLD_TURN`` thresholds since it was first held is held anew.
    """
    x, cand = cal.x, cal.candidate
    if cal.held < 0.0:
        copy_into(cand, rows(0, 1), x, rows(CAL_Z, 1), CAL_ZD, 1)
    g = mc_calibrated(cand, 0, y[0], y[1], y[2])
    if has_up:
        turned = abs(mc_heading_between(u[0], u[1], u[2], f[0], f[1], f[2], g[0], g[1], g[2]))
    else:  # about the field as given, made unit (it has the field's unit)
        n = math.sqrt(dot3(y, y))
        turned = abs(mc_heading_between(y[0] / n, y[1] / n, y[2] / n, f[0], f[1], f[2],
                                        g[0], g[1], g[2]))
    if turned > CAL_HOLD_TURN * cal.heading:
        copy_into(cand, rows(0, 1), x, rows(CAL_Z, 1), CAL_ZD, 1)
        cal.held = 0.0
    else:
        cal.held = max_of(cal.held, 0.0) + dt
    if cal.held >= CAL_HOLD:
        cal.converged = 1.0


# --- outputs -----------------------------------------------------------------------

def mc_cache(cal):
    """The calibration :func:`mc_apply` uses, and whether it is ready and applied."""
    enabled = cal.enabled != 0.0
    ready = enabled and (cal.loaded != 0.0 or cal.converged != 0.0)
    applied = ready and cal.identity == 0.0
    cal.ready = 1.0 if (ready or not enabled) else 0.0
    cal.applied = 1.0 if applied else 0.0
    a = cal.coef
    if applied:
        x = cal.x
        g = cal.scale
        d0, d1, d2, d3, d4 = soft_iron_of(x)
        z0, z1, z2 = offset_of(x)
        a[0] = g + g * d0
        a[1] = g * d2
        a[2] = g * d3
        a[3] = g * d2
        a[4] = g + g * d1
        a[5] = g * d4
        a[6] = g * d3
        a[7] = g * d4
        a[8] = g - g * (d0 + d1)
        a[9] = g * z0
        a[10] = g * z1
        a[11] = g * z2
    else:
        fill(a, 0, 12, 0.0)
        a[0] = 1.0
        a[4] = 1.0
        a[8] = 1.0


def mc_apply(cal, y0, y1, y2):
    """The calibrated field ``A y − z`` (the field as given until a calibration is applied)."""
    a = cal.coef
    return (a[0] * y0 + a[1] * y1 + a[2] * y2 - a[9],
            a[3] * y0 + a[4] * y1 + a[5] * y2 - a[10],
            a[6] * y0 + a[7] * y1 + a[8] * y2 - a[11])


def mc_quality(cal):
    """Heading error (rad, 1σ) the calibration's uncertainty causes; inf before any field."""
    if cal.stale != 0.0:
        mc_assess(cal, 0.0)
    return cal.quality


def mc_field(cal):
    """The calibrated field now, as the filter tracks it (body frame)."""
    x = cal.x
    g = cal.scale
    m0, m1, m2 = sub3(field_with_offset_of(x), offset_of(x))  # m = s − z
    return (m0 * g, m1 * g, m2 * g)


# --- helpers -------------------------------------------------------------------------


def mc_calibrated(zd, at, y0, y1, y2):
    """``(I + D(d)) y − z`` with ``(z, d)`` at ``zd[at:at + 8]``."""
    d0 = zd[at + 3]
    d1 = zd[at + 4]
    d2 = zd[at + 5]
    d3 = zd[at + 6]
    d4 = zd[at + 7]
    return (y0 + d0 * y0 + d2 * y1 + d3 * y2 - zd[at],
            y1 + d2 * y0 + d1 * y1 + d4 * y2 - zd[at + 1],
            y2 + d3 * y0 + d4 * y1 - (d0 + d1) * y2 - zd[at + 2])


def mc_heading_between(u0, u1, u2, f0, f1, f2, g0, g1, g2):
    """The angle (rad) about ``u`` (unit) from the horizontal part of ``f`` to that of ``g``."""
    a0 = u1 * f2 - u2 * f1
    a1 = u2 * f0 - u0 * f2
    a2 = u0 * f1 - u1 * f0
    b0 = u1 * g2 - u2 * g1
    b1 = u2 * g0 - u0 * g2
    b2 = u0 * g1 - u1 * g0
    c0 = a1 * b2 - a2 * b1
    c1 = a2 * b0 - a0 * b2
    c2 = a0 * b1 - a1 * b0
    return math.atan2(c0 * u0 + c1 * u1 + c2 * u2, a0 * b0 + a1 * b1 + a2 * b2)


# --- Python's calls: on the record's holder ----------------------------------------
#
# numba types a record given from Python anew at every call (about 25 µs for
# CAL's 55 fields), a one-element array in under 1 µs (record.py): Python
# calls the functions above through these, which pass the holder's record on.

def mc_init_in(holder, enabled, noise, field_rw, soft_iron, delay, heading, deadband, drift):
    """:func:`mc_init` on the record in ``holder``."""
    mc_init(holder[0], enabled, noise, field_rw, soft_iron, delay, heading, deadband, drift)


def mc_reset_in(holder):
    """:func:`mc_reset` on the record in ``holder``."""
    mc_reset(holder[0])


def mc_restart_in(holder):
    """:func:`mc_restart` on the record in ``holder``: what was refused forgotten."""
    mc_restart(holder[0])


def mc_load_state_in(holder, x3, x4, x5, x6, x7, x8, x9, x10, x11, scale):
    """:func:`mc_load_state` on the record in ``holder``."""
    mc_load_state(holder[0], x3, x4, x5, x6, x7, x8, x9, x10, x11, scale)


def mc_learn_in(holder, y, r, dt, w, has_up, u, allow):
    """:func:`mc_learn` on the record in ``holder``."""
    return mc_learn(holder[0], y, r, dt, w, has_up, u, allow)


def mc_predict_in(holder, rw, rx, ry, rz, dt):
    """:func:`~ext_observer.core.ahrs.magcal_filter.mc_predict` on the record in ``holder``."""
    mc_predict(holder[0], rw, rx, ry, rz, dt)


def mc_assess_in(holder, dt):
    """:func:`mc_assess` on the record in ``holder``."""
    mc_assess(holder[0], dt)


def mc_reconsider_in(holder):
    """:func:`mc_reconsider`, then :func:`mc_cache`, on the record in ``holder``."""
    mc_reconsider(holder[0])
    mc_cache(holder[0])


def mc_apply_in(holder, y0, y1, y2):
    """:func:`mc_apply` on the record in ``holder``."""
    return mc_apply(holder[0], y0, y1, y2)


def mc_quality_in(holder):
    """:func:`mc_quality` on the record in ``holder``."""
    return mc_quality(holder[0])
