"""
The calibration's steps around its filter (core/ahrs/magcal_kernel.py), against independent forms.

Each step is called on the calibration's block of an estimator's flat state
(at ``MC0``, as :class:`~ext_observer.core.ahrs.ahrs_observer.AhrsObserver`
allocates it) and the whole block is compared with what the step must
leave: the quality from the covariance of the calibrated field ``J P Jᵀ``
in numpy matrix form (``J = [−I, ∂(D(d) y)/∂d]``, its columns from ``D`` of
the unit vectors), the heading turned between two fields from their
projections on the horizontal plane, the applied calibration ``g (I + D)``,
and the counts, flags and priors each step keeps. The filter's own steps
(``mc_predict``, ``mc_start``, ``mc_update``, tested in test_magcal_filter.py
and the calibration's tests) are run on a copy to say what ``mc_learn``
must leave in the filter's slots. Written for mutmut's survivors
(docs/tests.md#mutmut): the end-to-end tests learn a calibration, but a
quality off by a slot only delayed their convergence.
"""

import math

import numpy as np
import pytest

from ext_observer.core.ahrs import magcal_filter as mf
from ext_observer.core.ahrs import magcal_kernel as mk
from ext_observer.core.ahrs.ahrs_layout import MC0
from ext_observer.core.ahrs.ahrs_observer import AhrsObserver, AhrsParams
from ext_observer.core.ahrs.magcal_layout import (
    CAL_HOLD, CAL_N, CAL_REFUSED_TAU, CAL_SHIFT_SAMPLES, MC_APPLIED, MC_ASSESSED, MC_C,
    MC_CANDIDATE, MC_COEF, MC_CONVERGED, MC_DEADBAND, MC_DELAY, MC_DRIFT, MC_ENABLED,
    MC_FIELD_RW, MC_FIELD_SCALE, MC_FIELDS, MC_FRESH, MC_GATED, MC_HAS_PRIOR, MC_HEADING,
    MC_HELD, MC_IDENTITY, MC_INVALID, MC_JP, MC_LEARNED, MC_LOADED, MC_NIS, MC_NOISE, MC_P,
    MC_PRIOR_COV, MC_PRIOR_P, MC_PRIOR_SCALE, MC_PRIOR_X, MC_QUALITY, MC_READY, MC_REFUSED,
    MC_REFUSED_SHARE, MC_RESETS, MC_SCALE, MC_SEEN_HAS_UP, MC_SEEN_LIVE, MC_SEEN_UP, MC_SEEN_Y,
    MC_SHIFT, MC_SIZE, MC_SOFT_IRON, MC_STALE, MC_USED, MC_WATCHED, MC_WATCHING, MC_X)

OFF = MC0
N = CAL_N
PARAMS = AhrsParams()
# Slots computed by a different arithmetic here: compared to rounding.
ROUNDED = {MC_JP: 24, MC_C: 9, MC_QUALITY: 1, MC_COEF: 12}


def estimator_state():
    """An estimator's flat state (plain kernels), its calibration block at ``MC0``."""
    return AhrsObserver(PARAMS, compiled=False).flat_state


def get(s, slot, n=None):
    if n is None:
        return s[OFF + slot]
    return np.array(s[OFF + slot:OFF + slot + n], dtype=float)


def put(s, slot, values):
    for k, v in enumerate(np.ravel(values)):
        s[OFF + slot + k] = float(v)


def x_of(s):
    return get(s, MC_X, N)


def p_of(s):
    return get(s, MC_P, N * N).reshape(N, N)


def d_matrix(d):
    """``D(d)``: symmetric, trace zero."""
    return np.array([[d[0], d[2], d[3]], [d[2], d[1], d[4]], [d[3], d[4], -d[0] - d[1]]])


def calibrated(zd, y):
    """``(I + D(d)) y − z``."""
    zd = np.asarray(zd, dtype=float)
    return (np.eye(3) + d_matrix(zd[3:8])) @ y - zd[:3]


def horizontal(u, f):
    u = np.asarray(u, dtype=float) / np.linalg.norm(u)
    return f - (f @ u) * u


def turn_about(u, f, g):
    """The signed angle about ``u`` from the horizontal part of ``f`` to that of ``g``."""
    a, b = horizontal(u, f), horizontal(u, g)
    return math.atan2(np.cross(a, b) @ (np.asarray(u) / np.linalg.norm(u)), a @ b)


def assessed(s):
    """``J P Jᵀ`` of the latest field seen and the quality, in matrix form."""
    x, p = x_of(s), p_of(s)
    y = get(s, MC_SEEN_Y, 3)
    jac = np.hstack([-np.eye(3), np.column_stack([d_matrix(e) @ y for e in np.eye(5)])])
    jp = jac @ p[3:11, 3:11]
    c = jp @ jac.T
    f = calibrated(x[3:11], y)
    if get(s, MC_SEEN_HAS_UP):
        e = np.cross(get(s, MC_SEEN_UP, 3), f)
        quality = math.sqrt(max(e @ c @ e, 0.0) / (e @ e)) / np.linalg.norm(e)
    else:
        quality = math.sqrt(np.trace(c)) / np.linalg.norm(f)
    return jp, c, quality


def expect_assessed(e):
    jp, c, quality = assessed(e)
    put(e, MC_JP, jp)
    put(e, MC_C, c)
    e[OFF + MC_QUALITY] = quality
    e[OFF + MC_STALE] = 0.0


