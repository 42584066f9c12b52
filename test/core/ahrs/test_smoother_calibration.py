"""The calibration fitted on the whole recording (smoother_calibration.py)."""

import numpy as np
import pytest

from ext_observer.core.ahrs.smoother_calibration import fit_calibration, rotation_matrices
from ext_observer.core.quaternion import quaternion_from_rotation_vector

RATE = 50.0
FIELD = np.array([0.0, 20.0, -40.0])  # µT, world (ENU): north and down
BIAS = np.array([60.0, -35.0, 25.0])  # µT, more than the field's norm
SOFT = np.array([[1.06, 0.03, -0.02], [0.03, 0.95, 0.04], [-0.02, 0.04, 1.0]])


def _recording(angles, seconds=120.0, noise=0.3, seed=3):
    """A field read through ``SOFT`` and ``BIAS`` along attitudes from rotation vectors."""
    t = np.arange(0.0, seconds, 1.0 / RATE)
    q = quaternion_from_rotation_vector(angles(t))
    rng = np.random.default_rng(seed)
    body = np.einsum('nji,j->ni', rotation_matrices(q), FIELD)
    mag = body @ SOFT.T + BIAS + noise * rng.standard_normal(body.shape)
    return mag, q


def test_hard_and_soft_iron_are_recovered_from_a_turning_recording():
    mag, q = _recording(lambda t: np.stack((2.0 * np.sin(0.31 * t), 1.5 * np.cos(0.17 * t),
                                            0.4 * t), axis=1))
    # The synthetic noise is white: each sample counts.
    fit = fit_calibration(mag, q, RATE, correlation=1.0 / RATE)
    assert fit.soft_fitted
    # S is known up to a scale (the fit keeps trace(S⁻¹) = 3).
    scale = np.trace(np.linalg.inv(SOFT)) / 3.0
    np.testing.assert_allclose(fit.soft_iron, SOFT * scale, atol=0.01)
    np.testing.assert_allclose(fit.bias, BIAS, atol=0.5)
    m = fit.apply(mag)
    np.testing.assert_allclose(np.linalg.norm(m, axis=1).mean(),
                               np.linalg.norm(FIELD) / scale, rtol=0.01)


def test_a_recording_with_little_rotation_keeps_the_soft_iron_at_the_prior():
    # Level, the heading swinging by ±0.3 rad: the soft iron is not determined.
    mag, q = _recording(lambda t: np.stack((0.0 * t, 0.0 * t, 0.3 * np.sin(0.2 * t)), axis=1))
    fit = fit_calibration(mag, q, RATE, correlation=1.0 / RATE)
    assert not fit.soft_fitted
    assert fit.soft_sigma > 0.025
    np.testing.assert_array_equal(fit.soft_iron, np.eye(3))


def test_bad_input_is_refused():
    mag, q = _recording(lambda t: np.zeros((len(t), 3)), seconds=1.0)
    with pytest.raises(ValueError, match='shape'):
        fit_calibration(mag[:, :2], q, RATE)
    with pytest.raises(ValueError, match='rate'):
        fit_calibration(mag, q, 0.0)
