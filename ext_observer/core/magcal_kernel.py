"""
The maths of the online magnetometer calibration, as plain functions on a flat state.

:class:`~ext_observer.core.magcal.MagCalibrator` is a thin wrapper over
these functions. One calibrator's state is a block of :data:`MC_SIZE`
floats starting at an offset ``o`` of a container ``s`` (a Python list, or
a 1-D float64 array that may hold other state too); the ``MC_*`` constants
are the slots, relative to ``o``. Booleans are stored as 0.0/1.0, counts as
floats. The functions use only what numba's nopython mode compiles (float
arithmetic, :mod:`math`, ``for`` loops, ``s[o + k]``, calls between them,
tuples of floats returned), so the same source runs in plain Python on a
list, or compiled by ``numba.njit`` on an array: load this file a second
time as another module, replace each function of :data:`FUNCTIONS` by its
``njit`` version before any call, and pass that module as
``MagCalibrator(kernel=...)``. Nothing is allocated in the hot path: the
products' intermediates have scratch slots.

**The model**, body frame: a raw field sample is ``y = S m + b``, with
``m`` the true field, ``b`` the hard-iron offset and ``S`` a symmetric
soft-iron matrix. With ``A = S⁻¹ = I + D(d)`` (``D`` symmetric, trace 0:
five numbers ``d``) and ``z = A b``, the calibrated field is ``m = A y − z``.
``S`` is known only up to a scale (a uniform gain moves no direction), fixed
here by ``trace(A) = 3``, or by the trace of a loaded matrix.

What makes it observable is the gyro. The field is fixed in the world, so
in the body frame it turns against the body: between two fields ``m ← Rᵀ m``
with ``R`` the gyro's rotation, and a body that turns about two axes leaves
one offset and one matrix that fit (gyro-aided calibration: Troni and
Whitcomb 2013, "Adaptive estimation of measurement bias in
three-dimensional field sensors with angular rate sensors", Robotics:
Science and Systems; Kok and Schön 2016, "Magnetometer calibration using
inertial sensors", IEEE Sensors Journal 16(14), for the view of the field as
a constant world vector seen through the gyro's orientation). A Kalman
filter estimates ``(s, z, d, τ)`` with ``s = m + z = A y``: then the field's
turn, ``s ← Rᵀ s + (I − Rᵀ) z``, is linear, nothing ties ``s`` to ``z`` at
rest (the covariance stays well conditioned while nothing can be learned),
and the measurement ``y = A⁻¹ (s + τ ω × (s − z))`` is linear in ``s`` and
``z`` and linearized about the estimate in ``d`` and ``τ`` only. (Written as
``A y = s``, with the measured ``y`` in the regressor, its noise would pull
``A`` towards 0 while the body rests: the errors-in-variables bias.) Two
things measured on BROAD (Laidig et al. 2021) shape the filter beyond that:

- The field lags the gyro on real hardware (about 12 ms there);
  uncorrected, the lag correlates with the turn rate and biases the offset
  by about 1 % of the field. The lag ``τ`` is a state:
  ``m(t − τ) ≈ m + τ ω × m``.
- The world field is not quite constant where a body moves (a lab's field
  changes by a few percent over a metre). ``m`` is a random walk, relative
  ``field_rw`` per √s, so a slowly changing field is not learned as an
  offset; the offset itself may drift (``drift``).

A sample whose innovation is improbable (``GATE``) is not used (a field that
jumps: a magnet passing). The caller may also refuse a sample (``allow``).
When most samples are refused while the body turns (the offset changed for
good, or a field that moved while nothing was known misled the filter), or
the soft iron leaves its prior far behind, the calibration starts over.

**Convergence.** The quality is the heading error the calibration's
uncertainty would cause now: the covariance of ``(z, d)`` mapped onto the
calibrated field, along the horizontal direction across the field (body
frame, from the caller's up vector), over the horizontal field. The
calibration is converged once the quality has stayed below ``heading``
(rad) for ``_HOLD`` seconds of learning without the calibration turning the
heading by more than that meanwhile. Measured where it matters, so a robot
that only turns about its vertical converges (the offset along that axis is
never learned, and does not move the heading while it stays level).

**The field as given, or the learned calibration.** :func:`mc_apply`
returns the field as given until a converged calibration turns the heading
by more than ``deadband`` (RMS over the recent learning steps) from it: a
sensor calibrated already (BROAD's are) keeps its own calibration, which
what can be learned online, about 1 % of the field, does not beat. A loaded
calibration is applied at once.

**Arithmetic.** The formulas and their order are those of the numpy
implementation this replaced (sums left to right, ``x * x`` for squares);
the 3 × 3 inverses are written out with cofactors. Its matrix products went
through BLAS, whose kernels fuse multiply and add, so the two agree to
rounding, not to the bit (about 1e-14 in the estimator's attitude on the
test excerpts). Plain and compiled agree to the bit: without ``fastmath``
numba fuses nothing.
"""

