"""
Each sample's attitude from the whole recording: :func:`smooth_attitude`.

A strapdown integration corrected by zero-phase averages: offline VQF's
decomposition (D. Laidig, T. Seel, "VQF: Highly accurate IMU orientation
estimation with bias estimation and magnetic disturbance rejection",
Information Fusion 2023, arXiv:2203.17024, and ``offline_vqf.cpp`` of the
``vqf`` package), with our estimator in it:

1. the gyro bias from our online estimator
   (:class:`~ext_observer.core.ahrs.ahrs_observer.AhrsObserver`): its
   estimate at the end of the recording, or (``bias='both'``) each
   sample's from the passes over the recording and over the time-reversed
   one, the two (of disjoint data) weighted by their variances;
2. the strapdown attitude ``q_g`` with that bias (body → a slowly drifting
   frame I);
3. the inclination: the specific force in I averaged over a window centred
   on each sample (a uniform weight in time: the body's linear acceleration
   averages to its change of velocity over the window), turned to the
   vertical;
4. the heading (9D): the field (with the online pass's calibration where it
   applied one, from the first sample on) in the inclination-corrected
   frame, its horizontal direction averaged over a wider window, each
   sample weighted by how close its norm and dip stay to the field's at the
   start of the recording, turned north.

The windows are Gaussian-like (three box filters, cumulative sums), symmetric
in time, so without delay; everything but the online passes is numpy on
whole arrays. Conventions as the estimator's: ``(w, x, y, z)``, sensor →
ENU, SI units. What each step gave on BROAD: docs/offline.md.
"""

import dataclasses
import math
import os

import numpy as np

from ..quaternion import multiply, normalize, quaternion_from_rotation_vector
from .ahrs_filters import quat_multiply, rotate
from .ahrs_observer import AhrsObserver
from .ahrs_params import AhrsParams
from .compiled import compiled_name, wanted

__all__ = ['SmoothParams', 'smooth_attitude']


@dataclasses.dataclass(frozen=True)
class SmoothParams:
    """
    The smoother's settings (physical units; defaults chosen on BROAD's tuning trials).

    Attributes
    ----------
    window_acc : float
        s, σ of the window that averages the specific force in I.
    window_mag : float
        s, σ of the window that averages the field's horizontal direction.
    window_far : float
        s, σ of a wider window for the heading, for where the near one
        holds only disturbed fields.
    far_share : float
        How much the wider window's samples count against the near one's
        (per unit of window weight).
    mag_sigma : float
        A field sample whose norm deviates from the reference by this
        fraction (or whose dip does by this many rad) weighs ``exp(−1/2)``
        as much as an undisturbed one.
    ref_time : float
        s, the start of the recording that gives the field's reference
        norm and dip (its medians); 0: the most common norm and dip of the
        whole recording instead (for a recording that may start in a
        disturbed field).
    delay : float
        s, how late the sensor's samples are on the motion (e.g. the group
        delay of its low-pass filters): each sample's attitude is read
        this much later on the smoothed one, as only a smoother can. 0:
        none.
    bias : {'end', 'both'}
        The gyro bias: the online pass's at its end, for every sample; or
        each sample's from the passes over the recording and over the
        time-reversed one (for a bias that wanders; twice the time).
    bias_chunk : float
        s between two readings of the online passes' bias estimates
        (``bias='both'``).
    online : AhrsParams or None
        The online passes' parameters (default: the shipped defaults).

    """

    window_acc: float = 2.0
    window_mag: float = 30.0
    window_far: float = 300.0
    far_share: float = 0.01
    mag_sigma: float = 0.02
    ref_time: float = 2.0
    bias: str = 'end'
    delay: float = 0.0
    bias_chunk: float = 0.5
    online: AhrsParams = None

    def __post_init__(self):
        for name in ('window_acc', 'window_mag', 'window_far', 'mag_sigma', 'bias_chunk'):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f'{name} must be positive and finite, got {value}')
        if not (math.isfinite(self.ref_time) and self.ref_time >= 0.0):
            raise ValueError(f'ref_time must be finite and ≥ 0, got {self.ref_time}')
        if not math.isfinite(self.delay):
            raise ValueError(f'delay must be finite, got {self.delay}')
        if self.bias not in ('end', 'both'):
            raise ValueError(f"bias must be 'end' or 'both', got {self.bias!r}")
        if not (math.isfinite(self.far_share) and self.far_share >= 0.0):
            raise ValueError(f'far_share must be finite and ≥ 0, got {self.far_share}')


