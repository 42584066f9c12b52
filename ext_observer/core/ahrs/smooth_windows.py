"""
The smoother's zero-phase windows: the inclination and the heading.

Helpers of :mod:`~ext_observer.core.ahrs.smoother`: :func:`inclination`
(the specific force in I averaged around each sample, turned up),
:func:`heading` (the field's horizontal direction averaged, turned north;
across holes, each stretch's offset solved at once, :func:`heading_offsets`).
The windows are three box filters on cumulative sums (:func:`sums`).
"""

import numpy as np

from ..quaternion import rotation_matrices
from .smooth_strapdown import box3, field_parts, rotate_rows, tilted, turned_about_vertical

__all__ = ['average', 'field_weights', 'heading', 'heading_offsets', 'inclination',
           'most_common', 'sums', 'tridiagonal']


def sums(x, weight, sigma_samples, axis=None):
    """
    ``Σ K w x`` and ``Σ K w`` over a Gaussian-like window ``K`` of σ samples.

    Three centred box filters of ``2 h + 1`` samples (``h`` ≈ σ: a window of
    variance σ²), applied alike to ``weight x`` and ``weight``: zero phase,
    truncated at the ends. ``axis``
    (:class:`~ext_observer.core.ahrs.smoother._Axis`): on its even grid, in
    usual intervals (a lost sample: a slot of weight 0), read back at the
    samples.
    """
    h = max(1, int(round(sigma_samples)))
    num = weight[:, None] * x
    den = weight
    if axis is not None:
        num, den = axis.grid(num), axis.grid(den)
    num = box3(num, h, out=num)
    den = box3(den, h)
    if axis is not None:
        num, den = axis.samples(num), axis.samples(den)
    return num, den


def average(x, weight, sigma_samples, far=None, axis=None):
    """
    The weighted mean of ``x`` (N, k) over a window of σ samples around each.

    ``far``: ``(σ_far, share)``, a second, wider window whose weights count
    ``share`` as much (per unit of window weight): where the near window
    holds no weight, the far one decides. ``axis``: the windows in time
    (:func:`sums`), σ in usual intervals.
    """
    num, den = sums(x, weight, sigma_samples, axis)
    if far is not None and far[1] > 0.0:
        num_far, den_far = sums(x, weight, far[0], axis)
        scale = far[1] * sigma_samples / far[0]
        num += np.multiply(scale, num_far, out=num_far)
        den = den + scale * den_far
    return np.divide(num, np.maximum(den, np.finfo(float).tiny)[:, None], out=num)


def inclination(q, acc, axis, p):
    """
    ``c ⊗ q``: ``c``, the smallest rotation turning the averaged specific force in I up.

    With samples lost (``axis.slot``), a sample weighs its share of time
    (:meth:`~ext_observer.core.ahrs.smoother._Axis.spans`), and the slots of each hole of at least
    ``join_time`` hold the force in I on the straight line between the
    hole's two samples: the window weighs time uniformly across the hole
    too, so that the body's linear acceleration still averages to its change
    of velocity over the window.
    """
    a_i = rotate_rows(q, acc)
    if axis.slot is None:
        mean = average(a_i, np.ones(len(q)), p.window_acc * axis.rate)
    else:
        weight = axis.spans(p.join_time)
        den = axis.grid(weight)
        num = axis.grid(weight[:, None] * a_i)
        grid = np.arange(axis.size)
        # The interval each slot lies in ends at sample `closing`.
        closing = np.searchsorted(axis.slot, grid)
        hole = (den == 0.0) & (axis.dt[closing] >= p.join_time)
        for k in range(3):
            num[hole, k] = np.interp(grid[hole], axis.slot, a_i[:, k])
        den[hole] = 1.0
        x = num / np.maximum(den, np.finfo(float).tiny)[:, None]
        mean = average(x, den, p.window_acc * axis.rate)[axis.slot]
    return tilted(mean, q)


def heading(q, mag, axis, p, gaps=None, bridge=None):
    """
    ``r ⊗ q``: ``r``, about the vertical, turns the averaged horizontal field north (+y).

    A NaN row of ``mag`` (no field) weighs 0: its heading comes from the
    fields on both sides. ``gaps`` (:func:`gaps_of`; ``join`` not
    ``'none'``): the averages within each stretch between two gaps (the
    gyro's bridge across a long hole does not hold the heading); with
    ``join='solve'`` and ``bridge`` (the bridges' variances per body axis,
    (G, 3), rad²), each stretch's turn then offset by the other stretches'
    fields through the bridges (:func:`heading_offsets`).
    """
    got = field_weights(q, mag, axis, p)
    if got is None:
        return q  # no field, no heading: the strapdown's
    unit, weight = got
    has_gaps = gaps is not None and len(gaps[0]) > 0
    if has_gaps and p.join in ('local', 'chain', 'solve'):
        bounds = np.concatenate(([0], gaps[1], [len(q)]))
        mean = np.concatenate([
            average(unit[lo:hi], weight[lo:hi], p.window_mag * axis.rate,
                     (p.window_far * axis.rate, p.far_share), axis.part(lo, hi))
            for lo, hi in zip(bounds[:-1], bounds[1:])])
    else:
        mean = average(unit, weight, p.window_mag * axis.rate,
                        (p.window_far * axis.rate, p.far_share), axis)
    # The rotation by δ about z takes (sin δ, cos δ)·|h| to (0, |h|): north.
    turn = np.arctan2(mean[:, 0], mean[:, 1])
    if has_gaps and p.join == 'solve':
        turn = turn + heading_offsets(q, turn, unit, weight, axis, p, gaps, bridge)
    return turned_about_vertical(turn, q)


