"""Tests of the batched quaternion algebra (no ROS)."""

from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
import numpy as np
from numpy.testing import assert_allclose
import pytest

from ext_observer.core import quaternion as quat

SHAPES = [(4,), (1, 4), (3, 5, 4)]
finite = st.floats(-10.0, 10.0, allow_nan=False, allow_infinity=False)


def rand_q(rng, shape):
    return rng.standard_normal(shape)


@pytest.mark.parametrize('shape', SHAPES)
def test_product_is_associative_and_norm_multiplicative(shape):
    rng = np.random.default_rng(0)
    p, q, r = (rand_q(rng, shape) for _ in range(3))
    assert_allclose(quat.multiply(quat.multiply(p, q), r),
                    quat.multiply(p, quat.multiply(q, r)), atol=1e-12)
    assert_allclose(quat.norm(quat.multiply(p, q)),
                    quat.norm(p) * quat.norm(q), rtol=1e-12)
    assert quat.multiply(p, q).shape == shape


def test_hamilton_convention():
    i, j, k = np.eye(4)[1:]
    assert_allclose(quat.multiply(i, j), k)
    assert_allclose(quat.multiply(j, k), i)
    assert_allclose(quat.multiply(i, i), [-1, 0, 0, 0])


def test_broadcasting_over_leading_dimensions():
    rng = np.random.default_rng(1)
    p = rng.standard_normal((3, 1, 4))
    q = rng.standard_normal((5, 4))
    pq = quat.multiply(p, q)
    assert pq.shape == (3, 5, 4)
    assert_allclose(pq[2, 4], quat.multiply(p[2, 0], q[4]))


@pytest.mark.parametrize('shape', SHAPES)
def test_conjugate_gives_squared_norm(shape):
    q = rand_q(np.random.default_rng(2), shape)
    qq = quat.multiply(quat.conjugate(q), q)
    assert_allclose(qq[..., 0], quat.squared_norm(q))
    assert_allclose(qq[..., 1:], 0.0, atol=1e-12)
    assert_allclose(quat.norm(quat.normalize(q)), 1.0)


@pytest.mark.parametrize('shape', SHAPES)
def test_exp_log_round_trip(shape):
    rng = np.random.default_rng(3)
    v = rng.standard_normal(shape)
    v[..., 1:] *= 0.9  # keep the vector part below π for the principal branch
    assert_allclose(quat.log(quat.exp(v)), v, atol=1e-12)


@pytest.mark.parametrize('angle', [1e-3, 1e-6, 1e-8, 1e-10, 1e-14, 0.0])
def test_small_angle_branch_is_accurate(angle):
    r = np.array([angle, -2 * angle, 0.5 * angle])
    q = quat.quaternion_from_rotation_vector(r)
    half = 0.5 * np.linalg.norm(r)
    sinc = np.sin(half) / half if half > 0 else 1.0
    assert_allclose(q[1:], sinc * 0.5 * r, rtol=1e-15, atol=0)
    assert_allclose(quat.norm(q), 1.0, rtol=1e-15)
    assert_allclose(quat.rotation_vector_from_quaternion(q), r, rtol=1e-12,
                    atol=1e-300)
    v = np.array([0.0, angle, 0.0, 0.0])
    back = quat.log(quat.exp(v))
    assert_allclose(back[1:], v[1:], rtol=1e-14, atol=1e-300)
    assert abs(back[0]) < 1e-15


def test_rotation_vector_round_trip_and_sign_invariance():
    rng = np.random.default_rng(4)
    r = rng.standard_normal((100, 3))
    r *= (np.pi * 0.999 * rng.uniform(size=(100, 1))
          / np.linalg.norm(r, axis=-1, keepdims=True))
    q = quat.quaternion_from_rotation_vector(r)
    assert_allclose(quat.rotation_vector_from_quaternion(q), r, atol=1e-10)
    assert_allclose(quat.rotation_vector_from_quaternion(-3.0 * q), r, atol=1e-10)


def test_attitude_error_is_sign_invariant_angle():
    rng = np.random.default_rng(5)
    q = quat.random_unit_quaternions(rng, (50,))
    angle = rng.uniform(0.0, np.pi, 50)
    axis = rng.standard_normal((50, 3))
    axis /= np.linalg.norm(axis, axis=-1, keepdims=True)
    p = quat.multiply(q, quat.quaternion_from_rotation_vector(axis * angle[:, None]))
    assert_allclose(quat.attitude_error(q, p), angle, atol=1e-9)
    assert_allclose(quat.attitude_error(q, -2.0 * p), angle, atol=1e-9)
    assert_allclose(quat.attitude_error(q, q), 0.0, atol=1e-7)
    tiny = quat.quaternion_from_rotation_vector([1e-9, 0, 0])
    assert_allclose(quat.attitude_error(quat.IDENTITY, tiny), 1e-9, rtol=1e-6)


@pytest.mark.parametrize('func', [quat.conjugate, quat.norm, quat.exp, quat.log,
                                  quat.normalize, quat.manifold_distance])
def test_wrong_shape_names_expected_and_actual(func):
    with pytest.raises(ValueError, match=r'shape \(\.\.\., 4\), got \(3,\)'):
        func(np.zeros(3))


def test_wrong_rotation_vector_shape():
    with pytest.raises(ValueError, match=r'\(\.\.\., 3\), got \(2, 4\)'):
        quat.quaternion_from_rotation_vector(np.zeros((2, 4)))


def test_normalize_refuses_zero():
    with pytest.raises(ValueError, match='zero'):
        quat.normalize(np.zeros((2, 4)))


def test_distances():
    q = np.array([[2.0, 0, 0, 0], [0, 0.5, 0, 0]])
    assert_allclose(quat.manifold_distance(q), [1.0, 0.5])
    assert_allclose(quat.constraint_residual(q), [3.0, 0.75])


def test_random_unit_quaternions_are_uniform_and_reproducible():
    a = quat.random_unit_quaternions(np.random.default_rng(6), (20000,))
    b = quat.random_unit_quaternions(np.random.default_rng(6), (20000,))
    assert_allclose(a, b)
    assert_allclose(quat.norm(a), 1.0)
    # Uniform on S³: each coordinate has mean 0 and variance 1/4.
    assert_allclose(a.mean(axis=0), 0.0, atol=0.02)
    assert_allclose(a.var(axis=0), 0.25, atol=0.01)


@settings(max_examples=200, deadline=None)
@given(arrays(float, (3, 4), elements=finite), arrays(float, (3, 4), elements=finite))
def test_norm_of_product_property(p, q):
    assert_allclose(quat.norm(quat.multiply(p, q)), quat.norm(p) * quat.norm(q),
                    rtol=1e-9, atol=1e-9)


def test_right_matrix_is_right_multiplication():
    rng = np.random.default_rng(8)
    p = rng.standard_normal((6, 4))
    q = rng.standard_normal(4)
    assert_allclose(p @ quat.right_matrix(q), quat.multiply(p, q), atol=1e-14)
    with pytest.raises(ValueError, match=r'shape \(4,\), got \(2, 4\)'):
        quat.right_matrix(np.zeros((2, 4)))
