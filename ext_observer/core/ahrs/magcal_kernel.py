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
from .magcal_layout import (CAL_HOLD, CAL_HOLD_TURN, CAL_INF, CAL_N, CAL_REFUSED_SHARE,
                            CAL_REFUSED_TAU, CAL_SHIFT_SAMPLES, CAL_SIGNIFICANT, CAL_TINY,
                            CAL_TURNING2, CAL_WATCH, CAL_WILD, GATE, MC_AI, MC_APPLIED,
                            MC_ASSESSED, MC_C, MC_CANDIDATE, MC_COEF, MC_CONVERGED, MC_COUNTS,
                            MC_DEADBAND, MC_DELAY, MC_DRIFT, MC_ENABLED, MC_FIELDS, MC_FIELD_RW,
                            MC_FIELD_SCALE, MC_FRESH, MC_GATED, MC_HAS_PRIOR, MC_HEADING,
                            MC_HELD, MC_IDENTITY, MC_INVALID, MC_JP, MC_LEARNED, MC_LOADED,
                            MC_NIS, MC_NOISE, MC_P, MC_PRIOR_COV, MC_PRIOR_P, MC_PRIOR_SCALE,
                            MC_PRIOR_X, MC_QUALITY, MC_READY, MC_REFUSED, MC_REFUSED_SHARE,
                            MC_RESETS, MC_SCALE, MC_SEEN_HAS_UP, MC_SEEN_LIVE, MC_SEEN_UP,
                            MC_SEEN_Y, MC_SHIFT, MC_SIZE, MC_SOFT_IRON, MC_STALE, MC_USED,
                            MC_WATCHED, MC_WATCHING, MC_X)

# The functions, for a caller that compiles them (each one, before any call).
FUNCTIONS = ('mc_init', 'mc_reset', 'mc_restart', 'mc_load_state', 'mc_learn', 'mc_predict',
             'mc_start', 'mc_update', 'mc_assess', 'mc_watch', 'mc_reconsider', 'mc_cache',
             'mc_apply', 'mc_quality', 'mc_field', 'mc_inv3', 'mc_heading_between',
             'mc_calibrated', 'mc_symmetrize')

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
    for k in range(CAL_N + CAL_N * CAL_N):
        s[o + MC_X + k] = 0.0
    for k in range(9 + 1 + 81):
        s[o + MC_PRIOR_X + k] = 0.0
    s[o + MC_HAS_PRIOR] = 0.0
    s[o + MC_PRIOR_COV] = 0.0
    s[o + MC_SCALE] = 1.0
    s[o + MC_FRESH] = 1.0
    s[o + MC_LOADED] = 0.0
    s[o + MC_CONVERGED] = 0.0
    s[o + MC_QUALITY] = CAL_INF
    s[o + MC_STALE] = 0.0
    s[o + MC_LEARNED] = 0.0
    s[o + MC_REFUSED_SHARE] = 0.0
    s[o + MC_NIS] = 3.0
    for k in range(8):
        s[o + MC_CANDIDATE + k] = 0.0
    s[o + MC_HELD] = -1.0
    # The field as given is applied until the learned calibration turns
    # the heading by more than the deadband (mean square, rad²).
    s[o + MC_IDENTITY] = 1.0
    s[o + MC_SHIFT] = 0.0
    s[o + MC_WATCHED] = 0.0
    s[o + MC_FIELD_SCALE] = 1.0
    for k in range(6):
        s[o + MC_COUNTS + k] = 0.0
    for k in range(8):
        s[o + MC_SEEN_Y + k] = 0.0
    s[o + MC_ASSESSED] = 0.0
    s[o + MC_WATCHING] = 0.0
    mc_cache(s, o)


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

