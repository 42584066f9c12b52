"""
The maths of the online magnetometer calibration, as plain functions on a flat state.

:class:`~ext_observer.core.ahrs.magcal.MagCalibrator` is a thin wrapper over
these functions. One calibrator's state is a block of :data:`MC_SIZE`
floats at an offset ``o`` of a container ``s`` (the ``MC_*`` slots of
:mod:`~ext_observer.core.ahrs.magcal_layout`, relative to ``o``); flags are
0.0/1.0. Written in the part of Python numba compiles, so the same source
runs plain on a list or compiled on an array
(:mod:`~ext_observer.core.ahrs.compiled`), with no allocation in the hot
path. The model, the gate, convergence and when a calibration is applied:
docs/calibration.md ("The filter, in equations").
"""

import math

from .magcal_filter import mc_inv3, mc_predict, mc_start, mc_symmetrize, mc_update
from .magcal_layout import (CAL_D, CAL_HOLD, CAL_HOLD_TURN, CAL_INF, CAL_N, CAL_NIS_EXPECTED,
                            CAL_NY, CAL_REFUSED_SHARE, CAL_REFUSED_TAU, CAL_SHIFT_SAMPLES,
                            CAL_SIGNIFICANT, CAL_TINY, CAL_TURNING2, CAL_WATCH, CAL_WILD, CAL_Z,
                            CAL_ZD, GATE, MC_AI, MC_APPLIED, MC_ASSESSED, MC_C, MC_CANDIDATE,
                            MC_COEF, MC_CONVERGED, MC_COUNTS, MC_DEADBAND, MC_DELAY, MC_DRIFT,
                            MC_ENABLED, MC_FIELDS, MC_FIELD_RW, MC_FIELD_SCALE, MC_FRESH,
                            MC_GATED, MC_HAS_PRIOR, MC_HEADING, MC_HELD, MC_IDENTITY,
                            MC_INVALID, MC_JP, MC_LEARNED, MC_LOADED, MC_NIS, MC_NOISE, MC_P,
                            MC_PRIOR_COV, MC_PRIOR_P, MC_PRIOR_SCALE, MC_PRIOR_X, MC_QUALITY,
                            MC_READY, MC_REFUSED, MC_REFUSED_SHARE, MC_RESETS, MC_SCALE,
                            MC_SEEN_HAS_UP, MC_SEEN_LIVE, MC_SEEN_UP, MC_SEEN_Y, MC_SHIFT,
                            MC_SIZE, MC_SOFT_IRON, MC_STALE, MC_USED, MC_WATCHED, MC_WATCHING,
                            MC_X)
from .small_matrix import (col3_at, column3_into, copy_into, cross3, dot3, fill,
                           finite_or_zero, max_of, quad3_at, rows, store3, vec3_at, vec5_at)

# The functions, for a caller that compiles them (each one, before any call).
FUNCTIONS = ('mc_init', 'mc_reset', 'mc_forget', 'mc_restart', 'mc_load_state', 'mc_learn',
             'mc_admit', 'mc_lost', 'mc_start_over', 'mc_remember', 'mc_predict', 'mc_start',
             'mc_update', 'mc_assess', 'mc_field_covariance', 'mc_j_times', 'mc_heading_error',
             'mc_hold', 'mc_watch', 'mc_reconsider', 'mc_cache', 'mc_apply', 'mc_quality',
             'mc_field', 'mc_inv3', 'mc_heading_between', 'mc_calibrated', 'mc_symmetrize')

__all__ = ['FUNCTIONS', 'GATE'] + [name for name in dir() if name.startswith('MC_')] + list(
    FUNCTIONS)


# --- state -------------------------------------------------------------------

def mc_init(s, o, enabled, noise, field_rw, soft_iron, delay, heading, deadband, drift):
    """Set the parameters of the block at ``o``, then :func:`mc_reset`."""
    s[o + MC_ENABLED] = 1.0 if enabled else 0.0
    s[o + MC_NOISE] = noise
    s[o + MC_FIELD_RW] = field_rw
    s[o + MC_SOFT_IRON] = soft_iron
    s[o + MC_DELAY] = delay
    s[o + MC_HEADING] = heading
    s[o + MC_DEADBAND] = deadband
    s[o + MC_DRIFT] = drift
    for k in range(MC_SIZE - MC_AI):
        s[o + MC_AI + k] = 0.0
    mc_reset(s, o)


