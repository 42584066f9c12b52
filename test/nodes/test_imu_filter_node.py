"""
imu_filter_node as a drop-in for imu_filter_madgwick, and what it says of wrong units.

A params file written for imu_filter_madgwick starts the node unchanged and
is named in one warning for what it sets that is not used; its
``yaw_offset``, ``declination`` and ``orientation_stddev`` change the output
as imu_filter_madgwick's do. A magnetometer in µT, an accelerometer in g and
a gyro in deg/s each give one WARN naming the topic, the magnitude and the
unit expected, in the log once and in ``/diagnostics`` while it lasts.
"""

import math
import os
import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
import numpy as np
import pytest
from sensor_msgs.msg import Imu

from conftest import REPO
from broad_replay import errors_deg, load, offline as core_offline, rmse, START, TRIALS
from ext_observer.nodes.conversions import nanoseconds_from_stamp, quaternion_from_msg
from ext_observer.core.ahrs.ahrs_observer import world_from_enu
from ext_observer.core.quaternion import multiply_floats
from ext_observer.nodes.imu_filter_node import ImuFilterNode
from ext_observer.nodes.stream_watch import StreamWatch
from ext_observer.pipeline.imu_filter_parameters import IMU_FILTER_PARAMETERS, imu_filter_settings
from ext_observer.pipeline.raw_imu import heading_factor, RawImuPipeline
from ext_observer.pipeline.units import ACC_WINDOW, UnitCheck
from imu_driver import (connect, Driver, MAG_EVERY, published, replay_lockstep,
                          TOLERANCE)
from imu_filter_runs import replay, run_node, samples, turning
from ros_helpers import installed, overrides, SECOND, values_of

# imu_filter_madgwick's own params file (imu_tools, ROS 2: config/imu_filter.yaml),
# with three values changed as a user would.
MADGWICK_PARAMS = """\
imu_filter:
  ros__parameters:
    stateless: false
    use_mag: true
    publish_tf: true
    reverse_tf: false
    fixed_frame: "odom"
    constant_dt: 0.0
    publish_debug_topics: false
    world_frame: "enu"
    gain: 0.1
    zeta: 0.0
    mag_bias_x: 0.0
    mag_bias_y: 0.0
    mag_bias_z: 0.0
    orientation_stddev: 0.2
    yaw_offset: 0.3
    declination: 0.1
"""


