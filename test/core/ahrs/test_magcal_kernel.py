"""
The calibration's steps around its filter (core/ahrs/magcal_kernel.py), against independent forms.

Each step is called on a calibrator's record (plain, and compiled on a
structured one) and every field of the record is compared with what the
step must leave: the quality from the covariance of the calibrated field
``J P Jᵀ`` in numpy matrix form (``J = [−I, ∂(D(d) y)/∂d]``, its columns
from ``D`` of the unit vectors), the heading turned between two fields from
their projections on the horizontal plane, the applied calibration
``g (I + D)``, and the counts, flags and priors each step keeps. The
filter's own steps (``mc_predict``, ``mc_start``, ``mc_update``, tested in
test_magcal_filter.py and the calibration's tests) are run on a copy to say
what ``mc_learn`` must leave in the filter's fields. Written for mutmut's
survivors (docs/tests.md#mutmut): the end-to-end tests learn a calibration,
but a quality off by an index only delayed their convergence.
"""

import math
import sys

import numpy as np
import pytest

from ext_observer.core.ahrs import compiled as compiled_module
from ext_observer.core.ahrs import magcal_filter, magcal_kernel
from ext_observer.core.ahrs.ahrs_params import AhrsParams
from ext_observer.core.ahrs.magcal import MagCalibrator
from ext_observer.core.ahrs.magcal_layout import (CAL, CAL_HOLD, CAL_N, CAL_REFUSED_TAU,
                                                  CAL_SHIFT_SAMPLES)

N = CAL_N
PARAMS = AhrsParams()
NAMES = [path[-1] for path, _, _, _ in CAL.fields()]
# Fields computed by a different arithmetic here: compared to rounding.
ROUNDED = ('jp', 'c', 'quality', 'coef')
needs_numba = pytest.mark.skipif(not compiled_module.compiled_available(),
                                 reason='numba is not installed (requirements-test.txt has it)')


@pytest.fixture(params=[False, pytest.param(True, marks=needs_numba)],
                ids=['plain', 'compiled'])
def compiled(request):
    """The kernels to test: plain on plain records, or compiled on structured ones."""
    return request.param


def kernel(compiled):
    """magcal_kernel, or its compiled twin."""
    return compiled_module.kernels(True).magcal if compiled else magcal_kernel


def mk(s):
    """The kernel for the record ``s``: plain, or compiled for a structured record."""
    return kernel(isinstance(s, np.void))


def mf(s):
    """The filter for the record ``s``, as :func:`mk`."""
    if isinstance(s, np.void):
        package = kernel(True).__name__.rpartition('.')[0]
        return sys.modules[package + '.magcal_filter']
    return magcal_filter


def record(compiled):
    """A zeroed record with its fields as attributes (``numpy.record`` when compiled)."""
    if compiled:
        return CAL.holder(True).view(np.recarray)[0]
    return CAL.plain()


def copy(s):
    """A copy of the record, of its kind."""
    other = record(isinstance(s, np.void))
    CAL.copy(s, other)
    return other


def fresh(compiled):
    """A calibrator's record as an estimator sets it up (its parameters, mc_init)."""
    p = PARAMS
    s = record(compiled)
    mk(s).mc_init(s, True, p.mag_cal_noise, p.mag_cal_field_rw, p.mag_cal_soft_iron,
                  p.mag_cal_delay, p.mag_cal_heading, p.mag_cal_deadband, p.mag_cal_drift)
    return s


def get(s, name):
    """Field ``name``: a float, or an array for a vector."""
    value = CAL.get(s, name)
    return np.array(value, dtype=float) if isinstance(value, tuple) else value


def put(s, name, values, at=0):
    """``values`` into field ``name`` from index ``at``."""
    values = np.ravel(values)
    size = CAL.path(name)[1]
    assert at + len(values) <= size, f'{len(values)} values from {at} into {name} of {size}'
    if size == 1:
        setattr(s, name, float(values[0]))
        return
    target = getattr(s, name)
    for i, v in enumerate(values):
        target[at + i] = float(v)


def x_of(s):
    return get(s, 'x')


def p_of(s):
    return get(s, 'p').reshape(N, N)


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
    y = get(s, 'seen_y')
    jac = np.hstack([-np.eye(3), np.column_stack([d_matrix(e) @ y for e in np.eye(5)])])
    jp = jac @ p[3:11, 3:11]
    c = jp @ jac.T
    f = calibrated(x[3:11], y)
    if s.seen_has_up:
        e = np.cross(get(s, 'seen_up'), f)
        quality = math.sqrt(max(e @ c @ e, 0.0) / (e @ e)) / np.linalg.norm(e)
    else:
        quality = math.sqrt(np.trace(c)) / np.linalg.norm(f)
    return jp, c, quality


