"""
Luenberger-like attitude observers in the ambient space H (Section 3.2).

With ``E_k = exp(Ω_k / 2)`` the body-frame increment and ``y_k`` the
measured attitude, the paper's observers are

    extended (w):  q̂⁺ = q̂ ⊗ E + (y − q̂) ⊗ L − 4α q̂ (q̂̄q̂ − 1) ⊗ E
    plain (wo):    q̂⁺ = q̂ ⊗ E + (y − q̂) ⊗ L

and we add ``projected``: the plain update followed by normalization, which
is what most attitude filters do. The last term of ``extended`` is the
extension term of Corollary 1, ``α ∇V(f(q̂))`` with ``f(q̂) = q̂ ⊗ E`` and
``V = (x̄x − 1)²``, since ``|E| = 1``.

Gain modes (the right factor of the innovation):

- ``constant``: the paper's fixed quaternion ``L``.
- ``rotating``: ``L_k = κ E_k``; without noise the plain error obeys
  ``e⁺ = (1 − κ) e ⊗ E_k``, a contraction by ``1 − κ`` at every step.
- ``scheduled``: ``L_k = κ_k E_k`` with ``κ_k = max(1/(j + 1), κ_min)`` and
  ``j`` the number of measurements used so far: a running average of the
  transported measurements at first, then tracking with gain ``κ_min``.

Two implementations share one set of parameters: :class:`LuenbergerObserver`
runs a batch (Monte Carlo runs) on numpy arrays, :class:`SingleObserver`
runs one estimate on plain floats (the ROS node's fast path). Tests check
that they agree.
"""

import math

import numpy as np

from .. import quaternion as quat

__all__ = [
    'GAIN_MODES',
    'component_major',
    'multiply_components',
    'LuenbergerObserver',
    'ObserverConfig',
    'PAPER_ALPHA',
    'PAPER_GAIN',
    'SingleObserver',
    'VARIANTS',
]

VARIANTS = ('extended', 'plain', 'projected')
GAIN_MODES = ('constant', 'rotating', 'scheduled')
PAPER_GAIN = (0.11, -0.18, -0.18, -0.18)
PAPER_ALPHA = 0.01
DEFAULT_KAPPA = 0.05
DEFAULT_KAPPA_MIN = 0.02


def _finite_tuple(value, length, name):
    try:
        values = tuple(float(v) for v in value)
    except TypeError:
        raise ValueError(f'{name} must be a sequence of {length} numbers, '
                         f'got {value!r}') from None
    if len(values) != length:
        raise ValueError(f'{name} must have {length} elements, got {len(values)}')
    if not all(math.isfinite(v) for v in values):
        raise ValueError(f'{name} must be finite, got {values}')
    return values


class ObserverConfig:
    """
    Validated parameters of an observer.

    Parameters
    ----------
    variant : {'extended', 'plain', 'projected'}
        Which observer of Section 3.2 (``projected`` is ours).
    alpha : float
        Gain of the extension term (``extended`` only), > 0. The node
        additionally refuses values outside the certified range.
    gain : sequence of 4 float
        The paper's ``L`` (``constant`` mode), scalar first.
    gain_mode : {'constant', 'rotating', 'scheduled'}
    kappa : float
        ``κ`` of the ``rotating`` mode, in (0, 1].
    kappa_min : float
        Floor ``κ_min`` of the ``scheduled`` mode, in (0, 1].
    initial : sequence of 4 float
        Initial estimate (ambient, need not be unit); nonzero and finite.
    align_sign : bool
        Flip each measurement ``y`` to the hemisphere of ``q̂`` (``y`` and
        ``−y`` are the same rotation, but the R⁴ innovation ``y − q̂`` is
        not). Off by default, which keeps the paper's setup exact; on for
        real sources that publish ``w ≥ 0`` or flip sign.

    Raises
    ------
    ValueError
        With the reason, for any invalid value.

    """

    def __init__(self, variant='extended', alpha=PAPER_ALPHA, gain=PAPER_GAIN,
                 gain_mode='constant', kappa=DEFAULT_KAPPA,
                 kappa_min=DEFAULT_KAPPA_MIN, initial=(1.0, 0.0, 0.0, 0.0),
                 align_sign=False):
        if variant not in VARIANTS:
            raise ValueError(f'variant must be one of {VARIANTS}, got {variant!r}')
        if gain_mode not in GAIN_MODES:
            raise ValueError(
                f'gain_mode must be one of {GAIN_MODES}, got {gain_mode!r}')
        alpha = float(alpha)
        if not (math.isfinite(alpha) and alpha > 0.0):
            raise ValueError(f'alpha must be positive and finite, got {alpha}')
        for name, k in (('kappa', kappa), ('kappa_min', kappa_min)):
            if not (math.isfinite(float(k)) and 0.0 < float(k) <= 1.0):
                raise ValueError(f'{name} must be in (0, 1], got {k}')
        self.variant = variant
        self.alpha = alpha
        self.gain = _finite_tuple(gain, 4, 'gain')
        self.gain_mode = gain_mode
        self.kappa = float(kappa)
        self.kappa_min = float(kappa_min)
        self.initial = _finite_tuple(initial, 4, 'initial estimate')
        self.align_sign = bool(align_sign)
        if sum(v * v for v in self.initial) == 0.0:
            raise ValueError('initial estimate must be a nonzero quaternion')

    def kappa_at(self, measurements_used):
        """
        Return ``κ`` for the next measurement (rotating/scheduled modes).

        Parameters
        ----------
        measurements_used : int
            Measurements the observer has used so far.

        """
        if self.gain_mode == 'scheduled':
            return max(1.0 / (measurements_used + 1.0), self.kappa_min)
        return self.kappa

    def as_dict(self):
        """Return the parameters as a dict."""
        return dict(variant=self.variant, alpha=self.alpha, gain=self.gain,
                    gain_mode=self.gain_mode, kappa=self.kappa,
                    kappa_min=self.kappa_min, initial=self.initial,
                    align_sign=self.align_sign)


