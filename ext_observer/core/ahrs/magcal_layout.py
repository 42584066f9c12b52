"""
The magnetometer calibration's tuning and the layout of its state block.

One calibrator's state is :data:`MC_SIZE` floats from an offset ``o`` of a
container; the ``MC_*`` constants are the slots, relative to ``o``
(:mod:`~ext_observer.core.ahrs.magcal_kernel` says what they hold and does the
maths).
"""

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

__all__ = [name for name in dir() if name.startswith('MC_')] + ['GATE']