def expect_cache(e):
    """What ``mc_cache`` must leave: ``g (I + D)`` and ``g z`` where applied."""
    on = e[OFF + MC_ENABLED] != 0.0
    ready = on and (e[OFF + MC_LOADED] != 0.0 or e[OFF + MC_CONVERGED] != 0.0)
    applied = ready and e[OFF + MC_IDENTITY] == 0.0
    e[OFF + MC_READY] = 1.0 if ready or not on else 0.0
    e[OFF + MC_APPLIED] = 1.0 if applied else 0.0
    a, z = np.eye(3), np.zeros(3)
    if applied:
        x, g = x_of(e), e[OFF + MC_SCALE]
        a, z = g * (np.eye(3) + d_matrix(x[6:11])), g * x[3:6]
    put(e, MC_COEF, np.concatenate([a.ravel(), z]))


def assert_block(s, e):
    """Every slot of the block as expected: exactly, or to rounding where computed apart."""
    got, want = get(s, 0, MC_SIZE), get(e, 0, MC_SIZE)
    rounded = np.zeros(MC_SIZE, dtype=bool)
    for slot, n in ROUNDED.items():
        rounded[slot:slot + n] = True
        assert got[slot:slot + n] == pytest.approx(want[slot:slot + n], rel=1e-9, abs=1e-15)
    exact = ~rounded
    differ = np.flatnonzero(exact & ~((got == want) | (np.isnan(got) & np.isnan(want))))
    assert differ.size == 0, f'slots {differ.tolist()}: {got[differ]} != {want[differ]}'
    # Nothing outside the block is touched.
    assert s[:OFF] == e[:OFF]


def random_calibration(s, rng, scale=1e-4):
    """A learned state: ``x`` near a calibration, ``P`` positive definite (and not symmetric)."""
    x = np.concatenate([rng.normal(0.3, 0.1, 3), rng.normal(0.0, 0.1, 3),
                        rng.normal(0.0, 0.04, 5), [0.01]])
    a = rng.normal(size=(N, N))
    b = rng.normal(size=(N, N))
    put(s, MC_X, x)
    put(s, MC_P, scale * (a @ a.T + np.eye(N) + 0.3 * (b - b.T)))
    s[OFF + MC_FRESH] = 0.0


def seen(s, y, up=None):
    put(s, MC_SEEN_Y, y)
    if up is not None:
        put(s, MC_SEEN_UP, up)
    s[OFF + MC_SEEN_HAS_UP] = 0.0 if up is None else 1.0
    s[OFF + MC_SEEN_LIVE] = 1.0


UP = np.array([0.1, -0.2, 0.97]) / np.linalg.norm([0.1, -0.2, 0.97])
FIELD = np.array([0.21, -0.05, -0.43])


# --- state ---------------------------------------------------------------------

def test_init_sets_the_parameters_and_a_fresh_identity_calibration():
    s = [math.nan] * (OFF + MC_SIZE + 2)
    mk.mc_init(s, OFF, 1, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7)
    e = [math.nan] * (OFF + MC_SIZE + 2)
    for k in range(MC_SIZE):
        e[OFF + k] = 0.0
    for slot, v in ((MC_NOISE, 0.1), (MC_FIELD_RW, 0.2), (MC_SOFT_IRON, 0.3), (MC_DELAY, 0.4),
                    (MC_HEADING, 0.5), (MC_DEADBAND, 0.6), (MC_DRIFT, 0.7), (MC_ENABLED, 1.0),
                    (MC_SCALE, 1.0), (MC_FRESH, 1.0), (MC_QUALITY, math.inf), (MC_NIS, 3.0),
                    (MC_HELD, -1.0), (MC_IDENTITY, 1.0), (MC_FIELD_SCALE, 1.0),
                    (MC_READY, 0.0), (MC_COEF, 1.0), (MC_COEF + 4, 1.0), (MC_COEF + 8, 1.0)):
        e[OFF + slot] = v
    assert_block(s, e)
    assert s[OFF + MC_SIZE:] == e[OFF + MC_SIZE:]  # after the block: untouched
    mk.mc_init(s, OFF, 0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7)
    e[OFF + MC_ENABLED] = 0.0
    e[OFF + MC_READY] = 1.0  # off: the field as given is ready
    assert_block(s, e)


def dirty(seed):
    """An estimator's state whose calibration block holds random values in every slot."""
    s = estimator_state()
    rng = np.random.default_rng(seed)
    put(s, 0, rng.uniform(0.5, 2.0, MC_SIZE))
    return s


def test_reset_forgets_everything_learned_and_keeps_the_parameters_and_scratch():
    s = dirty(1)
    e = list(s)
    mk.mc_reset(s, OFF)
    put(e, MC_X, np.zeros(N + N * N))
    put(e, MC_PRIOR_X, np.zeros(9 + 1 + 81))
    put(e, MC_CANDIDATE, np.zeros(8))
    put(e, MC_FIELDS, np.zeros(6))
    put(e, MC_SEEN_Y, np.zeros(8))
    for slot, v in ((MC_HAS_PRIOR, 0.0), (MC_PRIOR_COV, 0.0), (MC_SCALE, 1.0), (MC_FRESH, 1.0),
                    (MC_LOADED, 0.0), (MC_CONVERGED, 0.0), (MC_QUALITY, math.inf),
                    (MC_STALE, 0.0), (MC_LEARNED, 0.0), (MC_REFUSED_SHARE, 0.0), (MC_NIS, 3.0),
                    (MC_HELD, -1.0), (MC_IDENTITY, 1.0), (MC_SHIFT, 0.0), (MC_WATCHED, 0.0),
                    (MC_FIELD_SCALE, 1.0), (MC_ASSESSED, 0.0), (MC_WATCHING, 0.0)):
        e[OFF + slot] = v
    expect_cache(e)
    assert_block(s, e)


