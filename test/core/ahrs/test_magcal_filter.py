"""
The calibration's Kalman filter against its documented model, in matrix form (no ROS).

``magcal_filter.py`` writes the filter on the flat state, in named steps
over small_matrix.py's helpers (the model: magcal_kernel.py's docstring,
docs/calibration.md); here the
same steps are written with numpy matrices: the prediction ``s ← Rᵀ s +
(I − Rᵀ) z``, ``P ← F P Fᵀ + Q``; the update with ``h(x) = A⁻¹ (s + τ ω ×
(s − z))``, its Jacobian by complex steps (exact to rounding, and not the
code's written-out one), ``S = H P Hᵀ + r² I``, ``K = P Hᵀ S⁻¹``, ``P −= K H
P``, the gate and the running NIS; the start from a field ``s = y + Y(y)
d`` with ``Y(y) d = D(d) y``. Each call runs on a block at an offset of a
larger container whose scratch and surroundings hold garbage, and every
slot of the container is compared: a slot one off, a sign turned or a
loop one short fails. Found missing by mutmut (docs/tests.md#mutmut): the
calibration's end-to-end tests bound the offsets to a few percent only.
"""

import math

import numpy as np
from numpy.testing import assert_allclose
import pytest

from ext_observer.core.ahrs import magcal_filter as mf
from ext_observer.core.ahrs import magcal_kernel
from ext_observer.core.ahrs.magcal_layout import (
    CAL_DIFFUSE, CAL_LOADED_BIAS_STD, CAL_N, GATE, MC_AH, MC_AI, MC_DELAY, MC_DRIFT,
    MC_FIELD_RW, MC_FIELD_SCALE, MC_FRESH, MC_H, MC_HAS_PRIOR, MC_K, MC_LEARNED, MC_NIS,
    MC_NOISE, MC_P, MC_PH, MC_PRIOR_COV, MC_PRIOR_P, MC_PRIOR_SCALE, MC_PRIOR_X,
    MC_REFUSED_SHARE, MC_S, MC_SCALE, MC_SI, MC_SIZE, MC_SOFT_IRON, MC_X, MC_YY)

O = 5  # the block's offset in its container
NORM = 48.0  # the field's norm (µT, say)


def container(rng, noise=0.025, field_rw=0.03, soft_iron=0.05, delay=0.02, drift=0.002):
    """A block set up as MagCalibrator does (mc_init), garbage around it and in its scratch."""
    s = rng.uniform(-1.0, 1.0, O + MC_SIZE + 4).tolist()
    magcal_kernel.mc_init(s, O, True, noise, field_rw, soft_iron, delay, math.radians(6.0),
                          math.radians(15.0), drift)
    for k in range(O + MC_AI, O + MC_SIZE + 4):
        s[k] = rng.uniform(-1.0, 1.0)
    for k in range(O):
        s[k] = rng.uniform(-1.0, 1.0)
    return s


def put(s, slot, values):
    for k, v in enumerate(np.ravel(values)):
        s[O + slot + k] = float(v)


def get(s, slot, shape):
    n = int(np.prod(shape))
    return np.array(s[O + slot:O + slot + n]).reshape(shape)


def covariance(rng):
    """A dense 12 × 12 covariance with the scales of (s, z, d, τ): every element matters."""
    a = rng.normal(size=(CAL_N, CAL_N))
    c = a @ a.T + 3.0 * np.eye(CAL_N)
    c = c / np.sqrt(np.outer(np.diag(c), np.diag(c)))
    sd = np.array([1.5, 1.2, 1.0, 0.9, 1.1, 0.8, 0.03, 0.02, 0.025, 0.035, 0.015, 0.01])
    return c * np.outer(sd, sd)


def estimate(rng):
    """A state (s, z, d, τ): a field of about NORM, an offset, a soft iron, a lag."""
    m = rng.normal(size=3)
    z = rng.normal(scale=5.0, size=3)
    d = rng.uniform(-0.06, 0.06, 5)
    return np.concatenate([NORM * m / np.linalg.norm(m) + z, z, d, [0.012]])


def E(k):
    """``D(e_k)``: the symmetric, trace-free soft iron of one unit of ``d_k``."""
    e = np.zeros(5)
    e[k] = 1.0
    return soft_iron(e)


def soft_iron(d):
    return np.array([[d[0], d[2], d[3]], [d[2], d[1], d[4]], [d[3], d[4], -d[0] - d[1]]])


def regressor(y):
    """``Y(y)``, with ``Y(y) d = D(d) y``."""
    return np.column_stack([E(k) @ y for k in range(5)])


