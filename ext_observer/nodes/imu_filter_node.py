"""
The ``imu_filter`` node: attitude from a raw IMU, the drop-in for imu_filter_madgwick.

Inputs: ``imu/data_raw`` (``sensor_msgs/Imu``: angular velocity, rad/s, and
linear acceleration, m/s²; the orientation is ignored) and, with
``use_mag``, ``imu/mag`` (``sensor_msgs/MagneticField``, T) at its own rate;
with ``velocity_source``, the body's velocity on ``odom``
(``nav_msgs/Odometry``) or ``velocity`` (``geometry_msgs/TwistStamped``)
(:mod:`~ext_observer.nodes.velocity_topic`); all subscribed with the
sensor-data QoS (best effort, volatile: reliable and best-effort drivers
both connect), overridable with ``qos_overrides``.
Outputs, one per IMU sample and stamped with it: ``imu/data``
(``sensor_msgs/Imu``: the sample with its orientation filled in, normalized,
and ``orientation_covariance`` the estimate's own, row-major about the world
frame's axes, or ``orientation_stddev``'s where ``orientation_covariance_mode``
says so (``fixed``; ``auto``, the default, when it is set); only while
subscribed) and ``attitude_estimate``
(``QuaternionStamped``, the ambient estimate, not normalized: its distance
to S³ is what the extension term holds small; only while subscribed too); ``/diagnostics`` every
``diagnostic_period``; as imu_filter_madgwick, with ``publish_debug_topics``
``imu/rpy/filtered``, ``imu/rpy/raw`` (and ``imu/steady_state``), with
``publish_tf`` the orientation on ``/tf`` where tf2_ros imports; the services
``~/reset`` and ``~/save_calibration`` (``std_srvs/Trigger``: the gyro bias and
the magnetometer calibration as a params file).

The estimator is :class:`~ext_observer.pipeline.raw_imu.RawImuPipeline` (validation,
stamps, the core's :class:`~ext_observer.core.ahrs.ahrs_observer.AhrsObserver`); this node
turns messages into its inputs and its estimates into messages, and says
what went wrong: drops, resets, a silent IMU, a missing magnetometer, and
values that only a wrong unit explains (:mod:`ext_observer.pipeline.units`). The
parameters are :data:`~ext_observer.pipeline.imu_filter_parameters.IMU_FILTER_PARAMETERS`,
imu_tools' two filters' among them (``docs/raw_imu.md``).
"""

import gc
import math
import os

from geometry_msgs.msg import QuaternionStamped, TransformStamped, Vector3Stamped
from rclpy.qos import QoSProfile
from sensor_msgs.msg import Imu, MagneticField
from std_msgs.msg import Bool
from std_srvs.srv import Trigger

from ext_observer.recordings.calibrate import write_params
from ext_observer.recordings.cdr import Undecodable
from ext_observer.core.ahrs.compiled import plain_warning
from ext_observer.pipeline.kernel_cache import BackgroundCompile, start_plan
from ext_observer.nodes.estimator_node_base import EstimatorNode, LOG_THROTTLE
from ext_observer.nodes.imu_filter_io import SerializedPath, TypedPath
from ext_observer.pipeline.imu_filter_parameters import (covariance_text, IMU_FILTER_PARAMETERS,
                                                         imu_filter_settings,
                                                         mag_frame_rpy_text, unused_text)
from ext_observer.nodes.node_common import NO_TF2, run_node, transform_broadcaster
from ext_observer.nodes.stream_watch import StreamWatch
from ext_observer.nodes.velocity_topic import VelocityTopic
from ext_observer.pipeline.health import health_text, HealthWatch
from ext_observer.pipeline.imu_filter_outputs import (field_mounting, raw_attitude,
                                                      rpy_from_quaternion,
                                                      transform_from_estimate, without_gravity)
from ext_observer.pipeline.pairing import BACKWARD_JUMP, KINDS
from ext_observer.pipeline.raw_imu import RawImuPipeline

__all__ = ['IMU_FILTER_PARAMETERS', 'ImuFilterNode', 'IMU_TOPIC', 'MAG_TOPIC', 'main']

IMU_TOPIC = 'imu/data_raw'
MAG_TOPIC = 'imu/mag'