def smooth_attitude(gyr, acc, mag, rate, params=None):
    """
    Each sample's attitude from the whole recording (a smoothed estimate).

    Parameters
    ----------
    gyr : array_like, shape (N, 3)
        Angular rate, rad/s, body frame.
    acc : array_like, shape (N, 3)
        Specific force, m/s² (points up at rest).
    mag : array_like, shape (N, 3), or None
        Magnetic field (any unit); None: 6D (the heading follows the gyro
        from the online estimator's first attitude).
    rate : float
        Sampling rate, Hz (samples evenly spaced, all finite).
    params : SmoothParams, optional

    Returns
    -------
    q : ndarray, shape (N, 4)
        Unit quaternions ``(w, x, y, z)``, sensor → ENU.
    cov : None
        No covariance yet (the return keeps its place).

    Raises
    ------
    ValueError
        For arrays of another shape, non-finite samples or a bad rate.

    """
    p = params if params is not None else SmoothParams()
    gyr, acc, mag = _checked(gyr, acc, mag, rate)
    dt = 1.0 / float(rate)
    bias, first, calibration = _bias(gyr, acc, mag, dt, p)
    q = _strapdown(gyr - bias, dt, first)
    q = _inclination(q, acc, rate, p)
    if mag is not None:
        q = _heading(q, calibration(mag), rate, p)
    if p.delay:
        q = _ahead(q, p.delay * rate)
    return q, None


def _ahead(q, samples):
    """
    ``q`` read ``samples`` later (may be fractional or negative), held at the ends.

    Between two samples, the normalized linear interpolation (the steps are
    small).
    """
    n = len(q)
    at = np.clip(np.arange(n) + samples, 0.0, n - 1.0)
    lo = np.minimum(np.floor(at).astype(np.int64), n - 2)
    frac = (at - lo)[:, None]
    a, b = q[lo], q[lo + 1]
    b = np.where(np.einsum('ij,ij->i', a, b)[:, None] < 0.0, -b, b)
    return normalize((1.0 - frac) * a + frac * b)


def _checked(gyr, acc, mag, rate):
    gyr = np.asarray(gyr, dtype=float)
    acc = np.asarray(acc, dtype=float)
    arrays = [('gyr', gyr), ('acc', acc)]
    if mag is not None:
        mag = np.asarray(mag, dtype=float)
        arrays.append(('mag', mag))
    for name, a in arrays:
        if a.ndim != 2 or a.shape[1] != 3:
            raise ValueError(f'{name} must have shape (N, 3), got {a.shape}')
        if a.shape[0] != gyr.shape[0]:
            raise ValueError(f'{name} has {a.shape[0]} samples, gyr {gyr.shape[0]}')
        if not np.isfinite(a).all():
            raise ValueError(f'{name} has non-finite samples')
    if len(gyr) < 2:
        raise ValueError(f'a recording needs at least 2 samples, got {len(gyr)}')
    if not (math.isfinite(rate) and rate > 0.0):
        raise ValueError(f'rate must be positive and finite, got {rate}')
    return gyr, acc, mag


def _bias_pass(gyr, acc, mag, dt, p):
    """
    The online estimator over the recording, its bias read every ``bias_chunk``.

    Returns the sample index of each reading (K,), the biases (K, 3), their
    variances (K, 3), the first estimate (4,) and the estimator (its state
    at the end).
    """
    est = AhrsObserver(p.online, use_mag=mag is not None)
    n = len(gyr)
    step = max(1, int(round(p.bias_chunk / dt)))
    ends = np.append(np.arange(step, n, step), n)
    biases, variances = np.empty((len(ends), 3)), np.empty((len(ends), 3))
    start, first = 0, None
    for i, end in enumerate(ends):
        q = est.run(gyr[start:end], acc[start:end], None if mag is None else mag[start:end], dt)
        if first is None:
            first = q[0]
        biases[i] = est.bias
        variances[i] = np.square(est.bias_std)
        start = end
    return ends - 1, biases, variances, first, est