def test_restart_keeps_what_is_learned_as_the_prior_and_follows_the_field_afresh():
    s = dirty(2)
    s[OFF + MC_ENABLED] = 1.0
    s[OFF + MC_FRESH] = 0.0
    e = list(s)
    mk.mc_restart(s, OFF)
    put(e, MC_PRIOR_X, x_of(e)[3:])
    put(e, MC_PRIOR_P, p_of(e)[3:, 3:])
    e[OFF + MC_PRIOR_SCALE] = e[OFF + MC_SCALE]
    e[OFF + MC_HAS_PRIOR] = 1.0
    e[OFF + MC_PRIOR_COV] = 1.0
    e[OFF + MC_FRESH] = 1.0
    assert_block(s, e)
    # Already fresh (nothing learned since), or off: only fresh.
    for enabled, fresh in ((1.0, 1.0), (0.0, 0.0)):
        s = dirty(3)
        s[OFF + MC_ENABLED] = enabled
        s[OFF + MC_FRESH] = fresh
        e = list(s)
        e[OFF + MC_FRESH] = 1.0
        mk.mc_restart(s, OFF)
        assert_block(s, e)


def test_a_loaded_calibration_is_the_prior_without_covariance_and_applied():
    s = dirty(4)
    s[OFF + MC_ENABLED] = 1.0
    prior = np.arange(1, 10) / 10.0
    e = list(s)
    mk.mc_load_state(s, OFF, *prior, 1.25)
    put(e, MC_PRIOR_X, prior)
    put(e, MC_X + 3, prior)  # applied at once
    for slot, v in ((MC_PRIOR_SCALE, 1.25), (MC_SCALE, 1.25), (MC_HAS_PRIOR, 1.0),
                    (MC_PRIOR_COV, 0.0), (MC_FRESH, 1.0), (MC_LOADED, 1.0), (MC_IDENTITY, 0.0),
                    (MC_CONVERGED, 0.0)):
        e[OFF + slot] = v
    expect_cache(e)
    assert e[OFF + MC_APPLIED] == 1.0
    assert_block(s, e)
    # Off: nothing loaded, the field as given.
    s = dirty(5)
    s[OFF + MC_ENABLED] = 0.0
    e = list(s)
    mk.mc_load_state(s, OFF, *prior, 1.25)
    expect_cache(e)
    assert e[OFF + MC_READY] == 1.0 and e[OFF + MC_APPLIED] == 0.0
    assert_block(s, e)


# --- the quality and convergence -----------------------------------------------

@pytest.mark.parametrize('seed', range(3))
@pytest.mark.parametrize('with_up', [True, False])
def test_the_quality_is_the_heading_error_of_the_calibrated_fields_covariance(seed, with_up):
    s = estimator_state()
    rng = np.random.default_rng(seed)
    random_calibration(s, rng)
    seen(s, FIELD + rng.normal(0.0, 0.05, 3), UP if with_up else None)
    s[OFF + MC_LOADED] = 1.0  # not learning: the quality only
    s[OFF + MC_STALE] = 1.0
    e = list(s)
    mk.mc_assess(s, OFF, 0.01)
    expect_assessed(e)
    assert 0.0 < e[OFF + MC_QUALITY] < 1.0
    assert_block(s, e)


def test_a_covariance_with_no_heading_variance_gives_a_quality_of_zero():
    s = estimator_state()
    random_calibration(s, np.random.default_rng(4))
    put(s, MC_P, -1e-4 * np.eye(N))  # not a covariance: its quadratic form is negative
    seen(s, FIELD, UP)
    s[OFF + MC_LOADED] = 1.0
    mk.mc_assess(s, OFF, 0.01)
    assert s[OFF + MC_QUALITY] == 0.0


def test_without_a_live_field_assessing_only_clears_stale():
    s = dirty(6)
    s[OFF + MC_SEEN_LIVE] = 0.0
    s[OFF + MC_STALE] = 1.0
    e = list(s)
    e[OFF + MC_STALE] = 0.0
    mk.mc_assess(s, OFF, 0.01)
    assert_block(s, e)


def learning(seed, with_up=True, scale=1e-10, field=FIELD):
    """A calibration learning (not converged), its latest field seen, the hold not started."""
    s = estimator_state()
    random_calibration(s, np.random.default_rng(seed), scale)
    seen(s, field, UP if with_up else None)
    s[OFF + MC_HEADING] = 1.0
    return s


def kernel_quality(s):
    c = list(s)
    mk.mc_assess(c, OFF, 0.0)
    return c[OFF + MC_QUALITY]


@pytest.mark.parametrize('with_up', [True, False])
def test_a_quality_below_the_threshold_starts_the_hold_from_the_calibration_now(with_up):
    s = learning(7, with_up)
    e = list(s)
    mk.mc_assess(s, OFF, 0.25)
    expect_assessed(e)
    assert e[OFF + MC_QUALITY] < 1e-3
    put(e, MC_CANDIDATE, x_of(e)[3:11])
    e[OFF + MC_HELD] = 0.25
    assert_block(s, e)
    # Held CAL_HOLD s in all (1.75 + 0.25): converged.
    s[OFF + MC_HELD] = 1.75
    e = list(s)
    mk.mc_assess(s, OFF, 0.25)
    expect_assessed(e)
    e[OFF + MC_HELD] = CAL_HOLD
    e[OFF + MC_CONVERGED] = 1.0
    assert_block(s, e)


