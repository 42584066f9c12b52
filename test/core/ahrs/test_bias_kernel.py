"""
The gyro bias filter in motion against its documented model, in matrix form (no ROS).

``bias_kernel.py`` keeps the bias's covariance as six numbers and updates
it one scalar measurement at a time; here the same steps are the textbook
Kalman filter written with numpy matrices: the update ``K = P h / (hᵀ P h
+ r)``, ``b += K y``, ``P -= K hᵀ P``; the gate (an innovation beyond 3 σ
teaches nothing); the clip at bias_max; the growth of the variances up to
bias_sigma_init². Found missing by mutmut (docs/tests.md#mutmut): the
end-to-end tests learn the bias, but a covariance off in one element only
slowed them down.
"""

import numpy as np
import pytest

from ext_observer.core.ahrs import bias_kernel as kernel
from ext_observer.core.ahrs.ahrs_filters import lowpass
from ext_observer.core.ahrs.ahrs_observer import AhrsObserver, AhrsParams
from ext_observer.core.ahrs.ahrs_state import STATE

# Element (i, j) of the covariance -> its slot among the six (xx xy xz yy yz zz).
SLOT = {(0, 0): 0, (0, 1): 1, (0, 2): 2, (1, 1): 3, (1, 2): 4, (2, 2): 5}


def state(p, bias=(0.0, 0.0, 0.0), bias_max=1.0, sigma_init=0.1):
    """An estimator's state record holding the bias ``bias`` and covariance ``p``."""
    s = AhrsObserver(AhrsParams(), use_mag=False, compiled=False).state[0]
    for i in range(3):
        s.bias.rate[i] = bias[i]
    for (i, j), k in SLOT.items():
        s.bias.p[k] = p[i, j]
    s.par.bias_max = bias_max
    s.par.bias_sigma_init = sigma_init
    return s


def covariance(s):
    return np.array([[kernel.bias_variance(s, i, j) for j in range(3)] for i in range(3)])


