"""
The field step (core/ahrs/field_kernel.py), step by step (no ROS): fast known answers for mutmut.

What ``ahrs_update_mag`` keeps of the fields (the references' norm and
dip, the candidate of a new field, their times), what the heading does
while it waits for the calibration and when the calibration finds the
sensor calibrated, and what ``_calibrate`` hands the calibration at each of
its steps. Each expected value is computed here from the rule the
docstrings state (a first-order low-pass of gain ``1 − exp(−dt/τ)``,
VQF's candidate timer with its factor of two, Laidig & Seel 2023; the
world's vertical as ``R(q)ᵀ e_z``), not read from the code. Level, the
norm and dip of a field are those of the world's field whatever the
heading, so the scenarios set them exactly. Part of ``make mutation``'s
subset of the kernel (docs/tests.md#mutmut): the whole file takes about
a second on the plain kernels.
"""

import copy
import math

import numpy as np
import pytest

from ext_observer.core.ahrs import magcal_kernel
from ext_observer.core.ahrs.ahrs_filters import UNIFORM_ANGLE_VARIANCE, rotate
from ext_observer.core.ahrs.field_kernel import (CLIP_HEADING_SHARE, FIELD_CORRELATION,
                                                FIELD_GATE, FIELD_HEADING_BIAS,
                                                FIELD_HEADING_NOISE, HEADING_LOST, _doubt_gain,
                                                _sideways_tilt, _turn_heading, ahrs_update_mag,
                                                field_back, field_clipped, field_doubt)
from ext_observer.core.ahrs.bias_kernel import bias_measure
from ext_observer.core.ahrs.ahrs_observer import AhrsObserver, AhrsParams
from ext_observer.core.ahrs.ahrs_state import STATE
from ext_observer.core.ahrs.magcal_layout import CAL
from ext_observer.core.quaternion import conjugate, multiply, quaternion_from_rotation_vector

DT = 0.01
LEVEL = (0.0, 0.0, 9.81)
STILL = (0.0, 0.0, 0.0)
NORM, DIP = 4.5e-5, math.radians(-60.0)


def record(est):
    """The estimate's state record, its fields by attribute (plain, or a view of the compiled)."""
    holder = est.state
    return holder.view(np.recarray)[0] if isinstance(holder, np.ndarray) else holder[0]


def calibration(est):
    """The calibration's record in the estimate's state (``cal``), plain or compiled."""
    return record(est).cal


def snapshot(s):
    """A plain copy of a state record."""
    copied = STATE.plain()
    STATE.copy(s, copied)
    return copied


def world_field(norm, dip, heading=0.0):
    """A field of this norm and dip whose horizontal part points ``heading`` east of north."""
    h = norm * math.cos(dip)
    return np.array([h * math.sin(heading), h * math.cos(heading), norm * math.sin(dip)])


def body_field(field, yaw):
    """The world ``field`` seen by a level body turned ``yaw`` about the vertical."""
    c, s = math.cos(yaw), math.sin(yaw)
    return (c * field[0] + s * field[1], -s * field[0] + c * field[1], field[2])


def yaw_of(q):
    w, x, y, z = q
    # Level (after a clip or a hole, the field may tilt it a little).
    assert abs(x) < 1e-6 and abs(y) < 1e-6
    return 2.0 * math.atan2(z, w)


def wrap(a):
    return math.atan2(math.sin(a), math.cos(a))


def test_the_first_field_sets_the_references_and_the_candidate():
    est = AhrsObserver(AhrsParams(mag_cal=False), use_mag=True)
    est.update(STILL, LEVEL, body_field(world_field(NORM, DIP, 0.7), 0.0), DT)
    s = record(est)
    assert s.field.has_ref == 1.0
    assert list(s.field.ref) == pytest.approx([NORM, DIP], rel=1e-12)
    assert list(s.field.cand) == pytest.approx([NORM, DIP], rel=1e-12)


@pytest.mark.parametrize('change', ['norm', 'dip'])
def test_a_new_field_is_followed_by_its_candidate_and_accepted_after_mag_new_time(change):
    # Level, turning at 1 rad/s (above mag_new_gyr once the low-passed rate
    # is), mag_new_time 1 s. 2 s of the first field make the references old;
    # then a field 30 % stronger (or 20 deg steeper), drifting slowly within
    # the candidate's band: rejected; the candidate follows it as a
    # low-pass of tau_mag_ref, its time counts the turning samples, the
    # rejection time every rejected one; after mag_new_time the field is
    # accepted: the references are the candidate's, the rejection time 0.
    params = AhrsParams(mag_cal=False, mag_new_time=1.0)
    est = AhrsObserver(params, use_mag=True)
    s = record(est)
    kr = 1.0 - math.exp(-DT / params.tau_mag_ref)
    rate, yaw = 1.0, 0.0
    for _ in range(200):
        yaw += rate * DT
        est.update((0.0, 0.0, rate), LEVEL, body_field(world_field(NORM, DIP), yaw), DT)
    assert not est.mag_disturbed and s.field.ref_age > 1.0
    cand, cand_time, rejected, accepted = None, 0.0, 0.0, None
    for k in range(200):
        norm, dip = (1.3 * NORM * (1.0 + 1e-4 * k), DIP) if change == 'norm' else (
            NORM, DIP - math.radians(20.0) + 1e-4 * k)
        yaw += rate * DT
        est.update((0.0, 0.0, rate), LEVEL, body_field(world_field(norm, dip), yaw), DT)
        if cand is None:   # off the old candidate: it starts over here
            cand = np.array([norm, dip])
        else:
            cand += kr * (np.array([norm, dip]) - cand)
            cand_time += DT
        if est.mag_disturbed:
            rejected += DT
            assert list(s.field.cand) == pytest.approx(list(cand), rel=1e-9), k
            assert s.field.cand_time == pytest.approx(cand_time, abs=1e-9), k
            assert s.field.rejected == pytest.approx(rejected, abs=1e-9), k
            assert list(s.field.ref) == pytest.approx([NORM, DIP], rel=1e-9), k
        else:
            accepted = k
            break
    assert accepted in (100, 101)
    assert s.field.rejected == 0.0 and s.field.ref_rest == 0.0
    # The references are the candidate's, then follow this field as any used.
    ref = cand + kr * (np.array([norm, dip]) - cand)
    assert list(s.field.ref) == pytest.approx(list(ref), rel=1e-9)
    assert s.field.ref_age == pytest.approx(cand_time + DT, abs=1e-9)


