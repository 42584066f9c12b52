"""
The calibration's Kalman filter against its documented model, in matrix form (no ROS).

``magcal_filter.py`` writes the filter on the calibrator's record, in named
steps over small_matrix.py's helpers (the model: magcal_kernel.py's
docstring, docs/calibration.md); here the
same steps are written with numpy matrices: the prediction ``s ← Rᵀ s +
(I − Rᵀ) z``, ``P ← F P Fᵀ + Q``; the update with ``h(x) = A⁻¹ (s + τ ω ×
(s − z))``, its Jacobian by complex steps (exact to rounding, and not the
code's written-out one), ``S = H P Hᵀ + r² I``, ``K = P Hᵀ S⁻¹``, ``P −= K H
P``, the gate and the running NIS; the start from a field ``s = y + Y(y)
d`` with ``Y(y) d = D(d) y``. Each call runs on a record whose scratch holds
garbage, plain and compiled, and every field of the record is compared: an
index one off, a sign turned or a loop one short fails. Written for
mutmut's survivors (docs/tests.md#mutmut): the calibration's end-to-end
tests bound the offsets to a few percent only.
"""

import math
import sys

import numpy as np
from numpy.testing import assert_allclose
import pytest

from ext_observer.core.ahrs import compiled as compiled_module
from ext_observer.core.ahrs import magcal_filter, magcal_kernel
from ext_observer.core.ahrs.magcal_layout import (CAL, CAL_DIFFUSE, CAL_LOADED_BIAS_STD, CAL_N,
                                                  GATE)

NORM = 48.0  # the field's norm (µT, say)
SCRATCH = ('ai', 'h', 'ah', 'ph', 's', 'si', 'k', 'yy', 'jp', 'c')
needs_numba = pytest.mark.skipif(not compiled_module.compiled_available(),
                                 reason='numba is not installed (requirements-test.txt has it)')


class Kernels:
    """The filter and the kernel, plain on plain records or compiled on structured ones."""

    def __init__(self, compiled):
        self.compiled = compiled
        if compiled:
            magcal = compiled_module.kernels(True).magcal
            self.filter = sys.modules[magcal.__name__.rpartition('.')[0] + '.magcal_filter']
            self.kernel = magcal
        else:
            self.filter, self.kernel = magcal_filter, magcal_kernel

    def record(self):
        """A zeroed record (a compiled one keeps its one-element array alive)."""
        return CAL.holder(self.compiled)[0]

    def array(self, values):
        """A vector as the kernels take it: a list plain, an array compiled."""
        return np.array(values, dtype=float) if self.compiled else list(values)


@pytest.fixture(params=[False, pytest.param(True, marks=needs_numba)],
                ids=['plain', 'compiled'])
def k(request):
    return Kernels(request.param)


def field_of(record, name):
    """A vector field of a record, written through (an array view, or the list)."""
    return record[name] if isinstance(record, np.void) else getattr(record, name)


def put(record, name, values, at=0):
    """``values`` into field ``name`` from index ``at``."""
    values = np.ravel(values)
    size = CAL.path(name)[1]
    assert at + len(values) <= size, f'{len(values)} values from {at} into {name} of {size}'
    if size == 1:
        CAL.set(record, name, float(values[0]))
        return
    target = field_of(record, name)
    for i, v in enumerate(values):
        target[at + i] = float(v)


def get(record, name, shape=()):
    return np.array(CAL.get(record, name), dtype=float).reshape(shape)


def copy(k, record):
    other = k.record()
    CAL.copy(record, other)
    return other


def randomize(record, rng, names=None):
    for path, _, _, size in CAL.fields():
        if names is None or path[-1] in names:
            put(record, path[-1], rng.uniform(-1.0, 1.0, size))


def container(k, rng, noise=0.025, field_rw=0.03, soft_iron=0.05, delay=0.02, drift=0.002):
    """A record set up as MagCalibrator does (mc_init), garbage in its scratch."""
    s = k.record()
    randomize(s, rng)
    k.kernel.mc_init(s, True, noise, field_rw, soft_iron, delay, math.radians(6.0),
                     math.radians(15.0), drift)
    randomize(s, rng, SCRATCH)
    return s


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
    """Every field of the record as expected (to rounding)."""
    for path, _, _, _ in CAL.fields():
        name = path[-1]
        assert_allclose(get(s, name, -1), get(expected, name, -1), rtol=1e-9, atol=1e-12,
                        err_msg=name)


