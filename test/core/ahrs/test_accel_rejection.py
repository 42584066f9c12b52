"""
Acceleration rejection: a long turn without a velocity, and a steady turn that is not rest.

The core on a simulated level turn without odometry (the low-passed specific
force tilted for as long as the turn lasts): rejected, the estimate stays
near level, also long past ``acc_reject_time`` (the force turns with the
body: not gravity); off, it tilts; a force that does not turn with the body
is trusted again after ``acc_reject_time``. The rest detection does not take
a steady turn's yaw rate for a bias. Plain and compiled agree to the bit.
No ROS.
"""

import math

import numpy as np
import pytest

from ext_observer.core.ahrs import compiled as compiled_module
from ext_observer.core.ahrs.ahrs_params import AhrsParams
from ext_observer.core.ahrs import accel_rejection as ar
from ext_observer.core.ahrs.ahrs_observer import AhrsObserver
from ext_observer.core.ahrs.ahrs_state import STATE
from ext_observer.core.ahrs.clip_and_rest import detect_rest

G = 9.81
RATE = 100.0
SPEED = 15.0  # m/s

needs_numba = pytest.mark.skipif(not compiled_module.compiled_available(),
                                 reason='numba is not installed')


def _turn(yaw_rate, seconds=30.0, still=10.0, speed=SPEED):
    """A level vehicle at ``speed``: still (the bias learned at rest), then a constant turn."""
    t = np.arange(int((still + seconds) * RATE)) / RATE
    rate = np.where(t >= still, yaw_rate, 0.0)
    zero = np.zeros_like(t)  # body x forward, z up; the specific force is ω × v and g
    return (np.column_stack((zero, zero, rate)),
            np.column_stack((zero, rate * speed, np.full_like(t, G))))


def _accelerating(acceleration, seconds, still=10.0):
    """A level vehicle still, then speeding up straight ahead at ``acceleration`` (m/s²)."""
    t = np.arange(int((still + seconds) * RATE)) / RATE
    zero = np.zeros_like(t)
    return (np.column_stack((zero, zero, zero)),
            np.column_stack((np.where(t >= still, acceleration, 0.0), zero,
                             np.full_like(t, G))))


def _run(gyr, acc, params=None, compiled=False, watch=None):
    """The estimates per sample, and ``watch(core)`` (a list of state values) after each."""
    core = AhrsObserver(params, use_mag=False, compiled=compiled)
    out, seen = [], []
    for k in range(len(gyr)):
        out.append(core.update(gyr[k], acc[k], None, 1.0 / RATE))
        if watch is not None:
            seen.append(watch(core))
    return np.array(out), np.array(seen)


def _tilt_deg(q):
    w, x, y, z = np.asarray(q).T
    return np.degrees(np.arccos(np.clip(w * w - x * x - y * y + z * z, -1.0, 1.0)))


def test_a_long_turn_without_a_velocity_is_rejected_and_stays_near_level():
    gyr, acc = _turn(0.3)  # 0.46 g: the apparent gravity 24.6° off the vertical
    held, seen = _run(gyr, acc, watch=lambda core: [core.field('rej.time')])
    off, _ = _run(gyr, acc, AhrsParams(acc_reject=0.0))
    assert _tilt_deg(held).max() < 3.0  # at most about acc_reject before it begins
    assert _tilt_deg(held)[-1000:].mean() < 1.0
    assert _tilt_deg(off)[-1000:].mean() > 10.0
    assert seen[-1, 0] > 25.0  # rejected since the turn began


def test_a_turn_that_lasts_is_rejected_for_as_long_as_it_lasts():
    # 8 m/s at 0.5 rad/s (0.41 g): the apparent gravity 22° off the vertical,
    # its low-pass still 15° off, for twice acc_reject_time (shortened, for speed).
    gyr, acc = _turn(0.5, seconds=40.0, speed=8.0)
    q, seen = _run(gyr, acc, AhrsParams(acc_reject_time=20.0),
                   watch=lambda core: [core.state[0].rej.time, core.state[0].rej.turned])
    tilt = _tilt_deg(q)
    assert tilt.max() < 3.5  # at most about acc_reject before it begins
    assert tilt[-int(20.0 * RATE):].max() < 1.0
    assert seen[-1, 0] > 38.0  # rejected since the turn began, and still
    assert seen[-1, 0] - seen[-1, 1] < 5.0  # all but its first seconds held by the turn