def rotation(q):
    w, x, y, z = np.asarray(q) / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def measurement(x, w):
    """``h(x) = A⁻¹ (s + τ ω × (s − z))`` (complex ``x`` too)."""
    a = np.eye(3) + soft_iron(x[6:11])
    return np.linalg.solve(a, x[:3] + x[11] * np.cross(w, x[:3] - x[3:6]))


def jacobian(x, w):
    """``∂h/∂x`` by complex steps: exact to rounding."""
    h = 1e-30
    return np.column_stack([measurement(x + 1j * h * np.eye(CAL_N)[k], w).imag / h
                            for k in range(CAL_N)])


def assert_same(s, expected):
    """Every slot of the container as expected (to rounding)."""
    assert_allclose(np.array(s), np.array(expected), rtol=1e-9, atol=1e-12)


# --- mc_inv3, mc_symmetrize ------------------------------------------------------


def test_the_written_out_inverse_is_the_inverse_and_writes_nine_slots():
    rng = np.random.default_rng(1)
    m = rng.normal(size=(3, 3)) + 2.0 * np.eye(3)  # not symmetric: a transposition shows
    s = rng.uniform(-1.0, 1.0, 16).tolist()
    expected = list(s)
    expected[4:13] = np.linalg.inv(m).ravel().tolist()
    mf.mc_inv3(s, 4, *m.ravel())
    assert_allclose(s, expected, rtol=1e-12, atol=1e-15)


def test_symmetrizing_takes_the_mean_of_p_and_its_transpose_and_nothing_else():
    rng = np.random.default_rng(2)
    p = rng.normal(size=(CAL_N, CAL_N))
    s = rng.uniform(-1.0, 1.0, CAL_N * CAL_N + 6).tolist()
    s[3:3 + CAL_N * CAL_N] = p.ravel().tolist()
    expected = list(s)
    expected[3:3 + CAL_N * CAL_N] = (0.5 * (p + p.T)).ravel().tolist()
    mf.mc_symmetrize(s, 3)
    assert s == expected


# --- mc_predict --------------------------------------------------------------------


@pytest.mark.parametrize('drift', [0.0, 0.004, 1.0])  # 1.0: within its range (to 10)
def test_the_prediction_turns_the_field_and_adds_the_walks(drift):
    rng = np.random.default_rng(3)
    s = container(rng, field_rw=0.03, drift=drift)
    x, p = estimate(rng), covariance(rng)
    put(s, MC_X, x)
    put(s, MC_P, p)
    put(s, MC_FIELD_SCALE, 47.0)
    q = (1.1, -0.35, 0.5, 0.2)  # not unit: the filter normalizes
    dt = 0.013
    expected = list(s)
    r = rotation(q)
    f = np.eye(CAL_N)
    f[0:3, 0:3] = r.T
    f[0:3, 3:6] = np.eye(3) - r.T
    walk = np.zeros((CAL_N, CAL_N))
    walk[0:3, 0:3] = (0.03 * 47.0) ** 2 * dt * np.eye(3)
    offset = (drift * 47.0) ** 2 * dt * np.block([[np.eye(3), np.eye(3)], [np.eye(3), np.eye(3)]])
    walk[0:6, 0:6] += offset
    x_expected = f @ x
    s_expected = r.T @ (x[:3] - x[3:6]) + x[3:6]  # m ← Rᵀ m, z kept
    assert_allclose(x_expected[:3], s_expected, rtol=1e-12)
    mf.mc_predict(s, O, *q, dt)
    for k, v in enumerate(x_expected):
        expected[O + MC_X + k] = v
    for k, v in enumerate((f @ p @ f.T + walk).ravel()):
        expected[O + MC_P + k] = v
    assert_same(s, expected)
    # The walks are there to see (the covariance without them differs).
    assert not np.allclose(get(s, MC_P, (CAL_N, CAL_N)), f @ p @ f.T, rtol=1e-6, atol=0.0)


def test_at_rest_the_prediction_only_adds_the_walks():
    rng = np.random.default_rng(4)
    s = container(rng, field_rw=0.02, drift=0.003)
    x, p = estimate(rng), covariance(rng)
    put(s, MC_X, x)
    put(s, MC_P, p)
    put(s, MC_FIELD_SCALE, 50.0)
    mf.mc_predict(s, O, 2.0, 0.0, 0.0, 0.0, 0.5)
    assert_allclose(get(s, MC_X, (CAL_N,)), x, rtol=1e-15)
    grown = get(s, MC_P, (CAL_N, CAL_N)) - p
    a, b = (0.02 * 50.0) ** 2 * 0.5, (0.003 * 50.0) ** 2 * 0.5
    expected = np.zeros((CAL_N, CAL_N))
    expected[0:3, 0:3] = (a + b) * np.eye(3)
    expected[0:3, 3:6] = expected[3:6, 0:3] = expected[3:6, 3:6] = b * np.eye(3)
    assert_allclose(grown, expected, rtol=1e-9, atol=1e-12)


