"""
The few ROS 2 messages the bag command reads and writes, as CDR bytes; no ROS.

A message in a rosbag2 bag is its CDR serialization: a 4-byte encapsulation
header (``00 00`` big endian, ``00 01`` little endian: XCDR1), then the
fields, each aligned to its size relative to the byte after that header.
The messages here all start with a ``std_msgs/Header`` (``int32 sec``,
``uint32 nanosec``, ``string frame_id``: a length with the terminating NUL,
the bytes, the NUL) followed by float64 fields, so their layout is fixed
once the frame_id's length is known:

==========================================  ===================================
``sensor_msgs/msg/Imu``                     orientation (x, y, z, w), its
                                            covariance (9), angular_velocity (3),
                                            its covariance, linear_acceleration
                                            (3), its covariance
``sensor_msgs/msg/MagneticField``           magnetic_field (3), its covariance
``geometry_msgs/msg/QuaternionStamped``     quaternion (x, y, z, w)
``geometry_msgs/msg/PoseStamped``           position (3), orientation (x, y, z, w)
==========================================  ===================================

:mod:`struct` reads and writes them in about a microsecond, where a general
deserializer takes ten or more; ``rosbags``' deserializer checks the first
message of each topic (:mod:`ext_observer.recordings.bag`). Quaternions are returned
and taken scalar first, ``(w, x, y, z)``, as everywhere in this package.
Stamps are integer nanoseconds.
"""

import struct
import sys

__all__ = ['FIELD_TYPE', 'IMU_TYPE', 'ImuData', 'QUATERNION_TYPE', 'REFERENCE_TYPES',
           'QuaternionStamped', 'Undecodable', 'decode_field', 'decode_imu',
           'decode_orientation', 'encode_field', 'encode_imu', 'encode_quaternion_stamped',
           'frame_id', 'imu_layout']

SECOND = 1_000_000_000
IMU_TYPE = 'sensor_msgs/msg/Imu'
FIELD_TYPE = 'sensor_msgs/msg/MagneticField'
QUATERNION_TYPE = 'geometry_msgs/msg/QuaternionStamped'
# Orientation messages: the offset of the quaternion after the header, bytes.
REFERENCE_TYPES = {IMU_TYPE: 0, QUATERNION_TYPE: 0, 'geometry_msgs/msg/PoseStamped': 24}

_LITTLE = b'\x00\x01\x00\x00'
_HEAD = (struct.Struct('>iII'), struct.Struct('<iII'))  # sec, nanosec, len(frame_id)
_VECTOR = (struct.Struct('>3d'), struct.Struct('<3d'))
_QUATERNION = (struct.Struct('>4d'), struct.Struct('<4d'))
_STAMP = struct.Struct('<iI')
_NATIVE = 1 if sys.byteorder == 'little' else 0  # this machine's byte order, as ``order``
_NINE = struct.Struct('=9d')  # in this machine's byte order
# angular_velocity, its covariance (skipped), linear_acceleration.
_RATES = (struct.Struct('>3d72x3d'), struct.Struct('<3d72x3d'))
# sensor_msgs/Imu after the header, bytes.
_IMU_COVARIANCE = 32
_IMU_GYR = 104
_IMU_ACC = 200
_IMU_SIZE = 296
_FIELD_SIZE = 96


class Undecodable(ValueError):
    """A message whose bytes are not the expected layout."""


def _header(raw):
    """Return (byte order 0 or 1, stamp ns, offset of the fields after the header)."""
    if len(raw) < 16 or raw[0] or raw[1] > 1:
        raise Undecodable(f'CDR encapsulation {bytes(raw[:2]).hex()} (XCDR1 expected)')
    order = raw[1]
    sec, nanosec, length = _HEAD[order].unpack_from(raw, 4)
    return order, sec * SECOND + nanosec, 4 + ((12 + length + 7) & -8)


def frame_id(raw):
    """Return the ``header.frame_id`` of a message that starts with a Header."""
    order, _, _ = _header(raw)
    length = _HEAD[order].unpack_from(raw, 4)[2]
    if length < 1 or len(raw) < 16 + length:
        raise Undecodable(f'frame_id of {length} bytes in a message of {len(raw)}')
    return bytes(raw[16:15 + length]).decode('utf-8', 'replace')


def imu_layout(raw):
    """
    Return what the bag command needs of a ``sensor_msgs/Imu``.

    Returns
    -------
    order : int
        0 big endian, 1 little endian.
    body : int
        Offset of the orientation.
    stamp : int
    gyr, acc : tuple of 3 float
        rad/s, m/s².

    Raises
    ------
    Undecodable

    """
    order, stamp, body = _header(raw)
    if len(raw) < body + _IMU_SIZE:
        raise Undecodable(f'{len(raw)} bytes, {body + _IMU_SIZE} expected')
    rates = _RATES[order].unpack_from(raw, body + _IMU_GYR)
    return order, body, stamp, rates[:3], rates[3:]


def decode_imu(raw):
    """Return ``(stamp, angular velocity, acceleration)`` of a ``sensor_msgs/Imu``."""
    return imu_layout(raw)[2:]


def decode_field(raw):
    """Return ``(stamp, field)`` of a ``sensor_msgs/MagneticField``."""
    order, stamp, body = _header(raw)
    if len(raw) < body + _FIELD_SIZE:
        raise Undecodable(f'{len(raw)} bytes, {body + _FIELD_SIZE} expected')
    return stamp, _VECTOR[order].unpack_from(raw, body)


