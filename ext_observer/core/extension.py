"""
The transversally stable extension of a discrete-time system.

Theorem 1 (and Corollary 1 for autonomous systems) of the paper: if
``V ≥ 0`` is C², ``V⁻¹(0)`` is the manifold, ``V ∘ f = V`` and
``‖∇V‖² ≥ b V`` near the manifold, then

    x_{k+1} = f(x_k, w_k) − α ∇V(f(x_k, w_k))                 (eq. 1, eq. 2)

converges to ``V⁻¹(0)`` exponentially for ``0 < α < min(2/d, δ/L)``.
Theorem 2 builds ``V = ½‖g‖²`` from a constraint ``g: Rⁿ → Rᵏ``, so that
``∇V = Dg(x)ᵀ g(x)`` and ``D²V = DgᵀDg + Σᵢ gᵢ D²gᵢ``.

States are batched arrays ``(..., n)`` (``(..., 3, 3)`` for SO(3)).
"""

from dataclasses import dataclass
from typing import Callable, Optional

import numpy as np

from . import quaternion as quat

__all__ = [
    'ConstraintExtension',
    'TransversalExtension',
    'so3_extension',
    'sphere_extension',
    'sphere_grad_V',
    'sphere_hessian_V',
    'sphere_V',
]


@dataclass(frozen=True)
class TransversalExtension:
    """
    A Lyapunov-like function ``V`` whose zero set is the manifold.

    Attributes
    ----------
    V : callable
        ``V(x) -> (...)``, non-negative, zero exactly on the manifold.
    grad_V : callable
        ``grad_V(x) -> (..., n)``, the gradient of ``V``.
    hessian_V : callable, optional
        ``hessian_V(x) -> (..., n, n)``; only needed for certification.

    """

    V: Callable
    grad_V: Callable
    hessian_V: Optional[Callable] = None

    def correct(self, x, alpha):
        """
        Apply the extension term: ``x − α ∇V(x)``.

        Parameters
        ----------
        x : ndarray, shape (..., n)
            The propagated state ``f(x_k, w_k)``.
        alpha : float
            Gain of the extension term, ``α > 0``.

        Returns
        -------
        x_next : ndarray, shape (..., n)

        """
        return x - alpha * self.grad_V(x)

    def step(self, f, x, alpha, *args):
        """
        One step of the extended system, Theorem 1 eq. (1).

        Parameters
        ----------
        f : callable
            The original map ``f(x, *args)``, with ``V ∘ f = V``.
        x : ndarray, shape (..., n)
            Current state ``x̃_k``.
        alpha : float
            Gain, inside the certified range for exponential convergence.
        *args
            Inputs ``w_k`` passed on to ``f``.

        Returns
        -------
        x_next : ndarray, shape (..., n)
            ``f(x, w) − α ∇V(f(x, w))``.

        """
        return self.correct(f(x, *args), alpha)


class ConstraintExtension(TransversalExtension):
    """
    Extension built from a constraint ``g`` (Theorem 2): ``V = ½‖g‖²``.

    Parameters
    ----------
    g : callable
        ``g(x) -> (..., k)``, zero exactly on the manifold.
    jacobian_g : callable
        ``jacobian_g(x) -> (..., k, n)``, the Jacobian ``Dg(x)``.
    hessians_g : callable, optional
        ``hessians_g(x) -> (..., k, n, n)``, the Hessians ``D²gᵢ(x)``,
        needed only for certification.

    """

    def __init__(self, g, jacobian_g, hessians_g=None):
        def V(x):
            r = g(x)
            return 0.5 * np.einsum('...i,...i->...', r, r)

        def grad_V(x):
            return np.einsum('...ij,...i->...j', jacobian_g(x), g(x))

        hessian_V = None
        if hessians_g is not None:
            def hessian_V(x):
                J = jacobian_g(x)
                return (np.einsum('...ki,...kj->...ij', J, J)
                        + np.einsum('...k,...kij->...ij', g(x), hessians_g(x)))

        super().__init__(V, grad_V, hessian_V)
        object.__setattr__(self, 'g', g)
        object.__setattr__(self, 'jacobian_g', jacobian_g)