@pytest.mark.parametrize('with_up', [True, False])
@pytest.mark.parametrize('sign', [1.0, -1.0])
@pytest.mark.parametrize('apart', [1.5, 1.9, 2.1, 2.5])
@pytest.mark.parametrize('held', [0.0, 0.5])
def test_the_hold_starts_over_when_the_calibration_turned_the_heading(with_up, sign, apart,
                                                                      held):
    """Turned by more than CAL_HOLD_TURN × heading since the hold started: held again from 0."""
    field = np.array([0.3, -0.35, -0.25])  # without an up, the axis: far from unit
    s = learning(8, with_up, field=field)
    s[OFF + MC_HELD] = held
    x = x_of(s)
    candidate = x[3:11] + sign * np.array([0.02, -0.01, 0.0, 0.01, 0.0, 0.0, 0.0, 0.0])
    put(s, MC_CANDIDATE, candidate)
    axis = UP if with_up else field
    turned = turn_about(axis, calibrated(x[3:11], field), calibrated(candidate, field))
    assert abs(turned) > 1e-3
    s[OFF + MC_HEADING] = abs(turned) / apart  # 2 × heading above or below the turn
    e = list(s)
    mk.mc_assess(s, OFF, 0.25)
    expect_assessed(e)
    assert e[OFF + MC_QUALITY] < e[OFF + MC_HEADING]
    if apart > 2.0:
        put(e, MC_CANDIDATE, x[3:11])
        e[OFF + MC_HELD] = 0.0
    else:
        e[OFF + MC_HELD] = held + 0.25
    assert_block(s, e)


def test_the_hold_pauses_a_little_above_the_threshold_and_ends_well_above_it():
    s = learning(9, scale=1e-4)
    q = kernel_quality(s)
    s[OFF + MC_HELD] = 0.5
    put(s, MC_CANDIDATE, np.full(8, 0.125))
    for heading, held in ((q / 1.5, 0.5), (q, 0.5), (q / 2.0, 0.5), (q / 2.5, -1.0)):
        c = list(s)
        c[OFF + MC_HEADING] = heading
        e = list(c)
        mk.mc_assess(c, OFF, 0.25)
        expect_assessed(e)
        e[OFF + MC_HELD] = held
        assert_block(c, e)
    # Converged or loaded: no hold.
    for slot in (MC_CONVERGED, MC_LOADED):
        c = list(s)
        c[OFF + slot] = 1.0
        c[OFF + MC_HEADING] = q / 2.5
        e = list(c)
        mk.mc_assess(c, OFF, 0.25)
        expect_assessed(e)
        assert_block(c, e)
        c[OFF + MC_HEADING] = e[OFF + MC_HEADING] = 2.0 * q
        mk.mc_assess(c, OFF, 0.25)
        assert_block(c, e)


def test_the_quality_asked_for_is_assessed_only_when_stale():
    s = learning(10)
    s[OFF + MC_HELD] = 0.5
    put(s, MC_CANDIDATE, x_of(s)[3:11])
    s[OFF + MC_QUALITY] = 0.75
    s[OFF + MC_STALE] = 0.0
    e = list(s)
    assert mk.mc_quality(s, OFF) == 0.75
    assert_block(s, e)
    s[OFF + MC_STALE] = 1.0
    e = list(s)
    expect_assessed(e)  # with no time elapsed: held as it was
    assert mk.mc_quality(s, OFF) == pytest.approx(e[OFF + MC_QUALITY], rel=1e-9)
    assert_block(s, e)


# --- outputs -----------------------------------------------------------------------

@pytest.mark.parametrize('enabled, loaded, converged, identity, applied', [
    (1.0, 1.0, 0.0, 0.0, True), (1.0, 0.0, 1.0, 0.0, True), (1.0, 1.0, 1.0, 1.0, False),
    (1.0, 0.0, 0.0, 0.0, False), (0.0, 1.0, 1.0, 0.0, False)])
def test_the_calibration_applied_is_the_scale_times_i_plus_d_and_the_offset(
        enabled, loaded, converged, identity, applied):
    s = dirty(11)
    for slot, v in ((MC_ENABLED, enabled), (MC_LOADED, loaded), (MC_CONVERGED, converged),
                    (MC_IDENTITY, identity)):
        s[OFF + slot] = v
    e = list(s)
    mk.mc_cache(s, OFF)
    expect_cache(e)
    assert e[OFF + MC_APPLIED] == (1.0 if applied else 0.0)
    assert_block(s, e)
    y = np.array([0.3, -0.7, 1.1])
    want = y
    if applied:
        x = x_of(s)
        want = s[OFF + MC_SCALE] * calibrated(x[3:11], y)
    assert mk.mc_apply(s, OFF, *y) == pytest.approx(want, rel=1e-12)


def test_the_field_now_is_the_scale_times_s_minus_z():
    s = dirty(12)
    x = x_of(s)
    assert mk.mc_field(s, OFF) == pytest.approx(s[OFF + MC_SCALE] * (x[:3] - x[3:6]), rel=1e-12)