def test_while_the_references_are_young_a_field_off_the_candidate_takes_back_twice_its_time():
    # Still 0.5 s, then turning with the first field: the references are
    # younger than mag_new_time (2 s) and no rest confirmed them. A field
    # 30 % stronger: off the candidate, each sample takes 2 dt from the
    # candidate's time (the candidate kept) until it is 0, then the
    # candidate is the new field, whose time counts up; it is accepted once
    # that time reaches the references' age (not mag_new_time). Back to
    # the first field, the rejection time decays by 2 dt a sample.
    params = AhrsParams(mag_cal=False, mag_new_time=2.0)
    est = AhrsObserver(params, use_mag=True)
    s = record(est)
    first = world_field(NORM, DIP)
    for _ in range(50):
        est.update(STILL, LEVEL, body_field(first, 0.0), DT)
    rate, yaw = 1.0, 0.0
    for _ in range(40):
        yaw += rate * DT
        est.update((0.0, 0.0, rate), LEVEL, body_field(first, yaw), DT)
    cand_time, age = s.field.cand_time, s.field.ref_age
    taken_back = math.ceil(cand_time / (2.0 * DT) - 1e-9)
    assert 0.1 < cand_time < age < 1.0 and s.field.ref_rest == 0.0
    strong = world_field(1.3 * NORM, DIP)
    n = 0
    while cand_time > 0.0:
        yaw += rate * DT
        est.update((0.0, 0.0, rate), LEVEL, body_field(strong, yaw), DT)
        cand_time = max(cand_time - 2.0 * DT, 0.0)
        n += 1
        assert s.field.cand_time == pytest.approx(cand_time, abs=1e-9), n
        assert est.mag_disturbed
        expected = [1.3 * NORM, DIP] if cand_time == 0.0 else [NORM, DIP]
        assert list(s.field.cand) == pytest.approx(expected, rel=1e-9), n
    assert n == taken_back
    assert s.field.ref_age == pytest.approx(age, abs=1e-12)   # fields not used do not age them
    steps = 0
    while est.mag_disturbed:
        yaw += rate * DT
        est.update((0.0, 0.0, rate), LEVEL, body_field(strong, yaw), DT)
        steps += 1
        assert steps < 200
    assert abs(steps * DT - age) <= 1.5 * DT
    rejected = s.field.rejected
    assert rejected == 0.0
    # A stretch of the old field (now rejected) then the new one again.
    for _ in range(30):
        yaw += rate * DT
        est.update((0.0, 0.0, rate), LEVEL, body_field(first, yaw), DT)
    assert s.field.rejected == pytest.approx(30 * DT, abs=1e-9)
    for k in range(1, 11):
        yaw += rate * DT
        est.update((0.0, 0.0, rate), LEVEL, body_field(strong, yaw), DT)
        assert s.field.rejected == pytest.approx((30 - 2 * k) * DT, abs=1e-9)


@pytest.mark.parametrize('waited', [1, 40])
def test_fields_waited_for_are_applied_when_the_calibration_finds_the_sensor_calibrated(waited):
    # 9D with the calibration, learning every 5 s (its steps stay out of the
    # way). Still, the first fields set the heading; turning, the body has
    # moved and the calibration is not ready: the fields wait. They point
    # 0.4 rad east of the heading: the heading does not follow them, but
    # the turn it would have had is kept (a running mean over all the
    # fields used, then k_mag). The calibration then says ready and not
    # applied (as it does when it finds the sensor calibrated: here set in
    # its block of the state, a converged calibration takes minutes): at the next
    # field the heading turns by the kept turn and corrects the rest of
    # the field's heading with the gain of all the fields used.
    params = AhrsParams(mag_cal_rate=0.2)
    est = AhrsObserver(params, use_mag=True)
    s = record(est)
    k_mag = 1.0 - math.exp(-DT / params.tau_mag)
    for _ in range(20):
        est.update(STILL, LEVEL, body_field(world_field(NORM, DIP), 0.0), DT)
    assert abs(yaw_of(est.q)) < 1e-12
    rate, yaw = 0.5, 0.0
    while s.cal_feed.moved == 0.0:
        yaw += rate * DT
        est.update((0.0, 0.0, rate), LEVEL, None, DT)
        assert yaw < 1.0
    assert calibration(est).ready == 0.0 and s.field.wait_n == 0.0
    used = s.field.mag_used
    assert used == 20.0
    turned = world_field(NORM, DIP, 0.4)
    turn = 0.0
    for k in range(waited):
        yaw += rate * DT
        q = est.update((0.0, 0.0, rate), LEVEL, body_field(turned, yaw), DT)
        assert yaw_of(q) == pytest.approx(wrap(yaw), abs=1e-9)    # not corrected
        kap = max(k_mag, 1.0 / (used + k + 1.0))
        turn += kap * (0.4 - turn)
        assert s.field.wait_n == k + 1.0
        assert s.field.wait_turn == pytest.approx(turn, abs=1e-12)
    assert s.field.mag_used == used
    calibration(est).ready = 1.0
    yaw += rate * DT
    since = s.cal_feed.since + DT
    q = est.update((0.0, 0.0, rate), LEVEL, body_field(turned, yaw), DT)
    total = used + waited + 1.0
    assert s.field.mag_used == total and s.field.wait_n == 0.0 and s.field.wait_turn == 0.0
    kap = max(k_mag, 1.0 / total, 1.0 - math.exp(-DT / max(1.0, 0.5 * since)))
    rest = 0.4 - turn
    correction = 2.0 * math.atan2(kap * math.sin(0.5 * rest),
                                  1.0 - kap + kap * math.cos(0.5 * rest))
    assert yaw_of(q) == pytest.approx(wrap(yaw + turn + correction), abs=1e-9)


