"""
Quaternion algebra on batched arrays.

Conventions, stated once for the whole package:

- A quaternion is an array of shape ``(..., 4)``, scalar first:
  ``(w, x, y, z)``. Every function broadcasts over the leading dimensions,
  so one call serves one quaternion or a million.
- The product is Hamilton's (``i j = k``).
- A vector quaternion has ``w = 0``; a rotation vector ``r`` (rad, shape
  ``(..., 3)``) corresponds to the unit quaternion ``exp((0, r / 2))``.
- Rotation increments are body-frame: ``q_{k+1} = q_k ⊗ exp(Ω_k / 2)``.

The functions do not silently normalize: the extension technique lives in
the ambient space H = R⁴, so non-unit quaternions are legitimate states.
Only :func:`normalize`, :func:`attitude_error` and
:func:`rotation_vector_from_quaternion` project to the unit sphere.
"""

import numpy as np

__all__ = [
    'IDENTITY',
    'attitude_error',
    'check_quaternions',
    'check_vectors',
    'conjugate',
    'constraint_residual',
    'exp',
    'log',
    'manifold_distance',
    'multiply',
    'multiply_floats',
    'norm',
    'normalize',
    'quaternion_from_rotation_vector',
    'random_unit_quaternions',
    'rotation_matrices',
    'right_matrix',
    'rotation_vector_from_quaternion',
    'squared_norm',
]

IDENTITY = np.array([1.0, 0.0, 0.0, 0.0])

# Below this angle (rad) sin(a)/a is evaluated by its Taylor series; the
# series 1 - a²/6 + a⁴/120 is exact to machine precision there.
_SMALL_ANGLE = 1e-4


def check_quaternions(q, name='q'):
    """
    Return ``q`` as a float array of shape ``(..., 4)``.

    Parameters
    ----------
    q : array_like, shape (..., 4)
        Quaternions, scalar first.
    name : str
        Name used in the error message.

    Returns
    -------
    q : ndarray, shape (..., 4)

    Raises
    ------
    ValueError
        If the last dimension is not 4.

    """
    return _check_last_axis(q, 4, name)


def _check_last_axis(a, size, name):
    a = np.asarray(a, dtype=float)
    if a.ndim == 0 or a.shape[-1] != size:
        raise ValueError(
            f'Expected `{name}` to have shape (..., {size}), got {a.shape}')
    return a


def check_vectors(v, name='v'):
    """
    Return ``v`` as a float array of shape ``(..., 3)``.

    Raises
    ------
    ValueError
        If the last dimension is not 3.

    """
    return _check_last_axis(v, 3, name)


def multiply(p, q):
    """
    Hamilton product ``p ⊗ q``.

    Parameters
    ----------
    p, q : array_like, shape (..., 4)
        Quaternions; leading dimensions broadcast.

    Returns
    -------
    pq : ndarray, shape (..., 4)

    """
    p = check_quaternions(p, 'p')
    q = check_quaternions(q, 'q')
    pw, px, py, pz = p[..., 0], p[..., 1], p[..., 2], p[..., 3]
    qw, qx, qy, qz = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    out = np.empty(np.broadcast_shapes(p.shape, q.shape))
    out[..., 0] = pw * qw - px * qx - py * qy - pz * qz
    out[..., 1] = pw * qx + px * qw + py * qz - pz * qy
    out[..., 2] = pw * qy - px * qz + py * qw + pz * qx
    out[..., 3] = pw * qz + px * qy - py * qx + pz * qw
    return out


def multiply_floats(p, q):
    """
    Hamilton product ``p ⊗ q`` of two quaternions given as 4 Python floats.

    The single-estimate paths (the nodes') use it: no numpy call per step.

    Parameters
    ----------
    p, q : sequence of 4 float

    Returns
    -------
    pq : tuple of 4 float

    """
    pw, px, py, pz = p
    qw, qx, qy, qz = q
    return (pw * qw - px * qx - py * qy - pz * qz,
            pw * qx + px * qw + py * qz - pz * qy,
            pw * qy - px * qz + py * qw + pz * qx,
            pw * qz + px * qy - py * qx + pz * qw)