import math

# --- tuning -------------------------------------------------------------------

# Innovations beyond this (χ², 3 degrees of freedom; 16.3 is 99.9 %) are refused.
GATE = 16.0
# The share of fields refused while the body turns faster than _TURNING
# (rad/s), with this time constant (s): above _REFUSED_SHARE, start over.
_REFUSED_TAU = 10.0
_REFUSED_SHARE = 0.7
_TURNING = 0.2
_TURNING2 = _TURNING ** 2
# A soft-iron element beyond this many prior standard deviations: start over.
_WILD = 4.0
# Seconds of learning the quality must stay below the threshold, the
# calibration settled, before it counts as converged.
_HOLD = 2.0
_HOLD_TURN = 2.0
# The heading turn of the learned calibration: its mean square over the last
# this many learning steps, from a quality of _WATCH times the threshold on
# (earlier, a calibration still far off would count).
_SHIFT_SAMPLES = 1000.0
_WATCH = 1.0
_SIGNIFICANT = 3.0
# Prior standard deviation of an unknown offset and field, times the first field's norm.
_DIFFUSE = 4.0
# Prior standard deviation of a loaded offset, times the field's norm.
_LOADED_BIAS_STD = 0.05
_MC_INF = float('inf')
_MC_TINY = 1e-300

# --- the state block (offsets from o) ------------------------------------------

