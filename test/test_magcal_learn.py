"""
The calibration's learning step, its watch and when it applies what it learned (magcal_kernel.py).

``mc_learn`` is called on the calibration's block of an estimator's flat
state, and the whole block compared with what it must leave: the filter's
steps (``mc_predict``, ``mc_start``, ``mc_update``) run on a copy, then the
counts (fields, used, gated, refused, invalid, resets), the share of fields
refused while turning, a start over and what it clears, the latest field
seen, the quality (in matrix form, test_magcal_kernel.py), the hold and the
watch of the heading turn. Written for mutmut's survivors (docs/tests.md#mutmut).
"""

import math

import numpy as np
import pytest

from ext_observer.core.ahrs import magcal_filter as mf
from ext_observer.core.ahrs import magcal_kernel as mk
from ext_observer.core.ahrs.magcal_layout import (
    CAL_REFUSED_TAU, CAL_SHIFT_SAMPLES, MC_ASSESSED, MC_CANDIDATE, MC_CONVERGED, MC_DEADBAND,
    MC_ENABLED, MC_FIELDS, MC_FRESH, MC_GATED, MC_HAS_PRIOR, MC_HEADING, MC_HELD, MC_IDENTITY,
    MC_INVALID, MC_LOADED, MC_PRIOR_COV, MC_QUALITY, MC_REFUSED, MC_REFUSED_SHARE, MC_RESETS,
    MC_SEEN_HAS_UP, MC_SEEN_LIVE, MC_SEEN_UP, MC_SEEN_Y, MC_SHIFT, MC_STALE, MC_USED,
    MC_WATCHED, MC_WATCHING, MC_X)
from test_magcal_kernel import (assert_block, calibrated, d_matrix, dirty, estimator_state,
                                expect_assessed, expect_cache, FIELD, learning, OFF,
                                p_of, put, turn_about, UP, x_of)


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
    return mk.mc_learn(s, OFF, *y, *r, dt, *w, 0.0 if up is None else 1.0,
                       *((7.0, 8.0, 9.0) if up is None else up), 1.0 if allow else 0.0)


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
