"""
Known answers for the raw-IMU estimator's parameters (core/ahrs/ahrs_observer.py), no ROS.

Each test builds synthetic samples with a known truth (noise-free, or with a
seeded rng), runs :class:`AhrsObserver` on floats with explicit parameters,
and checks an answer that follows from what the parameter means: a time
constant is where an exponential has fallen to 1/e, a threshold separates a
signal just inside it from one just outside, a time is when a flag turns.
"""

import copy
import math

import numpy as np
import pytest

from ext_observer.core.ahrs.ahrs_observer import AhrsObserver, AhrsParams

G = 9.81
RATE = 100.0
DT = 1.0 / RATE
UP = (0.0, 0.0, G)
# An undisturbed field (any unit): 45 along north and 60° down, ENU.
DIP = math.radians(-60.0)
FIELD = (0.0, 45.0 * math.cos(DIP), 45.0 * math.sin(DIP))


# Quaternions (w, x, y, z) on Python floats, sensor -> ENU --------------------------

def qmul(a, b):
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return (aw * bw - ax * bx - ay * by - az * bz, aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx, aw * bz + ax * by - ay * bx + az * bw)


def qconj(q):
    return (q[0], -q[1], -q[2], -q[3])


def qexp(v):
    """The unit quaternion of the rotation vector ``v`` (rad)."""
    angle = math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
    if angle == 0.0:
        return (1.0, 0.0, 0.0, 0.0)
    s = math.sin(0.5 * angle) / angle
    return (math.cos(0.5 * angle), v[0] * s, v[1] * s, v[2] * s)


def normalize(q):
    n = math.sqrt(sum(v * v for v in q))
    return tuple(v / n for v in q)


def rotate(q, v):
    """``q v q̄`` for a unit ``q``: body coordinates to world ones."""
    return qmul(qmul(q, (0.0,) + tuple(v)), qconj(q))[1:]


def tilt_deg(estimate, truth):
    """Inclination error: the angle between the estimated and the true vertical."""
    a = rotate(qconj(normalize(estimate)), (0.0, 0.0, 1.0))
    b = rotate(qconj(truth), (0.0, 0.0, 1.0))
    return math.degrees(math.acos(max(-1.0, min(1.0, sum(x * y for x, y in zip(a, b))))))


def angle_deg(estimate, truth):
    """Total attitude error."""
    d = qmul(normalize(estimate), qconj(truth))
    return math.degrees(2.0 * math.acos(min(1.0, abs(d[0]))))


def rotated_field(axis, angle, scale=1.0):
    """FIELD turned by ``angle`` (rad) about a world ``axis``, times ``scale``."""
    return tuple(scale * v for v in rotate(qexp(tuple(angle * a for a in axis)), FIELD))


# Synthetic samples ----------------------------------------------------------------

def simulate(rates, q0=(1.0, 0.0, 0.0, 0.0), bias=(0.0, 0.0, 0.0), field=FIELD,
             acc_extra=None):
    """
    Truth and samples for body rates ``rates`` (N, 3), rad/s.

    The truth moves as the estimator propagates, ``q_k = q_{k-1} ⊗ exp(ω_k dt)``;
    sample ``k`` is the gyro (``ω_k`` plus ``bias``), the specific force (up,
    plus ``acc_extra(k)`` in the body frame) and the field (``field``, or
    ``field(k)``, world frame) seen at ``q_k``.
    """
    q = normalize(q0)
    truth, gyr, acc, mag = [], [], [], []
    for k, w in enumerate(rates):
        w = tuple(float(v) for v in w)
        if k:
            q = normalize(qmul(q, qexp((w[0] * DT, w[1] * DT, w[2] * DT))))
        truth.append(q)
        a = rotate(qconj(q), UP)
        if acc_extra is not None:
            a = tuple(x + y for x, y in zip(a, acc_extra(k)))
        acc.append(a)
        mag.append(rotate(qconj(q), field(k) if callable(field) else field))
        gyr.append((w[0] + bias[0], w[1] + bias[1], w[2] + bias[2]))
    return truth, gyr, acc, mag