def assert_equal(s, expected):
    """Every field of the record as expected, to the bit."""
    for path, _, _, _ in CAL.fields():
        name = path[-1]
        assert get(s, name, -1).tobytes() == get(expected, name, -1).tobytes(), name


# --- mc_inv3, symmetrize ---------------------------------------------------------


def test_the_written_out_inverse_is_the_inverse_and_writes_nine_values(k):
    rng = np.random.default_rng(1)
    m = rng.normal(size=(3, 3)) + 2.0 * np.eye(3)  # not symmetric: a transposition shows
    s = k.array(rng.uniform(-1.0, 1.0, 12))
    expected = list(s)
    expected[:9] = np.linalg.inv(m).ravel().tolist()
    k.filter.mc_inv3(s, *m.ravel())
    assert_allclose(s, expected, rtol=1e-12, atol=1e-15)


def test_symmetrizing_takes_the_mean_of_p_and_its_transpose_and_nothing_else(k):
    rng = np.random.default_rng(2)
    p = rng.normal(size=(CAL_N, CAL_N))
    s = k.array(rng.uniform(-1.0, 1.0, CAL_N * CAL_N + 6))
    s[:CAL_N * CAL_N] = p.ravel().tolist()
    expected = list(s)
    expected[:CAL_N * CAL_N] = (0.5 * (p + p.T)).ravel().tolist()
    k.filter.symmetrize(s, 0, CAL_N)
    assert list(s) == expected


# --- mc_predict --------------------------------------------------------------------


@pytest.mark.parametrize('drift', [0.0, 0.004, 1.0])  # 1.0: within its range (to 10)
def test_the_prediction_turns_the_field_and_adds_the_walks(k, drift):
    rng = np.random.default_rng(3)
    s = container(k, rng, field_rw=0.03, drift=drift)
    x, p = estimate(rng), covariance(rng)
    put(s, 'x', x)
    put(s, 'p', p)
    put(s, 'field_scale', 47.0)
    q = (1.1, -0.35, 0.5, 0.2)  # not unit: the filter normalizes
    dt = 0.013
    expected = copy(k, s)
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
    k.filter.mc_predict(s, *q, dt)
    put(expected, 'x', x_expected)
    put(expected, 'p', f @ p @ f.T + walk)
    assert_same(s, expected)
    # The walks are there to see (the covariance without them differs).
    assert not np.allclose(get(s, 'p', (CAL_N, CAL_N)), f @ p @ f.T, rtol=1e-6, atol=0.0)


def test_at_rest_the_prediction_only_adds_the_walks(k):
    rng = np.random.default_rng(4)
    s = container(k, rng, field_rw=0.02, drift=0.003)
    x, p = estimate(rng), covariance(rng)
    put(s, 'x', x)
    put(s, 'p', p)
    put(s, 'field_scale', 50.0)
    k.filter.mc_predict(s, 2.0, 0.0, 0.0, 0.0, 0.5)
    assert_allclose(get(s, 'x', (CAL_N,)), x, rtol=1e-15)
    grown = get(s, 'p', (CAL_N, CAL_N)) - p
    a, b = (0.02 * 50.0) ** 2 * 0.5, (0.003 * 50.0) ** 2 * 0.5
    expected = np.zeros((CAL_N, CAL_N))
    expected[0:3, 0:3] = (a + b) * np.eye(3)
    expected[0:3, 3:6] = expected[3:6, 0:3] = expected[3:6, 3:6] = b * np.eye(3)
    assert_allclose(grown, expected, rtol=1e-9, atol=1e-12)


# --- mc_update ---------------------------------------------------------------------


