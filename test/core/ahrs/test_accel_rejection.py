"""
Acceleration rejection: a long turn without a velocity, and a steady turn that is not rest.

The core on a simulated level turn without odometry (the low-passed specific
force tilted for tens of seconds): rejected, the estimate stays near level;
off, it tilts; after ``acc_reject_time`` the force is trusted again. The rest
detection does not take a steady turn's yaw rate for a bias. Plain and
compiled agree to the bit. No ROS.
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


def _turn(yaw_rate, seconds=30.0, still=10.0):
    """A level vehicle at SPEED: still (the bias learned at rest), then a constant turn."""
    t = np.arange(int((still + seconds) * RATE)) / RATE
    rate = np.where(t >= still, yaw_rate, 0.0)
    zero = np.zeros_like(t)  # body x forward, z up; the specific force is ω × v and g
    return (np.column_stack((zero, zero, rate)),
            np.column_stack((zero, rate * SPEED, np.full_like(t, G))))


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


def test_after_the_longest_rejection_the_force_is_gravity_again():
    gyr, acc = _turn(0.3)
    q, seen = _run(gyr, acc, AhrsParams(acc_reject_time=5.0),
                   watch=lambda core: [core.field('rej.time')])
    tilt = _tilt_deg(q)
    assert tilt[-1000:].mean() > 10.0
    assert seen[:, 0].max() <= 5.0 + 1.0 / RATE


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
    gyr, acc = _turn(0.3, seconds=12.0)
    params = AhrsParams(acc_reject_time=5.0)
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
    assert ar._tilting(s, dt) == pytest.approx(expected, rel=1e-12)
    assert s.rej.tilt == pytest.approx(expected, rel=1e-12)


def test_a_reset_forgets_the_carried_vertical_the_rejection_and_the_tilt():
    s = STATE.plain()
    s.rej.carried[:] = [0.1, 0.2, 0.9]
    s.rej.time, s.rej.tilt = 0.7, 0.3
    ar.acc_rejection_reset(s)
    assert list(s.rej.carried) == [0.0, 0.0, 0.0] and s.rej.time == 0.0 and s.rej.tilt == 0.0


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