def heading_offsets(q, turn, unit, weight, axis, p, gaps, bridge):
    """
    rad (N,): each stretch's offset to its own heading ``turn`` (N,), all stretches at once.

    Each stretch (between two gaps) holds its own heading, ``turn`` (its
    fields averaged within it): its offset is 0, doubted by the directions'
    spread over it (``1 − R̄²``, ``R̄`` the weighted mean's length), the
    samples independent once every ``heading_tau`` s. Across each gap, the
    strapdown's heading holds up to the bridge's error about the vertical
    (``bridge`` (G, 3), rad² per body axis, turned into I): the two sides'
    turns plus their offsets should agree. The offsets minimizing both come
    from one tridiagonal linear system (:func:`tridiagonal`).
    """
    n = len(q)
    bounds = np.concatenate(([0], gaps[1], [n]))
    count = len(bounds) - 1
    su = np.add.reduceat(weight[:, None] * unit, bounds[:-1], axis=0)
    sw = np.add.reduceat(weight, bounds[:-1])
    length = np.linalg.norm(su, axis=1)
    some = (sw > 0.0) & (length > 0.0)
    spread = np.maximum(1.0 - np.square(length / np.maximum(sw, np.finfo(float).tiny)), 0.0)
    info = np.where(some, sw * axis.usual / (p.heading_tau * np.maximum(spread, _SPREAD)), 0.0)
    # The bridge's variance about I's vertical: Σ_i R_zi² v_i.
    vertical = rotation_matrices(q[gaps[1]])[:, 2, :]
    link = 1.0 / np.maximum(np.sum(np.square(vertical) * bridge, axis=1), 1e-12)
    jump = np.angle(np.exp(1j * (turn[gaps[1]] - turn[gaps[0]])))
    # Σ info c_s² + Σ link (c_{s+1} − c_s + jump)²: its normal equations.
    rhs = np.zeros(count)
    rhs[:-1] += link * jump
    rhs[1:] -= link * jump
    diagonal = info + _PRIOR + np.concatenate((link, [0.0])) + np.concatenate(([0.0], link))
    offset = tridiagonal(diagonal, -link, rhs)
    return offset[np.searchsorted(bounds, np.arange(n), side='right') - 1]


def field_weights(q, mag, axis, p):
    """
    The field's horizontal direction in I (N, 2) and each sample's weight (N,), or None.

    A sample weighs by how close its norm and dip stay to the reference's
    (``ref_time``, ``mag_sigma``) and by its share of time; 0 without a field.
    None: no horizontal field at all.
    """
    lost = np.isnan(mag[:, 0])
    norm, horizontal, vertical, unit = field_parts(q, mag)
    dip = np.arctan2(vertical, horizontal)
    if not np.any(horizontal > 0.0):
        return None
    start = (axis.slots() < max(1, int(round(p.ref_time * axis.rate)))) & ~lost
    if p.ref_time > 0.0 and start.any() and np.median(norm[start]) > 0.0:
        ref_norm = float(np.median(norm[start]))
        ref_dip = float(np.median(dip[start]))
    else:
        ref_norm, ref_dip = most_common(norm, dip, p.mag_sigma)
    z = (np.square((norm - ref_norm) / (p.mag_sigma * ref_norm))
         + np.square((dip - ref_dip) / p.mag_sigma))
    weight = np.where(lost, 0.0, np.exp(-0.5 * np.minimum(z, 1400.0)) * axis.spans(p.join_time))
    return unit, weight


_SPREAD = 1e-9
# rad⁻², a weak pull of every stretch's offset to none (no stretch with a
# field: no offsets).
_PRIOR = 1e-9


def tridiagonal(diagonal, off, rhs):
    """
    ``x`` (N,) solving the symmetric tridiagonal system ``diagonal`` (N,), ``off`` (N − 1,).

    Thomas's algorithm (the system is diagonally dominant: no pivoting).
    """
    n = len(diagonal)
    d = np.array(diagonal, dtype=float)
    r = np.array(rhs, dtype=float)
    for k in range(1, n):
        m = off[k - 1] / d[k - 1]
        d[k] -= m * off[k - 1]
        r[k] -= m * r[k - 1]
    x = np.empty(n)
    x[-1] = r[-1] / d[-1]
    for k in range(n - 2, -1, -1):
        x[k] = (r[k] - off[k] * x[k + 1]) / d[k]
    return x


def most_common(norm, dip, sigma, candidates=64, samples=20000):
    """
    The (norm, dip) that the most samples lie near: the mode, under the weights' kernel.

    The candidates are quantiles of the norm and of the dip (``candidates``
    of each); the samples (those with a field), at most about ``samples``
    evenly spread.
    """
    some = np.flatnonzero(norm > 0.0)  # a lost field's norm is 0
    some = some[::max(1, len(some) // samples)]
    n, d = norm[some], dip[some]
    pick = np.linspace(0, len(n) - 1, candidates).astype(np.int64)
    order = np.argsort(n)
    cn, cd = n[order][pick], d[order][pick]
    order = np.argsort(d)
    cn = np.concatenate((cn, n[order][pick]))
    cd = np.concatenate((cd, d[order][pick]))
    z = (np.square((n[None, :] - cn[:, None]) / (sigma * cn[:, None]))
         + np.square((d[None, :] - cd[:, None]) / sigma))
    best = int(np.argmax(np.exp(-0.5 * np.minimum(z, 1400.0)).sum(axis=1)))
    return float(cn[best]), float(cd[best])
