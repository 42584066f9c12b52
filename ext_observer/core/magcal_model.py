"""
The model of the online magnetometer calibration (:mod:`ext_observer.core.magcal`).

The model, body frame: a raw field sample is ``y = S m + b``, with ``m`` the
true field, ``b`` the hard-iron offset and ``S`` a symmetric soft-iron
matrix. With ``A = S⁻¹ = I + D(d)`` (``D`` symmetric, trace 0: five numbers
``d``) and ``z = A b``, the calibrated field is ``m = A y − z``. ``S`` is
known only up to a scale (a uniform gain moves no direction), fixed here by
``trace(A) = 3``, or by the trace of a loaded matrix.

What makes it observable is the gyro. The field is fixed in the world, so
in the body frame it turns against the body: between two fields ``m ← Rᵀ m``
with ``R`` the gyro's rotation, and a body that turns about two axes leaves
one offset and one matrix that fit (gyro-aided calibration: Troni and
Whitcomb 2013, "Adaptive estimation of measurement bias in
three-dimensional field sensors with angular rate sensors", Robotics:
Science and Systems; Kok and Schön 2016, "Magnetometer calibration using
inertial sensors", IEEE Sensors Journal 16(14), for the view of the field as
a constant world vector seen through the gyro's orientation). A Kalman
filter estimates ``(s, z, d, τ)`` with ``s = m + z = A y``: then the field's
turn, ``s ← Rᵀ s + (I − Rᵀ) z``, is linear, nothing ties ``s`` to ``z`` at
rest (the covariance stays well conditioned while nothing can be learned),
and the measurement ``y = A⁻¹ (s + τ ω × (s − z))`` is linear in ``s`` and
``z`` and linearized about the estimate in ``d`` and ``τ`` only. (Written as
``A y = s``, with the measured ``y`` in the regressor, its noise would pull
``A`` towards 0 while the body rests: the errors-in-variables bias.) Two
things measured on BROAD (Laidig et al. 2021) shape the filter beyond that:

- The field lags the gyro on real hardware (about 12 ms there);
  uncorrected, the lag correlates with the turn rate and biases the offset
  by about 1 % of the field. The lag ``τ`` is a state:
  ``m(t − τ) ≈ m + τ ω × m``.
- The world field is not quite constant where a body moves (a lab's field
  changes by a few percent over a metre). ``m`` is a random walk, relative
  ``field_rw`` per √s, so a slowly changing field is not learned as an
  offset; the offset itself may drift (``drift``).

Here: checking a saved calibration (:func:`check_calibration`), the
calibrated field, the heading between two fields, and where the measurement
Jacobians' changing entries sit.
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


# Entries of H (3 × 12) that change with the sample (the rest, the diagonal
# of I + τ[ω]× for s, is kept in a buffer): τ[ω]× for s, −τ[ω]× for z,
# −Y(y) for d, ω × m for τ.
_H_ROWS = (0, 0, 1, 1, 2, 2, 0, 0, 1, 1, 2, 2, 0, 0, 0, 1, 1, 1, 2, 2, 2, 2, 0, 1, 2)
_H_COLS = (1, 2, 0, 2, 0, 1, 4, 5, 3, 5, 3, 4, 6, 8, 9, 7, 8, 10, 6, 7, 9, 10, 11, 11, 11)
# Entries of J = [−I, Y(y)] (3 × 8) that change: Y(y).
_J_ROWS = (0, 0, 0, 1, 1, 1, 2, 2, 2, 2)
_J_COLS = (3, 5, 6, 4, 5, 7, 3, 4, 6, 7)
_EYE3 = np.eye(3)
_IDENTITY = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0)


def _calibrated(y, z, d):
    """``(I + D(d)) y − z`` for rows of shape (n, 3), (n, 3), (n, 5)."""
    y0, y1, y2 = y.T
    d0, d1, d2, d3, d4 = d.T
    return np.stack([y0 + d0 * y0 + d2 * y1 + d3 * y2, y1 + d2 * y0 + d1 * y1 + d4 * y2,
                     y2 + d3 * y0 + d4 * y1 - (d0 + d1) * y2], axis=1) - z


def _heading_between(up, f, g):
    """The angle (rad) about ``up`` from the horizontal part of ``f`` to that of ``g``."""
    a, b = np.cross(up, f), np.cross(up, g)
    return np.arctan2(np.einsum('ni,ni->n', np.cross(a, b), up),
                      np.einsum('ni,ni->n', a, b))
