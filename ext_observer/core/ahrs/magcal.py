"""
Online magnetometer calibration: hard iron, soft iron and the field's lag.

Learned while the body turns, from the field and the gyro alone: a Kalman
filter on ``(s, z, d, τ)`` with the gyro turning the field between samples,
a gate for improbable fields, a start-over when the calibration no longer
fits, a convergence test on the heading error the calibration's uncertainty
would cause, and the learned calibration applied only once it turns the
heading by more than a deadband (a loaded one at once). The maths is
:mod:`~ext_observer.core.ahrs.magcal_kernel`'s (plain functions on the
calibrator's record, plain or compiled), described in docs/calibration.md.
:class:`MagCalibrator` wraps them; :func:`check_calibration`
(:mod:`~ext_observer.core.ahrs.magcal_model`) checks a saved calibration.

The caller may refuse a sample (``allow``): :class:`AhrsObserver
<ext_observer.core.ahrs.ahrs_observer.AhrsObserver>` does for a field its norm/dip test
rejects once calibrated.

One code path serves one calibrator and a batch: one state per element
(``batch`` of them, one for one calibrator), each a record of
:data:`~ext_observer.core.ahrs.magcal_layout.CAL` in its holder
(:mod:`~ext_observer.core.ahrs.record`); inputs and outputs are Python
floats, or arrays of shape ``(B,)`` with ``batch=B``. Units: the field in
any unit (``noise``, ``field_rw`` and ``drift`` are relative to its norm),
time in s, angular rate in rad/s.
"""

import math
import sys

import numpy as np

from . import magcal_kernel
from .magcal_layout import CAL, CAL_Z
from .magcal_model import check_calibration

__all__ = ['MagCalibrator', 'STATES', 'check_calibration']

STATES = ('off', 'learning', 'converged', 'loaded')
_COUNTS = ('fields', 'used', 'gated', 'refused', 'invalid', 'resets')
_S, _Z, _D, _T = slice(0, 3), slice(3, 6), slice(6, 11), 11
# CAL's fields: the slots of its plain records.
_NAMES = tuple(path[-1] for path, _, _, _ in CAL.fields())


def _tuples(columns):
    """The columns of a ``(k, n)`` array as ``n`` k-tuples of floats (the kernel's vectors)."""
    return [tuple(v) for v in columns.T.tolist()]


def _value(holder, name):
    """Field ``name`` of a holder's record: a float, or a vector (an array, or a list)."""
    if isinstance(holder, np.ndarray):
        return holder[name][0]
    return getattr(holder[0], name)


def _compiled(kernel):
    """Whether a kernel module's functions are compiled (numba dispatchers)."""
    return hasattr(kernel.mc_learn, 'py_func')


