"""
The velocity aid: the body's own acceleration removed from the specific force.

A known answer for the kernel's step (a constant turn: with the velocity the
corrected specific force is gravity; a stale velocity leaves it as measured),
the core on a simulated turn (level with the velocity, tilted without; a
velocity given long ago is bit for bit no velocity; plain and compiled agree
to the bit), and the batch API (``attitude_from_imu``'s ``velocity`` and
``velocity_times``). No ROS.
"""

import copy
import math

import numpy as np
import pytest

from ext_observer import attitude_from_imu
from ext_observer.core.ahrs import compiled as compiled_module
from ext_observer.core.ahrs import velocity_kernel as vk
from ext_observer.core.ahrs.ahrs_params import AhrsParams
from ext_observer.core.ahrs.ahrs_observer import AhrsObserver
from ext_observer.core.ahrs.ahrs_state import STATE

G = 9.81
RATE = 100.0
SPEED = 15.0  # m/s
YAW_RATE = 0.3  # rad/s: 0.46 g centripetal at SPEED

needs_numba = pytest.mark.skipif(not compiled_module.compiled_available(),
                                 reason='numba is not installed')


def _turn(seconds=40.0, straight=10.0):
    """A level vehicle at SPEED: straight, then a constant turn; body x forward, z up."""
    n = int((straight + seconds) * RATE)
    t = np.arange(n) / RATE
    rate = np.where(t >= straight, YAW_RATE, 0.0)
    gyr = np.zeros((n, 3))
    gyr[:, 2] = rate
    acc = np.zeros((n, 3))
    acc[:, 1] = rate * SPEED  # ω × v
    acc[:, 2] = G
    velocity = np.tile((SPEED, 0.0, 0.0), (n, 1))
    return t, gyr, acc, velocity


def _tilt_deg(q):
    """Inclination of each estimate (the body's z from the vertical), degrees."""
    w, x, y, z = np.asarray(q).T
    return np.degrees(np.arccos(np.clip(w * w - x * x - y * y + z * z, -1.0, 1.0)))


def test_in_a_constant_turn_the_corrected_specific_force_is_gravity_and_stale_is_as_measured():
    s = AhrsObserver(use_mag=False, compiled=False).state[0]
    dt = 1.0 / RATE
    vk.velocity_sample(s, SPEED, 0.0, 0.0, -1.0)
    assert vk.velocity_step(s, 0.0, 0.0, YAW_RATE, dt) == 0.0  # no derivative yet
    vk.velocity_sample(s, SPEED, 0.0, 0.0, dt)
    assert vk.velocity_step(s, 0.0, 0.0, YAW_RATE, dt) == 1.0
    assert vk.velocity_removed(s, 0.0, YAW_RATE * SPEED, G) == (0.0, 0.0, G)
    # Accelerating at 2 m/s² along x: dv/dt joins ω × v.
    vk.velocity_sample(s, SPEED + 2.0 * dt, 0.0, 0.0, dt)
    vk.velocity_step(s, 0.0, 0.0, YAW_RATE, dt)
    fx, fy, fz = vk.velocity_removed(s, 2.0, YAW_RATE * (SPEED + 2.0 * dt), G)
    assert fx == pytest.approx(0.0, abs=1e-9) and fy == pytest.approx(0.0, abs=1e-12)
    assert fz == G
    # Older than the timeout: the specific force as measured, not in use.
    for _ in range(int(vk.VELOCITY_TIMEOUT / dt) + 1):
        vk.velocity_step(s, 0.0, 0.0, YAW_RATE, dt)
    assert s.vel.used == 0.0
    assert vk.velocity_removed(s, 0.0, YAW_RATE * SPEED, G) == (0.0, YAW_RATE * SPEED, G)


def _run(gyr, acc, velocity=None, compiled=False, given=None, params=None):
    """The core per sample; ``velocity`` at the samples ``given`` (default: every one)."""
    core = AhrsObserver(params, use_mag=False, compiled=compiled)
    dt = 1.0 / RATE
    out, last = [], None
    for k in range(len(gyr)):
        if velocity is not None and (given is None or k in given):
            core.velocity(velocity[k], None if last is None else (k - last) * dt)
            last = k
        out.append(core.update(gyr[k], acc[k], None, dt))
    return np.array(out)