def test_madgwick_params_file_starts_unchanged_warns_once_and_takes_effect(
        ros_processes, ros_context, spinner, tmp_path):
    path = tmp_path / 'imu_filter.yaml'
    path.write_text(MADGWICK_PARAMS)
    process = ros_processes([installed('imu_filter_node'), '--ros-args',
                             '--params-file', str(path), '-r', 'imu/data_raw:=/imu/raw',
                             '-r', 'imu/data:=/imu/filtered'])
    driver = spinner.add(Driver(ros_context, '/imu/raw', 'imu/mag'))
    spinner.spin_until(lambda: driver.imu_publisher.get_subscription_count() == 1
                       and process.process.poll() is None, 20.0, 'imu_filter_node')
    filtered = {}
    driver.create_subscription(Imu, '/imu/filtered', lambda msg: filtered.__setitem__(
        nanoseconds_from_stamp(msg.header.stamp), msg), 1000)
    # The process's own status reached this node: discovery is done both ways.
    statuses = []
    driver.create_subscription(DiagnosticArray, '/diagnostics',
                               lambda msg: statuses.extend(msg.status), 10)
    spinner.spin_until(lambda: driver.count_publishers('/imu/filtered') == 1
                       and any(st.name == 'imu_filter: inputs' for st in statuses), 20.0,
                       'imu/data and the status of the process')
    data = samples(150)
    # Each sample once the estimate of the one before has come back.
    for k, (stamp, gyr, acc, field) in enumerate(data):
        driver.send_field(stamp, field)
        driver.send_imu(stamp, gyr, acc)
        if k:
            spinner.spin_until(lambda: stamp in filtered, 10.0, f'estimate {k}')
    assert len(filtered) == len(data) - 1
    assert process.process.poll() is None, process.output
    # Nothing is named unused: gain, zeta and stateless are at
    # imu_filter_madgwick's defaults, the others honoured. publish_tf: true
    # broadcasts the TF where tf2_ros imports, else one WARN names it.
    assert 'not used here' not in process.output
    try:
        import tf2_ros  # noqa: F401
    except ImportError:
        assert process.output.count('publish_tf is true but tf2_ros does not import') == 1
    # The file's orientation_stddev is honoured: orientation_covariance_mode
    # 'auto' (the default) publishes its square, 0.2² on the diagonal, as
    # imu_filter_madgwick would (without it, the estimate's own: test_covariance.py).
    v = 0.2 ** 2
    for message in filtered.values():
        assert list(message.orientation_covariance) == [v, 0, 0, 0, v, 0, 0, 0, v]
    # yaw_offset and declination: a turn of R_z(0.3 − 0.1) of the estimate,
    # in the world frame.
    turn = (math.cos(0.1), 0.0, 0.0, math.sin(0.1))
    # The process and the reference saw the same samples, maybe a field
    # earlier or later: compare the heading turn, not the bits.
    # The same estimator with the defaults, offline, as the reference.
    pipeline = RawImuPipeline(imu_filter_settings(
        {spec.name: spec.default for spec in IMU_FILTER_PARAMETERS}))
    for stamp, gyr, acc, field in data:
        pipeline.field(stamp, field)
        _, estimate = pipeline.imu(stamp, gyr, acc)
        if estimate is not None and stamp in filtered:
            q = np.array(estimate.state) / np.linalg.norm(estimate.state)
            expected = np.array(multiply_floats(turn, tuple(q)))
            got = np.array(quaternion_from_msg(filtered[stamp].orientation))
            assert min(np.abs(got - expected).max(), np.abs(got + expected).max()) < 2e-3


@pytest.mark.parametrize('frame', ['enu', 'nwu', 'ned'])
def test_declination_turns_the_heading_to_true_north_in_every_frame(frame):
    # A body whose x axis points to magnetic north, with the declination
    # 0.2 rad east: its x axis points 0.2 rad east of true north.
    declination = 0.2
    north = (math.cos(math.pi / 4), 0.0, 0.0, math.sin(math.pi / 4))  # x → ENU y
    q = multiply_floats(heading_factor(frame, declination, 0.0), north)
    true = (math.cos((math.pi / 2 - declination) / 2), 0.0, 0.0,
            math.sin((math.pi / 2 - declination) / 2))
    expected = world_from_enu(np.array(true), frame)
    assert min(np.abs(np.array(q) - expected).max(),
               np.abs(np.array(q) + expected).max()) < 1e-12
    # yaw_offset turns about the frame's own z axis (imu_filter_madgwick's).
    offset = multiply_floats(heading_factor(frame, 0.0, 0.3), north)
    turned = multiply_floats((math.cos(0.15), 0.0, 0.0, math.sin(0.15)),
                             tuple(world_from_enu(np.array(north), frame)))
    assert np.abs(np.array(offset) - np.array(turned)).max() < 1e-12


@pytest.mark.parametrize('kind, change, expected', [
    ('field', dict(field=(20.0, 10.0, -40.0)),
     ('/imu/mag', '45.83', 'tesla expected', 'µT')),
    ('acceleration', dict(acc=(0.05, -0.03, 0.99)),
     ('/imu/data_raw', '0.9917', 'm/s² expected', 'g?')),
    ('angular_velocity', dict(gyr=(0.0, 0.0, 90.0)),
     ('/imu/data_raw', '90', 'rad/s expected', 'deg/s')),
])
def test_a_wrong_unit_is_one_clear_warn_naming_topic_magnitude_and_unit(
        ros_context, spinner, kind, change, expected):
    node = spinner.add(ImuFilterNode(context=ros_context,
                                     parameter_overrides=overrides(diagnostic_period=60.0)))
    driver = spinner.add(Driver(ros_context))
    connect(spinner, driver, node)
    assert node.status().level == DiagnosticStatus.OK
    replay(spinner, driver, [node], samples(ACC_WINDOW + 5, **change))
    status = node.status()
    assert status.level == DiagnosticStatus.WARN
    for text in expected:
        assert text in status.message, (text, status.message)
    values = values_of(status)
    assert int(values[f'implausible_{kind}']) > 0
    others = {'field', 'acceleration', 'angular_velocity'} - {kind}
    assert all(values[f'implausible_{other}'] == '0' for other in others)
    # The node keeps running on the samples as they are.
    assert node.state is not None and all(map(math.isfinite, node.state))
    assert node._said >= {kind}