def run(est, gyr, acc, mag=None):
    """Feed every sample; return per sample (q, rest, mag_disturbed, bias)."""
    out = []
    for k in range(len(gyr)):
        q = est.update(gyr[k], acc[k], None if mag is None else mag[k], DT)
        out.append((q, est.rest, est.mag_disturbed, est.bias))
    return out


def still(seconds):
    return np.zeros((int(round(seconds * RATE)), 3))


def turning(seconds, rate=0.5):
    """Turning about the body's z axis (the vertical when level) at ``rate`` rad/s."""
    rates = np.zeros((int(round(seconds * RATE)), 3))
    rates[:, 2] = rate
    return rates


def wandering(seconds, amplitude=0.2):
    """Slow rotation about an axis that wanders through the body (never rest)."""
    t = np.arange(int(round(seconds * RATE))) / RATE
    return amplitude * np.stack([np.sin(0.11 * t), np.cos(0.07 * t + 1.0),
                                 np.sin(0.05 * t + 2.0) + 0.5], axis=1)


def first_index(flags, value=True):
    """Index of the first sample whose flag is ``value`` (None if none is)."""
    for k, flag in enumerate(flags):
        if bool(flag) == value:
            return k
    return None


# The inclination gain -------------------------------------------------------------

@pytest.mark.parametrize('tau_acc_gain', [0.25, 1.0])
def test_inclination_error_decays_with_tau_acc_gain(tau_acc_gain):
    # Level and still; the estimate tilted by 0.2 rad. With a short
    # accelerometer low-pass (tau_acc 0.01 s) the correction's own gain sets
    # the pace: the error falls by 1/e per tau_acc_gain.
    n = int(3.5 * tau_acc_gain * RATE)
    truth, gyr, acc, _ = simulate(still(n / RATE))
    # (No bias learned in motion: its corrections would be taken for one; no
    # acceleration rejection: the knocked estimate is not the gyro's vertical.)
    est = AhrsObserver(AhrsParams(tau_acc=0.01, tau_acc_gain=tau_acc_gain, tau_bias=0.0,
                                  acc_reject=0.0), use_mag=False)
    est.update(gyr[0], acc[0], None, DT)
    est.q = qmul(qexp((0.2, 0.0, 0.0)), est.q)
    first = tilt_deg(est.q, truth[0])
    assert first == pytest.approx(math.degrees(0.2), rel=1e-9)
    errors = [tilt_deg(q, truth[k + 1]) for k, (q, *_) in enumerate(run(est, gyr[1:], acc[1:]))]
    for m in (1, 2, 3):
        k = round(m * tau_acc_gain * RATE) - 1
        assert errors[k] / first == pytest.approx(math.exp(-m), rel=0.08), m


# Rest detection -------------------------------------------------------------------

@pytest.mark.parametrize('rest_time', [0.5, 2.0])
def test_rest_is_detected_after_rest_time_and_not_before(rest_time):
    # Still from the first sample: rest comes rest_time later, to a sample.
    _, gyr, acc, _ = simulate(still(rest_time + 1.0))
    est = AhrsObserver(AhrsParams(rest_time=rest_time), use_mag=False)
    rest = [r for _, r, _, _ in run(est, gyr, acc)]
    # Sample 0 initializes; each later one adds dt to the time still.
    assert first_index(rest) == pytest.approx(rest_time * RATE, abs=1)