def expect_assessed(e):
    jp, c, quality = assessed(e)
    put(e, 'jp', jp)
    put(e, 'c', c)
    e.quality = quality
    e.stale = 0.0


def expect_cache(e):
    """What ``mc_cache`` must leave: ``g (I + D)`` and ``g z`` where applied."""
    on = e.enabled != 0.0
    ready = on and (e.loaded != 0.0 or e.converged != 0.0)
    applied = ready and e.identity == 0.0
    e.ready = 1.0 if ready or not on else 0.0
    e.applied = 1.0 if applied else 0.0
    a, z = np.eye(3), np.zeros(3)
    if applied:
        x, g = x_of(e), e.scale
        a, z = g * (np.eye(3) + d_matrix(x[6:11])), g * x[3:6]
    put(e, 'coef', np.concatenate([a.ravel(), z]))


def assert_block(s, e):
    """Every field of the record as expected: exactly, or to rounding where computed apart."""
    for name in NAMES:
        got, want = np.ravel(get(s, name)), np.ravel(get(e, name))
        if name in ROUNDED:
            assert got == pytest.approx(want, rel=1e-9, abs=1e-15), name
            continue
        differ = np.flatnonzero(~((got == want) | (np.isnan(got) & np.isnan(want))))
        assert differ.size == 0, f'{name}{differ.tolist()}: {got[differ]} != {want[differ]}'


def random_calibration(s, rng, scale=1e-4):
    """A learned state: ``x`` near a calibration, ``P`` positive definite (and not symmetric)."""
    x = np.concatenate([rng.normal(0.3, 0.1, 3), rng.normal(0.0, 0.1, 3),
                        rng.normal(0.0, 0.04, 5), [0.01]])
    a = rng.normal(size=(N, N))
    b = rng.normal(size=(N, N))
    put(s, 'x', x)
    put(s, 'p', scale * (a @ a.T + np.eye(N) + 0.3 * (b - b.T)))
    s.fresh = 0.0


def seen(s, y, up=None):
    put(s, 'seen_y', y)
    if up is not None:
        put(s, 'seen_up', up)
    s.seen_has_up = 0.0 if up is None else 1.0
    s.seen_live = 1.0


UP = np.array([0.1, -0.2, 0.97]) / np.linalg.norm([0.1, -0.2, 0.97])
FIELD = np.array([0.21, -0.05, -0.43])


# --- state ---------------------------------------------------------------------

def test_init_sets_the_parameters_and_a_fresh_identity_calibration(compiled):
    s = record(compiled)
    CAL.load(s, [math.nan] * CAL.size)
    mk(s).mc_init(s, 1, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7)
    e = record(compiled)
    for name, v in (('noise', 0.1), ('field_rw', 0.2), ('soft_iron', 0.3), ('delay', 0.4),
                    ('heading', 0.5), ('deadband', 0.6), ('drift', 0.7), ('enabled', 1.0),
                    ('scale', 1.0), ('fresh', 1.0), ('quality', math.inf), ('nis', 3.0),
                    ('held', -1.0), ('identity', 1.0), ('field_scale', 1.0),
                    ('ready', 0.0)):
        put(e, name, v)
    put(e, 'coef', np.eye(3).ravel())
    assert_block(s, e)
    mk(s).mc_init(s, 0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7)
    e.enabled = 0.0
    e.ready = 1.0  # off: the field as given is ready
    assert_block(s, e)


def dirty(compiled, seed):
    """A record that holds random values in every field."""
    s = record(compiled)
    CAL.load(s, np.random.default_rng(seed).uniform(0.5, 2.0, CAL.size))
    return s


def test_reset_forgets_everything_learned_and_keeps_the_parameters_and_scratch(compiled):
    s = dirty(compiled, 1)
    e = copy(s)
    mk(s).mc_reset(s)
    for name in ('x', 'p', 'prior_x', 'prior_scale', 'prior_p', 'candidate', 'fields', 'used',
                 'gated', 'refused', 'invalid', 'resets', 'seen_y', 'seen_up', 'seen_has_up',
                 'seen_live'):
        put(e, name, np.zeros(CAL.path(name)[1]))
    for name, v in (('has_prior', 0.0), ('prior_cov', 0.0), ('scale', 1.0), ('fresh', 1.0),
                    ('loaded', 0.0), ('converged', 0.0), ('quality', math.inf),
                    ('stale', 0.0), ('learned', 0.0), ('refused_share', 0.0), ('nis', 3.0),
                    ('held', -1.0), ('identity', 1.0), ('shift', 0.0), ('watched', 0.0),
                    ('field_scale', 1.0), ('assessed', 0.0), ('watching', 0.0)):
        put(e, name, v)
    expect_cache(e)
    assert_block(s, e)


