"""Tests of the transversal extension and its certificate (no ROS)."""

import json
import subprocess
import sys

import numpy as np
from numpy.testing import assert_allclose
import pytest

from ext_observer.core import (certified_alpha_max, estimate_certificate,
                               optimal_delta, s3_certificate, so3_extension,
                               sphere_extension)
from ext_observer.core import quaternion as quat


def kinematics(x, theta):
    """The paper's f: x ⊗ exp(Ω/2)."""
    return quat.multiply(x, quat.quaternion_from_rotation_vector(theta))


def shell_samples(rng, epsilon, n):
    """Points of H drawn in V⁻¹([0, ε]) = {1 − √ε ≤ |x|² ≤ 1 + √ε}."""
    root = np.sqrt(epsilon)
    n2 = rng.uniform(1.0 - root, 1.0 + root, n)
    return quat.random_unit_quaternions(rng, (n,)) * np.sqrt(n2)[:, None]


def test_V_is_invariant_under_the_kinematics():
    """Assumption A1: V ∘ f = V."""
    rng = np.random.default_rng(0)
    ext = sphere_extension()
    x = rng.standard_normal((1000, 4))
    theta = rng.uniform(0.0, 10.0, (1000, 3))
    assert_allclose(ext.V(kinematics(x, theta)), ext.V(x), rtol=1e-10)


def test_gradient_and_hessian_match_finite_differences():
    rng = np.random.default_rng(1)
    ext = sphere_extension()
    x = rng.standard_normal(4)
    h = 1e-6
    grad = np.array([(ext.V(x + h * e) - ext.V(x - h * e)) / (2 * h)
                     for e in np.eye(4)])
    assert_allclose(ext.grad_V(x), grad, rtol=1e-6)
    hess = np.array([(ext.grad_V(x + h * e) - ext.grad_V(x - h * e)) / (2 * h)
                     for e in np.eye(4)])
    assert_allclose(ext.hessian_V(x), hess, rtol=1e-6, atol=1e-8)
    assert_allclose(np.linalg.eigvalsh(ext.hessian_V(x))[-1],
                    12 * quat.squared_norm(x) - 4)


def test_paper_certificate():
    cert = s3_certificate(0.5, 0.059, alpha=0.01)
    assert cert.L == pytest.approx(3.69, abs=0.01)
    assert cert.alpha_max < 0.016
    assert cert.alpha_max == pytest.approx(0.059 / cert.L)
    # Exact d: 12 (√(1 + √ε) + δ)² − 4; the paper states 15.87.
    assert cert.d == pytest.approx(18.377, abs=1e-3)
    assert cert.b == pytest.approx(16 * (1 - np.sqrt(0.5)))
    assert 0.0 < cert.factor < 1.0
    assert cert.certifies(0.01) and not cert.certifies(0.02)


def test_optimal_delta_balances_the_two_bounds():
    delta, alpha_max = optimal_delta(0.5)
    cert = s3_certificate(0.5, delta)
    assert delta / cert.L == pytest.approx(2.0 / cert.d, rel=1e-9)
    assert alpha_max > s3_certificate(0.5, 0.059).alpha_max
    for other in (0.5 * delta, 0.9 * delta, 1.1 * delta, 2 * delta):
        assert s3_certificate(0.5, other).alpha_max < alpha_max
    assert certified_alpha_max(0.5) == alpha_max


@pytest.mark.parametrize('epsilon, delta', [(0.0, 0.1), (1.0, 0.1), (0.5, 0.0),
                                            (float('nan'), 0.1)])
def test_certificate_refuses_invalid_constants(epsilon, delta):
    with pytest.raises(ValueError):
        s3_certificate(epsilon, delta)


@pytest.mark.parametrize('epsilon, delta, alpha', [
    (0.5, 0.059, 0.01), (0.5, 0.059, 0.0159), (0.3, 0.2, 0.05)])
def test_certified_contraction_holds_on_every_sample(epsilon, delta, alpha):
    """Theorem 1: V(x⁺) ≤ (1 − bc) V(x) for every x in V⁻¹([0, ε])."""
    cert = s3_certificate(epsilon, delta, alpha)
    assert cert.certifies(alpha)
    rng = np.random.default_rng(2)
    ext = sphere_extension()
    x = shell_samples(rng, epsilon, 100000)
    theta = rng.uniform(0.0, 10.0, (100000, 3))
    x_next = ext.step(kinematics, x, alpha, theta)
    assert np.all(ext.V(x_next) <= cert.factor * ext.V(x) + 1e-15)


