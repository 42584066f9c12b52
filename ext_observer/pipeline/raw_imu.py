"""
The raw-IMU estimator as ``imu_filter_node`` runs it, without ROS.

:class:`RawImuPipeline` takes a raw IMU's samples and fields as the node
receives them (stamped in integer nanoseconds, in any order and of any
quality: :class:`~ext_observer.pipeline.pairing.StepPairer` checks and
counts them first) and returns the estimates the node publishes, each with
its covariance (:class:`~ext_observer.core.ahrs.uncertainty.AttitudeUncertainty`).
The node, the CSV and bag commands, calibrate and
:func:`~ext_observer.attitude_from_imu` all call it, so their estimates
are the node's to the bit. How samples, fields and faults are used:
docs/raw_imu.md ("How samples are used"); the covariance: docs/covariance.md.
The output's frame: the core's sensor → ENU estimate turned to true north,
into ``world_frame`` (``C`` of :data:`~ext_observer.core.ahrs.ahrs_observer.WORLD_FRAMES`),
then about that frame's z axis:
``q = R_z(yaw_offset) ⊗ C ⊗ R_up(−declination) ⊗ q_enu``.
"""

from collections import namedtuple
import math

import numpy as np

from ext_observer.core.ahrs.ahrs_observer import AhrsObserver
from ext_observer.core.ahrs.magcal import check_calibration
from ext_observer.core.quaternion import multiply_floats
from ext_observer.core.ahrs.uncertainty import AttitudeUncertainty, covariance_out
from ext_observer.core.ahrs.uncertainty_kernel import SAMPLE_NON_FINITE, SAMPLE_OK, SAMPLE_RESIDUAL
from ext_observer.core.validation import check_state
from ext_observer.pipeline.field_tracking import FieldTracker
from ext_observer.pipeline.guard import GUARD_REASONS
from ext_observer.pipeline.imu_filter_parameters import ahrs_params, uncertainty_params
from ext_observer.pipeline.imu_filter_outputs import field_mounting, heading_factor
from ext_observer.pipeline.pairing import BACKWARD_JUMP, Step, StepPairer
from ext_observer.pipeline.units import UnitCheck
from ext_observer.pipeline.velocity_aid import VelocityInput

__all__ = ['Estimate', 'RESET_CAUSES', 'RawImuEstimator', 'RawImuPipeline', 'heading_factor',
           'pairing_settings']

# Why the estimator restarted (the same causes as the nodes').
RESET_CAUSES = ('backward_jump', 'clock_jump', 'forward_gap', 'service')

SECOND = 1_000_000_000
# The soft-iron matrix of no distortion, row-major.
_IDENTITY = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)
# Largest accepted ‖θ‖ of one sample interval, rad (StepPairer).
MAX_INCREMENT = 20.0

# One estimate: the sample's stamp (ns), the ambient estimate in
# world_frame (4 floats), the guard's reason if it reinitialized the
# estimator on this sample (else None), the released step (its gap flag),
# and the covariance of the orientation (9 floats, row-major, rad², about
# world_frame's x, y, z axes).
Estimate = namedtuple('Estimate', 'stamp state reason step covariance')


def pairing_settings(settings):
    """Return the :class:`StepPairer` settings of the raw IMU's parameters."""
    # The steps wait for nothing: the accelerometer comes with the sample,
    # the field is used when it arrives.
    return dict(timeout=0, max_increment=MAX_INCREMENT,
                norm_tolerance=0.1,
                backward_jump=round(settings['backward_jump_threshold'] * SECOND),
                forward_gap=round(settings['forward_gap_threshold'] * SECOND),
                max_dt=round(settings['max_dt'] * SECOND),
                constant_dt=settings['constant_dt'],
                arrival_order=settings['constant_dt'] > 0.0)


# sample_step's outcomes as check_state's reasons (a step that raised: step_failed).
_SAMPLE_REASONS = {SAMPLE_NON_FINITE: 'state_non_finite', SAMPLE_RESIDUAL: 'residual_too_large'}