def test_calibrated_is_i_plus_d_times_y_minus_z():
    s = dirty(13)
    zd = get(s, MC_CANDIDATE, 8)
    y = np.array([0.4, 0.9, -0.2])
    want = calibrated(zd, y)
    assert mk.mc_calibrated(s, OFF + MC_CANDIDATE, *y) == pytest.approx(want, rel=1e-12)


@pytest.mark.parametrize('seed', range(4))
def test_the_heading_between_two_fields_is_the_angle_of_their_horizontal_parts(seed):
    rng = np.random.default_rng(seed)
    u = rng.normal(size=3)
    u /= np.linalg.norm(u)
    f, g = rng.normal(size=3), rng.normal(size=3)
    assert mk.mc_heading_between(*u, *f, *g) == pytest.approx(turn_about(u, f, g), rel=1e-12)
    # g: f turned about u by a known angle (Rodrigues), plus some of u.
    angle = rng.uniform(-3.0, 3.0)
    turned = (f * math.cos(angle) + np.cross(u, f) * math.sin(angle)
              + u * (u @ f) * (1.0 - math.cos(angle)) + 0.7 * u)
    assert mk.mc_heading_between(*u, *f, *turned) == pytest.approx(angle, rel=1e-9)


def test_a_loaded_calibration_is_applied_before_the_next_field():
    """A fault found here: applied from the next field on (the field as given till then)."""
    from ext_observer.core.ahrs.magcal import MagCalibrator
    cal = MagCalibrator()
    soft, bias = np.array([[1.1, 0.02, 0.0], [0.02, 0.95, 0.01], [0.0, 0.01, 1.0]]), FIELD / 3
    cal.load(bias, soft)
    assert cal.applied
    assert cal.apply(FIELD) == pytest.approx(np.linalg.solve(soft, FIELD - bias), rel=1e-12)


def test_the_heading_turn_is_the_same_whatever_the_norm_of_the_axis():
    """A fault found here: the axis was taken as unit (the raw field, an up of any norm)."""
    from ext_observer.core.ahrs.magcal import MagCalibrator
    cal = MagCalibrator()
    cal.load((0.1, -0.2, 0.05), np.diag([1.1, 0.95, 1.0]))
    cal.learn(FIELD, (1.0, 0.0, 0.0, 0.0), 0.01, (0.0, 0.0, 0.0), UP)
    turn = cal.heading_turn(FIELD, UP)
    assert abs(turn) > 0.05
    assert cal.heading_turn(FIELD, 40.0 * UP) == pytest.approx(turn, rel=1e-12)


def test_a_calibrated_field_along_the_vertical_is_no_crash_nor_nan():
    s = estimator_state()
    random_calibration(s, np.random.default_rng(18))
    put(s, MC_X + 3, (0.1, 0.2, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0))
    seen(s, (0.1, 0.2, -0.5), (0.0, 0.0, 1.0))  # calibrated: (0, 0, -0.5) exactly
    s[OFF + MC_LOADED] = 1.0
    mk.mc_assess(s, OFF, 0.01)
    # No horizontal part (never exactly so in practice): a number, not a
    # division by zero (0 today: nothing of the covariance lies across it).
    assert s[OFF + MC_QUALITY] >= 0.0


def test_a_calibrated_field_of_zero_has_no_heading():
    s = estimator_state()
    random_calibration(s, np.random.default_rng(17))
    put(s, MC_X + 6, np.zeros(5))
    y = x_of(s)[3:6]  # calibrated to 0 exactly: (I + 0) y − z
    seen(s, y)
    s[OFF + MC_LOADED] = 1.0
    mk.mc_assess(s, OFF, 0.01)
    with np.errstate(divide='ignore'):
        jp, c, _ = assessed(s)
    assert s[OFF + MC_QUALITY] == pytest.approx(math.sqrt(np.trace(c)) / 1e-300, rel=1e-6)


# The learning step (mc_learn) -------------------------------------------------------------
#
# mc_learn is called on the calibration's block of an estimator's flat state, and the whole
# block compared with what it must leave: the filter's steps (mc_predict, mc_start, mc_update)
# run on a copy, then the counts (fields, used, gated, refused, invalid, resets), the share of
# fields refused while turning, a start over and what it clears, the latest field seen, the
# quality (in matrix form, above), the hold and the watch of the heading turn.


# --- the watch of a calibration not applied yet -------------------------------------

@pytest.mark.parametrize('watched, n', [(0.0, 1.0), (4.0, 5.0), (-0.5, 1.0),
                                        (CAL_SHIFT_SAMPLES + 500.0, CAL_SHIFT_SAMPLES)])
def test_the_watch_keeps_the_mean_square_heading_turn_of_the_calibration(watched, n):
    s = learning(14)
    s[OFF + MC_WATCHED] = watched
    s[OFF + MC_SHIFT] = 0.01
    y = FIELD + np.array([0.02, 0.01, -0.03])
    e = list(s)
    mk.mc_watch(s, OFF, *y, *UP)
    angle = turn_about(UP, y, calibrated(x_of(s)[3:11], y))
    assert abs(angle) > 0.01
    e[OFF + MC_WATCHED] = watched + 1.0
    e[OFF + MC_SHIFT] = 0.01 + (angle * angle - 0.01) / n
    got = s[OFF + MC_SHIFT]
    s[OFF + MC_SHIFT] = e[OFF + MC_SHIFT]
    assert got == pytest.approx(e[OFF + MC_SHIFT], rel=1e-12)
    assert_block(s, e)


