"""
The gain certificate of Theorem 1: which α makes the manifold attractive.

Theorem 1 asks for ``ε, δ, b, L, d`` with

- ``L ≥ ‖∇V(x)‖`` on the sublevel set ``V⁻¹([0, ε])``;
- ``d > λ_max(D²V(x))`` on ``S_δ``, the points within ``δ`` of that set;
- ``‖∇V(x)‖² ≥ b V(x)`` on ``V⁻¹([0, ε])``;

and then certifies ``V(x_{k+1}) ≤ (1 − b c) V(x_k)`` with
``c = α − α² d / 2`` for every ``0 < α < min(2/d, δ/L)``.

For the unit sphere S³ with ``V(x) = (x̄x − 1)²`` everything is exact:
``V⁻¹([0, ε])`` is the shell ``1 − √ε ≤ ‖x‖² ≤ 1 + √ε``,
``‖∇V‖ = 4‖x‖ |‖x‖² − 1|`` peaks on its outer sphere, so
``L = 4 √ε √(1 + √ε)``; ``D²V = 4(‖x‖² − 1) I + 8 x xᵀ`` has
``λ_max = 12‖x‖² − 4``, largest on the outer boundary of ``S_δ``, so
``d = 12 (√(1 + √ε) + δ)² − 4``; and ``‖∇V‖² = 16‖x‖² V`` gives
``b = 16 (1 − √ε)``.

The paper's example (ε = 0.5, δ = 0.059) states L = 3.69 and d = 15.87. We
reproduce L = 3.6955; the exact d is 18.377 (the paper's 15.87 matches
neither its own ``λ_max = 12 xᵀx``, which would give 22.38, nor the exact
``12‖x‖² − 4``). The bound on α does not change: ``δ/L = 0.01597`` is the
smaller term for both values of d (``2/d`` is 0.126 with the paper's d and
0.109 with the exact one), so ``α < 0.016`` either way. Only the certified
per-step factor ``1 − bc`` uses d; with the exact d it is slightly weaker.
"""

from dataclasses import asdict, dataclass
from typing import Optional

import numpy as np

__all__ = [
    'GainCertificate',
    'certified_alpha_max',
    'estimate_certificate',
    'optimal_delta',
    's3_certificate',
]


@dataclass(frozen=True)
class GainCertificate:
    """
    The constants of Theorem 1 and the admissible range of α.

    Attributes
    ----------
    epsilon, delta : float
        The sublevel ``V⁻¹([0, ε])`` and the margin ``δ`` of ``S_δ``.
    L : float
        Bound on ``‖∇V‖`` over ``V⁻¹([0, ε])``.
    d : float
        Bound on ``λ_max(D²V)`` over ``S_δ``.
    b : float
        Constant with ``‖∇V‖² ≥ b V`` over ``V⁻¹([0, ε])``.
    alpha_max : float
        ``min(2/d, δ/L)``: any ``0 < α < alpha_max`` is certified.
    alpha, c, factor : float or None
        For a given α: ``c = α − α²d/2`` and the certified per-step factor
        ``1 − bc`` on V (None when no α was given).
    estimated : bool
        True when the constants come from sampling, not from exact formulas.

    """

    epsilon: float
    delta: float
    L: float
    d: float
    b: float
    alpha_max: float
    alpha: Optional[float] = None
    c: Optional[float] = None
    factor: Optional[float] = None
    estimated: bool = False

    def certifies(self, alpha):
        """Return True if ``0 < alpha < alpha_max``."""
        return 0.0 < alpha < self.alpha_max

    def to_dict(self):
        """Return the certificate as a plain dict (for JSON)."""
        return asdict(self)


def _with_alpha(epsilon, delta, L, d, b, alpha, estimated=False):
    L, d, b = float(L), float(d), float(b)
    alpha_max = min(2.0 / d, delta / L)
    c = factor = None
    if alpha is not None:
        alpha = float(alpha)
        c = alpha - alpha * alpha * d / 2.0
        factor = 1.0 - b * c
    return GainCertificate(float(epsilon), float(delta), float(L), float(d),
                           float(b), float(alpha_max), alpha, c, factor,
                           estimated)


def _check_epsilon_delta(epsilon, delta):
    if not (np.isfinite(epsilon) and 0.0 < epsilon < 1.0):
        raise ValueError(
            f'epsilon must be in (0, 1) so that b = 16(1 - sqrt(epsilon)) > 0, '
            f'got {epsilon}')
    if delta is not None and not (np.isfinite(delta) and delta > 0.0):
        raise ValueError(f'delta must be positive and finite, got {delta}')