def test_rest_against_the_known_answer_of_a_still_moving_still_recording():
    # 3 s still, 2 s turning at 1 rad/s, 4 s still: rest exactly while still
    # (after rest_time, and after the rest filter forgets the turn).
    p = AhrsParams(rest_time=1.0, tau_rest=0.2)
    rates = np.concatenate([still(3.0), turning(2.0, rate=1.0), still(4.0)])
    _, gyr, acc, _ = simulate(rates)
    rest = np.array([r for _, r, _, _ in run(AhrsObserver(p, use_mag=False), gyr, acc)])
    t = np.arange(len(rest)) / RATE
    # The low-passed rate falls from 1 rad/s below rest_gyr after
    # tau_rest * ln(1 / rest_gyr).
    forget = p.tau_rest * math.log(1.0 / p.rest_gyr)
    expected = ((t >= p.rest_time) & (t < 3.0)) | (t >= 5.0 + forget + p.rest_time)
    differ = np.flatnonzero(rest != expected)
    # Only at the edges of the expected answer (a sample or two of rounding).
    assert all(min(abs(t[k] - edge) for edge in (p.rest_time, 3.0, 5.0 + forget + p.rest_time))
               <= 2.5 * DT for k in differ), t[differ]
    assert not rest[(t >= 3.0 + 2 * DT) & (t < 5.0 + forget)].any()


@pytest.mark.parametrize('rest_acc, rest_for', [(0.5, (0.3,)), (1.0, (0.3, 0.75))])
def test_rest_acc_separates_a_trembling_specific_force(rest_acc, rest_for):
    # A still gyro, the specific force trembling at 5 Hz with amplitude 0.3
    # or 0.75 m/s² (its deviation from the rest filter's mean is about the
    # amplitude): rest where the amplitude is below rest_acc, never above.
    for amplitude in (0.3, 0.75):
        def shake(k):
            return (amplitude * math.sin(2 * math.pi * 5.0 * k * DT), 0.0, 0.0)

        _, gyr, acc, _ = simulate(still(4.0), acc_extra=shake)
        est = AhrsObserver(AhrsParams(rest_acc=rest_acc, rest_time=1.0), use_mag=False)
        rest = [r for _, r, _, _ in run(est, gyr, acc)]
        assert any(rest) == (amplitude in rest_for), amplitude


@pytest.mark.parametrize('tau_rest', [0.5, 2.0])
def test_bias_at_rest_converges_with_tau_rest(tau_rest):
    # At rest with a constant gyro bias (below rest_gyr): from the sample rest
    # is detected the estimate closes the gap by 1 - 1/e per tau_rest.
    bias = (0.01, -0.006, 0.004)
    p = AhrsParams(rest_time=0.5, tau_rest=tau_rest)
    _, gyr, acc, _ = simulate(still(p.rest_time + 3 * tau_rest + 0.5), bias=bias)
    out = run(AhrsObserver(p, use_mag=False), gyr, acc)
    start = first_index(r for _, r, _, _ in out)
    assert start == pytest.approx(p.rest_time * RATE, abs=1)
    for m in (1, 2, 3):
        learned = out[start + round(m * tau_rest * RATE) - 1][3]
        for b, b_hat in zip(bias, learned):
            assert b_hat / b == pytest.approx(1.0 - math.exp(-m), rel=0.02), m


# The gyro bias in motion (tau_bias > 0) and its clip --------------------------------

def test_bias_learned_in_motion_converges_to_the_constant_bias():
    # Turning all the time (never rest), the estimate learns a constant bias
    # from its own corrections; with tau_bias 0 it learns none.
    bias = (0.01, -0.008, 0.012)
    truth, gyr, acc, _ = simulate(wandering(45.0), q0=(0.9, 0.1, -0.2, 0.3), bias=bias)
    learned = {}
    for tau_bias in (0.0, 5.0, 20.0):
        est = AhrsObserver(AhrsParams(tau_bias=tau_bias, tau_acc=0.5), use_mag=False)
        out = run(est, gyr, acc)
        assert not any(r for _, r, _, _ in out)
        learned[tau_bias] = [np.abs(np.subtract(out[round(s * RATE) - 1][3], bias)).max()
                             for s in (10.0, 45.0)]
    assert learned[0.0] == [max(map(abs, bias))] * 2
    assert learned[5.0][1] < 1e-3
    # A longer time constant learns more slowly.
    assert learned[20.0][0] > learned[5.0][0]