def test_the_watch_applies_a_converged_calibration_that_turns_the_heading():
    s = learning(15)
    s[OFF + MC_CONVERGED] = 1.0
    s[OFF + MC_QUALITY] = 1e-3
    s[OFF + MC_DEADBAND] = 1e-3
    y = FIELD + np.array([0.02, 0.01, -0.03])
    mk.mc_watch(s, OFF, *y, *UP)
    assert s[OFF + MC_IDENTITY] == 0.0


@pytest.mark.parametrize('converged, shift, deadband, quality, applied', [
    (1.0, 0.011, 0.1, 0.02, True),      # beyond the deadband and 3 σ
    (0.0, 0.011, 0.1, 0.02, False),     # not converged
    (1.0, 0.01, 0.1, 0.02, False),      # at the deadband
    (1.0, 0.0036, 0.05, 0.02, False),   # at 3 σ (0.06²)
    (1.0, 0.0035, 0.05, 0.02, False),   # beyond the deadband, within 3 σ
    (1.0, 0.0035, 0.06, 0.01, False),   # within the deadband, beyond 3 σ
])
def test_a_converged_calibration_is_applied_once_it_turns_the_heading_significantly(
        converged, shift, deadband, quality, applied):
    s = dirty(16)
    s[OFF + MC_IDENTITY] = 1.0
    for slot, v in ((MC_CONVERGED, converged), (MC_SHIFT, shift), (MC_DEADBAND, deadband),
                    (MC_QUALITY, quality)):
        s[OFF + slot] = v
    if shift in (0.01, 0.0036):  # exactly at the bound, as the kernel squares it
        s[OFF + MC_SHIFT] = (deadband * deadband if shift == 0.01
                             else (3.0 * quality) * (3.0 * quality))
    e = list(s)
    e[OFF + MC_IDENTITY] = 0.0 if applied else 1.0
    mk.mc_reconsider(s, OFF)
    assert_block(s, e)


# --- learning -------------------------------------------------------------------

def learn(s, y, r=(1.0, 0.0, 0.0, 0.0), dt=0.01, w=(0.0, 0.0, 0.0), up=UP, allow=True):
    return mk.mc_learn(s, OFF, floats(y), floats(r), dt, floats(w), 0.0 if up is None else 1.0,
                       floats((7.0, 8.0, 9.0) if up is None else up), 1.0 if allow else 0.0)


def floats(v):
    """A vector as the kernel takes it: a tuple of floats."""
    return tuple(float(x) for x in v)


def turn(angle, axis):
    axis = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    return (math.cos(0.5 * angle), *(math.sin(0.5 * angle) * axis))


def predicted(e, w):
    """The field the filter expects: ``A⁻¹ (s + τ ω × (s − z))``."""
    x = x_of(e)
    sv, z, d, tau = x[:3], x[3:6], x[6:11], x[11]
    return np.linalg.solve(np.eye(3) + d_matrix(d), sv + tau * np.cross(w, sv - z))


def started(up=UP):
    """The estimator's calibration after its first field."""
    s = estimator_state()
    assert learn(s, FIELD, up=up) == 1.0
    put(s, MC_FIELDS, (10.0, 7.0, 2.0, 3.0, 1.0, 2.0))  # counts so far: counted on
    return s


def expect_seen(e, y, up, live):
    put(e, MC_SEEN_Y, y)
    if up is not None:
        put(e, MC_SEEN_UP, up)
    e[OFF + MC_SEEN_HAS_UP] = 0.0 if up is None else 1.0
    e[OFF + MC_SEEN_LIVE] = 1.0 if live else 0.0
    e[OFF + MC_ASSESSED] = 0.0
    e[OFF + MC_WATCHING] = 0.0
    if live:
        expect_assessed(e)
        e[OFF + MC_ASSESSED] = 1.0
    else:
        e[OFF + MC_STALE] = 1.0


@pytest.mark.parametrize('up', [UP, None])
def test_the_first_valid_field_starts_the_filter_and_is_assessed(up):
    s = estimator_state()
    e = list(s)
    assert learn(s, FIELD, w=(0.3, -0.1, 0.2), up=up) == 1.0
    norm = float(np.linalg.norm(FIELD))
    mf.mc_start(e, OFF, *FIELD, norm)
    mf.mc_update(e, OFF, *FIELD, 0.3, -0.1, 0.2, False, norm)
    e[OFF + MC_FIELDS] = 1.0
    e[OFF + MC_USED] = 1.0
    expect_seen(e, FIELD, up, True)
    assert e[OFF + MC_QUALITY] > 2.0 * e[OFF + MC_HEADING]  # no hold yet
    expect_cache(e)
    assert_block(s, e)


def step(s, y, r, dt, w, allow=True, up=UP, watched_share=None):
    """``mc_learn`` of a filter started already, and what it must leave (filter, counts)."""
    e = list(s)
    result = learn(s, y, r, dt, w, up, allow)
    norm = float(np.linalg.norm(y))
    take = math.isfinite(norm) and norm > 0.0
    mf.mc_predict(e, OFF, *r, dt)
    live = take and allow
    use = mf.mc_update(e, OFF, *(y if live else (0.0, 0.0, 0.0)), *np.nan_to_num(w), live, norm)
    e[OFF + MC_FIELDS] += 1.0
    e[OFF + MC_USED] += 1.0 if use else 0.0
    e[OFF + MC_GATED] += 1.0 if live and not use else 0.0
    e[OFF + MC_INVALID] += 0.0 if take else 1.0
    e[OFF + MC_REFUSED] += 1.0 if take and not allow else 0.0
    if watched_share is not None:
        k = 1.0 - math.exp(-dt / CAL_REFUSED_TAU)
        share = e[OFF + MC_REFUSED_SHARE]
        e[OFF + MC_REFUSED_SHARE] = share + k * (watched_share - share)
    assert result == (1.0 if use else 0.0)
    return e, live, use


