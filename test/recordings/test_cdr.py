"""Our CDR codecs (``recordings/cdr.py``) against ``rosbags``' own, message by message."""

import numpy as np
import pytest

from ext_observer.recordings import cdr
from recording_excerpt import TYPESTORE, header_stamp


def test_codecs_agree_with_rosbags():
    rng = np.random.default_rng(1)
    for frame in ('', 'a', 'imu_link', 'seven77', 'eight888'):
        stamp = int(rng.integers(1, 2 ** 31)) * 1_000_000_000 + int(rng.integers(0, 10 ** 9))
        gyr, acc, field = (tuple(rng.normal(size=3)) for _ in range(3))
        msg = TYPESTORE.deserialize_cdr(cdr.encode_imu(stamp, frame, gyr, acc), cdr.IMU_TYPE)
        assert (header_stamp(msg), msg.header.frame_id, msg.orientation_covariance[0]) == (
            stamp, frame, -1.0)
        assert (msg.angular_velocity.y, msg.linear_acceleration.z) == (gyr[1], acc[2])
        msg = TYPESTORE.deserialize_cdr(cdr.encode_field(stamp, frame, field), cdr.FIELD_TYPE)
        assert msg.magnetic_field.x == field[0]
        q = tuple(rng.normal(size=4))
        msg = TYPESTORE.deserialize_cdr(cdr.encode_quaternion_stamped(stamp, frame, q),
                                        cdr.QUATERNION_TYPE)
        assert (msg.quaternion.w, msg.quaternion.z) == (q[0], q[3])
        for little in (True, False):
            raw = bytes(TYPESTORE.serialize_cdr(
                TYPESTORE.deserialize_cdr(cdr.encode_imu(stamp, frame, gyr, acc), cdr.IMU_TYPE),
                cdr.IMU_TYPE, little_endian=little))
            assert cdr.decode_imu(raw) == (stamp, gyr, acc)
            order, body = cdr.imu_layout(raw)[:2]
            filled = TYPESTORE.deserialize_cdr(cdr.ImuData(0.1)(raw, order, body, *q),
                                               cdr.IMU_TYPE)
            n = np.linalg.norm(q)
            assert filled.orientation.x == pytest.approx(q[1] / n, abs=1e-15)
            assert filled.orientation_covariance[8] == pytest.approx(0.01)
            assert filled.linear_acceleration.y == acc[1]
            assert cdr.decode_orientation(raw, cdr.IMU_TYPE) == (stamp, None)
    with pytest.raises(cdr.Undecodable):
        cdr.decode_imu(cdr.encode_imu(1, 'imu', (0, 0, 0), (0, 0, 9.8))[:200])


def test_imu_data_writes_the_estimators_covariance_in_the_samples_byte_order():
    rng = np.random.default_rng(2)
    covariance = rng.normal(size=9)     # float64, this machine's order, as an estimator writes it
    q, acc = tuple(rng.normal(size=4)), tuple(rng.normal(size=3))
    raw = cdr.encode_imu(1_000_000_123, 'imu_link', (0.1, 0.2, 0.3), (0.0, 0.0, 9.8))
    for little in (True, False):
        sample = bytes(TYPESTORE.serialize_cdr(TYPESTORE.deserialize_cdr(raw, cdr.IMU_TYPE),
                                               cdr.IMU_TYPE, little_endian=little))
        order, body = cdr.imu_layout(sample)[:2]
        imu_data = cdr.ImuData(0.1)
        filled = imu_data.filled(sample, order, body, *q, covariance, acc)
        msg = TYPESTORE.deserialize_cdr(filled, cdr.IMU_TYPE)
        assert msg.orientation_covariance.tobytes() == covariance.tobytes()
        assert (msg.linear_acceleration.x, msg.linear_acceleration.z) == (acc[0], acc[2])
        assert msg.angular_velocity.y == 0.2
        # The same as 9 floats given to the message's writer.
        assert imu_data.filled(sample, order, body, *q, covariance) == imu_data(
            sample, order, body, *q, list(covariance))