def mc_reset(s, o):
    """Forget the calibration: learn from the next field on."""
    fill(s, o + MC_X, CAL_N + CAL_N * CAL_N, 0.0)
    fill(s, o + MC_PRIOR_X, 9 + 1 + 81, 0.0)
    mc_forget(s, o)
    s[o + MC_PRIOR_COV] = 0.0
    s[o + MC_SCALE] = 1.0
    s[o + MC_QUALITY] = CAL_INF
    s[o + MC_STALE] = 0.0
    s[o + MC_LEARNED] = 0.0
    s[o + MC_NIS] = CAL_NIS_EXPECTED
    fill(s, o + MC_CANDIDATE, CAL_ZD, 0.0)
    s[o + MC_HELD] = -1.0
    s[o + MC_FIELD_SCALE] = 1.0
    fill(s, o + MC_COUNTS, 6, 0.0)
    fill(s, o + MC_SEEN_Y, 8, 0.0)
    s[o + MC_ASSESSED] = 0.0
    s[o + MC_WATCHING] = 0.0
    mc_cache(s, o)


def mc_forget(s, o):
    """
    A fresh start at the next field, nothing learned kept (no prior), not applied.

    The field as given is applied until the learned calibration turns the
    heading by more than the deadband (mean square, rad²).
    """
    s[o + MC_FRESH] = 1.0
    s[o + MC_LOADED] = 0.0
    s[o + MC_CONVERGED] = 0.0
    s[o + MC_IDENTITY] = 1.0
    s[o + MC_SHIFT] = 0.0
    s[o + MC_WATCHED] = 0.0
    s[o + MC_REFUSED_SHARE] = 0.0
    s[o + MC_HAS_PRIOR] = 0.0


def mc_restart(s, o):
    """Keep what is learned, follow the field afresh from the next sample."""
    if s[o + MC_ENABLED] != 0.0 and s[o + MC_FRESH] == 0.0:
        for k in range(9):
            s[o + MC_PRIOR_X + k] = s[o + MC_X + 3 + k]
        s[o + MC_PRIOR_SCALE] = s[o + MC_SCALE]
        for i in range(9):
            for j in range(9):
                s[o + MC_PRIOR_P + 9 * i + j] = s[o + MC_P + CAL_N * (3 + i) + 3 + j]
        s[o + MC_HAS_PRIOR] = 1.0
        s[o + MC_PRIOR_COV] = 1.0
    s[o + MC_FRESH] = 1.0


def mc_load_state(s, o, x3, x4, x5, x6, x7, x8, x9, x10, x11, scale):
    """
    Start from a saved calibration: ``x[3:]`` and the scale (see ``MagCalibrator.load``).

    Nothing where the calibrator is off.
    """
    if s[o + MC_ENABLED] != 0.0:
        p = o + MC_PRIOR_X
        s[p] = x3
        s[p + 1] = x4
        s[p + 2] = x5
        s[p + 3] = x6
        s[p + 4] = x7
        s[p + 5] = x8
        s[p + 6] = x9
        s[p + 7] = x10
        s[p + 8] = x11
        s[o + MC_PRIOR_SCALE] = scale
        # Applied at once, before the next field starts the filter from it.
        for k in range(9):
            s[o + MC_X + 3 + k] = s[p + k]
        s[o + MC_SCALE] = scale
        s[o + MC_HAS_PRIOR] = 1.0
        s[o + MC_PRIOR_COV] = 0.0
        s[o + MC_FRESH] = 1.0
        s[o + MC_LOADED] = 1.0
        s[o + MC_IDENTITY] = 0.0
        s[o + MC_CONVERGED] = 0.0
    mc_cache(s, o)


# --- learning ------------------------------------------------------------------

