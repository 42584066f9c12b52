"""
The velocity aid through imu_filter_node: odometry over real DDS.

A level vehicle turning at 0.46 g (15 m/s, 0.3 rad/s), its IMU and its
wheel odometry published in lockstep to two nodes, one with
``velocity_source`` ``odom`` and one without: the first stays level, the
second tilts towards the centripetal acceleration. Then the odometry stops
(WARN, unaided) and bad velocities come (dropped, counted, WARN).
"""

import math
import os
import time

from diagnostic_msgs.msg import DiagnosticStatus
from geometry_msgs.msg import QuaternionStamped, TwistStamped
from nav_msgs.msg import Odometry
import numpy as np
import pytest
from sensor_msgs.msg import Imu

from broad_replay import START
from conftest import REPO
from ext_observer.nodes.conversions import quaternion_from_msg, stamp_from_nanoseconds
from ext_observer.nodes.imu_filter_node import ImuFilterNode
from ext_observer.nodes.velocity_topic import VELOCITY_DROP_REASONS, VELOCITY_TOPICS, VelocityTopic
from imu_driver import BEST_EFFORT, connect, Driver
from ros_helpers import overrides, SECOND, values_of

RATE = 100
SPEED = 15.0        # m/s at cruise
YAW_RATE = 0.3      # rad/s: 4.5 m/s², 0.46 g centripetal
ACCEL = 3.0         # m/s² from rest to cruise
ODOM_EVERY = 5      # 20 Hz odometry
REST_S, SECONDS = 1.0, 20.0
NOISE = (0.002, 0.05)   # gyro rad/s, accelerometer m/s²
AIDED = '/aided'


