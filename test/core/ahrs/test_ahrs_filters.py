"""
The estimator's shared arithmetic against independent forms of the same maths (no ROS).

``ahrs_filters.py`` rotates vectors, builds ``R(q̂)``, turns time constants
into gains, runs the second-order Butterworth whose states live in the
state, and finds a first attitude. Each is checked here against another way
of computing it (the quaternion product, the filter's difference equation
in direct form I, the rotation that the first attitude must perform) on
any quaternion, of any norm. Fast on purpose: it is the subset that
``make mutation`` runs first for this module (docs/tests.md#mutmut).
"""

import math

import numpy as np
import pytest

from ext_observer.core import quaternion as quat
from ext_observer.core.ahrs import ahrs_filters as f
from ext_observer.core.ahrs.ahrs_observer import AhrsObserver, AhrsParams


def rotated(q, v):
    """``q (0, v) q̄ / |q|²`` with the quaternion product."""
    q = np.asarray(q, dtype=float)
    p = quat.multiply(quat.multiply(q, np.concatenate(([0.0], v))), quat.conjugate(q))
    return p[1:] / (q @ q)


def quaternions(seed, count=6):
    rng = np.random.default_rng(seed)
    # Any direction and norm, w of either sign.
    return [rng.normal(size=4) * rng.uniform(0.2, 3.0) for _ in range(count)]


@pytest.mark.parametrize('seed', range(3))
def test_rotate_and_the_rotation_matrix_are_the_quaternion_product(seed):
    rng = np.random.default_rng(100 + seed)
    s = AhrsObserver(AhrsParams(), use_mag=False, compiled=False).state[0]
    for q in quaternions(seed):
        v = rng.normal(size=3)
        assert f.rotate(*q, *v) == pytest.approx(rotated(q, v), rel=1e-12, abs=1e-12)
        for i in range(4):
            s.est.q[i] = q[i]
        r = np.reshape(f.rotation_matrix(s), (3, 3))
        assert r @ v == pytest.approx(rotated(q, v), rel=1e-12, abs=1e-12)


def test_gain_clip():
    assert f.gain(2.0, 0.01) == pytest.approx(1.0 - math.exp(-0.005), rel=1e-15)
    assert f.gain(0.5, 0.5) == pytest.approx(1.0 - math.exp(-1.0), rel=1e-15)
    assert [f.clip(v, -1.0, 2.0) for v in (-3.0, -1.0, 0.5, 2.0, 5.0)] == [
        -1.0, -1.0, 0.5, 2.0, 2.0]


def butterworth_state(coefficients):
    s = AhrsObserver(AhrsParams(), use_mag=False, compiled=False).state[0]
    for k, c in enumerate(coefficients):
        s.coef.bw[k] = c
    return s


def direct_form_1(coefficients, x, y0):
    """The difference equation, from a past held at input and output ``y0``."""
    b0, b1, b2, a1, a2 = coefficients
    xs, ys = [y0, y0], [y0, y0]
    for v in x:
        ys.append(b0 * v + b1 * xs[-1] + b2 * xs[-2] - a1 * ys[-1] - a2 * ys[-2])
        xs.append(v)
    return np.array(ys[2:])


# A low-pass with unit DC gain (b0 + b1 + b2 = 1 + a1 + a2), asymmetric on
# purpose so that no two coefficients can stand for each other.
COEFFICIENTS = (0.05, 0.09, 0.03, -1.3, 0.47)


def test_the_butterworth_is_its_difference_equation_from_a_steady_start():
    rng = np.random.default_rng(7)
    x = rng.normal(size=(40, 3))
    y0 = np.array([0.3, -1.2, 9.8])
    s = butterworth_state(COEFFICIENTS)
    f.steady(s.coef.bw, s.inc.lp, 0, *y0)
    out = np.array([f.lowpass(s.coef.bw, s.inc.lp, 0, *v) for v in x])
    for axis in range(3):
        assert out[:, axis] == pytest.approx(direct_form_1(COEFFICIENTS, x[:, axis], y0[axis]),
                                             rel=1e-12, abs=1e-12)


def test_a_steady_butterworth_holds_a_constant_input():
    s = butterworth_state(COEFFICIENTS)
    f.steady(s.coef.bw, s.bias.r_lp, 6, 1.5, -2.0, 0.25)
    for _ in range(3):
        assert f.lowpass(s.coef.bw, s.bias.r_lp, 6, 1.5, -2.0, 0.25) == pytest.approx(
            (1.5, -2.0, 0.25), rel=1e-12)


@pytest.mark.parametrize('seed', range(3))
def test_the_first_attitude_takes_gravity_up_and_the_field_north(seed):
    rng = np.random.default_rng(200 + seed)
    # Norms below and above 1: m/s², or g, or anything.
    for magnitude in (0.3, 1.0, 9.8, 20.0):
        acc = rng.normal(size=3)
        acc *= magnitude / np.linalg.norm(acc)
        field = rng.normal(size=3)
        q = np.array(f.first_attitude(*acc, 0.0, 0.0, 0.0, 0.0, 1.0))
        assert q @ q == pytest.approx(1.0, rel=1e-12)
        assert rotated(q, acc) == pytest.approx([0.0, 0.0, np.linalg.norm(acc)], abs=1e-9)
        # The smallest rotation: its axis is horizontal, no heading of its own.
        assert q[3] == 0.0
        q = np.array(f.first_attitude(*acc, 1.0, *field, 1.0))
        up = rotated(q, acc)
        assert up == pytest.approx([0.0, 0.0, np.linalg.norm(acc)], abs=1e-9)
        north = rotated(q, field)
        assert north[0] == pytest.approx(0.0, abs=1e-9) and north[1] > 0.0
        # A field given but not used (use_mag false): the heading of no field.
        assert f.first_attitude(*acc, 1.0, *field, 0.0) == pytest.approx(
            f.first_attitude(*acc, 0.0, 0.0, 0.0, 0.0, 0.0), abs=1e-15)


