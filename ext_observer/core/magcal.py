"""
Online magnetometer calibration: hard iron, soft iron and the field's lag.

The model, a Kalman filter on ``(s, z, d, τ)`` with the gyro turning the
field between samples: :mod:`~ext_observer.core.magcal_model`, which also
checks a saved calibration. Learned while the body turns, from the field and
the gyro alone.

A sample whose innovation is improbable (``GATE``) is not used (a field that
jumps: a magnet passing). The caller may also refuse a sample (``allow``):
:class:`AhrsObserver <ext_observer.core.ahrs.AhrsObserver>` does for a field
its norm/dip test rejects once calibrated. When most samples are refused
while the body turns (the offset changed for good, or a field that moved
while nothing was known misled the filter), or the soft iron leaves its
prior far behind, the calibration starts over.

**Convergence.** The quality is the heading error the calibration's
uncertainty would cause now: the covariance of ``(z, d)`` mapped onto the
calibrated field, along the horizontal direction across the field (body
frame, from the caller's up vector), over the horizontal field. The
calibration is converged once the quality has stayed below ``heading``
(rad) for ``_HOLD`` seconds of learning without the calibration turning the
heading by more than that meanwhile. Measured where it matters, so a robot
that only turns about its vertical converges (the offset along that axis is
never learned, and does not move the heading while it stays level).

**The field as given, or the learned calibration.** :meth:`MagCalibrator.apply`
returns the field as given until a converged calibration turns the heading
by more than ``deadband`` (RMS over the recent learning steps) from it: a
sensor calibrated already (BROAD's are) keeps its own calibration, which
what can be learned online, about 1 % of the field, does not beat. A loaded
calibration is applied at once.

One code path serves one calibrator and a batch: the state has a leading
batch axis (length 1 for one calibrator), inputs and outputs are Python
floats, or arrays of shape ``(B,)`` with ``batch=B``. Units: the field in
any unit (``noise``, ``field_rw`` and ``drift`` are relative to its norm),
time in s, angular rate in rad/s.
"""

import math

import numpy as np

from .magcal_model import (_calibrated, _EYE3, _H_COLS, _H_ROWS, _heading_between,
                           _IDENTITY, _J_COLS, _J_ROWS, check_calibration)

__all__ = ['MagCalibrator', 'STATES', 'check_calibration']

STATES = ('off', 'learning', 'converged', 'loaded')

