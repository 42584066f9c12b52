"""
Online magnetometer calibration: hard iron, soft iron and the field's lag.

Learned while the body turns, from the field and the gyro alone: a Kalman
filter on ``(s, z, d, τ)`` with the gyro turning the field between samples,
a gate for improbable fields, a start-over when the calibration no longer
fits, a convergence test on the heading error the calibration's uncertainty
would cause, and the learned calibration applied only once it turns the
heading by more than a deadband (a loaded one at once). The maths is
:mod:`~ext_observer.core.ahrs.magcal_kernel`'s (plain functions on a flat
state, plain or compiled), described in docs/calibration.md.
:class:`MagCalibrator` wraps them; :func:`check_calibration`
(:mod:`~ext_observer.core.ahrs.magcal_model`) checks a saved calibration.

The caller may refuse a sample (``allow``): :class:`AhrsObserver
<ext_observer.core.ahrs.ahrs_observer.AhrsObserver>` does for a field its norm/dip test
rejects once calibrated.

One code path serves one calibrator and a batch: one state block per element
(``batch`` of them, one for one calibrator), inputs and outputs are Python
floats, or arrays of shape ``(B,)`` with ``batch=B``. Units: the field in
any unit (``noise``, ``field_rw`` and ``drift`` are relative to its norm),
time in s, angular rate in rad/s.
"""

import math
import sys

import numpy as np

from . import magcal_kernel
from .magcal_kernel import (MC_APPLIED, MC_ASSESSED, MC_COEF, MC_CONVERGED,
                            MC_COUNTS, MC_ENABLED, MC_FRESH, MC_LOADED, MC_READY, MC_SCALE,
                            MC_SHIFT, MC_WATCHING, MC_X)
from .magcal_model import check_calibration

__all__ = ['MagCalibrator', 'STATES', 'check_calibration']

STATES = ('off', 'learning', 'converged', 'loaded')
_COUNTS = ('fields', 'used', 'gated', 'refused', 'invalid', 'resets')
_S, _Z, _D, _T = slice(0, 3), slice(3, 6), slice(6, 11), 11