class RawImuEstimator:
    """
    The core's raw-IMU estimator with the node's frames: one call per sample or field.

    Parameters
    ----------
    settings : dict
        ``ahrs.*``, ``covariance.*`` (those missing take their defaults),
        ``use_mag``, ``world_frame``, ``declination``, ``yaw_offset``,
        ``mag_bias_*``, ``divergence_max_residual``.
    compiled : bool, optional
        The core's kernels (:class:`~ext_observer.core.ahrs.ahrs_observer.AhrsObserver`'s
        ``compiled``): default, compiled where numba is installed.

    Attributes
    ----------
    core : ext_observer.core.ahrs.ahrs_observer.AhrsObserver
    uncertainty : ext_observer.core.ahrs.uncertainty.AttitudeUncertainty
        The variance of the estimate's inclination and heading.
    latest_field : tuple of 3 float or None
        The latest field (T, hard-iron offset removed).

    """

    def __init__(self, settings, compiled=None):
        params = ahrs_params(settings)
        self.core = AhrsObserver(params=params, use_mag=settings['use_mag'], compiled=compiled)
        self.uncertainty = AttitudeUncertainty.for_estimator(
            params, uncertainty_params(settings), use_mag=bool(settings['use_mag']))
        self.uncertainty.use_kernels(self.core.kernels)
        # Where sample_step writes the covariance when the caller gives no array.
        self._covariance = np.zeros(9)
        self.world_frame = settings['world_frame']
        self.latest_field = None
        self._field_dt = None  # the last regular interval between fields, s
        self.fields = FieldTracker(self.core, self.uncertainty)
        self._gyro_bias = None
        self._held_bias = None
        self.configure(settings)

    def configure(self, settings):
        """
        Take the settings that may change at runtime.

        A saved magnetometer calibration (``mag_bias_*``, ``mag_soft_iron``,
        ``m_raw = S m + b``) starts the online calibration where it has one
        (9D, ``ahrs.mag_cal``), which goes on refining it; without one it is
        applied as it is, ``m = S⁻¹ (m_raw − b)`` (imu_filter_madgwick's
        ``mag_bias_*`` with ``S = I``).

        Raises
        ------
        ValueError
            For a calibration that is not finite, not symmetric positive
            definite, or singular.
        """
        self.max_residual = float(settings['divergence_max_residual'])
        bias, soft_iron = check_calibration(
            (settings['mag_bias_x'], settings['mag_bias_y'], settings['mag_bias_z']),
            settings['mag_soft_iron'])
        saved = (tuple(bias.tolist()), tuple(soft_iron.ravel().tolist()))
        given = saved != ((0.0, 0.0, 0.0), _IDENTITY)
        if self.core.calibration is not None:
            self._mag_bias = (0.0, 0.0, 0.0)
            self._unskew = None
            if given and saved != getattr(self, '_loaded', None):
                self.core.load_calibration(*saved)
                self._loaded = saved
        else:
            self._mag_bias = saved[0]
            self._unskew = (None if saved[1] == _IDENTITY
                            else tuple(np.linalg.inv(soft_iron).ravel().tolist()))
        self._frame = heading_factor(self.world_frame, settings['declination'],
                                     settings['yaw_offset'])
        self._mounting = field_mounting(settings)
        self._mag_timeout = float(settings.get('mag_timeout', 0.0))
        # The gyro bias given (gyro_bias_*, rad/s): the estimate starts from
        # it, now and after each reset; gyro_bias_learning false holds the
        # bias where it is.
        gyro_bias = tuple(float(settings.get(f'gyro_bias_{axis}', 0.0)) for axis in 'xyz')
        if gyro_bias != self._gyro_bias:
            self._gyro_bias = gyro_bias
            self.core.bias = gyro_bias
            if self._held_bias is not None:
                self._held_bias = gyro_bias
        if settings.get('gyro_bias_learning', True):
            self._held_bias = None
        elif self._held_bias is None:
            self._held_bias = self.core.bias

    def field(self, field, dt=None):
        """
        Correct the heading with a field; before the first step, only keep it.

        Parameters
        ----------
        field : sequence of 3 float
            T, as measured (validated by the caller); the hard-iron offset is
            removed here.
        dt : float, optional
            Time since the previous field, s; None (the first field of a time
            line): the IMU's interval.

        """
        if self._mounting is not None:
            r = self._mounting
            field = (r[0] * field[0] + r[1] * field[1] + r[2] * field[2],
                     r[3] * field[0] + r[4] * field[1] + r[5] * field[2],
                     r[6] * field[0] + r[7] * field[1] + r[8] * field[2])
        if dt is not None and 0.0 < self._mag_timeout < dt:
            # A field back after a loss: its gain is that of a regular
            # interval, so that the heading does not return in one step; the
            # heading's doubt is what the gyro alone added since the last
            # field, which the fields back correct with their Kalman gain.
            dt = self._field_dt
            if self.core.initialized and self.uncertainty.started:
                self.core.field_back(float(self.uncertainty.held_variance))
        elif dt is not None:
            self._field_dt = dt
        bx, by, bz = self._mag_bias
        field = (field[0] - bx, field[1] - by, field[2] - bz)
        if self._unskew is not None:
            a = self._unskew
            field = (a[0] * field[0] + a[1] * field[1] + a[2] * field[2],
                     a[3] * field[0] + a[4] * field[1] + a[5] * field[2],
                     a[6] * field[0] + a[7] * field[1] + a[8] * field[2])
        self.latest_field = field
        if self.core.initialized:
            self.core.update_mag(field, dt)
            self.fields.track(dt, field)

    def unbridged(self, gyr, dt):
        """
        A hole of ``dt`` s too long to bridge (over ``max_dt``), ended by a sample of rate ``gyr``.

        The estimate holds and its covariance grows by the rotation the hole
        may have hidden (:meth:`AhrsObserver.unbridged
        <ext_observer.core.ahrs.ahrs_observer.AhrsObserver.unbridged>`); a
        heading that lost too much is taken afresh from the next fields, as
        at a start (the covariance counts their gains from one again).
        """
        var, t0 = self.core.unbridged(gyr, dt)
        self.uncertainty.unbridged(dt, var, t0)
        if self.core.field('mag_used') == 0.0:
            self.fields.restart()

    def velocity(self, velocity, dt=None):
        """The body's velocity (m/s, IMU frame) for the velocity aid, ``dt`` s after the last."""
        self.core.velocity(velocity, dt)

    def use_kernels(self, kernels):
        """Go on with other kernels (plain or compiled): the core's and the covariance's."""
        self.core.use_kernels(kernels)
        self.uncertainty.use_kernels(kernels)

    def step(self, gyr, acc, dt, covariance=None):
        """
        Run one IMU sample: the usual one (an estimate exists) in one call.

        :func:`~ext_observer.core.ahrs.uncertainty_kernel.sample_step` runs the
        core's step, the guard and the covariance's: the one path of a
        sample. Where no estimate exists yet, or the step failed the guard,
        the sample starts the estimate instead (:meth:`_initialize`).

        Parameters
        ----------
        gyr, acc : sequence of 3 float
            Angular velocity (rad/s) and specific force (m/s²) of the sample,
            validated by the caller (finite, nonzero acceleration).
        dt : float
            Time since the previous sample, s.
        covariance : array of 9 float64, optional
            Where to write :attr:`covariance`, as :func:`covariance_out` accepts.

        Returns
        -------
        state : tuple of 4 float
            The ambient estimate in ``world_frame``, finite.
        reason : str or None
            Why the estimator was reinitialized from this sample
            (:data:`~ext_observer.pipeline.guard.GUARD_REASONS`), else None.

        """
        core = self.core
        cov = self._covariance if covariance is None else covariance_out(covariance)
        try:
            outcome, w, x, y, z = core.kernels.sample_step(
                core.state, self.uncertainty.state, cov,
                gyr[0], gyr[1], gyr[2], acc[0], acc[1], acc[2], dt, self.max_residual)
        except (ValueError, OverflowError, ZeroDivisionError):
            outcome = None
        if outcome == SAMPLE_OK:
            if self._held_bias is not None:
                core.bias = self._held_bias
            return ((w, x, y, z) if self._frame is None
                    else multiply_floats(self._frame, (w, x, y, z))), None
        state, reason = self._initialize(  # no estimate yet, or it failed the guard
            gyr, acc, dt, 'step_failed' if outcome is None else _SAMPLE_REASONS.get(outcome))
        if covariance is not None:
            covariance[:] = self.uncertainty.covariance
        if self._held_bias is not None:
            core.bias = self._held_bias
        return state, reason

    def _initialize(self, gyr, acc, dt, reason=None):
        """
        Start the estimate from this sample (and the latest field); with a ``reason``, start again.

        Without a reason the estimate did not exist (the first sample): its
        first step initializes it, and a first state that fails the guard
        starts it once more, with that reason.
        """
        core = self.core
        if reason is None:
            try:
                q = core.update(gyr, acc, self.latest_field, dt)
            except (ValueError, OverflowError, ZeroDivisionError):
                reason = 'step_failed'
            else:
                reason = check_state(q, None, self.max_residual)
        if reason is not None:
            core.reset()
            core.bias = self._start_bias
            q = core.update(gyr, acc, self.latest_field, dt)
        self._start(dt, acc)
        # The state property's value, from the q the step returned.
        return (q if self._frame is None else multiply_floats(self._frame, q)), reason

    def _start(self, dt, acc=None):
        """The core has just initialized (and used the latest field, if any)."""
        self.uncertainty.start(dt, acc)
        self.fields.restart()
        if self.latest_field is not None and self.core.use_mag:
            self.fields.track(None, self.latest_field)

    @property
    def frame(self):
        """The left factor from the core's ENU estimate to the published one (None: identity)."""
        return self._frame

    @property
    def state(self):
        """The estimate in ``world_frame`` (ambient), or None before the first step."""
        q = self.core.q
        if q is None or self._frame is None:
            return q
        return multiply_floats(self._frame, q)

    def reset(self):
        """Forget the estimate: the next step initializes it again (from the bias given)."""
        self.core.reset()
        self.core.bias = self._start_bias
        self.uncertainty.reset()

    @property
    def _start_bias(self):
        return self._gyro_bias if self._held_bias is None else self._held_bias

    @property
    def bias_learning(self):
        """Whether the gyro bias is learned (``gyro_bias_learning``), else held."""
        return self._held_bias is None

    @property
    def covariance(self):
        """The orientation's covariance (9 floats, row-major, rad², world axes), or None."""
        return self.uncertainty.covariance if self.uncertainty.started else None

    def key_values(self):
        """
        Return the diagnostic pairs of the estimator.

        ``world_frame``, ``use_mag``, ``initialized``, ``bias_x``, ``bias_y``,
        ``bias_z`` (rad/s), ``bias_std_x``, ``bias_std_y``, ``bias_std_z``
        (its σ, rad/s), ``gyro_clipped`` (samples at the gyro's range so
        far), ``holes_bridged`` (intervals much longer than the usual one
        integrated across so far), ``rest``, ``mag_disturbed``, ``residual``
        (``|q̂̄q̂ − 1|``), ``inclination_std_deg`` and ``heading_std_deg``
        (the σ of the published covariance, degrees); NaN before the first
        step.
        """
        core = self.core
        q = core.q
        residual = math.nan if q is None else abs(
            q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3] - 1.0)
        bx, by, bz = core.bias
        sx, sy, sz = core.bias_std
        clipped = core.clipped
        tracker = self.uncertainty
        started = q is not None and tracker.started
        return [('world_frame', self.world_frame), ('use_mag', bool(core.use_mag)),
                ('initialized', q is not None), ('bias_x', float(bx)),
                ('bias_y', float(by)), ('bias_z', float(bz)), ('bias_std_x', float(sx)),
                ('bias_std_y', float(sy)), ('bias_std_z', float(sz)), ('rest', bool(core.rest)),
                ('bias_learning', self.bias_learning), ('gyro_clipped', clipped),
                ('holes_bridged', core.holes),
                ('mag_disturbed', bool(core.mag_disturbed)), ('residual', residual),
                ('inclination_std_deg',
                 math.degrees(tracker.inclination_std) if started else math.nan),
                ('heading_std_deg', math.degrees(tracker.heading_std) if started else math.nan),
                ('calibration', core.calibration_state),
                ('kernels', 'compiled' if core.compiled else 'plain')] + self._calibration_values()

    def _calibration_values(self):
        calibration = self.core.calibration
        if calibration is None:
            return []
        b = calibration.bias
        return [('calibration_heading_std_deg', math.degrees(calibration.quality)),
                ('calibration_resets', int(calibration.counts['resets'][0])),
                ('calibration_bias_x', float(b[0])), ('calibration_bias_y', float(b[1])),
                ('calibration_bias_z', float(b[2])),
                ('calibration_soft_iron', ' '.join(
                    f'{v:.6g}' for v in calibration.soft_iron.ravel()))]

    def calibration(self):
        """
        Return the calibration learned or loaded, as the params file holds it.

        Returns
        -------
        bias : tuple of 3 float
            ``mag_bias_*``, T.
        soft_iron : tuple of 9 float
            ``mag_soft_iron``, row-major.

        Raises
        ------
        ValueError
            When there is none yet (off, or still learning).
        """
        calibration = self.core.calibration
        state = self.core.calibration_state
        if calibration is None or state not in ('converged', 'loaded'):
            raise ValueError(f'no magnetometer calibration to save: it is {state}'
                             + (' (turn the sensor about several axes)'
                                if state == 'learning' else ''))
        return (tuple(float(v) for v in calibration.bias),
                tuple(float(v) for v in calibration.soft_iron.ravel()))