def test_restart_keeps_what_is_learned_as_the_prior_and_follows_the_field_afresh(compiled):
    s = dirty(compiled, 2)
    s.enabled = 1.0
    s.fresh = 0.0
    e = copy(s)
    mk(s).mc_restart(s)
    put(e, 'prior_x', x_of(e)[3:])
    put(e, 'prior_p', p_of(e)[3:, 3:])
    e.prior_scale = e.scale
    e.has_prior = 1.0
    e.prior_cov = 1.0
    e.fresh = 1.0
    e.refused_share = 0.0  # counted afresh, unless the caller keeps it
    assert_block(s, e)
    # Already fresh (nothing learned since), or off: only fresh and the share.
    for enabled, fresh in ((1.0, 1.0), (0.0, 0.0)):
        s = dirty(compiled, 3)
        s.enabled = enabled
        s.fresh = fresh
        e = copy(s)
        e.fresh = 1.0
        e.refused_share = 0.3
        mk(s).mc_restart(s, 0.3)
        assert_block(s, e)


def test_a_loaded_calibration_is_the_prior_without_covariance_and_applied(compiled):
    s = dirty(compiled, 4)
    s.enabled = 1.0
    prior = np.arange(1, 10) / 10.0
    e = copy(s)
    mk(s).mc_load_state(s, *prior, 1.25)
    put(e, 'prior_x', prior)
    put(e, 'x', prior, at=3)  # applied at once
    for name, v in (('prior_scale', 1.25), ('scale', 1.25), ('has_prior', 1.0),
                    ('prior_cov', 0.0), ('fresh', 1.0), ('loaded', 1.0), ('identity', 0.0),
                    ('converged', 0.0), ('refused_share', 0.0)):
        put(e, name, v)
    expect_cache(e)
    assert e.applied == 1.0
    assert_block(s, e)
    # Off: nothing loaded, the field as given.
    s = dirty(compiled, 5)
    s.enabled = 0.0
    e = copy(s)
    mk(s).mc_load_state(s, *prior, 1.25)
    expect_cache(e)
    assert e.ready == 1.0 and e.applied == 0.0
    assert_block(s, e)


# --- the quality and convergence -----------------------------------------------

@pytest.mark.parametrize('seed', range(3))
@pytest.mark.parametrize('with_up', [True, False])
def test_the_quality_is_the_heading_error_of_the_calibrated_fields_covariance(compiled, seed,
                                                                                with_up):
    s = fresh(compiled)
    rng = np.random.default_rng(seed)
    random_calibration(s, rng)
    seen(s, FIELD + rng.normal(0.0, 0.05, 3), UP if with_up else None)
    s.loaded = 1.0  # not learning: the quality only
    s.stale = 1.0
    e = copy(s)
    mk(s).mc_assess(s, 0.01)
    expect_assessed(e)
    assert 0.0 < e.quality < 1.0
    assert_block(s, e)


def test_a_covariance_with_no_heading_variance_gives_a_quality_of_zero(compiled):
    s = fresh(compiled)
    random_calibration(s, np.random.default_rng(4))
    put(s, 'p', -1e-4 * np.eye(N))  # not a covariance: its quadratic form is negative
    seen(s, FIELD, UP)
    s.loaded = 1.0
    mk(s).mc_assess(s, 0.01)
    assert s.quality == 0.0


def test_without_a_live_field_assessing_only_clears_stale(compiled):
    s = dirty(compiled, 6)
    s.seen_live = 0.0
    s.stale = 1.0
    e = copy(s)
    e.stale = 0.0
    mk(s).mc_assess(s, 0.01)
    assert_block(s, e)


def learning(compiled, seed, with_up=True, scale=1e-10, field=FIELD):
    """A calibration learning (not converged), its latest field seen, the hold not started."""
    s = fresh(compiled)
    random_calibration(s, np.random.default_rng(seed), scale)
    seen(s, field, UP if with_up else None)
    s.heading = 1.0
    return s


def kernel_quality(s):
    c = copy(s)
    mk(c).mc_assess(c, 0.0)
    return c.quality


@pytest.mark.parametrize('with_up', [True, False])
def test_a_quality_below_the_threshold_starts_the_hold_from_the_calibration_now(compiled,
                                                                                 with_up):
    s = learning(compiled, 7, with_up)
    e = copy(s)
    mk(s).mc_assess(s, 0.25)
    expect_assessed(e)
    assert e.quality < 1e-3
    put(e, 'candidate', x_of(e)[3:11])
    e.held = 0.25
    assert_block(s, e)
    # Held CAL_HOLD s in all (1.75 + 0.25): converged.
    s.held = 1.75
    e = copy(s)
    mk(s).mc_assess(s, 0.25)
    expect_assessed(e)
    e.held = CAL_HOLD
    e.converged = 1.0
    assert_block(s, e)