def test_a_vertical_bias_is_learned_in_motion_from_the_field_only():
    # Level and turning about the vertical with a bias on the body's z axis:
    # the accelerometer cannot see the heading drift it makes, the field
    # can. With tau_bias > 0 in 9D the heading corrections (once steady:
    # the first fields' running mean over) teach it; in 6D, or with tau_bias
    # 0, it is never learned.
    bias = (0.0, 0.0, 0.01)
    _, gyr, acc, mag = simulate(turning(40.0, 0.3), bias=bias)
    for use_mag, tau_bias in ((False, 5.0), (True, 0.0), (True, 5.0)):
        est = AhrsObserver(AhrsParams(tau_bias=tau_bias, tau_mag=2.0, mag_cal=False),
                           use_mag=use_mag)
        z = [b[2] for _, _, _, b in run(est, gyr, acc, mag)]
        if use_mag and tau_bias:
            assert z[round(1.0 * RATE)] == 0.0  # the heading's first fields teach nothing
            assert z[-1] == pytest.approx(bias[2], abs=5e-4)
        else:
            assert max(map(abs, z)) == 0.0


def test_a_bias_is_learned_in_motion_tilted_through_the_field_and_gravity():
    # Pitched 30° and turning about the body's z: the world's vertical is
    # no body axis, so the heading corrections measure the bias through all
    # of R's low-passed z row, the inclination's through its x and y rows.
    # The whole bias is learned, on each axis.
    bias = (0.004, -0.006, 0.01)
    _, gyr, acc, mag = simulate(turning(40.0, 0.3), q0=qexp((0.0, math.radians(30.0), 0.0)),
                                bias=bias)
    est = AhrsObserver(AhrsParams(tau_bias=5.0, tau_mag=2.0, mag_cal=False), use_mag=True)
    learned_bias = run(est, gyr, acc, mag)[-1][3]
    assert learned_bias == pytest.approx(bias, abs=5e-4)


def test_bias_learned_in_motion_is_clipped_at_bias_max():
    # A bias of 0.03 rad/s on x: learned as it is under a bias_max of 0.05,
    # held at 0.02 under a bias_max of 0.02 (and never beyond).
    bias = (0.03, -0.01, 0.0)
    _, gyr, acc, _ = simulate(wandering(45.0), q0=(0.9, 0.1, -0.2, 0.3), bias=bias)
    for bias_max, expected in ((0.05, 0.03), (0.02, 0.02)):
        est = AhrsObserver(AhrsParams(tau_bias=5.0, tau_acc=0.5, bias_max=bias_max),
                           use_mag=False)
        xs = [b[0] for _, _, _, b in run(est, gyr, acc)]
        assert max(map(abs, xs)) <= bias_max
        assert xs[-1] == pytest.approx(expected, abs=5e-4)


def test_bias_learned_at_rest_is_clipped_at_bias_max():
    # bias_max is the largest bias estimate, per axis: at rest too. A bias of
    # 0.02 rad/s (below rest_gyr, so rest is detected) under bias_max 0.01.
    _, gyr, acc, _ = simulate(still(6.0), bias=(0.02, 0.0, 0.0))
    out = run(AhrsObserver(AhrsParams(bias_max=0.01), use_mag=False), gyr, acc)
    assert out[-1][1]  # rest
    assert max(abs(b[0]) for _, _, _, b in out) <= 0.01


# The field: norm, dip, a new field, the references ----------------------------------

def learned(params, seconds=2.0, rates=None):
    """An estimator that has learned FIELD over ``seconds`` (still, or ``rates``)."""
    rates = still(seconds) if rates is None else rates
    truth, gyr, acc, mag = simulate(rates)
    est = AhrsObserver(params, use_mag=True)
    out = run(est, gyr, acc, mag)
    assert not any(d for _, _, d, _ in out)
    return est, truth[-1], gyr[-1], acc[-1]