def test_outside_the_certified_range_the_contraction_can_fail():
    """With α well beyond 2/d the extension overshoots: V grows somewhere."""
    rng = np.random.default_rng(3)
    ext = sphere_extension()
    x = shell_samples(rng, 0.5, 10000)
    x_next = ext.correct(x, 0.3)
    assert np.any(ext.V(x_next) > ext.V(x))


def test_extended_system_converges_exponentially():
    rng = np.random.default_rng(4)
    ext = sphere_extension()
    x = shell_samples(rng, 0.5, 1000)
    for _ in range(100):
        x = ext.step(kinematics, x, 0.01, rng.uniform(0, 0.5, (1000, 3)))
    assert np.max(ext.V(x)) < 1e-6


def test_sampled_certificate_estimates_the_exact_one():
    rng = np.random.default_rng(5)
    samples = quat.random_unit_quaternions(rng, (20000,)) * np.sqrt(
        rng.uniform(0.0, 2.0, 20000))[:, None]
    est = estimate_certificate(sphere_extension(), samples, 0.5, 0.059, rng=rng)
    exact = s3_certificate(0.5, 0.059)
    assert est.estimated and not exact.estimated
    assert est.L == pytest.approx(exact.L, rel=0.01)
    assert est.d == pytest.approx(exact.d, rel=0.02)
    assert est.b == pytest.approx(exact.b, rel=0.02)
    assert est.L <= exact.L * (1 + 1e-12) and est.d <= exact.d * (1 + 1e-12)


def test_so3_extension_drives_the_constraint_to_zero():
    rng = np.random.default_rng(6)
    ext = so3_extension()
    q = quat.random_unit_quaternions(rng, (200,))
    R = rotation_matrices(q) + 0.1 * rng.standard_normal((200, 3, 3))

    def f(R, theta):
        return R @ rotation_matrices(quat.quaternion_from_rotation_vector(theta))

    theta = rng.uniform(0, 1, (200, 3))
    # A1 for SO(3): V(f(R)) = V(R).
    assert_allclose(ext.V(f(R, theta)), ext.V(R), rtol=1e-9)
    start = ext.V(R)
    for _ in range(150):
        R = ext.step(f, R, 0.05, rng.uniform(0, 1, (200, 3)))
    residual = np.linalg.norm(np.swapaxes(R, -1, -2) @ R - np.eye(3), axis=(-2, -1))
    assert np.all(start > 1e-3)
    assert np.max(residual) < 1e-8


def test_so3_gradient_equals_constraint_form():
    rng = np.random.default_rng(7)
    ext = so3_extension()
    R = rng.standard_normal((5, 3, 3))
    flat = np.einsum('...ij,...i->...j', ext.jacobian_g(R), ext.g(R))
    assert_allclose(ext.grad_V(R).reshape(5, 9), flat, rtol=1e-10)
    h = 1e-6
    R0 = R[0]
    numeric = np.zeros((3, 3))
    for a in range(3):
        for b in range(3):
            dR = np.zeros((3, 3))
            dR[a, b] = h
            numeric[a, b] = (ext.V(R0 + dR) - ext.V(R0 - dR)) / (2 * h)
    assert_allclose(ext.grad_V(R0), numeric, rtol=1e-6)


def rotation_matrices(q):
    """Rotation matrices of unit quaternions (test helper)."""
    w, x, y, z = np.moveaxis(q, -1, 0)
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
        np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
        np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
    ], -2)


def test_gains_command_line_json():
    out = subprocess.run(
        [sys.executable, '-m', 'ext_observer', 'gains', '--epsilon', '0.5',
         '--delta', '0.059', '--optimize-delta', '--json'],
        capture_output=True, text=True, timeout=60, check=True).stdout
    result = json.loads(out)
    for key in ('epsilon', 'delta', 'L', 'd', 'b', 'alpha_max', 'delta_opt',
                'alpha_max_opt'):
        assert key in result
    assert result['L'] == pytest.approx(3.69, abs=0.01)
    assert result['alpha_max'] < 0.016
    assert result['alpha_max_opt'] > result['alpha_max']


def test_gains_command_line_refuses_bad_epsilon():
    proc = subprocess.run(
        [sys.executable, '-m', 'ext_observer', 'gains', '--epsilon', '2'],
        capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2
    assert 'epsilon must be in (0, 1)' in proc.stderr
