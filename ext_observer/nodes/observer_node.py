"""
The ``observer`` node: the core's Luenberger-like observer on ROS topics.

Step k pairs a gyro increment (``gyro/increment``, or integrated from
``imu/data_raw``) with an attitude measurement (``attitude/measurement``,
``attitude/imu`` or ``attitude/pose``) through
:class:`~ext_observer.pipeline.pairing.StepPairer`, runs the guarded
observer (:class:`~ext_observer.pipeline.guard.GuardedObserver`) and
publishes ``attitude_estimate`` (ambient), ``attitude_estimate/unit`` and
``imu/data``, stamped ``t_{k+1}``. Topics and stamps: docs/nodes.md; faults
and what each does: docs/faults.md; the raw-IMU estimator is
``imu_filter_node``.
"""

import math

from builtin_interfaces.msg import Time
from geometry_msgs.msg import PoseStamped, QuaternionStamped, Vector3Stamped
from rclpy.qos import QoSProfile
from sensor_msgs.msg import Imu

from ext_observer.nodes.conversions import (nanoseconds_from_stamp, quaternion_from_msg,
                                      STAMP_MAX, vector_from_msg)
from ext_observer.nodes.estimator_node_base import (EstimatorNode, floor_text, LOG_THROTTLE,
                                         RESET_CAUSES, SECOND, STATUS_SUFFIX)
from ext_observer.pipeline.guard import GUARD_REASONS, GuardedObserver
from ext_observer.nodes.node_common import run_node
from ext_observer.nodes.node_parameters import (CERTIFIED_EPSILON, INCREMENT_TOPICS,
                                              make_observer, MEASUREMENT_TOPICS,
                                              OBSERVER_PARAMETERS, observer_settings,
                                              pairing_settings, RELIABILITIES)
from ext_observer.pipeline.pairing import BACKWARD_JUMP, DROP_REASONS, StepPairer

__all__ = ['CERTIFIED_EPSILON', 'DROP_REASONS', 'GUARD_REASONS', 'OBSERVER_PARAMETERS',
           'RESET_CAUSES', 'STATUS_SUFFIX', 'ObserverNode', 'main', 'observer_settings']