def flagged(est, truth, gyr, acc, field):
    """Whether the next sample, with the world field ``field``, is flagged (state kept)."""
    probe = copy.deepcopy(est)
    probe.update(gyr, acc, rotate(qconj(truth), field), DT)
    return bool(probe.mag_disturbed)


@pytest.mark.parametrize('mag_norm_th', [0.05, 0.1])
def test_a_field_whose_norm_leaves_mag_norm_th_is_disturbed(mag_norm_th):
    est, truth, gyr, acc = learned(AhrsParams(mag_norm_th=mag_norm_th))
    for factor, disturbed in ((0.8, False), (1.25, True)):
        for sign in (1.0, -1.0):
            field = tuple((1.0 + sign * factor * mag_norm_th) * v for v in FIELD)
            assert flagged(est, truth, gyr, acc, field) == disturbed, (factor, sign)


@pytest.mark.parametrize('mag_dip_th', [math.radians(5.0), math.radians(10.0)])
def test_a_field_whose_dip_leaves_mag_dip_th_is_disturbed(mag_dip_th):
    # Turned about east, the field keeps its norm and changes its dip by the angle.
    est, truth, gyr, acc = learned(AhrsParams(mag_dip_th=mag_dip_th))
    for factor, disturbed in ((0.8, False), (1.25, True)):
        for sign in (1.0, -1.0):
            field = rotated_field((1.0, 0.0, 0.0), sign * factor * mag_dip_th)
            assert flagged(est, truth, gyr, acc, field) == disturbed, (factor, sign)


def test_a_disturbed_field_is_flagged_exactly_while_it_lasts():
    # Turning; from 4 s to 6 s the field is 30 % stronger (a magnet): flagged
    # exactly then, and the heading stays right through it.
    def field(k):
        return tuple(1.3 * v for v in FIELD) if 4.0 <= k * DT < 6.0 else FIELD

    truth, gyr, acc, mag = simulate(turning(8.0), field=field)
    out = run(AhrsObserver(AhrsParams(), use_mag=True), gyr, acc, mag)
    t = np.arange(len(out)) * DT
    disturbed = np.array([d for _, _, d, _ in out])
    assert np.array_equal(disturbed, (t >= 4.0) & (t < 6.0))
    assert max(angle_deg(q, truth[k]) for k, (q, *_) in enumerate(out) if k > 100) < 0.5


@pytest.mark.parametrize('mag_new_time', [1.0, 2.5])
def test_a_new_field_is_accepted_after_mag_new_time_while_turning(mag_new_time):
    # From 3 s on the field is 30 % stronger for good (a new place). Turning
    # faster than mag_new_gyr it is accepted mag_new_time later; turning
    # slower, or still, never.
    change = 3.0

    def field(k):
        return tuple(1.3 * v for v in FIELD) if k * DT >= change else FIELD

    seconds = change + mag_new_time + 2.0
    for rates, mag_new_gyr, accepted in ((turning(seconds, 0.5), 0.45, True),
                                         (turning(seconds, 0.5), 0.55, False),
                                         (still(seconds), 0.45, False)):
        truth, gyr, acc, mag = simulate(rates, field=field)
        est = AhrsObserver(AhrsParams(mag_new_time=mag_new_time, mag_new_gyr=mag_new_gyr),
                           use_mag=True)
        disturbed = [d for _, _, d, _ in run(est, gyr, acc, mag)]
        start = round(change * RATE)
        assert first_index(disturbed) == start
        if accepted:
            assert first_index(disturbed[start:], False) == pytest.approx(
                mag_new_time * RATE, abs=2)
            assert not any(disturbed[start + round(mag_new_time * RATE) + 2:])
        else:
            assert all(disturbed[start:])


