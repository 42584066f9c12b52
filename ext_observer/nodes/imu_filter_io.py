"""
The ``imu_filter`` node's two message paths: rclpy's message objects, or CDR bytes.

With ``serialized_io`` false the node's callbacks get message objects
(:class:`TypedPath`), else the messages' CDR bytes (:class:`SerializedPath`,
read and written by :mod:`ext_observer.recordings.cdr`;
docs/nodes.md#serialized-inputs-and-outputs). The node runs one body per
input for both (:class:`~ext_observer.nodes.imu_filter_node.ImuFilterNode`'s
``_imu_sample`` and ``_field_sample``); what differs is here. Both paths
have the same calls:

- ``imu(sample, estimated)``: an IMU sample decoded, ``(stamp, gyr, acc,
  covariance, out_stamp, order, body)``: the stamp (ns), the rates (rad/s)
  and accelerations (m/s²), where the estimate's covariance goes (None
  where not ``estimated``: the fixed one), the stamp as the outputs carry
  it, and the bytes' layout (:func:`~ext_observer.recordings.cdr.imu_layout`;
  None for a message);
- ``field(sample)``: a magnetic field decoded, ``(stamp, field)`` (ns, T);
- ``frame(sample)``, ``header(sample, stamp)`` (of the debug topics and
  ``/tf``), ``estimate(out_stamp, w, x, y, z)`` (``attitude_estimate``) and
  ``imu_data(sample, order, body, w, x, y, z, covariance, acc)``
  (``imu/data``): what goes out;
- ``configure(frame, ...)``: the settings those depend on.

Bytes that do not decode raise :class:`~ext_observer.recordings.cdr.Undecodable`.
"""

import numpy as np
from std_msgs.msg import Header

from ext_observer.nodes.conversions import nanoseconds_from_stamp, vector_from_msg
from ext_observer.recordings.cdr import (decode_field, frame_id, ImuData, imu_layout,
                                         QuaternionStamped as EstimateBytes)

__all__ = ['SerializedPath', 'TypedPath']


class TypedPath:
    """
    The typed path: rclpy's message objects.

    ``imu/data`` is the input message itself, filled in place: the message is
    the node's once its callback has run.

    Parameters
    ----------
    estimate : geometry_msgs.msg.QuaternionStamped
        The ``attitude_estimate`` message, reused for every sample.

    """

    def __init__(self, estimate):
        self._estimate = estimate
        # Its parts, read once: this runs for every sample.
        self._estimate_header, self._estimate_quaternion = estimate.header, estimate.quaternion
        self._fixed_covariance = None

    def configure(self, frame, fixed_covariance):
        """Take the estimate's frame_id and the fixed covariance (9 floats)."""
        self._estimate_header.frame_id = frame
        self._fixed_covariance = fixed_covariance

    @staticmethod
    def imu(msg, estimated):
        """
        A ``sensor_msgs/Imu``'s stamp, rates and accelerations (see the module).

        The estimated covariance is written straight into the message that
        goes out (its own float64 array): no copy.
        """
        # nanoseconds_from_stamp and vector_from_msg, written out: this runs
        # for every sample (the fields of a message are Python ints and floats).
        header_stamp = msg.header.stamp
        v, a = msg.angular_velocity, msg.linear_acceleration
        return (header_stamp.sec * 1_000_000_000 + header_stamp.nanosec,
                (v.x, v.y, v.z), (a.x, a.y, a.z),
                msg.orientation_covariance if estimated else None, header_stamp, None, None)

    @staticmethod
    def field(msg):
        """A ``sensor_msgs/MagneticField``'s ``(stamp, field)``: ns, T."""
        return nanoseconds_from_stamp(msg.header.stamp), vector_from_msg(msg.magnetic_field)

    @staticmethod
    def frame(msg):
        """The message's ``header.frame_id``."""
        return msg.header.frame_id

    @staticmethod
    def header(msg, stamp):
        """The header of the debug topics and ``/tf``: the message's own."""
        return msg.header

    def estimate(self, stamp, w, x, y, z):
        """``attitude_estimate``; ``stamp`` the message's own (``builtin_interfaces/Time``)."""
        self._estimate_header.stamp = stamp
        q = self._estimate_quaternion
        q.w, q.x, q.y, q.z = w, x, y, z
        return self._estimate

    def imu_data(self, msg, order, body, w, x, y, z, covariance, acc):
        """
        ``imu/data``: the message with the normalized orientation written in.

        ``covariance`` None: the fixed one written in (else the estimate has
        written its own there); ``acc``, the acceleration to write, or None.
        """
        n = (w * w + x * x + y * y + z * z) ** 0.5
        q = msg.orientation
        q.w, q.x, q.y, q.z = w / n, x / n, y / n, z / n
        if covariance is None:
            # In place: the message's own float64 array (cheaper than a new one).
            msg.orientation_covariance[:] = self._fixed_covariance
        if acc is not None:
            a = msg.linear_acceleration
            a.x, a.y, a.z = acc
        return msg


class SerializedPath:
    """
    The serialized path: CDR bytes in, CDR bytes out.

    Its ``field``, ``frame``, ``estimate`` and ``imu_data`` are
    :mod:`ext_observer.recordings.cdr`'s readers and writers themselves (no
    call of its own on the way).
    """

    field = staticmethod(decode_field)
    frame = staticmethod(frame_id)

    def __init__(self):
        self.estimate = self.imu_data = None
        # Where the estimate's covariance goes before it is written into the bytes.
        self._covariance = np.zeros(9)

    def configure(self, frame, orientation_stddev):
        """Take the estimate's frame_id and the fixed covariance's σ (rad)."""
        self.estimate = EstimateBytes(frame)
        self.imu_data = ImuData(orientation_stddev).filled

    def imu(self, raw, estimated):
        """A ``sensor_msgs/Imu``'s stamp, rates and accelerations from its bytes (the module's)."""
        order, body, stamp, gyr, acc = imu_layout(raw)
        return stamp, gyr, acc, self._covariance if estimated else None, stamp, order, body

    @staticmethod
    def header(raw, stamp):
        """The header of the debug topics and ``/tf``, made from the bytes."""
        header = Header(frame_id=frame_id(raw))
        header.stamp.sec, header.stamp.nanosec = divmod(stamp, 1_000_000_000)
        return header