def drive(seconds=SECONDS, seed=0):
    """(stamp, gyr, acc, body velocity) per IMU sample of a level vehicle in a left turn."""
    rng = np.random.default_rng(seed)
    out = []
    for k in range(int(seconds * RATE)):
        t = k / RATE
        moving = max(0.0, t - REST_S)
        speed = min(SPEED, ACCEL * moving)
        accel = ACCEL if 0.0 < ACCEL * moving < SPEED else 0.0
        yaw_rate = YAW_RATE if t >= REST_S else 0.0
        # Level: the specific force is (v̇, v ω, g) in the body (x forward, z up).
        gyr = np.array([0.0, 0.0, yaw_rate]) + NOISE[0] * rng.standard_normal(3)
        acc = np.array([accel, speed * yaw_rate, 9.81]) + NOISE[1] * rng.standard_normal(3)
        out.append((START + k * SECOND // RATE, tuple(gyr), tuple(acc), (speed, 0.0, 0.0)))
    return out


class OdometryDriver(Driver):
    """The raw IMU driver with odometry (odom) and a twist (velocity); the aided node's outputs."""

    def __init__(self, context):
        super().__init__(context)
        # Reliable, as most odometry is: the sensor-data subscription takes it too.
        self.odom_publisher = self.create_publisher(Odometry, 'odom', 100)
        self.twist_publisher = self.create_publisher(TwistStamped, 'velocity', BEST_EFFORT)
        self.aided_estimates = {}
        self.create_subscription(QuaternionStamped, f'{AIDED}/attitude_estimate',
                                 self._keep(self.aided_estimates), 1000)
        self.create_subscription(Imu, f'{AIDED}/imu/data', lambda msg: None, 10)

    def send_odom(self, stamp, v):
        msg = Odometry()
        msg.header.stamp = stamp_from_nanoseconds(stamp)
        msg.header.frame_id = 'odom'
        msg.child_frame_id = 'base_link'
        linear = msg.twist.twist.linear
        linear.x, linear.y, linear.z = (float(c) for c in v)
        self.odom_publisher.publish(msg)

    def send_twist(self, stamp, v):
        msg = TwistStamped()
        msg.header.stamp = stamp_from_nanoseconds(stamp)
        msg.header.frame_id = 'base_link'
        linear = msg.twist.linear
        linear.x, linear.y, linear.z = (float(c) for c in v)
        self.twist_publisher.publish(msg)


def wait(spinner, condition, what, seconds=60.0):
    deadline = time.monotonic() + seconds
    while not condition():
        spinner.executor.spin_once(timeout_sec=0.01)
        assert time.monotonic() < deadline, what


def replay(spinner, driver, nodes, data, send=None):
    """Each velocity (every ODOM_EVERY-th sample), then its sample, once every node took the last."""
    aided = [n for n in nodes if n.velocity_input.subscription is not None]
    for k, (stamp, gyr, acc, v) in enumerate(data):
        if send is not None and k % ODOM_EVERY == 0:
            counts = [n.velocity_input.received for n in aided]
            send(stamp, v)
            wait(spinner, lambda: all(n.velocity_input.received > c
                                      for n, c in zip(aided, counts)), f'velocity {k}')
        counts = [n.pairer.received['increment'] for n in nodes]
        driver.send_imu(stamp, gyr, acc)
        wait(spinner, lambda: all(n.pairer.received['increment'] > c
                                  for n, c in zip(nodes, counts)), f'sample {k}')


def inclination_errors_deg(estimates, stamps):
    """Angle between the estimate's up and the level body's z, degrees, per stamp."""
    out = []
    for t in stamps:
        w, x, y, z = quaternion_from_msg(estimates[t].quaternion)
        # R[2, 2] of the sensor → ENU rotation: the world's up on the body's z.
        r22 = (w * w - x * x - y * y + z * z) / (w * w + x * x + y * y + z * z)
        out.append(math.degrees(math.acos(min(1.0, max(-1.0, r22)))))
    return np.array(out)


def start(spinner, ros_context, source='odom', frame='base_link'):
    """
    A node aided by ``source`` (its ``velocity_frame`` ``frame``) and one without, and their driver.

    The aided one is in the namespace AIDED, its inputs remapped to the
    global topics (remapping works), its outputs its own.
    """
    topic = VELOCITY_TOPICS[source]
    aided = spinner.add(ImuFilterNode(
        node_name='aided', namespace=AIDED, context=ros_context,
        parameter_overrides=overrides(use_mag=False, velocity_source=source,
                                      velocity_frame=frame),
        cli_args=['--ros-args', '-r', 'imu/data_raw:=/imu/data_raw',
                  '-r', f'{topic}:=/{topic}']))
    plain = spinner.add(ImuFilterNode(node_name='plain', context=ros_context,
                                      parameter_overrides=overrides(use_mag=False)))
    driver = spinner.add(OdometryDriver(ros_context))
    connect(spinner, driver, aided, plain)
    publisher = driver.odom_publisher if source == 'odom' else driver.twist_publisher
    wait(spinner, lambda: publisher.get_subscription_count() == 1, 'the velocity matched')
    return aided, plain, driver


def test_odometry_keeps_a_turning_vehicle_level_and_its_loss_falls_back_with_a_warn(
        ros_context, spinner):
    aided, plain, driver = start(spinner, ros_context)
    assert aided.velocity_input.subscription.topic_name == '/odom'
    assert plain.velocity_input.subscription is None
    data = drive()
    replay(spinner, driver, [aided, plain], data, send=driver.send_odom)
    # The last 5 s of the turn (at cruise since 6 s).
    late = [t for t, *_ in data[-5 * RATE:]]
    wait(spinner, lambda: all(t in driver.estimates and t in driver.aided_estimates
                              for t in late), 'the estimates')
    with_odom = inclination_errors_deg(driver.aided_estimates, late)
    without = inclination_errors_deg(driver.estimates, late)
    rms = [np.sqrt(np.mean(errors ** 2)) for errors in (with_odom, without)]
    print(f'inclination error over the last 5 s, RMS: with odom {rms[0]:.3f}°, '
          f'without {rms[1]:.3f}°')
    assert with_odom.max() < 1.0, with_odom.max()
    assert without.min() > 3.0, without.min()
    status = aided.status()
    values = values_of(status)
    assert status.level == DiagnosticStatus.OK, status.message
    assert (values['velocity_source'], values['velocity_used']) == ('odom', 'true')
    assert float(values['velocity_age_s']) <= ODOM_EVERY / RATE + 1e-9
    assert int(values['velocities_used']) == int(values['velocities_received']) \
        == len(data) // ODOM_EVERY
    assert values_of(plain.status())['velocity_used'] == 'false'
    # The odometry stops: past velocity_timeout (0.5 s) the node runs unaided and WARNs.
    t0 = data[-1][0]
    more = [(t0 + (k + 1) * SECOND // RATE, gyr, acc, v)
            for k, (_, gyr, acc, v) in enumerate(drive()[-60:])]
    replay(spinner, driver, [aided, plain], more)
    status = aided.status()
    values = values_of(status)
    assert status.level == DiagnosticStatus.WARN
    assert 'no fresh velocity on /odom' in status.message, status.message
    assert values['velocity_used'] == 'false' and float(values['velocity_age_s']) > 0.5
    assert aided.observer.velocity_used is False


def test_bad_velocities_are_dropped_counted_and_warned(ros_context, spinner):
    aided, _, driver = start(spinner, ros_context, source='twist')
    assert aided.velocity_input.subscription.topic_name == '/velocity'
    data = drive(seconds=2.0)
    replay(spinner, driver, [aided], data, send=driver.send_twist)
    aided.status()
    last = data[-1][0]
    bad = [(last - SECOND, (15.0, 0.0, 0.0)),               # 1 s before the IMU: stale
           (last + SECOND // 1000, (math.nan, 0.0, 0.0)),   # not finite
           (data[-ODOM_EVERY - 1][0], (15.0, 0.0, 0.0))]     # before the last taken
    for stamp, v in bad:
        count = aided.velocity_input.received
        driver.send_twist(stamp, v)
        wait(spinner, lambda: aided.velocity_input.received > count, 'the bad velocity')
    status = aided.status()
    values = values_of(status)
    for reason in VELOCITY_DROP_REASONS:
        assert int(values[f'dropped_velocity_{reason}']) == 1, reason
        assert f'velocity_{reason} (+1)' in status.message, status.message
    assert status.level == DiagnosticStatus.WARN
    # Never in an estimate: the estimator's velocity is still the last good one.
    assert int(values['velocities_used']) == len(data) // ODOM_EVERY
    assert all(math.isfinite(c) for c in aided.state)


def test_odometry_in_another_frame_than_expected_warns_and_is_counted(ros_context,
                                                                     spinner):
    # velocity_frame empty: the velocity is expected in the IMU's frame
    # (imu_link); the odometry's child_frame_id is base_link.
    aided, _, driver = start(spinner, ros_context, frame='')
    data = drive(seconds=1.0)
    replay(spinner, driver, [aided], data, send=driver.send_odom)
    status = aided.status()
    values = values_of(status)
    sent = len(data) // ODOM_EVERY
    assert values['velocity_frame_mismatch'] == 'true'
    # The first came before any IMU sample: no frame to compare it with yet.
    assert int(values['velocity_frame_mismatches']) == sent - 1
    assert status.level == DiagnosticStatus.WARN
    assert "in frame 'base_link' (child_frame_id), expected 'imu_link'" in status.message
    # Still used: only the frame's name is in doubt.
    assert int(values['velocities_used']) == sent
    # Odometry in the IMU's frame: no longer a mismatch (the count stays).
    stamp = data[-1][0] + SECOND // RATE
    count = aided.velocity_input.received
    msg = Odometry()
    msg.header.stamp = stamp_from_nanoseconds(stamp)
    msg.child_frame_id = 'imu_link'
    msg.twist.twist.linear.x = SPEED
    driver.odom_publisher.publish(msg)
    wait(spinner, lambda: aided.velocity_input.received > count, 'the odometry in imu_link')
    values = values_of(aided.status())
    assert values['velocity_frame_mismatch'] == 'false'
    assert int(values['velocity_frame_mismatches']) == sent - 1


def test_velocity_keys_are_documented_and_a_wrong_source_is_refused(ros_context):
    from ext_observer.nodes.node_common import ParameterError

    with pytest.raises(ParameterError, match='velocity_source'):
        ImuFilterNode(node_name='wrong', context=ros_context,
                      parameter_overrides=overrides(velocity_source='wheels'))
    node = ImuFilterNode(node_name='documented', context=ros_context)
    try:
        keys = [key for key, _ in VelocityTopic(node, {'velocity_source': 'none'}).key_values()]
    finally:
        node.destroy_node()
    keys += [f'dropped_velocity_{reason}' for reason in VELOCITY_DROP_REASONS]
    with open(os.path.join(REPO, 'docs', 'diagnostics.md'), encoding='utf-8') as page:
        text = page.read()
    assert [key for key in keys if f'`{key}`' not in text] == []