def up_of(q):
    """The world's vertical in the body frame, ``R(q)ᵀ e_z``, from the rotation matrix."""
    w, x, y, z = np.asarray(q) / np.linalg.norm(q)
    r = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                  [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                  [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])
    return r.T @ np.array([0.0, 0.0, 1.0])


def test_each_calibration_step_hands_the_calibration_its_turn_time_rate_vertical_and_verdict():
    # 9D, a calibration loaded (so it is ready and its fields are checked
    # against the references), learning at 20 Hz (every 5th field). The
    # body turns about a tilted axis at a changing rate, tilted; every
    # third field of a calibration step is 40 % too strong. At each field
    # the kernel's calibration block is compared with one stepped here by
    # the calibration's own mc_learn, given what the kernel must hand it:
    # the gyro's rotation since the last step, the time since it, the
    # latest rate, the vertical R(q)ᵀ e_z, and whether the calibrated field
    # passes the references' norm and dip test. Between steps, nothing.
    params = AhrsParams(mag_cal_rate=20.0)
    # The plain kernels: their field step is called here on the state.
    est = AhrsObserver(params, use_mag=True, compiled=False)
    offset, soft = np.array([2e-5, -1e-5, 0.5e-5]), np.diag([1.1, 0.95, 1.0])
    est.load_calibration(tuple(offset), soft)
    s = record(est)
    field = world_field(NORM, DIP, 0.3)
    period = 1.0 / params.mag_cal_rate
    steps = refused = 0
    # Turned 2 rad about the vertical and rolled 0.4 rad: no component of
    # the attitude small, so a component read from the wrong slot shows.
    truth = np.array([math.cos(1.0) * math.cos(0.2), math.cos(1.0) * math.sin(0.2),
                      -math.sin(1.0) * math.sin(0.2), math.sin(1.0) * math.cos(0.2)])
    for k in range(240):
        rate = np.array([0.6 * math.sin(0.05 * k), 0.4 + 0.002 * k, -0.3])
        t = np.linalg.norm(rate) * DT
        w, v = truth[0], truth[1:]
        e = np.concatenate(([math.cos(0.5 * t)], math.sin(0.5 * t) / t * rate * DT))
        truth = np.concatenate(([w * e[0] - v @ e[1:]], w * e[1:] + e[0] * v + np.cross(v, e[1:])))
        est.update(tuple(rate), tuple(9.81 * up_of(truth)), None, DT)
        body = np.array(rotate(truth[0], -truth[1], -truth[2], -truth[3], *field))
        strong = steps % 3 == 2
        raw = soft @ (body * (1.4 if strong else 1.0)) + offset
        wait = s.cal_feed.wait + DT
        if wait >= period:
            # The kernel's attitude need not be unit (the extension term
            # pulls it back): the vertical is that of its rotation.
            for i in range(4):
                s.est.q[i] *= 1.03
        before = snapshot(s)
        ahrs_update_mag(s, *raw, DT)
        if wait < period:
            assert s.cal_feed.wait == pytest.approx(wait, abs=1e-15)
            assert CAL.flat(s.cal) == CAL.flat(before.cal)
            continue
        shadow = copy.deepcopy(before)
        c = np.array(magcal_kernel.mc_apply(shadow.cal, *raw))
        w = rotate(*before.est.q, *c)
        h = math.hypot(w[0], w[1])
        norm, dip = math.hypot(h, w[2]), math.atan2(w[2], h)
        ref_n, ref_d = before.field.ref[0], before.field.ref[1]
        # (the first field's step: no references yet, nothing to check)
        allow = before.field.has_ref == 0.0 or (abs(norm - ref_n) <= params.mag_norm_th * ref_n
                                             and abs(dip - ref_d) <= params.mag_dip_th)
        assert allow != strong, (k, norm / ref_n, dip - ref_d)
        magcal_kernel.mc_learn(shadow.cal, tuple(raw), tuple(before.cal_feed.turn),
                               wait, tuple(before.cal_feed.rate), 1.0,
                               tuple(up_of(before.est.q)), 1.0 if allow else 0.0)
        a, b = np.array(CAL.flat(s.cal)), np.array(CAL.flat(shadow.cal))
        assert len(a) == CAL.size
        bad = ~np.isclose(a, b, rtol=1e-9, atol=0.0)
        assert not bad.any(), (k, np.flatnonzero(bad), a[bad], b[bad])
        assert list(s.cal_feed.turn) == [1.0, 0.0, 0.0, 0.0]
        assert s.cal_feed.wait == 0.0
        steps += 1
        refused += strong
    assert steps in (47, 48) and refused == steps // 3
    assert s.cal.refused == refused and s.cal.used >= 30.0


def test_a_calibration_applied_while_running_restarts_the_references_from_its_field():
    # Level and still, a raw field with an offset: the references are the
    # raw field's norm and dip. A calibration loaded while running is
    # applied at the next field (a calibration step): the references and
    # the candidate are then the calibrated field's, the candidate's time
    # 0, the refinement's time restarts (one field's dt after that field)
    # and the heading's running mean is over (no mean: the refinement).
    est = AhrsObserver(AhrsParams(), use_mag=True)
    s = record(est)
    field = world_field(NORM, DIP, 0.5)
    offset = np.array([2e-5, -1.5e-5, 1e-5])
    raw = tuple(np.asarray(body_field(field, 0.0)) + offset)
    for _ in range(50):
        est.update(STILL, LEVEL, raw, DT)
    n_raw = float(np.linalg.norm(raw))
    assert s.field.ref[0] == pytest.approx(n_raw, rel=1e-9)
    est.load_calibration(tuple(offset), np.eye(3))
    est.update(STILL, LEVEL, raw, DT)
    assert list(s.field.ref) == pytest.approx([NORM, DIP], rel=1e-9)
    assert list(s.field.cand) == pytest.approx([NORM, DIP], rel=1e-9)
    assert s.field.cand_time == 0.0
    assert s.cal_feed.since == DT and s.field.mag_used == math.inf