def mc_learn(s, o, y, r, dt, w, has_up, u, allow):
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
    fresh = s[o + MC_FRESH] != 0.0
    norm = math.sqrt(y[0] * y[0] + y[1] * y[1] + y[2] * y[2])
    valid, take = mc_admit(s, o, norm, allow)
    valid = valid and not fresh
    if not take:
        y = (0.0, 0.0, 0.0)
    w = (finite_or_zero(w[0]), finite_or_zero(w[1]), finite_or_zero(w[2]))
    if not fresh:
        mc_predict(s, o, r[0], r[1], r[2], r[3], dt)
    start = take and fresh
    if start:
        mc_start(s, o, y[0], y[1], y[2], norm)
    live = take and not start
    use = mc_update(s, o, y[0], y[1], y[2], w[0], w[1], w[2], live, norm)
    if use or start:
        s[o + MC_USED] += 1.0
    if live and not use:
        s[o + MC_GATED] += 1.0
    if mc_lost(s, o, valid and (take or s[o + MC_APPLIED] != 0.0), use, live, w, dt):
        mc_start_over(s, o)
    seen = mc_remember(s, o, y, has_up, u, take)
    if seen and s[o + MC_LOADED] == 0.0 and (s[o + MC_CONVERGED] == 0.0
                                             or s[o + MC_IDENTITY] != 0.0):
        # The convergence test, and the watch of a calibration not applied,
        # need the quality now.
        mc_assess(s, o, dt)
        s[o + MC_ASSESSED] = 1.0
    else:
        s[o + MC_STALE] = 1.0  # computed when asked for
        s[o + MC_ASSESSED] = 0.0
    s[o + MC_WATCHING] = 0.0
    # Watched once the calibration is nearly good enough to be used.
    if (has_up and seen and s[o + MC_IDENTITY] != 0.0
            and s[o + MC_QUALITY] < CAL_WATCH * s[o + MC_HEADING]):
        mc_watch(s, o, y[0], y[1], y[2], u[0], u[1], u[2])
        s[o + MC_WATCHING] = 1.0
    mc_cache(s, o)
    return 1.0 if (use or start) else 0.0


def mc_admit(s, o, norm, allow):
    """
    Count the field (given, invalid, refused): ``(valid, take)``.

    Valid: on, finite and nonzero; taken: valid and not refused by the caller.
    """
    on = s[o + MC_ENABLED] != 0.0
    if on:
        s[o + MC_FIELDS] += 1.0
    take = on and math.isfinite(norm) and norm > 0.0
    if on and not take:
        s[o + MC_INVALID] += 1.0
    valid = take
    if not allow:
        if take:
            s[o + MC_REFUSED] += 1.0
        take = False
    return valid, take


def mc_lost(s, o, watched, use, live, w, dt):
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
    share = s[o + MC_REFUSED_SHARE]
    if watched:
        share = share + k_share * ((0.0 if use else 1.0) - share)  # a low-pass of "refused"
        s[o + MC_REFUSED_SHARE] = share
    lost = watched and share > CAL_REFUSED_SHARE
    if live:
        wild = CAL_WILD * s[o + MC_SOFT_IRON]
        for k in range(CAL_NY):
            if abs(s[o + MC_X + CAL_D + k]) > wild:
                lost = True
    return lost


def mc_start_over(s, o):
    """The calibration no longer fits: forget it (the counts kept), one more reset counted."""
    s[o + MC_RESETS] += 1.0
    mc_forget(s, o)


def mc_remember(s, o, y, has_up, u, take):
    """The sample learned from, for the quality assessed lazily; whether it counts (seen)."""
    store3(s, o + MC_SEEN_Y, y)
    if has_up:
        store3(s, o + MC_SEEN_UP, u)
        s[o + MC_SEEN_HAS_UP] = 1.0
    else:
        s[o + MC_SEEN_HAS_UP] = 0.0
    seen = take and s[o + MC_FRESH] == 0.0
    s[o + MC_SEEN_LIVE] = 1.0 if seen else 0.0
    return seen


def mc_watch(s, o, y0, y1, y2, u0, u1, u2):
    """How far the learned calibration turns the heading from the field as given."""
    f0, f1, f2 = mc_calibrated(s, o + MC_X + 3, y0, y1, y2)
    angle = mc_heading_between(u0, u1, u2, y0, y1, y2, f0, f1, f2)
    # A mean over the samples watched, then over the last CAL_SHIFT_SAMPLES.
    watched = s[o + MC_WATCHED] + 1.0
    s[o + MC_WATCHED] = watched
    n = watched
    if n < 1.0:
        n = 1.0
    if n > CAL_SHIFT_SAMPLES:
        n = CAL_SHIFT_SAMPLES
    k = 1.0 / n
    shift = s[o + MC_SHIFT]
    s[o + MC_SHIFT] = shift + k * (angle * angle - shift)
    mc_reconsider(s, o)


