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
from ext_observer.pipeline.imu_filter_parameters import IMU_FILTER_PARAMETERS
from imu_driver import Driver
from ros_helpers import installed, SECOND

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
    smallest = min(min(np.diag(np.reshape(m.orientation_covariance, (3, 3))))
                   for m in filtered.values())
    print(f'{len(filtered)} imu/data messages, smallest variance {smallest:.3g} rad²')
    out = process.output
    assert "orientation_covariance of imu/data: the estimate's own" in out, out
    assert 'orientation_stddev 0.0 means not given' in out, out
    assert 'publish_tf' in out, out
    try:
        import tf2_ros  # noqa: F401
    except ImportError:
        # The pip wheels: one WARN, saying what to do.
        assert out.count('publish_tf is true but tf2_ros does not import here') == 1, out
        assert 'ROS 2 installation' in out


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
    from imu_driver import connect
    from ros_helpers import overrides

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
    print(f'{len(received)} estimates of {len(samples)} samples, turn {turn:.4f} rad')
    assert turn == pytest.approx(1.99, abs=0.005), turn


# Debug topics and gravity removal (the ROS-free part: pipeline/test_imu_filter_outputs.py) ------

# Every world frame: in NED the published orientation's z points down, so
# gravity removed with it instead of the estimator's own (ENU) would be added.
# NED on the typed path too (serialized_io false): it removes gravity apart.
@pytest.mark.parametrize('frame, serialized', [('enu', True), ('nwu', True), ('ned', True),
                                               ('ned', False)])
def test_debug_topics_are_imu_datas_rpy_and_gravity_is_removed_at_rest(
        ros_context, spinner, frame, serialized):
    from geometry_msgs.msg import Vector3Stamped
    from std_msgs.msg import Bool

    from ext_observer.core.quaternion import multiply_floats
    from ext_observer.nodes.imu_filter_node import ImuFilterNode
    from ext_observer.pipeline.imu_filter_outputs import gravity_in_sensor, rpy_from_quaternion
    from imu_driver import connect
    from ros_helpers import overrides

    node = spinner.add(ImuFilterNode(
        node_name='debugged', context=ros_context, parameter_overrides=overrides(
            publish_debug_topics=True, remove_gravity_vector=True, yaw_offset=0.3,
            world_frame=frame, serialized_io=serialized)))
    driver = spinner.add(Driver(ros_context))
    out = {'imu': {}, 'filtered': {}, 'raw': {}, 'steady': []}

    def keep(store):
        return lambda msg: store.__setitem__(nanoseconds_from_stamp(msg.header.stamp), msg)
    driver.create_subscription(Imu, 'imu/data', keep(out['imu']), 1000)
    driver.create_subscription(Vector3Stamped, 'imu/rpy/filtered', keep(out['filtered']), 1000)
    driver.create_subscription(Vector3Stamped, 'imu/rpy/raw', keep(out['raw']), 1000)
    driver.create_subscription(Bool, 'imu/steady_state',
                               lambda msg: out['steady'].append(msg.data), 1000)
    connect(spinner, driver, node)
    spinner.spin_until(lambda: all(driver.count_publishers(t) == 1 for t in (
        'imu/rpy/filtered', 'imu/rpy/raw', 'imu/steady_state')), 10.0, 'the debug topics')
    # At rest, tilted (about x by 0.4 rad, then z by 1 rad), with noise.
    rng = np.random.default_rng(32)
    tilt = multiply_floats((math.cos(0.5), 0.0, 0.0, math.sin(0.5)),
                           (math.cos(0.2), math.sin(0.2), 0.0, 0.0))
    g = np.array(gravity_in_sensor(tilt, 9.81))
    field = (2e-5, 1e-5, -4e-5)
    count = 300
    for k in range(count):
        stamp = START + k * SECOND // 100
        acc = tuple(float(v) for v in g + rng.normal(0.0, 0.02, 3))
        gyr = tuple(float(v) for v in rng.normal(0.0, 0.002, 3))
        driver.send_field(stamp, field)
        driver.send_imu(stamp, gyr, acc)
        if k:
            spinner.spin_until(lambda: stamp in out['imu'] and stamp in out['filtered']
                               and stamp in out['raw'], 10.0, f'outputs {k}')
    assert len(out['imu']) == count - 1
    worst_rpy = worst_acc = 0.0
    for stamp, msg in out['imu'].items():
        filtered = out['filtered'][stamp]
        assert filtered.header.frame_id == msg.header.frame_id == 'imu_link'
        o = msg.orientation
        expected = rpy_from_quaternion((o.w, o.x, o.y, o.z))
        v = filtered.vector
        worst_rpy = max(worst_rpy, np.abs(np.subtract((v.x, v.y, v.z), expected)).max())
        a = msg.linear_acceleration
        worst_acc = max(worst_acc, math.sqrt(a.x * a.x + a.y * a.y + a.z * a.z))
        # The sample alone agrees with the filter at rest, to the noise.
        r = out['raw'][stamp].vector
        assert np.abs(np.subtract((r.x, r.y, r.z), expected)).max() < 0.05
    # imu/rpy/filtered is the roll, pitch and yaw of imu/data.
    assert worst_rpy < 1e-12, worst_rpy
    # At rest with remove_gravity_vector: what is left is noise.
    assert worst_acc < 0.2, worst_acc
    print(f'rpy difference {worst_rpy:.2e} rad, largest |a| without gravity {worst_acc:.3f} m/s²')
    spinner.spin_until(lambda: len(out['steady']) >= count - 1, 10.0, 'steady states')
    assert out['steady'][-1] is True
    # At runtime: false gives the specific force as measured again.
    from rclpy.parameter import Parameter
    assert node.set_parameters([Parameter('remove_gravity_vector', value=False)])[0].successful
    stamp = START + count * SECOND // 100
    driver.send_field(stamp, field)
    driver.send_imu(stamp, (0.0, 0.0, 0.0), tuple(g))
    spinner.spin_until(lambda: stamp in out['imu'], 10.0, 'the last estimate')
    a = out['imu'][stamp].linear_acceleration
    assert (a.x, a.y, a.z) == tuple(g)