# --- mc_update ---------------------------------------------------------------------


def updated(rng, target_nis, nis_before=5.0, learned=10.0, norm=None):
    """A container, the field that gives ``target_nis``, and what the update must leave."""
    s = container(rng, noise=0.02)
    x, p = estimate(rng), covariance(rng)
    w = np.array([0.8, -1.3, 0.6])
    put(s, MC_X, x)
    put(s, MC_P, p)
    put(s, MC_FIELD_SCALE, 46.0)
    put(s, MC_NIS, nis_before)
    put(s, MC_LEARNED, learned)
    a = np.eye(3) + soft_iron(x[6:11])
    pred = measurement(x, w)
    h = jacobian(x, w)
    r = (0.02 * 46.0) ** 2
    big_s = h @ p @ h.T + r * np.eye(3)
    si = np.linalg.inv(big_s)
    nu = rng.normal(size=3)
    nu *= math.sqrt(target_nis / (nu @ si @ nu))
    y = pred + nu
    expected = list(s)
    put(expected, MC_AI, np.linalg.inv(a))
    put(expected, MC_H, a @ h)
    put(expected, MC_AH, h)
    put(expected, MC_PH, p @ h.T)
    put(expected, MC_S, big_s)
    put(expected, MC_SI, si)
    put(expected, MC_NIS, nis_before + 0.02 * (min(target_nis, 3.0 * GATE) - nis_before))
    put(expected, MC_LEARNED, learned + 1.0)
    if target_nis < GATE:
        k = p @ h.T @ si
        x_new = x + k @ nu
        put(expected, MC_K, k)
        put(expected, MC_X, x_new)
        put(expected, MC_P, p - k @ h @ p)
        m = np.linalg.norm(x_new[:3] - x_new[3:6])
        put(expected, MC_FIELD_SCALE, max(m, 0.25 * (norm or 0.0)))
    return s, y.tolist(), w.tolist(), expected


def test_an_update_within_the_gate_is_the_kalman_update():
    rng = np.random.default_rng(5)
    s, y, w, expected = updated(rng, 4.0, norm=NORM)
    # The lag and the rotation both matter here (τ ω × m is 0.8 of the field's unit).
    assert mf.mc_update(s, O, *y, *w, True, NORM) is True
    assert_same(s, expected)
    assert get(s, MC_FIELD_SCALE, ()) > 0.25 * NORM


def test_an_updated_field_scale_is_at_least_a_quarter_of_the_norm():
    rng = np.random.default_rng(6)
    norm = 400.0  # the field's |s − z| is about 48: a quarter of 400 rules
    s, y, w, expected = updated(rng, 2.0, norm=norm)
    assert mf.mc_update(s, O, *y, *w, True, norm) is True
    assert_same(s, expected)
    assert get(s, MC_FIELD_SCALE, ()) == 100.0


@pytest.mark.parametrize('nis', [20.0, 60.0])
def test_an_improbable_field_is_refused_and_only_moves_the_mean_nis(nis):
    # Between GATE and 3 GATE the NIS counts as it is; beyond, as 3 GATE.
    rng = np.random.default_rng(7)
    s, y, w, expected = updated(rng, nis)
    assert mf.mc_update(s, O, *y, *w, True, NORM) is False
    assert_same(s, expected)
    assert get(s, MC_NIS, ()) == pytest.approx(5.0 + 0.02 * (min(nis, 48.0) - 5.0), rel=1e-9)


@pytest.mark.parametrize('learned, symmetric', [(10.0, False), (63.0, True)])
def test_a_field_not_live_is_only_counted_and_p_is_symmetrized_every_64(learned, symmetric):
    rng = np.random.default_rng(8)
    s = container(rng)
    x, p = estimate(rng), covariance(rng)
    p[2, 7] += 1e-3  # a little asymmetry, as rounding makes
    put(s, MC_X, x)
    put(s, MC_P, p)
    put(s, MC_LEARNED, learned)
    put(s, MC_FIELD_SCALE, 33.0)
    expected = list(s)
    put(expected, MC_LEARNED, learned + 1.0)
    if symmetric:
        put(expected, MC_P, 0.5 * (p + p.T))
    assert mf.mc_update(s, O, 40.0, -3.0, 20.0, 0.5, 0.1, -0.2, False, NORM) is False
    assert s == expected


# --- mc_start ----------------------------------------------------------------------