@pytest.mark.parametrize('with_up', [True, False])
@pytest.mark.parametrize('sign', [1.0, -1.0])
@pytest.mark.parametrize('apart', [1.5, 1.9, 2.1, 2.5])
@pytest.mark.parametrize('held', [0.0, 0.5])
def test_the_hold_starts_over_when_the_calibration_turned_the_heading(compiled, with_up, sign,
                                                                      apart, held):
    """Turned by more than CAL_HOLD_TURN × heading since the hold started: held again from 0."""
    field = np.array([0.3, -0.35, -0.25])  # without an up, the axis: far from unit
    s = learning(compiled, 8, with_up, field=field)
    s.held = held
    x = x_of(s)
    candidate = x[3:11] + sign * np.array([0.02, -0.01, 0.0, 0.01, 0.0, 0.0, 0.0, 0.0])
    put(s, 'candidate', candidate)
    axis = UP if with_up else field
    turned = turn_about(axis, calibrated(x[3:11], field), calibrated(candidate, field))
    assert abs(turned) > 1e-3
    s.heading = abs(turned) / apart  # 2 × heading above or below the turn
    e = copy(s)
    mk(s).mc_assess(s, 0.25)
    expect_assessed(e)
    assert e.quality < e.heading
    if apart > 2.0:
        put(e, 'candidate', x[3:11])
        e.held = 0.0
    else:
        e.held = held + 0.25
    assert_block(s, e)


def test_the_hold_pauses_a_little_above_the_threshold_and_ends_well_above_it(compiled):
    s = learning(compiled, 9, scale=1e-4)
    q = kernel_quality(s)
    s.held = 0.5
    put(s, 'candidate', np.full(8, 0.125))
    for heading, held in ((q / 1.5, 0.5), (q, 0.5), (q / 2.0, 0.5), (q / 2.5, -1.0)):
        c = copy(s)
        c.heading = heading
        e = copy(c)
        mk(c).mc_assess(c, 0.25)
        expect_assessed(e)
        e.held = held
        assert_block(c, e)
    # Converged or loaded: no hold.
    for name in ('converged', 'loaded'):
        c = copy(s)
        put(c, name, 1.0)
        c.heading = q / 2.5
        e = copy(c)
        mk(c).mc_assess(c, 0.25)
        expect_assessed(e)
        assert_block(c, e)
        c.heading = e.heading = 2.0 * q
        mk(c).mc_assess(c, 0.25)
        assert_block(c, e)


def test_the_quality_asked_for_is_assessed_only_when_stale(compiled):
    s = learning(compiled, 10)
    s.held = 0.5
    put(s, 'candidate', x_of(s)[3:11])
    s.quality = 0.75
    s.stale = 0.0
    e = copy(s)
    assert mk(s).mc_quality(s) == 0.75
    assert_block(s, e)
    s.stale = 1.0
    e = copy(s)
    expect_assessed(e)  # with no time elapsed: held as it was
    assert mk(s).mc_quality(s) == pytest.approx(e.quality, rel=1e-9)
    assert_block(s, e)


# --- outputs -----------------------------------------------------------------------

@pytest.mark.parametrize('enabled, loaded, converged, identity, applied', [
    (1.0, 1.0, 0.0, 0.0, True), (1.0, 0.0, 1.0, 0.0, True), (1.0, 1.0, 1.0, 1.0, False),
    (1.0, 0.0, 0.0, 0.0, False), (0.0, 1.0, 1.0, 0.0, False)])
def test_the_calibration_applied_is_the_scale_times_i_plus_d_and_the_offset(
        compiled, enabled, loaded, converged, identity, applied):
    s = dirty(compiled, 11)
    for name, v in (('enabled', enabled), ('loaded', loaded), ('converged', converged),
                    ('identity', identity)):
        put(s, name, v)
    e = copy(s)
    mk(s).mc_cache(s)
    expect_cache(e)
    assert e.applied == (1.0 if applied else 0.0)
    assert_block(s, e)
    y = np.array([0.3, -0.7, 1.1])
    want = y
    if applied:
        x = x_of(s)
        want = s.scale * calibrated(x[3:11], y)
    assert mk(s).mc_apply(s, *y) == pytest.approx(want, rel=1e-12)


def test_the_field_now_is_the_scale_times_s_minus_z(compiled):
    s = dirty(compiled, 12)
    x = x_of(s)
    assert mk(s).mc_field(s) == pytest.approx(s.scale * (x[:3] - x[3:6]), rel=1e-12)