# imu_complementary_filter's users -------------------------------------------------

def test_complementary_filter_own_file_starts_the_node_and_names_its_parameters(
        ros_processes, ros_context, spinner):
    from rclpy.qos import QoSProfile, ReliabilityPolicy

    # Its own file, unchanged, under its own node name; it asks for a
    # reliable imu/data_raw (qos_overrides), so the driver here is reliable.
    process = ros_processes([installed('imu_filter_node'), '--ros-args',
                             '-r', '__node:=complementary_filter_gain_node',
                             '--params-file', COMPLEMENTARY_FILE])
    driver = spinner.add(Driver(ros_context))
    reliable = driver.create_publisher(Imu, 'imu/data_raw', QoSProfile(
        depth=10, reliability=ReliabilityPolicy.RELIABLE))
    received = []
    driver.create_subscription(Imu, 'imu/data', received.append, 1000)
    spinner.spin_until(lambda: reliable.get_subscription_count() == 1
                       and driver.count_publishers('imu/data') == 1, 20.0, 'the node')
    deadline = time.monotonic() + 20.0
    k = 0
    while len(received) < 20:
        assert time.monotonic() < deadline and process.process.poll() is None, process.output
        msg = Imu()
        msg.header.stamp.sec, msg.header.stamp.nanosec = 1_700_000_000 + k // 100, (
            k % 100) * 10_000_000
        msg.header.frame_id = 'imu_link'
        msg.angular_velocity.z = 0.1
        msg.linear_acceleration.z = 9.81
        reliable.publish(msg)
        k += 1
        spinner.spin_for(0.01)
    out = process.output
    warnings = [line for line in out.splitlines() if 'not used here' in line]
    assert len(warnings) == 1, out
    for name, replacement in (('gain_acc', 'ahrs.tau_acc_gain'), ('gain_mag', 'ahrs.tau_mag'),
                              ('bias_alpha', 'ahrs.tau_rest'),
                              ('do_bias_estimation', 'ahrs.tau_bias'),
                              ('do_adaptive_gain', 'ahrs.tau_acc')):
        assert f'{name}=' in warnings[0] and replacement in warnings[0], (name, warnings[0])
    # Its use_mag: false is honoured (6D), its orientation_stddev (not in
    # the file) leaves the estimate's own covariance.
    assert 'use_mag false' in out, out
    assert all(msg.orientation_covariance[0] > 0.0 for msg in received)