# Innovations beyond this (χ², 3 degrees of freedom; 16.3 is 99.9 %) are refused.
GATE = 16.0
# The share of fields refused while the body turns faster than _TURNING
# (rad/s), with this time constant (s): above _REFUSED_SHARE, start over.
_REFUSED_TAU = 10.0
_REFUSED_SHARE = 0.7
_TURNING = 0.2
# A soft-iron element beyond this many prior standard deviations: start over.
_WILD = 4.0
# Seconds of learning the quality must stay below the threshold, the
# calibration settled, before it counts as converged.
_HOLD = 2.0
_HOLD_TURN = 2.0
# The heading turn of the learned calibration: its mean square over the last
# this many learning steps, from a quality of _WATCH times the threshold on
# (earlier, a calibration still far off would count).
_SHIFT_SAMPLES = 1000
_WATCH = 1.0
_SIGNIFICANT = 3.0
# Prior standard deviation of an unknown offset and field, times the first field's norm.
_DIFFUSE = 4.0
# Prior standard deviation of a loaded offset, times the field's norm.
_LOADED_BIAS_STD = 0.05
_N = 12  # m (3), z (3), d (5), τ
_S, _Z, _D, _T = slice(0, 3), slice(3, 6), slice(6, 11), 11


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
    deadband : float or ndarray
        The learned calibration is applied only if it turns the heading by
        more than this (rad, RMS) from the field as given.
    drift : float or ndarray
        Random walk of the offset, relative to the field's norm, per √s.

    Attributes
    ----------
    counts : dict of ndarray (B,) or (1,)
        ``fields`` given to :meth:`learn`, ``used``, ``gated`` (improbable),
        ``refused`` (by the caller), ``invalid`` (non-finite or zero),
        ``resets`` (started over: the calibration no longer fitted).

    """

    def __init__(self, batch=None, enabled=True, noise=0.025, field_rw=0.03, soft_iron=0.05,
                 delay=0.02, heading=math.radians(6.0), deadband=math.radians(15.0),
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
        self._h[:, [0, 1, 2], [0, 1, 2]] = 1.0
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
        self._candidate = np.zeros((n, 8))  # (z, d) when the quality first passed
        self._held = np.full(n, -1.0)  # time since then (s); -1: not below
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
        valid = take & ~self._fresh
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
        # Most fields refused while the body turns, by the gate or (where
        # the calibration is applied, so that the caller tests calibrated
        # fields) by the caller: the calibration no longer fits (the offset
        # changed, or it was learned wrong); start over.
        watched = valid & ((w * w).sum(axis=1) > _TURNING ** 2)
        watched &= take | self._applied
        k_share = 1.0 - math.exp(-float(dt) / _REFUSED_TAU)
        share = self._refused_share
        self._refused_share = np.where(watched, share + k_share * (~use - share), share)
        lost = watched & (self._refused_share > _REFUSED_SHARE)
        # A soft iron far outside its prior: the filter has gone astray
        # (a field that changed while it could not yet tell); start over.
        lost |= live & (np.abs(self._x[:, _D]).max(axis=1) > _WILD * self._soft_iron)
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
        if (self._seen[2] & ~self._loaded & (~self._converged | self._identity)).any():
            # The convergence test, and the watch of a calibration not
            # applied, need the quality now.
            self._assess(float(dt))
        else:
            self._stale = True  # computed when asked for
        if up is not None:
            # Watched once the calibration is nearly good enough to be used.
            watch = (take & ~self._fresh & self._identity
                     & (self._quality < _WATCH * self._heading))
            if watch.any():
                self._watch(y, up_rows, watch)
        self._cache()
        return self._out(use | start)

    def _predict(self, rotation, dt):
        """
        The field turns against the body and walks in the world.

        With ``s = m + z`` (= ``A y``, the field before the offset is
        removed): ``m ← Rᵀ m`` is ``s ← Rᵀ s + (I − Rᵀ) z``. At rest ``R = I``
        and nothing ties ``s`` to ``z``, which keeps the covariance well
        conditioned while nothing can be learned.
        """
        n = self._n
        w, x, y, z = rotation
        s = 2.0 / (w * w + x * x + y * y + z * z)
        r = np.array([1.0 - s * (y * y + z * z), s * (x * y - w * z), s * (x * z + w * y),
                      s * (x * y + w * z), 1.0 - s * (x * x + z * z), s * (y * z - w * x),
                      s * (x * z - w * y), s * (y * z + w * x), 1.0 - s * (x * x + y * y)],
                     dtype=float).reshape(9, n).T.reshape(n, 3, 3)
        rt = r.transpose(0, 2, 1)
        state, p = self._x, self._p
        offset = state[:, _Z, None]
        state[:, _S] = (rt @ (state[:, _S, None] - offset) + offset)[:, :, 0]
        p[:, _S, :] = rt @ p[:, _S, :] + (_EYE3 - rt) @ p[:, _Z, :]
        p[:, :, _S] = p[:, :, _S] @ r + p[:, :, _Z] @ (_EYE3 - r)
        q = ((self._field_rw * self._field_scale) ** 2 * float(dt))[:, None, None] * _EYE3
        p[:, _S, _S] += q
        if self._drift.any():
            # The offset drifts (temperature, a payload moved): never quite
            # frozen. s = m + z drifts with it.
            q = ((self._drift * self._field_scale) ** 2 * float(dt))[:, None, None] * _EYE3
            p[:, _S, _S] += q
            p[:, _S, _Z] += q
            p[:, _Z, _S] += q
            p[:, _Z, _Z] += q

    def _update(self, y, w, live, norm):
        """
        One (gated) Kalman update with ``y = A⁻¹ (s + τ ω × (s − z))``.

        Linear in ``s`` and ``z``, linearized in ``d`` and ``τ`` about the
        estimate: the measured ``y`` never enters the gain (written as
        ``A y = s + …`` with ``y`` in the regressor, its noise would pull
        ``A`` towards 0 at rest, the errors-in-variables bias).
        """
        n = self._n
        x, p = self._x, self._p
        s0, s1, s2, z0, z1, z2, d0, d1, d2, d3, d4, tau = self._columns(x)
        w0, w1, w2 = self._columns(w)
        m0, m1, m2 = s0 - z0, s1 - z1, s2 - z2
        c0, c1, c2 = w1 * m2 - w2 * m1, w2 * m0 - w0 * m2, w0 * m1 - w1 * m0
        a_inv = np.linalg.inv(np.array(
            [1.0 + d0, d2, d3, d2, 1.0 + d1, d4, d3, d4, 1.0 - d0 - d1],
            dtype=float).reshape(9, n).T.reshape(n, 3, 3))
        pred = (a_inv @ np.array([s0 + tau * c0, s1 + tau * c1, s2 + tau * c2],
                                 dtype=float).reshape(3, n).T[:, :, None])[:, :, 0]
        nu = y - pred
        p0, p1, p2 = self._columns(pred)
        tw0, tw1, tw2 = tau * w0, tau * w1, tau * w2
        h = self._h
        h[:, _H_ROWS, _H_COLS] = np.array(
            [-tw2, tw1, tw2, -tw0, -tw1, tw0, tw2, -tw1, -tw2, tw0, tw1, -tw0,
             -p0, -p1, -p2, -p1, -p0, -p2, p2, p2, -p0, -p1, c0, c1, c2],
            dtype=float).reshape(25, n).T
        h = a_inv @ h
        ph = p @ h.transpose(0, 2, 1)
        s = h @ ph
        s += ((self._noise * self._field_scale) ** 2)[:, None, None] * _EYE3
        s_inv = np.linalg.inv(s)
        nis = np.einsum('ni,nij,nj->n', nu, s_inv, nu)
        use = live & (nis < GATE)
        self._nis = np.where(live, self._nis + 0.02 * (np.minimum(nis, 3 * GATE) - self._nis),
                             self._nis)
        k = ph @ s_inv
        if not use.all():
            k[~use] = 0.0
        x += (k @ nu[:, :, None])[:, :, 0]
        p -= k @ ph.transpose(0, 2, 1)
        self._learned += 1
        if self._learned % 64 == 0:  # rounding makes P drift from symmetric, slowly
            p[:] = 0.5 * (p + p.transpose(0, 2, 1))
        m = x[:, _S] - x[:, _Z]
        self._field_scale = np.where(use, np.maximum(np.sqrt((m * m).sum(axis=1)), 0.25 * norm),
                                     self._field_scale)
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
            # s = A y = y + Y(y) d: as uncertain as d (and correlated with
            # it), plus the noise; independent of the offset.
            yy = np.zeros((3, 5))
            yy[_J_ROWS, np.array(_J_COLS) - 3] = (y[i, 0], y[i, 1], y[i, 2], y[i, 1], y[i, 0],
                                                  y[i, 2], -y[i, 2], -y[i, 2], y[i, 0], y[i, 1])
            x[i, _S] = y[i] + yy @ x[i, _D]
            p[i, _S, 3:] = yy @ p[i, _D, 3:]
            p[i, 3:, _S] = p[i, _S, 3:].T
            noise = self._noise[i] * norm[i]
            p[i, _S, _S] = yy @ p[i, _D, _D] @ yy.T + _EYE3 * noise * noise
            m = x[i, _S] - x[i, _Z]
            self._field_scale[i] = max(float(np.linalg.norm(m)), 0.25 * norm[i])
            self._refused_share[i] = 0.0
        self._fresh &= ~start

    def _watch(self, y, up, watch):
        """How far the learned calibration turns the heading from the field as given."""
        angle = _heading_between(up, y, _calibrated(y, self._x[:, _Z], self._x[:, _D]))
        # A mean over the samples watched, then over the last _SHIFT_SAMPLES.
        self._watched += watch
        k = 1.0 / np.minimum(np.maximum(self._watched, 1), _SHIFT_SAMPLES)
        shift = self._shift
        self._shift = np.where(watch, shift + k * (angle * angle - shift), shift)
        # Applied once it turns the heading by more than the deadband, and by
        # more than its own uncertainty could (3 σ): a sensor calibrated
        # already is not recalibrated with a less certain calibration.
        self._identity &= ~(self._converged & (self._shift > self._deadband ** 2)
                            & (self._shift > (_SIGNIFICANT * self._quality) ** 2))

    def _assess(self, dt=0.0):
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
        # Converged once the quality has stayed below the threshold for
        # _HOLD s of learning and the calibration has not turned the heading
        # by more than the threshold meanwhile (a filter misled by a field
        # that changes keeps moving; a settled one does not).
        learning = live & ~self._loaded & ~self._converged
        below = learning & (quality < self._heading)
        if below.any():
            z, d = self._x[:, _Z], self._x[:, _D]
            fresh = below & (self._held < 0.0)
            self._candidate[fresh] = self._x[fresh, 3:11]
            turned = np.abs(_heading_between(
                up if up is not None else y, _calibrated(y, z, d),
                _calibrated(y, self._candidate[:, :3], self._candidate[:, 3:])))
            moved = below & (turned > _HOLD_TURN * self._heading)
            self._candidate[moved] = self._x[moved, 3:11]
            self._held = np.where(below, np.where(moved, 0.0, np.maximum(self._held, 0.0) + dt),
                                  self._held)
            self._converged |= below & (self._held >= _HOLD)
        # The hold pauses while the quality is a little above the threshold
        # (it changes with the attitude), and ends well above it.
        self._held = np.where(learning & (quality > _HOLD_TURN * self._heading), -1.0,
                              self._held)

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
        m = (self._x[:, _S] - self._x[:, _Z]) * self._scale[:, None]
        return m[0] if self.batch is None else m