def test_calibrated_is_i_plus_d_times_y_minus_z(compiled):
    s = dirty(compiled, 13)
    zd = get(s, 'candidate')
    y = np.array([0.4, 0.9, -0.2])
    want = calibrated(zd, y)
    assert mk(s).mc_calibrated(s.candidate, 0, *y) == pytest.approx(want, rel=1e-12)


@pytest.mark.parametrize('seed', range(4))
def test_the_heading_between_two_fields_is_the_angle_of_their_horizontal_parts(compiled, seed):
    rng = np.random.default_rng(seed)
    u = rng.normal(size=3)
    u /= np.linalg.norm(u)
    f, g = rng.normal(size=3), rng.normal(size=3)
    heading_between = kernel(compiled).mc_heading_between
    assert heading_between(*u, *f, *g) == pytest.approx(turn_about(u, f, g), rel=1e-12)
    # g: f turned about u by a known angle (Rodrigues), plus some of u.
    angle = rng.uniform(-3.0, 3.0)
    turned = (f * math.cos(angle) + np.cross(u, f) * math.sin(angle)
              + u * (u @ f) * (1.0 - math.cos(angle)) + 0.7 * u)
    assert heading_between(*u, *f, *turned) == pytest.approx(angle, rel=1e-9)


def test_a_loaded_calibration_is_applied_before_the_next_field(compiled):
    """At once: not from the next field on (with the field as given till then)."""
    cal = MagCalibrator(kernel=kernel(compiled))
    soft, bias = np.array([[1.1, 0.02, 0.0], [0.02, 0.95, 0.01], [0.0, 0.01, 1.0]]), FIELD / 3
    cal.load(bias, soft)
    assert cal.applied
    assert cal.apply(FIELD) == pytest.approx(np.linalg.solve(soft, FIELD - bias), rel=1e-12)


def test_the_heading_turn_is_the_same_whatever_the_norm_of_the_axis(compiled):
    """The axis is made unit (the raw field, an up of any norm)."""
    cal = MagCalibrator(kernel=kernel(compiled))
    cal.load((0.1, -0.2, 0.05), np.diag([1.1, 0.95, 1.0]))
    cal.learn(FIELD, (1.0, 0.0, 0.0, 0.0), 0.01, (0.0, 0.0, 0.0), UP)
    turn = cal.heading_turn(FIELD, UP)
    assert abs(turn) > 0.05
    assert cal.heading_turn(FIELD, 40.0 * UP) == pytest.approx(turn, rel=1e-12)


def test_a_calibrated_field_along_the_vertical_is_no_crash_nor_nan(compiled):
    s = fresh(compiled)
    random_calibration(s, np.random.default_rng(18))
    put(s, 'x', (0.1, 0.2, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0), at=3)
    seen(s, (0.1, 0.2, -0.5), (0.0, 0.0, 1.0))  # calibrated: (0, 0, -0.5) exactly
    s.loaded = 1.0
    mk(s).mc_assess(s, 0.01)
    # No horizontal part (never exactly so in practice): a number, not a
    # division by zero (0 today: nothing of the covariance lies across it).
    assert s.quality >= 0.0


def test_a_calibrated_field_of_zero_has_no_heading(compiled):
    s = fresh(compiled)
    random_calibration(s, np.random.default_rng(17))
    put(s, 'x', np.zeros(5), at=6)
    y = x_of(s)[3:6]  # calibrated to 0 exactly: (I + 0) y − z
    seen(s, y)
    s.loaded = 1.0
    mk(s).mc_assess(s, 0.01)
    with np.errstate(divide='ignore'):
        jp, c, _ = assessed(s)
    assert s.quality == pytest.approx(math.sqrt(np.trace(c)) / 1e-300, rel=1e-6)


# The learning step (mc_learn) -------------------------------------------------------------
#
# mc_learn is called on a calibrator's record, and every field compared with what it must
# leave: the filter's steps (mc_predict, mc_start, mc_update)
# run on a copy, then the counts (fields, used, gated, refused, invalid, resets), the share of
# fields refused while turning, a start over and what it clears, the latest field seen, the
# quality (in matrix form, above), the hold and the watch of the heading turn.


# --- the watch of a calibration not applied yet -------------------------------------

@pytest.mark.parametrize('watched, n', [(0.0, 1.0), (4.0, 5.0), (-0.5, 1.0),
                                        (CAL_SHIFT_SAMPLES + 500.0, CAL_SHIFT_SAMPLES)])
def test_the_watch_keeps_the_mean_square_heading_turn_of_the_calibration(compiled, watched, n):
    s = learning(compiled, 14)
    s.watched = watched
    s.shift = 0.01
    y = FIELD + np.array([0.02, 0.01, -0.03])
    e = copy(s)
    mk(s).mc_watch(s, *y, *UP)
    angle = turn_about(UP, y, calibrated(x_of(s)[3:11], y))
    assert abs(angle) > 0.01
    e.watched = watched + 1.0
    e.shift = 0.01 + (angle * angle - 0.01) / n
    got = s.shift
    s.shift = e.shift
    assert got == pytest.approx(e.shift, rel=1e-12)
    assert_block(s, e)


