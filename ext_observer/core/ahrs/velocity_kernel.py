"""
The velocity aid: the body's own acceleration removed from the specific force.

On a vehicle the accelerometer measures ``f = a_kin − g`` (its reaction, up at
rest), with the kinematic acceleration of the IMU in its own, rotating frame
``a_kin = dv/dt + ω × v``. In a long turn ``ω × v`` never averages out, and an
estimator that takes ``f`` for gravity tilts towards it. Given the body's
velocity ``v`` (IMU frame, m/s, e.g. wheel odometry), the accelerometer step
uses ``f − a_kin`` instead. A velocity older than ``P_VEL_TIMEOUT`` (or none)
leaves the specific force as measured: today's estimator, to the bit.

Written in the part of Python that numba compiles, as
:mod:`~ext_observer.core.ahrs.ahrs_kernel` (which calls it).
"""

from .ahrs_layout import (P_VEL_TIMEOUT, S_ACC_STILL, S_BIAS, S_VEL, S_VEL_ACC, S_VEL_AGE, S_VEL_DV,
                          S_VEL_N, S_VEL_USED)

# s: a velocity older than this is not used (wheel odometry comes at 10-100 Hz).
VELOCITY_TIMEOUT = 0.5
# m/s: a body faster than this is not at rest, however still its gyro (a
# steady turn below rest_gyr would otherwise teach the bias its yaw rate).
MOVING_SPEED = 0.1


def velocity_sample(s, vx, vy, vz, dt):
    """
    A velocity (m/s, IMU frame) ``dt`` s after the previous one (``dt`` ≤ 0: none before).

    Its derivative is the difference over its own interval, held until the
    next velocity: matched to the velocity's rate, whatever the IMU's. A
    velocity after a gap longer than the timeout starts the derivative over.
    """
    if s[S_VEL_N] > 0.0 and 0.0 < dt <= s[P_VEL_TIMEOUT]:
        s[S_VEL_DV] = (vx - s[S_VEL]) / dt
        s[S_VEL_DV + 1] = (vy - s[S_VEL + 1]) / dt
        s[S_VEL_DV + 2] = (vz - s[S_VEL + 2]) / dt
        s[S_VEL_N] = 2.0
    else:
        s[S_VEL_N] = 1.0
    s[S_VEL] = vx
    s[S_VEL + 1] = vy
    s[S_VEL + 2] = vz
    s[S_VEL_AGE] = 0.0


def velocity_step(s, gx, gy, gz, dt):
    """
    Age the velocity by an IMU step of ``dt``; 1.0 when it is used, its ``a_kin`` kept.

    ``ω`` is the sample's rate less the bias estimate; ``a_kin`` is kept in
    ``S_VEL_ACC`` for the accelerometer step (:func:`velocity_removed`). A
    body that moves is not at rest: its bias is not learned from its rate.
    """
    if s[S_VEL_N] == 0.0:
        return 0.0  # never a velocity: the state as without the aid
    s[S_VEL_AGE] += dt
    if s[S_VEL_N] < 2.0 or not s[S_VEL_AGE] <= s[P_VEL_TIMEOUT]:
        s[S_VEL_USED] = 0.0
        return 0.0
    wx, wy, wz = gx - s[S_BIAS], gy - s[S_BIAS + 1], gz - s[S_BIAS + 2]
    vx, vy, vz = s[S_VEL], s[S_VEL + 1], s[S_VEL + 2]
    if vx * vx + vy * vy + vz * vz > MOVING_SPEED * MOVING_SPEED:
        s[S_ACC_STILL] = 0.0  # read by this sample's rest detection (clip_and_rest)
    s[S_VEL_ACC] = s[S_VEL_DV] + wy * vz - wz * vy
    s[S_VEL_ACC + 1] = s[S_VEL_DV + 1] + wz * vx - wx * vz
    s[S_VEL_ACC + 2] = s[S_VEL_DV + 2] + wx * vy - wy * vx
    s[S_VEL_USED] = 1.0
    return 1.0


def velocity_removed(s, ax, ay, az):
    """The specific force less this step's kinematic acceleration, where it is used."""
    if s[S_VEL_USED] == 0.0:
        return ax, ay, az
    return ax - s[S_VEL_ACC], ay - s[S_VEL_ACC + 1], az - s[S_VEL_ACC + 2]