class LuenbergerObserver:
    """
    A batch of observers updated together (one per Monte Carlo run).

    Parameters
    ----------
    variant, alpha, gain, gain_mode, kappa, kappa_min, initial, align_sign
        See :class:`ObserverConfig`.
    batch_shape : tuple of int
        Leading shape of the state; ``()`` for a single estimate.

    Attributes
    ----------
    state : ndarray, shape (*batch_shape, 4)
        The ambient estimate ``q̂_k``, scalar first.
    measurements_used : int
        Measurements used since the last reset (drives ``scheduled``).

    """

    def __init__(self, variant='extended', alpha=PAPER_ALPHA, gain=PAPER_GAIN,
                 initial=(1.0, 0.0, 0.0, 0.0), batch_shape=(),
                 gain_mode='constant', kappa=DEFAULT_KAPPA,
                 kappa_min=DEFAULT_KAPPA_MIN, align_sign=False):
        self.config = ObserverConfig(variant, alpha, gain, gain_mode, kappa,
                                     kappa_min, initial, align_sign)
        self.batch_shape = tuple(batch_shape)
        # (y − q̂) ⊗ L as one matmul with the right-multiplication matrix.
        self._gain_matrix = quat.right_matrix(self.config.gain)
        self.reset()

    def reset(self, initial=None):
        """
        Restart from ``initial`` (default: the configured initial estimate).

        Parameters
        ----------
        initial : array_like, shape (4,) or (*batch_shape, 4), optional

        """
        initial = self.config.initial if initial is None else initial
        initial = quat.check_quaternions(initial, 'initial')
        if not np.all(np.isfinite(initial)) or np.any(quat.norm(initial) == 0.0):
            raise ValueError('initial estimate must be finite and nonzero')
        self.state = initial
        self.measurements_used = 0

    @property
    def state(self):
        """The estimate ``q̂_k``, shape ``(*batch_shape, 4)`` (a view)."""
        return np.moveaxis(self._q, 0, -1)

    @state.setter
    def state(self, value):
        value = quat.check_quaternions(value, 'state')
        self._q = np.array(np.moveaxis(
            np.broadcast_to(value, self.batch_shape + (4,)), -1, 0), order='C')

    def step(self, increment, measurement=None, rotation=None):
        """
        Advance by one step: from ``q̂_k`` to ``q̂_{k+1}``.

        The batch is stored as contiguous components ``(4, *batch_shape)``
        (structure of arrays), which is about twice as fast as working on
        the strided components of ``(..., 4)`` arrays at large batches.

        Parameters
        ----------
        increment : array_like, shape (..., 3)
            Body rotation ``θ_k`` over ``[t_k, t_{k+1})``, rad
            (``Ω_k = (0, θ_k)``); broadcasts against the batch.
        measurement : array_like, shape (..., 4), optional
            ``y_k``, the measured attitude at ``t_k``. Without it the step
            propagates, with the extension term only.
        rotation : array_like, shape (..., 4), optional
            ``E_k = exp(Ω_k / 2)`` if already computed (several observers fed
            the same increments share it); ``increment`` is then ignored.

        Returns
        -------
        state : ndarray, shape (*batch_shape, 4)
            ``q̂_{k+1}``, a new array (also the new :attr:`state`).

        """
        cfg = self.config
        q = self._q
        if rotation is None:
            E = _rotation_components(
                quat.check_vectors(increment, 'increment'), q.ndim - 1)
        else:
            E = _components(quat.check_quaternions(rotation, 'rotation'),
                            q.ndim - 1)
        shape = np.broadcast_shapes(q.shape, E.shape)
        # The propagation q̂ ⊗ E, scaled by (1 − 4α(q̂̄q̂ − 1)) for extended:
        # that is q̂ ⊗ E − α ∇V(q̂ ⊗ E), the term of Corollary 1.
        new = multiply_components(q, E, np.empty(shape))
        if cfg.variant == 'extended':
            scale = np.einsum('i...,i...->...', q, q)
            scale -= 1.0
            scale *= -4.0 * cfg.alpha
            scale += 1.0
            new *= scale
        if measurement is not None:
            y = _components(quat.check_quaternions(measurement, 'measurement'),
                            q.ndim - 1)
            if cfg.align_sign:
                dot = np.einsum('i...,i...->...', y, q)
                y = np.where(dot < 0.0, -y, y)
            innovation = y - q  # a new array, safe to scale in place
            if cfg.gain_mode == 'constant':
                flat = innovation.reshape(4, -1)
                new += (self._gain_matrix.T @ flat).reshape(innovation.shape)
            else:
                kappa = cfg.kappa_at(self.measurements_used)
                innovation *= kappa
                new += multiply_components(
                    innovation, E, np.empty(np.broadcast_shapes(
                        innovation.shape, E.shape)))
            self.measurements_used += 1
        if cfg.variant == 'projected':
            n = np.sqrt(np.einsum('i...,i...->...', new, new))
            if not np.all(np.isfinite(n)) or np.any(n == 0.0):
                raise ValueError('Cannot normalize a quaternion that is zero '
                                 'or not finite')
            new /= n
        self._q = np.ascontiguousarray(np.broadcast_to(
            new, (4,) + self.batch_shape))
        return self.state