def _bias(gyr, acc, mag, dt, p):
    """
    The gyro bias (N, 3) or (3,), the first attitude and the field's calibration.

    ``bias='end'``: one online pass; its bias at the end (it has seen the
    whole recording) for every sample. ``'both'``: :func:`_bias_both_ways`.
    """
    if p.bias == 'both':
        return _bias_both_ways(gyr, acc, mag, dt, p)
    est = AhrsObserver(p.online, use_mag=mag is not None)
    q = est.run(gyr, acc, mag, dt)
    return np.array(est.bias), q[0], _calibration(est)


def _bias_both_ways(gyr, acc, mag, dt, p):
    """
    The bias at each sample from the recording up to it and after it.

    Time-reversed, the gyro reads ``−ω − b``: the reversed pass's bias is
    negated back. Each sample takes the variance-weighted mean of the two
    (VQF's offline form does so with its own filter). Also returns the
    forward pass's first estimate and the field's calibration (a function
    of the raw field).
    """
    n = len(gyr)
    index_f, b_f, v_f, first, forward = _bias_pass(gyr, acc, mag, dt, p)
    index_b, b_b, v_b, _, _ = _bias_pass(-gyr[::-1], acc[::-1],
                                         None if mag is None else mag[::-1], dt, p)
    # Reading i of the reversed pass holds the samples from n − 1 − index_b[i] on.
    index_b = (n - 1 - index_b)[::-1]
    b_b, v_b = -b_b[::-1], v_b[::-1]
    samples = np.arange(n)
    bias = np.empty((n, 3))
    for axis in range(3):
        bf = np.interp(samples, index_f, b_f[:, axis])
        vf = np.interp(samples, index_f, v_f[:, axis])
        bb = np.interp(samples, index_b, b_b[:, axis])
        vb = np.interp(samples, index_b, v_b[:, axis])
        bias[:, axis] = (bf * vb + bb * vf) / (vf + vb)
    return bias, first, _calibration(forward)


def _calibration(est):
    """
    The raw field → the calibrated field, by the online pass's calibration at its end.

    That calibration has seen the whole recording; it applies from the first
    sample. Where the online pass applied none (off, or not worth applying:
    ``mag_cal_deadband``), the field as given.
    """
    cal = est.calibration
    if cal is None or not cal.applied:
        return lambda mag: mag
    inverse = np.linalg.inv(cal.soft_iron)
    offset = cal.bias
    return lambda mag: (mag - offset) @ inverse.T


def _strapdown(rate, dt, first):
    """
    ``q_k = q_{k−1} ⊗ exp(ω_k dt / 2)`` from ``q_0 = first``, each normalized.

    One compiled loop where numba is wanted (:func:`_integrate`); else
    :func:`_strapdown_blocked`, numpy on whole arrays. The two agree to
    rounding.
    """
    loop = _compiled_loop()
    if loop is None:
        return _strapdown_blocked(rate, dt, first)
    out = np.empty((len(rate), 4))
    first = normalize(np.asarray(first, dtype=float))
    loop(np.ascontiguousarray(rate, dtype=float), float(dt), first[0], first[1], first[2],
         first[3], out)
    return out


