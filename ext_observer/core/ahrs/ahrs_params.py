"""
The raw-IMU estimator's parameters (:class:`AhrsParams`) and its covariance's
(:class:`UncertaintyParams`).

What a user tunes: time constants in seconds, thresholds in rad/s and m/s²
(VQF's way; see :mod:`ext_observer.core.ahrs.ahrs_observer`). :data:`AHRS_TABLE`
declares each once (name, default, unit, range, one line); the node's
``ahrs.*`` parameters, docs/parameters.md and config/imu_filter.yaml come
from it. A bad value raises ``ValueError`` naming the parameter.
"""

import math

from .parameter_rows import Tunable, Tunables

__all__ = ['AHRS_TABLE', 'AhrsParams', 'UNCERTAINTY_TABLE', 'UncertaintyParams']

# Time constants above this are "forever" (s).
_LONG = 1e4
_T = Tunable

AHRS_TABLE = (
    # Theorem 1 on S³ (ε = 0.5, best δ) certifies (0, 0.0762): python -m ext_observer gains.
    _T('alpha', 0.05, '', 0.0, 0.0762,
       'gain α of the extension term that holds the estimate near S³ (below 0.0762: the '
       'range certified by Theorem 1)', high_open=True),
    _T('tau_acc', 2.0, 's', 0.0, _LONG,
       'time constant of the world-frame low-pass of the accelerometer'),
    _T('tau_acc_gain', 0.05, 's', 0.0, _LONG,
       'time constant of the inclination correction (the gain κ_a)'),
    _T('tau_mag', 15.0, 's', 0.0, _LONG,
       'time constant of the heading correction from the magnetometer (κ_m; the gain of '
       'each field follows from the interval since the previous field)'),
    # A Kalman filter on the inclination (and in 9D heading) corrections, VQF's
    # idea (docs/raw_imu.md#wherever-the-robot-starts); 0: learned at rest only.
    _T('tau_bias', 100.0, 's', 0.0, 1e6,
       'time constant of the gyro bias estimate in steady motion (a Kalman filter on the '
       'inclination and heading corrections)', low_closed=True, zero_off=True),
    _T('bias_max', math.radians(2.0), 'rad/s', 0.0, 10.0,
       'largest gyro bias estimate per axis'),
    _T('rest_gyr', math.radians(2.0), 'rad/s', 0.0, 10.0,
       'rest detection: threshold on the angular rate'),
    _T('rest_acc', 0.5, 'm/s²', 0.0, 100.0,
       'rest detection: threshold on the deviation of the specific force'),
    _T('rest_time', 1.5, 's', 0.0, _LONG,
       'rest detection: time below both thresholds before rest'),
    _T('tau_rest', 0.5, 's', 0.0, _LONG,
       'time constant of the rest-detection filters and of the bias estimate at rest'),
    _T('mag_norm_th', 0.05, '', 0.0, 100.0,
       'magnetic disturbance: relative deviation of the field norm from its reference'),
    _T('mag_dip_th', math.radians(10.0), 'rad', 0.0, math.pi,
       'magnetic disturbance: deviation of the dip angle from its reference'),
    _T('mag_new_time', 20.0, 's', 0.0, _LONG,
       'time a new, consistent field must last (while the body turns) before it is '
       'accepted'),
    _T('mag_new_gyr', math.radians(20.0), 'rad/s', 0.0, 100.0,
       'angular rate the body must turn at for that time to count'),
    _T('tau_mag_ref', 20.0, 's', 0.0, 1e6,
       'time constant of the learned field norm and dip references'),
    _T('mag_cal', True, '', None, None,
       'calibrate the magnetometer online in 9D (hard-iron offset and soft-iron matrix, '
       'learned while the body turns; docs/calibration.md); false: the fields are used '
       'as given'),
    _T('mag_cal_noise', 0.025, '', 0.0, 1.0,
       "the field's noise per sample and axis, relative to its norm"),
    # The calibration learns from the gyro's prediction of the field over
    # about the time it takes this walk to reach the field's noise (well
    # under a second with the defaults).
    _T('mag_cal_field_rw', 0.03, '1/√s', 0.0, 10.0,
       'how fast the world field may change where the body goes, relative to its norm'),
    _T('mag_cal_soft_iron', 0.05, '', 0.0, 10.0,
       'prior standard deviation of each element of the soft-iron matrix S − I'),
    _T('mag_cal_delay', 0.02, 's', 0.0, 10.0,
       "prior standard deviation of the field's lag behind the gyro (learned)",
       low_closed=True, zero_off=True),
    _T('mag_cal_heading', math.radians(6.0), 'rad', 0.0, math.pi,
       'the calibration is converged, and the heading follows the field, when the heading '
       'error its uncertainty would cause is below this (1σ)'),
    # And by more than three times its own uncertainty: below, the sensor
    # is taken as calibrated (on BROAD, whose fields are calibrated, what
    # is learned from a trial turns the heading by 2–11°).
    _T('mag_cal_deadband', math.radians(15.0), 'rad', 0.0, math.pi,
       'a learned calibration replaces the field as given only when it turns the heading '
       'by more than this (RMS over the recent attitudes)'),
    # A payload moves, the temperature changes.
    _T('mag_cal_drift', 0.002, '1/√s', 0.0, 10.0,
       "random walk of the hard-iron offset, relative to the field's norm",
       low_closed=True, zero_off=True),
    _T('mag_cal_rate', 100.0, 'Hz', 0.0, 1e5,
       'most fields per second the calibration learns from (one value for a batch; every '
       'field is calibrated)'),
    # Where the robot starts: the bias in motion and a clipped gyro.
    _T('bias_sigma_init', math.radians(0.5), 'rad/s', 0.0, 10.0,
       'σ of the gyro bias per axis before anything is learned (the most its uncertainty '
       'grows to)'),
    _T('bias_sigma_motion', math.radians(0.07), 'rad/s', 0.0, 10.0,
       'σ of the gyro bias estimate in steady motion (with tau_bias, how noisy a '
       'correction is taken to be)'),
    _T('gyro_range', 0.0, 'rad/s', 0.0, 1e3,
       "the gyro's measuring range per axis where the driver knows it (a sample at it is "
       'clipped); 0: unknown, a rate stuck at the largest magnitude seen is taken as clipped',
       low_closed=True, zero_off=True),
    # A long turn: Fusion's acceleration rejection, with its maximum time
    # (docs/raw_imu.md#acceleration-rejection).
    _T('acc_reject', math.radians(3.0), 'rad', 0.0, math.pi,
       'acceleration rejection: a low-passed specific force this far from the vertical the '
       'gyro carries is not taken for gravity', low_closed=True, zero_off=True),
    _T('acc_reject_time', 60.0, 's', 0.0, _LONG,
       'acceleration rejection: the longest it lasts; then the specific force is gravity again'),
)