def test_after_the_longest_rejection_a_force_that_does_not_turn_is_gravity_again():
    gyr, acc = _accelerating(2.0, 20.0)  # 0.2 g straight ahead: nothing turns
    q, seen = _run(gyr, acc, AhrsParams(acc_reject_time=12.0),
                   watch=lambda core: [core.state[0].rej.time, core.state[0].rej.turned])
    tilt = _tilt_deg(q)
    assert tilt[-100:].mean() > 10.0
    assert 11.0 < seen[:, 0].max() <= 12.0 + 1.0 / RATE
    assert seen[:, 1].max() == 0.0


def test_a_tilted_vertical_in_a_spin_is_no_turn_and_the_force_is_gravity_again():
    # A body spinning in place about the vertical at 0.5 rad/s, gravity its only
    # force, the gyro's vertical put 6° off: the force's deviation from it is
    # fixed in the world, not in the body (no turn), and after acc_reject_time
    # the force is gravity again.
    n = int(20.0 * RATE)
    gyr = np.tile((0.0, 0.0, 0.5), (n, 1))
    acc = np.tile((0.0, 0.0, G), (n, 1))
    core = AhrsObserver(AhrsParams(acc_reject_time=12.0), use_mag=False, compiled=False)
    still = int(5.0 * RATE)
    for k in range(still):
        core.update((0.0, 0.0, 0.0), acc[k], None, 1.0 / RATE)
    s = core.state[0]
    s.rej.carried[:] = [math.sin(math.radians(6.0)), 0.0, math.cos(math.radians(6.0))]
    times, turned = [], []
    for k in range(n):
        core.update(gyr[k], acc[k], None, 1.0 / RATE)
        times.append(s.rej.time)
        turned.append(s.rej.turned)
    assert 11.0 < max(times) <= 12.0 + 1.0 / RATE
    assert max(turned) < 0.5
    assert _tilt_deg([core.q])[0] < 1.0


def test_a_steady_turn_faster_than_bias_max_is_not_rest():
    # A bias grown to bias_max (2 °/s) along z, a steady yaw rate of 3.7 °/s:
    # within rest_gyr of the bias, but no bias can be that large.
    core = AhrsObserver(use_mag=False, compiled=False)
    core.update((0.0, 0.0, 0.0), (0.0, 0.0, G), None, 1.0 / RATE)
    s = core.state[0]
    s.bias.rate[2] = AhrsParams().bias_max
    for _ in range(int(3.0 * RATE)):
        s.rest.acc_still = 1.0
        detect_rest(s, 0.0, 0.0, 0.065)
    assert s.rest.detected == 0.0
    assert s.bias.rate[2] == AhrsParams().bias_max
    for _ in range(int(3.0 * RATE)):  # a rate a bias can be, steady: rest
        detect_rest(s, 0.0, 0.0, 0.5 * AhrsParams().bias_max)
    assert s.rest.detected == 1.0


def _steered(yaw_rate, slope_deg, cruise=15.0, ramp=2.0, hold=10.0):
    """
    A vehicle cruising straight on a road sloping sideways (rest, to an IMU),
    then steering into a turn over ``ramp`` s (body z: the road's normal).
    """
    t = np.arange(int((cruise + ramp + hold) * RATE)) / RATE
    rate = yaw_rate * np.clip((t - cruise) / ramp, 0.0, 1.0)
    c, s = math.cos(math.radians(slope_deg)), math.sin(math.radians(slope_deg))
    zero = np.zeros_like(t)
    return (np.column_stack((zero, zero, rate)),
            np.column_stack((zero, rate * SPEED + G * s, np.full_like(t, G * c))))