# The gyro bias: given, saved, loaded, switched ---------------------------------------

def test_a_saved_gyro_bias_reloads_and_applies_from_the_first_sample(
        ros_context, spinner, tmp_path):
    import yaml
    from std_srvs.srv import Trigger

    from ext_observer.nodes.imu_filter_node import ImuFilterNode
    from ext_observer.pipeline.imu_filter_parameters import imu_filter_settings
    from ext_observer.pipeline.raw_imu import RawImuPipeline
    from imu_driver import connect
    from ros_helpers import overrides

    bias = (0.01, -0.015, 0.02)  # rad/s
    path = tmp_path / 'calibration.yaml'
    learner = spinner.add(ImuFilterNode(node_name='learner', context=ros_context,
                                        parameter_overrides=overrides(
                                            calibration_file=str(path), use_mag=False)))
    # 6 s at rest on a biased gyro: the bias is learned.
    rng = np.random.default_rng(33)
    for k in range(600):
        gyr = tuple(float(v) for v in np.add(bias, rng.normal(0.0, 0.001, 3)))
        learner.pipeline.imu(START + k * SECOND // 100, gyr, (0.0, 0.0, 9.81))
    learned = learner.observer.bias
    assert np.abs(np.subtract(learned, bias)).max() < 1e-3, learned
    driver = spinner.add(Driver(ros_context))
    client = driver.create_client(Trigger, '/learner/save_calibration')
    spinner.spin_until(client.service_is_ready, 10.0, 'the save service')
    future = client.call_async(Trigger.Request())
    spinner.spin_until(future.done, 10.0, 'the save answer')
    result = future.result()
    # The gyro bias is saved; the magnetometer's (off in 6D) is said not to be.
    assert result.success and 'magnetometer calibration not saved' in result.message
    saved = yaml.safe_load(path.read_text())['learner']['ros__parameters']
    assert 'mag_bias_x' not in saved
    assert tuple(saved[f'gyro_bias_{a}'] for a in 'xyz') == learned
    # A new node loads it (as --params-file does) and starts from it.
    fresh = spinner.add(ImuFilterNode(node_name='fresh', context=ros_context,
                                      parameter_overrides=overrides(use_mag=False, **saved)))
    assert fresh.observer.bias == learned
    spinner.executor.remove_node(learner)
    spinner.nodes.remove(learner)
    learner.destroy_node()
    received = []
    driver.create_subscription(Imu, 'imu/data', received.append, 1000)
    connect(spinner, driver, fresh)
    spinner.spin_until(lambda: fresh.imu_publisher.get_subscription_count() == 2, 10.0,
                       'both subscriptions to imu/data')
    # 1 s at rest, the gyro reading exactly its bias: from the first sample
    # the estimate does not turn (rest is detected only after 1.5 s, so
    # nothing is learned meanwhile).
    samples = [(START + k * SECOND // 100, learned, (0.0, 0.0, 9.81)) for k in range(101)]
    for k, (stamp, gyr, acc) in enumerate(samples):
        driver.send_imu(stamp, gyr, acc)
        if k:
            spinner.spin_until(lambda: len(received) == k, 10.0, f'estimate {k}')
    first, last = received[0].orientation, received[-1].orientation
    turned = 2.0 * math.acos(min(1.0, abs(first.w * last.w + first.x * last.x
                                          + first.y * last.y + first.z * last.z)))
    # Without it, the same samples turn the estimate by the bias over 1 s.
    pipeline = RawImuPipeline(imu_filter_settings(defaults(use_mag=False)))
    states = [pipeline.imu(t, g, a)[1] for t, g, a in samples]
    q0, q1 = states[1].state, states[-1].state
    unsaved = 2.0 * math.acos(min(1.0, abs(np.dot(q0, q1))
                                  / np.linalg.norm(q0) / np.linalg.norm(q1)))
    print(f'turn over 1 s at rest: {turned:.2e} rad with the saved bias, '
          f'{unsaved:.4f} rad without')
    assert turned < 1e-4, turned
    assert unsaved > 0.02, unsaved


def test_gyro_bias_learning_switches_at_runtime(ros_context):
    from rclpy.parameter import Parameter

    from ext_observer.nodes.imu_filter_node import ImuFilterNode
    from ros_helpers import values_of
    from ros_helpers import overrides

    node = ImuFilterNode(node_name='switched', context=ros_context,
                         parameter_overrides=overrides(use_mag=False, gyro_bias_z=0.005))
    try:
        assert node.observer.bias == (0.0, 0.0, 0.005)
        assert node.set_parameters([Parameter('gyro_bias_learning', value=False)])[0].successful
        rest = [(START + k * SECOND // 100, (0.0, 0.0, 0.02), (0.0, 0.0, 9.81))
                for k in range(400)]
        for stamp, gyr, acc in rest[:200]:
            node.pipeline.imu(stamp, gyr, acc)
        # Held: at rest for 2 s and nothing learned.
        assert node.observer.bias == (0.0, 0.0, 0.005)
        assert values_of(node.status())['bias_learning'] == 'false'
        assert node.set_parameters([Parameter('gyro_bias_learning', value=True)])[0].successful
        for stamp, gyr, acc in rest[200:]:
            node.pipeline.imu(stamp, gyr, acc)
        assert node.observer.bias[2] == pytest.approx(0.02, abs=2e-3)
        # A reset starts again from the bias given.
        node.pipeline.reset('service')
        assert node.observer.bias == (0.0, 0.0, 0.005)
        # Beyond ahrs.bias_max: refused with the reason.
        result = node.set_parameters([Parameter('gyro_bias_x', value=0.5)])[0]
        assert not result.successful and 'bias_max' in result.reason
    finally:
        node.destroy_node()


# TF -------------------------------------------------------------------------------

def test_publish_tf_broadcasts_the_orientation_where_tf2_ros_imports(ros_context, spinner):
    tf2_ros = pytest.importorskip(
        'tf2_ros', reason='tf2_ros is not on PyPI: the TF broadcast needs a ROS installation')
    from ext_observer.nodes.imu_filter_node import ImuFilterNode
    from ext_observer.pipeline.imu_filter_outputs import transform_from_estimate
    from imu_driver import connect
    from ros_helpers import overrides

    node = spinner.add(ImuFilterNode(node_name='tf', context=ros_context,
                                     parameter_overrides=overrides(
                                         publish_tf=True, fixed_frame='odom', use_mag=False)))
    assert node.tf_broadcaster is not None
    buffer = tf2_ros.Buffer()
    listener = tf2_ros.TransformListener(buffer, node, spin_thread=False)
    driver = spinner.add(Driver(ros_context))
    connect(spinner, driver, node)
    for k in range(50):
        driver.send_imu(START + k * SECOND // 100, (0.0, 0.0, 0.5), (0.3, 0.0, 9.8))
        spinner.spin_for(0.02)
    spinner.spin_until(lambda: buffer.can_transform('odom', 'imu_link', rclpy_time_zero()),
                       10.0, 'the transform')
    t = buffer.lookup_transform('odom', 'imu_link', rclpy_time_zero())
    r = t.transform.rotation
    _, _, expected = transform_from_estimate(node.state, 'odom', 'imu_link')
    assert np.abs(np.subtract((r.w, r.x, r.y, r.z), expected)).max() < 1e-9
    del listener


def rclpy_time_zero():
    from rclpy.time import Time
    return Time()


# The launch file -------------------------------------------------------------------

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
LAUNCH_FILE = os.path.join(REPO, 'launch', 'imu_filter.launch.py')


def test_the_launch_file_is_imu_tools_shape_and_installed_by_setup():
    import ast

    tree = ast.parse(open(LAUNCH_FILE).read())
    calls = {node.func.attr: node for node in ast.walk(tree)
             if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute)}
    keywords = {k.arg: k.value for k in calls['Node'].keywords}
    assert {k: ast.literal_eval(keywords[k]) for k in ('package', 'executable', 'name')} == {
        'package': 'ext_observer', 'executable': 'imu_filter_node', 'name': 'imu_filter'}
    # imu_tools' shape: the installed config/imu_filter.yaml, overridable.
    assert ast.literal_eval(calls['DeclareLaunchArgument'].args[0]) == 'params_file'
    assert "'config'" in ast.unparse(tree) and "'imu_filter.yaml'" in ast.unparse(tree)
    setup = open(os.path.join(REPO, 'setup.py')).read()
    assert "'imu_filter_node = ext_observer.nodes.executables:imu_filter_node'" in setup
    assert "glob('launch/*.launch.py')" in setup


def test_ros2_launch_starts_the_node_where_launch_ros_imports(ros_processes):
    import shutil

    pytest.importorskip('launch_ros', reason='launch_ros is not on PyPI: the launch file '
                        'needs a ROS 2 installation (colcon)')
    from ament_index_python.packages import (get_package_share_directory,
                                             PackageNotFoundError)
    try:
        share = get_package_share_directory('ext_observer')
    except PackageNotFoundError:
        pytest.skip('ext_observer is not installed with colcon in this environment')
    ros2 = shutil.which('ros2')
    if ros2 is None:
        pytest.skip('the ros2 command is not on PATH')
    assert os.path.exists(os.path.join(share, 'launch', 'imu_filter.launch.py'))
    process = ros_processes([ros2, 'launch', 'ext_observer', 'imu_filter.launch.py',
                             f'params_file:={MADGWICK_FILE}'])
    deadline = time.monotonic() + 30.0
    while 'raw IMU on /imu/data_raw' not in process.output:
        assert process.process.poll() is None, process.output
        assert time.monotonic() < deadline, process.output
        time.sleep(0.1)
    assert "the estimate's own" in process.output


# The docs' switching table -----------------------------------------------------------

# Every parameter the two imu_tools nodes declare (ROS 2 branch:
# imu_filter_madgwick/src/imu_filter_ros.cpp and
# imu_complementary_filter/src/complementary_filter_ros.cpp).
MADGWICK_DECLARES = ('stateless', 'use_mag', 'publish_tf', 'reverse_tf', 'fixed_frame',
                     'constant_dt', 'remove_gravity_vector', 'publish_debug_topics',
                     'yaw_offset', 'declination', 'world_frame', 'gain', 'zeta',
                     'mag_bias_x', 'mag_bias_y', 'mag_bias_z', 'orientation_stddev')
COMPLEMENTARY_DECLARES = ('fixed_frame', 'use_mag', 'publish_tf', 'reverse_tf',
                          'constant_dt', 'publish_debug_topics', 'gain_acc', 'gain_mag',
                          'do_bias_estimation', 'bias_alpha', 'do_adaptive_gain',
                          'orientation_stddev')


def test_every_parameter_of_both_filters_is_declared_here_and_in_the_switching_table():
    import re

    text = open(os.path.join(REPO, 'docs', 'raw_imu.md')).read()
    start = text.index('| parameter | imu_filter_madgwick | imu_complementary_filter | here |')
    rows = text[start:text.index('\n\n', start)].splitlines()[2:]
    listed = {name for row in rows for name in re.findall(r'`([a-z_]+)`', row.split('|')[1])}
    declared = {spec.name for spec in IMU_FILTER_PARAMETERS}
    for name in set(MADGWICK_DECLARES) | set(COMPLEMENTARY_DECLARES):
        assert name in listed, f'{name} missing from the switching table'
        assert name in declared, f'{name} not declared by imu_filter_node'
    # The params files in test/data name nothing else (qos_overrides is rclpy's).
    import yaml
    for path, node in ((MADGWICK_FILE, 'imu_filter'),
                       (COMPLEMENTARY_FILE, 'complementary_filter_gain_node')):
        with open(path) as f:
            names = set(yaml.safe_load(f)[node]['ros__parameters']) - {'qos_overrides'}
        assert names <= set(MADGWICK_DECLARES) | set(COMPLEMENTARY_DECLARES), names