def component_major(a):
    """
    Return ``a`` (shape ``(..., 4)``) backed by contiguous components.

    The values and shape are those of ``a``; the memory is laid out as
    ``(4, ...)``. :meth:`LuenbergerObserver.step` takes such arrays without
    copying them, which pays when several observers share one input.

    Parameters
    ----------
    a : array_like, shape (..., n)

    Returns
    -------
    view : ndarray, shape (..., n)

    """
    return np.moveaxis(_components(a), 0, -1)


def _components(a, ndim=0):
    """
    Return ``(..., n)`` as contiguous components ``(n, ...)``.

    Leading axes are padded to ``ndim`` so that the components broadcast
    against a batch of ``ndim`` dimensions as ``(..., n)`` arrays do.
    """
    a = np.asarray(a, dtype=float)
    a = a.reshape((1,) * (ndim + 1 - a.ndim) + a.shape)
    return np.ascontiguousarray(np.moveaxis(a, -1, 0))


def _rotation_components(theta, ndim=0):
    """``exp((0, θ/2))`` as components ``(4, ...)`` from ``θ`` ``(..., 3)``."""
    half = 0.5 * _components(theta, ndim)  # a new array: never scale the caller's
    a = np.sqrt(np.einsum('i...,i...->...', half, half))
    out = np.empty((4,) + a.shape)
    # [row, ...] keeps a 0-d row an array (a valid `out`) for batch ().
    np.cos(a, out=out[0, ...])
    np.multiply(half, quat._sinc(a), out=out[1:])
    return out