def updated(k, rng, target_nis, nis_before=5.0, learned=10.0, norm=None):
    """A record, the field that gives ``target_nis``, and what the update must leave."""
    s = container(k, rng, noise=0.02)
    x, p = estimate(rng), covariance(rng)
    w = np.array([0.8, -1.3, 0.6])
    put(s, 'x', x)
    put(s, 'p', p)
    put(s, 'field_scale', 46.0)
    put(s, 'nis', nis_before)
    put(s, 'learned', learned)
    a = np.eye(3) + soft_iron(x[6:11])
    pred = measurement(x, w)
    h = jacobian(x, w)
    r = (0.02 * 46.0) ** 2
    big_s = h @ p @ h.T + r * np.eye(3)
    si = np.linalg.inv(big_s)
    nu = rng.normal(size=3)
    nu *= math.sqrt(target_nis / (nu @ si @ nu))
    y = pred + nu
    expected = copy(k, s)
    put(expected, 'ai', np.linalg.inv(a))
    put(expected, 'h', a @ h)
    put(expected, 'ah', h)
    put(expected, 'ph', p @ h.T)
    put(expected, 's', big_s)
    put(expected, 'si', si)
    put(expected, 'nis', nis_before + 0.02 * (min(target_nis, 3.0 * GATE) - nis_before))
    put(expected, 'learned', learned + 1.0)
    if target_nis < GATE:
        gain = p @ h.T @ si
        x_new = x + gain @ nu
        put(expected, 'k', gain)
        put(expected, 'x', x_new)
        put(expected, 'p', p - gain @ h @ p)
        m = np.linalg.norm(x_new[:3] - x_new[3:6])
        put(expected, 'field_scale', max(m, 0.25 * (norm or 0.0)))
    return s, y.tolist(), w.tolist(), expected


def test_an_update_within_the_gate_is_the_kalman_update(k):
    rng = np.random.default_rng(5)
    s, y, w, expected = updated(k, rng, 4.0, norm=NORM)
    # The lag and the rotation both matter here (τ ω × m is 0.8 of the field's unit).
    assert k.filter.mc_update(s, *y, *w, True, NORM) is True
    assert_same(s, expected)
    assert get(s, 'field_scale', ()) > 0.25 * NORM


def test_an_updated_field_scale_is_at_least_a_quarter_of_the_norm(k):
    rng = np.random.default_rng(6)
    norm = 400.0  # the field's |s − z| is about 48: a quarter of 400 rules
    s, y, w, expected = updated(k, rng, 2.0, norm=norm)
    assert k.filter.mc_update(s, *y, *w, True, norm) is True
    assert_same(s, expected)
    assert get(s, 'field_scale', ()) == 100.0


@pytest.mark.parametrize('nis', [20.0, 60.0])
def test_an_improbable_field_is_refused_and_only_moves_the_mean_nis(k, nis):
    # Between GATE and 3 GATE the NIS counts as it is; beyond, as 3 GATE.
    rng = np.random.default_rng(7)
    s, y, w, expected = updated(k, rng, nis)
    assert k.filter.mc_update(s, *y, *w, True, NORM) is False
    assert_same(s, expected)
    assert get(s, 'nis', ()) == pytest.approx(5.0 + 0.02 * (min(nis, 48.0) - 5.0), rel=1e-9)


@pytest.mark.parametrize('learned, symmetric', [(10.0, False), (63.0, True)])
def test_a_field_not_live_is_only_counted_and_p_is_symmetrized_every_64(k, learned, symmetric):
    rng = np.random.default_rng(8)
    s = container(k, rng)
    x, p = estimate(rng), covariance(rng)
    p[2, 7] += 1e-3  # a little asymmetry, as rounding makes
    put(s, 'x', x)
    put(s, 'p', p)
    put(s, 'learned', learned)
    put(s, 'field_scale', 33.0)
    expected = copy(k, s)
    put(expected, 'learned', learned + 1.0)
    if symmetric:
        put(expected, 'p', 0.5 * (p + p.T))
    assert k.filter.mc_update(s, 40.0, -3.0, 20.0, 0.5, 0.1, -0.2, False, NORM) is False
    assert_equal(s, expected)


# --- mc_start ----------------------------------------------------------------------


def started(k, s, y, norm, x_after_zero, p_before, scale):
    """
    What mc_start leaves: ``s = y + Y d``, its covariance, the scratch, the flags.

    The refused share is as the restart, forget or load that made the filter
    fresh left it (mc_restart's ``refused``).
    """
    expected = copy(k, s)
    yy = regressor(y)
    x = np.array(x_after_zero, dtype=float)
    x[:3] = y + yy @ x[6:11]
    t = np.eye(CAL_N)
    t[0:3, :] = 0.0
    t[0:3, 6:11] = yy
    p = t @ p_before @ t.T
    p[0:3, 0:3] += (get(s, 'noise') * norm) ** 2 * np.eye(3)
    put(expected, 'x', x)
    put(expected, 'p', p)
    put(expected, 'yy', yy)
    put(expected, 'k', yy @ p_before[6:11, 6:11])  # 15 of its scratch's 36
    put(expected, 'scale', scale)
    put(expected, 'field_scale', max(np.linalg.norm(x[:3] - x[3:6]), 0.25 * norm))
    put(expected, 'fresh', 0.0)
    return expected


