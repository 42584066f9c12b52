"""
The magnetometer calibration's tuning, and its state: the record :data:`CAL`.

One calibrator's state is a record of :data:`CAL`'s fields
(:mod:`~ext_observer.core.ahrs.record`), each declared below with its unit
and meaning; :mod:`~ext_observer.core.ahrs.magcal_kernel` does the maths on
it. The filter's state ``x`` is one vector for the Kalman algebra; its
parts are read and written by name, through :func:`field_with_offset_of`,
:func:`offset_of`, :func:`soft_iron_of`, :func:`lag_of` and
:func:`set_field_with_offset` (the one place their positions are read), and
the blocks of its covariance ``p`` by the parts' first rows (``CAL_S``,
``CAL_Z``, ``CAL_D``, ``CAL_TAU``). "field" is the unit of the fields the
calibrator is given (any unit).
"""

from .record import Group
from .small_matrix import store3, value_at, vec3_at, vec5_at

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

# --- the filter's state x (s, z, d, τ) and the rows of its covariance P ---------------

CAL_N = 12  # the filter's state: s = m + z (3), z (3), d (5), τ
# Where each part starts (in x, and as rows of P).
CAL_S = 0
CAL_Z = 3
CAL_D = 6
CAL_TAU = 11
CAL_ZD = 8  # the calibration proper, (z, d)
CAL_ZDT = CAL_N - CAL_Z  # what a prior holds: (z, d, τ), x[CAL_Z:]
CAL_NY = 5  # d, and the columns of Y(y), with D(d) y = Y(y) d


# --- the parts of x, by name -----------------------------------------------------------


def field_with_offset_of(x):
    """``s = m + z = A y`` (field, body frame): the calibrated field, its offset still in."""
    return vec3_at(x, CAL_S)


def set_field_with_offset(x, s):
    """``s`` (a 3-tuple) into ``x``."""
    store3(x, CAL_S, s)


def offset_of(x):
    """``z`` (field, body frame): the hard-iron offset."""
    return vec3_at(x, CAL_Z)


def soft_iron_of(x):
    """``d`` (5-tuple, 1): the soft iron, ``A = I + D(d)``, ``D(d)`` symmetric and traceless."""
    return vec5_at(x, CAL_D, 1)


def lag_of(x):
    """``τ`` (s): how far the field lags the gyro."""
    return value_at(x, CAL_TAU)

# --- the state -------------------------------------------------------------------