_MC_N = 12  # the filter's state: s = m + z (3), z (3), d (5), τ
MC_X = 0  # (s, z, d, τ): s at 0-2, z at 3-5, d at 6-10, τ at 11
MC_P = MC_X + _MC_N  # its covariance, 12 × 12 row-major
# What a fresh start starts from: x[3:] (9), the scale, the covariance of
# x[3:] (9 × 9, row-major) and whether there is a prior and whether it has
# a covariance (restart: yes; load: no, a tighter prior about it).
MC_PRIOR_X = MC_P + _MC_N * _MC_N
MC_PRIOR_SCALE = MC_PRIOR_X + 9
MC_PRIOR_P = MC_PRIOR_SCALE + 1
MC_HAS_PRIOR = MC_PRIOR_P + 81
MC_PRIOR_COV = MC_HAS_PRIOR + 1
MC_SCALE = MC_PRIOR_COV + 1  # A = scale · (I + D)
MC_FRESH = MC_SCALE + 1  # initialize at the next valid field
MC_LOADED = MC_FRESH + 1
MC_CONVERGED = MC_LOADED + 1
MC_IDENTITY = MC_CONVERGED + 1  # the field as given is applied
MC_ENABLED = MC_IDENTITY + 1
MC_QUALITY = MC_ENABLED + 1
MC_STALE = MC_QUALITY + 1  # the quality is assessed when asked for
MC_LEARNED = MC_STALE + 1  # learning steps, for the occasional symmetrization of P
MC_REFUSED_SHARE = MC_LEARNED + 1
MC_NIS = MC_REFUSED_SHARE + 1  # mean normalized innovation squared
MC_CANDIDATE = MC_NIS + 1  # (z, d) when the quality first passed (8)
MC_HELD = MC_CANDIDATE + 8  # time since then (s); -1: not below
MC_SHIFT = MC_HELD + 1  # mean square heading turn of the calibration (rad²)
MC_WATCHED = MC_SHIFT + 1  # samples watched
MC_FIELD_SCALE = MC_WATCHED + 1  # the field's norm, for the noises
# The counts: fields given, used, gated (improbable), refused (by the
# caller), invalid (non-finite or zero), resets (started over).
MC_COUNTS = MC_FIELD_SCALE + 1
MC_FIELDS = MC_COUNTS
MC_USED = MC_COUNTS + 1
MC_GATED = MC_COUNTS + 2
MC_REFUSED = MC_COUNTS + 3
MC_INVALID = MC_COUNTS + 4
MC_RESETS = MC_COUNTS + 5
# What mc_apply uses: A row-major (9), then z (3); the identity where not applied.
MC_COEF = MC_COUNTS + 6
MC_READY = MC_COEF + 12  # converged or loaded, or off
MC_APPLIED = MC_READY + 1
# The latest sample learned from, for the quality assessed lazily.
MC_SEEN_Y = MC_APPLIED + 1
MC_SEEN_UP = MC_SEEN_Y + 3
MC_SEEN_HAS_UP = MC_SEEN_UP + 3
MC_SEEN_LIVE = MC_SEEN_HAS_UP + 1
# What the latest mc_learn did: assessed the quality, watched the heading turn.
MC_ASSESSED = MC_SEEN_LIVE + 1
MC_WATCHING = MC_ASSESSED + 1
# The parameters (MagCalibrator's).
MC_NOISE = MC_WATCHING + 1
MC_FIELD_RW = MC_NOISE + 1
MC_SOFT_IRON = MC_FIELD_RW + 1
MC_DELAY = MC_SOFT_IRON + 1
MC_HEADING = MC_DELAY + 1
MC_DEADBAND = MC_HEADING + 1
MC_DRIFT = MC_DEADBAND + 1
# Scratch: A⁻¹ (3 × 3), H (3 × 12) and A⁻¹ H, P Hᵀ (12 × 3), the
# innovation covariance S and its inverse (3 × 3), the gain K (12 × 3),
# Y(y) (3 × 5), J P (3 × 8) and the calibrated field's covariance (3 × 3).
MC_AI = MC_DRIFT + 1
MC_H = MC_AI + 9
MC_AH = MC_H + 36
MC_PH = MC_AH + 36
MC_S = MC_PH + 36
MC_SI = MC_S + 9
MC_K = MC_SI + 9
MC_YY = MC_K + 36
MC_JP = MC_YY + 15
MC_C = MC_JP + 24
MC_SIZE = MC_C + 9

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
    for k in range(_MC_N + _MC_N * _MC_N):
        s[o + MC_X + k] = 0.0
    for k in range(9 + 1 + 81):
        s[o + MC_PRIOR_X + k] = 0.0
    s[o + MC_HAS_PRIOR] = 0.0
    s[o + MC_PRIOR_COV] = 0.0
    s[o + MC_SCALE] = 1.0
    s[o + MC_FRESH] = 1.0
    s[o + MC_LOADED] = 0.0
    s[o + MC_CONVERGED] = 0.0
    s[o + MC_QUALITY] = _MC_INF
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
                s[o + MC_PRIOR_P + 9 * i + j] = s[o + MC_P + _MC_N * (3 + i) + 3 + j]
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
    watched = (valid and w0 * w0 + w1 * w1 + w2 * w2 > _TURNING2
               and (take or s[o + MC_APPLIED] != 0.0))
    k_share = 1.0 - math.exp(-dt / _REFUSED_TAU)
    share = s[o + MC_REFUSED_SHARE]
    if watched:
        share = share + k_share * ((0.0 if use else 1.0) - share)
        s[o + MC_REFUSED_SHARE] = share
    lost = watched and share > _REFUSED_SHARE
    # A soft iron far outside its prior: the filter has gone astray (a
    # field that changed while it could not yet tell); start over.
    if live:
        wild = _WILD * s[o + MC_SOFT_IRON]
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
            and s[o + MC_QUALITY] < _WATCH * s[o + MC_HEADING]):
        mc_watch(s, o, y0, y1, y2, u0, u1, u2)
        s[o + MC_WATCHING] = 1.0
    mc_cache(s, o)
    return 1.0 if (use or start) else 0.0