def test_the_watch_applies_a_converged_calibration_that_turns_the_heading(compiled):
    s = learning(compiled, 15)
    s.converged = 1.0
    s.quality = 1e-3
    s.deadband = 1e-3
    y = FIELD + np.array([0.02, 0.01, -0.03])
    mk(s).mc_watch(s, *y, *UP)
    assert s.identity == 0.0


@pytest.mark.parametrize('converged, shift, deadband, quality, applied', [
    (1.0, 0.011, 0.1, 0.02, True),      # beyond the deadband and 3 σ
    (0.0, 0.011, 0.1, 0.02, False),     # not converged
    (1.0, 0.01, 0.1, 0.02, False),      # at the deadband
    (1.0, 0.0036, 0.05, 0.02, False),   # at 3 σ (0.06²)
    (1.0, 0.0035, 0.05, 0.02, False),   # beyond the deadband, within 3 σ
    (1.0, 0.0035, 0.06, 0.01, False),   # within the deadband, beyond 3 σ
])
def test_a_converged_calibration_is_applied_once_it_turns_the_heading_significantly(
        compiled, converged, shift, deadband, quality, applied):
    s = dirty(compiled, 16)
    s.identity = 1.0
    for name, v in (('converged', converged), ('shift', shift), ('deadband', deadband),
                    ('quality', quality)):
        put(s, name, v)
    if shift in (0.01, 0.0036):  # exactly at the bound, as the kernel squares it
        s.shift = (deadband * deadband if shift == 0.01
                             else (3.0 * quality) * (3.0 * quality))
    e = copy(s)
    e.identity = 0.0 if applied else 1.0
    mk(s).mc_reconsider(s)
    assert_block(s, e)


# --- learning -------------------------------------------------------------------