CAL = Group('cal', "one magnetometer calibrator: its Kalman filter, prior, verdicts, counts, "
            "parameters and scratch", [
                # The filter on x = (s, z, d, τ): A = I + D(d) and the offset z
                # calibrate a field y as A y − z = m, with s = m + z = A y.
                ('x', 'field (s, z), 1 (d), s (τ)', 's at 0-2, z at 3-5, d at 6-10, τ at 11',
                 CAL_N),
                ('p', "x's units²", "x's covariance, 12 × 12 row-major", CAL_N * CAL_N),
                # What a fresh start starts from (a restart: what was learned, with its
                # covariance; a load: a saved calibration, a tighter prior about it).
                ('prior_x', 'field (z), 1 (d), s (τ)', "the prior's (z, d, τ)", CAL_ZDT),
                ('prior_scale', '1', "the prior's scale"),
                ('prior_p', "prior_x's units²", "prior_x's covariance, 9 × 9 row-major",
                 CAL_ZDT * CAL_ZDT),
                ('has_prior', 'flag', 'a fresh start starts from the prior'),
                ('prior_cov', 'flag', 'the prior has a covariance (a restart)'),
                ('scale', '1', 'the calibrated field is scale · (A y − z)'),
                # Where the calibration stands.
                ('fresh', 'flag', 'the filter starts afresh at the next valid field'),
                ('loaded', 'flag', 'a saved calibration was loaded'),
                ('converged', 'flag', 'the quality passed the threshold and held'),
                ('identity', 'flag', 'the field as given is applied, not the calibration'),
                ('enabled', 'flag', 'the calibrator is on'),
                ('quality', 'rad', "heading error (1σ) from the calibration's uncertainty"),
                ('stale', 'flag', 'the quality is assessed when asked for'),
                ('learned', 'count', 'learning steps, for the occasional symmetrization of p'),
                ('refused_share', '1', 'share of the fields refused while turning, low-passed'),
                ('nis', '1', 'mean normalized innovation squared'),
                ('candidate', 'field (z), 1 (d)', '(z, d) when the quality first passed',
                 CAL_ZD),
                ('held', 's', 'time since, the quality below the threshold; -1: not below'),
                ('shift', 'rad²', 'mean square heading turn of the calibration'),
                ('watched', 'count', 'samples whose heading turn was watched'),
                ('field_scale', 'field', "the field's norm the noises scale with"),
                # The counts, in MagCalibrator's order.
                ('fields', 'count', 'fields given'),
                ('used', 'count', 'fields learned from'),
                ('gated', 'count', 'fields refused as improbable (the gate)'),
                ('refused', 'count', 'fields refused by the caller'),
                ('invalid', 'count', 'fields not finite, or zero'),
                ('resets', 'count', 'start-overs (the calibration no longer fitted)'),
                # What mc_apply uses: the identity where not applied.
                ('coef', '1 (A), field (z)', 'scale · A row-major, then scale · z', 12),
                ('ready', 'flag', 'converged or loaded, or the calibrator off'),
                ('applied', 'flag', 'mc_apply applies the calibration, not the identity'),
                # The latest sample learned from, for the quality assessed lazily.
                ('seen_y', 'field', 'its field, body frame', 3),
                ('seen_up', '1', "the world's vertical then, body frame (unit)", 3),
                ('seen_has_up', 'flag', 'seen_up is known'),
                ('seen_live', 'flag', 'its field was learned from (not a fresh start)'),
                # What the latest mc_learn did.
                ('assessed', 'flag', 'it assessed the quality'),
                ('watching', 'flag', 'it watched the heading turn'),
                # The parameters (MagCalibrator's).
                ('noise', '1', "the field's noise per sample and axis, over its norm"),
                ('field_rw', '1/√s', "the field's random walk in the world, over its norm"),
                ('soft_iron', '1', 'prior standard deviation of each element of S − I'),
                ('delay', 's', "prior standard deviation of the field's lag behind the gyro"),
                ('heading', 'rad', 'converged when the quality is below this'),
                ('deadband', 'rad', 'applied once it turns the heading by more (RMS)'),
                ('drift', '1/√s', "the offset's random walk, over the field's norm"),
                # Scratch of the filter's steps.
                ('ai', '1', 'A⁻¹, 3 × 3', 9),
                ('h', '1 (s, z), field (d), field/s (τ)',
                 'H, the Jacobian of A ŷ = s + τ ω × (s − z), 3 × 12', 3 * CAL_N),
                ('ah', "as h", "A⁻¹ H, the measurement's Jacobian, 3 × 12", 3 * CAL_N),
                ('ph', "x's units · field", 'P (A⁻¹ H)ᵀ, 12 × 3', 3 * CAL_N),
                ('s', 'field²', 'the innovation covariance S, 3 × 3', 9),
                ('si', '1/field²', 'S⁻¹', 9),
                ('k', "x's units / field", 'the gain K, 12 × 3 (a start: Y(y) P[d, d], 3 × 5)',
                 3 * CAL_N),
                ('yy', 'field', 'Y(y), 3 × 5', 3 * CAL_NY),
                ('jp', 'field² (z), field (d)', 'J P[zd, zd], 3 × 8, with J = [−I, Y(y)]',
                 3 * CAL_ZD),
                ('c', 'field²', "the calibrated field's covariance J P Jᵀ, 3 × 3", 9),
            ])


__all__ = [name for name in dir() if name.startswith('CAL_')] + [
    'CAL', 'GATE', 'field_with_offset_of', 'lag_of', 'offset_of', 'set_field_with_offset',
    'soft_iron_of']
