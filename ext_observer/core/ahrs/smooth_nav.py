"""
The smoother across holes by velocity and position: a strapdown navigation in I.

Helper of :mod:`~ext_observer.core.ahrs.smoother` (``join='velocity'``):
:func:`join_velocity`. Each stretch between two holes holds its attitude up
to a small unknown rotation ``φ_s`` (in I); within it, the velocity and the
position follow from the specific force turned into I minus gravity; across
a hole they change by what the force on both sides allows (its mean, give
or take ``nav_accel`` m/s²); the velocity and the position stay bounded, as
a lab's (``nav_speed`` m/s, ``nav_room`` m, per second of data); across a
hole the rotations of the two sides differ by the gyro bridge's error. The
rotations, velocities and positions of all stretches are solved together:
one block-tridiagonal system (:func:`block_tridiagonal`), linear in the
number of holes.
"""

import numpy as np

from ..quaternion import conjugate, multiply, normalize, quaternion_from_rotation_vector
from ..quaternion import rotation_matrices, rotation_vector_from_quaternion
from .smooth_strapdown import rotate_rows

__all__ = ['block_tridiagonal', 'join_velocity', 'skew']

# Unknowns per stretch: its rotation φ (3), velocity and position at its first sample (3, 3).
_SIZE = 9
# A weak pull of every unknown to 0 (rad², m²/s², m² per unit): no stretch is left free.
_PRIOR = 1e-9


def skew(v):
    """``[v]×`` (..., 3, 3): ``[v]× u = v × u``."""
    z = np.zeros(v.shape[:-1])
    return np.stack((np.stack((z, -v[..., 2], v[..., 1]), axis=-1),
                     np.stack((v[..., 2], z, -v[..., 0]), axis=-1),
                     np.stack((-v[..., 1], v[..., 0], z), axis=-1)), axis=-2)


def block_tridiagonal(diagonal, upper, rhs):
    """
    ``x`` (S, k) solving the symmetric block-tridiagonal system (S, k, k), (S − 1, k, k), (S, k).

    ``upper[s]`` couples block ``s`` (rows) to ``s + 1``; the lower blocks are
    its transposes. Block Thomas's algorithm (the system is positive
    definite).
    """
    count = len(diagonal)
    d = np.array(diagonal, dtype=float)
    r = np.array(rhs, dtype=float)
    for s in range(1, count):
        m = np.linalg.solve(d[s - 1], upper[s - 1]).T
        d[s] -= m @ upper[s - 1]
        r[s] -= m @ r[s - 1]
    x = np.empty_like(r)
    x[-1] = np.linalg.solve(d[-1], r[-1])
    for s in range(count - 2, -1, -1):
        x[s] = np.linalg.solve(d[s], r[s] - upper[s] @ x[s + 1])
    return x


def _segment_cumsum(x, start, segment):
    """Cumulative sums of ``x`` (N, 3) restarted at each stretch's first sample ``start``."""
    c = np.cumsum(x, axis=0)
    return c - c[start][segment] + x[start][segment]


def _add_prior(normal, rhs, rows, value, weight, start):
    """
    Add ``Σ w |A x_s + c|²`` over each stretch's samples to its normal equations, in place.

    ``rows`` (N, 3, 9): ``A`` per sample; ``value`` (N, 3): ``c``; ``weight``
    (N,); ``start``: each stretch's first sample.
    """
    weighted = (weight[:, None, None] * rows).transpose(0, 2, 1)
    normal += np.add.reduceat(np.matmul(weighted, rows), start, axis=0)
    rhs -= np.add.reduceat(np.matmul(weighted, value[:, :, None])[:, :, 0], start, axis=0)


def _hole_rows(q, q_bridged, f, g, sums, bridge, gaps, p):
    """
    The rows across each hole (G): velocity, position and rotation, with their information.

    Each row is ``(J_s, J_t, c, W)``: the residual ``J_s x_s + J_t x_{s+1} + c``
    between the stretches before and after the hole, weighed by ``W``.
    ``sums``: the stretches' running ``F``, ``V``, ``P``, ``Q`` and ``τ``
    (:func:`join_velocity`).
    """
    big_f, big_v, big_p, big_q, tau = sums
    before, after, span = gaps
    e, b, h = before, after, span[:, None, None]
    fe, fb = f[e], f[b]
    i3 = np.broadcast_to(np.eye(3), (len(e), 3, 3))
    z3 = np.zeros((len(e), 3, 3))
    # Velocity across the hole: v_{s+1} = v_e + h (a_e + a_b) / 2.
    jv_s = np.concatenate((skew(big_f[e]) + 0.5 * h * skew(fe), -i3, z3), axis=2)
    jv_t = np.concatenate((0.5 * h * skew(fb), i3, z3), axis=2)
    cv = -big_v[e] - 0.5 * span[:, None] * (fe + fb - 2.0 * g)
    # Position: p_{s+1} = p_e + h v_e + h² (2 a_e + a_b) / 6.
    jp_s = np.concatenate((skew(big_q[e]) + h * skew(big_f[e]) + h * h / 3.0 * skew(fe),
                           -(tau[e][:, None, None] + h) * i3, -i3), axis=2)
    jp_t = np.concatenate((h * h / 6.0 * skew(fb), z3, i3), axis=2)
    cp = (-big_p[e] - span[:, None] * big_v[e]
          - np.square(span)[:, None] / 6.0 * (2.0 * fe + fb - 3.0 * g))
    # Rotation: φ_{s+1} − φ_s + ρ, ρ the stretches' turn against the bridge, doubted by
    # the bridge's variance turned into I, times nav_bridge.
    turn = multiply(multiply(q[b], conjugate(q_bridged[b])),
                    conjugate(multiply(q[e], conjugate(q_bridged[e]))))
    turn = normalize(np.where(turn[:, :1] < 0.0, -turn, turn))
    rho = rotation_vector_from_quaternion(turn)
    r = rotation_matrices(q[b])
    cov = p.nav_bridge * np.einsum('gij,gj,gkj->gik', r, bridge, r) + 1e-12 * np.eye(3)
    jr_s = np.concatenate((-i3, z3, z3), axis=2)
    jr_t = np.concatenate((i3, z3, z3), axis=2)
    return ((jv_s, jv_t, cv, np.broadcast_to(np.eye(3) / p.nav_accel ** 2, (len(e), 3, 3))
             / np.square(span)[:, None, None]),
            (jp_s, jp_t, cp, np.broadcast_to(np.eye(3) / p.nav_accel ** 2, (len(e), 3, 3))
             / (0.25 * span ** 4)[:, None, None]),
            (jr_s, jr_t, rho, np.linalg.inv(cov)))