def learn(s, y, r=(1.0, 0.0, 0.0, 0.0), dt=0.01, w=(0.0, 0.0, 0.0), up=UP, allow=True):
    return mk(s).mc_learn(s, floats(y), floats(r), dt, floats(w), 0.0 if up is None else 1.0,
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


def started(compiled, up=UP):
    """The estimator's calibration after its first field."""
    s = fresh(compiled)
    assert learn(s, FIELD, up=up) == 1.0
    # Counts so far: counted on.
    for name, v in (('fields', 10.0), ('used', 7.0), ('gated', 2.0), ('refused', 3.0),
                    ('invalid', 1.0), ('resets', 2.0)):
        put(s, name, v)
    return s


def expect_seen(e, y, up, live):
    put(e, 'seen_y', y)
    if up is not None:
        put(e, 'seen_up', up)
    e.seen_has_up = 0.0 if up is None else 1.0
    e.seen_live = 1.0 if live else 0.0
    e.assessed = 0.0
    e.watching = 0.0
    if live:
        expect_assessed(e)
        e.assessed = 1.0
    else:
        e.stale = 1.0


@pytest.mark.parametrize('up', [UP, None])
def test_the_first_valid_field_starts_the_filter_and_is_assessed(compiled, up):
    s = fresh(compiled)
    e = copy(s)
    assert learn(s, FIELD, w=(0.3, -0.1, 0.2), up=up) == 1.0
    norm = float(np.linalg.norm(FIELD))
    mf(e).mc_start(e, *FIELD, norm)
    mf(e).mc_update(e, *FIELD, 0.3, -0.1, 0.2, False, norm)
    e.fields = 1.0
    e.used = 1.0
    expect_seen(e, FIELD, up, True)
    assert e.quality > 2.0 * e.heading  # no hold yet
    expect_cache(e)
    assert_block(s, e)


def step(s, y, r, dt, w, allow=True, up=UP, watched_share=None):
    """``mc_learn`` of a filter started already, and what it must leave (filter, counts)."""
    e = copy(s)
    result = learn(s, y, r, dt, w, up, allow)
    norm = float(np.linalg.norm(y))
    take = math.isfinite(norm) and norm > 0.0
    mf(e).mc_predict(e, *r, dt)
    live = take and allow
    use = mf(e).mc_update(e, *(y if live else (0.0, 0.0, 0.0)), *np.nan_to_num(w), live, norm)
    e.fields += 1.0
    e.used += 1.0 if use else 0.0
    e.gated += 1.0 if live and not use else 0.0
    e.invalid += 0.0 if take else 1.0
    e.refused += 1.0 if take and not allow else 0.0
    if watched_share is not None:
        k = 1.0 - math.exp(-dt / CAL_REFUSED_TAU)
        share = e.refused_share
        e.refused_share = share + k * (watched_share - share)
    assert result == (1.0 if use else 0.0)
    return e, live, use


RATE = (0.3, -0.2, 0.25)
R = turn(0.05, (0.2, 0.5, 0.8))


@pytest.mark.parametrize('offset, used', [(0.0, True), (3.0, False)])
@pytest.mark.parametrize('rate', [RATE, (0.3, 0.0, 0.0), (0.0, -0.3, 0.0), (0.0, 0.0, 0.3)])
def test_a_field_learned_while_turning_is_counted_and_moves_the_refused_share(compiled, offset,
                                                                              used, rate):
    s = started(compiled)
    s.refused_share = 0.5
    c = copy(s)
    mf(c).mc_predict(c, *R, 0.05)
    y = predicted(c, rate) + offset * np.linalg.norm(FIELD)
    e, live, use = step(s, y, R, 0.05, rate, watched_share=0.0 if used else 1.0)
    assert use == used
    expect_seen(e, y, UP, True)
    expect_cache(e)
    assert_block(s, e)


def test_a_field_learned_at_the_turning_rate_leaves_the_refused_share(compiled):
    s = started(compiled)
    s.refused_share = 0.5
    c = copy(s)
    mf(c).mc_predict(c, *R, 0.05)
    y = predicted(c, (0.2, 0.0, 0.0)) + 3.0 * np.linalg.norm(FIELD)
    e, live, use = step(s, y, R, 0.05, (0.2, 0.0, 0.0))
    assert not use and e.refused_share == 0.5
    expect_seen(e, y, UP, True)
    expect_cache(e)
    assert_block(s, e)


LOST = (('fresh', 1.0), ('loaded', 0.0), ('converged', 0.0), ('identity', 1.0),
        ('shift', 0.0), ('watched', 0.0), ('refused_share', 0.0), ('has_prior', 0.0))


def learned_for_long(s):
    """Flags a start over must clear."""
    for name, v in (('converged', 1.0), ('identity', 0.0), ('shift', 0.3),
                    ('watched', 5.0), ('has_prior', 1.0), ('prior_cov', 1.0)):
        put(s, name, v)


def test_most_fields_refused_while_turning_start_the_calibration_over(compiled):
    s = started(compiled)
    learned_for_long(s)
    s.refused_share = 0.69
    c = copy(s)
    mf(c).mc_predict(c, *R, 1.0)
    y = predicted(c, RATE) + 10.0 * np.linalg.norm(FIELD)
    e, live, use = step(s, y, R, 1.0, RATE, watched_share=1.0)
    assert not use and e.refused_share > 0.7
    for name, v in LOST:
        put(e, name, v)
    e.resets += 1.0
    expect_seen(e, y, UP, False)
    expect_cache(e)
    assert_block(s, e)


@pytest.mark.parametrize('k, value, lost', [(0, 0.5, True), (1, -0.5, True), (2, 0.5, True),
                                            (3, -0.5, True), (4, 0.5, True), (5, 0.5, False),
                                            (4, 0.15, False)])
def test_a_soft_iron_far_beyond_its_prior_starts_the_calibration_over(compiled, k, value, lost):
    s = started(compiled)
    learned_for_long(s)
    s.x[6 + k] = value  # CAL_WILD × soft_iron = 0.2
    c = copy(s)
    mf(c).mc_predict(c, *R, 0.01)
    y = predicted(c, (0.0, 0.0, 0.0))
    e, live, use = step(s, y, R, 0.01, (0.0, 0.0, 0.0))
    assert use
    if lost:
        for name, v in LOST:
            put(e, name, v)
        e.resets += 1.0
    # Converged and applied where not lost: no quality assessed.
    expect_seen(e, y, UP, False)
    e.seen_live = 0.0 if lost else 1.0
    expect_cache(e)
    assert_block(s, e)


@pytest.mark.parametrize('y', [(math.nan, 0.1, 0.2), (0.0, 0.0, 0.0), (0.1, math.inf, 0.2)])
@pytest.mark.parametrize('allow', [True, False])
def test_an_invalid_field_is_counted_and_teaches_nothing(compiled, y, allow):
    s = started(compiled)
    s.refused_share = 0.5
    e, live, use = step(s, y, R, 0.01, RATE, allow=allow)
    expect_seen(e, (0.0, 0.0, 0.0), UP, False)
    expect_cache(e)
    assert_block(s, e)
    # While fresh: nothing predicted.
    s = fresh(compiled)
    e = copy(s)
    assert learn(s, y, R, 0.01, RATE, allow=allow) == 0.0
    mf(e).mc_update(e, 0.0, 0.0, 0.0, *RATE, False, 0.0)
    e.fields = 1.0
    e.invalid = 1.0
    expect_seen(e, (0.0, 0.0, 0.0), UP, False)
    expect_cache(e)
    assert_block(s, e)


@pytest.mark.parametrize('applied', [False, True])
def test_a_field_the_caller_refuses_is_counted_and_watched_where_applied(compiled, applied):
    s = started(compiled)
    s.refused_share = 0.5
    if applied:
        s.converged = 1.0
        s.identity = 0.0
        mk(s).mc_cache(s)
    e, live, use = step(s, FIELD, R, 0.05, RATE, allow=False,
                        watched_share=1.0 if applied else None)
    assert e.refused == 4.0
    expect_seen(e, (0.0, 0.0, 0.0), UP, False)
    expect_cache(e)
    assert_block(s, e)


def test_off_nothing_is_counted_nor_learned(compiled):
    s = fresh(compiled)
    s.enabled = 0.0
    mk(s).mc_cache(s)
    e = copy(s)
    assert learn(s, FIELD, R, 0.01, RATE) == 0.0
    mf(e).mc_update(e, 0.0, 0.0, 0.0, *RATE, False, 0.0)
    expect_seen(e, (0.0, 0.0, 0.0), UP, False)
    expect_cache(e)
    assert_block(s, e)


@pytest.mark.parametrize('up', [UP, None])
def test_a_calibration_nearly_good_enough_is_held_and_watched(compiled, up):
    s = started(compiled, up)
    s.heading = 100.0
    put(s, 'seen_up', (5.0, 6.0, 7.0))  # without an up: kept as it was
    c = copy(s)
    mf(c).mc_predict(c, *R, 0.05)
    y = predicted(c, RATE) + 0.01 * np.linalg.norm(FIELD)
    e, live, use = step(s, y, R, 0.05, RATE, up=up, watched_share=0.0)
    assert use
    expect_seen(e, y, up, True)
    assert e.quality < 100.0
    put(e, 'candidate', x_of(e)[3:11])
    e.held = 0.05
    if up is not None:
        angle = turn_about(up, y, calibrated(x_of(e)[3:11], y))
        assert abs(angle) > 1e-4
        e.watched = 1.0
        e.shift = angle * angle
        e.watching = 1.0
        assert s.shift == pytest.approx(angle * angle, rel=1e-9)
        s.shift = e.shift
    expect_cache(e)
    assert_block(s, e)


@pytest.mark.parametrize('loaded, converged, identity, assessed', [
    (1.0, 0.0, 1.0, False), (0.0, 1.0, 1.0, True), (0.0, 1.0, 0.0, False),
    (0.0, 0.0, 0.0, True)])
def test_the_quality_is_assessed_while_learning_or_watching_a_converged_calibration(
        compiled, loaded, converged, identity, assessed):
    s = started(compiled)
    for name, v in (('loaded', loaded), ('converged', converged), ('identity', identity)):
        put(s, name, v)
    s.quality = 0.5
    c = copy(s)
    mf(c).mc_predict(c, *R, 0.05)
    y = predicted(c, RATE)
    e, live, use = step(s, y, R, 0.05, RATE, watched_share=0.0)
    expect_seen(e, y, UP, assessed)
    e.seen_live = 1.0
    assert e.quality != 0.5 if assessed else e.quality == 0.5
    expect_cache(e)
    assert_block(s, e)


@pytest.mark.parametrize('axis', range(3))
def test_a_rate_that_is_not_finite_counts_as_zero(compiled, axis):
    s = started(compiled)
    c = copy(s)
    mf(c).mc_predict(c, *R, 0.05)
    y = predicted(c, (0.0, 0.0, 0.0))
    zero, bad, some = copy(s), copy(s), copy(s)
    rate = [0.0, 0.0, 0.0]
    learn(zero, y, R, 0.05, tuple(rate))
    rate[axis] = math.nan
    learn(bad, y, R, 0.05, tuple(rate))
    rate[axis] = 0.5
    learn(some, y, R, 0.05, tuple(rate))
    assert_block(bad, zero)
    # (the rate counts: its lag's column of the filter's measurement)
    assert not np.array_equal(p_of(some), p_of(zero))


def test_a_quality_at_the_threshold_is_not_watched(compiled):
    s = started(compiled)
    c = copy(s)
    mf(c).mc_predict(c, *R, 0.05)
    y = predicted(c, RATE)
    c = copy(s)
    learn(c, y, R, 0.05, RATE)
    quality = c.quality
    for heading, watched in ((quality, 0.0), (math.nextafter(quality, math.inf), 1.0)):
        c = copy(s)
        c.heading = heading
        learn(c, y, R, 0.05, RATE)
        assert c.quality == quality
        assert c.watching == watched and c.watched == watched
