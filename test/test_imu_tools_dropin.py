"""
imu_tools' own files and habits, unchanged, start imu_filter_node and do what they say.

The params files of imu_filter_madgwick and imu_complementary_filter
(``test/data/imu_tools/``, copied unchanged) start the installed node over
DDS; each option they name does here what it does there, or is named in
the start-up warning with what replaces it (docs/raw_imu.md).
"""

import math
import os
import time

from diagnostic_msgs.msg import DiagnosticArray
import numpy as np
import pytest
from sensor_msgs.msg import Imu

from ext_observer.nodes.conversions import nanoseconds_from_stamp
from ext_observer.nodes.imu_filter_parameters import (covariance_estimated,
                                                      IMU_FILTER_PARAMETERS)
from ros_helpers import installed, SECOND
from test_raw_imu import Driver

DATA = os.path.join(os.path.dirname(os.path.abspath(__file__)), 'data', 'imu_tools')
MADGWICK_FILE = os.path.join(DATA, 'imu_filter.yaml')
COMPLEMENTARY_FILE = os.path.join(DATA, 'filter_config.yaml')
START = 1_700_000_000 * SECOND


def defaults(**changes):
    values = {spec.name: spec.default for spec in IMU_FILTER_PARAMETERS}
    values.update(changes)
    return values


def start_process(ros_processes, spinner, ros_context, argv, topic='imu/data'):
    """Start the installed node; return it, a Driver and the imu/data messages by stamp."""
    process = ros_processes([installed('imu_filter_node'), '--ros-args'] + argv)
    driver = spinner.add(Driver(ros_context))
    spinner.spin_until(lambda: driver.imu_publisher.get_subscription_count() == 1
                       and process.process.poll() is None, 20.0, 'imu_filter_node')
    filtered = {}
    driver.create_subscription(Imu, topic, lambda msg: filtered.__setitem__(
        nanoseconds_from_stamp(msg.header.stamp), msg), 1000)
    statuses = []
    driver.create_subscription(DiagnosticArray, '/diagnostics',
                               lambda msg: statuses.extend(msg.status), 10)
    # The process's own status reached this node: discovery is done both ways.
    spinner.spin_until(lambda: driver.count_publishers(topic) == 1
                       and any(st.name == 'imu_filter: inputs' for st in statuses), 20.0,
                       'imu/data and the status of the process')
    return process, driver, filtered


def send_each(spinner, driver, filtered, samples, field=(2e-5, 1e-5, -4e-5)):
    """Publish each sample once the estimate of the one before has come back."""
    for k, (stamp, gyr, acc) in enumerate(samples):
        if field is not None:
            driver.send_field(stamp, field)
        driver.send_imu(stamp, gyr, acc)
        if k:
            spinner.spin_until(lambda: stamp in filtered, 10.0, f'estimate {k}')


def test_orientation_stddev_zero_means_not_given():
    # imu_tools' default, 0.0, is "not given": the estimate's own covariance.
    assert covariance_estimated(defaults(orientation_stddev=0.0))
    assert covariance_estimated(defaults())
    # A positive value other than ours is a user's number: fixed.
    assert not covariance_estimated(defaults(orientation_stddev=0.2))
    # Asked for outright, either way.
    assert not covariance_estimated(defaults(orientation_stddev=0.0,
                                             orientation_covariance_mode='fixed'))
    assert covariance_estimated(defaults(orientation_stddev=0.2,
                                         orientation_covariance_mode='estimate'))