def mc_predict(s, o, rw, rx, ry, rz, dt):
    """
    The field turns against the body and walks in the world.

    With ``s = m + z`` (= ``A y``, the field before the offset is removed):
    ``m ← Rᵀ m`` is ``s ← Rᵀ s + (I − Rᵀ) z``. At rest ``R = I`` and nothing
    ties ``s`` to ``z``, which keeps the covariance well conditioned while
    nothing can be learned.
    """
    q2 = 2.0 / (rw * rw + rx * rx + ry * ry + rz * rz)
    r00 = 1.0 - q2 * (ry * ry + rz * rz)
    r01 = q2 * (rx * ry - rw * rz)
    r02 = q2 * (rx * rz + rw * ry)
    r10 = q2 * (rx * ry + rw * rz)
    r11 = 1.0 - q2 * (rx * rx + rz * rz)
    r12 = q2 * (ry * rz - rw * rx)
    r20 = q2 * (rx * rz - rw * ry)
    r21 = q2 * (ry * rz + rw * rx)
    r22 = 1.0 - q2 * (rx * rx + ry * ry)
    # I − R
    e00 = 1.0 - r00
    e11 = 1.0 - r11
    e22 = 1.0 - r22
    x = o + MC_X
    z0 = s[x + 3]
    z1 = s[x + 4]
    z2 = s[x + 5]
    v0 = s[x] - z0
    v1 = s[x + 1] - z1
    v2 = s[x + 2] - z2
    s[x] = r00 * v0 + r10 * v1 + r20 * v2 + z0
    s[x + 1] = r01 * v0 + r11 * v1 + r21 * v2 + z1
    s[x + 2] = r02 * v0 + r12 * v1 + r22 * v2 + z2
    p = o + MC_P
    # P[s, :] ← Rᵀ P[s, :] + (I − Rᵀ) P[z, :]
    for c in range(_MC_N):
        a0 = s[p + c]
        a1 = s[p + _MC_N + c]
        a2 = s[p + 2 * _MC_N + c]
        b0 = s[p + 3 * _MC_N + c]
        b1 = s[p + 4 * _MC_N + c]
        b2 = s[p + 5 * _MC_N + c]
        s[p + c] = (r00 * a0 + r10 * a1 + r20 * a2) + (e00 * b0 - r10 * b1 - r20 * b2)
        s[p + _MC_N + c] = (r01 * a0 + r11 * a1 + r21 * a2) + (-r01 * b0 + e11 * b1 - r21 * b2)
        s[p + 2 * _MC_N + c] = (r02 * a0 + r12 * a1 + r22 * a2) + (-r02 * b0 - r12 * b1
                                                                + e22 * b2)
    # P[:, s] ← P[:, s] R + P[:, z] (I − R)
    for i in range(_MC_N):
        row = p + _MC_N * i
        a0 = s[row]
        a1 = s[row + 1]
        a2 = s[row + 2]
        b0 = s[row + 3]
        b1 = s[row + 4]
        b2 = s[row + 5]
        s[row] = (a0 * r00 + a1 * r10 + a2 * r20) + (b0 * e00 - b1 * r10 - b2 * r20)
        s[row + 1] = (a0 * r01 + a1 * r11 + a2 * r21) + (-b0 * r01 + b1 * e11 - b2 * r21)
        s[row + 2] = (a0 * r02 + a1 * r12 + a2 * r22) + (-b0 * r02 - b1 * r12 + b2 * e22)
    a = s[o + MC_FIELD_RW] * s[o + MC_FIELD_SCALE]
    q = a * a * dt
    for i in range(3):
        s[p + (_MC_N + 1) * i] += q
    drift = s[o + MC_DRIFT]
    if drift != 0.0:
        # The offset drifts (temperature, a payload moved): never quite
        # frozen. s = m + z drifts with it.
        a = drift * s[o + MC_FIELD_SCALE]
        q = a * a * dt
        for i in range(3):
            s[p + (_MC_N + 1) * i] += q
        for i in range(3):
            s[p + _MC_N * i + 3 + i] += q
        for i in range(3):
            s[p + _MC_N * (3 + i) + i] += q
        for i in range(3):
            s[p + (_MC_N + 1) * (3 + i)] += q