def test_a_rate_ramping_into_a_turn_is_not_learned_as_a_bias():
    # Steering slowly into a 0.1 g turn: the rate leads its low-pass by under
    # rest_gyr, and a bias following it (to bias_max) would tilt a sloped road.
    gyr, acc = _steered(0.065, 5.0)
    _, seen = _run(gyr, acc, watch=lambda core: [core.field('bias.rate')[2],
                                                 core.field('rest.detected')])
    cruise = int(15.0 * RATE)
    assert seen[cruise - 1, 1] == 1.0  # cruising straight is rest
    assert abs(seen[-1, 0]) < math.radians(0.5)
    assert seen[cruise + int(2.0 * RATE):, 1].max() == 0.0


@needs_numba
def test_plain_and_compiled_agree_to_the_bit_through_a_rejection_and_its_end():
    # A turn (held past acc_reject_time), then speeding up straight (not held).
    turn_gyr, turn_acc = _turn(0.3, seconds=15.0)
    straight_gyr, straight_acc = _accelerating(2.0, 15.0, still=2.0)
    gyr, acc = np.vstack((turn_gyr, straight_gyr)), np.vstack((turn_acc, straight_acc))
    params = AhrsParams(acc_reject_time=12.0)
    plain, _ = _run(gyr, acc, params)
    compiled, _ = _run(gyr, acc, params, compiled=True)
    assert np.array_equal(plain, compiled)


# Known answers of the step's helpers, on a plain record (fast, for mutmut).

def test_the_angle_between_two_vectors_of_any_norm():
    rng = np.random.default_rng(3)
    for _ in range(20):
        a, b = rng.normal(size=3) * 3.0, rng.normal(size=3) * 0.2
        expected = math.acos(np.dot(a, b) / np.linalg.norm(a) / np.linalg.norm(b))
        assert ar._angle(*a, *b) == pytest.approx(expected, abs=1e-12)
    assert ar._angle(0.0, 0.0, 2.0, 0.0, 3.0, 0.0) == pytest.approx(math.pi / 2)


def test_the_tilting_rate_is_the_horizontal_part_of_the_rate_less_the_bias():
    s = STATE.plain()
    s.par.tau_acc = 1.5
    s.est.q[:] = [math.cos(0.3), math.sin(0.3), 0.0, 0.0]  # rolled 0.6 rad about x
    s.rest.gyr_lp[:] = [0.4, 0.7, 1.1]
    s.bias.rate[:] = [0.05, -0.1, 0.2]
    s.rej.tilt = 0.25
    r = np.array([0.35, 0.8, 0.9])  # the low-passed rate less the bias, body frame
    c, sn = math.cos(0.6), math.sin(0.6)
    w = np.array([[1.0, 0.0, 0.0], [0.0, c, -sn], [0.0, sn, c]]) @ r  # in the world frame
    dt = 0.01
    k = dt / (2.0 * 1.5 + dt)
    expected = 0.25 + k * (math.hypot(w[0], w[1]) - 0.25)
    world = ar._world_rate(s)
    assert world == pytest.approx(tuple(w), rel=1e-12)
    assert ar._tilting(s, world[0], world[1], dt) == pytest.approx(expected, rel=1e-12)
    assert s.rej.tilt == pytest.approx(expected, rel=1e-12)


def test_a_reset_forgets_the_carried_vertical_the_rejection_and_the_tilt():
    s = STATE.plain()
    s.rej.carried[:] = [0.1, 0.2, 0.9]
    s.rej.dev[:] = [0.1, -0.2, 0.0]
    s.rej.path[:] = [1.0, 2.0, 3.0, 4.0, 5.0, 6.0]
    s.rej.time, s.rej.tilt, s.rej.turned = 0.7, 0.3, 0.5
    s.rej.follow, s.rej.predicted = 0.2, 0.4
    ar.acc_rejection_reset(s)
    assert list(s.rej.carried) == [0.0, 0.0, 0.0] and s.rej.time == 0.0 and s.rej.tilt == 0.0
    assert list(s.rej.dev) == [0.0] * 3 and list(s.rej.path) == [0.0] * 6
    assert s.rej.turned == 0.0 and s.rej.follow == 0.0 and s.rej.predicted == 0.0


def _deviation_state(d):
    s = STATE.plain()
    s.par.tau_acc = 2.0
    s.bias.p[:] = [1e-8, 0.0, 0.0, 1e-8, 0.0, 1e-8]
    s.rej.dev[:] = d
    return s