def test_a_heading_turn_turns_the_estimate_and_its_low_passed_vertical_alike():
    # _turn_heading(r): q <- r ⊗ q for r = (rw, 0, 0, rz) of any norm, and
    # the acceleration's low-pass states (world frame, two of three
    # components each) turned by r's angle about the vertical, not scaled.
    est = AhrsObserver(AhrsParams(), use_mag=False)
    est.update(STILL, (1.2, -0.8, 9.7), None, DT)
    s = record(est)
    states = np.array([0.3, -0.2, 9.7, 0.1, 0.05, -0.4])
    s.inc.lp[:] = list(states)
    q0 = np.array(s.est.q, dtype=float)
    a = 0.7
    rw, rz = 0.9 * math.cos(0.5 * a), 0.9 * math.sin(0.5 * a)
    _turn_heading(s, rw, rz)
    w, x, y, z = q0
    assert list(s.est.q) == pytest.approx(
        [rw * w - rz * z, rw * x - rz * y, rw * y + rz * x, rw * z + rz * w], abs=1e-15)
    turn = np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])
    expected = np.concatenate([turn @ states[0:2], states[2:3], turn @ states[3:5],
                               states[5:6]])
    assert np.allclose(s.inc.lp, expected, rtol=0.0, atol=1e-14)


def test_in_motion_the_steady_heading_correction_teaches_the_bias_through_the_low_passed_vertical():
    # 9D without the calibration, tilted and turning (never at rest), a
    # gyro bias: the heading is corrected by each field. R(q)'s z row is
    # low-passed with k_mag at each field; once the heading's gain is the
    # steady k_mag (after 1/k_mag fields) and the start is over, each
    # correction is one measurement of the bias along that row: the rate
    # -2 rz / (rw dt) of the correction r = (rw, rz), of noise density
    # bias_r tau_mag / tau_acc (the bias filter's own update, tested in
    # test_bias_kernel.py). Before that (1/k_mag fields: 2 s; the start:
    # 2 tau_acc, 3 s, the later here), the field's step leaves the bias and
    # its covariance alone.
    params = AhrsParams(mag_cal=False, tau_mag=2.0, tau_acc=1.5)
    est = AhrsObserver(params, use_mag=True)
    s = record(est)
    k_mag = 1.0 - math.exp(-DT / params.tau_mag)
    field = world_field(NORM, DIP, 0.3)
    truth = np.array([math.cos(0.3), math.sin(0.3) * 0.6, math.sin(0.3) * 0.8, 0.0])
    bias = np.array([0.01, -0.02, 0.015])
    z_row = None
    learned = quiet = 0
    for k in range(600):
        rate = np.array([0.3 * math.sin(0.03 * k), 0.2 * math.cos(0.05 * k), 0.5])
        t = np.linalg.norm(rate) * DT
        e = np.concatenate(([math.cos(0.5 * t)], math.sin(0.5 * t) / t * rate * DT))
        w, v = truth[0], truth[1:]
        truth = np.concatenate(([w * e[0] - v @ e[1:]], w * e[1:] + e[0] * v + np.cross(v, e[1:])))
        est.update(tuple(rate + bias), tuple(9.81 * up_of(truth)), None, DT)
        if k == 0:   # the start: the low-passed row starts at R(q)'s
            assert np.allclose(s.bias.rz_lp, up_of(est.q), rtol=0.0, atol=1e-14)
        body = rotate(truth[0], -truth[1], -truth[2], -truth[3], *field)
        before = snapshot(s)
        ahrs_update_mag(s, *body, DT)
        q = np.array(s.est.q, dtype=float)
        row = up_of(q)      # R(q)'s z row is R(q)ᵀ e_z
        rz_lp = np.array(before.bias.rz_lp)
        z_row = rz_lp + k_mag * (row - rz_lp)
        assert np.allclose(s.bias.rz_lp, z_row, rtol=0.0, atol=1e-12), k
        used = before.field.mag_used + 1.0
        kap = max(k_mag, 1.0 / used)
        steady = (kap == k_mag and used * k_mag > 1.0 and before.rest.detected == 0.0
                  and before.inc.start >= 2.0 * params.tau_acc)
        shadow = copy.deepcopy(before)
        if steady:
            h = rotate(*before.est.q, *body)
            psi = math.atan2(h[0], h[1])
            rw, rz = 1.0 - kap + kap * math.cos(0.5 * psi), kap * math.sin(0.5 * psi)
            bias_measure(shadow, *z_row, -2.0 * rz / (rw * DT),
                         before.coef.bias_r * params.tau_mag / (params.tau_acc * DT))
            learned += 1
        else:
            quiet += 1
        assert np.allclose(s.bias.rate, shadow.bias.rate, rtol=1e-9,
                           atol=1e-15), k
        assert np.allclose(s.bias.p, shadow.bias.p, rtol=1e-9,
                           atol=0.0), k
    assert learned > 250 and quiet > 250


# --- after a clipped gyro or a hole ----------------------------------------------------

RANGE = math.radians(250.0)


def test_the_calibration_learns_nothing_from_a_clipped_stretch():
    # A body turning about the vertical past the gyro's range for 0.3 s:
    # the calibration sees no field of those samples (its field count
    # stands), and learns again once the gyro is back in range.
    est = AhrsObserver(AhrsParams(gyro_range=RANGE, mag_cal_rate=1e4), use_mag=True,
                       compiled=False)
    field = world_field(NORM, DIP)
    yaw = 0.0

    def step(rate):
        nonlocal yaw
        yaw += rate * DT
        est.update((0.0, 0.0, max(-RANGE, min(RANGE, rate))), LEVEL, body_field(field, yaw), DT)

    for _ in range(100):
        step(0.5)
    before = calibration(est).fields
    assert before > 0.0
    for _ in range(30):
        step(1.5 * RANGE)
    assert est.clipped == 30
    assert calibration(est).fields == before
    for _ in range(10):
        step(0.5)
    assert calibration(est).fields > before


