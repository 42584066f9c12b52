"""
The magnetometer's calibration fitted on the whole recording: :func:`fit_calibration`.

The model is the online calibrator's (docs/calibration.md): the raw field
``y = S m + b``, hard iron ``b`` and soft iron ``S``; calibrated,
``m = A (y − b)``, ``A = S⁻¹ = I + E`` with ``E`` symmetric and traceless
(the field keeps the raw one's unit). The Earth's field is fixed in the
world: turned by the smoothed attitude ``R_k`` (its inclination from the
whole recording, its heading the strapdown's, which drifts slowly), the
calibrated field is one vector ``m_w`` per stretch of the recording,
``R_k A (y_k − b) = m_w``. With ``c = A b`` that is linear in ``(E, c, m_w)``,
so one weighted least-squares fit over every sample at once needs no
starting guess: the gyro-aided calibration of Troni and Whitcomb (2013)
and the world-field view of Kok and Schön (2016) that the online
calibrator runs as a Kalman filter, here in batch, with the direction of
the field (its dip included) and not only its norm, as the ellipsoid fits
of Renaudin et al. (2010) and Vasconcelos et al. (2011) use. Disturbed
stretches are down-weighted (iteratively reweighted by the residual, a
Cauchy weight); the priors are the online calibrator's (``E`` about 0, σ
``mag_cal_soft_iron``) and, loosely, the hard iron about a given one. The
samples' errors are correlated in time: the data count as one
independent sample per ``correlation`` seconds. Where the recording's
rotations do not determine the soft iron (the posterior σ of some
combination of ``E`` stays above half the prior's), ``E`` is held at 0 and
only the hard iron is fitted. numpy only.

Not used by :func:`~ext_observer.core.ahrs.smoother.smooth_attitude` yet:
on BROAD as recorded it made the smoothed heading worse than the online
pass's calibration (docs/offline.md, "The calibration from the whole
recording"); ``bench/smooth_hard_iron.py --calibration fit`` measures it.
"""

import dataclasses

import numpy as np

__all__ = ['FieldCalibration', 'fit_calibration', 'rotation_matrices']

# The five traceless symmetric directions of E, as the online calibrator orders them.
_BASIS = np.array([
    [[1.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, -1.0]],
    [[0.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, -1.0]],
    [[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 0.0]],
    [[0.0, 0.0, 1.0], [0.0, 0.0, 0.0], [1.0, 0.0, 0.0]],
    [[0.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 1.0, 0.0]],
])


@dataclasses.dataclass(frozen=True)
class FieldCalibration:
    """
    A fitted calibration ``y = S m + b``.

    Attributes
    ----------
    bias : ndarray, shape (3,)
        The hard iron ``b`` (the field's unit).
    soft_iron : ndarray, shape (3, 3)
        ``S``; the identity where the recording did not determine it.
    norm : float
        The calibrated field's norm.
    soft_fitted : bool
        Whether the soft iron was fitted (else held at the prior).
    soft_sigma : float
        The posterior σ of the worst-determined combination of ``E``.

    """

    bias: np.ndarray
    soft_iron: np.ndarray
    norm: float
    soft_fitted: bool
    soft_sigma: float

    def apply(self, mag):
        """The calibrated field ``S⁻¹ (y − b)``, shape (N, 3)."""
        return (np.asarray(mag, dtype=float) - self.bias) @ np.linalg.inv(self.soft_iron).T


def rotation_matrices(q):
    """The rotation matrices (N, 3, 3) of unit quaternions ``q`` (N, 4) ``(w, x, y, z)``."""
    w, x, y, z = (q[:, i] for i in range(4))
    return np.stack((
        1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - w * z), 2.0 * (x * z + w * y),
        2.0 * (x * y + w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - w * x),
        2.0 * (x * z - w * y), 2.0 * (y * z + w * x), 1.0 - 2.0 * (x * x + y * y),
    ), axis=1).reshape(-1, 3, 3)