def mc_update(s, o, y0, y1, y2, w0, w1, w2, live, norm):
    """
    One (gated) Kalman update with ``y = A⁻¹ (s + τ ω × (s − z))``; 1.0 if used.

    Linear in ``s`` and ``z``, linearized in ``d`` and ``τ`` about the
    estimate: the measured ``y`` never enters the gain (written as
    ``A y = s + …`` with ``y`` in the regressor, its noise would pull ``A``
    towards 0 at rest, the errors-in-variables bias). Where not ``live``
    only the step is counted.
    """
    use = False
    x = o + MC_X
    p = o + MC_P
    if live:
        s0 = s[x]
        s1 = s[x + 1]
        s2 = s[x + 2]
        z0 = s[x + 3]
        z1 = s[x + 4]
        z2 = s[x + 5]
        d0 = s[x + 6]
        d1 = s[x + 7]
        d2 = s[x + 8]
        d3 = s[x + 9]
        d4 = s[x + 10]
        tau = s[x + 11]
        m0 = s0 - z0
        m1 = s1 - z1
        m2 = s2 - z2
        c0 = w1 * m2 - w2 * m1
        c1 = w2 * m0 - w0 * m2
        c2 = w0 * m1 - w1 * m0
        ai = o + MC_AI
        mc_inv3(s, ai, 1.0 + d0, d2, d3, d2, 1.0 + d1, d4, d3, d4, 1.0 - d0 - d1)
        v0 = s0 + tau * c0
        v1 = s1 + tau * c1
        v2 = s2 + tau * c2
        p0 = s[ai] * v0 + s[ai + 1] * v1 + s[ai + 2] * v2
        p1 = s[ai + 3] * v0 + s[ai + 4] * v1 + s[ai + 5] * v2
        p2 = s[ai + 6] * v0 + s[ai + 7] * v1 + s[ai + 8] * v2
        nu0 = y0 - p0
        nu1 = y1 - p1
        nu2 = y2 - p2
        tw0 = tau * w0
        tw1 = tau * w1
        tw2 = tau * w2
        # H: I + τ[ω]× for s, −τ[ω]× for z, −Y(pred) for d, ω × m for τ;
        # then A⁻¹ H.
        h = o + MC_H
        for k in range(36):
            s[h + k] = 0.0
        s[h] = 1.0
        s[h + 1] = -tw2
        s[h + 2] = tw1
        s[h + 4] = tw2
        s[h + 5] = -tw1
        s[h + 6] = -p0
        s[h + 8] = -p1
        s[h + 9] = -p2
        s[h + 11] = c0
        s[h + 12] = tw2
        s[h + 13] = 1.0
        s[h + 14] = -tw0
        s[h + 15] = -tw2
        s[h + 17] = tw0
        s[h + 19] = -p1
        s[h + 20] = -p0
        s[h + 22] = -p2
        s[h + 23] = c1
        s[h + 24] = -tw1
        s[h + 25] = tw0
        s[h + 26] = 1.0
        s[h + 27] = tw1
        s[h + 28] = -tw0
        s[h + 30] = p2
        s[h + 31] = p2
        s[h + 33] = -p0
        s[h + 34] = -p1
        s[h + 35] = c2
        ah = o + MC_AH
        for r in range(3):
            a0 = s[ai + 3 * r]
            a1 = s[ai + 3 * r + 1]
            a2 = s[ai + 3 * r + 2]
            for c in range(_MC_N):
                s[ah + _MC_N * r + c] = (a0 * s[h + c] + a1 * s[h + _MC_N + c]
                                         + a2 * s[h + 2 * _MC_N + c])
        # P Hᵀ, and S = H P Hᵀ + R summed along (the rows of P Hᵀ in order).
        # Written out, with the rows of A⁻¹ H held: the hot loop.
        a0, a1, a2, a3, a4, a5 = s[ah], s[ah + 1], s[ah + 2], s[ah + 3], s[ah + 4], s[ah + 5]
        a6, a7, a8, a9, a10, a11 = (s[ah + 6], s[ah + 7], s[ah + 8], s[ah + 9], s[ah + 10],
                                    s[ah + 11])
        b = ah + _MC_N
        b0, b1, b2, b3, b4, b5 = s[b], s[b + 1], s[b + 2], s[b + 3], s[b + 4], s[b + 5]
        b6, b7, b8, b9, b10, b11 = s[b + 6], s[b + 7], s[b + 8], s[b + 9], s[b + 10], s[b + 11]
        e = ah + 2 * _MC_N
        e0, e1, e2, e3, e4, e5 = s[e], s[e + 1], s[e + 2], s[e + 3], s[e + 4], s[e + 5]
        e6, e7, e8, e9, e10, e11 = s[e + 6], s[e + 7], s[e + 8], s[e + 9], s[e + 10], s[e + 11]
        ph = o + MC_PH
        s00 = s01 = s02 = s10 = s11 = s12 = s20 = s21 = s22 = 0.0
        for i in range(_MC_N):
            row = p + _MC_N * i
            q0, q1, q2, q3, q4, q5 = (s[row], s[row + 1], s[row + 2], s[row + 3], s[row + 4],
                                      s[row + 5])
            q6, q7, q8, q9, q10, q11 = (s[row + 6], s[row + 7], s[row + 8], s[row + 9],
                                        s[row + 10], s[row + 11])
            v0 = (q0 * a0 + q1 * a1 + q2 * a2 + q3 * a3 + q4 * a4 + q5 * a5 + q6 * a6 + q7 * a7
                  + q8 * a8 + q9 * a9 + q10 * a10 + q11 * a11)
            v1 = (q0 * b0 + q1 * b1 + q2 * b2 + q3 * b3 + q4 * b4 + q5 * b5 + q6 * b6 + q7 * b7
                  + q8 * b8 + q9 * b9 + q10 * b10 + q11 * b11)
            v2 = (q0 * e0 + q1 * e1 + q2 * e2 + q3 * e3 + q4 * e4 + q5 * e5 + q6 * e6 + q7 * e7
                  + q8 * e8 + q9 * e9 + q10 * e10 + q11 * e11)
            s[ph + 3 * i] = v0
            s[ph + 3 * i + 1] = v1
            s[ph + 3 * i + 2] = v2
            f0 = s[ah + i]
            f1 = s[b + i]
            f2 = s[e + i]
            s00 += f0 * v0
            s01 += f0 * v1
            s02 += f0 * v2
            s10 += f1 * v0
            s11 += f1 * v1
            s12 += f1 * v2
            s20 += f2 * v0
            s21 += f2 * v1
            s22 += f2 * v2
        a = s[o + MC_NOISE] * s[o + MC_FIELD_SCALE]
        a = a * a
        s00 += a
        s11 += a
        s22 += a
        sm = o + MC_S
        s[sm] = s00
        s[sm + 1] = s01
        s[sm + 2] = s02
        s[sm + 3] = s10
        s[sm + 4] = s11
        s[sm + 5] = s12
        s[sm + 6] = s20
        s[sm + 7] = s21
        s[sm + 8] = s22
        si = o + MC_SI
        mc_inv3(s, si, s00, s01, s02, s10, s11, s12, s20, s21, s22)
        i00, i01, i02, i10, i11, i12 = s[si], s[si + 1], s[si + 2], s[si + 3], s[si + 4], s[si + 5]
        i20, i21, i22 = s[si + 6], s[si + 7], s[si + 8]
        nis = (nu0 * i00 * nu0 + nu0 * i01 * nu1 + nu0 * i02 * nu2
               + nu1 * i10 * nu0 + nu1 * i11 * nu1 + nu1 * i12 * nu2
               + nu2 * i20 * nu0 + nu2 * i21 * nu1 + nu2 * i22 * nu2)
        use = nis < GATE
        capped = nis
        if 3.0 * GATE < nis:
            capped = 3.0 * GATE
        s[o + MC_NIS] = s[o + MC_NIS] + 0.02 * (capped - s[o + MC_NIS])
        if use:
            # K = P Hᵀ S⁻¹, x += K ν, P −= K (P Hᵀ)ᵀ, a row of K at a time.
            g0a, g0b, g0c = s[ph], s[ph + 1], s[ph + 2]
            g1a, g1b, g1c = s[ph + 3], s[ph + 4], s[ph + 5]
            g2a, g2b, g2c = s[ph + 6], s[ph + 7], s[ph + 8]
            g3a, g3b, g3c = s[ph + 9], s[ph + 10], s[ph + 11]
            g4a, g4b, g4c = s[ph + 12], s[ph + 13], s[ph + 14]
            g5a, g5b, g5c = s[ph + 15], s[ph + 16], s[ph + 17]
            g6a, g6b, g6c = s[ph + 18], s[ph + 19], s[ph + 20]
            g7a, g7b, g7c = s[ph + 21], s[ph + 22], s[ph + 23]
            g8a, g8b, g8c = s[ph + 24], s[ph + 25], s[ph + 26]
            g9a, g9b, g9c = s[ph + 27], s[ph + 28], s[ph + 29]
            g10a, g10b, g10c = s[ph + 30], s[ph + 31], s[ph + 32]
            g11a, g11b, g11c = s[ph + 33], s[ph + 34], s[ph + 35]
            kk = o + MC_K
            for i in range(_MC_N):
                f0 = s[ph + 3 * i]
                f1 = s[ph + 3 * i + 1]
                f2 = s[ph + 3 * i + 2]
                k0 = f0 * i00 + f1 * i10 + f2 * i20
                k1 = f0 * i01 + f1 * i11 + f2 * i21
                k2 = f0 * i02 + f1 * i12 + f2 * i22
                s[kk + 3 * i] = k0
                s[kk + 3 * i + 1] = k1
                s[kk + 3 * i + 2] = k2
                s[x + i] += k0 * nu0 + k1 * nu1 + k2 * nu2
                row = p + _MC_N * i
                s[row] -= k0 * g0a + k1 * g0b + k2 * g0c
                s[row + 1] -= k0 * g1a + k1 * g1b + k2 * g1c
                s[row + 2] -= k0 * g2a + k1 * g2b + k2 * g2c
                s[row + 3] -= k0 * g3a + k1 * g3b + k2 * g3c
                s[row + 4] -= k0 * g4a + k1 * g4b + k2 * g4c
                s[row + 5] -= k0 * g5a + k1 * g5b + k2 * g5c
                s[row + 6] -= k0 * g6a + k1 * g6b + k2 * g6c
                s[row + 7] -= k0 * g7a + k1 * g7b + k2 * g7c
                s[row + 8] -= k0 * g8a + k1 * g8b + k2 * g8c
                s[row + 9] -= k0 * g9a + k1 * g9b + k2 * g9c
                s[row + 10] -= k0 * g10a + k1 * g10b + k2 * g10c
                s[row + 11] -= k0 * g11a + k1 * g11b + k2 * g11c
    learned = s[o + MC_LEARNED] + 1.0
    s[o + MC_LEARNED] = learned
    if learned % 64.0 == 0.0:  # rounding makes P drift from symmetric, slowly
        mc_symmetrize(s, p)
    if use:
        m0 = s[x] - s[x + 3]
        m1 = s[x + 1] - s[x + 4]
        m2 = s[x + 2] - s[x + 5]
        scale = math.sqrt(m0 * m0 + m1 * m1 + m2 * m2)
        if 0.25 * norm > scale:
            scale = 0.25 * norm
        s[o + MC_FIELD_SCALE] = scale
    return use