RATE = (0.3, -0.2, 0.25)
R = turn(0.05, (0.2, 0.5, 0.8))


@pytest.mark.parametrize('offset, used', [(0.0, True), (3.0, False)])
@pytest.mark.parametrize('rate', [RATE, (0.3, 0.0, 0.0), (0.0, -0.3, 0.0), (0.0, 0.0, 0.3)])
def test_a_field_learned_while_turning_is_counted_and_moves_the_refused_share(offset, used,
                                                                              rate):
    s = started()
    s[OFF + MC_REFUSED_SHARE] = 0.5
    c = list(s)
    mf.mc_predict(c, OFF, *R, 0.05)
    y = predicted(c, rate) + offset * np.linalg.norm(FIELD)
    e, live, use = step(s, y, R, 0.05, rate, watched_share=0.0 if used else 1.0)
    assert use == used
    expect_seen(e, y, UP, True)
    expect_cache(e)
    assert_block(s, e)


def test_a_field_learned_at_the_turning_rate_leaves_the_refused_share():
    s = started()
    s[OFF + MC_REFUSED_SHARE] = 0.5
    c = list(s)
    mf.mc_predict(c, OFF, *R, 0.05)
    y = predicted(c, (0.2, 0.0, 0.0)) + 3.0 * np.linalg.norm(FIELD)
    e, live, use = step(s, y, R, 0.05, (0.2, 0.0, 0.0))
    assert not use and e[OFF + MC_REFUSED_SHARE] == 0.5
    expect_seen(e, y, UP, True)
    expect_cache(e)
    assert_block(s, e)


LOST = ((MC_FRESH, 1.0), (MC_LOADED, 0.0), (MC_CONVERGED, 0.0), (MC_IDENTITY, 1.0),
        (MC_SHIFT, 0.0), (MC_WATCHED, 0.0), (MC_REFUSED_SHARE, 0.0), (MC_HAS_PRIOR, 0.0))


def learned_for_long(s):
    """Flags a start over must clear."""
    for slot, v in ((MC_CONVERGED, 1.0), (MC_IDENTITY, 0.0), (MC_SHIFT, 0.3),
                    (MC_WATCHED, 5.0), (MC_HAS_PRIOR, 1.0), (MC_PRIOR_COV, 1.0)):
        s[OFF + slot] = v


def test_most_fields_refused_while_turning_start_the_calibration_over():
    s = started()
    learned_for_long(s)
    s[OFF + MC_REFUSED_SHARE] = 0.69
    c = list(s)
    mf.mc_predict(c, OFF, *R, 1.0)
    y = predicted(c, RATE) + 10.0 * np.linalg.norm(FIELD)
    e, live, use = step(s, y, R, 1.0, RATE, watched_share=1.0)
    assert not use and e[OFF + MC_REFUSED_SHARE] > 0.7
    for slot, v in LOST:
        e[OFF + slot] = v
    e[OFF + MC_RESETS] += 1.0
    expect_seen(e, y, UP, False)
    expect_cache(e)
    assert_block(s, e)


@pytest.mark.parametrize('k, value, lost', [(0, 0.5, True), (1, -0.5, True), (2, 0.5, True),
                                            (3, -0.5, True), (4, 0.5, True), (5, 0.5, False),
                                            (4, 0.15, False)])
def test_a_soft_iron_far_beyond_its_prior_starts_the_calibration_over(k, value, lost):
    s = started()
    learned_for_long(s)
    s[OFF + MC_X + 6 + k] = value  # CAL_WILD × soft_iron = 0.2
    c = list(s)
    mf.mc_predict(c, OFF, *R, 0.01)
    y = predicted(c, (0.0, 0.0, 0.0))
    e, live, use = step(s, y, R, 0.01, (0.0, 0.0, 0.0))
    assert use
    if lost:
        for slot, v in LOST:
            e[OFF + slot] = v
        e[OFF + MC_RESETS] += 1.0
    # Converged and applied where not lost: no quality assessed.
    expect_seen(e, y, UP, False)
    e[OFF + MC_SEEN_LIVE] = 0.0 if lost else 1.0
    expect_cache(e)
    assert_block(s, e)


@pytest.mark.parametrize('y', [(math.nan, 0.1, 0.2), (0.0, 0.0, 0.0), (0.1, math.inf, 0.2)])
@pytest.mark.parametrize('allow', [True, False])
def test_an_invalid_field_is_counted_and_teaches_nothing(y, allow):
    s = started()
    s[OFF + MC_REFUSED_SHARE] = 0.5
    e, live, use = step(s, y, R, 0.01, RATE, allow=allow)
    expect_seen(e, (0.0, 0.0, 0.0), UP, False)
    expect_cache(e)
    assert_block(s, e)
    # While fresh: nothing predicted.
    s = estimator_state()
    e = list(s)
    assert learn(s, y, R, 0.01, RATE, allow=allow) == 0.0
    mf.mc_update(e, OFF, 0.0, 0.0, 0.0, *RATE, False, 0.0)
    e[OFF + MC_FIELDS] = 1.0
    e[OFF + MC_INVALID] = 1.0
    expect_seen(e, (0.0, 0.0, 0.0), UP, False)
    expect_cache(e)
    assert_block(s, e)