@pytest.mark.parametrize('tau_mag_ref', [1.0, 3.0])
def test_the_norm_reference_follows_a_small_change_with_tau_mag_ref(tau_mag_ref):
    # The field's norm steps up by 3 % (within mag_norm_th 5 %: used). The
    # reference norm moves 1 - 1/e of the way per tau_mag_ref, and the
    # threshold with it: after tau_mag_ref a field is disturbed from about
    # (1 + 0.03 (1 - 1/e)) (1 + 5 %) times the old norm on.
    p = AhrsParams(tau_mag_ref=tau_mag_ref, mag_norm_th=0.05)
    est, truth, gyr, acc = learned(p, seconds=1.0)
    stronger = tuple(1.03 * v for v in FIELD)
    for _ in range(round(tau_mag_ref * RATE)):
        est.update(gyr, acc, rotate(qconj(truth), stronger), DT)
        assert not est.mag_disturbed
    edge = (1.0 + 0.03 * (1.0 - math.exp(-1.0))) * 1.05
    assert not flagged(est, truth, gyr, acc, tuple(edge * 0.997 * v for v in FIELD))
    assert flagged(est, truth, gyr, acc, tuple(edge * 1.003 * v for v in FIELD))


def test_the_dip_reference_follows_a_small_change_with_tau_mag_ref():
    # The same for the dip: 2° steeper (within mag_dip_th 5°: used); after
    # tau_mag_ref the reference has moved 1 - 1/e of the way, and the band
    # of ±5° around it with it.
    tau = 2.0
    p = AhrsParams(tau_mag_ref=tau, mag_dip_th=math.radians(5.0))
    est, truth, gyr, acc = learned(p, seconds=1.0)

    def field(dip):
        return (0.0, 45.0 * math.cos(dip), 45.0 * math.sin(dip))

    for _ in range(round(tau * RATE)):
        est.update(gyr, acc, rotate(qconj(truth), field(DIP - math.radians(2.0))), DT)
        assert not est.mag_disturbed
    reference = DIP - math.radians(2.0) * (1.0 - math.exp(-1.0))
    for side in (1.0, -1.0):
        edge = reference + side * math.radians(5.0)
        assert not flagged(est, truth, gyr, acc, field(edge - side * math.radians(0.1)))
        assert flagged(est, truth, gyr, acc, field(edge + side * math.radians(0.1)))


# An upside-down start ---------------------------------------------------------------

@pytest.mark.parametrize('use_mag', [False, True])
@pytest.mark.parametrize('tilt', [0.0, 0.05])
def test_an_upside_down_start_converges(use_mag, tilt):
    # The body starts upside down (the accelerometer reads -g along its z;
    # exactly, or tilted a little) and turns: the first attitude is right
    # and the estimate stays right.
    rng = np.random.default_rng(21)
    q0 = qmul(qexp((math.pi, 0.0, 0.0)), qexp(tuple(rng.normal(0.0, tilt, 3))))
    truth, gyr, acc, mag = simulate(wandering(10.0, amplitude=0.5), q0=q0)
    assert acc[0][2] < -0.99 * G
    out = run(AhrsObserver(AhrsParams(), use_mag=use_mag), gyr, acc, mag if use_mag else None)
    errors = [(angle_deg if use_mag else tilt_deg)(q, truth[k]) for k, (q, *_) in enumerate(out)]
    assert errors[0] < 1.0
    assert max(errors) < 1.0


def test_an_estimate_upside_down_from_the_truth_recovers():
    # The estimate level while the body is upside down: the filtered
    # specific force points straight down, a correction with no direction
    # (it only shrinks the estimate); the turn gives it one.
    truth, gyr, acc, _ = simulate(wandering(30.0, amplitude=0.5),
                                  q0=qexp((math.pi, 0.0, 0.0)))
    est = AhrsObserver(AhrsParams(), use_mag=False)
    est.update(gyr[0], UP, None, DT)  # a first sample level: the body flipped at once
    errors = [tilt_deg(q, truth[k + 1]) for k, (q, *_) in enumerate(run(est, gyr[1:], acc[1:]))]
    assert errors[0] > 150.0
    assert max(errors[-500:]) < 1.0