def _tuples(columns):
    """The columns of a ``(k, n)`` array as ``n`` k-tuples of floats (the kernel's vectors)."""
    return [tuple(v) for v in columns.T.tolist()]


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
    kernel : module, optional
        The functions of :mod:`~ext_observer.core.ahrs.magcal_kernel` (default),
        or a module with the same functions and constants (the same file
        loaded again with its functions compiled by ``numba.njit``).
    state : list or ndarray of float, optional
        The container of the state: ``batch`` (or one) blocks of
        ``MC_SIZE`` floats from ``offset`` on (a 1-D float64 array for a
        compiled kernel). Default: a new Python list.
    offset : int
        Where the first block starts in ``state``.
    blocks : list of (container, int), optional
        Instead of ``state``: where each element's block is (its container
        and offset), one per element, e.g. inside each estimator's state.

    Attributes
    ----------
    counts : dict of ndarray (B,) or (1,)
        ``fields`` given to :meth:`learn`, ``used``, ``gated`` (improbable),
        ``refused`` (by the caller), ``invalid`` (non-finite or zero),
        ``resets`` (started over: the calibration no longer fitted).

    """

    def __init__(self, batch=None, enabled=True, noise=0.025, field_rw=0.03, soft_iron=0.05,
                 delay=0.02, heading=math.radians(6.0), deadband=math.radians(15.0),
                 drift=0.002, kernel=None, state=None, offset=0, blocks=None):
        self.batch = batch
        n = 1 if batch is None else int(batch)
        self._n = n
        self._k = k = magcal_kernel if kernel is None else kernel
        size = int(k.MC_SIZE)
        if blocks is None:
            offset = int(offset)
            if state is None:
                state = [0.0] * (offset + n * size)
            blocks = [(state, offset + i * size) for i in range(n)]
        blocks = [(s, int(o)) for s, o in blocks]
        if len(blocks) != n:
            raise ValueError(f'{len(blocks)} blocks given for {n} calibrator(s)')
        for s, o in blocks:
            if o < 0 or len(s) < o + size:
                raise ValueError(f'a state of {len(s)} floats has no block of {size} at {o}')
        self._blocks = blocks
        self._s, self._o = blocks[0]  # one calibrator's

        def per(value):
            return np.broadcast_to(np.asarray(value, dtype=float), (n,)).tolist()

        on = [1.0 if v else 0.0 for v in np.broadcast_to(np.asarray(enabled, dtype=bool), (n,))]
        for (s, o), *values in zip(blocks, on, per(noise), per(field_rw), per(soft_iron),
                                   per(delay), per(heading), per(deadband), per(drift)):
            k.mc_init(s, o, *values)

    def __getstate__(self):
        # The kernel, a module, by name (copies and pickles share it).
        state = self.__dict__.copy()
        state['_k'] = None if self._k is magcal_kernel else self._k.__name__
        return state

    def __setstate__(self, state):
        name = state['_k']
        state['_k'] = magcal_kernel if name is None else sys.modules[name]
        self.__dict__.update(state)

    def use_kernel(self, kernel, blocks):
        """
        Go on with another kernel module on states that hold the same values.

        Parameters
        ----------
        kernel : module
            The calibration's kernel (plain, or the compiled module).
        blocks : list of (state, offset)
            One per calibrator, each a copy of the block it replaces.

        """
        blocks = [(s, int(o)) for s, o in blocks]
        if len(blocks) != self._n:
            raise ValueError(f'{len(blocks)} blocks given for {self._n} calibrator(s)')
        self._k = kernel
        self._blocks = blocks
        self._s, self._o = blocks[0]

    # --- state ---------------------------------------------------------------

    def reset(self):
        """Forget the calibration: learn from the next field on."""
        for s, o in self._blocks:
            self._k.mc_reset(s, o)

    def restart(self):
        """Keep what is learned, follow the field afresh from the next sample."""
        for s, o in self._blocks:
            self._k.mc_restart(s, o)

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
        blocks = self._blocks if index is None else [self._blocks[int(index)]]
        for s, o in blocks:
            self._k.mc_load_state(s, o, *state.tolist(), float(scale))

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
        k, dt = self._k, float(dt)
        if self.batch is None:
            y0, y1, y2 = mag
            rw, rx, ry, rz = rotation
            w0, w1, w2 = rate
            u0, u1, u2 = (0.0, 0.0, 0.0) if up is None else up
            if allow is not True:
                allow = np.asarray(allow, dtype=bool).reshape(-1)[0]
            return k.mc_learn(self._s, self._o, (float(y0), float(y1), float(y2)),
                              (float(rw), float(rx), float(ry), float(rz)), dt,
                              (float(w0), float(w1), float(w2)), 0.0 if up is None else 1.0,
                              (float(u0), float(u1), float(u2)), 1.0 if allow else 0.0) != 0.0
        n, blocks = self._n, self._blocks
        y = _tuples(np.array(mag, dtype=float).reshape(3, n))
        r = np.empty((4, n))
        for i, v in enumerate(rotation):
            r[i] = v
        r = _tuples(r)
        w = _tuples(np.array(rate, dtype=float).reshape(3, n))
        u = _tuples(np.zeros((3, n)) if up is None else np.array(up, dtype=float).reshape(3, n))
        has_up = 0.0 if up is None else 1.0
        allow = (np.ones(n, dtype=bool) if allow is True
                 else np.broadcast_to(np.asarray(allow, dtype=bool).reshape(-1), (n,)))
        # The elements depend on each other as the vectorized filter had
        # them: the field of an element not started yet turns while any
        # element learns; when any element needs the quality now, all have
        # it assessed; when any watches its heading turn, all reconsider
        # applying their calibration.
        fresh = [s[o + MC_FRESH] != 0.0 for s, o in blocks]
        if not all(fresh):
            for i, (s, o) in enumerate(blocks):
                if fresh[i]:
                    k.mc_predict(s, o, *r[i], dt)
        used = np.empty(n, dtype=bool)
        for i, (s, o) in enumerate(blocks):
            used[i] = k.mc_learn(s, o, y[i], r[i], dt, w[i], has_up, u[i],
                                 1.0 if allow[i] else 0.0) != 0.0
        assessed = [s[o + MC_ASSESSED] != 0.0 for s, o in blocks]
        if any(assessed):
            for i, (s, o) in enumerate(blocks):
                if not assessed[i]:
                    k.mc_assess(s, o, dt)
        watching = [s[o + MC_WATCHING] != 0.0 for s, o in blocks]
        if any(watching):
            for i, (s, o) in enumerate(blocks):
                if not watching[i]:
                    k.mc_reconsider(s, o)
                    k.mc_cache(s, o)
        return used

    # --- outputs -------------------------------------------------------------

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
        y0, y1, y2 = mag
        if self.batch is None:
            return self._k.mc_apply(self._s, self._o, y0, y1, y2)
        a00, a01, a02, a10, a11, a12, a20, a21, a22, z0, z1, z2 = self._rows(MC_COEF, 12).T
        return (a00 * y0 + a01 * y1 + a02 * y2 - z0, a10 * y0 + a11 * y1 + a12 * y2 - z1,
                a20 * y0 + a21 * y1 + a22 * y2 - z2)

    def _slots(self, slot):
        """The value of a slot, per element: shape (n,)."""
        return self._rows(slot, 1)[:, 0]

    def _flags(self, slot):
        return self._slots(slot) != 0.0

    def _x(self):
        """The filter's state, shape (n, 12)."""
        return self._rows(MC_X, 12)

    def _rows(self, slot, count):
        """``count`` slots from ``slot`` on, per element: shape (n, count)."""
        return np.array([s[o + slot:o + slot + count] for s, o in self._blocks], dtype=float)

    def _out(self, v):
        return v[0].item() if self.batch is None else v

    @property
    def ready(self):
        """Whether :meth:`apply` calibrates (converged or loaded), or the calibrator is off."""
        if self.batch is None:
            return bool(self._s[self._o + MC_READY] != 0.0)
        return self._flags(MC_READY)

    @property
    def applied(self):
        """Whether :meth:`apply` uses the learned (or loaded) calibration, not the identity."""
        if self.batch is None:
            return bool(self._s[self._o + MC_APPLIED] != 0.0)
        return self._flags(MC_APPLIED)

    @property
    def converged(self):
        """Whether the learned calibration has passed the quality threshold."""
        return self._out(self._flags(MC_ENABLED) & self._flags(MC_CONVERGED))

    @property
    def state(self):
        """``'off'``, ``'learning'``, ``'converged'`` or ``'loaded'`` (a list with ``batch``)."""
        states = ['off' if not on else 'loaded' if loaded else
                  'converged' if conv else 'learning'
                  for on, loaded, conv in zip(self._flags(MC_ENABLED), self._flags(MC_LOADED),
                                              self._flags(MC_CONVERGED))]
        return states[0] if self.batch is None else states

    @property
    def quality(self):
        """Heading error (rad, 1σ) the calibration's uncertainty causes; inf before any field."""
        if self.batch is None:  # the node's path, read at every field
            return float(self._k.mc_quality(self._s, self._o))
        return np.array([float(self._k.mc_quality(s, o)) for s, o in self._blocks])

    def heading_turn(self, mag, up):
        """
        How far the calibration learned so far turns a field's heading (one calibrator).

        Parameters
        ----------
        mag : sequence of 3 float
            The field as given (as :meth:`learn` takes it).
        up : sequence of 3 float
            The world's vertical in the body frame (any norm).

        Returns
        -------
        float
            The angle about ``up`` from the field as given to the field the
            learned calibration makes of it, rad; 0 before anything is learned.

        """
        k, st, o = self._k, self._s, self._o
        f0, f1, f2 = k.mc_calibrated(st, o + MC_X + 3, mag[0], mag[1], mag[2])
        n = math.sqrt(up[0] * up[0] + up[1] * up[1] + up[2] * up[2]) or 1.0
        return float(k.mc_heading_between(up[0] / n, up[1] / n, up[2] / n, mag[0], mag[1],
                                          mag[2], f0, f1, f2))

    @property
    def counts(self):
        """The counts (see the class's attributes): a dict of int64 arrays (B,) or (1,)."""
        return {key: self._slots(MC_COUNTS + j).astype(np.int64)
                for j, key in enumerate(_COUNTS)}

    @property
    def _shift(self):
        """The mean square heading turn of the learned calibration (rad²), shape (n,)."""
        return self._slots(MC_SHIFT)

    @property
    def bias(self):
        """The hard-iron offset ``b`` (field unit), shape (3,) or (B, 3)."""
        x = self._x()
        b = np.linalg.solve(self._unit_a(x), x[:, _Z, None])[:, :, 0]
        return b[0] if self.batch is None else b

    @property
    def soft_iron(self):
        """The soft-iron matrix ``S``, shape (3, 3) or (B, 3, 3)."""
        s = np.linalg.inv(self._unit_a(self._x()) * self._slots(MC_SCALE)[:, None, None])
        return s[0] if self.batch is None else s

    def _unit_a(self, x):
        d0, d1, d2, d3, d4 = x[:, _D].T
        return np.stack([d0 + 1.0, d2, d3, d2, d1 + 1.0, d4, d3, d4, 1.0 - d0 - d1],
                        axis=1).reshape(self._n, 3, 3)

    @property
    def delay(self):
        """The field's lag behind the gyro (s)."""
        return self._out(self._x()[:, _T])

    @property
    def field(self):
        """The calibrated field now, as the filter tracks it (body frame), shape (3,) or (B, 3)."""
        x = self._x()
        m = (x[:, _S] - x[:, _Z]) * self._slots(MC_SCALE)[:, None]
        return m[0] if self.batch is None else m
