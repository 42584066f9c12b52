"""
The velocity aid: the body's own acceleration removed from the specific force.

On a vehicle the accelerometer measures ``f = a_kin − g`` (its reaction, up at
rest), with the kinematic acceleration of the IMU in its own, rotating frame
``a_kin = dv/dt + ω × v``. In a long turn ``ω × v`` never averages out, and an
estimator that takes ``f`` for gravity tilts towards it. Given the body's
velocity ``v`` (IMU frame, m/s, e.g. wheel odometry), the accelerometer step
uses ``f − a_kin`` instead. A velocity older than ``par.velocity_timeout`` (or none)
leaves the specific force as measured: today's estimator, to the bit.

Written in the part of Python that numba compiles, as
:mod:`~ext_observer.core.ahrs.ahrs_kernel` (which calls it).
"""

from .record import Group

VEL = Group('vel', "The velocity aid: the body's velocity at the IMU, IMU frame", [
    ('v', 'm/s', 'the latest velocity', 3),
    ('dv', 'm/s²', 'its derivative over the latest interval', 3),
    ('n', '', 'velocities taken since the last gap (2: a derivative)'),
    ('age', 's', 'of IMU steps since the latest velocity'),
    ('acc', 'm/s²', 'the kinematic acceleration of this step', 3),
    ('used', '1', "this step's specific force had it removed"),
])

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
    if s.vel.n > 0.0 and 0.0 < dt <= s.par.velocity_timeout:
        s.vel.dv[0] = (vx - s.vel.v[0]) / dt
        s.vel.dv[1] = (vy - s.vel.v[1]) / dt
        s.vel.dv[2] = (vz - s.vel.v[2]) / dt
        s.vel.n = 2.0
    else:
        s.vel.n = 1.0
    s.vel.v[0] = vx
    s.vel.v[1] = vy
    s.vel.v[2] = vz
    s.vel.age = 0.0


def velocity_step(s, gx, gy, gz, dt):
    """
    Age the velocity by an IMU step of ``dt``; 1.0 when it is used, its ``a_kin`` kept.

    ``ω`` is the sample's rate less the bias estimate; ``a_kin`` is kept in
    ``S_VEL_ACC`` for the accelerometer step (:func:`velocity_removed`). A
    body that moves is not at rest: its bias is not learned from its rate.
    """
    if s.vel.n == 0.0:
        return 0.0  # never a velocity: the state as without the aid
    s.vel.age += dt
    if s.vel.n < 2.0 or not s.vel.age <= s.par.velocity_timeout:
        s.vel.used = 0.0
        return 0.0
    wx, wy, wz = gx - s.bias.rate[0], gy - s.bias.rate[1], gz - s.bias.rate[2]
    vx, vy, vz = s.vel.v[0], s.vel.v[1], s.vel.v[2]
    if vx * vx + vy * vy + vz * vz > MOVING_SPEED * MOVING_SPEED:
        s.rest.acc_still = 0.0  # read by this sample's rest detection (clip_and_rest)
    s.vel.acc[0] = s.vel.dv[0] + wy * vz - wz * vy
    s.vel.acc[1] = s.vel.dv[1] + wz * vx - wx * vz
    s.vel.acc[2] = s.vel.dv[2] + wx * vy - wy * vx
    s.vel.used = 1.0
    return 1.0


def velocity_removed(s, ax, ay, az):
    """The specific force less this step's kinematic acceleration, where it is used."""
    if s.vel.used == 0.0:
        return ax, ay, az
    return ax - s.vel.acc[0], ay - s.vel.acc[1], az - s.vel.acc[2]
