"""Tests of the transversal extension on S³ and SO(3) (no ROS)."""

import numpy as np
from numpy.testing import assert_allclose

from ext_observer.core import so3_extension, sphere_extension
from ext_observer.core import quaternion as quat
from sphere_shell import kinematics, shell_samples


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


def test_so3_extension_drives_the_constraint_to_zero():
    rng = np.random.default_rng(6)
    ext = so3_extension()
    q = quat.random_unit_quaternions(rng, (200,))
    R = quat.rotation_matrices(q) + 0.1 * rng.standard_normal((200, 3, 3))

    def f(R, theta):
        return R @ quat.rotation_matrices(quat.quaternion_from_rotation_vector(theta))

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