def right_matrix(q):
    """
    Matrix ``R`` of right multiplication by ``q``: ``p ⊗ q = p @ R``.

    Multiplying a batch by a constant quaternion is then one matmul.

    Parameters
    ----------
    q : array_like, shape (4,)

    Returns
    -------
    R : ndarray, shape (4, 4)

    """
    q = check_quaternions(q)
    if q.shape != (4,):
        raise ValueError(f'Expected `q` to have shape (4,), got {q.shape}')
    return multiply(np.eye(4), q)


def rotation_matrices(q):
    """
    Rotation matrices of unit quaternions: ``R(q) v = q ⊗ v ⊗ q̄``.

    Parameters
    ----------
    q : array_like, shape (..., 4)
        Unit quaternions ``(w, x, y, z)`` (not normalized here).

    Returns
    -------
    R : ndarray, shape (..., 3, 3)

    """
    w, x, y, z = np.moveaxis(check_quaternions(q), -1, 0)
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
    ], -2)


def conjugate(q):
    """
    Conjugate ``q̄ = (w, -x, -y, -z)``.

    Parameters
    ----------
    q : array_like, shape (..., 4)

    Returns
    -------
    q_bar : ndarray, shape (..., 4)

    """
    q = check_quaternions(q)
    return q * np.array([1.0, -1.0, -1.0, -1.0])


def squared_norm(q):
    """
    Real part of ``q̄ q``, that is ``‖q‖²``.

    Parameters
    ----------
    q : array_like, shape (..., 4)

    Returns
    -------
    n2 : ndarray, shape (...)

    """
    q = check_quaternions(q)
    return np.einsum('...i,...i->...', q, q)


def norm(q):
    """
    Euclidean norm ``‖q‖ = sqrt(q̄ q)``.

    Parameters
    ----------
    q : array_like, shape (..., 4)

    Returns
    -------
    n : ndarray, shape (...)

    """
    return np.sqrt(squared_norm(q))


def normalize(q):
    """
    Project onto the unit sphere S³: ``q / ‖q‖``.

    Parameters
    ----------
    q : array_like, shape (..., 4)

    Returns
    -------
    u : ndarray, shape (..., 4)

    Raises
    ------
    ValueError
        If any quaternion has zero norm (it has no direction), or is not
        finite.

    """
    q = check_quaternions(q)
    n = norm(q)
    if not np.all(np.isfinite(n)) or np.any(n == 0.0):
        raise ValueError(
            'Cannot normalize a quaternion that is zero or not finite')
    return q / n[..., np.newaxis]


def _sinc(a):
    """Return ``sin(a) / a`` with a Taylor branch near zero."""
    a = np.asarray(a, dtype=float)
    small = np.abs(a) < _SMALL_ANGLE
    safe = np.where(small, 1.0, a)
    a2 = a * a
    return np.where(small, 1.0 - a2 / 6.0 + a2 * a2 / 120.0, np.sin(safe) / safe)


def exp(q):
    """
    Quaternion exponential.

    For ``q = (w, v)``: ``exp(q) = e^w (cos‖v‖, sin(‖v‖) v / ‖v‖)``. For a
    vector quaternion (``w = 0``) the result is a unit quaternion. A Taylor
    branch keeps it accurate for ``‖v‖`` down to zero (below 1e-8 rad the
    relative error stays at machine precision).

    Parameters
    ----------
    q : array_like, shape (..., 4)

    Returns
    -------
    e : ndarray, shape (..., 4)

    """
    q = check_quaternions(q)
    return np.exp(q[..., 0])[..., np.newaxis] * _exp_vector(q[..., 1:])


def _exp_vector(v):
    """``exp((0, v))`` for vectors ``v`` of shape (..., 3), with the Taylor branch."""
    a = np.sqrt(np.einsum('...i,...i->...', v, v))
    return np.concatenate(
        (np.cos(a)[..., np.newaxis], _sinc(a)[..., np.newaxis] * v), axis=-1)