def decode_orientation(raw, msgtype):
    """
    Return ``(stamp, (w, x, y, z))`` of a message of :data:`REFERENCE_TYPES`.

    The orientation is None for a ``sensor_msgs/Imu`` that has none
    (``orientation_covariance[0] = −1``).
    """
    order, stamp, body = _header(raw)
    if len(raw) < body + REFERENCE_TYPES[msgtype] + 32:
        raise Undecodable(f'{len(raw)} bytes, too short for {msgtype}')
    x, y, z, w = _QUATERNION[order].unpack_from(raw, body + REFERENCE_TYPES[msgtype])
    if msgtype == IMU_TYPE and _VECTOR[order].unpack_from(raw, body + _IMU_COVARIANCE)[0] == -1:
        return stamp, None
    return stamp, (w, x, y, z)


def _frame_bytes(frame_id):
    """A Header's frame_id and the padding to the 8-byte aligned fields."""
    text = frame_id.encode() + b'\x00'
    return struct.pack('<I', len(text)) + text + bytes(-(12 + len(text)) % 8)


def _stamp_bytes(stamp):
    return _STAMP.pack(*divmod(stamp, SECOND))


def _diagonal(variance):
    return (variance, 0.0, 0.0, 0.0, variance, 0.0, 0.0, 0.0, variance)


def encode_imu(stamp, frame_id, gyr, acc, orientation=None, orientation_variance=0.0):
    """
    Return a ``sensor_msgs/Imu`` as CDR (little endian).

    ``orientation`` ``(w, x, y, z)``; None gives a raw IMU's message: the
    identity with ``orientation_covariance[0] = −1`` (no orientation).
    """
    if orientation is None:
        orientation, covariance = (1.0, 0.0, 0.0, 0.0), (-1.0,) + (0.0,) * 8
    else:
        covariance = _diagonal(orientation_variance)
    w, x, y, z = orientation
    return b''.join((_LITTLE, _stamp_bytes(stamp), _frame_bytes(frame_id),
                     struct.pack('<4d9d3d9d3d9d', x, y, z, w, *covariance, *gyr,
                                 *(0.0,) * 9, *acc, *(0.0,) * 9)))


def encode_field(stamp, frame_id, field):
    """Return a ``sensor_msgs/MagneticField`` (T) as CDR (little endian)."""
    return b''.join((_LITTLE, _stamp_bytes(stamp), _frame_bytes(frame_id),
                     struct.pack('<3d9d', *field, *(0.0,) * 9)))


class QuaternionStamped:
    """``geometry_msgs/QuaternionStamped`` messages of one frame_id, as CDR."""

    def __init__(self, frame_id):
        frame = _frame_bytes(frame_id)
        self._frame = frame
        self._pack = struct.Struct(f'<4siI{len(frame)}s4d').pack

    def __call__(self, stamp, w, x, y, z):
        """Return the message of ``(w, x, y, z)`` stamped ``stamp``."""
        sec, nanosec = divmod(stamp, SECOND)
        return self._pack(_LITTLE, sec, nanosec, self._frame, x, y, z, w)


def encode_quaternion_stamped(stamp, frame_id, q):
    """Return a ``geometry_msgs/QuaternionStamped`` of ``q`` ``(w, x, y, z)`` as CDR."""
    return QuaternionStamped(frame_id)(stamp, *q)


class ImuData:
    """
    ``imu/data`` as ``imu_filter_node`` fills it, from the input sample's bytes.

    The sample goes out as it came (header, rates, accelerations and their
    covariances, in its byte order) with the orientation set to the
    normalized estimate and ``orientation_covariance`` to σ² on the
    diagonal, or to the estimate's own covariance when one is given.
    """

    def __init__(self, orientation_stddev):
        covariance = _diagonal(orientation_stddev ** 2)
        self._covariance = tuple(struct.pack(order + '9d', *covariance) for order in '><')
        self._nine = tuple(struct.Struct(order + '9d').pack for order in '><')

    def __call__(self, raw, order, body, w, x, y, z, covariance=None):
        """
        Return the message; ``order`` and ``body`` from :func:`imu_layout`.

        ``covariance``: 9 floats, row-major, rad²; None: ``orientation_stddev``'s.
        """
        return self.filled(raw, order, body, w, x, y, z,
                           None if covariance is None else _NINE.pack(*covariance))

    def filled(self, raw, order, body, w, x, y, z, covariance=None, acc=None):
        """
        The same with ``covariance`` as an estimator writes it.

        ``covariance``: 9 float64 in this machine's byte order, as any buffer
        (a numpy array, bytes): its memory goes out as it is where the sample
        is in this machine's order too, else swapped to the sample's. ``acc``:
        the linear acceleration to write instead of the sample's (m/s²).
        """
        if covariance is None:
            covariance = self._covariance[order]
        elif order != _NATIVE:
            covariance = self._nine[order](*_NINE.unpack(covariance))
        n = (w * w + x * x + y * y + z * z) ** 0.5
        parts = [raw[:body], _QUATERNION[order].pack(x / n, y / n, z / n, w / n), covariance]
        if acc is None:
            parts.append(raw[body + _IMU_GYR:])
        else:
            parts += (raw[body + _IMU_GYR:body + _IMU_ACC], _VECTOR[order].pack(*acc),
                      raw[body + _IMU_ACC + 24:])
        return b''.join(parts)
