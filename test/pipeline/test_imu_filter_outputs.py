"""
imu_tools' conventions, without ROS (``pipeline/imu_filter_outputs.py``).

The roll, pitch and yaw of ``imu/rpy/filtered`` (tf2's first solution, any
norm, the gimbal lock), gravity removed in the sensor frame, and the TF
imu_filter_madgwick publishes (and its reverse). The node's debug topics
and TF through DDS: test_imu_tools_dropin.py.
"""

import math

import numpy as np
import pytest


def random_unit(rng):
    q = rng.normal(size=4)
    return tuple(float(v) for v in q / np.linalg.norm(q))


def test_rpy_is_tf2s_first_solution_and_rebuilds_the_attitude():
    from ext_observer.core.quaternion import multiply_floats
    from ext_observer.pipeline.imu_filter_outputs import rpy_from_quaternion

    def about(axis, angle):
        q = [math.cos(0.5 * angle), 0.0, 0.0, 0.0]
        q[1 + axis] = math.sin(0.5 * angle)
        return tuple(q)

    rng = np.random.default_rng(30)
    for _ in range(200):
        q = random_unit(rng)
        roll, pitch, yaw = rpy_from_quaternion(tuple(3.0 * v for v in q))  # any norm
        assert -math.pi / 2 <= pitch <= math.pi / 2
        rebuilt = multiply_floats(about(2, yaw), multiply_floats(about(1, pitch),
                                                                 about(0, roll)))
        assert min(np.abs(np.subtract(rebuilt, q)).max(),
                   np.abs(np.add(rebuilt, q)).max()) < 1e-12
    assert rpy_from_quaternion((1.0, 0.0, 0.0, 0.0)) == (0.0, -0.0, 0.0)
    # Gimbal lock: yaw 0, roll takes the turn (tf2's rule).
    locked = multiply_floats(about(2, 0.4), about(1, math.pi / 2))
    roll, pitch, yaw = rpy_from_quaternion(locked)
    assert (pitch, yaw) == (pytest.approx(math.pi / 2), 0.0)


def test_gravity_removed_in_the_sensor_frame():
    from ext_observer.pipeline.imu_filter_outputs import gravity_in_sensor, STANDARD_GRAVITY
    from ext_observer.pipeline.imu_filter_outputs import without_gravity

    rng = np.random.default_rng(31)
    for _ in range(100):
        q = random_unit(rng)
        w, x, y, z = q
        # R(q)ᵀ up, from the full rotation matrix.
        r = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                      [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                      [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])
        expected = r.T @ np.array([0.0, 0.0, STANDARD_GRAVITY])
        assert np.allclose(gravity_in_sensor(tuple(2.0 * v for v in q)), expected,
                           atol=1e-12)
        assert np.allclose(without_gravity(tuple(expected + [0.1, 0.2, 0.3]), q),
                           [0.1, 0.2, 0.3], atol=1e-12)


def test_transform_is_imu_filter_madgwicks_and_its_reverse():
    from ext_observer.pipeline.imu_filter_outputs import transform_from_estimate

    q = (0.5, 0.5, -0.5, 0.5)
    assert transform_from_estimate((1.0, 1.0, -1.0, 1.0), 'odom', 'imu_link') == (
        'odom', 'imu_link', q)
    parent, child, r = transform_from_estimate(q, 'odom', 'imu_link', reverse=True)
    assert (parent, child, r) == ('imu_link', 'odom', (0.5, -0.5, 0.5, -0.5))