def test_unit_check_counts_by_magnitude_only():
    check = UnitCheck()
    for _ in range(3 * ACC_WINDOW):
        check.imu((0.3, -0.2, 1.0), (0.1, 0.2, 9.8))
        check.field((2e-5, 0.0, -4e-5))
    assert check.counts == {'field': 0, 'acceleration': 0, 'angular_velocity': 0}
    # A shock or a moment of free fall is not a unit: the mean over a window is.
    check.imu((0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    check.imu((0.0, 0.0, 0.0), (0.0, 0.0, 300.0))
    assert check.counts['acceleration'] == 0
    check.field((3e-5, 4e-5, 0.0))
    check.field((0.3, 0.4, 0.0))   # gauss
    assert check.counts['field'] == 1 and 'gauss' in check.findings['field']
    check.field((3e4, 4e4, 0.0))   # nT
    assert check.counts['field'] == 2 and 'nT' in check.findings['field']


def test_the_missing_magnetometer_is_said_once_in_the_log(
        ros_processes, ros_context, spinner):
    process = ros_processes([installed('imu_filter_node'), '--ros-args', '-p',
                             'diagnostic_period:=0.2'])
    driver = spinner.add(Driver(ros_context))
    spinner.spin_until(lambda: driver.imu_publisher.get_subscription_count() == 1, 20.0,
                       'imu_filter_node')
    stamp = START
    deadline = time.monotonic() + 30.0
    # IMU samples and no field, for several status periods after the first warning.
    while process.output.count('no magnetic field on /imu/mag') == 0:
        assert time.monotonic() < deadline, process.output
        driver.send_imu(stamp, (0.0, 0.0, 0.1), (0.0, 0.0, 9.81))
        stamp += SECOND // 100
        spinner.spin_for(0.01)
    until = time.monotonic() + 1.5
    while time.monotonic() < until:
        driver.send_imu(stamp, (0.0, 0.0, 0.1), (0.0, 0.0, 9.81))
        stamp += SECOND // 100
        spinner.spin_for(0.01)
    assert process.output.count('no magnetic field on /imu/mag') == 1, process.output
    assert 'is the magnetometer publishing there?' in process.output
    assert process.process.poll() is None


def test_madgwick_unused_parameters_are_named_only_when_given(ros_context):
    quiet = ImuFilterNode(node_name='quiet', context=ros_context)
    loud = ImuFilterNode(node_name='loud', context=ros_context, parameter_overrides=overrides(
        gain=0.05, zeta=0.01, stateless=True, orientation_stddev=0.1))
    try:
        assert not quiet.parameters.given & {'gain', 'zeta', 'stateless'}
        assert loud.parameters.given >= {'gain', 'zeta', 'stateless', 'orientation_stddev'}
    finally:
        quiet.destroy_node()
        loud.destroy_node()


# Each option of the node through DDS, against RawImuPipeline offline on the
# same samples in the same order: equal to rounding (the same float code).
OPTION_TOLERANCE = 1e-12


def defaults(**changes):
    values = {spec.name: spec.default for spec in IMU_FILTER_PARAMETERS}
    values.update(changes)
    return imu_filter_settings(values)


def offline(settings, data, use_fields=True):
    """The estimates of RawImuPipeline fed as :func:`replay` feeds the node."""
    pipeline = RawImuPipeline(settings)
    out = {}
    for stamp, gyr, acc, field in data:
        if use_fields:
            pipeline.field(stamp, field)
        _, estimate = pipeline.imu(stamp, gyr, acc)
        if estimate is not None:
            out[stamp] = estimate.state
    return out


def published_states(driver, stamps):
    return {t: quaternion_from_msg(driver.estimates[t].quaternion) for t in stamps
            if t in driver.estimates}


def assert_equal_estimates(got, expected):
    assert len(got) >= len(expected) - 1 and len(expected) > 10
    worst = max(np.abs(np.array(got[t]) - np.array(expected[t])).max() for t in got)
    assert worst <= OPTION_TOLERANCE, worst


def test_a_fixed_calibration_is_removed_from_the_field(ros_context, spinner):
    # Without the online calibration (ahrs.mag_cal false), mag_bias_* and
    # mag_soft_iron are applied as they are: m = S⁻¹ (m_raw − b).
    bias = (3e-5, -2e-5, 1e-5)
    soft = np.array([[1.05, 0.02, -0.01], [0.02, 0.97, 0.03], [-0.01, 0.03, 1.02]])
    data = turning(200)
    raw = [(t, g, a, tuple(soft @ np.array(field) + bias)) for t, g, a, field in data]
    fixed = {'ahrs.mag_cal': False, 'mag_bias_x': bias[0], 'mag_bias_y': bias[1],
             'mag_bias_z': bias[2], 'mag_soft_iron': soft.ravel().tolist()}
    node, driver = run_node(spinner, ros_context, raw, 'fixed', **fixed)
    assert node.observer.calibration_state == 'off'
    got = published_states(driver, [t for t, *_ in data])
    assert_equal_estimates(got, offline(defaults(**fixed), raw))
    # The same as the undistorted field, to the rounding of the inverse; and
    # far from the distorted field taken as it is.
    clean = offline(defaults(**{'ahrs.mag_cal': False}), data)
    assert max(np.abs(np.array(got[t]) - clean[t]).max() for t in got) < 1e-9
    as_is = offline(defaults(**{'ahrs.mag_cal': False}), raw)
    assert max(np.abs(np.array(as_is[t]) - clean[t]).max() for t in got) > 1e-3


def test_a_saved_calibration_is_loaded_refined_saved_and_refused_when_bad(
        ros_context, spinner, tmp_path):
    from std_srvs.srv import Trigger

    from ext_observer.recordings.calibrate import read_params
    from ext_observer.nodes.node_common import ParameterError

    bias = (3e-5, -2e-5, 1e-5)
    soft = [1.05, 0.02, -0.01, 0.02, 0.97, 0.03, -0.01, 0.03, 1.02]
    path = tmp_path / 'saved.yaml'
    node = spinner.add(ImuFilterNode(
        node_name='calibrated', context=ros_context, parameter_overrides=overrides(
            mag_bias_x=bias[0], mag_bias_y=bias[1], mag_bias_z=bias[2], mag_soft_iron=soft,
            calibration_file=str(path))))
    # With the online calibration (the default in 9D) the saved one is where
    # it starts from the first field on, refined from there; none is
    # subtracted before it.
    core = node.observer
    assert core.calibration_state == 'loaded'
    assert node.pipeline.estimator._mag_bias == (0.0, 0.0, 0.0)
    distorted = np.reshape(soft, (3, 3))
    for stamp, gyr, acc, field in turning(20):
        node.pipeline.field(stamp, tuple(distorted @ np.array(field) + bias))
        node.pipeline.imu(stamp, gyr, acc)
    assert core.calibration_state == 'loaded'
    assert core.calibration.bias == pytest.approx(bias, abs=2e-6)
    assert core.calibration.soft_iron.ravel() == pytest.approx(soft, abs=0.02)
    values = values_of(node.status())
    assert values['calibration'] == 'loaded'
    assert float(values['calibration_bias_x']) == pytest.approx(
        core.calibration.bias[0], rel=1e-5)
    # ~/save_calibration writes a params file that gives it back.
    driver = spinner.add(Driver(ros_context))
    client = driver.create_client(Trigger, '/calibrated/save_calibration')
    spinner.spin_until(client.service_is_ready, 10.0, 'the save service')
    future = client.call_async(Trigger.Request())
    spinner.spin_until(future.done, 10.0, 'the save answer')
    assert future.result().success, future.result().message
    saved_bias, saved_soft = read_params(str(path), node='calibrated')
    now_bias, now_soft = node.pipeline.estimator.calibration()
    assert saved_bias == pytest.approx(now_bias, abs=1e-15)
    assert saved_soft.ravel() == pytest.approx(now_soft, abs=1e-12)
    # No magnetometer calibration to save while learning, said so (the gyro
    # bias is saved: test_imu_tools_dropin.py).
    learning = spinner.add(ImuFilterNode(
        node_name='learning', context=ros_context,
        parameter_overrides=overrides(calibration_file=str(tmp_path / 'learning.yaml'))))
    assert learning.observer.calibration_state == 'learning'
    client = driver.create_client(Trigger, '/learning/save_calibration')
    spinner.spin_until(client.service_is_ready, 10.0, 'the save service')
    future = client.call_async(Trigger.Request())
    spinner.spin_until(future.done, 10.0, 'the save answer')
    message = future.result().message
    assert 'magnetometer calibration not saved' in message and 'learning' in message
    # A bad saved value stops the start with the reason.
    for bad, reason in (
            (dict(mag_soft_iron=[1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0]), 'singular'),
            (dict(mag_soft_iron=[1.0, 0.5, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]), 'symmetric'),
            (dict(mag_soft_iron=[1.0] * 8), 'mag_soft_iron'),
            (dict(mag_bias_x=math.nan), 'mag_bias_x')):
        with pytest.raises(ParameterError, match=reason):
            ImuFilterNode(node_name='bad', context=ros_context,
                          parameter_overrides=overrides(**bad))


def test_a_distorted_broad_excerpt_through_dds_learns_its_calibration(ros_context, spinner):
    # The shipped excerpt with a hard iron of 1.5 × the field's norm and a
    # soft iron, replayed to the node through DDS: the heading is held on
    # the gyro (a WARN naming the state) until the calibration converges,
    # then follows the calibrated field; the node computes what the core
    # computes offline.
    data = dict(load(TRIALS[0]))
    norm = float(np.mean(np.linalg.norm(data['mag'], axis=1)))  # µT
    bias = 1.5 * norm * np.array([0.6, -0.48, 0.64])
    soft = np.array([[1.06, 0.03, -0.05], [0.03, 0.95, 0.04], [-0.05, 0.04, 1.02]])
    data['mag'] = data['mag'] @ soft.T + bias
    rate = float(data['rate'])
    node = spinner.add(ImuFilterNode(context=ros_context))
    driver = spinner.add(Driver(ros_context))
    connect(spinner, driver, node)
    core = node.observer
    # 12 s: the body has moved for 2 s (from 10 s on).
    learning = round(12.0 * rate)
    replay_lockstep(spinner, driver, node, data, count=learning)
    assert core.calibration_state == 'learning'
    status = node.status()
    assert status.level == DiagnosticStatus.WARN
    assert 'calibration learning' in status.message
    assert values_of(status)['calibration'] == 'learning'
    times = replay_lockstep(spinner, driver, node, data, first=learning)
    assert core.calibration_state == 'converged'
    calibration = core.calibration
    assert calibration.applied
    # The offset within 5 % of the field's norm (it converged at 19 s offline).
    assert np.linalg.norm(np.array(calibration.bias) / 1e-6 - bias) < 0.05 * norm
    status = node.status()
    assert status.level == DiagnosticStatus.OK, status.message
    assert values_of(status)['calibration'] == 'converged'
    # The same as the core offline, and the heading right from 40 s on.
    expected = core_offline(data, mag_every=MAG_EVERY)
    assert np.nanmax(np.abs(published(driver.estimates, times) - expected)) <= TOLERANCE
    late = dict(data, movement=data['movement'] & (np.arange(len(times)) >= 40.0 * rate))
    angles = errors_deg(published(driver.outputs, times), late)
    assert len(angles) > 4000 and rmse(angles) < 6.0, rmse(angles)


def test_constant_dt_replaces_the_stamps(ros_context, spinner):
    rng = np.random.default_rng(4)
    data = turning(200)
    # Jittered stamps (±3 ms around 10 ms), still increasing.
    jittered, stamp = [], START
    for k, (_, g, a, f) in enumerate(data):
        stamp += int(SECOND // 100 + rng.integers(-3, 4) * 1_000_000)
        jittered.append((stamp, g, a, f))
    node, driver = run_node(spinner, ros_context, jittered, 'constant', constant_dt=0.01)
    got = published_states(driver, [t for t, *_ in jittered])
    assert_equal_estimates(got, offline(defaults(constant_dt=0.01), jittered))
    # The stamps' own intervals give another estimate (and no estimate of the
    # first sample: with constant_dt it answers too).
    from_stamps = offline(defaults(), jittered)
    assert jittered[0][0] in got and jittered[0][0] not in from_stamps
    assert max(np.abs(np.array(got[t]) - from_stamps[t]).max()
               for t in from_stamps if t in got) > 1e-6


def test_use_mag_false_ignores_fields_and_runs_6d(ros_context, spinner):
    data = turning(150)
    node = spinner.add(ImuFilterNode(node_name='six', context=ros_context,
                                     parameter_overrides=overrides(use_mag=False)))
    driver = spinner.add(Driver(ros_context))
    connect(spinner, driver, node)
    # The node does not subscribe to imu/mag: the fields published beside
    # the samples reach nobody.
    assert node.measurement_subscription is None
    assert driver.mag_publisher.get_subscription_count() == 0
    for k, (stamp, gyr, acc, field) in enumerate(data):
        driver.send_field(stamp, field)
        driver.send_imu(stamp, gyr, acc)
        spinner.spin_until(lambda: node.pairer.received['increment'] == k + 1, 10.0,
                           f'sample {k}')
    spinner.spin_until(lambda: len(driver.estimates) >= len(data) - 1, 10.0, 'estimates')
    assert node.pairer.received['measurement'] == 0
    got = published_states(driver, [t for t, *_ in data])
    assert_equal_estimates(got, offline(defaults(use_mag=False), data, use_fields=False))
    assert values_of(node.status())['use_mag'] == 'false'


def test_reset_service_restarts_from_the_next_sample(ros_context, spinner):
    from std_srvs.srv import Trigger

    data = turning(120)
    node, driver = run_node(spinner, ros_context, data[:60], 'resettable')
    client = driver.create_client(Trigger, '/resettable/reset')
    spinner.spin_until(client.service_is_ready, 10.0, 'the reset service')
    future = client.call_async(Trigger.Request())
    spinner.spin_until(future.done, 10.0, 'the reset answer')
    assert future.result().success and 'reset' in future.result().message
    assert node.resets['service'] == 1 and node.state is None
    replay(spinner, driver, [node], data[60:])
    spinner.spin_until(lambda: len(driver.estimates) >= len(data) - 1, 10.0, 'estimates')
    # After the reset the estimator starts over on the next sample, from the
    # latest field: as a fresh pipeline that saw the same time line.
    pipeline = RawImuPipeline(defaults())
    for stamp, gyr, acc, field in data:
        if stamp == data[60][0]:
            pipeline.reset('service')
        pipeline.field(stamp, field)
        pipeline.imu(stamp, gyr, acc)
    t = data[-1][0]
    assert np.abs(np.array(quaternion_from_msg(driver.estimates[t].quaternion))
                  - np.array(pipeline.estimator.state)).max() <= OPTION_TOLERANCE
    assert values_of(node.status())['resets_service'] == '1'


def test_runtime_changes_take_effect_and_structural_ones_are_refused(ros_context, spinner):
    from rclpy.parameter import Parameter

    node = spinner.add(ImuFilterNode(node_name='tuned', context=ros_context))
    results = node.set_parameters([Parameter('mag_bias_x', value=1e-5),
                                   Parameter('orientation_stddev', value=0.1),
                                   Parameter('yaw_offset', value=0.5)])
    assert all(r.successful for r in results)
    # With the online calibration, a new saved offset restarts it from there.
    assert node.observer.calibration_state == 'loaded'
    assert node._orientation_covariance[0] == pytest.approx(0.01)
    # orientation_covariance_mode 'auto': an orientation_stddev set is used.
    assert not node._covariance_estimated
    assert node.set_parameters([Parameter('orientation_stddev', value=0.05)])[0].successful
    assert node._covariance_estimated
    assert node.pipeline.estimator._frame == pytest.approx(heading_factor('enu', 0.0, 0.5))
    for name, value in (('ahrs.tau_acc', 5.0), ('use_mag', False), ('world_frame', 'ned')):
        result = node.set_parameters([Parameter(name, value=value)])[0]
        assert not result.successful and 'read-only' in result.reason, name
    result = node.set_parameters([Parameter('forward_gap_action', value='skip')])[0]
    assert not result.successful and 'forward_gap_action' in result.reason
    assert node.parameters.values['forward_gap_action'] == 'propagate'


def test_a_clock_switch_resets_and_the_guard_reinitializes(ros_context, spinner):
    from rclpy.parameter import Parameter

    data = turning(80)
    node, driver = run_node(spinner, ros_context, data[:40], 'guarded')
    assert node.state is not None
    # use_sim_time switches the node clock to ROS time: a clock change.
    node.set_parameters([Parameter('use_sim_time', value=True)])
    spinner.spin_until(lambda: node.resets['clock_jump'] == 1, 5.0, 'the clock reset')
    assert node.state is None
    replay(spinner, driver, [node], data[40:60])
    # A diverged estimate is reinitialized from the sample, and never published.
    node.observer.q = (30.0, 0.0, 0.0, 0.0)
    replay(spinner, driver, [node], data[60:])
    spinner.spin_until(lambda: data[-1][0] in driver.estimates, 10.0, 'the last estimate')
    assert node.reinitializations['residual_too_large'] == 1
    values = values_of(node.status())
    assert values['reinitialized_residual_too_large'] == '1'
    assert values['resets_clock_jump'] == '1'
    for msg in driver.estimates.values():
        q = quaternion_from_msg(msg.quaternion)
        assert all(map(math.isfinite, q)) and abs(math.sqrt(sum(v * v for v in q)) - 1) < 0.1


def test_a_silent_imu_is_named_in_its_own_words_and_never_rounded_up(ros_context):
    from ext_observer.nodes.estimator_node_base import floor_text

    # 4.99997 s of silence is "4.99 s or more", never "5 s": the text states
    # no more than was measured.
    assert floor_text(4.99997) == '4.99'
    assert floor_text(2.0) == '2'
    node = ImuFilterNode(node_name='quiet', context=ros_context)
    try:
        texts = node._silent_texts({'increment': 4.99997, 'measurement': 0.0}, 2.0)
        assert texts == {'increment': 'no IMU samples on /imu/data_raw for 4.99 s or more'}
        assert node._silent_texts({'increment': 1.99, 'measurement': 0.0}, 2.0) == {}
    finally:
        node.destroy_node()


def test_lost_samples_go_warn_with_their_share_once_and_back_to_ok(
        ros_processes, ros_context, spinner):
    # The shipped executable; 100 Hz stamps published in real time: 2 s with
    # every 20th sample missing (5 %), a hole of 25 samples, then 3 s whole
    # (longer than the 2 s window).
    process = ros_processes([installed('imu_filter_node'), '--ros-args', '-p',
                             'diagnostic_period:=0.2', '-p', 'use_mag:=false'])
    driver = spinner.add(Driver(ros_context))
    statuses = []
    driver.create_subscription(
        DiagnosticArray, '/diagnostics', lambda msg: statuses.extend(
            st for st in msg.status if st.name == 'imu_filter: inputs'), 10)
    spinner.spin_until(lambda: driver.imu_publisher.get_subscription_count() == 1
                       and statuses, 20.0, 'imu_filter_node')
    k, missing = 0, 0

    def publish(count, skip=None):
        # At 100 Hz of the wall clock, the statuses taken between samples.
        nonlocal k, missing
        due = time.monotonic()
        for _ in range(count):
            if skip is not None and k % skip == skip - 1:
                missing += 1
            else:
                driver.send_imu(START + k * SECOND // 100, (0.0, 0.0, 0.1), (0.0, 0.0, 9.81))
            k += 1
            due += 0.01
            while time.monotonic() < due:
                spinner.executor.spin_once(timeout_sec=max(0.0, due - time.monotonic()))
    publish(250, skip=20)
    lossy = statuses[-1]
    k += 25
    missing += 25
    publish(50)
    holed = statuses[-1]
    publish(300)
    last = statuses[-1]
    values = values_of(lossy)
    assert lossy.level == DiagnosticStatus.WARN, lossy.message
    assert 'of the IMU samples lost over the last 2 s' in lossy.message
    # 5 % of what the window holds (its edges cut the pattern a little).
    assert 0.03 <= float(values['samples_lost_share']) <= 0.08
    assert float(values['sample_interval_s']) == 0.01
    # Stamps START on: far from the node clock, whose lag is reported as it is.
    assert float(values['lag_s']) > 1.0
    values = values_of(holed)
    assert holed.level == DiagnosticStatus.WARN, holed.message
    assert math.isclose(float(values['longest_hole_total_s']), 0.26)
    values = values_of(last)
    assert last.level == DiagnosticStatus.OK, last.message
    assert float(values['samples_lost_share']) == 0.0
    assert int(values['samples_lost']) >= missing
    assert int(values['samples_lost_queue']) >= 0
    # Once per episode in the log, with what to do.
    assert process.output.count('of the IMU samples lost over the last 2 s') == 1, \
        process.output
    assert 'IMU samples arriving whole again' in process.output
    assert 'raise queue_depth' in process.output
    # The stream's keys on the page.
    with open(os.path.join(REPO, 'docs', 'diagnostics.md'), encoding='utf-8') as page:
        text = page.read()
    keys = [key for key, _ in StreamWatch(ImuFilterNode, '').key_values()]
    assert set(keys) <= values.keys()
    assert [key for key in keys + ['undecodable_increment', 'undecodable_measurement']
            if f'`{key}`' not in text] == []


def test_a_magnet_taken_off_starts_the_calibration_over_and_says_so(ros_context, spinner):
    # A saved calibration of a pure offset (a magnet on the body), the body
    # turning about the vertical at 0.3 rad/s: the calibrated fields fit.
    # The offset gone (the magnet taken off), the fields fit as given: the
    # calibration starts over, ready at once ('converged', used as given),
    # and the status counts it (calibration_resets).
    bias = (1.5e-5, -1e-5, 0.8e-5)
    node = spinner.add(ImuFilterNode(
        node_name='magnet', context=ros_context, parameter_overrides=overrides(
            mag_bias_x=bias[0], mag_bias_y=bias[1], mag_bias_z=bias[2])))
    field = (0.0, 2.2e-5, -3.9e-5)  # T, north and down, dip about 60°
    rate, period = 0.3, SECOND // 100

    def turn(seconds, start, angle, offset):
        for k in range(seconds * 100):
            stamp = start + k * period
            angle += rate / 100
            c, s = math.cos(angle), math.sin(angle)
            body = (c * field[0] + s * field[1], -s * field[0] + c * field[1], field[2])
            node.pipeline.field(stamp, tuple(b + o for b, o in zip(body, offset)))
            node.pipeline.imu(stamp, (0.0, 0.0, rate), (0.0, 0.0, 9.81))
        return start + seconds * 100 * period, angle

    stamp, angle = turn(4, START, 0.0, bias)
    values = values_of(node.status())
    assert (values['calibration'], values['calibration_resets']) == ('loaded', '0')
    turn(4, stamp, angle, (0.0, 0.0, 0.0))
    values = values_of(node.status())
    assert (values['calibration'], values['calibration_resets']) == ('converged', '1')