def sphere_V(x):
    """
    The paper's ``V(x) = (x̄x − 1)²`` on H (Section 3.1).

    Parameters
    ----------
    x : array_like, shape (..., 4)

    Returns
    -------
    V : ndarray, shape (...)

    """
    r = quat.squared_norm(x) - 1.0
    return r * r


def sphere_grad_V(x):
    """
    Gradient ``∇V(x) = 4 x (x̄x − 1)``.

    Parameters
    ----------
    x : array_like, shape (..., 4)

    Returns
    -------
    grad : ndarray, shape (..., 4)

    """
    x = quat.check_quaternions(x, 'x')
    return 4.0 * x * (quat.squared_norm(x) - 1.0)[..., np.newaxis]


def sphere_hessian_V(x):
    """
    Exact Hessian ``D²V(x) = 4(‖x‖² − 1) I + 8 x xᵀ``.

    Its largest eigenvalue is ``12‖x‖² − 4`` (along ``x``).

    Parameters
    ----------
    x : array_like, shape (..., 4)

    Returns
    -------
    hessian : ndarray, shape (..., 4, 4)

    """
    x = quat.check_quaternions(x, 'x')
    n2 = quat.squared_norm(x)
    return (4.0 * (n2 - 1.0)[..., np.newaxis, np.newaxis] * np.eye(4)
            + 8.0 * x[..., :, np.newaxis] * x[..., np.newaxis, :])


def sphere_extension():
    """
    Return the extension of quaternion kinematics to H with the paper's V.

    Returns
    -------
    extension : TransversalExtension
        ``V = (x̄x − 1)²``, ``∇V = 4x(x̄x − 1)``, exact Hessian.

    """
    return TransversalExtension(sphere_V, sphere_grad_V, sphere_hessian_V)


def _so3_g(R):
    R = np.asarray(R, dtype=float)
    G = np.swapaxes(R, -1, -2) @ R - np.eye(3)
    return G.reshape(G.shape[:-2] + (9,))


def _so3_jacobian(R):
    """Return D(RᵀR − I), flattened to shape (..., 9, 9)."""
    R = np.asarray(R, dtype=float)
    eye = np.eye(3)
    # d(RᵀR)_ij / dR_ab = δ_jb R_ai + δ_ib R_aj
    J = (np.einsum('jb,...ai->...ijab', eye, R)
         + np.einsum('ib,...aj->...ijab', eye, R))
    return J.reshape(R.shape[:-2] + (9, 9))


def _so3_hessians(R):
    R = np.asarray(R, dtype=float)
    eye = np.eye(3)
    # d²(RᵀR)_ij / dR_ab dR_cd = δ_ac (δ_jb δ_id + δ_ib δ_jd)
    H = (np.einsum('ac,jb,id->ijabcd', eye, eye, eye)
         + np.einsum('ac,ib,jd->ijabcd', eye, eye, eye)).reshape(9, 9, 9)
    return np.broadcast_to(H, R.shape[:-2] + (9, 9, 9))


def _so3_grad_V(R):
    """Return ``∇V(R) = 2 R (RᵀR − I)`` in matrix shape (..., 3, 3)."""
    R = np.asarray(R, dtype=float)
    return 2.0 * R @ (np.swapaxes(R, -1, -2) @ R - np.eye(3))


class _SO3Extension(ConstraintExtension):
    """Extension of SO(3) in R^{3×3} with ``g(R) = RᵀR − I``."""

    def __init__(self):
        super().__init__(_so3_g, _so3_jacobian, _so3_hessians)
        # Same gradient as Dgᵀg, kept in the shape of R for the user.
        object.__setattr__(self, 'grad_V', _so3_grad_V)


def so3_extension():
    """
    Return the extension of rigid-body kinematics on SO(3) to R^{3×3}.

    The constraint is ``g(R) = RᵀR − I`` (Theorem 2), so
    ``V(R) = ½‖RᵀR − I‖²_F`` and ``∇V(R) = 2R(RᵀR − I)``, a
    ``(..., 3, 3)`` array. The kinematics ``R⁺ = R exp([θ]×)`` preserve
    ``RᵀR`` and hence ``V``, which is assumption A1.

    Returns
    -------
    extension : ConstraintExtension
        With matrix-shaped ``V`` and ``grad_V``; ``g``, ``jacobian_g``
        work on the flattened 9-vector of ``RᵀR − I``.

    """
    return _SO3Extension()
