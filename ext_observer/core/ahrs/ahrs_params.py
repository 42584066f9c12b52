"""
The raw-IMU estimator's parameters (:class:`AhrsParams`), in physical units.

What a user tunes: time constants in seconds, thresholds in rad/s and m/s²
(VQF's way; see :mod:`ext_observer.core.ahrs.estimator`). Checked when made: a bad
value raises ``ValueError`` naming the parameter.
"""

import math

__all__ = ['AhrsParams']


class AhrsParams:
    """
    What a user tunes, in physical units (seconds, rad/s, m/s²).

    Parameters
    ----------
    alpha : float
        Gain of the extension term, in (0, 0.0762): the certified range of
        Theorem 1 on S³ (ε = 0.5, best δ; ``python -m ext_observer gains``).
    tau_acc : float
        Time constant (s) of the world-frame low-pass of the accelerometer.
    tau_acc_gain : float
        Time constant (s) of the Luenberger gain ``κ_a`` on the inclination
        measurement.
    tau_mag : float
        Time constant (s) of the heading correction (``κ_m``).
    tau_bias : float
        Time constant (s) of the bias estimate in steady motion: a Kalman
        filter on the inclination (and in 9D heading) corrections (VQF's
        idea), whose bias may wander by ``bias_sigma_motion`` in this time;
        0 turns learning in motion off (the bias is then learned at rest
        only).
    bias_max : float
        Largest bias estimate (rad/s), per axis.
    bias_sigma_init : float
        σ of the gyro bias before anything is learned (rad/s, per axis), and
        the most it grows to.
    bias_sigma_motion : float
        σ of the bias estimate in steady motion (rad/s): with ``tau_bias``
        it sets how noisy a correction rate is taken to be.
    gyro_range : float
        The gyro's measuring range (rad/s, per axis) where the driver knows
        it; a sample at it is clipped. 0: unknown (a rate stuck at the
        largest magnitude seen is taken as clipped).
    rest_gyr : float
        Rest threshold on the angular rate (rad/s).
    rest_acc : float
        Rest threshold on the deviation of the specific force (m/s²).
    rest_time : float
        Time (s) below both thresholds before rest is declared.
    tau_rest : float
        Time constant (s) of the low-pass filters of rest detection and of
        the bias estimate at rest.
    mag_norm_th : float
        Relative deviation of the field norm from its reference that counts
        as a disturbance.
    mag_dip_th : float
        Deviation (rad) of the dip angle from its reference that counts as a
        disturbance.
    mag_new_time : float
        Time (s) a new, consistent field must last before it is accepted.
    mag_new_gyr : float
        Angular rate (rad/s) the body must turn at for that time to count.
    tau_mag_ref : float
        Time constant (s) of the learned field norm and dip references.
    mag_cal : bool
        Calibrate the magnetometer online in 9D (hard and soft iron); false:
        the fields are used as given, exactly as without the calibrator.
    mag_cal_noise : float
        The field's noise per sample and axis, relative to its norm.
    mag_cal_field_rw : float
        How fast the world field may change where the body goes, relative to
        its norm, per √s: the calibration learns from the gyro's prediction
        of the field over about the time it takes this walk to reach the
        field's noise (well under a second with the defaults).
    mag_cal_soft_iron : float
        Prior standard deviation of each element of the soft-iron matrix
        ``S − I``.
    mag_cal_delay : float
        Prior standard deviation (s) of the field's lag behind the gyro,
        which is learned; 0: no lag.
    mag_cal_heading : float
        The calibration is converged (and the heading follows the field)
        when the heading error its uncertainty would cause is below this
        (rad, 1σ).
    mag_cal_deadband : float
        A learned calibration replaces the field as given only when it turns
        the heading by more than this (rad, RMS over the recent attitudes),
        and by more than three times its own uncertainty: below, the sensor
        is taken as calibrated (on BROAD, whose fields are calibrated, what
        is learned from a trial turns the heading by 2–11°).
    mag_cal_drift : float
        Random walk of the hard-iron offset, relative to the field's norm,
        per √s (a payload moves, the temperature changes); 0: constant.
    mag_cal_rate : float
        Most fields per second the calibration learns from (Hz; one value
        for a batch); every field is calibrated.

    Raises
    ------
    ValueError
        With the name and the reason, for any invalid value.

    """

    DEFAULTS = dict(
        alpha=0.05,
        tau_acc=2.0,
        tau_acc_gain=0.05,
        tau_mag=15.0,
        tau_bias=100.0,
        bias_max=math.radians(2.0),
        bias_sigma_init=math.radians(0.5),
        bias_sigma_motion=math.radians(0.07),
        gyro_range=0.0,
        rest_gyr=math.radians(2.0),
        rest_acc=0.5,
        rest_time=1.5,
        tau_rest=0.5,
        mag_norm_th=0.05,
        mag_dip_th=math.radians(10.0),
        mag_new_time=20.0,
        mag_new_gyr=math.radians(20.0),
        tau_mag_ref=20.0,
        mag_cal=True,
        mag_cal_noise=0.025,
        mag_cal_field_rw=0.03,
        mag_cal_soft_iron=0.05,
        mag_cal_delay=0.02,
        mag_cal_heading=math.radians(6.0),
        mag_cal_deadband=math.radians(15.0),
        mag_cal_drift=0.002,
        mag_cal_rate=100.0,
    )

    def __init__(self, **values):
        unknown = set(values) - set(self.DEFAULTS)
        if unknown:
            raise ValueError(f'unknown parameters: {sorted(unknown)}')
        merged = dict(self.DEFAULTS, **values)
        for name, value in merged.items():
            if isinstance(self.DEFAULTS[name], bool):
                if value not in (True, False):
                    raise ValueError(f'{name} must be true or false, got {value!r}')
                setattr(self, name, bool(value))
                continue
            value = float(value)
            if not math.isfinite(value):
                raise ValueError(f'{name} must be finite, got {value}')
            if name in ('tau_bias', 'mag_cal_delay', 'mag_cal_drift', 'gyro_range'):
                if value < 0.0:
                    raise ValueError(f'{name} must be >= 0 (0: off), got {value}')
            elif not value > 0.0:
                raise ValueError(f'{name} must be positive, got {value}')
            setattr(self, name, value)
        if not self.alpha < 0.0762:
            raise ValueError(
                f'alpha must be below the certified 0.0762, got {self.alpha}')

    def as_dict(self):
        """Return the parameters as a dict."""
        return {name: getattr(self, name) for name in self.DEFAULTS}

    def __repr__(self):
        items = ', '.join(f'{k}={v}' if isinstance(v, bool) else f'{k}={v:g}'
                          for k, v in self.as_dict().items())
        return f'AhrsParams({items})'
