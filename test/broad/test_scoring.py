"""
BROAD's scoring (``broad/scoring.py``) on synthetic arrays: heading and
inclination errors, sign and norm ignored, the RMSE over movement, the
norm deviation, the group means.
"""

import math

import numpy as np
import pytest

from broad_synthetic import NAMES, rotation
from ext_observer import broad
from ext_observer.core.quaternion import multiply


@pytest.fixture
def references():
    rng = np.random.default_rng(3)
    q = rng.standard_normal((50, 4))
    return q / np.linalg.norm(q, axis=1, keepdims=True)


@pytest.mark.parametrize('angle', [1e-3, 0.3, 2.0, 3.1])
def test_heading_error_is_about_the_world_vertical(references, angle):
    est = multiply(rotation((0, 0, 1), angle), references)
    total, heading, inclination = broad.error_angles(est, references)
    np.testing.assert_allclose(total, angle, atol=1e-7)
    np.testing.assert_allclose(heading, angle, atol=1e-7)
    np.testing.assert_allclose(inclination, 0.0, atol=1e-6)


@pytest.mark.parametrize('axis', [(1, 0, 0), (0, 1, 0), (1, -2, 0)])
def test_inclination_error_is_about_a_horizontal_axis(references, axis):
    est = multiply(rotation(axis, 0.4), references)
    total, heading, inclination = broad.error_angles(est, references)
    np.testing.assert_allclose(total, 0.4, atol=1e-7)
    np.testing.assert_allclose(heading, 0.0, atol=1e-7)
    np.testing.assert_allclose(inclination, 0.4, atol=1e-7)


def test_heading_and_inclination_split_a_world_frame_error(references):
    # e = R_x(φ) R_z(θ) = (cφ cθ, sφ cθ, sφ sθ, cφ sθ) in half angles: BROAD's
    # formulas give θ and φ exactly. A body-frame error would not (hence the
    # order q̂ ⊗ q_ref⁻¹).
    est = multiply(multiply(rotation((1, 0, 0), 0.2), rotation((0, 0, 1), 0.7)), references)
    _, heading, inclination = broad.error_angles(est, references)
    np.testing.assert_allclose(heading, 0.7, atol=1e-7)
    np.testing.assert_allclose(inclination, 0.2, atol=1e-7)
    body = multiply(references, rotation((1, 0, 0), 0.3))
    _, _, inclination = broad.error_angles(body, references)
    assert np.ptp(inclination) > 0.1  # the body axis is tilted in the world


def test_scoring_ignores_sign_and_norm(references):
    est = multiply(rotation((0, 1, 1), 0.5), references)
    expected = broad.error_angles(est, references)
    scaled = -2.5 * est  # an ambient estimate, off S³ and with the other sign
    for a, b in zip(broad.error_angles(scaled, references), expected):
        np.testing.assert_allclose(a, b, atol=1e-12)


def test_rmse_over_movement_skips_nan_references(references):
    n = len(references)
    angles = np.radians(np.where(np.arange(n) % 2 == 0, 1.0, 3.0))
    movement = np.arange(n) >= 10
    assert broad.rmse_deg(angles, movement) == pytest.approx(math.sqrt(5.0))
    est = multiply(rotation((0, 0, 1), math.radians(2.0)), references)
    est[:10] = multiply(rotation((0, 0, 1), math.radians(50.0)), references[:10])
    ref = references.copy()
    ref[20:30] = np.nan  # a gap of the optical reference
    est[20:30] = multiply(rotation((0, 0, 1), math.radians(90.0)), references[20:30])
    s = broad.score(est, ref, movement)
    assert set(s) == {'total_rmse_deg', 'heading_rmse_deg', 'inclination_rmse_deg'}
    assert s['total_rmse_deg'] == pytest.approx(2.0)
    assert s['heading_rmse_deg'] == pytest.approx(2.0)
    assert s['inclination_rmse_deg'] == pytest.approx(0.0, abs=1e-5)
    assert math.isnan(broad.rmse_deg(np.full(5, np.nan)))


def test_norm_deviation():
    q = [np.array([[1.0, 0, 0, 0], [0, 1.1, 0, 0]]), np.array([[0.0, 0, 0.9, 0]])]
    d = broad.norm_deviation(q)
    assert d['samples'] == 3
    assert d['mean'] == pytest.approx((0.0 + 0.21 + 0.19) / 3)
    assert d['max'] == pytest.approx(0.21)


def test_group_means_average_the_trials():
    groups = broad.find_groups('/nonexistent', NAMES)
    scores = {name: {'total_rmse_deg': float(i + 1)} for i, name in enumerate(NAMES)}
    means = broad.group_means(scores, groups, 'total_rmse_deg')
    assert means['all_trials'] == pytest.approx(2.5)
    assert means['undisturbed'] == pytest.approx(1.5)
    assert means['disturbed'] == pytest.approx(3.5)
    assert means['vibration'] == pytest.approx(3.0)