def log(q):
    """
    Quaternion logarithm, the inverse of :func:`exp` on its principal branch.

    ``log(q) = (ln‖q‖, atan2(‖v‖, w) v / ‖v‖)``; the vector part has norm in
    ``[0, π]``.

    Parameters
    ----------
    q : array_like, shape (..., 4)
        Nonzero quaternions.

    Returns
    -------
    l : ndarray, shape (..., 4)

    """
    q = check_quaternions(q)
    w = q[..., 0]
    v = q[..., 1:]
    vn = np.sqrt(np.einsum('...i,...i->...', v, v))
    n = np.sqrt(w * w + vn * vn)
    a = np.arctan2(vn, w)
    # a / ‖v‖ = a / (n sin a): use the stable ratio a / sin(a) near zero.
    with np.errstate(divide='ignore', invalid='ignore'):
        ratio = np.where(vn > 0.0, a / np.where(vn > 0.0, vn, 1.0),
                         1.0 / np.where(n > 0.0, n, 1.0))
        log_n = np.log(n)
    return np.concatenate((log_n[..., np.newaxis],
                           ratio[..., np.newaxis] * v), axis=-1)


def quaternion_from_rotation_vector(r):
    """
    Unit quaternion of the rotation vector ``r``: ``exp((0, r / 2))``.

    Parameters
    ----------
    r : array_like, shape (..., 3)
        Rotation vectors (axis times angle), rad.

    Returns
    -------
    q : ndarray, shape (..., 4)

    """
    return _exp_vector(0.5 * check_vectors(r, 'r'))


def rotation_vector_from_quaternion(q):
    """
    Rotation vector of the attitude ``q`` (normalized first).

    ``q`` and ``-q`` give the same rotation vector, with angle in ``[0, π]``.

    Parameters
    ----------
    q : array_like, shape (..., 4)
        Nonzero quaternions.

    Returns
    -------
    r : ndarray, shape (..., 3)
        Rotation vectors, rad.

    """
    q = normalize(q)
    q = np.where(q[..., :1] < 0.0, -q, q)
    return 2.0 * log(q)[..., 1:]


def attitude_error(p, q):
    """
    Angle of the rotation between the attitudes ``p`` and ``q``.

    Sign-invariant (``q`` and ``-q`` are the same attitude) and defined for
    any nonzero quaternions (they are normalized first).

    Parameters
    ----------
    p, q : array_like, shape (..., 4)

    Returns
    -------
    angle : ndarray, shape (...)
        In ``[0, π]``, rad.

    """
    p = check_quaternions(p, 'p')
    q = check_quaternions(q, 'q')
    if np.any(squared_norm(p) == 0.0) or np.any(squared_norm(q) == 0.0):
        raise ValueError('The attitude of a zero quaternion is undefined')
    # p̄ ⊗ q = (p·q, p_w q_v − q_w p_v − p_v × q_v); both parts scale with
    # ‖p‖‖q‖, so the angle needs no normalization. atan2 stays accurate at
    # small angles, unlike acos.
    pw, px, py, pz = p[..., 0], p[..., 1], p[..., 2], p[..., 3]
    qw, qx, qy, qz = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    dot = pw * qw + px * qx + py * qy + pz * qz
    vx = pw * qx - qw * px - (py * qz - pz * qy)
    vy = pw * qy - qw * py - (pz * qx - px * qz)
    vz = pw * qz - qw * pz - (px * qy - py * qx)
    vn = np.sqrt(vx * vx + vy * vy + vz * vz)
    return 2.0 * np.arctan2(vn, np.abs(dot))


def manifold_distance(q):
    """
    Euclidean distance to the unit sphere: ``|‖q‖ - 1|``.

    Parameters
    ----------
    q : array_like, shape (..., 4)

    Returns
    -------
    dist : ndarray, shape (...)

    """
    return np.abs(norm(q) - 1.0)


def constraint_residual(q):
    """
    Constraint residual ``|q̄q - 1|``, the square root of the paper's V.

    This is the quantity the paper's ``dist(q, S³)`` columns report.

    Parameters
    ----------
    q : array_like, shape (..., 4)

    Returns
    -------
    residual : ndarray, shape (...)

    """
    return np.abs(squared_norm(q) - 1.0)


def random_unit_quaternions(rng, shape=()):
    """
    Draw attitudes uniformly on S³ (normalized Gaussian samples).

    Parameters
    ----------
    rng : numpy.random.Generator
    shape : tuple of int
        Leading shape.

    Returns
    -------
    q : ndarray, shape (*shape, 4)

    """
    shape = tuple(np.atleast_1d(shape).astype(int)) if shape != () else ()
    while True:
        q = rng.standard_normal(shape + (4,))
        n = norm(q)
        if np.all(n > 1e-12):
            return q / n[..., np.newaxis]
