"""
What the covariance is told of each field: the heading gain the core applied, and why.

:class:`FieldTracker` follows :class:`~ext_observer.core.ahrs.ahrs_observer.AhrsObserver`'s
field step from outside it and hands
:class:`~ext_observer.core.ahrs.uncertainty.AttitudeUncertainty` the gain each field
corrected the heading with (the running mean of the first fields, then ``tau_mag``'s;
the doubt's Kalman gain after a hole or a clipped gyro), the magnetometer calibration's
heading σ, the reference a heading still learning rests on, and the field's innovation
(the heading's lag behind the fields): docs/covariance.md.
"""

import math

from ext_observer.core.ahrs.ahrs_filters import rotate

__all__ = ['FieldTracker']


class FieldTracker:
    """The covariance's view of one core's field steps (``core``, ``uncertainty``)."""

    def __init__(self, core, uncertainty):
        self.core = core
        self.uncertainty = uncertainty
        self.fields_used = 0
        self.calibrated = True

    def restart(self):
        """The heading is taken afresh from the next fields (a start, a heading lost)."""
        self.fields_used = 0
        self.calibrated = True

    def track(self, dt, field):
        """Tell the uncertainty what the core's last field did to the heading."""
        core = self.core
        # The online magnetometer calibration, where the core has one: until it is ready the
        # heading does not follow the field, and once ready the next used
        # field sets it again (a running mean from 1).
        calibration = getattr(core, 'calibration', None)
        calibrated = calibration is None or bool(calibration.ready)
        if calibrated and not self.calibrated:
            self.fields_used = 0
        self.calibrated = calibrated
        # The calibration's own heading σ counts where the heading follows
        # the calibrated field; a calibration not applied (the sensor looked
        # calibrated, the field is used as given) does not move the heading,
        # and the field's own error is heading_floor's.
        sigma = (float(calibration.quality) if calibration is not None and calibration.applied
                 else 0.0)
        # The references' dip: how far the start's tilt error turns a field's heading.
        dip = core.field('ref')[1] if core.use_mag else math.nan
        # After a hole or a clipped gyro the field may have corrected the
        # heading with the Kalman gain of the doubt the gyro left, above
        # the usual one (also a field judged disturbed or a calibration
        # still waiting): the covariance follows the gain applied.
        doubt = float(core.field('doubt_gain'))
        if doubt > 0.0:
            self.fields_used += calibrated
            self.uncertainty.field(dt, max(doubt, self.uncertainty.heading_gain(
                self.fields_used, dt)), sigma, math.nan, dip, self._innovation(field))
            return
        if not (core.use_mag and calibrated and not core.mag_disturbed):
            reference = math.nan
            if not calibrated and core.use_mag and not core.mag_disturbed:
                # Learning: the heading rests on the field as given; how far
                # the calibration learned so far turns this field's heading
                # says how wrong that may be (a disturbed field says nothing).
                quality = float(calibration.quality)
                if math.isfinite(quality):
                    w, x, y, z = core.q
                    turn = calibration.heading_turn(field, (
                        2.0 * (x * z - w * y), 2.0 * (y * z + w * x),
                        w * w - x * x - y * y + z * z))
                    reference = turn * turn + quality * quality
                else:
                    reference = math.inf
            self.uncertainty.field(dt, 0.0, 0.0, reference, dip)
            return
        # AhrsObserver.update_mag: a running mean of the first fields, then
        # 1 − exp(−dt / tau_mag).
        self.fields_used += 1
        self.uncertainty.field(dt, self.uncertainty.heading_gain(self.fields_used, dt), sigma,
                               math.nan, dip, self._innovation(field))

    def _innovation(self, field):
        """
        The heading (rad) of the field used in the corrected estimate's frame.

        Counted only where the field corrected the heading: its recent mean is
        the heading's lag behind the fields. The field as the core used it
        (calibrated, or as given until a calibration is applied).
        """
        calibration = getattr(self.core, 'calibration', None)
        used = calibration.apply(field) if calibration is not None else field
        mx, my, _ = rotate(*self.core.q, *used)
        return math.atan2(mx, my)
