"""
Conversions between ROS messages and the core's plain values.

This is the one place where ROS meets the core's conventions:

- ``geometry_msgs/Quaternion`` stores ``(x, y, z, w)`` by field name; the core
  is scalar first, ``(w, x, y, z)``. Every quaternion that crosses the
  boundary goes through :func:`quaternion_from_msg` or
  :func:`msg_from_quaternion`.
- ``geometry_msgs/Vector3`` is ``(x, y, z)`` in both worlds (an increment
  ``θ_k`` in rad).
- A ``builtin_interfaces/Time`` stamp is an integer number of nanoseconds
  here (``sec * 10**9 + nanosec``), so stamps compare and pair exactly.

The functions from messages copy the values as floats (NaN, infinities and
subnormals pass unchanged) and never raise on a message: validation belongs
to the core (``ext_observer.core.validation``), applied by the nodes.
"""

from builtin_interfaces.msg import Time
from geometry_msgs.msg import Quaternion, QuaternionStamped, Vector3, Vector3Stamped

__all__ = [
    'STAMP_MAX',
    'msg_from_quaternion',
    'msg_from_vector',
    'nanoseconds_from_stamp',
    'quaternion_from_msg',
    'quaternion_stamped',
    'stamp_from_nanoseconds',
    'vector_from_msg',
    'vector_stamped',
]

NANOSECONDS_PER_SECOND = 1_000_000_000

# The latest stamp a builtin_interfaces/Time holds (sec is an int32), ns.
STAMP_MAX = (2 ** 31 - 1) * NANOSECONDS_PER_SECOND + NANOSECONDS_PER_SECOND - 1


def quaternion_from_msg(msg):
    """
    Return a ``geometry_msgs/Quaternion`` as a scalar-first tuple.

    Parameters
    ----------
    msg : geometry_msgs.msg.Quaternion

    Returns
    -------
    q : tuple of 4 float
        ``(w, x, y, z)``.

    """
    return (float(msg.w), float(msg.x), float(msg.y), float(msg.z))


def msg_from_quaternion(q):
    """
    Return a scalar-first quaternion as a ``geometry_msgs/Quaternion``.

    Parameters
    ----------
    q : sequence of 4 float or ndarray, shape (4,)
        ``(w, x, y, z)``.

    Returns
    -------
    msg : geometry_msgs.msg.Quaternion

    Raises
    ------
    ValueError
        If ``q`` does not have 4 elements.

    """
    w, x, y, z = _floats(q, 4, 'quaternion')
    return Quaternion(x=x, y=y, z=z, w=w)


def vector_from_msg(msg):
    """
    Return a ``geometry_msgs/Vector3`` as a tuple ``(x, y, z)``.

    Parameters
    ----------
    msg : geometry_msgs.msg.Vector3

    Returns
    -------
    v : tuple of 3 float

    """
    return (float(msg.x), float(msg.y), float(msg.z))


def msg_from_vector(v):
    """
    Return a 3-vector as a ``geometry_msgs/Vector3``.

    Parameters
    ----------
    v : sequence of 3 float or ndarray, shape (3,)

    Returns
    -------
    msg : geometry_msgs.msg.Vector3

    Raises
    ------
    ValueError
        If ``v`` does not have 3 elements.

    """
    x, y, z = _floats(v, 3, 'vector')
    return Vector3(x=x, y=y, z=z)


def nanoseconds_from_stamp(stamp):
    """
    Return a ``builtin_interfaces/Time`` as integer nanoseconds.

    Parameters
    ----------
    stamp : builtin_interfaces.msg.Time

    Returns
    -------
    nanoseconds : int
        Negative for a negative ``sec`` (a ROS time never is; the nodes drop
        such stamps with the zero ones).

    """
    return int(stamp.sec) * NANOSECONDS_PER_SECOND + int(stamp.nanosec)


def stamp_from_nanoseconds(nanoseconds):
    """
    Return integer nanoseconds as a ``builtin_interfaces/Time``.

    Parameters
    ----------
    nanoseconds : int
        In ``[0, STAMP_MAX]``.

    Returns
    -------
    stamp : builtin_interfaces.msg.Time

    Raises
    ------
    ValueError
        Outside that range.

    """
    nanoseconds = int(nanoseconds)
    if not 0 <= nanoseconds <= STAMP_MAX:
        raise ValueError(f'a stamp must lie in [0, {STAMP_MAX}] ns, got {nanoseconds}')
    sec, nanosec = divmod(nanoseconds, NANOSECONDS_PER_SECOND)
    return Time(sec=sec, nanosec=nanosec)


def quaternion_stamped(q, nanoseconds, frame_id):
    """
    Return a ``geometry_msgs/QuaternionStamped``.

    Parameters
    ----------
    q : sequence of 4 float
        ``(w, x, y, z)``.
    nanoseconds : int
        The stamp.
    frame_id : str

    Returns
    -------
    msg : geometry_msgs.msg.QuaternionStamped

    """
    msg = QuaternionStamped()
    msg.header.stamp = stamp_from_nanoseconds(nanoseconds)
    msg.header.frame_id = frame_id
    msg.quaternion = msg_from_quaternion(q)
    return msg


def vector_stamped(v, nanoseconds, frame_id):
    """
    Return a ``geometry_msgs/Vector3Stamped``.

    Parameters
    ----------
    v : sequence of 3 float
    nanoseconds : int
        The stamp.
    frame_id : str

    Returns
    -------
    msg : geometry_msgs.msg.Vector3Stamped

    """
    msg = Vector3Stamped()
    msg.header.stamp = stamp_from_nanoseconds(nanoseconds)
    msg.header.frame_id = frame_id
    msg.vector = msg_from_vector(v)
    return msg


def _floats(values, length, name):
    values = tuple(float(v) for v in values)
    if len(values) != length:
        raise ValueError(f'a {name} needs {length} elements, got {len(values)}')
    return values
