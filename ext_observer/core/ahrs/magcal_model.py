"""
Checking a saved magnetometer calibration (:mod:`ext_observer.core.ahrs.magcal`).

The model, body frame: a raw field sample is ``y = S m + b``, with ``m`` the
true field, ``b`` the hard-iron offset and ``S`` a symmetric soft-iron
matrix (the filter that learns them, and its description:
:mod:`~ext_observer.core.ahrs.magcal_kernel`). A saved calibration is ``b`` and
``S``; :func:`check_calibration` tells what is wrong with one.
"""

import numpy as np

__all__ = ['check_calibration']


def check_calibration(bias, soft_iron):
    """
    Validate a saved calibration.

    Parameters
    ----------
    bias : sequence of 3 floats
        Hard-iron offset ``b``, in the field's unit.
    soft_iron : sequence of 9 floats or array_like, shape (3, 3)
        ``S`` (row-major), in ``y = S m + b``.

    Returns
    -------
    bias : ndarray, shape (3,)
    soft_iron : ndarray, shape (3, 3)
        Symmetric (the mean of ``S`` and ``Sᵀ``).

    Raises
    ------
    ValueError
        Naming what is wrong: a shape, a non-finite value, an asymmetric,
        singular or not positive definite matrix.

    """
    b = np.asarray(bias, dtype=float)
    if b.shape != (3,):
        raise ValueError(f'the hard-iron offset must have 3 values, got shape {b.shape}')
    if not np.all(np.isfinite(b)):
        raise ValueError(f'the hard-iron offset must be finite, got {b.tolist()}')
    s = np.asarray(soft_iron, dtype=float)
    if s.shape == (9,):
        s = s.reshape(3, 3)
    if s.shape != (3, 3):
        raise ValueError(
            f'the soft-iron matrix must have 9 values (3 × 3, row-major), got shape {s.shape}')
    if not np.all(np.isfinite(s)):
        raise ValueError(f'the soft-iron matrix must be finite, got {s.ravel().tolist()}')
    scale = np.max(np.abs(s))
    if np.max(np.abs(s - s.T)) > 1e-6 * scale:
        raise ValueError(f'the soft-iron matrix must be symmetric, got {s.ravel().tolist()}')
    s = 0.5 * (s + s.T)
    eig = np.linalg.eigvalsh(s)
    if not (scale > 0.0 and eig[0] > 1e-6 * scale):
        raise ValueError(
            'the soft-iron matrix must be positive definite (not singular), got eigenvalues '
            f'{eig.tolist()}')
    return b, s

