"""
imu_filter_node's serialized path against its typed one, through real DDS.

Two nodes in one process, one with ``serialized_io`` true (CDR bytes in and
out, read and written by the node) and one with it false (rclpy's message
objects), take the same BROAD samples; every ``imu/data`` and
``attitude_estimate`` they publish is compared byte for byte (all but the
alignment padding after ``frame_id``, which Fast CDR leaves unwritten in a
typed message), and their estimates to the bit; with the debug topics and
``/tf``, those too (the two paths make their headers apart).
"""

import struct
import time

from diagnostic_msgs.msg import DiagnosticStatus
import numpy as np
import pytest
from geometry_msgs.msg import QuaternionStamped, Vector3Stamped
from rclpy.node import Node
from sensor_msgs.msg import Imu, MagneticField
from std_msgs.msg import Bool

from broad_replay import fields_tesla, load, stamps, TRIALS
from ext_observer.nodes import imu_filter_node
from ext_observer.nodes.imu_filter_node import ImuFilterNode
from ext_observer.recordings import cdr
from imu_driver import BEST_EFFORT
from ros_helpers import overrides

SAMPLES = 400
MAG_EVERY = 4
PATHS = ('serialized', 'typed')
DEBUG_TOPICS = {'imu/rpy/filtered': Vector3Stamped, 'imu/rpy/raw': Vector3Stamped,
                'imu/steady_state': Bool}


def meaningful(raw):
    """The bytes of a message that starts with a Header, but the padding after frame_id."""
    length = int.from_bytes(raw[12:16], 'little')
    body = 4 + ((12 + length + 7) & -8)
    return bytes(raw[:16 + length]) + bytes(raw[body:])


class Feeder(Node):
    """Publishes the same samples to both nodes' inputs; keeps their outputs as bytes."""

    def __init__(self, context):
        super().__init__('feeder', context=context)
        self.imu = [self.create_publisher(Imu, f'/{p}/imu/data_raw', BEST_EFFORT)
                    for p in PATHS]
        self.mag = [self.create_publisher(MagneticField, f'/{p}/imu/mag', BEST_EFFORT)
                    for p in PATHS]
        self.outputs = {p: {} for p in PATHS}
        self.estimates = {p: {} for p in PATHS}
        for p in PATHS:
            self.create_subscription(Imu, f'/{p}/imu/data', self._keep(self.outputs[p]),
                                     1000, raw=True)
            self.create_subscription(QuaternionStamped, f'/{p}/attitude_estimate',
                                     self._keep(self.estimates[p]), 1000, raw=True)

    @staticmethod
    def _keep(store):
        def callback(raw):
            store[cdr.imu_layout(raw)[2] if len(raw) > 200
                  else cdr.decode_orientation(raw, cdr.QUATERNION_TYPE)[0]] = raw
        return callback

    def keep_debug_topics(self):
        """Keep each node's debug topics too, as bytes in the order received."""
        self.debug = {p: {topic: [] for topic in DEBUG_TOPICS} for p in PATHS}
        for p in PATHS:
            for topic, msg_type in DEBUG_TOPICS.items():
                self.create_subscription(msg_type, f'/{p}/{topic}',
                                         self.debug[p][topic].append, 1000, raw=True)


class KeptTransforms:
    """Stands in for tf2_ros's broadcaster (not on PyPI): keeps what it is sent."""

    def __init__(self):
        self.sent = []

    def sendTransform(self, t):  # noqa: N802 (tf2_ros's name)
        # Its fields, the floats as bytes (to the bit).
        v, r = t.transform.translation, t.transform.rotation
        self.sent.append((t.header.stamp.sec, t.header.stamp.nanosec, t.header.frame_id,
                          t.child_frame_id, struct.pack('<7d', v.x, v.y, v.z,
                                                        r.x, r.y, r.z, r.w)))


def header_part(raw):
    """A message that starts with a Header: its stamp (ns) and the bytes that count."""
    sec, nanosec = struct.unpack_from('<iI', raw, 4)
    return sec * 1_000_000_000 + nanosec, meaningful(raw)


def lockstep(spinner, nodes, publishers, make, what):
    """Publish one message to each node; spin until each took it."""
    before = [n.pairer.received[what] + n.undecodable[what] for n in nodes]
    for publisher in publishers:
        publisher.publish(make())
    deadline = time.monotonic() + 10.0
    while any(n.pairer.received[what] + n.undecodable[what] == b
              for n, b in zip(nodes, before)):
        spinner.executor.spin_once(timeout_sec=0.01)
        assert time.monotonic() < deadline, f'a {what} never arrived'


def imu_msg(stamp, gyr, acc):
    msg = Imu()
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(int(stamp), 1_000_000_000)
    msg.header.frame_id = 'imu_link'
    msg.angular_velocity.x, msg.angular_velocity.y, msg.angular_velocity.z = map(float, gyr)
    a = msg.linear_acceleration
    a.x, a.y, a.z = map(float, acc)
    msg.angular_velocity_covariance[4] = 1e-6
    msg.linear_acceleration_covariance[8] = 1e-3
    msg.orientation_covariance[0] = -1.0
    return msg