def test_the_core_stays_level_in_a_long_turn_with_the_velocity_and_tilts_without():
    _, gyr, acc, velocity = _turn()
    aided = _tilt_deg(_run(gyr, acc, velocity))
    # (Without acceleration rejection, which keeps it near level: test_accel_rejection.py.)
    plain = _tilt_deg(_run(gyr, acc, params=AhrsParams(acc_reject=0.0)))
    assert aided.max() < 0.01
    assert plain[-1000:].mean() > 10.0


def test_a_stale_velocity_steps_as_no_velocity_to_the_bit():
    _, gyr, acc, velocity = _turn(seconds=5.0, straight=0.0)
    dt = 1.0 / RATE
    core = AhrsObserver(use_mag=False, compiled=False)
    none = AhrsObserver(use_mag=False, compiled=False)
    core.velocity(velocity[0])
    core.velocity(velocity[1], dt)
    fresh = int(vk.VELOCITY_TIMEOUT * RATE) - 1  # the timeout's last step: rounding's
    for k in range(fresh):
        aided = core.update(gyr[k], acc[k], None, dt)
        assert core.velocity_used
        assert aided != none.update(gyr[k], acc[k], None, dt)
    # Once stale: each step is the one a core that never had a velocity takes.
    core.update(gyr[fresh], acc[fresh], None, dt)
    fresh += 1
    core.update(gyr[fresh], acc[fresh], None, dt)
    assert not core.velocity_used
    twin = copy.deepcopy(core)
    twin.state[0].vel.n = 0.0  # no velocity ever
    for k in range(fresh + 1, len(gyr)):
        assert core.update(gyr[k], acc[k], None, dt) == twin.update(gyr[k], acc[k], None, dt)
    # A single velocity has no derivative: not used, the estimate as without one.
    once = AhrsObserver(use_mag=False, compiled=False)
    once.velocity(velocity[0])
    base = AhrsObserver(use_mag=False, compiled=False)
    for k in range(200):
        assert once.update(gyr[k], acc[k], None, dt) == base.update(gyr[k], acc[k], None, dt)


@needs_numba
def test_plain_and_compiled_agree_to_the_bit_with_the_velocity():
    _, gyr, acc, velocity = _turn(seconds=10.0, straight=2.0)
    given = set(range(0, len(gyr), 5)) - set(range(300, 500))  # 20 Hz, with a 2 s gap
    plain = _run(gyr, acc, velocity, compiled=False, given=given)
    compiled = _run(gyr, acc, velocity, compiled=True, given=given)
    assert np.array_equal(plain, compiled)


@pytest.mark.parametrize('at_own_times', [False, True])
def test_attitude_from_imu_takes_a_velocity_per_sample_or_at_its_own_times(at_own_times):
    t, gyr, acc, velocity = _turn(seconds=20.0)
    without = attitude_from_imu(gyr, acc, rate=RATE,  # acceleration rejection off
                                parameters={'use_mag': False, 'ahrs.acc_reject': 0.0})
    if at_own_times:  # odometry at 20 Hz, on the IMU's clock
        extra = {'velocity': velocity[::5], 'velocity_times': t[::5]}
    else:
        extra = {'velocity': velocity}
    aided = attitude_from_imu(gyr, acc, rate=RATE, parameters={'use_mag': False}, **extra)
    assert _tilt_deg(aided.quaternions).max() < 0.05
    assert _tilt_deg(without.quaternions)[-500:].mean() > 10.0


def test_attitude_from_imu_refuses_a_velocity_it_cannot_place():
    _, gyr, acc, velocity = _turn(seconds=1.0, straight=1.0)
    with pytest.raises(ValueError, match='velocity_times'):
        attitude_from_imu(gyr, acc, rate=RATE, velocity=velocity[:-1])
    with pytest.raises(ValueError, match='without velocity'):
        attitude_from_imu(gyr, acc, rate=RATE, velocity_times=np.arange(3.0))