def test_a_clip_keeps_the_fields_the_calibration_refused_and_a_hole_forgets_them():
    # A calibration that no longer fits starts over once most fields are
    # refused while the body turns. A clipped sample restarts its filter (the
    # turn across the stretch is unknown) but the fields went on being judged:
    # the refused share stands. A hole's restart counts afresh.
    est = AhrsObserver(AhrsParams(gyro_range=RANGE, mag_cal_rate=1e4), use_mag=True,
                       compiled=False)
    field = world_field(NORM, DIP)
    yaw = 0.0

    def step(rate, dt=DT):
        nonlocal yaw
        yaw += rate * dt
        est.update((0.0, 0.0, max(-RANGE, min(RANGE, rate))), LEVEL, body_field(field, yaw), dt)

    for _ in range(100):
        step(0.5)
    est.set_field('cal.refused_share', 0.6)
    step(1.5 * RANGE)
    for _ in range(10):  # the filter starts again from what it learned
        step(0.5)
    assert est.clipped == 1
    assert est.field('cal.refused_share') == pytest.approx(0.6, abs=0.02)
    step(0.5, 0.3)  # a hole whose turn the calibration cannot trust
    for _ in range(10):
        step(0.5)
    assert est.holes == 1
    assert est.field('cal.refused_share') < 0.02


def test_after_a_short_clip_the_heading_is_not_taken_afresh_from_a_bent_field():
    # A level body turning at 0.5 rad/s past the gyro's range for 0.1 s
    # (it loses about 5°), then for 1 s a field bent 30° in heading that
    # the norm and dip tests cannot see (a magnet passing by). The clip's
    # doubt (σ about 5°) weighs the fields with its Kalman gain and keeps
    # them within its gate: the heading stays near its loss and the field
    # takes the loss back once it is straight again, where taking the heading
    # afresh from the fields after the clip followed the bend to 30°.
    est = AhrsObserver(AhrsParams(mag_cal=False, gyro_range=RANGE), use_mag=True,
                       compiled=False)
    straight = world_field(NORM, DIP)
    bent = world_field(NORM, DIP, math.radians(30.0))
    yaw = 0.0

    def step(rate, field=straight):
        nonlocal yaw
        yaw += rate * DT
        est.update((0.0, 0.0, max(-RANGE, min(RANGE, rate))), LEVEL, body_field(field, yaw), DT)
        return abs(wrap(yaw_of(est.q) - yaw))

    for _ in range(300):
        step(0.0)
    for _ in range(500):
        step(0.5)
    for _ in range(10):
        step(1.2 * RANGE)
    assert est.clipped == 10
    assert record(est).field.head_doubt > math.radians(3.0) ** 2
    during = max(step(0.5, bent) for _ in range(100))
    assert during < math.radians(10.0)
    for _ in range(200):
        after = step(0.5)
    assert after < math.radians(3.0)


def test_after_a_hole_the_heading_comes_back_from_the_field_as_its_doubt_allows():
    # A level body at rest, the field fixed; a 0.45 s hole hides a turn of
    # 16° (40 °/s for 0.4 s) that the bridge between two still samples
    # cannot see. The hole's variance (σ ≈ 6°) lets the field take most of
    # the error back within 2 s, where tau_mag's gain alone gives back 12 %.
    est = AhrsObserver(AhrsParams(mag_cal=False), use_mag=True, compiled=False)
    field = world_field(NORM, DIP)
    for _ in range(300):
        est.update(STILL, LEVEL, body_field(field, 0.0), DT)
    turn = math.radians(40.0) * 0.4
    est.update(STILL, LEVEL, body_field(field, turn), 0.45)
    assert est.holes == 1
    doubt = record(est).field.head_doubt
    assert doubt > math.radians(4.0) ** 2
    lost = abs(wrap(yaw_of(est.q) - turn))
    assert lost > math.radians(12.0)
    for _ in range(200):
        est.update(STILL, LEVEL, body_field(field, turn), DT)
    assert abs(wrap(yaw_of(est.q) - turn)) < 0.4 * lost
    assert record(est).field.head_doubt < 0.5 * doubt


def _tilted_about_east(angle):
    """A level estimate tilted ``angle`` about the world's east axis (across a north field)."""
    est = AhrsObserver(AhrsParams(mag_cal=False), use_mag=True, compiled=False)
    for _ in range(20):
        est.update(STILL, LEVEL, body_field(world_field(NORM, DIP), 0.0), DT)
    s = record(est)
    s.inc.start = 2.0 * s.par.tau_acc  # the low-pass settled: the doubt is inc.sigma
    half = 0.5 * angle
    w, x, y, z = (float(v) for v in s.est.q)
    # q <- (cos, sin e_x) ⊗ q: the world's east axis
    s.est.q[0], s.est.q[1], s.est.q[2], s.est.q[3] = multiply(
        np.array([math.cos(half), math.sin(half), 0.0, 0.0]), np.array([w, x, y, z]))
    return est, s


def test_the_dip_gate_widens_with_the_inclinations_doubt():
    # Tilted 15° about east, a level body's field shows its dip 15° off the
    # reference: beyond mag_dip_th (10°), disturbed while the inclination is
    # sure, and within √(th² + (FIELD_GATE σ)²) while it is unsure by σ = 5°.
    for sigma, disturbed in ((0.0, 1.0), (math.radians(5.0), 0.0)):
        est, s = _tilted_about_east(math.radians(15.0))
        s.inc.sigma = sigma
        ahrs_update_mag(s, *world_field(NORM, DIP), DT)
        assert s.field.mag_dist == disturbed
    assert FIELD_GATE * 5.0 > math.sqrt(15.0 ** 2 - 10.0 ** 2)


