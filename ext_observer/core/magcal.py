"""
Online magnetometer calibration: hard iron, soft iron and the field's lag.

The model, body frame: a raw field sample is ``y = S m + b``, with ``m`` the
true field, ``b`` the hard-iron offset and ``S`` a symmetric soft-iron
matrix. Written with ``A = S⁻¹`` (calibrated field ``A y − z``, ``z = A b``)
it is linear in the unknowns::

    y = m + z − D(d) y,        A = I + D(d),  D symmetric, trace 0,

so a Kalman filter estimates ``(m, z, d)`` exactly as a linear one; no
linearization of the calibration itself. ``S`` is known only up to a scale
(a uniform gain moves no direction), fixed here by ``trace(A) = 3``, or by
the trace of a loaded matrix.

What makes it observable is the gyro. The field is fixed in the world, so
in the body frame it turns against the body: between two fields the state
``m`` is propagated with the gyro's rotation, ``m ← Rᵀ m``, and a body that
turns about two axes leaves one offset and one matrix that fit
(gyro-aided calibration: Troni and Whitcomb 2013, "Adaptive estimation of
measurement bias in three-dimensional field sensors with angular rate
sensors", Robotics: Science and Systems; Kok and Schön 2016,
"Magnetometer calibration using inertial sensors", IEEE Sensors Journal
16(14), for the view of the field as a constant world vector seen through
the gyro's orientation). Two things measured on BROAD (Laidig et al. 2021)
shape the filter beyond that:

- The field lags the gyro by a few samples on real hardware (about 12 ms
  there); uncorrected, the lag correlates with the turn rate and biases the
  offset by about 1 % of the field. The lag ``τ`` is a state:
  ``m(t − τ) ≈ m + τ ω × m``, so ``A y − z = m + τ ω × m``, linearized in
  ``τ`` only (an extended step on one scalar).
- The world field is not quite constant where a body moves (a lab's field
  changes by a few percent over a metre). ``m`` is a random walk, relative
  ``field_rw`` per √s: the gyro's prediction is trusted over about a
  second, so a slowly changing field is not learned as an offset.

A sample whose innovation is improbable (``gate``) is not used (a field that
jumps: a magnet passing); a body-fixed offset that changes for good shows
as samples refused one after the other, and the calibration starts over.
The caller may also refuse a sample (``allow``): :class:`AhrsObserver
<ext_observer.core.ahrs.AhrsObserver>` does for a field its norm/dip test
rejects once calibrated.

**Convergence.** The quality is the heading error the calibration's
uncertainty would cause now: the covariance of ``(z, d)`` mapped onto the
calibrated field, along the horizontal direction across the field (body
frame, from the caller's up vector), over the horizontal field. Below
``heading`` (rad) the calibration is converged. Measured where it matters,
so a robot that only turns about its vertical converges (the offset along
that axis is never learned, and does not move the heading while it stays
level).

One code path serves one calibrator and a batch: the state has a leading
batch axis (length 1 for one calibrator), inputs and outputs are Python
floats, or arrays of shape ``(B,)`` with ``batch=B``. Units: the field in
any unit (``noise`` and ``field_rw`` are relative to its norm), time in s,
angular rate in rad/s.
"""

import math

import numpy as np

__all__ = ['MagCalibrator', 'STATES', 'check_calibration']

STATES = ('off', 'learning', 'converged', 'loaded')

# Innovations beyond this (χ², 3 degrees of freedom; 16.3 is 99.9 %) are refused.
GATE = 16.0
# Time constant (s) of the share of refused samples; above half, start over.
_REFUSED_TAU = 5.0
# The heading turn of the learned calibration: its mean square over the last
# this many learning steps, from a quality of _WATCH times the threshold on.
_SHIFT_SAMPLES = 1000
_WATCH = 3.0
# Prior standard deviation of an unknown offset and field, times the first field's norm.
_DIFFUSE = 4.0
# Prior standard deviation of a loaded offset, times the field's norm.
_LOADED_BIAS_STD = 0.05
_N = 12  # m (3), z (3), d (5), τ
_M, _Z, _D, _T = slice(0, 3), slice(3, 6), slice(6, 11), 11


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


