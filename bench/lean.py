"""
A measurement prototype: how fast the batched extended step can be in numpy.

Not the package's maths (that lives in ``ext_observer.core`` alone): this
is the same update written the way the benchmark suggests the core could
compute it, timed in the same run and checked against
:meth:`LuenbergerObserver.step` to 1e-12 every time it runs, so that the
change request in ``docs/performance.md`` rests on a measured figure.

The three differences from the core's step:

- structure of arrays: quaternions are ``(4, N)`` with contiguous rows,
  instead of ``(N, 4)`` whose components are strided views;
- the constant gain ``(y − q̂) ⊗ L`` is a product with a constant 4 × 4
  matrix (one matmul) instead of a general Hamilton product;
- results go into preallocated buffers (``out=``) instead of new arrays.

``E = exp(Ω/2)`` is given (as when observers share the increments); the
trigonometry it needs is timed separately as the floor of the other case.
"""

import numpy as np

from ext_observer.core import LuenbergerObserver, multiply, PAPER_ALPHA, PAPER_GAIN
from ext_observer.core.paper.observer import multiply_components


def right_matrix(quaternion):
    """Return ``R`` with ``p ⊗ quaternion = R @ p`` for ``p`` of shape (4, N)."""
    basis = np.eye(4)
    return np.stack([multiply(basis[i], quaternion) for i in range(4)], axis=1)


class LeanExtendedStep:
    """
    The extended observer's step, constant gain, on ``(4, N)`` arrays.

    Parameters
    ----------
    batch : int
    alpha : float
    gain : sequence of 4 float

    """

    def __init__(self, batch, alpha=PAPER_ALPHA, gain=PAPER_GAIN):
        self.alpha = alpha
        self.gain_matrix = right_matrix(np.asarray(gain, dtype=float))
        self.propagated = np.empty((4, batch))
        self.scratch = np.empty((4, batch))
        self.residual = np.empty(batch)

    def __call__(self, q, e, y, out):
        """
        Write ``q̂⁺`` into ``out``; all arguments ``(4, N)``, C-contiguous.

        ``q`` is the estimate, ``e = exp(Ω/2)``, ``y`` the measurement.
        """
        # q ⊗ e, the core's product of components, its terms in the scratch.
        p = multiply_components(q, e, self.propagated, self.scratch[0])
        np.subtract(y, q, out=self.scratch)
        np.matmul(self.gain_matrix, self.scratch, out=out)
        out += p
        r = self.residual
        np.einsum('ij,ij->j', q, q, out=r)
        r -= 1.0
        r *= 4.0 * self.alpha
        p *= r
        out -= p
        return out


def check_against_core(batch=1000, seed=0):
    """Raise if the prototype differs from the core's step; return the gap."""
    rng = np.random.default_rng(seed)
    q = rng.standard_normal((batch, 4))
    e = rng.standard_normal((batch, 4))
    e /= np.linalg.norm(e, axis=1, keepdims=True)
    y = rng.standard_normal((batch, 4))
    core = LuenbergerObserver('extended', batch_shape=(batch,))
    core.state = q.copy()
    expected = core.step(np.zeros((batch, 3)), y, rotation=e)
    out = np.empty((4, batch))
    LeanExtendedStep(batch)(np.ascontiguousarray(q.T), np.ascontiguousarray(e.T),
                            np.ascontiguousarray(y.T), out)
    gap = float(np.abs(out.T - expected).max())
    if not gap < 1e-12:
        raise RuntimeError(f'lean prototype differs from the core by {gap}')
    return gap