def mc_learn(s, o, y0, y1, y2, rw, rx, ry, rz, dt, w0, w1, w2, has_up, u0, u1, u2, allow):
    """
    Learn from one field sample; 1.0 if it was used, else 0.0.

    ``y``: the raw field, body frame. ``r = (rw, rx, ry, rz)``: the body's
    rotation since the previous sample learned from, previous body frame →
    current one (any nonzero norm). ``dt``: seconds since that sample.
    ``w``: the angular rate now (rad/s, bias removed), for the lag. ``u``:
    the world's vertical in the body frame (unit), for the quality, where
    ``has_up``; without it the error of the whole calibrated field counts.
    ``allow`` false: the caller refuses this sample (counted as refused).
    """
    on = s[o + MC_ENABLED] != 0.0
    fresh = s[o + MC_FRESH] != 0.0
    norm = math.sqrt(y0 * y0 + y1 * y1 + y2 * y2)
    if on:
        s[o + MC_FIELDS] += 1.0
    take = on and math.isfinite(norm) and norm > 0.0
    if on and not take:
        s[o + MC_INVALID] += 1.0
    valid = take and not fresh
    if not allow:
        if take:
            s[o + MC_REFUSED] += 1.0
        take = False
    if not take:
        y0 = 0.0
        y1 = 0.0
        y2 = 0.0
    if not math.isfinite(w0):
        w0 = 0.0
    if not math.isfinite(w1):
        w1 = 0.0
    if not math.isfinite(w2):
        w2 = 0.0
    if not fresh:
        mc_predict(s, o, rw, rx, ry, rz, dt)
    start = take and fresh
    if start:
        mc_start(s, o, y0, y1, y2, norm)
    live = take and not start
    use = mc_update(s, o, y0, y1, y2, w0, w1, w2, live, norm)
    if use or start:
        s[o + MC_USED] += 1.0
    if live and not use:
        s[o + MC_GATED] += 1.0
    # Most fields refused while the body turns, by the gate or (where the
    # calibration is applied, so that the caller tests calibrated fields)
    # by the caller: the calibration no longer fits (the offset changed, or
    # it was learned wrong); start over.
    watched = (valid and w0 * w0 + w1 * w1 + w2 * w2 > CAL_TURNING2
               and (take or s[o + MC_APPLIED] != 0.0))
    k_share = 1.0 - math.exp(-dt / CAL_REFUSED_TAU)
    share = s[o + MC_REFUSED_SHARE]
    if watched:
        share = share + k_share * ((0.0 if use else 1.0) - share)
        s[o + MC_REFUSED_SHARE] = share
    lost = watched and share > CAL_REFUSED_SHARE
    # A soft iron far outside its prior: the filter has gone astray (a
    # field that changed while it could not yet tell); start over.
    if live:
        wild = CAL_WILD * s[o + MC_SOFT_IRON]
        for k in range(5):
            if abs(s[o + MC_X + 6 + k]) > wild:
                lost = True
    if lost:
        s[o + MC_RESETS] += 1.0
        s[o + MC_FRESH] = 1.0
        s[o + MC_LOADED] = 0.0
        s[o + MC_CONVERGED] = 0.0
        s[o + MC_IDENTITY] = 1.0
        s[o + MC_SHIFT] = 0.0
        s[o + MC_WATCHED] = 0.0
        s[o + MC_REFUSED_SHARE] = 0.0
        s[o + MC_HAS_PRIOR] = 0.0
    fresh = s[o + MC_FRESH] != 0.0
    s[o + MC_SEEN_Y] = y0
    s[o + MC_SEEN_Y + 1] = y1
    s[o + MC_SEEN_Y + 2] = y2
    if has_up:
        s[o + MC_SEEN_UP] = u0
        s[o + MC_SEEN_UP + 1] = u1
        s[o + MC_SEEN_UP + 2] = u2
        s[o + MC_SEEN_HAS_UP] = 1.0
    else:
        s[o + MC_SEEN_HAS_UP] = 0.0
    seen = take and not fresh
    s[o + MC_SEEN_LIVE] = 1.0 if seen else 0.0
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
        mc_watch(s, o, y0, y1, y2, u0, u1, u2)
        s[o + MC_WATCHING] = 1.0
    mc_cache(s, o)
    return 1.0 if (use or start) else 0.0


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
    y0 = s[o + MC_SEEN_Y]
    y1 = s[o + MC_SEEN_Y + 1]
    y2 = s[o + MC_SEEN_Y + 2]
    # The covariance of the calibrated field, J P[3:11, 3:11] Jᵀ with
    # J = [−I, Y(y)].
    p = o + MC_P + CAL_N * 3 + 3
    jp = o + MC_JP
    for c in range(8):
        s[jp + c] = (-s[p + c] + y0 * s[p + CAL_N * 3 + c] + y1 * s[p + CAL_N * 5 + c]
                     + y2 * s[p + CAL_N * 6 + c])
        s[jp + 8 + c] = (-s[p + CAL_N + c] + y1 * s[p + CAL_N * 4 + c] + y0 * s[p + CAL_N * 5 + c]
                         + y2 * s[p + CAL_N * 7 + c])
        s[jp + 16 + c] = (-s[p + 2 * CAL_N + c] - y2 * s[p + CAL_N * 3 + c]
                          - y2 * s[p + CAL_N * 4 + c] + y0 * s[p + CAL_N * 6 + c]
                          + y1 * s[p + CAL_N * 7 + c])
    cc = o + MC_C
    for r in range(3):
        a = jp + 8 * r
        s[cc + 3 * r] = -s[a] + y0 * s[a + 3] + y1 * s[a + 5] + y2 * s[a + 6]
        s[cc + 3 * r + 1] = -s[a + 1] + y1 * s[a + 4] + y0 * s[a + 5] + y2 * s[a + 7]
        s[cc + 3 * r + 2] = (-s[a + 2] - y2 * s[a + 3] - y2 * s[a + 4] + y0 * s[a + 6]
                             + y1 * s[a + 7])
    f0, f1, f2 = mc_calibrated(s, o + MC_X + 3, y0, y1, y2)
    has_up = s[o + MC_SEEN_HAS_UP] != 0.0
    u0 = s[o + MC_SEEN_UP]
    u1 = s[o + MC_SEEN_UP + 1]
    u2 = s[o + MC_SEEN_UP + 2]
    if not has_up:
        across = math.sqrt(s[cc] + s[cc + 4] + s[cc + 8])
        horizontal = math.sqrt(f0 * f0 + f1 * f1 + f2 * f2)
    else:
        e0 = u1 * f2 - u2 * f1
        e1 = u2 * f0 - u0 * f2
        e2 = u0 * f1 - u1 * f0
        horizontal = math.sqrt(e0 * e0 + e1 * e1 + e2 * e2)
        h = horizontal
        if h < CAL_TINY:
            h = CAL_TINY
        e0 = e0 / h
        e1 = e1 / h
        e2 = e2 / h
        v = (e0 * s[cc] * e0 + e0 * s[cc + 1] * e1 + e0 * s[cc + 2] * e2
             + e1 * s[cc + 3] * e0 + e1 * s[cc + 4] * e1 + e1 * s[cc + 5] * e2
             + e2 * s[cc + 6] * e0 + e2 * s[cc + 7] * e1 + e2 * s[cc + 8] * e2)
        if v < 0.0:
            v = 0.0
        across = math.sqrt(v)
    h = horizontal
    if h < CAL_TINY:
        h = CAL_TINY
    quality = across / h
    s[o + MC_QUALITY] = quality
    # Converged once the quality has stayed below the threshold for CAL_HOLD s
    # of learning and the calibration has not turned the heading by more
    # than the threshold meanwhile (a filter misled by a field that changes
    # keeps moving; a settled one does not).
    heading = s[o + MC_HEADING]
    learning = s[o + MC_LOADED] == 0.0 and s[o + MC_CONVERGED] == 0.0
    if learning and quality < heading:
        x = o + MC_X
        cand = o + MC_CANDIDATE
        if s[o + MC_HELD] < 0.0:
            for k in range(8):
                s[cand + k] = s[x + 3 + k]
        g0, g1, g2 = mc_calibrated(s, cand, y0, y1, y2)
        if has_up:
            turned = abs(mc_heading_between(u0, u1, u2, f0, f1, f2, g0, g1, g2))
        else:  # about the field as given, made unit (it has the field's unit)
            n = math.sqrt(y0 * y0 + y1 * y1 + y2 * y2)
            turned = abs(mc_heading_between(y0 / n, y1 / n, y2 / n, f0, f1, f2, g0, g1, g2))
        if turned > CAL_HOLD_TURN * heading:
            for k in range(8):
                s[cand + k] = s[x + 3 + k]
            s[o + MC_HELD] = 0.0
        else:
            held = s[o + MC_HELD]
            if held < 0.0:
                held = 0.0
            s[o + MC_HELD] = held + dt
        if s[o + MC_HELD] >= CAL_HOLD:
            s[o + MC_CONVERGED] = 1.0
    # The hold pauses while the quality is a little above the threshold (it
    # changes with the attitude), and ends well above it.
    if learning and quality > CAL_HOLD_TURN * heading:
        s[o + MC_HELD] = -1.0


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