def started(s, y, norm, x_after_zero, p_before, scale):
    """What mc_start leaves: ``s = y + Y d``, its covariance, the scratch, the flags."""
    expected = list(s)
    yy = regressor(y)
    x = np.array(x_after_zero, dtype=float)
    x[:3] = y + yy @ x[6:11]
    t = np.eye(CAL_N)
    t[0:3, :] = 0.0
    t[0:3, 6:11] = yy
    p = t @ p_before @ t.T
    p[0:3, 0:3] += (s[O + MC_NOISE] * norm) ** 2 * np.eye(3)
    put(expected, MC_X, x)
    put(expected, MC_P, p)
    put(expected, MC_YY, yy)
    put(expected, MC_K, yy @ p_before[6:11, 6:11])  # 15 slots of its scratch
    put(expected, MC_SCALE, scale)
    put(expected, MC_FIELD_SCALE, max(np.linalg.norm(x[:3] - x[3:6]), 0.25 * norm))
    put(expected, MC_REFUSED_SHARE, 0.0)
    put(expected, MC_FRESH, 0.0)
    return expected


def garbage_filter(rng, s):
    """An old filter in x and P, as a start finds it."""
    put(s, MC_X, rng.normal(size=CAL_N))
    put(s, MC_P, rng.normal(size=CAL_N * CAL_N))
    put(s, MC_REFUSED_SHARE, 0.4)
    put(s, MC_FRESH, 1.0)


def test_a_start_from_nothing_is_a_diffuse_offset_and_the_priors_of_soft_iron_and_lag():
    rng = np.random.default_rng(9)
    s = container(rng, noise=0.03, soft_iron=0.06, delay=0.025)
    garbage_filter(rng, s)
    y = np.array([30.0, -25.0, 28.0])
    norm = float(np.linalg.norm(y))
    p0 = np.diag([0.0] * 3 + [(CAL_DIFFUSE * norm) ** 2] * 3 + [0.06 ** 2] * 5 + [0.025 ** 2])
    expected = started(s, y, norm, np.zeros(CAL_N), p0, 1.0)
    put(s, MC_SCALE, 1.9)
    mf.mc_start(s, O, *y.tolist(), norm)
    assert_same(s, expected)
    assert get(s, MC_X, (3,)).tolist() == y.tolist()


@pytest.mark.parametrize('near', [False, True])
def test_a_restart_keeps_the_learned_offset_soft_iron_lag_and_their_covariance(near):
    rng = np.random.default_rng(10)
    s = container(rng, noise=0.02)
    garbage_filter(rng, s)
    y = np.array([-20.0, 35.0, 22.0])
    norm = float(np.linalg.norm(y))
    prior = estimate(rng)[3:]
    if near:  # an offset near the field: the field scale is a quarter of the norm
        prior[:3] = 0.95 * y
    cov = covariance(rng)[3:, 3:]
    put(s, MC_PRIOR_X, prior)
    put(s, MC_PRIOR_SCALE, 1.3)
    put(s, MC_PRIOR_P, cov)
    put(s, MC_HAS_PRIOR, 1.0)
    put(s, MC_PRIOR_COV, 1.0)
    p0 = np.zeros((CAL_N, CAL_N))
    p0[3:, 3:] = cov
    expected = started(s, y, norm, np.concatenate([np.zeros(3), prior]), p0, 1.3)
    mf.mc_start(s, O, *y.tolist(), norm)
    assert_same(s, expected)
    field_scale = get(s, MC_FIELD_SCALE, ())
    assert (field_scale == 0.25 * norm) == near


def test_a_loaded_calibration_starts_with_a_tighter_prior_about_it():
    rng = np.random.default_rng(11)
    s = container(rng, noise=0.02, soft_iron=0.07, delay=0.015)
    garbage_filter(rng, s)
    y = np.array([12.0, 40.0, -18.0])
    norm = float(np.linalg.norm(y))
    prior = estimate(rng)[3:]
    put(s, MC_PRIOR_X, prior)
    put(s, MC_PRIOR_SCALE, 1.7)
    put(s, MC_PRIOR_P, rng.normal(size=81))  # no covariance given: not read
    put(s, MC_HAS_PRIOR, 1.0)
    put(s, MC_PRIOR_COV, 0.0)
    std = CAL_LOADED_BIAS_STD * norm / 1.7
    p0 = np.diag([0.0] * 3 + [std ** 2] * 3 + [(0.2 * 0.07) ** 2] * 5 + [0.015 ** 2])
    expected = started(s, y, norm, np.concatenate([np.zeros(3), prior]), p0, 1.7)
    mf.mc_start(s, O, *y.tolist(), norm)
    assert_same(s, expected)


def test_the_regressor_is_the_soft_iron_applied_to_the_field():
    # The independent form the start's tests use: Y(y) d = D(d) y.
    rng = np.random.default_rng(12)
    y, d = rng.normal(size=3), rng.normal(size=5)
    assert_allclose(regressor(y) @ d, soft_iron(d) @ y, rtol=1e-12, atol=1e-14)
    assert np.trace(soft_iron(d)) == pytest.approx(0.0, abs=1e-15)