def mc_start(s, o, y0, y1, y2, norm):
    """Initialize the filter from the field ``y`` (of norm ``norm``)."""
    x = o + MC_X
    p = o + MC_P
    for k in range(_MC_N + _MC_N * _MC_N):
        s[x + k] = 0.0
    soft = s[o + MC_SOFT_IRON]
    delay = s[o + MC_DELAY]
    if s[o + MC_HAS_PRIOR] == 0.0:
        s[o + MC_SCALE] = 1.0
        big = _DIFFUSE * norm
        big = big * big
        for i in range(3, 6):
            s[p + (_MC_N + 1) * i] = big
        for i in range(6, 11):
            s[p + (_MC_N + 1) * i] = soft * soft
        s[p + (_MC_N + 1) * 11] = delay * delay
    else:
        for k in range(9):
            s[x + 3 + k] = s[o + MC_PRIOR_X + k]
        s[o + MC_SCALE] = s[o + MC_PRIOR_SCALE]
        if s[o + MC_PRIOR_COV] != 0.0:
            for i in range(9):
                for j in range(9):
                    s[p + _MC_N * (3 + i) + 3 + j] = s[o + MC_PRIOR_P + 9 * i + j]
        else:  # loaded: a tighter prior about it
            std = _LOADED_BIAS_STD * norm / s[o + MC_SCALE]
            for i in range(3, 6):
                s[p + (_MC_N + 1) * i] = std * std
            a = 0.2 * soft
            for i in range(6, 11):
                s[p + (_MC_N + 1) * i] = a * a
            s[p + (_MC_N + 1) * 11] = delay * delay
    # s = A y = y + Y(y) d: as uncertain as d (and correlated with it),
    # plus the noise; independent of the offset.
    yy = o + MC_YY
    for k in range(15):
        s[yy + k] = 0.0
    s[yy] = y0
    s[yy + 2] = y1
    s[yy + 3] = y2
    s[yy + 6] = y1
    s[yy + 7] = y0
    s[yy + 9] = y2
    s[yy + 10] = -y2
    s[yy + 11] = -y2
    s[yy + 13] = y0
    s[yy + 14] = y1
    for r in range(3):
        acc = 0.0
        for k in range(5):
            acc += s[yy + 5 * r + k] * s[x + 6 + k]
        s[x + r] = (y0 if r == 0 else y1 if r == 1 else y2) + acc
    # P[s, 3:] = Y P[d, 3:], and its transpose
    for r in range(3):
        for c in range(3, _MC_N):
            acc = 0.0
            for k in range(5):
                acc += s[yy + 5 * r + k] * s[p + _MC_N * (6 + k) + c]
            s[p + _MC_N * r + c] = acc
    for r in range(3):
        for c in range(3, _MC_N):
            s[p + _MC_N * c + r] = s[p + _MC_N * r + c]
    # P[s, s] = Y P[d, d] Yᵀ + noise² I; Y P[d, d] into the scratch of K
    t = o + MC_K
    for r in range(3):
        for c in range(5):
            acc = 0.0
            for k in range(5):
                acc += s[yy + 5 * r + k] * s[p + _MC_N * (6 + k) + 6 + c]
            s[t + 5 * r + c] = acc
    noise = s[o + MC_NOISE] * norm
    for r in range(3):
        for c in range(3):
            acc = 0.0
            for k in range(5):
                acc += s[t + 5 * r + k] * s[yy + 5 * c + k]
            if r == c:
                acc += noise * noise
            s[p + _MC_N * r + c] = acc
    m0 = s[x] - s[x + 3]
    m1 = s[x + 1] - s[x + 4]
    m2 = s[x + 2] - s[x + 5]
    scale = math.sqrt(m0 * m0 + m1 * m1 + m2 * m2)
    if 0.25 * norm > scale:
        scale = 0.25 * norm
    s[o + MC_FIELD_SCALE] = scale
    s[o + MC_REFUSED_SHARE] = 0.0
    s[o + MC_FRESH] = 0.0