def _holders(blocks, n, compiled):
    """The holders given, checked: ``n`` of them, of the kernel's kind."""
    holders = list(blocks)
    if len(holders) != n:
        raise ValueError(f'{len(holders)} blocks given for {n} calibrator(s)')
    for holder in holders:
        if compiled:
            fits = (isinstance(holder, np.ndarray) and holder.shape == (1,)
                    and holder.dtype == CAL.dtype)
        else:
            fits = (isinstance(holder, list) and len(holder) == 1
                    and getattr(type(holder[0]), '__slots__', None) == _NAMES)
        if not fits:
            kind = ('a one-element array of CAL.dtype, for compiled kernels' if compiled
                    else 'a one-element list of a plain CAL record, for plain kernels')
            raise ValueError(f'a calibrator\'s block must be the holder of its record ({kind}; '
                             f'CAL.holder or record.holder_of), got {type(holder).__name__}')
    return holders


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
    blocks : list of holders, optional
        Each element's state, one per element: the holder of a record of
        :data:`~ext_observer.core.ahrs.magcal_layout.CAL` (a one-element
        structured array of ``CAL.dtype`` for a compiled kernel, a
        one-element list of ``CAL.plain()`` for the plain one), e.g. the
        calibration's record inside each estimator's state
        (:func:`~ext_observer.core.ahrs.record.holder_of`). Default: new
        holders of the kernel's kind.

    Attributes
    ----------
    counts : dict of ndarray (B,) or (1,)
        ``fields`` given to :meth:`learn`, ``used``, ``gated`` (improbable),
        ``refused`` (by the caller), ``invalid`` (non-finite or zero),
        ``resets`` (started over: the calibration no longer fitted).

    """

    def __init__(self, batch=None, enabled=True, noise=0.025, field_rw=0.03, soft_iron=0.05,
                 delay=0.02, heading=math.radians(6.0), deadband=math.radians(15.0),
                 drift=0.002, kernel=None, blocks=None):
        self.batch = batch
        n = 1 if batch is None else int(batch)
        self._n = n
        self._k = k = magcal_kernel if kernel is None else kernel
        compiled = _compiled(k)
        if blocks is None:
            blocks = [CAL.holder(compiled) for _ in range(n)]
        self._blocks = _holders(blocks, n, compiled)
        self._holder = self._blocks[0]  # one calibrator's

        def per(value):
            return np.broadcast_to(np.asarray(value, dtype=float), (n,)).tolist()

        on = [1.0 if v else 0.0 for v in np.broadcast_to(np.asarray(enabled, dtype=bool), (n,))]
        for holder, *values in zip(self._blocks, on, per(noise), per(field_rw),
                                   per(soft_iron), per(delay), per(heading), per(deadband),
                                   per(drift)):
            k.mc_init_in(holder, *values)

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
        blocks : list of holders
            One per calibrator, each the holder of a copy of the record it
            replaces, of the kernel's kind (see the class's ``blocks``).

        """
        self._blocks = _holders(blocks, self._n, _compiled(kernel))
        self._holder = self._blocks[0]
        self._k = kernel

    # --- state ---------------------------------------------------------------

    def reset(self):
        """Forget the calibration: learn from the next field on."""
        for holder in self._blocks:
            self._k.mc_reset_in(holder)

    def restart(self):
        """Keep what is learned, follow the field afresh from the next sample."""
        for holder in self._blocks:
            self._k.mc_restart_in(holder)

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
        for holder in blocks:
            self._k.mc_load_state_in(holder, *state.tolist(), float(scale))

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
            return k.mc_learn_in(self._holder, (float(y0), float(y1), float(y2)),
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
        fresh = [_value(h, 'fresh') != 0.0 for h in blocks]
        if not all(fresh):
            for i, h in enumerate(blocks):
                if fresh[i]:
                    k.mc_predict_in(h, *r[i], dt)
        used = np.empty(n, dtype=bool)
        for i, h in enumerate(blocks):
            used[i] = k.mc_learn_in(h, y[i], r[i], dt, w[i], has_up, u[i],
                                 1.0 if allow[i] else 0.0) != 0.0
        assessed = [_value(h, 'assessed') != 0.0 for h in blocks]
        if any(assessed):
            for i, h in enumerate(blocks):
                if not assessed[i]:
                    k.mc_assess_in(h, dt)
        watching = [_value(h, 'watching') != 0.0 for h in blocks]
        if any(watching):
            for i, h in enumerate(blocks):
                if not watching[i]:
                    k.mc_reconsider_in(h)
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
            return self._k.mc_apply_in(self._holder, y0, y1, y2)
        a00, a01, a02, a10, a11, a12, a20, a21, a22, z0, z1, z2 = self._field('coef').T
        return (a00 * y0 + a01 * y1 + a02 * y2 - z0, a10 * y0 + a11 * y1 + a12 * y2 - z1,
                a20 * y0 + a21 * y1 + a22 * y2 - z2)

    def _field(self, name):
        """Field ``name`` per element: shape (n,), or (n, size) for a vector."""
        return np.array([_value(h, name) for h in self._blocks], dtype=float)

    def _flags(self, name):
        return self._field(name) != 0.0

    def _x(self):
        """The filter's state, shape (n, 12)."""
        return self._field('x')

    def _out(self, v):
        return v[0].item() if self.batch is None else v

    @property
    def ready(self):
        """Whether :meth:`apply` calibrates (converged or loaded), or the calibrator is off."""
        if self.batch is None:
            return bool(_value(self._holder, 'ready') != 0.0)
        return self._flags('ready')

    @property
    def applied(self):
        """Whether :meth:`apply` uses the learned (or loaded) calibration, not the identity."""
        if self.batch is None:
            return bool(_value(self._holder, 'applied') != 0.0)
        return self._flags('applied')

    @property
    def converged(self):
        """Whether the learned calibration has passed the quality threshold."""
        return self._out(self._flags('enabled') & self._flags('converged'))

    @property
    def state(self):
        """``'off'``, ``'learning'``, ``'converged'`` or ``'loaded'`` (a list with ``batch``)."""
        if self.batch is None:  # the node's path, read at every field
            h = self._holder
            return ('off' if _value(h, 'enabled') == 0.0 else
                    'loaded' if _value(h, 'loaded') != 0.0 else
                    'converged' if _value(h, 'converged') != 0.0 else 'learning')
        states = ['off' if not on else 'loaded' if loaded else
                  'converged' if conv else 'learning'
                  for on, loaded, conv in zip(self._flags('enabled'), self._flags('loaded'),
                                              self._flags('converged'))]
        return states[0] if self.batch is None else states

    @property
    def quality(self):
        """Heading error (rad, 1σ) the calibration's uncertainty causes; inf before any field."""
        if self.batch is None:  # the node's path, read at every field
            return float(self._k.mc_quality_in(self._holder))
        return np.array([float(self._k.mc_quality_in(h)) for h in self._blocks])

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
        k = self._k
        f0, f1, f2 = k.mc_calibrated(_value(self._holder, 'x'), CAL_Z, mag[0], mag[1], mag[2])
        n = math.sqrt(up[0] * up[0] + up[1] * up[1] + up[2] * up[2]) or 1.0
        return float(k.mc_heading_between(up[0] / n, up[1] / n, up[2] / n, mag[0], mag[1],
                                          mag[2], f0, f1, f2))

    @property
    def counts(self):
        """The counts (see the class's attributes): a dict of int64 arrays (B,) or (1,)."""
        return {key: self._field(key).astype(np.int64) for key in _COUNTS}

    @property
    def _shift(self):
        """The mean square heading turn of the learned calibration (rad²), shape (n,)."""
        return self._field('shift')

    @property
    def bias(self):
        """The hard-iron offset ``b`` (field unit), shape (3,) or (B, 3)."""
        x = self._x()
        b = np.linalg.solve(self._unit_a(x), x[:, _Z, None])[:, :, 0]
        return b[0] if self.batch is None else b

    @property
    def soft_iron(self):
        """The soft-iron matrix ``S``, shape (3, 3) or (B, 3, 3)."""
        s = np.linalg.inv(self._unit_a(self._x()) * self._field('scale')[:, None, None])
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
        m = (x[:, _S] - x[:, _Z]) * self._field('scale')[:, None]
        return m[0] if self.batch is None else m
