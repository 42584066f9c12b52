"""
The kernels' vector and small-matrix helpers (core/ahrs/small_matrix.py), against numpy.

Each helper on random values against numpy's form of the same algebra, on a
plain list as the plain kernels run them; the sums' order, which keeps the
kernels' bits, against the products written out left to right.
"""

import math

import sys

import numpy as np
import pytest

from ext_observer.core.ahrs import compiled
from ext_observer.core.ahrs import small_matrix as sm

RNG = np.random.default_rng(7)


def vec(n=3):
    return tuple(RNG.normal(size=n).tolist())


def state(n, off=3):
    """A list of ``off`` guard values then ``n`` random ones."""
    return [7.0] * off + RNG.normal(size=n).tolist()


def test_vector_algebra_is_numpys():
    a, b, k = vec(), vec(), 0.7
    assert sm.add3(a, b) == tuple(np.add(a, b))
    assert sm.sub3(a, b) == tuple(np.subtract(a, b))
    assert sm.neg3(a) == tuple(np.negative(a))
    assert sm.scale3(k, a) == tuple(k * np.array(a))
    assert sm.add_scaled3(a, k, b) == tuple(np.array(a) + k * np.array(b))
    assert sm.dot3(a, b) == a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
    assert sm.dot3(a, b) == pytest.approx(np.dot(a, b), rel=1e-15)
    np.testing.assert_allclose(sm.cross3(a, b), np.cross(a, b), rtol=1e-14)


def test_scalars():
    assert sm.max_of(1.0, 2.0) == 2.0 and sm.max_of(3.0, 2.0) == 3.0
    assert math.isnan(sm.max_of(math.nan, 0.0))
    assert sm.finite_or_zero(2.5) == 2.5
    for bad in (math.nan, math.inf, -math.inf):
        assert sm.finite_or_zero(bad) == 0.0


def test_reading_and_writing_an_array():
    s = state(40)
    assert sm.vec3_at(s, 5) == (s[5], s[6], s[7])
    assert sm.col3_at(s, 4, 6) == (s[4], s[10], s[16])
    assert sm.vec5_at(s, 3, 2) == (s[3], s[5], s[7], s[9], s[11])
    t = list(s)
    sm.store3(t, 8, (1.0, 2.0, 3.0))
    assert t[8:11] == [1.0, 2.0, 3.0] and t[:8] == s[:8] and t[11:] == s[11:]
    t = list(s)
    sm.column3_into(t, 4, 5, (1.0, 2.0, 3.0))
    assert (t[4], t[9], t[14]) == (1.0, 2.0, 3.0)
    assert [v for i, v in enumerate(t) if i not in (4, 9, 14)] == [
        v for i, v in enumerate(s) if i not in (4, 9, 14)]
    t = list(s)
    sm.fill(t, 6, 4, 0.25)
    assert t[6:10] == [0.25] * 4 and t[:6] == s[:6] and t[10:] == s[10:]


def test_three_by_three_products_are_numpys():
    s = state(9)
    m = np.array(s[3:]).reshape(3, 3)
    v = vec()
    np.testing.assert_allclose(sm.mat3_vec_at(s, 3, v), m @ v, rtol=1e-13)
    np.testing.assert_allclose(sm.vec_mat3_at(v, s, 3), np.array(v) @ m, rtol=1e-13)
    np.testing.assert_allclose(sm.mat3t_vec(tuple(s[3:]), v), m.T @ v, rtol=1e-13)
    assert sm.quad3_at(s, 3, v) == pytest.approx(np.array(v) @ m @ v, rel=1e-12)


def test_a_rotation_and_its_complement():
    w, x, y, z = 2.0 * np.array([0.9, 0.1, -0.3, 0.2])  # not unit: any norm
    r = np.array(sm.rotation_of(w, x, y, z)).reshape(3, 3)
    n = math.sqrt(w * w + x * x + y * y + z * z)
    w, x, y, z = w / n, x / n, y / n, z / n
    expected = np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])
    np.testing.assert_allclose(r, expected, atol=1e-15)
    np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-15)
    e = np.array(sm.identity_minus(tuple(r.ravel()))).reshape(3, 3)
    np.testing.assert_array_equal(e, np.eye(3) - r)


def test_a_skew_block_and_a_diagonal():
    s = [0.0] * 3 + [9.0] * 30
    v = vec()
    sm.skew_into(s, 4, 6, 0.5, v)
    block = np.array([s[4:7], s[10:13], s[16:19]])
    cross = np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])
    np.testing.assert_array_equal(block, 0.5 * np.eye(3) + cross)
    assert s[7:10] == [9.0] * 3 and s[13:16] == [9.0] * 3 and s[19] == 9.0 and s[3] == 9.0
    s = [1.0] * 28
    sm.diagonal_into(s, 3, 5, 1, 3, 4.0)
    m = np.array(s[3:]).reshape(5, 5)
    np.testing.assert_array_equal(np.diag(m), [1.0, 4.0, 4.0, 4.0, 1.0])
    sm.add_diagonal(s, 3, 5, 2, 2, 0.5)
    m2 = np.array(s[3:]).reshape(5, 5)
    np.testing.assert_array_equal(np.diag(m2), [1.0, 4.0, 4.5, 4.5, 1.0])
    assert np.sum(m2) == np.sum(m) + 1.0