# A new field while turning about any axis, in any attitude ------------------------------
#
# The field the estimator rejects as disturbed is taken as the new normal once it has stayed
# consistent for mag_new_time while the body turns faster than mag_new_gyr. The turning check
# reads the low-passed rate; read from the wrong slots (S_REST_GYR + 1 … + 3) it would pass a
# test that turns about z while level (where those slots hold the same values), and leave a
# sensor pitched 15° with a magnet appearing 39° off in heading. Here the body turns about its
# x and its y axis, pitched, rolled and both: accepted on time, heading right after.

# s: from here on the field is 30 % stronger (a new place); later than
# MAG_NEW_TIME, so that the references have been confirmed for longer than
# that and the new field waits the whole MAG_NEW_TIME (a new field is never
# made to wait longer than fields confirmed the references).
CHANGE = 5.0
MAG_NEW_TIME = 4.0
ATTITUDES = {'pitched': qexp((0.0, math.radians(15.0), 0.0)),
             'rolled': qexp((math.radians(15.0), 0.0, 0.0)),
             'pitched and rolled': qmul(qexp((0.0, 0.0, 0.4)),
                                        qmul(qexp((0.0, math.radians(15.0), 0.0)),
                                             qexp((math.radians(-20.0), 0.0, 0.0))))}


def stronger(k):
    return tuple(1.3 * v for v in FIELD) if k * DT >= CHANGE else FIELD


def about(axis, seconds, rate=0.5):
    """Turning about the body's ``axis`` (0: x, 1: y, 2: z) at ``rate`` rad/s."""
    rates = turning(seconds, 0.0)
    rates[:, axis] = rate
    return rates


@pytest.mark.parametrize('attitude', sorted(ATTITUDES))
@pytest.mark.parametrize('axis', [0, 1, 2])
def test_a_new_field_is_accepted_turning_about_any_axis_in_any_attitude(axis, attitude):
    seconds = CHANGE + MAG_NEW_TIME + 3.0
    truth, gyr, acc, mag = simulate(about(axis, seconds), q0=ATTITUDES[attitude],
                                    field=stronger)
    est = AhrsObserver(AhrsParams(mag_new_time=MAG_NEW_TIME, mag_new_gyr=0.45), use_mag=True)
    out = run(est, gyr, acc, mag)
    disturbed = [d for _, _, d, _ in out]
    start = round(CHANGE * RATE)
    assert first_index(disturbed) == start
    assert first_index(disturbed[start:], False) == pytest.approx(MAG_NEW_TIME * RATE, abs=2)
    assert not any(disturbed[start + round(MAG_NEW_TIME * RATE) + 2:])
    # The heading follows the new field (the same direction, stronger).
    errors = [angle_deg(q, truth[k]) for k, (q, *_) in enumerate(out)]
    assert max(errors[-round(RATE):]) < 1.0


@pytest.mark.parametrize('axis', [0, 1, 2])
def test_turning_slower_than_mag_new_gyr_about_any_axis_keeps_the_field_rejected(axis):
    # The same, turning at 0.4 rad/s under mag_new_gyr 0.45: never accepted.
    seconds = CHANGE + MAG_NEW_TIME + 3.0
    _, gyr, acc, mag = simulate(about(axis, seconds, rate=0.4), q0=ATTITUDES['pitched'],
                                field=stronger)
    est = AhrsObserver(AhrsParams(mag_new_time=MAG_NEW_TIME, mag_new_gyr=0.45), use_mag=True)
    disturbed = [d for _, _, d, _ in run(est, gyr, acc, mag)]
    start = round(CHANGE * RATE)
    assert first_index(disturbed) == start
    assert all(disturbed[start:])