def mc_watch(s, o, y0, y1, y2, u0, u1, u2):
    """How far the learned calibration turns the heading from the field as given."""
    f0, f1, f2 = mc_calibrated(s, o + MC_X + 3, y0, y1, y2)
    angle = mc_heading_between(u0, u1, u2, y0, y1, y2, f0, f1, f2)
    # A mean over the samples watched, then over the last _SHIFT_SAMPLES.
    watched = s[o + MC_WATCHED] + 1.0
    s[o + MC_WATCHED] = watched
    n = watched
    if n < 1.0:
        n = 1.0
    if n > _SHIFT_SAMPLES:
        n = _SHIFT_SAMPLES
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
    a = _SIGNIFICANT * s[o + MC_QUALITY]
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
    p = o + MC_P + _MC_N * 3 + 3
    jp = o + MC_JP
    for c in range(8):
        s[jp + c] = (-s[p + c] + y0 * s[p + _MC_N * 3 + c] + y1 * s[p + _MC_N * 5 + c]
                     + y2 * s[p + _MC_N * 6 + c])
        s[jp + 8 + c] = (-s[p + _MC_N + c] + y1 * s[p + _MC_N * 4 + c] + y0 * s[p + _MC_N * 5 + c]
                         + y2 * s[p + _MC_N * 7 + c])
        s[jp + 16 + c] = (-s[p + 2 * _MC_N + c] - y2 * s[p + _MC_N * 3 + c]
                          - y2 * s[p + _MC_N * 4 + c] + y0 * s[p + _MC_N * 6 + c]
                          + y1 * s[p + _MC_N * 7 + c])
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
        if h < _MC_TINY:
            h = _MC_TINY
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
    if h < _MC_TINY:
        h = _MC_TINY
    quality = across / h
    s[o + MC_QUALITY] = quality
    # Converged once the quality has stayed below the threshold for _HOLD s
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
        else:
            turned = abs(mc_heading_between(y0, y1, y2, f0, f1, f2, g0, g1, g2))
        if turned > _HOLD_TURN * heading:
            for k in range(8):
                s[cand + k] = s[x + 3 + k]
            s[o + MC_HELD] = 0.0
        else:
            held = s[o + MC_HELD]
            if held < 0.0:
                held = 0.0
            s[o + MC_HELD] = held + dt
        if s[o + MC_HELD] >= _HOLD:
            s[o + MC_CONVERGED] = 1.0
    # The hold pauses while the quality is a little above the threshold (it
    # changes with the attitude), and ends well above it.
    if learning and quality > _HOLD_TURN * heading:
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