def test_the_fields_dip_corrects_the_tilt_across_it_by_the_kalman_gain_of_the_doubt():
    # Tilted 8° about east with the inclination unsure by σ = 10°: one field
    # turns the estimate back about east by k · 8°, k = P / (P + r) with
    # P = σ² and r the field direction's variance, the heading's noise and
    # shared error over the field's interval times cos²(dip); the heading and
    # the doubt stay (the field says nothing of the tilt along it).
    tilt, sigma = math.radians(8.0), math.radians(10.0)
    est, s = _tilted_about_east(tilt)
    s.inc.sigma = sigma
    before = tuple(float(v) for v in s.est.q)
    # The body is level: its field is the world's, its dip seen 8° off.
    ahrs_update_mag(s, *world_field(NORM, DIP), DT)
    r = ((FIELD_HEADING_NOISE ** 2 + FIELD_HEADING_BIAS ** 2 * FIELD_CORRELATION)
         * math.cos(DIP) ** 2 / DT)
    k = sigma ** 2 / (sigma ** 2 + r)
    after = np.array([float(v) for v in s.est.q])
    turn = multiply(after, conjugate(np.array(before)))  # the world-frame rotation applied
    assert 2.0 * math.atan2(turn[1], turn[0]) == pytest.approx(-k * tilt, rel=2e-3)
    assert abs(turn[2]) < 1e-12 and abs(turn[3]) < 1e-12
    assert s.inc.sigma == sigma


def test_a_fields_sideways_error_is_shared_by_heading_and_tilt_as_their_doubts_say():
    # A field 10° off north, the heading's doubt FIELD_HEADING_BIAS², the
    # tilt's 10°: the heading takes w = h² P_h / (h² P_h + v² P_t) of the
    # field's gain κ, a turn about north the rest of the sideways part
    # (tan b = −h sin ψ / v); while the fields' running mean sets the
    # heading, its doubt is a uniform heading's.
    est = AhrsObserver(AhrsParams(mag_cal=False), use_mag=True, compiled=False)
    for _ in range(20):
        est.update(STILL, LEVEL, body_field(world_field(NORM, DIP), 0.0), DT)
    s = record(est)
    s.field.mag_used = 1e6  # the running mean long over
    kap, psi, tilt = 0.01, math.radians(10.0), math.radians(10.0)
    h2, v2 = math.cos(DIP) ** 2, math.sin(DIP) ** 2
    ph = FIELD_HEADING_BIAS ** 2
    w = h2 * ph / (h2 * ph + v2 * tilt ** 2)
    before = np.array([float(v) for v in s.est.q])
    assert _sideways_tilt(s, tilt, kap, psi) == pytest.approx(w * kap, rel=1e-9)
    turn = multiply(np.array([float(v) for v in s.est.q]), conjugate(before))
    b = (1.0 - w) * kap * math.atan(-math.cos(DIP) * math.sin(psi) / math.sin(DIP))
    assert 2.0 * math.atan2(turn[2], turn[0]) == pytest.approx(b, rel=1e-9)
    assert abs(turn[1]) < 1e-12 and abs(turn[3]) < 1e-12
    s.field.mag_used = 3.0
    wu = h2 * UNIFORM_ANGLE_VARIANCE / (h2 * UNIFORM_ANGLE_VARIANCE + v2 * tilt ** 2)
    assert _sideways_tilt(s, tilt, kap, psi) == pytest.approx(wu * kap, rel=1e-9)
    assert w < 0.1 < 0.9 < wu


def _rotation(q, v):
    """Rows of ``v`` in the frame ``q`` maps to the world: ``R(q)ᵀ v`` (world → body)."""
    return rotate(*conjugate(q), *v)


def _clipped_spin(use_mag, spin=6.0, seconds=3.0, after=1.5, shake=4.0):
    """
    The inclination error (rad) of each sample after a clipped spin of a shaken body.

    5 s still, ``seconds`` of a spin at ``spin`` rad/s about a tilted axis
    (clipped at ±250 °/s), then a slow wobble; a horizontal acceleration of
    ``shake`` m/s² (1.5 and 1.1 Hz) from the spin on, so that the
    accelerometer shows the vertical poorly.
    """
    axis = np.array([1.0, 0.6, 0.3]) / math.sqrt(1.45)
    est = AhrsObserver(AhrsParams(gyro_range=RANGE, mag_cal=False), use_mag=use_mag,
                       compiled=False)
    field = world_field(NORM, DIP)
    q = np.array([1.0, 0.0, 0.0, 0.0])
    still, spinning, total = int(5.0 / DT), int(seconds / DT), int((5.0 + seconds + after) / DT)
    errors = []
    for k in range(total):
        t = k * DT
        if k < still:
            rate = np.zeros(3)
        elif k < still + spinning:
            rate = spin * axis
        else:
            rate = 0.6 * np.array([math.sin(2.1 * t), math.cos(1.3 * t),
                                   0.5 * math.sin(0.7 * t)])
        q = multiply(q, quaternion_from_rotation_vector(rate * DT))
        moved = k >= still
        a = shake * np.array([math.sin(3.0 * math.pi * t), math.cos(2.2 * math.pi * t), 0.0])
        acc = _rotation(q, (a if moved else np.zeros(3)) + np.array(LEVEL))
        est.update(tuple(np.clip(rate, -RANGE, RANGE)), acc,
                   _rotation(q, field) if use_mag else None, DT)
        if k >= still + spinning:
            e = multiply(np.array(est.q) / np.linalg.norm(est.q), conjugate(q))
            errors.append(2.0 * math.acos(min(math.hypot(e[0], e[3]), 1.0)))
    return np.array(errors)


def test_after_a_clipped_spin_the_fields_dip_brings_the_inclination_back():
    # 3 s at 344 °/s past a ±250 °/s range leave the inclination about 10°
    # off; the shaken body's accelerometer takes over a second to correct it
    # (6D). In 9D the field's dip corrects the tilt across the field at the
    # Kalman gain of the inclination's doubt: the second after the spin
    # under 70 % of 6D's RMS.
    six, nine = (_clipped_spin(use_mag) for use_mag in (False, True))
    assert np.degrees(six[0]) > 5.0  # the spin did leave the inclination off
    first = slice(0, int(1.0 / DT))
    rms6 = math.degrees(math.sqrt(np.mean(six[first] ** 2)))
    rms9 = math.degrees(math.sqrt(np.mean(nine[first] ** 2)))
    assert rms9 < 0.7 * rms6, (rms6, rms9)