class RawImuPipeline:
    """
    Stamped raw-IMU samples in, the node's estimates out; every input counted.

    Parameters
    ----------
    settings : dict
        The settings of ``imu_filter_node`` (:func:`~ext_observer.pipeline.imu_filter_parameters.
        imu_filter_settings`).
    depth : int
        Most inputs waiting (the node's ``queue_depth``).
    compiled : bool, optional
        The estimator's kernels (:class:`RawImuEstimator`).

    Attributes
    ----------
    estimator : RawImuEstimator
    pairer : ext_observer.pipeline.pairing.StepPairer
        Validation, stamps, and the input counters.
    units : ext_observer.pipeline.units.UnitCheck
        Magnitudes that only a wrong unit explains.
    resets : dict
        By cause (:data:`RESET_CAUSES`).
    reinitializations : dict
        By the divergence guard, by reason.

    """

    def __init__(self, settings, depth=100, compiled=None):
        self.estimator = RawImuEstimator(settings, compiled)
        self.pairer = StepPairer(depth=depth, **pairing_settings(settings))
        self.units = UnitCheck()
        self.resets = dict.fromkeys(RESET_CAUSES, 0)
        self.reinitializations = dict.fromkeys(GUARD_REASONS, 0)
        self._constant_dt = settings['constant_dt']
        self._gap_resets = settings['forward_gap_action'] == 'reset'
        self._velocity = VelocityInput(self.estimator, settings)

    def configure(self, settings):
        """Take the settings that may change at runtime."""
        self.estimator.configure(settings)
        self.pairer.configure(**pairing_settings(settings))
        self._constant_dt = settings['constant_dt']
        self._gap_resets = settings['forward_gap_action'] == 'reset'
        self._velocity.configure(settings)

    def reset(self, cause):
        """Restart the estimator (the next sample initializes it), counted as ``cause``."""
        self.estimator.reset()
        # The core forgot the velocity: the next one is a first (a new time line may be earlier).
        self._velocity.stamp = None
        self.resets[cause] += 1

    def restart(self, cause):
        """Start a new time line and restart the estimator; return the inputs discarded."""
        discarded = self.pairer.restart()
        self.reset(cause)
        return discarded

    def imu(self, stamp, gyr, acc, covariance=None):
        """
        Take one IMU sample and run the step it closes.

        Parameters
        ----------
        stamp : int
            ns.
        gyr, acc : sequence of 3 float
            rad/s, m/s².
        covariance : array of 9 float64, optional
            Where to write the estimate's covariance (then the Estimate's).

        Returns
        -------
        outcome : str or None
            As :meth:`StepPairer.add_angular_velocity
            <ext_observer.pipeline.pairing.StepPairer.add_angular_velocity>`: None, a
            drop reason, or ``'backward_jump'`` (the estimator was reset).
        estimate : Estimate or None
            The estimate of this sample, when it ran a step.

        """
        self.units.imu(gyr, acc)
        pairer = self.pairer
        start = pairer.pending_stamp
        outcome, steps = pairer.add_sample(stamp, gyr, acc)
        if outcome == 'dt_too_large' and self.estimator.core.initialized:
            # The hole is not bridged: the sample after it starts the next step.
            self.estimator.unbridged(gyr, (stamp - start) * 1e-9)
        if outcome == BACKWARD_JUMP:
            self.reset('backward_jump')
        estimate = None
        if (not steps and self._constant_dt > 0.0 and outcome in (None, BACKWARD_JUMP)
                and pairer.last_stamp is None and pairer.pending_stamp == stamp):
            # constant_dt: the first sample of a time line answers too, the
            # estimate initialized from it (the next one steps from there).
            step = Step(stamp, (0.0, 0.0, 0.0), None, None, False, False, stamp)
            state, reason = self.estimator.step(gyr, acc, self._constant_dt, covariance)
            return outcome, Estimate(stamp, state, reason, step,
                                     self.estimator.uncertainty.covariance
                                     if covariance is None else covariance)
        for step in steps:
            if step.end != stamp:
                # Cannot happen: a step is released by the sample that closes it.
                continue
            if step.gap and self._gap_resets:
                self.reset('forward_gap')
            state, reason = self.estimator.step(
                gyr, acc, self._constant_dt or (step.end - step.stamp) * 1e-9, covariance)
            if reason is not None:
                self.reinitializations[reason] += 1
            estimate = Estimate(stamp, state, reason, step,
                                self.estimator.uncertainty.covariance if covariance is None
                                else covariance)
        return outcome, estimate

    def velocity(self, stamp, velocity):
        """
        The body's velocity (ns, m/s).

        See :class:`~ext_observer.pipeline.velocity_aid.VelocityInput`.
        """
        return self._velocity.take(stamp, velocity)

    def field_silence(self):
        """How long the IMU's stamps have gone on since the last field, s (None: no field yet)."""
        last, field = self.pairer.last_stamp, self.pairer.field_stamp
        if last is None or field is None:
            return None
        return max(last - field, 0) * 1e-9

    def field(self, stamp, field):
        """
        Take one magnetometer sample (T) and correct the heading with it at once.

        Returns
        -------
        outcome : str or None
            None when used, else the drop reason.

        """
        self.units.field(field)
        previous = self.pairer.field_stamp
        outcome = self.pairer.add_field(stamp, field)
        if outcome is None:
            # The first field of a time line (or after a jump back) has no interval.
            self.estimator.field(field, None if previous is None or stamp <= previous
                                 else (stamp - previous) * 1e-9)
        return outcome