def test_a_velocity_in_the_vehicles_frame_with_the_imus_mounting_and_lever_arm():
    # The IMU turned 90° about the vehicle's z and 1.5 m ahead, 0.5 m left of
    # its reference point: in a turn it feels ω × v and ω × (ω × r), in its axes.
    t, _, _, velocity = _turn(seconds=20.0)
    arm = np.array((1.5, 0.5, 0.0))
    ramp = 2.0  # s into the turn: ω̇ × r finite
    gyr_v = np.zeros((len(t), 3))
    gyr_v[:, 2] = YAW_RATE * np.clip((t - 10.0) / ramp, 0.0, 1.0)
    w, w_dot = gyr_v, np.gradient(gyr_v, axis=0) * RATE
    acc_v = (np.cross(w, velocity) + np.cross(w_dot, arm) + np.cross(w, np.cross(w, arm))
             + (0.0, 0.0, G))
    half = math.radians(90.0) / 2.0
    mounting = [math.cos(half), 0.0, 0.0, math.sin(half)]
    to_imu = np.array(((0.0, 1.0, 0.0), (-1.0, 0.0, 0.0), (0.0, 0.0, 1.0)))  # R^T
    gyr, acc = gyr_v @ to_imu.T, acc_v @ to_imu.T
    frame = {'use_mag': False, 'velocity_mounting': mounting,
             'velocity_lever_arm': arm.tolist()}
    aided = attitude_from_imu(gyr, acc, rate=RATE, parameters=frame, velocity=velocity)
    assert _tilt_deg(aided.quaternions).max() < 0.1
    wrong = attitude_from_imu(gyr, acc, rate=RATE, parameters={'use_mag': False},
                              velocity=velocity)
    assert _tilt_deg(wrong.quaternions)[-500:].mean() > 10.0
    with pytest.raises(ValueError, match='velocity_mounting'):
        attitude_from_imu(gyr, acc, rate=RATE, velocity=velocity,
                          parameters={'velocity_mounting': [1.0, 1.0, 0.0, 0.0]})


def test_a_csv_with_velocity_columns_runs_aided(tmp_path):
    # Odometry at 20 Hz in the same file: vel_* empty on the other lines.
    from ext_observer.recordings.csvio import main as csv_main, read_columns, read_velocity
    t, gyr, acc, velocity = _turn(seconds=20.0)
    rows = ['t,gyr_x,gyr_y,gyr_z,acc_x,acc_y,acc_z,vel_x,vel_y,vel_z']
    t = t.tolist()
    for k in range(len(t)):
        vel = ','.join(map(repr, velocity[k].tolist())) if k % 5 == 0 else ',,'
        rows.append(','.join(map(repr, [t[k], *gyr[k].tolist(), *acc[k].tolist()])) + ',' + vel)
    path = tmp_path / 'drive.csv'
    path.write_text('\n'.join(rows) + '\n')
    times, read = read_velocity(str(path))
    np.testing.assert_array_equal(times, t[::5])  # t as written
    np.testing.assert_array_equal(read, velocity[::5])
    out = tmp_path / 'out.csv'
    assert csv_main([str(path), '--out', str(out), '--no-mag']) == 0
    columns = read_columns(str(out), ('qw', 'qx', 'qy', 'qz'))
    q = np.column_stack([columns[name] for name in ('qw', 'qx', 'qy', 'qz')])
    assert _tilt_deg(q).max() < 0.05
    # Without the columns (and without rejection) the same drive tilts.
    plain = tmp_path / 'plain.csv'
    plain.write_text('\n'.join(row.rsplit(',', 3)[0] for row in rows) + '\n')
    assert read_velocity(str(plain)) == (None, None)
    params = tmp_path / 'off.yaml'
    params.write_text('imu_filter_node:\n  ros__parameters:\n    ahrs:\n      acc_reject: 0.0\n')
    assert csv_main([str(plain), '--out', str(out), '--no-mag', '--params', str(params)]) == 0
    columns = read_columns(str(out), ('qw', 'qx', 'qy', 'qz'))
    q = np.column_stack([columns[name] for name in ('qw', 'qx', 'qy', 'qz')])
    assert _tilt_deg(q)[-500:].mean() > 10.0
    # A line with part of a velocity is refused, naming it.
    rows[3] = rows[3].rsplit(',', 3)[0] + ',1.0,,'
    path.write_text('\n'.join(rows) + '\n')
    with pytest.raises(ValueError, match=r't = 0\.02: a velocity with only some'):
        read_velocity(str(path))