def test_the_first_attitude_upside_down_and_of_a_zero_vector():
    # Gravity along −z: the half turn about x (the smallest rotation is not unique).
    q = f.first_attitude(0.0, 0.0, -9.8, 0.0, 0.0, 0.0, 0.0, 0.0)
    assert q == (0.0, 1.0, 0.0, 0.0)
    q = f.first_attitude(1e-12, 0.0, -9.8, 0.0, 0.0, 0.0, 0.0, 0.0)
    assert rotated(q, (1e-12, 0.0, -9.8)) == pytest.approx([0.0, 0.0, 9.8], abs=1e-9)
    assert f.first_attitude(0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0) == (1.0, 0.0, 0.0, 0.0)


@pytest.mark.parametrize('tau, dt, tau_bias', [(0.5, 0.01, 20.0), (3.0, 0.0025, 0.5),
                                               (0.1, 0.04, 2.0)])
def test_the_coefficients_are_a_butterworth_at_1_over_2_pi_tau_and_first_order_gains(tau, dt,
                                                                                      tau_bias):
    # The accelerometer's low-pass (docs/raw_imu.md): second-order
    # Butterworth, cutoff 1/(2π tau_acc): unit gain at DC, 1/√2 at the
    # cutoff (prewarped: exact), zero at Nyquist; the gains 1 − e^(−dt/τ).
    from ext_observer.core.ahrs.ahrs_kernel import ahrs_coefficients
    s = AhrsObserver(AhrsParams(), use_mag=False, compiled=False).state[0]
    s.par.tau_acc, s.par.tau_acc_gain, s.par.tau_rest = tau, 2.0 * tau, 5.0 * tau
    s.par.bias_sigma_motion, s.par.tau_bias = 0.01, tau_bias
    ahrs_coefficients(s, dt)
    b0, b1, b2, a1, a2 = (s.coef.bw[k] for k in range(5))

    def gain_at(omega):
        z = np.exp(-1j * omega * dt)
        return abs((b0 + b1 * z + b2 * z * z) / (1.0 + a1 * z + a2 * z * z))

    assert gain_at(0.0) == pytest.approx(1.0, rel=1e-8)   # b0 ~ 1e-7: rounding
    assert gain_at(1.0 / tau) == pytest.approx(math.sqrt(0.5), rel=1e-8)
    assert gain_at(math.pi / dt) == pytest.approx(0.0, abs=1e-9)
    assert b1 == pytest.approx(2.0 * b0, rel=1e-15) and b2 == b0
    assert s.coef.k_acc == pytest.approx(1.0 - math.exp(-dt / (2.0 * tau)), rel=1e-12)
    assert s.coef.k_rest == pytest.approx(1.0 - math.exp(-dt / (5.0 * tau)), rel=1e-12)
    # The bias in motion: σ² grows by bias_sigma_motion² dt / tau_bias per
    # sample; a correction rate's noise density bias_sigma_motion² tau_bias.
    assert s.coef.bias_q == pytest.approx(1e-4 * dt / tau_bias, rel=1e-12)
    assert s.coef.bias_r == pytest.approx(1e-4 * tau_bias, rel=1e-12)


def test_the_kernels_quaternion_product_is_the_cores():
    rng = np.random.default_rng(11)
    for _ in range(20):
        a, b = rng.normal(size=4), rng.normal(size=4)
        np.testing.assert_allclose(f.quat_multiply(*a, *b), quat.multiply(a, b), rtol=1e-13,
                                   atol=1e-15)


def test_the_deviation_from_gravity_is_the_larger_of_the_vertical_and_the_horizontal_share():
    from ext_observer.core.constants import STANDARD_GRAVITY as G
    # Vertical: (f_z − g)²/g²; horizontal: (f_x² + f_y²)/2/g²; the larger counts.
    assert f.gravity_deviation(0.0, 0.0, G) == 0.0
    assert f.gravity_deviation(0.0, 0.0, G + 2.0) == pytest.approx(4.0 / G ** 2, rel=1e-14)
    assert f.gravity_deviation(0.0, 0.0, G - 2.0) == pytest.approx(4.0 / G ** 2, rel=1e-14)
    assert f.gravity_deviation(3.0, 1.0, G + 0.5) == pytest.approx(5.0 / G ** 2, rel=1e-14)
    assert f.gravity_deviation(0.3, 0.1, G + 0.5) == pytest.approx(0.25 / G ** 2, rel=1e-14)


def test_a_first_order_step_moves_each_component_by_its_gain():
    v = [1.0, -2.0, 4.0]
    out = f.first_order_step(v, 0.25, 3.0, 2.0, 0.0)
    assert out == (1.5, -1.0, 3.0) and v == [1.5, -1.0, 3.0]
