"""
The velocity aid's topic in ``imu_filter_node``: the body's velocity from odometry.

``velocity_source`` ``odom``: ``nav_msgs/Odometry`` on ``odom``, its
``twist.twist.linear`` (m/s, in ``child_frame_id`` as REP 105 has it);
``twist``: ``geometry_msgs/TwistStamped`` on ``velocity``, its ``linear``;
``none`` (the default): no subscription. Each velocity goes to
:meth:`RawImuPipeline.velocity <ext_observer.pipeline.raw_imu.RawImuPipeline.velocity>`;
one that is not finite, out of order or stamped ``velocity_timeout`` before
the latest IMU sample (stale) is dropped, counted by reason and logged
(throttled). A velocity whose frame (Odometry's ``child_frame_id``,
TwistStamped's ``frame_id``) is not ``velocity_frame`` (by default the IMU
samples' ``frame_id``) is used, as the field in another frame is, but counted
and warned of once: the mounting and lever arm describe another frame.
Deserialized messages: they come at tens of Hz, not the IMU's rate.
"""

import math

from ext_observer.nodes.estimator_node_base import LOG_THROTTLE

__all__ = ['VELOCITY_DROP_REASONS', 'VELOCITY_TOPICS', 'VelocityTopic']

# The topic and message type of each velocity_source.
VELOCITY_TOPICS = {'odom': 'odom', 'twist': 'velocity'}
VELOCITY_DROP_REASONS = ('not_finite', 'out_of_order', 'stale')


def _message_type(source):
    # nav_msgs only where the odometry is asked for.
    if source == 'odom':
        from nav_msgs.msg import Odometry
        return Odometry
    from geometry_msgs.msg import TwistStamped
    return TwistStamped


class VelocityTopic:
    """
    The subscription, its checks, counters, diagnostic pairs and WARN.

    Parameters
    ----------
    node : ext_observer.nodes.imu_filter_node.ImuFilterNode
    settings : dict
        The node's (``velocity_source``, ``velocity_timeout``).

    Attributes
    ----------
    source : str
    subscription : rclpy.subscription.Subscription or None
    received : int
    used : int
        Velocities handed to the estimator.
    drops : dict
        Dropped velocities by reason (:data:`VELOCITY_DROP_REASONS`).
    mismatches : int
        Velocities in another frame than the one expected (:meth:`frame_mismatch`).
    """

    def __init__(self, node, settings):
        self.node = node
        self.source = settings['velocity_source']
        self.received = self.used = 0
        self.drops = dict.fromkeys(VELOCITY_DROP_REASONS, 0)
        self.mismatches = 0
        self._frame = None  # the latest velocity's
        self._warned_frame = False
        self._aided = None  # as last reported: None before the first status
        self.subscription = None
        if self.source != 'none':
            self.subscription = node._subscribe(
                _message_type(self.source), VELOCITY_TOPICS[self.source], self.callback)

    def callback(self, msg):
        """Take one Odometry or TwistStamped; drop it, with its reason, when bad."""
        self.received += 1
        stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        linear = msg.twist.twist.linear if self.source == 'odom' else msg.twist.linear
        self._frame = msg.child_frame_id if self.source == 'odom' else msg.header.frame_id
        if self.frame_mismatch() is not None:
            self.mismatches += 1
        pipeline = self.node.pipeline
        latest = pipeline.pairer.last_stamp
        timeout = self.node.parameters.settings['velocity_timeout']
        reason = None
        if latest is not None and stamp < latest - timeout * 1e9:
            reason = 'stale'
        else:
            reason = pipeline.velocity(stamp, (linear.x, linear.y, linear.z))
        if reason is None:
            self.used += 1
            return
        self.drops[reason] += 1
        self.node.get_logger().warning(
            f'{self.subscription.topic_name}: velocity dropped ({reason}: stamp '
            f'{stamp * 1e-9:.3f} s, linear {linear.x:g}, {linear.y:g}, {linear.z:g}); '
            f'counted as dropped_velocity_{reason}', throttle_duration_sec=LOG_THROTTLE)

    def expected_frame(self):
        """The velocity's frame expected: `velocity_frame`, else the IMU samples' (or None)."""
        return self.node.parameters.settings['velocity_frame'] or self.node._frames['imu']

    def frame_mismatch(self):
        """The text for the latest velocity in another frame than expected, or None."""
        expected = self.expected_frame()
        if self._frame is None or not expected or self._frame == expected:
            return None
        what = 'child_frame_id' if self.source == 'odom' else 'frame_id'
        origin = ('velocity_frame' if self.node.parameters.settings['velocity_frame']
                  else "the IMU samples' frame_id; velocity_frame is empty")
        return (f"velocity on {self.subscription.topic_name} in frame '{self._frame}' "
                f"({what}), expected '{expected}' ({origin}): velocity_mounting and "
                'velocity_lever_arm place the IMU in the expected frame; set velocity_frame '
                'to the frame they describe')

    def faults(self):
        """``dropped_velocity_<reason>``: a rise makes the status WARN."""
        return {f'dropped_velocity_{reason}': count for reason, count in self.drops.items()}

    def key_values(self):
        """The diagnostic pairs: the source, whether the aid is in use, the age, the counts."""
        core = self.node.observer
        age = core.field('vel.age') if core.field('vel.n') > 0.0 else math.nan
        return [('velocity_source', self.source), ('velocity_used', bool(core.velocity_used)),
                ('velocity_age_s', age), ('velocities_received', self.received),
                ('velocities_used', self.used),
                ('velocity_frame_mismatch', self.frame_mismatch() is not None),
                ('velocity_frame_mismatches', self.mismatches)]

    def problems(self, steps):
        """A WARN while the steps go on without a velocity asked for, or it is in another frame."""
        if self.subscription is None:
            return []
        mismatch = self.frame_mismatch()
        if mismatch is not None and not self._warned_frame:
            self._warned_frame = True  # said once in the log; /diagnostics at every status
            self.node.get_logger().warning(mismatch)
        parts = [] if mismatch is None else [mismatch]
        if steps == 0:
            return parts
        return parts + self._aid_problems()

    def _aid_problems(self):
        aided = bool(self.node.observer.velocity_used)
        logger = self.node.get_logger()
        topic = self.subscription.topic_name
        if aided and self._aided is False:
            logger.info(f'velocity on {topic} fresh again: the velocity aid is back')
        text = (f'no fresh velocity on {topic} (none within velocity_timeout '
                f'{self.node.parameters.settings["velocity_timeout"]:g} s): the specific '
                'force is taken as gravity, unaided')
        if not aided and self._aided is not False:
            logger.warning(text)
        self._aided = aided
        return [] if aided else [text]