class ObserverNode(EstimatorNode):
    """
    Estimate the attitude from gyro increments and attitude measurements.

    Parameters
    ----------
    node_name : str
        Default ``observer``.
    **kwargs
        Passed to ``rclpy.node.Node`` (``context``, ``namespace``,
        ``parameter_overrides``, ...).

    Attributes
    ----------
    guarded : ext_observer.pipeline.guard.GuardedObserver
        The core's observer with the divergence guard.
    pairer : ext_observer.pipeline.pairing.StepPairer
        Validation, stamps, pairing and the input counters.
    resets : dict
        Restarts from the initial estimate, by cause (:data:`RESET_CAUSES`).
    reinitializations : dict
        Restarts from the latest measurement by the divergence guard, by
        reason (:data:`~ext_observer.pipeline.guard.GUARD_REASONS`).

    Raises
    ------
    ParameterError
        If a parameter is refused at start-up.

    """

    NODE_NAME = 'observer'

    def __init__(self, node_name=NODE_NAME, **kwargs):
        super().__init__(node_name, OBSERVER_PARAMETERS, observer_settings, **kwargs)
        settings = self.parameters.settings
        depth = settings['queue_depth']
        self.increment_source = settings['increment_source']
        self.measurement_source = settings['measurement_source']
        self.guarded = GuardedObserver(make_observer(settings),
                                       settings['divergence_max_residual'],
                                       settings['divergence_max_innovation'])
        self.pairer = StepPairer(depth=depth, **pairing_settings(settings))
        self._last_interval = None
        output_qos = QoSProfile(depth=depth)
        self.unit_publisher = self.create_publisher(
            QuaternionStamped, 'attitude_estimate/unit', output_qos,
            event_callbacks=self.qos.publisher('attitude_estimate/unit', output_qos,
                                               matched=self.unit_matched_callback))
        # gyro/increment with input_reliability, the other sources with the
        # sensor-data QoS (overridable).
        if self.increment_source == 'increment':
            self.increment_subscription = self._subscribe(
                Vector3Stamped, INCREMENT_TOPICS['increment'], self.increment_callback,
                RELIABILITIES[settings['input_reliability']])
        else:
            self.increment_subscription = self._subscribe(
                Imu, INCREMENT_TOPICS['imu'], self.imu_data_raw_callback)
        measurement_type, measurement_callback = {
            'quaternion': (QuaternionStamped, self.measurement_callback),
            'imu': (Imu, self.attitude_imu_callback),
            'pose': (PoseStamped, self.attitude_pose_callback)}[self.measurement_source]
        self.measurement_subscription = self._subscribe(
            measurement_type, MEASUREMENT_TOPICS[self.measurement_source],
            measurement_callback)
        # The per-step path reads no parameter and builds no message: the
        # settings it needs are cached (_cache_settings), the outputs are
        # built once and their fields set in place before each publish.
        self._now = self._clock.now().nanoseconds
        self._estimate_msg = QuaternionStamped()
        self._stamp = Time()  # of a step with no sample of its own
        self._unit_msg = QuaternionStamped()
        # imu/data of a step without an IMU sample at hand (the increments
        # come from gyro/increment, or the sample was pushed out of the
        # queue): its rates are not known, -1 in the first element of their
        # covariances (sensor_msgs/Imu).
        self._imu_msg = Imu()
        self._imu_msg.angular_velocity_covariance[0] = -1.0
        self._imu_msg.linear_acceleration_covariance[0] = -1.0
        # IMU samples by stamp, (message, ω), until the step their stamp
        # ends is published (the message goes out on imu/data with the
        # estimate).
        self._imu_samples = {}
        self._body_frame_id = ''
        self._cache_settings(settings)
        self._publish_unit = self.unit_publisher.get_subscription_count() > 0
        self._timeout_timer = None
        self._start_timeout_timer(settings)
        self.get_logger().info(
            f'{settings["variant"]} observer, alpha {settings["alpha"]:g}, '
            f'{settings["gain_mode"]} gain {self._gain_text(settings)}; increments on '
            f'{self.increment_subscription.topic_name}, measurements on '
            f'{self.measurement_subscription.topic_name}')

    @property
    def observer(self):
        """The core's estimator, :class:`~ext_observer.core.SingleObserver`."""
        return self.guarded.observer

    @property
    def state(self):
        """The current estimate (ambient, w, x, y, z)."""
        return self.guarded.state

    @property
    def drops(self):
        """Inputs dropped, by reason (:data:`DROP_REASONS`)."""
        return self.pairer.drops

    @property
    def counts(self):
        """
        The inputs and what came of them.

        ``increments``, ``measurements`` received; ``steps_corrected``,
        ``steps_propagated``.
        """
        received, processed = self.pairer.received, self.pairer.processed
        return {'increments': received['increment'],
                'measurements': received['measurement'],
                'steps_corrected': processed['measurement'],
                'steps_propagated': processed['increment'] - processed['measurement']}

    @staticmethod
    def _gain_text(settings):
        mode = settings['gain_mode']
        if mode == 'constant':
            return f'L = {settings["gain"]}'
        if mode == 'rotating':
            return f'kappa {settings["kappa"]:g}'
        return f'kappa_min {settings["kappa_min"]:g}'

    # Inputs ---------------------------------------------------------------

    def increment_callback(self, msg):
        """Take ``θ_k`` and process every step that is ready."""
        # The clock is read once per step, here: the increment's deadline
        # needs it. A measurement releases steps by stamps, not by time, so
        # its callback uses this reading; the timeout timer reads the clock
        # again for the deadlines.
        now = self._now = self._clock.now().nanoseconds
        stamp = nanoseconds_from_stamp(msg.header.stamp)
        self._body_frame_id = msg.header.frame_id
        if self.pairer.add_increment(stamp, vector_from_msg(msg.vector), now) == BACKWARD_JUMP:
            self._backward_jump(stamp)
        self._process(now)

    def imu_data_raw_callback(self, msg):
        """Take an IMU sample ``ω`` (rad/s); its successor makes the increment."""
        stamp = nanoseconds_from_stamp(msg.header.stamp)
        pairer = self.pairer
        now = self._now = self._clock.now().nanoseconds
        self._body_frame_id = msg.header.frame_id
        omega = vector_from_msg(msg.angular_velocity)
        if pairer.add_angular_velocity(stamp, omega, now) == BACKWARD_JUMP:
            self._backward_jump(stamp)
        if pairer.pending_stamp == stamp:
            # Taken (a dropped sample is never kept, nor replaces one).
            samples = self._imu_samples
            samples[stamp] = msg
            if len(samples) > 2 * self._depth + 2:
                del samples[next(iter(samples))]
        self._process(now)

    def attitude_imu_callback(self, msg):
        """Take ``y`` from the orientation of a ``sensor_msgs/Imu``."""
        if msg.orientation_covariance[0] == -1.0:
            # The driver says it has no orientation (sensor_msgs/Imu).
            self.pairer.reject('measurement', 'no_orientation')
            return
        self._measurement(msg.header.stamp, msg.orientation)

    def attitude_pose_callback(self, msg):
        """Take ``y`` from the orientation of a ``geometry_msgs/PoseStamped``."""
        self._measurement(msg.header.stamp, msg.pose.orientation)

    def measurement_callback(self, msg):
        """Take ``y_k`` and process every step that is ready."""
        self._measurement(msg.header.stamp, msg.quaternion)

    def _measurement(self, header_stamp, quaternion):
        stamp = nanoseconds_from_stamp(header_stamp)
        if self.pairer.add_measurement(stamp, quaternion_from_msg(quaternion)) \
                == BACKWARD_JUMP:
            self._backward_jump(stamp)
        self._process(self._now)

    def timeout_callback(self):
        """Propagate the steps whose measurement did not come in time."""
        now = self._now = self._clock.now().nanoseconds
        # attitude_estimate/unit and imu/data go out only while someone
        # subscribes: the matched event says so at once, this timer keeps it
        # right.
        self._publish_unit = self.unit_publisher.get_subscription_count() > 0
        self._publish_imu = self.imu_publisher.get_subscription_count() > 0
        self._process(now)

    def unit_matched_callback(self, info):
        """A subscription to ``attitude_estimate/unit`` came or went."""
        self._publish_unit = info.current_count > 0

    # Resets (EstimatorNode) -------------------------------------------------

    def _reset_estimator(self):
        self.guarded.reset()

    def _reset_message(self):
        return f'observer reset to the initial estimate {list(self.guarded.state)}'

    def _forget_samples(self):
        self._imu_samples.clear()

    # Steps ----------------------------------------------------------------

    def _process(self, now):
        for step in self.pairer.pop_ready(now):
            self._step(step)

    def _step(self, step):
        """Run one released step and publish its estimate."""
        if step.gap:
            self._forward_gap(step)
        elif step.previous is not None:
            self._last_interval = step.stamp - step.previous
        # The sample stamped t_{k+1} closed the step: it goes out with q̂_{k+1}.
        sample = None if step.end is None else self._take_imu_sample(step.end)
        state, reason = self.guarded.step(step.increment, step.measurement)
        if reason is not None:
            self._reinitialized(reason, step.stamp, 'the latest measurement')
        if step.early:
            self.get_logger().warning(
                f'{self._depth} increments waiting: stepping without waiting for '
                'measurements', throttle_duration_sec=LOG_THROTTLE)
        msg = self._estimate_msg
        if sample is not None:
            # Stamped t_{k+1}, the sample's own stamp.
            stamp = msg.header.stamp = sample.header.stamp
        else:
            end = step.end
            if end is None:
                end = min(step.stamp + (self._period or self._last_interval or 0), STAMP_MAX)
            stamp = self._stamp
            stamp.sec, stamp.nanosec = divmod(end, SECOND)
            msg.header.stamp = stamp
        w, x, y, z = state
        q = msg.quaternion
        q.w, q.x, q.y, q.z = w, x, y, z
        self.estimate_publisher.publish(msg)
        if self._publish_unit or self._publish_imu:
            n = math.sqrt(w * w + x * x + y * y + z * z)
            w, x, y, z = w / n, x / n, y / n, z / n
        if self._publish_unit:
            msg = self._unit_msg
            msg.header.stamp = stamp
            q = msg.quaternion
            q.w, q.x, q.y, q.z = w, x, y, z
            self.unit_publisher.publish(msg)
        if self._publish_imu:
            if sample is not None:
                # The sample itself goes out, its header, rates and
                # covariances passed through (as imu_filter_madgwick does):
                # the message is this node's once its callback has run.
                msg = sample
                msg.orientation_covariance = self._orientation_covariance
            else:
                msg = self._imu_msg
                msg.header.stamp = stamp
                msg.header.frame_id = self._body_frame_id
            q = msg.orientation
            q.w, q.x, q.y, q.z = w, x, y, z
            self.imu_publisher.publish(msg)

    def _take_imu_sample(self, stamp):
        """Remove and return the kept sample stamped ``stamp`` (and older ones), or None."""
        samples = self._imu_samples
        while samples:
            first = next(iter(samples))
            if first > stamp:
                return None
            sample = samples.pop(first)
            if first == stamp:
                return sample
        return None

    def _cache_settings(self, settings):
        # step_period in ns (0: the interval between the two last steps).
        self._period = round(settings['step_period'] * SECOND)
        self._depth = settings['queue_depth']
        self._imu_msg.orientation_covariance = [
            float(v) for v in settings['orientation_covariance']]
        # The same (numpy) array goes into every sample passed through.
        self._orientation_covariance = self._imu_msg.orientation_covariance
        self._estimate_msg.header.frame_id = settings['frame_id']
        self._unit_msg.header.frame_id = settings['frame_id']

    # Parameters -----------------------------------------------------------

    def _start_timeout_timer(self, settings):
        if self._timeout_timer is not None:
            self.destroy_timer(self._timeout_timer)
        # Deadlines are checked four times per timeout (at most at 200 Hz).
        # With no timeout at all an increment never waits, so a slow check is
        # enough.
        timeout = settings['measurement_timeout']
        period = min(max(timeout / 4.0, 0.005), 0.25) if timeout > 0.0 else 0.25
        self._timeout_timer = self.create_timer(period, self.timeout_callback)

    def _apply_parameters(self, settings, changed):
        super()._apply_parameters(settings, changed)
        structural = {'variant', 'alpha', 'gain', 'gain_mode', 'kappa', 'kappa_min',
                      'align_sign'}
        if changed & structural:
            # Keep the current estimate: a new gain acts from the next step on.
            observer = make_observer(settings, initial=self.observer.state)
            observer.measurements_used = self.observer.measurements_used
            self.guarded.observer = observer
            self.get_logger().info(
                f'now {settings["variant"]} observer, alpha {settings["alpha"]:g}, '
                f'{settings["gain_mode"]} gain {self._gain_text(settings)}')
        self._cache_settings(settings)
        self.guarded.max_residual = settings['divergence_max_residual']
        self.guarded.max_innovation = settings['divergence_max_innovation']
        self.pairer.configure(**pairing_settings(settings))
        if 'measurement_timeout' in changed:
            self._start_timeout_timer(settings)

    # Diagnostics (EstimatorNode) ------------------------------------------

    def _estimator_values(self):
        settings = self.parameters.settings
        return [('variant', settings['variant']), ('alpha', settings['alpha']),
                ('gain_mode', settings['gain_mode']),
                ('align_sign', settings['align_sign']),
                ('increment_source', self.increment_source),
                ('measurement_source', self.measurement_source)]

    def _silent_texts(self, silent, timeout):
        quiet = super()._silent_texts(silent, timeout)
        if not quiet and silent['measurement'] >= timeout:
            quiet['measurement'] = (
                f'no measurements on {self.measurement_subscription.topic_name} for '
                f'{floor_text(silent["measurement"])} s or more: steps propagate')
        return quiet


def main(args=None):
    """Run the ``observer`` node (``ros2 run ext_observer observer_node``)."""
    return run_node(ObserverNode, args)


if __name__ == '__main__':
    import sys
    sys.exit(main())