@pytest.mark.parametrize('applied', [False, True])
def test_a_field_the_caller_refuses_is_counted_and_watched_where_applied(applied):
    s = started()
    s[OFF + MC_REFUSED_SHARE] = 0.5
    if applied:
        s[OFF + MC_CONVERGED] = 1.0
        s[OFF + MC_IDENTITY] = 0.0
        mk.mc_cache(s, OFF)
    e, live, use = step(s, FIELD, R, 0.05, RATE, allow=False,
                        watched_share=1.0 if applied else None)
    assert e[OFF + MC_REFUSED] == 4.0
    expect_seen(e, (0.0, 0.0, 0.0), UP, False)
    expect_cache(e)
    assert_block(s, e)


def test_off_nothing_is_counted_nor_learned():
    s = estimator_state()
    s[OFF + MC_ENABLED] = 0.0
    mk.mc_cache(s, OFF)
    e = list(s)
    assert learn(s, FIELD, R, 0.01, RATE) == 0.0
    mf.mc_update(e, OFF, 0.0, 0.0, 0.0, *RATE, False, 0.0)
    expect_seen(e, (0.0, 0.0, 0.0), UP, False)
    expect_cache(e)
    assert_block(s, e)


@pytest.mark.parametrize('up', [UP, None])
def test_a_calibration_nearly_good_enough_is_held_and_watched(up):
    s = started(up)
    s[OFF + MC_HEADING] = 100.0
    put(s, MC_SEEN_UP, (5.0, 6.0, 7.0))  # without an up: kept as it was
    c = list(s)
    mf.mc_predict(c, OFF, *R, 0.05)
    y = predicted(c, RATE) + 0.01 * np.linalg.norm(FIELD)
    e, live, use = step(s, y, R, 0.05, RATE, up=up, watched_share=0.0)
    assert use
    expect_seen(e, y, up, True)
    assert e[OFF + MC_QUALITY] < 100.0
    put(e, MC_CANDIDATE, x_of(e)[3:11])
    e[OFF + MC_HELD] = 0.05
    if up is not None:
        angle = turn_about(up, y, calibrated(x_of(e)[3:11], y))
        assert abs(angle) > 1e-4
        e[OFF + MC_WATCHED] = 1.0
        e[OFF + MC_SHIFT] = angle * angle
        e[OFF + MC_WATCHING] = 1.0
        assert s[OFF + MC_SHIFT] == pytest.approx(angle * angle, rel=1e-9)
        s[OFF + MC_SHIFT] = e[OFF + MC_SHIFT]
    expect_cache(e)
    assert_block(s, e)


@pytest.mark.parametrize('loaded, converged, identity, assessed', [
    (1.0, 0.0, 1.0, False), (0.0, 1.0, 1.0, True), (0.0, 1.0, 0.0, False),
    (0.0, 0.0, 0.0, True)])
def test_the_quality_is_assessed_while_learning_or_watching_a_converged_calibration(
        loaded, converged, identity, assessed):
    s = started()
    for slot, v in ((MC_LOADED, loaded), (MC_CONVERGED, converged), (MC_IDENTITY, identity)):
        s[OFF + slot] = v
    s[OFF + MC_QUALITY] = 0.5
    c = list(s)
    mf.mc_predict(c, OFF, *R, 0.05)
    y = predicted(c, RATE)
    e, live, use = step(s, y, R, 0.05, RATE, watched_share=0.0)
    expect_seen(e, y, UP, assessed)
    e[OFF + MC_SEEN_LIVE] = 1.0
    assert e[OFF + MC_QUALITY] != 0.5 if assessed else e[OFF + MC_QUALITY] == 0.5
    expect_cache(e)
    assert_block(s, e)


@pytest.mark.parametrize('axis', range(3))
def test_a_rate_that_is_not_finite_counts_as_zero(axis):
    s = started()
    c = list(s)
    mf.mc_predict(c, OFF, *R, 0.05)
    y = predicted(c, (0.0, 0.0, 0.0))
    zero, bad, some = list(s), list(s), list(s)
    rate = [0.0, 0.0, 0.0]
    learn(zero, y, R, 0.05, tuple(rate))
    rate[axis] = math.nan
    learn(bad, y, R, 0.05, tuple(rate))
    rate[axis] = 0.5
    learn(some, y, R, 0.05, tuple(rate))
    assert_block(bad, zero)
    # (the rate counts: its lag's column of the filter's measurement)
    assert not np.array_equal(p_of(some), p_of(zero))


def test_a_quality_at_the_threshold_is_not_watched():
    s = started()
    c = list(s)
    mf.mc_predict(c, OFF, *R, 0.05)
    y = predicted(c, RATE)
    c = list(s)
    learn(c, y, R, 0.05, RATE)
    quality = c[OFF + MC_QUALITY]
    for heading, watched in ((quality, 0.0), (math.nextafter(quality, math.inf), 1.0)):
        c = list(s)
        c[OFF + MC_HEADING] = heading
        learn(c, y, R, 0.05, RATE)
        assert c[OFF + MC_QUALITY] == quality
        assert c[OFF + MC_WATCHING] == watched and c[OFF + MC_WATCHED] == watched