def field_msg(stamp, field):
    msg = MagneticField()
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(int(stamp), 1_000_000_000)
    msg.header.frame_id = 'imu_link'
    f = msg.magnetic_field
    f.x, f.y, f.z = map(float, field)
    return msg


@pytest.mark.parametrize('settings', [
    {},
    {'orientation_covariance_mode': 'fixed', 'orientation_stddev': 0.2,
     'remove_gravity_vector': True, 'frame_id': 'odom', 'publish_debug_topics': True},
], ids=['defaults', 'fixed-gravity-debug'])
def test_serialized_and_typed_paths_publish_the_same_bytes(ros_context, spinner, settings,
                                                          monkeypatch):
    debug = settings.get('publish_debug_topics', False)
    if debug:
        # /tf through a broadcaster of each node's own, whether tf2_ros imports or not.
        monkeypatch.setattr(imu_filter_node, 'transform_broadcaster',
                            lambda node: (KeptTransforms(), None))
    nodes = [spinner.add(ImuFilterNode(context=ros_context, namespace=p,
                                       parameter_overrides=overrides(
                                           serialized_io=p == 'serialized', publish_tf=debug,
                                           **settings)))
             for p in PATHS]
    feeder = spinner.add(Feeder(ros_context))
    if debug:
        feeder.keep_debug_topics()
    spinner.spin_until(lambda: all(n._publish_imu and n._publish_estimate for n in nodes)
                       and all(p.get_subscription_count() == 1 for p in feeder.imu + feeder.mag)
                       and all(feeder.count_publishers(f'/{p}/attitude_estimate') == 1
                               for p in PATHS)
                       and (not debug or all(
                           publisher.get_subscription_count() == 1 for n in nodes
                           for publisher in (n.rpy_filtered_publisher, n.rpy_raw_publisher,
                                             n.steady_state_publisher))),
                       10.0, 'the endpoints')
    data = load(TRIALS[0])
    gyr, acc, mag = data['gyr'], data['acc'], fields_tesla(data)
    times = stamps(SAMPLES, float(data['rate']))
    for k in range(SAMPLES):
        lockstep(spinner, nodes, feeder.imu, lambda: imu_msg(times[k], gyr[k], acc[k]),
                 'increment')
        if k % MAG_EVERY == 0:
            lockstep(spinner, nodes, feeder.mag, lambda: field_msg(times[k], mag[k]),
                     'measurement')
    spinner.spin_until(lambda: all(len(feeder.outputs[p]) == SAMPLES - 1
                                   and len(feeder.estimates[p]) == SAMPLES - 1
                                   for p in PATHS), 10.0, 'every output')
    serialized, typed = nodes
    assert np.array_equal(np.array(serialized.state), np.array(typed.state))
    for store in (feeder.outputs, feeder.estimates):
        assert store['serialized'].keys() == store['typed'].keys()
        for stamp, raw in store['typed'].items():
            mine = store['serialized'][stamp]
            assert len(mine) == len(raw)
            assert meaningful(mine) == meaningful(raw), stamp
    # The covariance went out as configured: σ² fixed, or the estimate's own.
    last = feeder.outputs['serialized'][times[-1]]
    layout = cdr.imu_layout(last)
    covariance = np.frombuffer(last[layout[1] + 32:layout[1] + 104])
    if settings:
        v = 0.2 ** 2
        assert list(covariance) == [v, 0, 0, 0, v, 0, 0, 0, v]
    else:
        assert covariance[0] > 0 and covariance[0] != 0.0025
    assert serialized.undecodable == {'increment': 0, 'measurement': 0}
    if debug:
        # The debug topics and /tf: the same messages, in the same order.
        spinner.spin_until(lambda: all(len(kept) == SAMPLES - 1 for p in PATHS
                                       for kept in feeder.debug[p].values()),
                           10.0, 'every debug output')
        for topic in ('imu/rpy/filtered', 'imu/rpy/raw'):
            mine, theirs = ([header_part(raw) for raw in feeder.debug[p][topic]]
                            for p in PATHS)
            assert [stamp for stamp, _ in theirs] == list(times[1:]), topic
            assert mine == theirs, topic
        # std_msgs/Bool: its one byte after the encapsulation (padding may follow).
        mine, theirs = ([raw[4] for raw in feeder.debug[p]['imu/steady_state']]
                        for p in PATHS)
        assert mine == theirs
        mine, theirs = (n.tf_broadcaster.sent for n in nodes)
        assert len(theirs) == SAMPLES - 1 and mine == theirs


def test_undecodable_bytes_are_counted_not_crashing(ros_context, spinner):
    node = spinner.add(ImuFilterNode(context=ros_context))
    node.imu_data_raw_serialized_callback(b'\x00\x01\x00\x00' + bytes(8))
    node.imu_data_raw_serialized_callback(b'\x07\x07' + bytes(400))
    node.imu_mag_serialized_callback(cdr.encode_field(1, 'imu', (1e-5, 0.0, 0.0))[:40])
    assert node.undecodable == {'increment': 2, 'measurement': 1}
    assert node.pairer.received['increment'] == 0
    status = node.status()
    values = {kv.key: kv.value for kv in status.values}
    assert values['undecodable_increment'] == '2'
    assert values['undecodable_measurement'] == '1'
    assert status.level == DiagnosticStatus.WARN
    assert 'undecodable_increment (+2)' in status.message