class ImuFilterNode(EstimatorNode):
    """
    Estimate the attitude from a raw IMU (gyro, accelerometer, magnetometer).

    Parameters
    ----------
    node_name : str
        Default ``imu_filter``, as imu_filter_madgwick's.
    **kwargs
        Passed to ``rclpy.node.Node``.

    Attributes
    ----------
    pipeline : ext_observer.pipeline.raw_imu.RawImuPipeline
        The estimator with its input checks and counters.
    pairer : ext_observer.pipeline.pairing.StepPairer
        The pipeline's.

    Raises
    ------
    ParameterError
        If a parameter is refused at start-up.

    """

    NODE_NAME = 'imu_filter'
    INPUT_WORDS = {'increment': 'IMU samples', 'measurement': 'magnetic fields'}

    def __init__(self, node_name=NODE_NAME, **kwargs):
        super().__init__(node_name, IMU_FILTER_PARAMETERS, imu_filter_settings, **kwargs)
        settings = self.parameters.settings
        # The compiled kernels where numba is installed, but the node waits
        # neither for the compiler (a cold cache) nor for loading them: it
        # starts on the plain ones, the same estimates (docs/compiled.md).
        plan = start_plan()
        self.pipeline = RawImuPipeline(settings, depth=settings['queue_depth'],
                                       compiled=False if plan == 'background' else None)
        self.pairer = self.pipeline.pairer
        # One set of counters: the pipeline counts the resets it makes
        # itself (stamps), the node those it is told of (clock, service).
        self.resets = self.pipeline.resets
        self.reinitializations = self.pipeline.reinitializations
        self.stream = StreamWatch(self, self.INPUT_WORDS['increment'])
        # Inputs that did not decode (serialized_io), by kind.
        self.undecodable = dict.fromkeys(KINDS, 0)
        serialized = settings['serialized_io']
        self.increment_subscription = self._subscribe(
            Imu, IMU_TOPIC, self.imu_data_raw_serialized_callback if serialized
            else self.imu_data_raw_callback, raw=serialized, lost=self.stream.message_lost)
        self.measurement_subscription = (
            self._subscribe(MagneticField, MAG_TOPIC, self.imu_mag_serialized_callback
                            if serialized else self.imu_mag_callback, raw=serialized)
            if settings['use_mag'] else None)
        # The velocity aid's odom or velocity topic (velocity_source).
        self.velocity_input = VelocityTopic(self, settings)
        self._estimate_msg = QuaternionStamped()
        # The two paths' adapters (imu_filter_io; Inputs, below).
        self._typed = TypedPath(self._estimate_msg)
        self._serialized = SerializedPath()
        self._status_steps = self._status_fields = 0
        self._said = set()
        self._field_lost = False
        self._health = HealthWatch()
        # The frame_id of the first IMU sample and field, for the mounting check.
        self._frames = {'imu': None, 'mag': None}
        self._unit_counts = dict(self.pipeline.units.counts)
        self._status_clipped = 0
        self._calibration_state = None  # as last reported
        self._calibration_resets = 0  # the calibration's start-overs, as last reported
        self.save_calibration_service = self.create_service(
            Trigger, '~/save_calibration', self.save_calibration_callback)
        self._cache_settings(settings)
        logger = self.get_logger()
        self._create_extra_outputs(settings, logger)
        logger.info(
            f'raw IMU on {self.increment_subscription.topic_name}'
            + (f' and {self.measurement_subscription.topic_name}' if settings['use_mag']
               else ' (use_mag false: heading free)')
            + (f', velocity on {self.velocity_input.subscription.topic_name}'
               if self.velocity_input.subscription is not None else '')
            + f', world frame {settings["world_frame"]}, '
            f'{self.pipeline.estimator.core.params}'
            + ('' if serialized else '; serialized_io false: messages deserialized'))
        logger.info(covariance_text(settings))
        self.compiler = None
        if plan == 'plain' and plain_warning():
            logger.warning(plain_warning())
        if plan == 'background':
            self.compiler = BackgroundCompile()
            self._compile_timer = self.create_timer(0.1, self.compile_timer_callback)
            if self.compiler.compiling:
                logger.info(f'compiling the estimator\'s kernels in the background (pid '
                            f'{self.compiler.pid}, once per install or upgrade): the '
                            'plain kernels run meanwhile, with the same estimates')
        unused = unused_text(self.parameters.values, self.parameters.given)
        if unused:
            logger.warning(unused)
        self._warn_deprecated(settings)

    def _warn_deprecated(self, settings):
        """Log once that mag_frame_rpy is deprecated (at start, or when set at runtime)."""
        text = mag_frame_rpy_text(settings)
        if text is not None and 'mag_frame_rpy' not in self._said:
            self._said.add('mag_frame_rpy')
            self.get_logger().warning(text)

    def _create_extra_outputs(self, settings, logger):
        """imu_filter_madgwick's debug topics and TF, where the settings ask for them."""
        self.rpy_filtered_publisher = self.rpy_raw_publisher = None
        self.steady_state_publisher = None
        if settings['publish_debug_topics']:
            # imu_filter_madgwick's debug topics (and the complementary filter's).
            qos = QoSProfile(depth=settings['queue_depth'])
            self.rpy_filtered_publisher = self.create_publisher(
                Vector3Stamped, 'imu/rpy/filtered', qos)
            self.rpy_raw_publisher = self.create_publisher(Vector3Stamped, 'imu/rpy/raw', qos)
            self.steady_state_publisher = self.create_publisher(Bool, 'imu/steady_state', qos)
        self.tf_broadcaster = None
        if settings['publish_tf']:
            self.tf_broadcaster, error = transform_broadcaster(self)
            if self.tf_broadcaster is None:
                logger.warning(NO_TF2.format(error=error))
            else:
                self._transform = TransformStamped()

    @property
    def state(self):
        """The current estimate in ``world_frame`` (ambient; None before the first step)."""
        return self.pipeline.estimator.state

    @property
    def observer(self):
        """The core's estimator, :class:`~ext_observer.core.ahrs.ahrs_observer.AhrsObserver`."""
        return self.pipeline.estimator.core

    @property
    def drops(self):
        """Inputs dropped, by reason."""
        return self.pairer.drops

    @property
    def counts(self):
        """``imu_samples`` and ``fields`` received, ``fields_used``."""
        received, processed = self.pairer.received, self.pairer.processed
        return {'imu_samples': received['increment'], 'fields': received['measurement'],
                'fields_used': processed['measurement']}

    # Inputs ---------------------------------------------------------------
    #
    # One body per input, _imu_sample and _field_sample, for both paths: the
    # typed (rclpy's message objects) and the serialized (CDR bytes). What
    # differs is confined to the paths' adapters (imu_filter_io): the input
    # decoded (stamp, vectors, where the covariance goes) and the outputs
    # written (the message filled in place, or bytes).

    def imu_data_raw_callback(self, msg):
        """Take one IMU sample; publish the estimate of the step it closes."""
        self._imu_sample(self._typed, msg)

    def imu_data_raw_serialized_callback(self, raw):
        """
        Take one IMU sample as CDR bytes; publish the estimate of its step as bytes.

        The same estimates and messages as :meth:`imu_data_raw_callback`
        (docs/nodes.md#serialized-inputs-and-outputs), without a message
        object: rclpy neither deserializes the input nor serializes the outputs.
        """
        self._imu_sample(self._serialized, raw)

    def _imu_sample(self, path, sample):
        """
        Run the pipeline on one IMU sample and publish its outputs.

        Parameters
        ----------
        path : ext_observer.nodes.imu_filter_io.TypedPath or SerializedPath
            The sample's path: its decoding and its outputs.
        sample : sensor_msgs.msg.Imu or bytes
            The input, as the subscription gave it.

        """
        try:
            stamp, gyr, acc, covariance, out_stamp, order, body = path.imu(
                sample, self._covariance_estimated)
        except Undecodable as error:
            self._undecodable('increment', error)
            return
        if self._frames['imu'] is None:
            self._frames['imu'] = path.frame(sample)
        # No clock is read: the steps wait for nothing.
        outcome, estimate = self.pipeline.imu(stamp, gyr, acc, covariance)
        if outcome == BACKWARD_JUMP:
            self._backward_jump(stamp, reset=False)
        self.stream.sample(stamp)
        if estimate is None:
            return
        if estimate.step.gap:
            self._forward_gap(estimate.step, reset=False)
        if estimate.reason is not None:
            self._reinitialized(estimate.reason, estimate.step.stamp, 'the sample',
                                count=False)
        state = estimate.state
        w, x, y, z = state
        if self._publish_estimate:
            self.estimate_publisher.publish(path.estimate(out_stamp, w, x, y, z))
        if self.rpy_filtered_publisher is not None or self.tf_broadcaster is not None:
            header = path.header(sample, stamp)
            if self.rpy_filtered_publisher is not None:
                self._publish_debug(header, state, acc)
            if self.tf_broadcaster is not None:
                self._broadcast(header, state)
        if self._publish_imu:
            # The sample itself goes out, its header, rates and covariances
            # passed through (as imu_filter_madgwick does).
            self.imu_publisher.publish(path.imu_data(
                sample, order, body, w, x, y, z, covariance,
                without_gravity(acc, self.observer.q) if self._remove_gravity else None))

    def imu_mag_callback(self, msg):
        """Take a magnetic field (T) and correct the heading with it at once."""
        self._field_sample(self._typed, msg)

    def imu_mag_serialized_callback(self, raw):
        """Take a magnetic field (T) as CDR bytes and correct the heading with it."""
        self._field_sample(self._serialized, raw)

    def _field_sample(self, path, sample):
        """Correct the heading with a field; ``sample`` the message or its bytes."""
        try:
            stamp, field = path.field(sample)
        except Undecodable as error:
            self._undecodable('measurement', error)
            return
        if self._frames['mag'] is None:
            self._frames['mag'] = path.frame(sample)
        self.pipeline.field(stamp, field)

    def _undecodable(self, kind, error):
        self.undecodable[kind] += 1
        topic = IMU_TOPIC if kind == 'increment' else MAG_TOPIC
        self.get_logger().warning(
            f'{self.resolve_topic_name(topic)}: a message that does not decode ({error}); '
            f'dropped (undecodable_{kind} in /diagnostics)', throttle_duration_sec=LOG_THROTTLE)

    def _forget_samples(self):
        self.stream.restart()

    def _broadcast(self, header, state):
        """The orientation on /tf, as imu_filter_madgwick's publishTransform."""
        settings = self.parameters.settings
        parent, child, (w, x, y, z) = transform_from_estimate(
            state, settings['fixed_frame'], header.frame_id, settings['reverse_tf'])
        t = self._transform
        t.header.stamp = header.stamp
        t.header.frame_id = parent
        t.child_frame_id = child
        r = t.transform.rotation
        r.w, r.x, r.y, r.z = w, x, y, z
        self.tf_broadcaster.sendTransform(t)

    def _publish_debug(self, header, state, acc):
        """imu/rpy/filtered (the estimate), imu/rpy/raw (the sample alone), imu/steady_state."""
        w, x, y, z = state
        n = (w * w + x * x + y * y + z * z) ** 0.5
        rpy = Vector3Stamped(header=header)
        v = rpy.vector
        # Of the normalized orientation, the one imu/data carries.
        v.x, v.y, v.z = rpy_from_quaternion((w / n, x / n, y / n, z / n))
        self.rpy_filtered_publisher.publish(rpy)
        estimator = self.pipeline.estimator
        field = estimator.latest_field if estimator.core.use_mag else None
        rpy = Vector3Stamped(header=header)
        v = rpy.vector
        v.x, v.y, v.z = rpy_from_quaternion(raw_attitude(acc, field, estimator.frame))
        self.rpy_raw_publisher.publish(rpy)
        self.steady_state_publisher.publish(Bool(data=bool(estimator.core.rest)))

    def compile_timer_callback(self):
        """Go on with the compiled kernels once the background compile has them."""
        compiler = self.compiler
        kernels = compiler.take()
        if kernels is not None:
            # Between two samples (one executor thread): the same state, the
            # same estimates from here on, faster.
            self.pipeline.estimator.use_kernels(kernels)
            gc.freeze()     # numba's objects too (node_common._spin)
            if compiler.compiling:
                self.get_logger().info(f'compiled kernels ready after {compiler.seconds:.1f} '
                                       's: the estimator goes on with them')
        elif compiler.error is not None:
            self.get_logger().warning(f'compiled kernels unavailable, the plain ones go on: '
                                      f'{compiler.error}')
        elif compiler.running:
            return
        self._compile_timer.cancel()
        self.destroy_timer(self._compile_timer)
        compiler.stop()
        self.compiler = None

    def destroy_node(self):
        """End a background compile, then destroy the node."""
        if getattr(self, 'compiler', None) is not None:
            self.compiler.stop()
            self.compiler = None
        super().destroy_node()

    # Resets (EstimatorNode) -------------------------------------------------

    def _reset_estimator(self):
        self.pipeline.estimator.reset()

    def _reset_message(self):
        return 'raw-IMU estimator reset: the next sample initializes it from gravity'

    # Parameters -----------------------------------------------------------

    def _cache_settings(self, settings):
        variance = settings['orientation_stddev'] ** 2
        self._orientation_covariance = [variance, 0.0, 0.0, 0.0, variance, 0.0,
                                        0.0, 0.0, variance]
        self._covariance_estimated = settings['covariance_estimated']
        self._remove_gravity = settings['remove_gravity_vector']
        self._typed.configure(settings['frame_id'], self._orientation_covariance)
        self._serialized.configure(settings['frame_id'], settings['orientation_stddev'])

    def _apply_parameters(self, settings, changed):
        super()._apply_parameters(settings, changed)
        self.pipeline.configure(settings)
        self._cache_settings(settings)
        self._warn_deprecated(settings)

    # Diagnostics (EstimatorNode) ------------------------------------------

    def _estimator_values(self):
        units = self.pipeline.units.counts
        values = self.pipeline.estimator.key_values()
        if self.compiler is not None:
            now = 'plain (compiling)' if self.compiler.compiling else 'plain (loading)'
            values = [(key, now if key == 'kernels' else value) for key, value in values]
        silence = self.pipeline.field_silence()
        return (values + [(f'implausible_{kind}', count) for kind, count in units.items()]
                + self.stream.key_values() + self.velocity_input.key_values()
                + [('health', health_text(self._health(self.pipeline))),
                   ('field_lost', self._field_lost),
                   ('field_silent_s', math.nan if silence is None else silence),
                   ('field_frame_mismatch', self._frame_mismatch() is not None)])

    def faults(self):
        """The fault counters (EstimatorNode's), and the inputs that did not decode."""
        counters = super().faults()
        counters.update((f'undecodable_{kind}', count)
                        for kind, count in self.undecodable.items())
        counters.update(self.velocity_input.faults())
        return counters

    def _problems(self, steps):
        parts = []
        fields = self.pairer.processed['measurement']
        if (self.measurement_subscription is not None and steps > self._status_steps
                and fields == self._status_fields):
            text = (f'no magnetic field on {self.measurement_subscription.topic_name} '
                    'since the last status: heading not corrected')
            parts.append(text)
            if fields == 0 and 'no_field' not in self._said:
                # Said once in the log; /diagnostics says it at every status.
                self._said.add('no_field')
                self.get_logger().warning(text + ' (use_mag true: is the magnetometer '
                                          'publishing there?)')
        self._status_steps, self._status_fields = steps, fields
        parts.extend(self._field_problems())
        units = self.pipeline.units
        topics = {'field': MAG_TOPIC, 'acceleration': IMU_TOPIC,
                  'angular_velocity': IMU_TOPIC}
        for kind, count in units.counts.items():
            if count == self._unit_counts[kind]:
                continue
            text = f'{self.resolve_topic_name(topics[kind])}: {units.findings[kind]}'
            parts.append(text)
            if kind not in self._said:
                self._said.add(kind)
                self.get_logger().warning(
                    text + ' (the samples are used as they are; counted in '
                    f'/diagnostics as implausible_{kind})')
        self._unit_counts = dict(units.counts)
        parts.extend(self._clipping_problems())
        parts.extend(self._calibration_problems())
        parts.extend(self.velocity_input.problems(steps))
        parts.extend(self.stream.problems(self._clock.now().nanoseconds))
        return parts

    def _field_problems(self):
        # A field lost (none for mag_timeout on the IMU's stamps): WARN while
        # it lasts, the log once per episode; and a field in another frame.
        parts = []
        silence = self.pipeline.field_silence()
        timeout = self.parameters.settings['mag_timeout']
        lost = (self.measurement_subscription is not None and silence is not None
                and 0.0 < timeout <= silence)
        logger = self.get_logger()
        if lost:
            text = (f'field lost: no magnetic field on {self.measurement_subscription.topic_name}'
                    f' for {silence:.1f} s (mag_timeout {timeout:g} s): running 6D, the '
                    'heading held on the gyro, its variance growing')
            parts.append(text)
            if not self._field_lost:
                logger.warning(text)
        elif self._field_lost:
            logger.info('magnetic field back: the heading returns to it at the rate of '
                        'ahrs.tau_mag')
        self._field_lost = lost
        text = self._frame_mismatch()
        if text is not None:
            parts.append(text)
            if 'frame_mismatch' not in self._said:
                self._said.add('frame_mismatch')
                logger.warning(text)
        return parts

    def _frame_mismatch(self):
        """The text for a field in another frame than the IMU's with no mounting set, or None."""
        imu, mag = self._frames['imu'], self._frames['mag']
        if imu is None or mag is None or imu == mag:
            return None
        if field_mounting(self.parameters.settings) is not None:
            return None
        return (f"magnetic field in frame '{mag}', IMU samples in '{imu}', and no mag_mounting "
                'set: the field is used as if in the IMU frame. Set mag_mounting to the '
                "mounting (a unit quaternion w, x, y, z; the node cannot look it up on /tf: "
                'tf2 is not on PyPI), or give both the same frame_id')

    def _clipping_problems(self):
        # A gyro at its range (ahrs.gyro_range, or a rate stuck at its peak):
        # WARN while it clips, a line in the log the first time.
        clipped = self.pipeline.estimator.core.clipped
        new = clipped - self._status_clipped
        self._status_clipped = clipped
        if new <= 0:
            return []
        text = (f'gyro clipped: {new} samples at its range since the last status (the '
                'attitude is taken again from the accelerometer and the field)')
        if 'gyro_clipped' not in self._said:
            self._said.add('gyro_clipped')
            self.get_logger().warning(text + '; a wider range in the driver avoids it')
        return [text]

    def _calibration_problems(self):
        # The online magnetometer calibration: WARN while it learns from the
        # fields that came (the heading is held on the gyro), a line in the
        # log at each change.
        core = self.pipeline.estimator.core
        state = core.calibration_state
        resets = 0 if core.calibration is None else int(core.calibration.counts['resets'][0])
        if resets > self._calibration_resets:
            self.get_logger().warning(
                'magnetometer calibration started over: the fields no longer fit it (a '
                'magnet or payload taken off or moved on the body, or it was learned wrong); '
                f'{resets} so far (diagnostics: calibration_resets)')
        self._calibration_resets = resets
        if state == 'learning' and not self.pairer.processed['measurement']:
            state = None
        if state == 'converged' and core.calibration.applied:
            state = 'applied'
        if state != self._calibration_state:
            logger = self.get_logger()
            if state == 'applied':
                logger.info('magnetometer calibration converged and applied: the heading was '
                            'aligned once to the calibrated field and follows it from now '
                            'on; ~/save_calibration writes it to '
                            f'{self.parameters.settings["calibration_file"]}')
            elif state == 'converged':
                logger.info('magnetometer calibration converged: it turns the heading by '
                            'less than ahrs.mag_cal_deadband, so the field is used as given '
                            '(the sensor looks calibrated); applied if that changes')
            elif state == 'learning':
                logger.warning('magnetometer calibration learning: the heading is held on '
                               'the gyro until it converges (turn the sensor about several '
                               'axes)')
            elif state == 'loaded':
                logger.info('magnetometer calibration: started from the saved one '
                            '(mag_bias_*, mag_soft_iron), refined online')
            self._calibration_state = state
        if state == 'learning':
            return ['magnetometer calibration learning: heading held on the gyro until it '
                    'converges']
        return []

    def save_calibration_callback(self, request, response):
        """Service ``~/save_calibration``: write the calibrations as a params file."""
        path = self.parameters.settings['calibration_file']
        estimator = self.pipeline.estimator
        # The gyro bias always; the magnetometer's once it has one.
        gyro_bias = estimator.core.bias
        try:
            bias, soft_iron = estimator.calibration()
            missing = ''
        except ValueError as error:
            bias = soft_iron = None
            missing = f'; magnetometer calibration not saved: {error}'
        try:
            write_params(path, bias, soft_iron, node=self.get_name(), gyro_bias=gyro_bias,
                         comment=f'The calibration {self.get_fully_qualified_name()} '
                         'learned; load it with --params-file.')
        except (ValueError, OSError) as error:
            response.success = False
            response.message = str(error)
            self.get_logger().warning(f'~/save_calibration: {error}')
            return response
        response.success = True
        response.message = (f'saved to {os.path.abspath(path)}: gyro bias '
                            + ', '.join(f'{v:.6g}' for v in gyro_bias) + ' rad/s'
                            + (', magnetometer calibration' if bias is not None else missing))
        (self.get_logger().info if bias is not None else self.get_logger().warning)(
            f'~/save_calibration: {response.message}')
        return response


def main(args=None):
    """Run the ``imu_filter`` node (``ros2 run ext_observer imu_filter_node``)."""
    return run_node(ImuFilterNode, args)


if __name__ == '__main__':
    import sys
    sys.exit(main())