@pytest.mark.parametrize('transposed', [False, True])
def test_a_product_of_views_is_numpys_and_sums_left_to_right(transposed):
    n, k, m = 3, 4, 5
    a_at, b_at, out_at = 3, 2, 4
    a_arr, b_arr = state(n * k + 2, a_at), state(k * m + 1, b_at)
    out_arr = state(n * m + 3, out_at)
    a = np.array(a_arr[a_at:a_at + n * k]).reshape(n, k)
    b_stored = np.array(b_arr[b_at:b_at + k * m]).reshape((m, k) if transposed else (k, m))
    b = b_stored.T if transposed else b_stored
    b_view = sm.cols(b_at, k) if transposed else sm.rows(b_at, m)
    # OUT += A B onto what is there, product by product; A and B only read
    t, a_before, b_before = list(out_arr), list(a_arr), list(b_arr)
    sm.matmul_acc_into(t, sm.rows(out_at, m), a_arr, sm.rows(a_at, k), b_arr, b_view, n, k, m)
    got = np.array(t[out_at:out_at + n * m]).reshape(n, m)
    before = np.array(out_arr[out_at:out_at + n * m]).reshape(n, m)
    np.testing.assert_allclose(got, before + a @ b, rtol=1e-12)
    written = (before[2, 4] + a[2, 0] * b[0, 4] + a[2, 1] * b[1, 4] + a[2, 2] * b[2, 4]
               + a[2, 3] * b[3, 4])
    assert got[2, 4] == written
    assert t[:out_at] == out_arr[:out_at] and t[out_at + n * m:] == out_arr[out_at + n * m:]
    assert a_arr == a_before and b_arr == b_before


def test_a_product_within_one_array_is_the_product_of_its_parts():
    # OUT, A and B in one array (a covariance's blocks): the same as apart.
    n, k, m = 3, 4, 2
    s = state(n * k + k * m + n * m)
    a_at, b_at, out_at = 3, 3 + n * k, 3 + n * k + k * m
    t = list(s)
    sm.matmul_acc_into(t, sm.rows(out_at, m), t, sm.rows(a_at, k), t, sm.rows(b_at, m),
                       n, k, m)
    apart = list(s)
    sm.matmul_acc_into(apart, sm.rows(out_at, m), list(s), sm.rows(a_at, k), list(s),
                       sm.rows(b_at, m), n, k, m)
    assert t == apart and t[:out_at] == s[:out_at] and t != s


def test_twelve_long_sums_and_combinations():
    a, b, c, k = vec(12), vec(12), vec(12), vec()
    written = a[0] * b[0]
    for i in range(1, 12):
        written += a[i] * b[i]
    assert sm.dot12(a, b) == written
    onto = 0.25
    for i in range(12):
        onto += a[i] * b[i]
    assert sm.dot12_onto(0.25, a, b) == onto
    assert sm.dot12(a, b) == pytest.approx(np.dot(a, b), rel=1e-13)
    s = state(30)
    assert sm.vec12_at(s, 4, 2) == tuple(s[4:28:2])
    combination = k[0] * np.array(a) + k[1] * np.array(b) + k[2] * np.array(c)
    t = list(s)
    sm.combination12_into(t, 5, k, a, b, c)
    np.testing.assert_allclose(t[5:17], combination, rtol=1e-13)
    assert t[:5] == s[:5] and t[17:] == s[17:]
    t = list(s)
    sm.sub_combination12(t, 5, k, a, b, c)
    np.testing.assert_allclose(t[5:17], np.array(s[5:17]) - combination, rtol=1e-12)
    assert t[:5] == s[:5] and t[17:] == s[17:]


def test_a_copy_and_a_transposed_copy():
    s, source = state(12 + 4), state(12, 2)
    t = list(s)
    sm.copy_into(t, sm.rows(3, 4), source, sm.rows(2, 4), 3, 4)
    assert t[3:15] == source[2:14] and t[:3] == s[:3] and t[15:] == s[15:]
    t = list(s)
    sm.copy_into(t, sm.cols(3, 3), source, sm.rows(2, 4), 3, 4)
    np.testing.assert_array_equal(np.array(t[3:15]).reshape(4, 3),
                                  np.array(source[2:14]).reshape(3, 4).T)
    assert t[:3] == s[:3] and t[15:] == s[15:]
    # Within one array.
    t = list(s)
    sm.copy_into(t, sm.rows(9, 3), t, sm.rows(3, 3), 2, 3)
    assert t[9:15] == s[3:9] and t[:9] == s[:9]


def test_the_helpers_are_compiled_with_the_kernels():
    pytest.importorskip('numba')
    k = compiled.kernels(True)
    twin = sys.modules[k.ahrs.__name__.rpartition('.')[0] + '.small_matrix']
    for name, value in vars(sm).items():
        if callable(value) and getattr(value, '__module__', '') == sm.__name__:
            assert hasattr(vars(twin)[name], 'py_func'), name