def mc_reconsider(s, o):
    """
    Apply the learned calibration once it turns the heading by more than the deadband.

    And by more than its own uncertainty could (3 σ): a sensor calibrated
    already is not recalibrated with a less certain calibration.
    """
    shift = s[o + MC_SHIFT]
    deadband = s[o + MC_DEADBAND]
    a = CAL_SIGNIFICANT * s[o + MC_QUALITY]
    if (s[o + MC_CONVERGED] != 0.0 and shift > deadband * deadband and shift > a * a):
        s[o + MC_IDENTITY] = 0.0


def mc_assess(s, o, dt):
    """The quality (heading error from the calibration's uncertainty) and convergence."""
    s[o + MC_STALE] = 0.0
    if s[o + MC_SEEN_LIVE] == 0.0:
        return
    y = vec3_at(s, o + MC_SEEN_Y)
    mc_field_covariance(s, o, y)
    f = mc_calibrated(s, o + MC_X + CAL_Z, y[0], y[1], y[2])
    has_up = s[o + MC_SEEN_HAS_UP] != 0.0
    u = vec3_at(s, o + MC_SEEN_UP)
    quality = mc_heading_error(s, o + MC_C, f, has_up, u)
    s[o + MC_QUALITY] = quality
    # Converged once the quality has stayed below the threshold for CAL_HOLD s
    # of learning without the calibration turning the heading by more than
    # that meanwhile (a filter misled by a field that changes keeps moving).
    heading = s[o + MC_HEADING]
    learning = s[o + MC_LOADED] == 0.0 and s[o + MC_CONVERGED] == 0.0
    if learning and quality < heading:
        mc_hold(s, o, y, f, has_up, u, dt)
    # The hold pauses while the quality is a little above the threshold (it
    # changes with the attitude), and ends well above it.
    if learning and quality > CAL_HOLD_TURN * heading:
        s[o + MC_HELD] = -1.0


def mc_field_covariance(s, o, y):
    """``C = J P[z d, z d] Jᵀ``, the calibrated field's covariance, ``J = [−I, Y(y)]``."""
    p = o + MC_P + (CAL_N + 1) * CAL_Z
    jp = o + MC_JP
    for c in range(CAL_ZD):  # J P
        z = col3_at(s, p + c, CAL_N)
        d = vec5_at(s, p + CAL_N * (CAL_D - CAL_Z) + c, CAL_N)
        column3_into(s, jp + c, CAL_ZD, mc_j_times(y, z, d))
    for r in range(3):  # (J P) Jᵀ, a row at a time
        a = jp + CAL_ZD * r
        store3(s, o + MC_C + 3 * r, mc_j_times(y, vec3_at(s, a), vec5_at(s, a + 3, 1)))


def mc_j_times(y, z, d):
    """``J (z, d) = −z + Y(y) d``, the zeros of ``Y`` skipped."""
    return (-z[0] + y[0] * d[0] + y[1] * d[2] + y[2] * d[3],
            -z[1] + y[1] * d[1] + y[0] * d[2] + y[2] * d[4],
            -z[2] - y[2] * d[0] - y[2] * d[1] + y[0] * d[3] + y[1] * d[4])


def mc_heading_error(s, cc, f, has_up, u):
    """
    The quality: the calibrated field ``f``'s standard deviation across it, over its norm (rad).

    Across in the horizontal plane where the vertical ``u`` is known (the
    heading's error), else the whole field's (``C`` at ``s[cc:]``).
    """
    if not has_up:
        across = math.sqrt(s[cc] + s[cc + 4] + s[cc + 8])
        horizontal = math.sqrt(dot3(f, f))
    else:
        e = cross3(u, f)  # horizontal, across the field
        horizontal = math.sqrt(dot3(e, e))
        h = max_of(horizontal, CAL_TINY)
        v = quad3_at(s, cc, (e[0] / h, e[1] / h, e[2] / h))  # eᵀ C e, e made unit
        across = math.sqrt(max_of(v, 0.0))
    return across / max_of(horizontal, CAL_TINY)