def test_the_gyros_losses_add_up_as_the_fields_doubt_until_the_heading_is_lost():
    # Each loss adds its variance to the heading's doubt and to its tilt
    # share; the loss that takes the doubt to HEADING_LOST clears both and
    # the heading starts again from the running mean of the next fields.
    est = AhrsObserver(AhrsParams(mag_cal=False), use_mag=True, compiled=False)
    for _ in range(20):
        est.update(STILL, LEVEL, body_field(world_field(NORM, DIP), 0.0), DT)
    s = record(est)
    assert s.field.head_doubt == 0.0 and s.field.tilt_doubt == 0.0 and s.field.mag_used == 20.0
    field_doubt(s, 0.25 * HEADING_LOST)
    field_doubt(s, 0.5 * HEADING_LOST)
    assert s.field.head_doubt == pytest.approx(0.75 * HEADING_LOST, rel=1e-12)
    assert s.field.tilt_doubt == pytest.approx(0.75 * HEADING_LOST, rel=1e-12)
    field_doubt(s, 0.25 * HEADING_LOST)
    assert (s.field.head_doubt, s.field.tilt_doubt, s.field.mag_used) == (0.0, 0.0, 0.0)


@pytest.mark.parametrize('vertical', [1.0, 0.25, 0.0])
def test_a_clipped_stretchs_losses_add_up_in_the_heading_doubts_sigma(vertical):
    # Along a clipped stretch the rate stays beyond the range: each sample
    # adds CLIP_HEADING_SHARE of the σ of its part about the vertical to the
    # doubt's σ (not its variance to the variance), and of all of it to the
    # tilt share's σ, until the heading is lost. ``vertical``: the share of
    # the clipped variance about the world's vertical (gyro.clipped_vertical).
    est = AhrsObserver(AhrsParams(mag_cal=False), use_mag=True, compiled=False)
    for _ in range(20):
        est.update(STILL, LEVEL, body_field(world_field(NORM, DIP), 0.0), DT)
    s = record(est)
    var = (RANGE * DT) ** 2
    s.gyro.clipped_vertical = vertical * var
    for n in range(1, 4):
        field_clipped(s, var)
        sigma = n * CLIP_HEADING_SHARE * RANGE * DT
        assert s.field.head_doubt == pytest.approx(vertical * sigma * sigma, rel=1e-12)
        assert s.field.tilt_doubt == pytest.approx(sigma * sigma, rel=1e-12)
    assert s.field.field_clipped == 1.0 and s.field.mag_used == 20.0
    if vertical == 0.0:
        return  # the heading is never lost
    while s.field.mag_used != 0.0:
        field_clipped(s, var)
    assert s.field.head_doubt == 0.0 and s.field.tilt_doubt == 0.0


def test_a_clipped_axis_is_the_headings_by_its_vertical_component():
    # gyro.clipped_vertical: each clipped axis's (range dt)² times the square
    # of its component along the world's vertical (R(q̂)ᵀ e_z); the range is
    # the largest rate seen (1.2 × RANGE here). Level: z all of it, x none;
    # rolled 90° about x: y all of it; rolled 60°: the vertical in the body
    # is (0, sin 60°, cos 60°), y and z together all of it, y alone 3/4.
    est = AhrsObserver(AhrsParams(mag_cal=False, gyro_range=RANGE), use_mag=True,
                       compiled=False)
    for _ in range(20):
        est.update(STILL, LEVEL, body_field(world_field(NORM, DIP), 0.0), DT)
    s = record(est)
    top2 = (1.2 * RANGE * DT) ** 2
    for angle, rate, share in ((0.0, (0.0, 0.0, 1.2 * RANGE), 1.0),
                               (0.0, (1.2 * RANGE, 0.0, 0.0), 0.0),
                               (90.0, (0.0, 1.2 * RANGE, 0.0), 1.0),
                               (60.0, (0.0, 1.2 * RANGE, 1.2 * RANGE), 1.0),
                               (60.0, (0.0, 1.2 * RANGE, 0.0), 0.75)):
        half = 0.5 * math.radians(angle)
        for i, v in enumerate((math.cos(half), math.sin(half), 0.0, 0.0)):
            s.est.q[i] = v
        est.update(rate, LEVEL, None, DT)
        clipped = sum(abs(r) > 0 for r in rate)
        assert s.gyro.clipped == pytest.approx(clipped * top2, rel=1e-12), (angle, rate)
        assert s.gyro.clipped_vertical == pytest.approx(share * top2, rel=1e-6), (angle, rate)


def test_a_field_does_not_end_the_doubt_while_a_clipped_stretch_still_adds_to_it():
    # A doubt small enough that an undisturbed field's gain is the usual one
    # ends at that field, but not while the gyro's clipped stretch is still
    # running (gyro.clip_left): its per-sample losses must add up.
    est = AhrsObserver(AhrsParams(mag_cal=False), use_mag=True, compiled=False)
    for _ in range(20):
        est.update(STILL, LEVEL, body_field(world_field(NORM, DIP), 0.0), DT)
    s = record(est)
    ref_norm, ref_dip = s.field.ref[0], s.field.ref[1]
    for clip_left, ends in ((0.5, False), (0.0, True)):
        s.field.head_doubt = 1e-12
        s.gyro.clip_left = clip_left
        _doubt_gain(s, s.coef.k_mag, ref_norm, ref_dip, 0.0, DT)
        assert (s.field.head_doubt == 0.0) == ends


def test_the_tilts_doubt_is_forgotten_at_the_inclinations_pace():
    # T <- T exp(-2 dt / (tau_acc + tau_acc_gain)) at each field, also one
    # whose norm is off the references (its gain then the usual one).
    est = AhrsObserver(AhrsParams(mag_cal=False), use_mag=True, compiled=False)
    for _ in range(20):
        est.update(STILL, LEVEL, body_field(world_field(NORM, DIP), 0.0), DT)
    s = record(est)
    s.field.head_doubt = s.field.tilt_doubt = 0.01
    dt = 0.05
    assert _doubt_gain(s, 0.125, 2.0 * NORM, DIP, 0.0, dt) == 0.125
    tau = s.par.tau_acc + s.par.tau_acc_gain
    assert s.field.tilt_doubt == pytest.approx(0.01 * math.exp(-2.0 * dt / tau), rel=1e-12)