def garbage_filter(rng, s):
    """An old filter in x and P, as a start finds it."""
    put(s, 'x', rng.normal(size=CAL_N))
    put(s, 'p', rng.normal(size=CAL_N * CAL_N))
    put(s, 'refused_share', 0.4)
    put(s, 'fresh', 1.0)


def test_a_start_from_nothing_is_a_diffuse_offset_and_the_priors_of_soft_iron_and_lag(k):
    rng = np.random.default_rng(9)
    s = container(k, rng, noise=0.03, soft_iron=0.06, delay=0.025)
    garbage_filter(rng, s)
    y = np.array([30.0, -25.0, 28.0])
    norm = float(np.linalg.norm(y))
    p0 = np.diag([0.0] * 3 + [(CAL_DIFFUSE * norm) ** 2] * 3 + [0.06 ** 2] * 5 + [0.025 ** 2])
    expected = started(k, s, y, norm, np.zeros(CAL_N), p0, 1.0)
    put(s, 'scale', 1.9)
    k.filter.mc_start(s, *y.tolist(), norm)
    assert_same(s, expected)
    assert get(s, 'x', -1)[:3].tolist() == y.tolist()


@pytest.mark.parametrize('near', [False, True])
def test_a_restart_keeps_the_learned_offset_soft_iron_lag_and_their_covariance(k, near):
    rng = np.random.default_rng(10)
    s = container(k, rng, noise=0.02)
    garbage_filter(rng, s)
    y = np.array([-20.0, 35.0, 22.0])
    norm = float(np.linalg.norm(y))
    prior = estimate(rng)[3:]
    if near:  # an offset near the field: the field scale is a quarter of the norm
        prior[:3] = 0.95 * y
    cov = covariance(rng)[3:, 3:]
    put(s, 'prior_x', prior)
    put(s, 'prior_scale', 1.3)
    put(s, 'prior_p', cov)
    put(s, 'has_prior', 1.0)
    put(s, 'prior_cov', 1.0)
    p0 = np.zeros((CAL_N, CAL_N))
    p0[3:, 3:] = cov
    expected = started(k, s, y, norm, np.concatenate([np.zeros(3), prior]), p0, 1.3)
    k.filter.mc_start(s, *y.tolist(), norm)
    assert_same(s, expected)
    field_scale = get(s, 'field_scale', ())
    assert (field_scale == 0.25 * norm) == near


def test_a_loaded_calibration_starts_with_a_tighter_prior_about_it(k):
    rng = np.random.default_rng(11)
    s = container(k, rng, noise=0.02, soft_iron=0.07, delay=0.015)
    garbage_filter(rng, s)
    y = np.array([12.0, 40.0, -18.0])
    norm = float(np.linalg.norm(y))
    prior = estimate(rng)[3:]
    put(s, 'prior_x', prior)
    put(s, 'prior_scale', 1.7)
    put(s, 'prior_p', rng.normal(size=81))  # no covariance given: not read
    put(s, 'has_prior', 1.0)
    put(s, 'prior_cov', 0.0)
    std = CAL_LOADED_BIAS_STD * norm / 1.7
    p0 = np.diag([0.0] * 3 + [std ** 2] * 3 + [(0.2 * 0.07) ** 2] * 5 + [0.015 ** 2])
    expected = started(k, s, y, norm, np.concatenate([np.zeros(3), prior]), p0, 1.7)
    k.filter.mc_start(s, *y.tolist(), norm)
    assert_same(s, expected)


def test_the_regressor_is_the_soft_iron_applied_to_the_field():
    # The independent form the start's tests use: Y(y) d = D(d) y.
    rng = np.random.default_rng(12)
    y, d = rng.normal(size=3), rng.normal(size=5)
    assert_allclose(regressor(y) @ d, soft_iron(d) @ y, rtol=1e-12, atol=1e-14)
    assert np.trace(soft_iron(d)) == pytest.approx(0.0, abs=1e-15)
