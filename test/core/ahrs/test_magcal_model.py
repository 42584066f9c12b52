"""
A saved magnetometer calibration checked (``core/ahrs/magcal_model.py``):
what it returns and what it refuses, by name.
"""

import math

import numpy as np
from numpy.testing import assert_array_equal
import pytest

from ext_observer.core.ahrs.magcal_model import check_calibration


def test_a_good_calibration_comes_back_as_arrays_and_symmetric():
    s = np.array([[1.1, 0.02, 0.0], [0.02 + 1e-9, 0.95, 0.01], [0.0, 0.01, 1.0]])
    bias, soft_iron = check_calibration((1e-6, -2e-6, 3e-6), s.ravel().tolist())
    assert_array_equal(bias, [1e-6, -2e-6, 3e-6])
    assert soft_iron.shape == (3, 3)
    assert_array_equal(soft_iron, soft_iron.T)
    assert soft_iron[0, 1] == pytest.approx(0.02 + 0.5e-9, abs=1e-15)


@pytest.mark.parametrize('bias, soft_iron, reason', [
    ((1.0, 2.0), np.eye(3), 'offset must have 3 values'),
    ((1.0, math.nan, 0.0), np.eye(3), 'offset must be finite'),
    ((0.0, 0.0, 0.0), np.eye(2), r'9 values \(3 × 3, row-major\)'),
    ((0.0, 0.0, 0.0), np.diag([1.0, math.inf, 1.0]), 'matrix must be finite'),
    ((0.0, 0.0, 0.0), [[1.0, 0.1, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]], 'symmetric'),
    ((0.0, 0.0, 0.0), np.diag([1.0, 1.0, 0.0]), 'positive definite'),
    ((0.0, 0.0, 0.0), np.diag([1.0, -1.0, 1.0]), 'positive definite'),
    ((0.0, 0.0, 0.0), np.zeros((3, 3)), 'positive definite'),
])
def test_a_bad_calibration_is_refused_naming_what_is_wrong(bias, soft_iron, reason):
    with pytest.raises(ValueError, match=reason):
        check_calibration(bias, soft_iron)