def multiply_components(p, q, out, scratch=None):
    """
    Hamilton product of components ``(4, ...)`` into ``out``.

    ``scratch``: an array of ``out.shape[1:]`` for the terms (else a new one).
    """
    pw, px, py, pz = p
    qw, qx, qy, qz = q
    t = np.empty(out.shape[1:]) if scratch is None else scratch
    for row, terms in enumerate((
            ((pw, qw, 1), (px, qx, -1), (py, qy, -1), (pz, qz, -1)),
            ((pw, qx, 1), (px, qw, 1), (py, qz, 1), (pz, qy, -1)),
            ((pw, qy, 1), (px, qz, -1), (py, qw, 1), (pz, qx, 1)),
            ((pw, qz, 1), (px, qy, 1), (py, qx, -1), (pz, qw, 1)))):
        (a, b, _), *rest = terms
        target = out[row, ...]
        np.multiply(a, b, out=target)
        for a, b, sign in rest:
            np.multiply(a, b, out=t)
            if sign > 0:
                target += t
            else:
                target -= t
    return out


def _quaternion_from_rotation_vector(r):
    hx, hy, hz = 0.5 * r[0], 0.5 * r[1], 0.5 * r[2]
    a = math.sqrt(hx * hx + hy * hy + hz * hz)
    if a < 1e-4:
        a2 = a * a
        s = 1.0 - a2 / 6.0 + a2 * a2 / 120.0
    else:
        s = math.sin(a) / a
    return (math.cos(a), s * hx, s * hy, s * hz)


class SingleObserver:
    """
    One observer on plain Python floats: the same maths, no numpy.

    A single-sample step in floats costs a few µs, against tens of µs for
    numpy on 4-element arrays; the ROS node uses this class. The update is
    identical to :class:`LuenbergerObserver` with ``batch_shape=()`` (tested).

    Parameters
    ----------
    variant, alpha, gain, gain_mode, kappa, kappa_min, initial, align_sign
        See :class:`ObserverConfig`.

    Attributes
    ----------
    state : tuple of 4 float
        The ambient estimate ``q̂_k``.
    measurements_used : int

    """

    def __init__(self, variant='extended', alpha=PAPER_ALPHA, gain=PAPER_GAIN,
                 initial=(1.0, 0.0, 0.0, 0.0), gain_mode='constant',
                 kappa=DEFAULT_KAPPA, kappa_min=DEFAULT_KAPPA_MIN,
                 align_sign=False):
        self.config = ObserverConfig(variant, alpha, gain, gain_mode, kappa,
                                     kappa_min, initial, align_sign)
        self.reset()

    def reset(self, initial=None):
        """
        Restart from ``initial`` (default: the configured initial estimate).

        Parameters
        ----------
        initial : sequence of 4 float, optional

        """
        initial = self.config.initial if initial is None else _finite_tuple(
            initial, 4, 'initial estimate')
        if sum(v * v for v in initial) == 0.0:
            raise ValueError('initial estimate must be a nonzero quaternion')
        self.state = tuple(initial)
        self.measurements_used = 0

    def step(self, increment, measurement=None):
        """
        Advance by one step: from ``q̂_k`` to ``q̂_{k+1}``.

        Parameters
        ----------
        increment : sequence of 3 float
            ``θ_k``, rad.
        measurement : sequence of 4 float, optional
            ``y_k``, scalar first.

        Returns
        -------
        state : tuple of 4 float

        """
        cfg = self.config
        q = self.state
        E = _quaternion_from_rotation_vector(increment)
        new = quat.multiply_floats(q, E)
        propagated = new
        if measurement is not None:
            y0, y1, y2, y3 = measurement
            if cfg.align_sign and (y0 * q[0] + y1 * q[1] + y2 * q[2]
                                   + y3 * q[3]) < 0.0:
                y0, y1, y2, y3 = -y0, -y1, -y2, -y3
            innovation = (y0 - q[0], y1 - q[1], y2 - q[2], y3 - q[3])
            if cfg.gain_mode == 'constant':
                c = quat.multiply_floats(innovation, cfg.gain)
            else:
                kappa = cfg.kappa_at(self.measurements_used)
                c = tuple(kappa * v for v in quat.multiply_floats(innovation, E))
            new = (new[0] + c[0], new[1] + c[1], new[2] + c[2], new[3] + c[3])
            self.measurements_used += 1
        if cfg.variant == 'extended':
            s = 4.0 * cfg.alpha * (
                q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3] - 1.0)
            new = (new[0] - s * propagated[0], new[1] - s * propagated[1],
                   new[2] - s * propagated[2], new[3] - s * propagated[3])
        elif cfg.variant == 'projected':
            n = math.sqrt(sum(v * v for v in new))
            if n == 0.0 or not math.isfinite(n):
                raise ValueError('projected update reached a zero or '
                                 'non-finite quaternion')
            new = tuple(v / n for v in new)
        self.state = new
        return new
