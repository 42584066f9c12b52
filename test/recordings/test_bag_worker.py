"""
The bag command's reading side (``recordings/bag_worker.py``) message by
message: the first message of each topic checked against ``rosbags``' own
deserializer (its layout, its stamp, its values), a velocity read from
TwistStamped and Odometry. (The two processes end to end:
``recordings/test_bag.py``.)
"""

from types import SimpleNamespace

import numpy as np
import pytest

from ext_observer.recordings import cdr
from ext_observer.recordings.bag_worker import (_check_first, _velocity, ODOMETRY_TYPE,
                                                TWIST_TYPE)
from recording_excerpt import TYPESTORE

STAMP = 12 * 1_000_000_000 + 345
GYR, ACC = (0.1, -0.2, 0.3), (0.0, 0.5, 9.8)


def test_the_first_message_agrees_with_rosbags_or_is_refused_naming_the_topic():
    imu = SimpleNamespace(topic='/imu/data_raw', msgtype=cdr.IMU_TYPE)
    raw = cdr.encode_imu(STAMP, 'imu', GYR, ACC)
    _check_first(TYPESTORE, imu, 'imu', raw, STAMP, GYR + ACC)
    with pytest.raises(ValueError, match='/imu/data_raw: its messages do not have the layout'):
        _check_first(TYPESTORE, imu, 'imu', raw, STAMP + 1, GYR + ACC)
    with pytest.raises(ValueError, match='do not have the layout'):
        _check_first(TYPESTORE, imu, 'imu', raw, STAMP, ACC + GYR)
    with pytest.raises(ValueError, match='/imu/data_raw: its first message does not deserialize'):
        _check_first(TYPESTORE, imu, 'imu', raw[:40], STAMP, GYR + ACC)
    reference = SimpleNamespace(topic='/truth', msgtype=cdr.QUATERNION_TYPE)
    q = (0.5, 0.5, -0.5, 0.5)
    raw = cdr.encode_quaternion_stamped(STAMP, 'map', q)
    _check_first(TYPESTORE, reference, 'reference', raw, STAMP, q)
    with pytest.raises(ValueError, match='do not have the layout'):
        _check_first(TYPESTORE, reference, 'reference', raw, STAMP, q[::-1])


@pytest.mark.parametrize('msgtype', [TWIST_TYPE, ODOMETRY_TYPE])
def test_a_velocity_is_its_linear_twist_and_its_stamp(msgtype):
    cls = TYPESTORE.types[msgtype]
    header = TYPESTORE.types['std_msgs/msg/Header'](
        stamp=TYPESTORE.types['builtin_interfaces/msg/Time'](sec=12, nanosec=345),
        frame_id='odom')
    vector3 = TYPESTORE.types['geometry_msgs/msg/Vector3']
    twist = TYPESTORE.types['geometry_msgs/msg/Twist'](
        linear=vector3(x=1.0, y=-2.0, z=0.5), angular=vector3(x=0.0, y=0.0, z=0.0))
    msg = cls(header=header, twist=twist) if msgtype == TWIST_TYPE else _odometry(header, twist)
    raw = bytes(TYPESTORE.serialize_cdr(msg, msgtype))
    assert _velocity(TYPESTORE, raw, msgtype) == (STAMP, (1.0, -2.0, 0.5))
    with pytest.raises(cdr.Undecodable):
        _velocity(TYPESTORE, raw[:20], msgtype)


def _odometry(header, twist):
    """A nav_msgs/Odometry at rest but for ``twist``."""
    types = TYPESTORE.types
    point = types['geometry_msgs/msg/Point'](x=0.0, y=0.0, z=0.0)
    quaternion = types['geometry_msgs/msg/Quaternion'](x=0.0, y=0.0, z=0.0, w=1.0)
    pose = types['geometry_msgs/msg/PoseWithCovariance'](
        pose=types['geometry_msgs/msg/Pose'](position=point, orientation=quaternion),
        covariance=np.zeros(36))
    return types[ODOMETRY_TYPE](
        header=header, child_frame_id='base_link', pose=pose,
        twist=types['geometry_msgs/msg/TwistWithCovariance'](
            twist=twist, covariance=np.zeros(36)))
