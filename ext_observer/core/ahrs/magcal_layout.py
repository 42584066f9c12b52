"""
The magnetometer calibration's tuning and the layout of its state block.

One calibrator's state is :data:`MC_SIZE` floats from an offset ``o`` of a
container; the ``MC_*`` constants are the slots, relative to ``o``
(:mod:`~ext_observer.core.ahrs.magcal_kernel` says what they hold and does the
maths).
"""

from .layout import Layout

# --- tuning -------------------------------------------------------------------

# Innovations beyond this (χ², 3 degrees of freedom; 16.3 is 99.9 %) are refused.
GATE = 16.0
# The share of fields refused while the body turns faster than CAL_TURNING
# (rad/s), with this time constant (s): above CAL_REFUSED_SHARE, start over.
CAL_REFUSED_TAU = 10.0
CAL_REFUSED_SHARE = 0.7
CAL_TURNING = 0.2
CAL_TURNING2 = CAL_TURNING ** 2
# A soft-iron element beyond this many prior standard deviations: start over.
CAL_WILD = 4.0
# Seconds of learning the quality must stay below the threshold, the
# calibration settled, before it counts as converged.
CAL_HOLD = 2.0
CAL_HOLD_TURN = 2.0
# The heading turn of the learned calibration: its mean square over the last
# this many learning steps, from a quality of CAL_WATCH times the threshold on
# (earlier, a calibration still far off would count).
CAL_SHIFT_SAMPLES = 1000.0
CAL_WATCH = 1.0
CAL_SIGNIFICANT = 3.0
# Prior standard deviation of an unknown offset and field, times the first field's norm.
CAL_DIFFUSE = 4.0
# Prior standard deviation of a loaded offset, times the field's norm.
CAL_LOADED_BIAS_STD = 0.05
CAL_INF = float('inf')
CAL_TINY = 1e-300
# The mean NIS: smoothed by this share per update (about the last 50), each
# NIS counted at most CAL_NIS_CAP times the gate (a passing magnet weighs no
# more), started at its expected value (3 degrees of freedom).
CAL_NIS_RATE = 0.02
CAL_NIS_CAP = 3.0
CAL_NIS_EXPECTED = 3.0
# Learning steps between symmetrizations of P (rounding makes it drift, slowly).
CAL_SYMMETRIZE_EVERY = 64.0
# The field's norm the noises scale with: at least this share of the raw field's.
CAL_SCALE_FLOOR = 0.25
# Prior standard deviation of a loaded soft iron, times the soft-iron parameter.
CAL_LOADED_SOFT_SHARE = 0.2

# --- the state block (offsets from o) ------------------------------------------