# Entries of H (3 × 12) that change with the sample (the rest is I for z and
# the diagonal of I + τ[ω]×, kept in a buffer): τ[ω]×, −Y(y), ω × m.
_H_ROWS = (0, 0, 1, 1, 2, 2, 0, 0, 0, 1, 1, 1, 2, 2, 2, 2, 0, 1, 2)
_H_COLS = (1, 2, 0, 2, 0, 1, 6, 8, 9, 7, 8, 10, 6, 7, 9, 10, 11, 11, 11)
# Entries of J = [−I, Y(y)] (3 × 8) that change: Y(y).
_J_ROWS = (0, 0, 0, 1, 1, 1, 2, 2, 2, 2)
_J_COLS = (3, 5, 6, 4, 5, 7, 3, 4, 6, 7)
_EYE3 = np.eye(3)
_IDENTITY = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0)


class MagCalibrator:
    """
    Learns ``b`` and ``S`` of ``y = S m + b`` from fields and gyro rotations.

    Parameters
    ----------
    batch : int, optional
        ``None``: one calibrator, Python floats in and out; ``B``: arrays of
        shape ``(B,)``.
    enabled : bool or ndarray of bool, shape (B,)
        Where false the calibrator is ``'off'``: :meth:`apply` returns the
        field as given and nothing is learned.
    noise : float or ndarray
        Standard deviation of the field's noise per sample and axis, relative
        to the field's norm.
    field_rw : float or ndarray
        Random walk of the field in the world, relative to its norm, per √s.
    soft_iron : float or ndarray
        Prior standard deviation of each element of ``S − I``.
    delay : float or ndarray
        Prior standard deviation of the field's lag behind the gyro (s); 0
        does not learn it (no lag).
    heading : float or ndarray
        Converged when the heading error from the calibration's uncertainty
        is below this (rad).

    Attributes
    ----------
    counts : dict of ndarray (B,) or (1,)
        ``fields`` given to :meth:`learn`, ``used``, ``gated`` (improbable),
        ``refused`` (by the caller), ``invalid`` (non-finite or zero),
        ``resets`` (started over after refusals one after the other).

    """

    def __init__(self, batch=None, enabled=True, noise=0.025, field_rw=0.03, soft_iron=0.1,
                 delay=0.02, heading=math.radians(3.0), deadband=math.radians(10.0),
                 drift=0.002):
        self.batch = batch
        n = 1 if batch is None else int(batch)
        self._n = n

        def per(value):
            return np.broadcast_to(np.asarray(value, dtype=float), (n,)).copy()

        self._enabled = np.broadcast_to(np.asarray(enabled, dtype=bool), (n,)).copy()
        self._noise = per(noise)
        self._field_rw = per(field_rw)
        self._soft_iron = per(soft_iron)
        self._delay = per(delay)
        self._heading = per(heading)
        self._deadband = per(deadband)
        self._drift = per(drift)
        self._h = np.zeros((n, 3, _N))
        self._h[:, [0, 1, 2, 0, 1, 2], [0, 1, 2, 3, 4, 5]] = 1.0
        self._j = np.zeros((n, 3, 8))
        self._j[:, [0, 1, 2], [0, 1, 2]] = -1.0
        self.reset()

    # --- state ---------------------------------------------------------------

    def reset(self):
        """Forget the calibration: learn from the next field on."""
        n = self._n
        self._x = np.zeros((n, _N))
        self._p = np.zeros((n, _N, _N))
        self._scale = np.ones(n)  # A = scale · (I + D)
        self._fresh = np.ones(n, dtype=bool)  # initialize at the next valid field
        self._loaded = np.zeros(n, dtype=bool)
        self._converged = np.zeros(n, dtype=bool)
        self._prior = [None] * n  # what a fresh start starts from
        self._quality = np.full(n, np.inf)
        self._stale = False
        self._learned = 0  # learning steps, for the occasional symmetrization of P
        self._refused_share = np.zeros(n)
        self._nis = np.full(n, 3.0)
        # The field as given is applied until the learned calibration turns
        # the heading by more than the deadband (mean square, rad²).
        self._identity = np.ones(n, dtype=bool)
        self._shift = np.zeros(n)
        self._watched = np.zeros(n)
        self._field_scale = np.ones(n)
        self.counts = {key: np.zeros(n, dtype=np.int64)
                       for key in ('fields', 'used', 'gated', 'refused', 'invalid', 'resets')}
        self._cache()

    def restart(self):
        """Keep what is learned, follow the field afresh from the next sample."""
        for i in range(self._n):
            if self._enabled[i] and not self._fresh[i]:
                self._prior[i] = (self._x[i, 3:].copy(), self._scale[i],
                                  self._p[i, 3:, 3:].copy())
        self._fresh[:] = True

    def load(self, bias, soft_iron, index=None):
        """
        Start from a saved calibration (state ``'loaded'``), refined online.

        Parameters
        ----------
        bias : sequence of 3 floats
            ``b``, in the field's unit.
        soft_iron : sequence of 9 floats or array_like, shape (3, 3)
            ``S``, row-major.
        index : int, optional
            With ``batch``, the element to load (default: all).

        Raises
        ------
        ValueError
            For a non-finite, asymmetric, singular or indefinite value.

        """
        b, s = check_calibration(bias, soft_iron)
        a = np.linalg.inv(s)
        scale = np.trace(a) / 3.0
        unit = a / scale  # I + D
        state = np.concatenate([unit @ b, [unit[0, 0] - 1.0, unit[1, 1] - 1.0, unit[0, 1],
                                           unit[0, 2], unit[1, 2], 0.0]])
        for i in range(self._n) if index is None else [int(index)]:
            if self._enabled[i]:
                self._prior[i] = (state.copy(), scale, None)
                self._fresh[i] = True
                self._loaded[i] = True
                self._identity[i] = False
                self._converged[i] = False
        self._cache()

    # --- learning ----------------------------------------------------------

    def learn(self, mag, rotation, dt, rate, up=None, allow=True):
        """
        Learn from one field sample.

        Parameters
        ----------
        mag : sequence of 3 (floats or arrays)
            The raw field, body frame.
        rotation : sequence of 4 (floats or arrays)
            ``(w, x, y, z)``: the body's rotation since the previous sample
            learned from, previous body frame → current one (the product of
            the gyro's increments; any nonzero norm).
        dt : float
            Seconds since that sample.
        rate : sequence of 3 (floats or arrays)
            The angular rate now (rad/s, bias removed), for the lag.
        up : sequence of 3 (floats or arrays), optional
            The world's vertical in the body frame (unit), for the quality;
            without it the error of the whole calibrated field counts.
        allow : bool or ndarray of bool
            False: the caller refuses this sample (counted as ``refused``).

        Returns
        -------
        bool or ndarray of bool
            Whether the sample was used.

        """
        n = self._n
        counts = self.counts
        on = self._enabled
        y = np.array(mag, dtype=float).reshape(3, n).T
        norm = np.sqrt((y * y).sum(axis=1))
        counts['fields'] += on
        take = on & np.isfinite(norm) & (norm > 0.0)
        if not take.all():
            counts['invalid'] += on & ~take
        if allow is not True:
            allow = np.asarray(allow, dtype=bool).reshape(-1)
            counts['refused'] += take & ~allow
            take &= allow
        if not take.all():
            y[~take] = 0.0
        w = np.array(rate, dtype=float).reshape(3, n).T
        if not np.isfinite(w).all():
            w[~np.isfinite(w)] = 0.0
        if not self._fresh.all():
            self._predict(rotation, dt)
        start = take & self._fresh
        if start.any():
            self._start(start, y, norm)
        live = take & ~start
        use = self._update(y, w, live, norm)
        counts['used'] += use | start
        counts['gated'] += live & ~use
        # Refusals one after the other: the offset changed; start over.
        k_share = 1.0 - math.exp(-float(dt) / _REFUSED_TAU)
        share = self._refused_share
        self._refused_share = np.where(live, share + k_share * (~use - share), share)
        lost = live & (self._refused_share > 0.5)
        if lost.any():
            counts['resets'] += lost
            self._fresh |= lost
            self._loaded &= ~lost
            self._converged &= ~lost
            self._identity |= lost
            self._shift[lost] = 0.0
            self._watched[lost] = 0.0
            self._refused_share[lost] = 0.0
            for i in np.flatnonzero(lost):
                self._prior[i] = None
        up_rows = None if up is None else np.array(up, dtype=float).reshape(3, n).T
        self._seen = (y, up_rows, take & ~self._fresh)
        if (self._seen[2] & ~self._loaded & ~self._converged).any():
            self._assess()  # the convergence test needs the quality now
        else:
            self._stale = True  # computed when asked for
        if up is not None:
            # Watched once the calibration is nearly good enough to be used.
            watch = (take & ~self._fresh & self._identity
                     & (self._quality < _WATCH * self._heading))
            if watch.any():
                self._watch(y, up, watch)
        self._cache()
        return self._out(use | start)

    def _predict(self, rotation, dt):
        """The field turns against the body: ``m ← Rᵀ m``; it walks in the world."""
        n = self._n
        w, x, y, z = rotation
        s = 2.0 / (w * w + x * x + y * y + z * z)
        r = np.array([1.0 - s * (y * y + z * z), s * (x * y - w * z), s * (x * z + w * y),
                      s * (x * y + w * z), 1.0 - s * (x * x + z * z), s * (y * z - w * x),
                      s * (x * z - w * y), s * (y * z + w * x), 1.0 - s * (x * x + y * y)],
                     dtype=float).reshape(9, n).T.reshape(n, 3, 3)
        rt = r.transpose(0, 2, 1)
        state, p = self._x, self._p
        state[:, _M] = (rt @ state[:, _M, None])[:, :, 0]
        p[:, _M, :] = rt @ p[:, _M, :]
        p[:, :, _M] = p[:, :, _M] @ r
        q = (self._field_rw * self._field_scale) ** 2 * float(dt)
        p[:, _M, _M] += q[:, None, None] * _EYE3
        if self._drift.any():
            # The offset drifts (temperature, a payload moved): never quite frozen.
            q = (self._drift * self._field_scale) ** 2 * float(dt)
            p[:, _Z, _Z] += q[:, None, None] * _EYE3

    def _update(self, y, w, live, norm):
        """One Kalman update with ``y = m + τ ω × m + z − Y(y) d``; gated."""
        n = self._n
        x, p = self._x, self._p
        m0, m1, m2, z0, z1, z2, d0, d1, d2, d3, d4, tau = self._columns(x)
        y0, y1, y2 = self._columns(y)
        w0, w1, w2 = self._columns(w)
        c0, c1, c2 = w1 * m2 - w2 * m1, w2 * m0 - w0 * m2, w0 * m1 - w1 * m0
        nu = np.array([
            y0 - m0 - tau * c0 - z0 + y0 * d0 + y1 * d2 + y2 * d3,
            y1 - m1 - tau * c1 - z1 + y1 * d1 + y0 * d2 + y2 * d4,
            y2 - m2 - tau * c2 - z2 - y2 * (d0 + d1) + y0 * d3 + y1 * d4,
        ], dtype=float).reshape(3, n).T
        tw0, tw1, tw2 = tau * w0, tau * w1, tau * w2
        h = self._h
        h[:, _H_ROWS, _H_COLS] = np.array(
            [-tw2, tw1, tw2, -tw0, -tw1, tw0, -y0, -y1, -y2, -y1, -y0, -y2, y2, y2, -y0, -y1,
             c0, c1, c2], dtype=float).reshape(19, n).T
        ph = p @ h.transpose(0, 2, 1)
        s = h @ ph
        s += ((self._noise * self._field_scale) ** 2)[:, None, None] * _EYE3
        s_inv = np.linalg.inv(s)
        nis = np.einsum('ni,nij,nj->n', nu, s_inv, nu)
        use = live & (nis < GATE)
        self._nis = np.where(use, self._nis + 0.01 * (nis - self._nis), self._nis)
        k = ph @ s_inv
        if not use.all():
            k[~use] = 0.0
        x += (k @ nu[:, :, None])[:, :, 0]
        p -= k @ ph.transpose(0, 2, 1)
        self._learned += 1
        if self._learned % 64 == 0:  # rounding makes P drift from symmetric, slowly
            p[:] = 0.5 * (p + p.transpose(0, 2, 1))
        self._field_scale = np.where(use, np.maximum(
            np.sqrt((x[:, _M] ** 2).sum(axis=1)), 0.25 * norm), self._field_scale)
        return use

    def _start(self, start, y, norm):
        """Initialize the elements ``start`` from the field ``y``."""
        x, p = self._x, self._p
        for i in np.flatnonzero(start):
            prior = self._prior[i]
            p[i] = 0.0
            x[i] = 0.0
            if prior is None:
                self._scale[i] = 1.0
                big = (_DIFFUSE * norm[i]) ** 2
                p[i, 3, 3] = p[i, 4, 4] = p[i, 5, 5] = big
                p[i, _D, _D] = np.eye(5) * self._soft_iron[i] ** 2
                p[i, _T, _T] = self._delay[i] ** 2
            else:
                x[i, 3:], self._scale[i], cov = prior
                if cov is not None:
                    p[i, 3:, 3:] = cov
                else:  # loaded: a tighter prior about it
                    std = _LOADED_BIAS_STD * norm[i] / self._scale[i]
                    p[i, 3, 3] = p[i, 4, 4] = p[i, 5, 5] = std * std
                    p[i, _D, _D] = np.eye(5) * (0.2 * self._soft_iron[i]) ** 2
                    p[i, _T, _T] = self._delay[i] ** 2
            # The field now is this sample calibrated, m = A y − z: as uncertain
            # as the calibration (and correlated with it), plus the noise.
            d0, d1, d2, d3, d4 = x[i, _D]
            a = np.array([[1.0 + d0, d2, d3], [d2, 1.0 + d1, d4], [d3, d4, 1.0 - d0 - d1]])
            x[i, _M] = a @ y[i] - x[i, _Z]
            j = np.zeros((3, 8))
            j[:, :3] = -np.eye(3)
            j[_J_ROWS, _J_COLS] = (y[i, 0], y[i, 1], y[i, 2], y[i, 1], y[i, 0], y[i, 2],
                                   -y[i, 2], -y[i, 2], y[i, 0], y[i, 1])
            p[i, _M, 3:11] = j @ p[i, 3:11, 3:11]
            p[i, 3:11, _M] = p[i, _M, 3:11].T
            noise = self._noise[i] * norm[i]
            p[i, _M, _M] = j @ p[i, 3:11, 3:11] @ j.T + np.eye(3) * noise * noise
            self._field_scale[i] = max(float(np.linalg.norm(x[i, _M])), 0.25 * norm[i])
            self._refused_share[i] = 0.0
        self._fresh &= ~start

    def _watch(self, y, up, watch):
        """How far the learned calibration turns the heading from the field as given."""
        _, _, _, z0, z1, z2, d0, d1, d2, d3, d4, _ = self._columns(self._x)
        y0, y1, y2 = self._columns(y)
        u0, u1, u2 = up
        f0 = y0 + d0 * y0 + d2 * y1 + d3 * y2 - z0
        f1 = y1 + d2 * y0 + d1 * y1 + d4 * y2 - z1
        f2 = y2 + d3 * y0 + d4 * y1 - (d0 + d1) * y2 - z2
        # Horizontal parts (turned by 90° about the vertical: the same angle).
        a0, a1, a2 = u1 * f2 - u2 * f1, u2 * f0 - u0 * f2, u0 * f1 - u1 * f0
        b0, b1, b2 = u1 * y2 - u2 * y1, u2 * y0 - u0 * y2, u0 * y1 - u1 * y0
        sin = u0 * (a1 * b2 - a2 * b1) + u1 * (a2 * b0 - a0 * b2) + u2 * (a0 * b1 - a1 * b0)
        angle = np.arctan2(sin, a0 * b0 + a1 * b1 + a2 * b2)
        # A mean over the samples watched, then over the last _SHIFT_SAMPLES.
        self._watched += watch
        k = 1.0 / np.minimum(np.maximum(self._watched, 1), _SHIFT_SAMPLES)
        shift = self._shift
        self._shift = np.where(watch, shift + k * (angle * angle - shift), shift)
        self._identity &= ~(self._converged & (self._shift > self._deadband ** 2))

    def _assess(self):
        """The quality (heading error from the calibration's uncertainty) and convergence."""
        y, up, live = self._seen
        self._stale = False
        n = self._n
        j = self._j
        y0, y1, y2 = self._columns(y)
        j[:, _J_ROWS, _J_COLS] = np.array([y0, y1, y2, y1, y0, y2, -y2, -y2, y0, y1],
                                          dtype=float).reshape(10, n).T
        c = j @ self._p[:, 3:11, 3:11] @ j.transpose(0, 2, 1)  # of the calibrated field
        _, _, _, z0, z1, z2, d0, d1, d2, d3, d4, _ = self._columns(self._x)
        f0 = y0 + d0 * y0 + d2 * y1 + d3 * y2 - z0
        f1 = y1 + d2 * y0 + d1 * y1 + d4 * y2 - z1
        f2 = y2 + d3 * y0 + d4 * y1 - (d0 + d1) * y2 - z2
        if up is None:
            across = np.sqrt(np.trace(c, axis1=1, axis2=2))
            horizontal = np.sqrt(np.array([f0 * f0 + f1 * f1 + f2 * f2], dtype=float)
                                 .reshape(n))
        else:
            u0, u1, u2 = self._columns(up)
            cross = np.array([u1 * f2 - u2 * f1, u2 * f0 - u0 * f2, u0 * f1 - u1 * f0],
                             dtype=float).reshape(3, n).T
            horizontal = np.sqrt((cross * cross).sum(axis=1))
            cross /= np.maximum(horizontal, 1e-300)[:, None]
            across = np.sqrt(np.maximum(np.einsum('ni,nij,nj->n', cross, c, cross), 0.0))
        quality = across / np.maximum(horizontal, 1e-300)
        self._quality = np.where(live, quality, self._quality)
        self._converged |= live & ~self._loaded & (quality < self._heading)

    # --- outputs -------------------------------------------------------------

    def _columns(self, a):
        """Columns of an (n, k) array: k floats (one calibrator) or k arrays."""
        return tuple(a[0].tolist()) if self.batch is None else tuple(a.T)

    def _cache(self):
        """The calibration :meth:`apply` uses, as floats (or (B,) arrays)."""
        _, _, _, z0, z1, z2, d0, d1, d2, d3, d4, _ = self._columns(self._x)
        g = self._columns(self._scale[:, None])[0]
        coef = [g + g * d0, g * d2, g * d3, g * d2, g + g * d1, g * d4, g * d3, g * d4,
                g - g * (d0 + d1), g * z0, g * z1, g * z2]
        ready = self._enabled & (self._loaded | self._converged)
        self._ready = ready | ~self._enabled
        applied = ready & ~self._identity
        self._applied = applied
        if self.batch is None:
            self._coef = tuple(coef) if applied[0] else _IDENTITY
        else:
            self._coef = tuple(np.where(applied, c, i) for c, i in zip(coef, _IDENTITY))

    def apply(self, mag):
        """
        The calibrated field ``A y − z``.

        The field as given until a learned calibration is applied (see
        :attr:`applied`), and where the calibrator is off.

        Parameters
        ----------
        mag : sequence of 3 (floats or arrays)

        Returns
        -------
        tuple of 3 (floats or arrays)

        """
        a00, a01, a02, a10, a11, a12, a20, a21, a22, z0, z1, z2 = self._coef
        y0, y1, y2 = mag
        return (a00 * y0 + a01 * y1 + a02 * y2 - z0, a10 * y0 + a11 * y1 + a12 * y2 - z1,
                a20 * y0 + a21 * y1 + a22 * y2 - z2)

    def _out(self, v):
        return v[0].item() if self.batch is None else v

    @property
    def ready(self):
        """Whether :meth:`apply` calibrates (converged or loaded), or the calibrator is off."""
        return self._out(self._ready)

    @property
    def applied(self):
        """Whether :meth:`apply` uses the learned (or loaded) calibration, not the identity."""
        return self._out(self._applied)

    @property
    def converged(self):
        """Whether the learned calibration has passed the quality threshold."""
        return self._out(self._enabled & self._converged)

    @property
    def state(self):
        """``'off'``, ``'learning'``, ``'converged'`` or ``'loaded'`` (a list with ``batch``)."""
        states = ['off' if not on else 'loaded' if loaded else
                  'converged' if conv else 'learning'
                  for on, loaded, conv in zip(self._enabled, self._loaded, self._converged)]
        return states[0] if self.batch is None else states

    @property
    def quality(self):
        """Heading error (rad, 1σ) the calibration's uncertainty causes; inf before any field."""
        if self._stale:
            self._assess()
        return self._out(self._quality)

    @property
    def bias(self):
        """The hard-iron offset ``b`` (field unit), shape (3,) or (B, 3)."""
        b = np.linalg.solve(self._unit_a(), self._x[:, _Z, None])[:, :, 0]
        return b[0] if self.batch is None else b

    @property
    def soft_iron(self):
        """The soft-iron matrix ``S``, shape (3, 3) or (B, 3, 3)."""
        s = np.linalg.inv(self._unit_a() * self._scale[:, None, None])
        return s[0] if self.batch is None else s

    def _unit_a(self):
        d0, d1, d2, d3, d4 = self._x[:, _D].T
        return np.stack([d0 + 1.0, d2, d3, d2, d1 + 1.0, d4, d3, d4, 1.0 - d0 - d1],
                        axis=1).reshape(self._n, 3, 3)

    @property
    def delay(self):
        """The field's lag behind the gyro (s)."""
        return self._out(self._x[:, _T])

    @property
    def field(self):
        """The calibrated field now, as the filter tracks it (body frame), shape (3,) or (B, 3)."""
        m = self._x[:, _M] * self._scale[:, None]
        return m[0] if self.batch is None else m