def test_a_field_back_after_a_loss_doubts_the_heading_not_the_tilt_and_keeps_what_was_learned():
    # The variance the gyro alone added is the heading's doubt (the tilt's
    # none); the references and the calibration stay, the calibration
    # follows the field afresh; past HEADING_LOST the heading is taken
    # afresh from the next fields; in 6D nothing happens.
    est = AhrsObserver(AhrsParams(), use_mag=True, compiled=False)
    for _ in range(20):
        est.update(STILL, LEVEL, body_field(world_field(NORM, DIP), 0.0), DT)
    s = record(est)
    ref = (s.field.ref[0], s.field.ref[1])
    field_back(s, 0.0)
    assert s.field.head_doubt == 0.0 and s.cal.fresh == 0.0
    field_back(s, 0.25 * HEADING_LOST)
    field_back(s, 0.5 * HEADING_LOST)
    assert s.field.head_doubt == pytest.approx(0.75 * HEADING_LOST, rel=1e-12)
    assert s.field.tilt_doubt == 0.0 and s.field.mag_used == 20.0
    assert (s.field.ref[0], s.field.ref[1]) == ref and s.field.has_ref == 1.0
    assert s.cal.fresh == 1.0 and s.cal_feed.wait == math.inf
    field_back(s, 0.25 * HEADING_LOST)
    assert (s.field.head_doubt, s.field.mag_used) == (0.0, 0.0)
    six = AhrsObserver(AhrsParams(mag_cal=False), use_mag=False, compiled=False)
    six.update(STILL, LEVEL, None, DT)
    field_back(record(six), 0.1)
    assert record(six).field.head_doubt == 0.0


def test_a_field_off_the_references_does_not_end_the_doubt():
    # Its own r is large (its deviation over cos²(dip)), so its Kalman gain
    # is small; the doubt ends only where an undisturbed field's gain would
    # be the usual one: P / (P + r_u) <= k_mag.
    est = AhrsObserver(AhrsParams(mag_cal=False), use_mag=True, compiled=False)
    for _ in range(20):
        est.update(STILL, LEVEL, body_field(world_field(NORM, DIP), 0.0), DT)
    s = record(est)
    k_mag = s.coef.k_mag
    ru = FIELD_HEADING_NOISE ** 2 / DT + FIELD_HEADING_BIAS ** 2 / DT
    p = 3.0 * ru * k_mag
    s.field.head_doubt = p
    dip = DIP + math.radians(9.0)  # off by less than mag_dip_th
    k = _doubt_gain(s, k_mag, NORM, dip, 0.0, DT)
    assert k == k_mag  # its own gain is below the usual one
    assert s.field.head_doubt > 0.5 * p  # kept: P ← (1 − k)² P + k² r, not ended
    s.field.head_doubt = 0.5 * ru * k_mag
    _doubt_gain(s, k_mag, NORM, DIP, 0.0, DT)
    assert s.field.head_doubt == 0.0


def _turning_with(est, field, offset, seconds, yaw, rate=0.5, scale=1.0):
    """Turn the level body at ``rate`` about the vertical, fed ``scale`` × the field plus ``offset``."""
    for _ in range(round(seconds / DT)):
        yaw += rate * DT
        raw = np.asarray(body_field(field * scale, yaw)) + offset
        est.update((0.0, 0.0, rate), LEVEL, tuple(raw), DT)
        if calibration(est).resets:
            break
    return yaw


@pytest.mark.parametrize('case', ['taken off', 'kept, bent from outside', 'taken off, still'])
def test_a_magnet_taken_off_is_told_by_the_fields_fitting_as_given(case):
    # A calibration with an offset applied (loaded), the body turning. The
    # magnet taken off: the calibrated fields are refused, the fields as
    # given fit the references. Their share, low-passed over
    # FIELD_CORRELATION while the body turns, passes CAL_REFUSED_SHARE after
    # −ln(0.3) = 1.2 s: the calibration starts over from none (a reset),
    # ready at once and not applied, so the heading takes the fields as
    # given and stays right. Kept on, a field bent from outside fits as
    # given no more than calibrated; a still body tells nothing.
    est = AhrsObserver(AhrsParams(), use_mag=True, compiled=False)
    field = world_field(NORM, DIP, 0.0)
    offset = np.array([1.5e-5, -1e-5, 0.8e-5])
    est.load_calibration(tuple(offset), np.eye(3))
    yaw = _turning_with(est, field, offset, 3.0, 0.0)
    cal = calibration(est)
    assert (cal.applied, cal.resets, record(est).cal_feed.as_given) == (1.0, 0.0, 0.0)
    if case == 'taken off':
        start = yaw
        yaw = _turning_with(est, field, 0.0 * offset, 3.0, yaw)
        after = (yaw - start) / 0.5
        assert 1.1 < after < 1.5
        assert (cal.resets, cal.applied, cal.ready, cal.loaded) == (1.0, 0.0, 1.0, 0.0)
        assert est.calibration_state == 'converged'
        yaw = _turning_with(est, field, 0.0 * offset, 2.0, yaw)
        assert abs(wrap(yaw_of(est.q) - yaw)) < math.radians(2.0)
        assert cal.resets == 1.0 and cal.applied == 0.0
    elif case == 'kept, bent from outside':
        _turning_with(est, field, offset, 5.0, yaw, scale=1.3)
        assert cal.resets == 0.0 and cal.applied == 1.0
        assert record(est).cal_feed.as_given == 0.0
    else:
        _turning_with(est, field, 0.0 * offset, 5.0, yaw, rate=0.0)
        assert cal.resets == 0.0 and cal.applied == 1.0
