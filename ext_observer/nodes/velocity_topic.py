"""
The velocity aid's topic in ``imu_filter_node``: the body's velocity from odometry.

``velocity_source`` ``odom``: ``nav_msgs/Odometry`` on ``odom``, its
``twist.twist.linear`` (m/s, in ``child_frame_id`` as REP 105 has it);
``twist``: ``geometry_msgs/TwistStamped`` on ``velocity``, its ``linear``;
``none`` (the default): no subscription. Each velocity goes to
:meth:`RawImuPipeline.velocity <ext_observer.pipeline.raw_imu.RawImuPipeline.velocity>`;
one that is not finite, out of order or stamped ``velocity_timeout`` before
the latest IMU sample (stale) is dropped, counted by reason and logged
(throttled). Deserialized messages: they come at tens of Hz, not the IMU's rate.
"""

import math

from ext_observer.core.ahrs.ahrs_layout import S_VEL_AGE, S_VEL_N
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
    """

    def __init__(self, node, settings):
        self.node = node
        self.source = settings['velocity_source']
        self.received = self.used = 0
        self.drops = dict.fromkeys(VELOCITY_DROP_REASONS, 0)
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

    def faults(self):
        """``dropped_velocity_<reason>``: a rise makes the status WARN."""
        return {f'dropped_velocity_{reason}': count for reason, count in self.drops.items()}

    def key_values(self):
        """The diagnostic pairs: the source, whether the aid is in use, the age, the counts."""
        core = self.node.observer
        s = core.flat_state
        age = float(s[S_VEL_AGE]) if s[S_VEL_N] > 0.0 else math.nan
        return [('velocity_source', self.source), ('velocity_used', bool(core.velocity_used)),
                ('velocity_age_s', age), ('velocities_received', self.received),
                ('velocities_used', self.used)]

    def problems(self, steps):
        """A WARN while a velocity is asked for and the steps go on without one."""
        if self.subscription is None or steps == 0:
            return []
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
