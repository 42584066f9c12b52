"""
What imu_filter_madgwick publishes beside the orientation, without ROS.

A node that replaces imu_filter_madgwick keeps its extra outputs: the roll,
pitch and yaw of the debug topics (``imu/rpy/filtered``, ``imu/rpy/raw``),
the specific force without gravity (``remove_gravity_vector``) and the
orientation as a TF transform (``publish_tf``, ``reverse_tf``,
``fixed_frame``). Each is a small function of the estimate here; the node
only puts the numbers into messages. Quaternions scalar first
``(w, x, y, z)``, sensor → world; angles in rad, accelerations in m/s².
"""

import math

from ext_observer.core.ahrs.frames import initial_attitude
from ext_observer.core.constants import STANDARD_GRAVITY
from ext_observer.core.ahrs.ahrs_observer import WORLD_FRAMES
from ext_observer.core.quaternion import multiply_floats

__all__ = ['IDENTITY_MOUNTING', 'STANDARD_GRAVITY', 'field_mounting', 'gravity_in_sensor',
           'heading_factor', 'mounting_matrix', 'quaternion_from_rpy', 'quaternion_matrix',
           'raw_attitude', 'rpy_from_quaternion', 'transform_from_estimate', 'without_gravity']

# imu_filter_madgwick's gravity (its getGravity's default), m/s².


def rpy_from_quaternion(q):
    """
    Return roll, pitch and yaw (rad) of an attitude, as tf2's ``getRPY`` gives them.

    Fixed axes x, y, z (``q = R_z(yaw) R_y(pitch) R_x(roll)``), pitch in
    [−π/2, π/2]; at gimbal lock (pitch ±π/2) yaw is 0 and roll takes the
    whole turn, as tf2's ``Matrix3x3::getEulerYPR`` (its first solution).
    ``q`` need not be normalized.

    Returns
    -------
    roll, pitch, yaw : float

    """
    w, x, y, z = q
    s = 2.0 / (w * w + x * x + y * y + z * z)
    m20 = s * (x * z - w * y)
    m21 = s * (y * z + w * x)
    m22 = 1.0 - s * (x * x + y * y)
    if abs(m20) >= 1.0:
        delta = math.atan2(m21, m22)
        return delta, (0.5 * math.pi if m20 < 0.0 else -0.5 * math.pi), 0.0
    m10 = s * (x * y + w * z)
    m00 = 1.0 - s * (y * y + z * z)
    return math.atan2(m21, m22), -math.asin(m20), math.atan2(m10, m00)


def gravity_in_sensor(q_enu, gravity=STANDARD_GRAVITY):
    """
    Return what the accelerometer reads of gravity at rest, in the sensor frame.

    ``R(q)ᵀ (0, 0, g)``: the world's up axis (ENU) seen from the sensor,
    scaled by ``gravity`` (the specific force points up at rest).

    Parameters
    ----------
    q_enu : sequence of 4 float
        Sensor → ENU, any norm.

    Returns
    -------
    tuple of 3 float

    """
    w, x, y, z = q_enu
    s = gravity * 2.0 / (w * w + x * x + y * y + z * z)
    # The third row of the rotation matrix: the sensor's axes' up components.
    return (s * (x * z - w * y), s * (y * z + w * x),
            gravity - s * (x * x + y * y))


def without_gravity(acc, q_enu, gravity=STANDARD_GRAVITY):
    """Return the specific force ``acc`` minus gravity's part, sensor frame (m/s²)."""
    gx, gy, gz = gravity_in_sensor(q_enu, gravity)
    return acc[0] - gx, acc[1] - gy, acc[2] - gz


def raw_attitude(acc, field=None, frame=None):
    """
    Return the attitude of one sample alone (gravity, and the field's heading).

    imu_filter_madgwick's ``imu/rpy/raw``: no filter, the accelerometer and
    the magnetometer of the moment. Without a field the heading is that of
    the smallest rotation taking the accelerometer's axis to the vertical.

    Parameters
    ----------
    acc : sequence of 3 float
        Specific force, m/s², sensor frame.
    field : sequence of 3 float, optional
        Magnetic field (any unit), sensor frame.
    frame : sequence of 4 float, optional
        Left factor from ENU to the published world frame
        (:func:`heading_factor`); None: ENU.

    Returns
    -------
    tuple of 4 float
        Unit quaternion, sensor → world.

    """
    q = initial_attitude(acc, field, use_mag=field is not None)
    return q if frame is None else multiply_floats(frame, q)


