"""
A node that publishes raw IMU samples (``imu/data_raw``) and fields
(``imu/mag``) from best-effort publishers, and the lockstep replay of a BROAD
excerpt into an imu_filter_node: the field of sample k published once the
node has taken sample k, and sample k + 1 once it has taken the field, so
that the node sees the same sequence as the offline run of the core
(:func:`broad_replay.offline`), whatever the scheduling.
"""

import time

import numpy as np
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Imu, MagneticField
from geometry_msgs.msg import QuaternionStamped

from broad_replay import fields_tesla, stamps
from ext_observer.nodes.conversions import (nanoseconds_from_stamp, quaternion_from_msg,
                                      stamp_from_nanoseconds)


BEST_EFFORT = QoSProfile(depth=100, reliability=ReliabilityPolicy.BEST_EFFORT)


MAG_EVERY = 3


class Driver(Node):
    """A raw IMU driver: imu/data_raw and imu/mag, best effort; records the outputs."""

    def __init__(self, context, imu_topic='imu/data_raw', mag_topic='imu/mag'):
        super().__init__('raw_imu_driver', context=context)
        self.imu_publisher = self.create_publisher(Imu, imu_topic, BEST_EFFORT)
        self.mag_publisher = self.create_publisher(MagneticField, mag_topic, BEST_EFFORT)
        self.outputs = {}
        self.estimates = {}
        self.create_subscription(Imu, 'imu/data', self._keep(self.outputs), 1000)
        self.create_subscription(QuaternionStamped, 'attitude_estimate',
                                 self._keep(self.estimates), 1000)

    @staticmethod
    def _keep(store):
        def callback(msg):
            store[nanoseconds_from_stamp(msg.header.stamp)] = msg
        return callback

    def send_imu(self, stamp, gyr, acc, frame_id='imu_link'):
        msg = Imu()
        msg.header.stamp = stamp_from_nanoseconds(stamp)
        msg.header.frame_id = frame_id
        v = msg.angular_velocity
        v.x, v.y, v.z = (float(a) for a in gyr)
        a = msg.linear_acceleration
        a.x, a.y, a.z = (float(b) for b in acc)
        msg.angular_velocity_covariance[0] = 1e-6
        msg.linear_acceleration_covariance[0] = 1e-3
        # A raw IMU has no orientation.
        msg.orientation_covariance[0] = -1.0
        self.imu_publisher.publish(msg)

    def send_field(self, stamp, field, frame_id='imu_link'):
        msg = MagneticField()
        msg.header.stamp = stamp_from_nanoseconds(stamp)
        msg.header.frame_id = frame_id
        f = msg.magnetic_field
        f.x, f.y, f.z = (float(b) for b in field)
        self.mag_publisher.publish(msg)


def connect(spinner, driver, *observers):
    spinner.spin_until(
        lambda: (driver.imu_publisher.get_subscription_count() == len(observers)
                 and all(o._publish_imu and o._publish_estimate for o in observers)),
        10.0, 'the subscriptions')


def replay_lockstep(spinner, driver, observer, data, count=None, mag_every=MAG_EVERY,
                    first=0):
    """
    Publish samples ``first`` to ``count`` of the excerpt.

    The field of sample k goes between samples k and k + 1, each message
    once the node has taken the one before.
    """
    gyr, acc, mag = data['gyr'], data['acc'], fields_tesla(data)
    count = len(gyr) if count is None else count
    times = stamps(count, float(data['rate']))
    received = observer.pairer.received
    imu0, mag0 = received['increment'], received['measurement']
    fields = 0
    deadline = time.monotonic() + 120.0
    for k in range(first, count):
        driver.send_imu(times[k], gyr[k], acc[k])
        if k % mag_every:
            continue
        while received['increment'] < imu0 + k - first + 1:
            spinner.executor.spin_once(timeout_sec=0.01)
            assert time.monotonic() < deadline, f'sample {k} never arrived'
        driver.send_field(times[k], mag[k])
        fields += 1
        while received['measurement'] < mag0 + fields:
            spinner.executor.spin_once(timeout_sec=0.01)
            assert time.monotonic() < deadline, f'the field of sample {k} never arrived'
    spinner.spin_until(lambda: len(driver.outputs) >= count - 1
                       and len(driver.estimates) >= count - 1, 20.0, 'the last outputs')
    return times


def published(store, times):
    """The published quaternions at ``times[1:]`` as an array (N, 4), NaN for sample 0."""
    out = np.full((len(times), 4), np.nan)
    for k, t in enumerate(times[1:], 1):
        msg = store[t]
        out[k] = quaternion_from_msg(msg.orientation if isinstance(msg, Imu)
                                     else msg.quaternion)
    return out


# imu/data and attitude_estimate against the core run offline on the same
# samples in the same order: the node runs the same float code on the same
# float64 values, so they agree to rounding; measured: 0 (bit for bit).
TOLERANCE = 1e-12