def rotation_matrix_of(q):
    w, x, y, z = q
    return ((w * w + x * x - y * y - z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
            2 * (x * y + w * z), (w * w - x * x + y * y - z * z), 2 * (y * z - w * x),
            2 * (x * z - w * y), 2 * (y * z + w * x), (w * w - x * x - y * y + z * z))


def random_covariance(rng, scale):
    a = rng.normal(size=(3, 3))
    return scale * (a @ a.T + 0.5 * np.eye(3))


@pytest.mark.parametrize('seed', range(4))
def test_a_bias_measurement_is_the_kalman_update(seed):
    rng = np.random.default_rng(seed)
    p = random_covariance(rng, 1e-4)
    h = rng.normal(size=3)
    r = 1e-4 * rng.uniform(0.5, 2.0)
    bias = rng.normal(scale=0.01, size=3)
    y = 0.5 * np.sqrt(h @ p @ h + r)   # within the gate
    s = state(p, bias)
    kernel.bias_measure(s, h[0], h[1], h[2], y, r)
    gain = p @ h / (h @ p @ h + r)
    assert [s.bias.rate[i] for i in range(3)] == pytest.approx(bias + gain * y, rel=1e-12)
    expected = p - np.outer(gain, h @ p)
    assert covariance(s) == pytest.approx(expected, rel=1e-9, abs=1e-18)
    # bias_variance reads the one symmetric matrix, whichever the order.
    assert np.array_equal(covariance(s), covariance(s).T)


def test_an_innovation_beyond_3_sigma_teaches_nothing_and_the_bias_is_clipped():
    p = np.diag([1e-4, 2e-4, 3e-4])
    h = np.array([0.6, -0.8, 0.0])
    r = 1e-4
    sigma = np.sqrt(h @ p @ h + r)   # 0.0134 rad/s
    s = state(p)
    before = np.array(STATE.flat(s))
    kernel.bias_measure(s, h[0], h[1], h[2], 3.01 * sigma, r)
    assert np.array_equal(np.array(STATE.flat(s)), before, equal_nan=True)
    kernel.bias_measure(s, h[0], h[1], h[2], 2.99 * sigma, r)
    assert s.bias.rate[0] > 0.0 and s.bias.rate[1] < 0.0 and s.bias.rate[2] == 0.0
    # A bias_max below what it would learn: held at the bound, per axis.
    s = state(p, bias_max=1e-3)
    kernel.bias_measure(s, h[0], h[1], h[2], 2.99 * sigma, r)
    assert [s.bias.rate[i] for i in range(3)] == [1e-3, -1e-3, 0.0]


def test_the_bias_variances_grow_by_q_up_to_bias_sigma_init_squared():
    p = np.array([[1e-6, 2e-7, 0.0], [2e-7, 5e-3, 1e-7], [0.0, 1e-7, 2e-2]])
    s = state(p, sigma_init=0.1)   # bias_sigma_init² = 0.01
    q = 1e-6
    s.coef.bias_q = q
    kernel._bias_grow(s)
    grown = covariance(s)
    # xx grows by q; yy by q (below the cap); zz, above the cap already,
    # stays as it is (the growth never lowers a variance); off-diagonal kept.
    assert np.diag(grown) == pytest.approx([1e-6 + q, 5e-3 + q, 2e-2], rel=1e-12)
    assert grown[0, 1] == 2e-7 and grown[1, 2] == 1e-7
    s.bias.p[SLOT[1, 1]] = 0.01 - 0.5 * q
    s.bias.p[SLOT[2, 2]] = 1e-3
    kernel._bias_grow(s)
    assert kernel.bias_variance(s, 1, 1) == pytest.approx(0.01, rel=1e-12)
    assert kernel.bias_variance(s, 2, 2) == pytest.approx(1e-3 + q, rel=1e-12)


def test_forgetting_the_bias_leaves_bias_sigma_init_on_each_axis_and_nothing_between():
    rng = np.random.default_rng(3)
    s = state(random_covariance(rng, 1e-4), sigma_init=0.02)
    kernel.bias_forget(s)
    assert covariance(s) == pytest.approx(0.02 ** 2 * np.eye(3), rel=1e-12, abs=0.0)


# A Butterworth low-pass with unit DC gain (test_ahrs_filters.py).
COEFFICIENTS = (0.05, 0.09, 0.03, -1.3, 0.47)


def attitude_state(q, p, rest=0.0):
    s = state(p)
    for i in range(4):
        s.est.q[i] = q[i]
    for k, c in enumerate(COEFFICIENTS):
        s.coef.bw[k] = c
    s.rest.detected = rest
    s.coef.bias_q = 1e-9
    s.coef.bias_r = 1e-5
    kernel.rlp_steady(s)
    return s


def test_in_motion_two_corrections_measure_the_bias_through_the_rows_of_r():
    # learn_bias's model (its docstring): the variances grow, then the two
    # horizontal corrections are the measurements −2 r_x / (r_w dt) and
    # −2 r_y / (r_w dt) of the bias through the low-passed R's rows x and y,
    # of variance bias_r / dt. At a steady attitude the low-pass is R.
    rng = np.random.default_rng(11)
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    p = random_covariance(rng, 1e-5)
    dt, rw, rx, ry = 0.01, 1.0, 2e-6, -3e-6
    s = attitude_state(q, p)
    kernel.learn_bias(s, rw, rx, ry, dt, True)
    r = np.reshape(rotation_matrix_of(q), (3, 3))
    expected = attitude_state(q, p)
    kernel._bias_grow(expected)
    kernel.bias_measure(expected, *r[0], -2.0 * rx / (rw * dt), 1e-5 / dt)
    kernel.bias_measure(expected, *r[1], -2.0 * ry / (rw * dt), 1e-5 / dt)
    assert [s.bias.rate[i] for i in range(3)] != [0.0, 0.0, 0.0]
    assert [s.bias.rate[i] for i in range(3)] == pytest.approx(
        [expected.bias.rate[i] for i in range(3)], rel=1e-9)
    assert covariance(s) == pytest.approx(covariance(expected), rel=1e-9)
    # The low-passed R stays R (all three rows, steady).
    for j in range(3):
        assert lowpass(s.coef.bw, s.bias.r_lp, 6 * j, *r[j]) == pytest.approx(r[j], rel=1e-9,
                                                                          abs=1e-12)
    # At rest, or before the low-pass has settled: the variances grow, no
    # measurement.
    for rest, settled in ((1.0, True), (0.0, False)):
        s = attitude_state(q, p, rest=rest)
        kernel.learn_bias(s, rw, rx, ry, dt, settled)
        grown = attitude_state(q, p, rest=rest)
        kernel._bias_grow(grown)
        assert [s.bias.rate[i] for i in range(3)] == [0.0, 0.0, 0.0]
        assert covariance(s) == pytest.approx(covariance(grown), rel=1e-12)