def transform_from_estimate(q, fixed_frame, imu_frame, reverse=False):
    """
    Return the TF transform of an attitude, as imu_filter_madgwick broadcasts it.

    Parameters
    ----------
    q : sequence of 4 float
        Sensor → world, any norm (normalized here).
    fixed_frame, imu_frame : str
        The world's frame name (``fixed_frame``) and the sample's
        ``frame_id``.
    reverse : bool
        ``reverse_tf``: the transform from the sensor to the fixed frame
        (the inverse rotation) instead.

    Returns
    -------
    parent, child : str
        ``header.frame_id`` and ``child_frame_id``.
    rotation : tuple of 4 float
        Unit quaternion ``(w, x, y, z)``: the child's axes in the parent's;
        the translation is zero.

    """
    w, x, y, z = q
    n = math.sqrt(w * w + x * x + y * y + z * z)
    w, x, y, z = w / n, x / n, y / n, z / n
    if reverse:
        return imu_frame, fixed_frame, (w, -x, -y, -z)
    return fixed_frame, imu_frame, (w, x, y, z)


# A mounting quaternion (w, x, y, z) that leaves the frame as it is.
IDENTITY_MOUNTING = (1.0, 0.0, 0.0, 0.0)


def quaternion_matrix(q):
    """
    Return the rotation matrix R (9 floats, row-major) of a mounting quaternion ``(w, x, y, z)``.

    The one definition for the mountings given as quaternions
    (``mag_mounting``: ``m_imu = R m_mag``; ``velocity_mounting``:
    ``v_imu = Rᵀ v``). ``q`` is taken as it is, not normalized: the
    parameters' checks hold its norm to 1 within their tolerance.
    """
    w, x, y, z = (float(c) for c in q)
    return (1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
            2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
            2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y))


def quaternion_from_rpy(rpy):
    """
    Return the unit quaternion (w, x, y, z) of roll, pitch, yaw (rad, fixed axes).

    tf2's ``setRPY``: the rotation of :func:`mounting_matrix`
    (``q_z(yaw) ⊗ q_y(pitch) ⊗ q_x(roll)``).
    """
    roll, pitch, yaw = (0.5 * float(v) for v in rpy)
    cr, sr = math.cos(roll), math.sin(roll)
    cp, sp = math.cos(pitch), math.sin(pitch)
    cy, sy = math.cos(yaw), math.sin(yaw)
    return (cr * cp * cy + sr * sp * sy, sr * cp * cy - cr * sp * sy,
            cr * sp * cy + sr * cp * sy, cr * cp * sy - sr * sp * cy)


def mounting_matrix(rpy):
    """
    Return R = R_z(yaw) R_y(pitch) R_x(roll) (9 floats, row-major), or None for (0, 0, 0).

    ``m_imu = R m_mag`` for a magnetometer frame at ``rpy`` (rad, fixed axes)
    in the IMU's, as tf2's ``setRPY`` and static_transform_publisher give it:
    the deprecated ``mag_frame_rpy``'s matrix, built from the angles so that
    its estimates stay those it gave (through :func:`quaternion_from_rpy`
    and :func:`quaternion_matrix` it is the same rotation within rounding).
    """
    roll, pitch, yaw = (float(v) for v in rpy)
    if roll == pitch == yaw == 0.0:
        return None
    cr, sr = math.cos(roll), math.sin(roll)
    cp, sp = math.cos(pitch), math.sin(pitch)
    cy, sy = math.cos(yaw), math.sin(yaw)
    return (cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr,
            sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr,
            -sp, cp * sr, cp * cr)


def field_mounting(settings):
    """
    Return the magnetometer's mounting R (``m_imu = R m_mag``, 9 floats); None: the IMU's frame.

    From ``mag_mounting`` (a unit quaternion w, x, y, z); from the
    deprecated ``mag_frame_rpy`` when that is the one set (the parameters'
    checks refuse both), its matrix built from the angles as before. Missing
    settings are their defaults.
    """
    rpy = settings.get('mag_frame_rpy', (0.0, 0.0, 0.0))
    if any(float(v) != 0.0 for v in rpy):
        return mounting_matrix(rpy)
    q = tuple(float(c) for c in settings.get('mag_mounting', IDENTITY_MOUNTING))
    return None if q == IDENTITY_MOUNTING else quaternion_matrix(q)


def _about_z(angle):
    return (math.cos(0.5 * angle), 0.0, 0.0, math.sin(0.5 * angle))


def heading_factor(world_frame, declination=0.0, yaw_offset=0.0):
    """
    Return the left factor from the core's ENU estimate to the published one.

    ``R_z(yaw_offset) ⊗ C ⊗ R_up(−declination)``, with ``C`` the frame's
    factor of :data:`~ext_observer.core.ahrs.ahrs_observer.WORLD_FRAMES`.

    Returns
    -------
    factor : tuple of 4 float or None
        None when it is the identity (ENU, no offsets): nothing to multiply.

    """
    if world_frame == 'enu' and declination == 0.0 and yaw_offset == 0.0:
        return None
    factor = multiply_floats(WORLD_FRAMES[world_frame], _about_z(-declination))
    return multiply_floats(_about_z(yaw_offset), factor)