def mc_inv3(s, out, a, b, c, d, e, f, g, h, i):
    """The inverse of ``[[a, b, c], [d, e, f], [g, h, i]]`` (cofactors) into ``s[out:out + 9]``."""
    c00 = e * i - f * h
    c01 = f * g - d * i
    c02 = d * h - e * g
    det = a * c00 + b * c01 + c * c02
    s[out] = c00 / det
    s[out + 1] = (c * h - b * i) / det
    s[out + 2] = (b * f - c * e) / det
    s[out + 3] = c01 / det
    s[out + 4] = (a * i - c * g) / det
    s[out + 5] = (c * d - a * f) / det
    s[out + 6] = c02 / det
    s[out + 7] = (b * g - a * h) / det
    s[out + 8] = (a * e - b * d) / det


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
    """The angle (rad) about ``u`` from the horizontal part of ``f`` to that of ``g``."""
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


def mc_symmetrize(s, p):
    """``P ← (P + Pᵀ) / 2`` for the 12 × 12 matrix at ``s[p:]``."""
    for i in range(_MC_N):
        for j in range(i + 1, _MC_N):
            v = 0.5 * (s[p + _MC_N * i + j] + s[p + _MC_N * j + i])
            s[p + _MC_N * i + j] = v
            s[p + _MC_N * j + i] = v