class AhrsParams(Tunables):
    """
    What a user tunes, in physical units: the rows of :data:`AHRS_TABLE`.

    ``AhrsParams(tau_mag=10.0)``: the defaults, ``tau_mag`` in its place.
    Each field is an attribute; ``AhrsParams.DEFAULTS`` is ``{name: default}``
    and ``AhrsParams.ROWS[name]`` the row (unit, range, description).

    Raises
    ------
    ValueError
        With the name and the reason, for any invalid value.

    """

    TABLE = AHRS_TABLE


# The defaults were chosen on BROAD's tuning trials (ext_observer/broad/split.py;
# docs/covariance.md says how, and what they give on the held-out ones). Those > 0 keep every
# variance positive; the others may be 0 (off).
UNCERTAINTY_TABLE = (
    # Angle random walk, measured at rest (0.006 °/s/√Hz).
    _T('gyro_noise', 1.0e-4, 'rad/s/√Hz', 0.0, 1.0, 'white noise density of the gyro'),
    _T('gyro_rate_noise', 1.3e-3, '(rad/s per rad/s)/√Hz', 0.0, 1.0,
       'noise density of the gyro error proportional to the rate (scale factor, '
       'misalignment, vibration)', low_closed=True, zero_off=True),
    # Steady-state σ of a first-order Gauss-Markov process (0.08 °/s).
    _T('bias_std', 1.4e-3, 'rad/s', 0.0, 1.0,
       'how far the gyro bias wanders from the learned one (σ)', low_closed=True,
       zero_off=True),
    _T('bias_time', 250.0, 's', 0.0, 1e6, 'correlation time of that wander'),
    # 0.24 °/s: the biases learned at the first rest.
    _T('bias_init', 4.1e-3, 'rad/s', 0.0, 1.0,
       'gyro bias uncertainty per axis before the first rest', low_closed=True,
       zero_off=True),
    _T('acc_noise', 3.2e-3, 'm/s²/√Hz', 0.0, 10.0,
       'accelerometer noise density (measured at rest)'),
    # 1.25° per sample at 286 Hz.
    _T('mag_noise', 1.3e-3, 'rad·√s', 0.0, 10.0,
       "noise density of the field's horizontal direction (measured at rest)"),
    # 0.46°.
    _T('inclination_floor', 8.0e-3, 'rad', 0.0, 1.0,
       'smallest inclination σ (translational acceleration, accelerometer calibration, '
       'mounting)', low_closed=True, zero_off=True),
    # 1.20°.
    _T('heading_floor', 2.1e-2, 'rad', 0.0, 1.0,
       'smallest heading σ once a field has set the heading (a bent but accepted field)',
       low_closed=True, zero_off=True),
    _T('stamp_error', 7.0e-4, 's', 0.0, 1.0,
       "timing error of a sample's stamp: the orientation is off by |ω| times it",
       low_closed=True, zero_off=True),
)


class UncertaintyParams(Tunables):
    """
    The noise of the sensors and of what the estimator does not model: :data:`UNCERTAINTY_TABLE`.

    ``UncertaintyParams(acc_noise=1e-2)``: the defaults, ``acc_noise`` in
    its place; each field an attribute, ``DEFAULTS`` ``{name: default}``.

    Raises
    ------
    ValueError
        With the name and the reason, for any invalid value.

    """

    TABLE = UNCERTAINTY_TABLE