def mc_hold(s, o, y, f, has_up, u, dt):
    """
    The quality is below the threshold: hold the calibration as it is, or start holding anew.

    Converged after ``CAL_HOLD`` s held; a calibration that turned the heading
    by more than ``CAL_HOLD_TURN`` thresholds since it was first held is held anew.
    """
    x = o + MC_X
    cand = o + MC_CANDIDATE
    if s[o + MC_HELD] < 0.0:
        copy_into(s, rows(cand, 1), s, rows(x + CAL_Z, 1), CAL_ZD, 1)
    g = mc_calibrated(s, cand, y[0], y[1], y[2])
    if has_up:
        turned = abs(mc_heading_between(u[0], u[1], u[2], f[0], f[1], f[2], g[0], g[1], g[2]))
    else:  # about the field as given, made unit (it has the field's unit)
        n = math.sqrt(dot3(y, y))
        turned = abs(mc_heading_between(y[0] / n, y[1] / n, y[2] / n, f[0], f[1], f[2],
                                        g[0], g[1], g[2]))
    if turned > CAL_HOLD_TURN * s[o + MC_HEADING]:
        copy_into(s, rows(cand, 1), s, rows(x + CAL_Z, 1), CAL_ZD, 1)
        s[o + MC_HELD] = 0.0
    else:
        s[o + MC_HELD] = max_of(s[o + MC_HELD], 0.0) + dt
    if s[o + MC_HELD] >= CAL_HOLD:
        s[o + MC_CONVERGED] = 1.0


# --- outputs -----------------------------------------------------------------------

def mc_cache(s, o):
    """The calibration :func:`mc_apply` uses, and whether it is ready and applied."""
    enabled = s[o + MC_ENABLED] != 0.0
    ready = enabled and (s[o + MC_LOADED] != 0.0 or s[o + MC_CONVERGED] != 0.0)
    applied = ready and s[o + MC_IDENTITY] == 0.0
    s[o + MC_READY] = 1.0 if (ready or not enabled) else 0.0
    s[o + MC_APPLIED] = 1.0 if applied else 0.0
    c = o + MC_COEF
    if applied:
        x = o + MC_X
        g = s[o + MC_SCALE]
        d0 = s[x + 6]
        d1 = s[x + 7]
        d2 = s[x + 8]
        d3 = s[x + 9]
        d4 = s[x + 10]
        s[c] = g + g * d0
        s[c + 1] = g * d2
        s[c + 2] = g * d3
        s[c + 3] = g * d2
        s[c + 4] = g + g * d1
        s[c + 5] = g * d4
        s[c + 6] = g * d3
        s[c + 7] = g * d4
        s[c + 8] = g - g * (d0 + d1)
        s[c + 9] = g * s[x + 3]
        s[c + 10] = g * s[x + 4]
        s[c + 11] = g * s[x + 5]
    else:
        for k in range(12):
            s[c + k] = 0.0
        s[c] = 1.0
        s[c + 4] = 1.0
        s[c + 8] = 1.0


def mc_apply(s, o, y0, y1, y2):
    """The calibrated field ``A y − z`` (the field as given until a calibration is applied)."""
    c = o + MC_COEF
    return (s[c] * y0 + s[c + 1] * y1 + s[c + 2] * y2 - s[c + 9],
            s[c + 3] * y0 + s[c + 4] * y1 + s[c + 5] * y2 - s[c + 10],
            s[c + 6] * y0 + s[c + 7] * y1 + s[c + 8] * y2 - s[c + 11])


def mc_quality(s, o):
    """Heading error (rad, 1σ) the calibration's uncertainty causes; inf before any field."""
    if s[o + MC_STALE] != 0.0:
        mc_assess(s, o, 0.0)
    return s[o + MC_QUALITY]


def mc_field(s, o):
    """The calibrated field now, as the filter tracks it (body frame)."""
    x = o + MC_X
    g = s[o + MC_SCALE]
    return ((s[x] - s[x + 3]) * g, (s[x + 1] - s[x + 4]) * g, (s[x + 2] - s[x + 5]) * g)


# --- helpers -------------------------------------------------------------------------


def mc_calibrated(s, zd, y0, y1, y2):
    """``(I + D(d)) y − z`` with ``(z, d)`` at ``s[zd:zd + 8]``."""
    d0 = s[zd + 3]
    d1 = s[zd + 4]
    d2 = s[zd + 5]
    d3 = s[zd + 6]
    d4 = s[zd + 7]
    return (y0 + d0 * y0 + d2 * y1 + d3 * y2 - s[zd],
            y1 + d2 * y0 + d1 * y1 + d4 * y2 - s[zd + 1],
            y2 + d3 * y0 + d4 * y1 - (d0 + d1) * y2 - s[zd + 2])


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