def _strapdown_blocked(rate, dt, first):
    """
    :func:`_strapdown` on whole arrays: a blocked scan.

    The running products within blocks of about √N samples (one product per
    column, over all blocks at once), then the blocks' running products, then
    each block's products from its start's.
    """
    n = len(rate)
    step = quaternion_from_rotation_vector(rate * dt)
    step[0] = normalize(np.asarray(first, dtype=float))
    size = max(1, int(math.ceil(math.sqrt(n))))
    blocks = -(-n // size)
    padded = np.zeros((blocks * size, 4))
    padded[:, 0] = 1.0
    padded[:n] = step
    # Column j holds the j-th sample of every block, contiguous.
    within = np.ascontiguousarray(padded.reshape(blocks, size, 4).transpose(1, 0, 2))
    for j in range(1, size):
        within[j] = multiply(within[j - 1], within[j])
    before = np.empty((blocks, 4))
    before[0] = (1.0, 0.0, 0.0, 0.0)
    for i in range(1, blocks):
        before[i] = multiply(before[i - 1], within[-1, i - 1])
    q = multiply(before[None, :, :], within).transpose(1, 0, 2).reshape(-1, 4)[:n]
    return normalize(q)


def _integrate(rate, dt, w, x, y, z, out):
    """
    The strapdown loop over samples: ``q_k`` into ``out`` (N, 4) from ``q_0 = (w, x, y, z)``.

    Compiled by :func:`_compiled_loop` (``_product``: the kernels' quaternion
    product, compiled).
    """
    out[0, 0], out[0, 1], out[0, 2], out[0, 3] = w, x, y, z
    for k in range(1, rate.shape[0]):
        vx, vy, vz = rate[k, 0] * dt, rate[k, 1] * dt, rate[k, 2] * dt
        angle = math.sqrt(vx * vx + vy * vy + vz * vz)
        # sin(a / 2) / a, its limit 1/2 below a rounding error's angle.
        s = math.sin(0.5 * angle) / angle if angle > 1e-8 else 0.5
        w, x, y, z = _product(w, x, y, z, math.cos(0.5 * angle), s * vx, s * vy, s * vz)
        scale = 1.0 / math.sqrt(w * w + x * x + y * y + z * z)
        w, x, y, z = w * scale, x * scale, y * scale, z * scale
        out[k, 0], out[k, 1], out[k, 2], out[k, 3] = w, x, y, z


_product = quat_multiply
_LOOP = []


def _compiled_loop():
    """
    :func:`_integrate` compiled by numba, or None where numba is not wanted.

    Cached on disk beside the kernels' compiled code, in a folder of its own
    (the kernels' twin of ``quat_multiply`` has the same file and name) for
    this version of the kernel files
    (:func:`~ext_observer.core.ahrs.compiled.compiled_name`).
    """
    global _product
    if not _LOOP:
        loop = None
        if wanted(None)[0]:
            import numba
            name, folder = compiled_name()
            saved = numba.config.CACHE_DIR
            numba.config.CACHE_DIR = os.path.join(folder, f'{name}_smoother')
            try:
                _product = numba.njit(cache=True)(quat_multiply)
                loop = numba.njit(cache=True)(_integrate)
            finally:
                numba.config.CACHE_DIR = saved
        _LOOP.append(loop)
    return _LOOP[0]


def _rotate(q, v):
    """
    The vectors ``v`` (N, 3) rotated by the quaternions ``q`` (N, 4): ``q ⊗ v ⊗ q̄ / |q|²``.

    The kernels' rotation (:func:`~ext_observer.core.ahrs.ahrs_filters.rotate`),
    on columns.
    """
    out = np.empty((len(v), 3))
    out[:, 0], out[:, 1], out[:, 2] = rotate(q[:, 0], q[:, 1], q[:, 2], q[:, 3],
                                             v[:, 0], v[:, 1], v[:, 2])
    return out


def _about_vertical(angle):
    """Unit quaternions (N, 4) of rotations by ``angle`` (N,) rad about the world's z axis."""
    r = np.zeros((len(angle), 4))
    r[:, 0] = np.cos(0.5 * angle)
    r[:, 3] = np.sin(0.5 * angle)
    return r


def _box(x, h):
    """Sums of ``x`` (along axis 0) over ``[k − h, k + h]`` at each sample ``k``, truncated."""
    n = len(x)
    c = np.empty((n + 2 * h + 1,) + x.shape[1:])
    c[:h + 1] = 0.0
    np.cumsum(x, axis=0, out=c[h + 1:n + h + 1])
    c[n + h + 1:] = c[n + h]
    # c[h + 1 + k] is the sum up to sample k; before the first, 0; past the last, all.
    return c[2 * h + 1:] - c[:n]


def _sums(x, weight, sigma_samples):
    """
    ``Σ K w x`` and ``Σ K w`` over a Gaussian-like window ``K`` of σ samples.

    Three centred box filters of ``2 h + 1`` samples (``h`` ≈ σ: a window of
    variance σ²), applied alike to ``weight x`` and ``weight``: zero phase,
    truncated at the ends.
    """
    h = max(1, int(round(sigma_samples)))
    num = weight[:, None] * x
    den = weight
    for _ in range(3):
        num = _box(num, h)
        den = _box(den, h)
    return num, den


def _average(x, weight, sigma_samples, far=None):
    """
    The weighted mean of ``x`` (N, k) over a window of σ samples around each.

    ``far``: ``(σ_far, share)``, a second, wider window whose weights count
    ``share`` as much (per unit of window weight): where the near window
    holds no weight, the far one decides.
    """
    num, den = _sums(x, weight, sigma_samples)
    if far is not None and far[1] > 0.0:
        num_far, den_far = _sums(x, weight, far[0])
        scale = far[1] * sigma_samples / far[0]
        num = num + scale * num_far
        den = den + scale * den_far
    return num / np.maximum(den, np.finfo(float).tiny)[:, None]


def _inclination(q, acc, rate, p):
    """``c ⊗ q``: ``c``, the smallest rotation turning the averaged specific force in I up."""
    a_i = _rotate(q, acc)
    mean = _average(a_i, np.ones(len(q)), p.window_acc * rate)
    up = mean / np.linalg.norm(mean, axis=1, keepdims=True)
    # (1 + up·z, up × z) normalized: the rotation by the angle between up and z about up × z.
    c = np.stack((1.0 + up[:, 2], up[:, 1], -up[:, 0], np.zeros(len(up))), axis=1)
    return normalize(multiply(normalize(c), q))


def _heading(q, mag, rate, p):
    """``r ⊗ q``: ``r``, about the vertical, turns the averaged horizontal field north (+y)."""
    m = _rotate(q, mag)
    norm = np.linalg.norm(m, axis=1)
    horizontal = np.hypot(m[:, 0], m[:, 1])
    dip = np.arctan2(m[:, 2], horizontal)
    if not np.any(horizontal > 0.0):
        return q  # no field, no heading: the strapdown's
    start = slice(0, max(1, int(round(p.ref_time * rate))))
    if p.ref_time > 0.0 and np.median(norm[start]) > 0.0:
        ref_norm = float(np.median(norm[start]))
        ref_dip = float(np.median(dip[start]))
    else:
        ref_norm, ref_dip = _most_common(norm, dip, p.mag_sigma)
    z = (np.square((norm - ref_norm) / (p.mag_sigma * ref_norm))
         + np.square((dip - ref_dip) / p.mag_sigma))
    weight = np.exp(-0.5 * np.minimum(z, 1400.0))
    unit = m[:, :2] / np.maximum(horizontal, np.finfo(float).tiny)[:, None]
    mean = _average(unit, weight, p.window_mag * rate, (p.window_far * rate, p.far_share))
    # The rotation by δ about z takes (sin δ, cos δ)·|h| to (0, |h|): north.
    return normalize(multiply(_about_vertical(np.arctan2(mean[:, 0], mean[:, 1])), q))


def _most_common(norm, dip, sigma, candidates=64, samples=20000):
    """
    The (norm, dip) that the most samples lie near: the mode, under the weights' kernel.

    The candidates are quantiles of the norm and of the dip (``candidates``
    of each); the samples (those with a field), at most about ``samples``
    evenly spread.
    """
    some = np.flatnonzero(norm > 0.0)
    some = some[::max(1, len(some) // samples)]
    n, d = norm[some], dip[some]
    pick = np.linspace(0, len(n) - 1, candidates).astype(np.int64)
    order = np.argsort(n)
    cn, cd = n[order][pick], d[order][pick]
    order = np.argsort(d)
    cn = np.concatenate((cn, n[order][pick]))
    cd = np.concatenate((cd, d[order][pick]))
    z = (np.square((n[None, :] - cn[:, None]) / (sigma * cn[:, None]))
         + np.square((d[None, :] - cd[:, None]) / sigma))
    best = int(np.argmax(np.exp(-0.5 * np.minimum(z, 1400.0)).sum(axis=1)))
    return float(cn[best]), float(cd[best])