@pytest.mark.parametrize('msgtype', ['nav_msgs/msg/Odometry', 'geometry_msgs/msg/TwistStamped'])
def test_a_bag_with_a_velocity_topic_runs_aided(tmp_path, msgtype):
    # The turn as a bag: the IMU at 100 Hz, the velocity at 20 Hz on its own topic.
    from rosbags.typesys import get_typestore, Stores
    from ext_observer.recordings import bag_io, cdr
    from ext_observer.recordings.bag import main as bag_main, run_bag
    store = get_typestore(Stores.ROS2_JAZZY)
    t, gyr, acc, velocity = _turn(seconds=20.0)
    writer = bag_io.BagWriter(str(tmp_path / 'in'), 'mcap',
                              [('/imu/data_raw', cdr.IMU_TYPE, []), ('/wheels', msgtype, [])])
    imu, wheels = writer.ids
    Header, Time = store.types['std_msgs/msg/Header'], store.types['builtin_interfaces/msg/Time']
    Vector3 = store.types['geometry_msgs/msg/Vector3']
    for k in range(len(t)):
        stamp = 10 ** 9 + k * 10 ** 7
        if k % 5 == 0:
            header = Header(stamp=Time(sec=stamp // 10 ** 9, nanosec=stamp % 10 ** 9),
                            frame_id='imu')
            twist = store.types['geometry_msgs/msg/Twist'](
                linear=Vector3(*velocity[k].tolist()), angular=Vector3(0.0, 0.0, 0.0))
            if msgtype.endswith('Odometry'):
                msg = store.types[msgtype](
                    header=header, child_frame_id='imu',
                    pose=store.types['geometry_msgs/msg/PoseWithCovariance'](
                        pose=store.types['geometry_msgs/msg/Pose'](
                            position=store.types['geometry_msgs/msg/Point'](0.0, 0.0, 0.0),
                            orientation=store.types['geometry_msgs/msg/Quaternion'](
                                0.0, 0.0, 0.0, 1.0)),
                        covariance=np.zeros(36)),
                    twist=store.types['geometry_msgs/msg/TwistWithCovariance'](
                        twist=twist, covariance=np.zeros(36)))
            else:
                msg = store.types[msgtype](header=header, twist=twist)
            if k == 1000:  # a bad one: dropped and counted, never in an estimate
                twist.linear.x = math.nan
            writer.write(wheels, stamp, bytes(store.serialize_cdr(msg, msgtype)))
        writer.write(imu, stamp + 1, cdr.encode_imu(stamp, 'imu', gyr[k].tolist(),
                                                   acc[k].tolist()))
    writer.close()
    run = run_bag(str(tmp_path / 'in'), str(tmp_path / 'out'), velocity_topic='wheels',
                  parameters={'use_mag': False})
    assert run.topics['velocity'][2] == len(t[::5])  # copied to the new bag too
    assert run.velocity_drops == {'not_finite': 1}
    assert np.isfinite(run.recording.quaternions).all()
    assert _tilt_deg(run.recording.quaternions[1:]).max() < 0.05
    assert run.recording.in_state('velocity_aided')[-500:].all()
    plain = run_bag(str(tmp_path / 'in'), None, parameters={'use_mag': False,
                                                            'ahrs.acc_reject': 0.0})
    assert _tilt_deg(plain.recording.quaternions[-500:]).mean() > 10.0
    # The command: a topic of another type is refused, naming it.
    assert bag_main([str(tmp_path / 'in'), '--out', str(tmp_path / 'o2'), '--no-mag',
                     '--velocity-topic', 'imu/data_raw']) == 2


# Known answers of the kernel's three functions, on a plain record (fast,
# for mutmut): every field each writes, per axis with values that differ.

def _record(timeout=0.5):
    s = STATE.plain()
    s.par.velocity_timeout = timeout
    s.rest.acc_still = 1.0
    s.bias.rate[:] = [0.01, -0.02, 0.03]
    return s


def test_a_velocity_sample_keeps_its_derivative_over_its_own_interval():
    s = _record()
    vk.velocity_sample(s, 1.0, 2.0, 3.0, -1.0)  # the first: no derivative yet
    assert (s.vel.n, list(s.vel.v), list(s.vel.dv), s.vel.age) == (1.0, [1.0, 2.0, 3.0],
                                                                   [0.0, 0.0, 0.0], 0.0)
    s.vel.age = 0.3
    vk.velocity_sample(s, 1.5, 1.0, 3.25, 0.25)
    assert s.vel.n == 2.0 and s.vel.age == 0.0 and list(s.vel.v) == [1.5, 1.0, 3.25]
    assert list(s.vel.dv) == [2.0, -4.0, 1.0]
    # At the timeout it is still a derivative; beyond it, or without an interval, none.
    vk.velocity_sample(s, 2.0, 1.0, 3.25, 0.5)
    assert s.vel.n == 2.0 and list(s.vel.dv) == [1.0, 0.0, 0.0]
    for dt in (0.5000001, 0.0, -0.1):
        before = list(s.vel.dv)
        vk.velocity_sample(s, 3.0, 1.0, 3.25, dt)
        assert s.vel.n == 1.0 and list(s.vel.dv) == before, dt
        s.vel.n = 2.0


def test_a_fresh_velocity_gives_its_kinematic_acceleration_per_axis():
    s = _record()
    vk.velocity_sample(s, 2.0, -1.0, 0.5, -1.0)
    vk.velocity_sample(s, 2.5, -1.5, 1.0, 0.25)  # dv = (2, -2, 2)
    g = (0.31, -0.52, 0.73)
    assert vk.velocity_step(s, *g, 0.01) == 1.0
    wx, wy, wz = g[0] - 0.01, g[1] + 0.02, g[2] - 0.03
    vx, vy, vz = 2.5, -1.5, 1.0
    expected = [2.0 + wy * vz - wz * vy, -2.0 + wz * vx - wx * vz, 2.0 + wx * vy - wy * vx]
    assert list(s.vel.acc) == expected
    assert s.vel.used == 1.0 and s.vel.age == 0.01
    assert s.rest.acc_still == 0.0  # a moving body is not at rest
    assert vk.velocity_removed(s, 1.0, 2.0, 9.0) == (1.0 - expected[0], 2.0 - expected[1],
                                                     9.0 - expected[2])


def test_a_slow_velocity_leaves_rest_alone_and_an_old_one_is_not_used():
    s = _record(timeout=0.1)
    vk.velocity_sample(s, 0.05, 0.0, 0.05, -1.0)
    vk.velocity_sample(s, 0.05, 0.05, 0.0, 0.05)  # |v| 0.07 m/s: below MOVING_SPEED
    assert vk.velocity_step(s, 0.0, 0.0, 0.0, 0.06) == 1.0 and s.rest.acc_still == 1.0
    assert vk.velocity_step(s, 0.0, 0.0, 0.0, 0.04) == 1.0  # aged to the timeout: used
    assert vk.velocity_step(s, 0.0, 0.0, 0.0, 0.01) == 0.0  # beyond it: not
    assert s.vel.used == 0.0 and s.vel.age == pytest.approx(0.11)
    assert vk.velocity_removed(s, 1.0, 2.0, 3.0) == (1.0, 2.0, 3.0)


def test_without_a_derivative_or_a_velocity_nothing_is_removed():
    s = _record()
    assert vk.velocity_step(s, 1.0, 1.0, 1.0, 0.01) == 0.0  # never a velocity
    assert s.vel.age == 0.0 and s.vel.used == 0.0  # untouched: the state as without the aid
    vk.velocity_sample(s, 5.0, 0.0, 0.0, -1.0)
    s.vel.used = 1.0
    assert vk.velocity_step(s, 1.0, 1.0, 1.0, 0.01) == 0.0  # one velocity: no derivative yet
    assert s.vel.used == 0.0 and s.vel.age == 0.01 and s.rest.acc_still == 1.0