def test_imu_filter_madgwick_own_file_starts_with_a_covariance_and_names_publish_tf(
        ros_processes, ros_context, spinner):
    with open(MADGWICK_FILE) as f:
        text = f.read()
    assert 'orientation_stddev: 0.0' in text and 'publish_tf: true' in text
    process, driver, filtered = start_process(
        ros_processes, spinner, ros_context, ['--params-file', MADGWICK_FILE])
    samples = [(START + k * SECOND // 100, (0.0, 0.0, 0.2), (0.5, -0.3, 9.7))
               for k in range(60)]
    send_each(spinner, driver, filtered, samples)
    assert len(filtered) == len(samples) - 1
    assert process.process.poll() is None, process.output
    # The estimate's own covariance: positive on the diagonal, never zeros.
    for msg in filtered.values():
        c = np.reshape(msg.orientation_covariance, (3, 3))
        assert np.all(np.diag(c) > 0.0) and np.all(np.isfinite(c)), c
    out = process.output
    assert "orientation_covariance of imu/data: the estimate's own" in out, out
    assert 'orientation_stddev 0.0 means not given' in out, out
    assert 'publish_tf' in out, out


# constant_dt: every sample, in the order it comes ---------------------------------

def test_constant_dt_pairs_every_sample_in_arrival_order():
    from ext_observer.pipeline.pairing import BACKWARD_JUMP, StepPairer

    ms = 1_000_000
    pairer = StepPairer(timeout=0, max_dt=50 * ms, constant_dt=0.01, arrival_order=True)
    stamps = [2 * SECOND, 2 * SECOND, 2 * SECOND + 20 * ms, 2 * SECOND + 10 * ms,
              2 * SECOND - 500 * ms, 2 * SECOND + 900 * ms]
    steps = []
    for k, stamp in enumerate(stamps):
        outcome, released = pairer.add_sample(stamp, (0.0, 0.0, 1.0), (0.0, 0.0, 9.8))
        assert outcome is None, (k, outcome)
        steps += released
    # Repeated, older and far stamps: each closes the interval of the one
    # before, Δt = constant_dt (max_dt is the stamps' rule, not used).
    assert [s.end for s in steps] == stamps[1:]
    assert all(s.increment == pytest.approx((0.0, 0.0, 0.01)) for s in steps)
    assert pairer.processed['increment'] == len(stamps) - 1
    assert not any(pairer.drops.values())
    # A driver that never stamps: all zero, all used.
    unstamped = StepPairer(timeout=0, constant_dt=0.01, arrival_order=True)
    assert [len(unstamped.add_sample(0, (0.0, 0.0, 1.0), (0.0, 0.0, 9.8))[1])
            for _ in range(4)] == [0, 1, 1, 1]
    # Only non-finite values are dropped; a jump back by more than
    # backward_jump still starts a new time line.
    assert pairer.add_sample(3 * SECOND, (math.nan, 0.0, 0.0), (0.0, 0.0, 9.8))[0] == (
        'non_finite_increment')
    assert pairer.add_sample(3 * SECOND, (0.0, 0.0, 1.0), (0.0, 0.0, math.inf))[0] == (
        'non_finite_acceleration')
    assert pairer.add_sample(SECOND // 2, (0.0, 0.0, 1.0), (0.0, 0.0, 9.8))[0] == BACKWARD_JUMP
    assert pairer.accounted('increment') == pairer.received['increment']
    # Without arrival_order the same stamps are dropped as before.
    strict = StepPairer(timeout=0, max_dt=50 * ms, constant_dt=0.01)
    outcomes = [strict.add_sample(t, (0.0, 0.0, 1.0), (0.0, 0.0, 9.8))[0] for t in stamps]
    assert outcomes[1] == 'duplicate_increment' and outcomes[3] == 'stale_increment'


def burst_samples(count, rate=1.0):
    """Samples stamped in pairs (a driver that stamps in bursts), turning about z."""
    return [(START + (k // 2) * 2 * SECOND // 100, (0.0, 0.0, rate), (0.0, 0.0, 9.81))
            for k in range(count)]


def yaw_of(q):
    w, x, y, z = q
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def test_constant_dt_integrates_every_sample_of_same_stamp_pairs_over_dds(
        ros_context, spinner):
    from ext_observer.nodes.imu_filter_node import ImuFilterNode
    from ros_helpers import overrides
    from test_raw_imu import connect

    node = spinner.add(ImuFilterNode(
        node_name='bursts', context=ros_context,
        parameter_overrides=overrides(constant_dt=0.01, use_mag=False,
                                      **{'ahrs.tau_bias': 0.0})))
    driver = spinner.add(Driver(ros_context))
    received = []
    driver.create_subscription(Imu, 'imu/data', received.append, 1000)
    connect(spinner, driver, node)
    samples = burst_samples(200)
    for k, (stamp, gyr, acc) in enumerate(samples):
        driver.send_imu(stamp, gyr, acc)
        spinner.spin_until(lambda: len(received) == k + 1, 10.0, f'estimate {k}')
    assert len(received) == 200
    assert not any(node.drops.values()), node.drops
    # 199 intervals of 0.01 s at 1 rad/s: 1.99 rad about z (the first sample
    # initializes the estimate).
    first = received[0].orientation
    last = received[-1].orientation
    turn = yaw_of((last.w, last.x, last.y, last.z)) - yaw_of((first.w, first.x, first.y,
                                                              first.z))
    assert turn == pytest.approx(1.99, abs=0.005), turn


def test_arrival_order_add_sample_is_add_angular_velocity_then_pop_ready():
    # The one-call path and the general one agree in arrival order too, on
    # test_pairing's arbitrary streams (duplicates, stale, jumps, gaps).
    from hypothesis import given, settings

    from ext_observer.pipeline.pairing import StepPairer
    from test_pairing import _pairer_state, assert_accounted, sample_operations

    @settings(max_examples=300, deadline=None)
    @given(sample_operations)
    def check(ops):
        options = dict(timeout=0, depth=4, backward_jump=SECOND,
                       forward_gap=SECOND // 2, max_dt=SECOND // 25, constant_dt=0.004,
                       max_increment=3.0, arrival_order=True)
        fast, general = StepPairer(**options), StepPairer(**options)
        stamp = 2 * SECOND
        for kind, delta, value, acc in ops:
            if delta is not None:
                stamp += delta
            if kind == 'sample':
                outcome, steps = fast.add_sample(stamp, value, acc)
                assert outcome == general.add_angular_velocity(stamp, value, 0, acc)
                assert list(steps) == general.pop_ready(0)
                assert outcome in (None, 'backward_jump', 'non_finite_increment',
                                   'non_finite_acceleration', 'zero_acceleration',
                                   'increment_too_large'), outcome
            elif kind == 'field':
                assert fast.add_field(stamp, value) == general.add_field(stamp, value)
            else:
                assert fast.restart() == general.restart()
            assert _pairer_state(fast) == _pairer_state(general)
        assert_accounted(fast)

    check()


# Debug topics and gravity removal: the ROS-free part -----------------------------

def random_unit(rng):
    q = rng.normal(size=4)
    return tuple(float(v) for v in q / np.linalg.norm(q))


def test_rpy_is_tf2s_first_solution_and_rebuilds_the_attitude():
    from ext_observer.core.quaternion import multiply_floats
    from ext_observer.pipeline.imu_tools import rpy_from_quaternion

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
    from ext_observer.pipeline.imu_tools import gravity_in_sensor, STANDARD_GRAVITY
    from ext_observer.pipeline.imu_tools import without_gravity

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
    from ext_observer.pipeline.imu_tools import transform_from_estimate

    q = (0.5, 0.5, -0.5, 0.5)
    assert transform_from_estimate((1.0, 1.0, -1.0, 1.0), 'odom', 'imu_link') == (
        'odom', 'imu_link', q)
    parent, child, r = transform_from_estimate(q, 'odom', 'imu_link', reverse=True)
    assert (parent, child, r) == ('imu_link', 'odom', (0.5, -0.5, 0.5, -0.5))