def s3_certificate(epsilon=0.5, delta=0.059, alpha=None):
    """
    Exact certificate for the unit sphere S³ with ``V(x) = (x̄x − 1)²``.

    Parameters
    ----------
    epsilon : float
        Sublevel of V, in (0, 1).
    delta : float
        Margin of ``S_δ``, > 0.
    alpha : float, optional
        If given, also compute ``c`` and the certified factor ``1 − bc``.

    Returns
    -------
    certificate : GainCertificate

    Raises
    ------
    ValueError
        If ``epsilon`` is not in (0, 1) or ``delta`` is not positive.

    Notes
    -----
    With the paper's ε = 0.5, δ = 0.059: L = 3.6955, d = 18.377 (the paper
    states 15.87), b = 4.686, alpha_max = δ/L = 0.01597. The bound on α is
    the paper's (< 0.016) because δ/L, not 2/d, is the binding term.

    """
    _check_epsilon_delta(epsilon, delta)
    root = np.sqrt(epsilon)
    r_out = np.sqrt(1.0 + root)
    L = 4.0 * r_out * root
    d = 12.0 * (r_out + delta) ** 2 - 4.0
    b = 16.0 * (1.0 - root)
    return _with_alpha(epsilon, delta, L, d, b, alpha)


def optimal_delta(epsilon=0.5):
    """
    Return the δ that maximizes the certified bound on α, and that bound.

    ``δ/L`` grows with δ and ``2/d(δ)`` falls, so the maximum of their
    minimum is where they cross; it is found by bisection.

    Parameters
    ----------
    epsilon : float
        Sublevel of V, in (0, 1).

    Returns
    -------
    delta_opt : float
    alpha_max_opt : float

    """
    _check_epsilon_delta(epsilon, None)

    def gap(delta):
        cert = s3_certificate(epsilon, delta)
        return delta / cert.L - 2.0 / cert.d

    lo, hi = 0.0, 1.0
    while gap(hi) < 0.0:
        hi *= 2.0
    for _ in range(100):
        mid = 0.5 * (lo + hi)
        if gap(mid) < 0.0:
            lo = mid
        else:
            hi = mid
    delta_opt = 0.5 * (lo + hi)
    return delta_opt, s3_certificate(epsilon, delta_opt).alpha_max


def certified_alpha_max(epsilon=0.5):
    """
    Largest α the theorem certifies on S³ for this ε, with the best δ.

    Parameters
    ----------
    epsilon : float
        Sublevel of V, in (0, 1).

    Returns
    -------
    alpha_max : float
        About 0.0762 for ε = 0.5 (δ = 0.2814).

    """
    return optimal_delta(epsilon)[1]


def estimate_certificate(extension, samples, epsilon, delta, alpha=None,
                         rng=None, directions=8):
    """
    Estimate the certificate of a general V by sampling (an estimate only).

    ``L`` and ``b`` are the max of ``‖∇V‖`` and the min of ``‖∇V‖²/V`` over
    the samples that lie in ``V⁻¹([0, ε])``; ``d`` is the max of
    ``λ_max(D²V)`` over those samples moved by random offsets of length
    below ``δ``. Sampling can miss the extremes, so L and d may be
    underestimated and b overestimated: treat the resulting ``alpha_max``
    as an estimate, not a guarantee.

    Parameters
    ----------
    extension : TransversalExtension
        Needs ``V``, ``grad_V`` and ``hessian_V`` on flat states (..., n).
    samples : array_like, shape (m, n)
        Points covering a neighbourhood of the manifold.
    epsilon, delta : float
        As in Theorem 1.
    alpha : float, optional
        If given, also compute ``c`` and ``1 − bc``.
    rng : numpy.random.Generator, optional
    directions : int
        Random offsets per sample for the estimate of d.

    Returns
    -------
    certificate : GainCertificate
        With ``estimated=True``.

    Raises
    ------
    ValueError
        If no sample lies in ``V⁻¹([0, ε])`` or the extension has no Hessian.

    """
    if extension.hessian_V is None:
        raise ValueError('estimate_certificate needs the Hessian of V')
    rng = np.random.default_rng() if rng is None else rng
    x = np.asarray(samples, dtype=float)
    if x.ndim != 2:
        raise ValueError(f'Expected `samples` to have shape (m, n), got {x.shape}')
    v = extension.V(x)
    inside = x[v <= epsilon]
    if inside.shape[0] == 0:
        raise ValueError(f'No sample lies in V^-1([0, {epsilon}])')
    v_in = extension.V(inside)
    g = extension.grad_V(inside)
    g2 = np.einsum('...i,...i->...', g, g)
    L = np.sqrt(g2.max())
    positive = v_in > 0.0
    b = (g2[positive] / v_in[positive]).min() if np.any(positive) else np.inf
    n = x.shape[1]
    u = rng.standard_normal((inside.shape[0], directions, n))
    u /= np.linalg.norm(u, axis=-1, keepdims=True)
    radius = delta * rng.uniform(size=(inside.shape[0], directions, 1)) ** (1.0 / n)
    shifted = (inside[:, np.newaxis, :] + radius * u).reshape(-1, n)
    shifted = np.concatenate((inside, shifted))
    d = np.linalg.eigvalsh(extension.hessian_V(shifted))[..., -1].max()
    return _with_alpha(epsilon, delta, L, d, b, alpha, estimated=True)