MAGCAL = Layout()
CAL_N = 12  # the filter's state: s = m + z (3), z (3), d (5), τ
# Where each part of the filter's state starts (in x, and as rows of P).
CAL_S = 0
CAL_Z = 3
CAL_D = 6
CAL_TAU = 11
CAL_ZD = 8  # the calibration proper, (z, d)
CAL_NY = 5  # d, and the columns of Y(y), with D(d) y = Y(y) d
MC_X = MAGCAL.field('x', CAL_N)  # (s, z, d, τ): s at 0-2, z at 3-5, d at 6-10, τ at 11
MC_P = MAGCAL.field('p', CAL_N * CAL_N)  # its covariance, 12 × 12 row-major
# What a fresh start starts from: x[3:] (9), the scale, the covariance of
# x[3:] (9 × 9, row-major) and whether there is a prior and whether it has
# a covariance (restart: yes; load: no, a tighter prior about it).
MC_PRIOR_X = MAGCAL.field('prior_x', 9)
MC_PRIOR_SCALE = MAGCAL.field('prior_scale')
MC_PRIOR_P = MAGCAL.field('prior_p', 81)
MC_HAS_PRIOR = MAGCAL.field('has_prior')
MC_PRIOR_COV = MAGCAL.field('prior_cov')
MC_SCALE = MAGCAL.field('scale')  # A = scale · (I + D)
MC_FRESH = MAGCAL.field('fresh')  # initialize at the next valid field
MC_LOADED = MAGCAL.field('loaded')
MC_CONVERGED = MAGCAL.field('converged')
MC_IDENTITY = MAGCAL.field('identity')  # the field as given is applied
MC_ENABLED = MAGCAL.field('enabled')
MC_QUALITY = MAGCAL.field('quality')
MC_STALE = MAGCAL.field('stale')  # the quality is assessed when asked for
MC_LEARNED = MAGCAL.field('learned')  # learning steps, for the occasional symmetrization of P
MC_REFUSED_SHARE = MAGCAL.field('refused_share')
MC_NIS = MAGCAL.field('nis')  # mean normalized innovation squared
MC_CANDIDATE = MAGCAL.field('candidate', 8)  # (z, d) when the quality first passed
MC_HELD = MAGCAL.field('held')  # time since then (s); -1: not below
MC_SHIFT = MAGCAL.field('shift')  # mean square heading turn of the calibration (rad²)
MC_WATCHED = MAGCAL.field('watched')  # samples watched
MC_FIELD_SCALE = MAGCAL.field('field_scale')  # the field's norm, for the noises
# The counts (MC_COUNTS, in this order): fields given, used, gated
# (improbable), refused (by the caller), invalid (non-finite or zero),
# resets (started over).
MC_FIELDS = MAGCAL.field('fields')
MC_USED = MAGCAL.field('used')
MC_GATED = MAGCAL.field('gated')
MC_REFUSED = MAGCAL.field('refused')
MC_INVALID = MAGCAL.field('invalid')
MC_RESETS = MAGCAL.field('resets')
MC_COUNTS = MC_FIELDS
# What mc_apply uses: A row-major (9), then z (3); the identity where not applied.
MC_COEF = MAGCAL.field('coef', 12)
MC_READY = MAGCAL.field('ready')  # converged or loaded, or off
MC_APPLIED = MAGCAL.field('applied')
# The latest sample learned from, for the quality assessed lazily.
MC_SEEN_Y = MAGCAL.field('seen_y', 3)
MC_SEEN_UP = MAGCAL.field('seen_up', 3)
MC_SEEN_HAS_UP = MAGCAL.field('seen_has_up')
MC_SEEN_LIVE = MAGCAL.field('seen_live')
# What the latest mc_learn did: assessed the quality, watched the heading turn.
MC_ASSESSED = MAGCAL.field('assessed')
MC_WATCHING = MAGCAL.field('watching')
# The parameters (MagCalibrator's).
MC_NOISE = MAGCAL.field('noise')
MC_FIELD_RW = MAGCAL.field('field_rw')
MC_SOFT_IRON = MAGCAL.field('soft_iron')
MC_DELAY = MAGCAL.field('delay')
MC_HEADING = MAGCAL.field('heading')
MC_DEADBAND = MAGCAL.field('deadband')
MC_DRIFT = MAGCAL.field('drift')
# Scratch: A⁻¹ (3 × 3), H (3 × 12) and A⁻¹ H, P Hᵀ (12 × 3), the
# innovation covariance S and its inverse (3 × 3), the gain K (12 × 3),
# Y(y) (3 × 5), J P (3 × 8) and the calibrated field's covariance (3 × 3).
MC_AI = MAGCAL.field('ai', 9)
MC_H = MAGCAL.field('h', 36)
MC_AH = MAGCAL.field('ah', 36)
MC_PH = MAGCAL.field('ph', 36)
MC_S = MAGCAL.field('s', 9)
MC_SI = MAGCAL.field('si', 9)
MC_K = MAGCAL.field('k', 36)
MC_YY = MAGCAL.field('yy', 15)
MC_JP = MAGCAL.field('jp', 24)
MC_C = MAGCAL.field('c', 9)
MC_SIZE = MAGCAL.size

__all__ = ([name for name in dir() if name.startswith(('MC_', 'CAL_'))]
           + ['GATE', 'MAGCAL'])