def fit_calibration(mag, q, rate, prior_bias=None, soft_iron=0.05, hard_iron=10.0, robust=0.05,
              correlation=1.0, segment=30.0, samples=20000, iterations=6):
    """
    The calibration that keeps the field fixed in the world over the recording.

    Parameters
    ----------
    mag : array_like, shape (N, 3)
        The raw field (any unit), all finite.
    q : array_like, shape (N, 4)
        Each sample's attitude, sensor → world, ``(w, x, y, z)``, e.g. the
        smoother's strapdown with its inclination corrected.
    rate : float
        Hz, the samples' rate.
    prior_bias : array_like, shape (3,), optional
        The hard iron's prior mean (default 0).
    soft_iron : float
        Prior σ of each element of ``E`` (the online calibrator's
        ``mag_cal_soft_iron``).
    hard_iron : float
        Prior σ of the hard iron about ``prior_bias``, in units of the median
        norm of ``mag − prior_bias`` (the default leaves it free).
    robust : float
        The Cauchy weight's scale, relative to the field's norm.
    correlation : float
        s over which the samples' errors count as one.
    segment : float
        s, the stretch over which the world field ``m_w`` is one vector (the
        strapdown's heading drifts, the field changes where the body goes).
    samples : int
        At most about this many samples, evenly spread, enter the fit.
    iterations : int
        Reweighting rounds.

    Returns
    -------
    FieldCalibration

    Raises
    ------
    ValueError
        For arrays of another shape, a non-finite or zero field, or bad settings.

    """
    y = np.asarray(mag, dtype=float)
    q = np.asarray(q, dtype=float)
    if y.ndim != 2 or y.shape[1] != 3 or len(y) < 10:
        raise ValueError(f'mag must have shape (N ≥ 10, 3), got {y.shape}')
    if q.shape != (len(y), 4):
        raise ValueError(f'q must have shape ({len(y)}, 4), got {q.shape}')
    if not (np.isfinite(y).all() and np.isfinite(q).all()):
        raise ValueError('mag and q must be finite')
    for name, value in (('rate', rate), ('soft_iron', soft_iron), ('hard_iron', hard_iron),
                        ('robust', robust), ('correlation', correlation),
                        ('segment', segment)):
        if not (np.isfinite(value) and value > 0.0):
            raise ValueError(f'{name} must be positive and finite, got {value}')
    step = max(1, len(y) // samples)
    index = np.arange(0, len(y), step)
    b0 = np.zeros(3) if prior_bias is None else np.asarray(prior_bias, dtype=float)
    scale = float(np.median(np.linalg.norm(y - b0, axis=1)))
    if not scale > 0.0:
        raise ValueError('mag is zero')
    ys = (y[index] - b0) / scale  # the prior's hard iron removed: c about 0
    r = rotation_matrices(q[index])
    seg = (index / rate / segment).astype(np.int64)
    segments = int(seg.max()) + 1
    share = max(1.0, len(y) / rate / correlation) / len(index)
    fit = _world(ys, r, seg, segments, soft_iron, hard_iron, robust, share, iterations, True)
    sigma = fit[2]
    fitted = sigma <= 0.5 * soft_iron
    if not fitted:
        fit = _world(ys, r, seg, segments, soft_iron, hard_iron, robust, share, iterations,
                     False)
    e, c, _, norm = fit
    a = np.eye(3) + np.einsum('p,pij->ij', e, _BASIS)
    b = b0 + scale * np.linalg.solve(a, c)
    return FieldCalibration(b, np.linalg.inv(a), norm * scale, bool(fitted), float(sigma))


def _world(y, r, seg, segments, soft_sigma, hard_sigma, robust, share, iterations, soft):
    """:func:`fit_calibration`'s reweighted least squares; ``(e, c, σ of e, |m_w|)``."""
    n = len(y)
    n_e = 5 if soft else 0
    size = n_e + 3 + 3 * segments
    # Rows: 3 per sample, r_k = R_k (y_k + E y_k − c) − m_w(seg_k).
    jac = np.zeros((n, 3, size))
    if soft:
        jac[:, :, :5] = np.einsum('nij,pjk,nk->nip', r, _BASIS, y)
    jac[:, :, n_e:n_e + 3] = -r
    for axis in range(3):
        jac[np.arange(n), axis, n_e + 3 + 3 * seg + axis] = -1.0
    rhs = -np.einsum('nij,nj->ni', r, y)
    prior = np.zeros(size)
    prior[:n_e] = 1.0 / soft_sigma ** 2
    prior[n_e:n_e + 3] = 1.0 / hard_sigma ** 2
    weight = np.ones(n)
    flat = jac.reshape(3 * n, size)
    for _ in range(iterations):
        w = np.repeat(weight * share / robust ** 2, 3)
        info = flat.T @ (flat * w[:, None]) + np.diag(prior)
        theta = np.linalg.solve(info, flat.T @ (rhs.reshape(-1) * w))
        res = (flat @ theta).reshape(n, 3) - rhs
        norm = float(np.median(np.linalg.norm(theta[n_e + 3:].reshape(-1, 3), axis=1)))
        weight = 1.0 / (1.0 + np.sum(np.square(res), axis=1) / (robust * norm) ** 2)
    sigma = 0.0
    if soft:
        sigma = float(np.sqrt(np.max(np.linalg.eigvalsh(np.linalg.inv(info)[:5, :5]))))
    e = np.zeros(5)
    e[:n_e] = theta[:n_e]
    return e, theta[n_e:n_e + 3], sigma, norm