def join_velocity(q, q_bridged, acc, bridge, gaps, axis, p):
    """
    ``q`` with each stretch turned by ``exp(φ_s)``: the rotations that keep the motion bounded.

    Parameters
    ----------
    q : ndarray, shape (N, 4)
        The attitude to correct (body → I), each stretch's rotation held
        within it (the gyro's).
    q_bridged : ndarray, shape (N, 4)
        The gyro's attitude across the holes (the bridge): ``q``'s
        stretches differ from it by a constant rotation each.
    acc : ndarray, shape (N, 3)
        Specific force, m/s².
    bridge : ndarray, shape (G, 3)
        rad², the bridges' variances per body axis.
    gaps, axis, p
        The holes (:func:`~ext_observer.core.ahrs.smooth_holes.gaps_of`), the
        time axis and the settings (``nav_speed``, ``nav_room``,
        ``nav_accel``, ``nav_tilt``, ``nav_bridge``).

    """
    before, after, span = gaps
    if len(before) == 0:
        return q
    n = len(q)
    bounds = np.concatenate(([0], after, [n]))
    start = bounds[:-1]
    count = len(start)
    segment = np.searchsorted(after, np.arange(n), side='right')
    f = rotate_rows(q, acc)
    g = np.array([0.0, 0.0, np.linalg.norm(np.mean(f, axis=0))])
    dt = axis.dt.copy()
    dt[start] = 0.0
    # Within a stretch: v_k = v_s + V_k − [F_k]× φ_s,
    # p_k = p_s + τ_k v_s + P_k − [Q_k]× φ_s.
    big_f = _segment_cumsum(f * dt[:, None], start, segment)
    big_v = _segment_cumsum((f - g) * dt[:, None], start, segment)
    tau = axis.times - axis.times[start][segment]
    big_p = _segment_cumsum(big_v * dt[:, None], start, segment)
    big_q = _segment_cumsum(big_f * dt[:, None], start, segment)
    normal = np.zeros((count, _SIZE, _SIZE))
    rhs = np.zeros((count, _SIZE))
    weight = np.where(dt > 0.0, dt, axis.usual)
    eye = np.broadcast_to(np.eye(3), (n, 3, 3))
    if np.isfinite(p.nav_speed):
        a = np.concatenate((-skew(big_f), eye, np.zeros((n, 3, 3))), axis=2)
        _add_prior(normal, rhs, a, big_v, weight / p.nav_speed ** 2, start)
    if np.isfinite(p.nav_room):
        a = np.concatenate((-skew(big_q), tau[:, None, None] * eye, eye), axis=2)
        _add_prior(normal, rhs, a, big_p, weight / p.nav_room ** 2, start)
    upper = np.zeros((count - 1, _SIZE, _SIZE))
    rows = _hole_rows(q, q_bridged, f, g, (big_f, big_v, big_p, big_q, tau), bridge, gaps, p)
    for js, jt, c, info in rows:
        normal[:-1] += np.einsum('gji,gjk,gkl->gil', js, info, js)
        normal[1:] += np.einsum('gji,gjk,gkl->gil', jt, info, jt)
        upper += np.einsum('gji,gjk,gkl->gil', js, info, jt)
        rhs[:-1] -= np.einsum('gji,gjk,gk->gi', js, info, c)
        rhs[1:] -= np.einsum('gji,gjk,gk->gi', jt, info, c)
    normal += _PRIOR * np.eye(_SIZE)
    # Each stretch's rotation about the tilt's join (``q``): doubted by nav_tilt.
    normal[:, :3, :3] += np.eye(3) / p.nav_tilt ** 2
    x = block_tridiagonal(normal, upper, rhs)
    return normalize(multiply(quaternion_from_rotation_vector(x[segment, :3]), q))