@pytest.mark.parametrize('fixed_in, turns', [('body', True), ('world', False)])
def test_a_deviation_turns_with_the_body_only_if_the_gyro_turns_it(fixed_in, turns):
    d, w, dt = np.array([0.2, 0.1, 0.0]), np.array([0.0, 0.0, 0.5]), 0.01
    s = _deviation_state(d)
    s.rej.follow, s.rej.predicted = 0.01, 0.02
    c, sn = math.cos(0.5 * dt), math.sin(0.5 * dt)
    h = np.array([[c, -sn, 0.0], [sn, c, 0.0], [0.0, 0.0, 1.0]]) @ d if fixed_in == 'body' else d
    p = np.cross(w, h)  # the rate of a deviation fixed in the body
    k = dt / (2.0 + dt)
    assert bool(ar._turns_with_body(s, *h, *w, dt)) is turns
    assert s.rej.follow == pytest.approx(0.01 + k * (np.dot((h - d) / dt, p) - 0.01), rel=1e-12)
    assert s.rej.predicted == pytest.approx(0.02 + k * (np.dot(p, p) - 0.02), rel=1e-12)


def test_a_deviation_along_the_rotation_axis_is_no_turn():
    d = np.array([0.0, 0.0, 0.2])  # along ω: gravity would look the same
    s = _deviation_state(d)
    assert not ar._turns_with_body(s, *d, 0.0, 0.0, 0.5, 0.01)
    assert s.rej.predicted == 0.0


def test_the_bias_carries_u_by_its_sigma_times_the_time_unless_the_body_turns():
    s = STATE.plain()
    sigma = 0.002
    s.bias.p[:] = [0.5 * sigma ** 2, 0.0, 0.0, sigma ** 2, 0.0, 0.25 * sigma ** 2]
    s.est.q[:] = [math.cos(0.2), 0.0, math.sin(0.2), 0.0]  # pitched: R's rows not the axes
    for _ in range(50):
        ar._path_step(s, 0.1)
    assert ar._carried_off(s) == pytest.approx(sigma * 5.0, rel=1e-12)
    # A full turn about the vertical at 0.5 rad/s, level: the path comes back to nothing.
    ar._rejection_starts(s)
    steps = 1000
    dt = 2.0 * math.pi / 0.5 / steps
    for k in range(steps):
        a = 0.5 * (k + 0.5) * dt
        s.est.q[:] = [math.cos(0.5 * a), 0.0, 0.0, math.sin(0.5 * a)]
        ar._path_step(s, dt)
    assert ar._carried_off(s) < 1e-3 * sigma * steps * dt


def test_a_force_rejected_too_long_becomes_the_vertical_it_shows():
    s = STATE.plain()
    s.par.acc_reject, s.par.acc_reject_time, s.par.tau_acc = 0.1, 20.0, 2.0
    s.coef.k_acc = 0.0  # no correction: u moves only towards the force
    s.bias.p[:] = [1e-12, 0.0, 0.0, 1e-12, 0.0, 1e-12]  # a bias sure enough to carry u
    s.rej.carried[:] = [0.0, 0.0, 1.0]
    s.est.q[:] = [1.0, 0.0, 0.0, 0.0]
    f = (0.0, 3.0, 9.3)  # 0.31 rad off the vertical: rejected
    ar.acc_rotation(s, *f, 0.5, False)
    assert s.rej.time == 0.5 and list(s.rej.carried)[:2] == [0.0, 0.0]
    s.rej.time = 19.99
    ar.acc_rotation(s, *f, 0.02, False)  # 20.01 s > acc_reject_time: taken as gravity
    # u is the force's direction, then one step (k = dt / 10 s, no tilting) towards the vertical.
    n, k = math.hypot(3.0, 9.3), 0.02 / 10.0
    uy, uz = (1.0 - k) * 3.0 / n, 9.3 / n + k * (1.0 - 9.3 / n)
    assert s.rej.time == 0.0 and s.rej.carried[0] == 0.0
    assert list(s.rej.carried)[1:] == pytest.approx([uy / math.hypot(uy, uz),
                                                     uz / math.hypot(uy, uz)], rel=1e-12)
