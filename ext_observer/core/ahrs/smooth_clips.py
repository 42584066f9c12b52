"""
The smoother and a clipped gyro: which rates are at the range, bridged, joined.

Helpers of :mod:`~ext_observer.core.ahrs.smoother`: :func:`clipped_rates`
(the samples at the range), :func:`unclipped` (each clipped stretch bridged
per axis by Hermite's cubic from both sides), :func:`clip_stretches` and
:func:`with_clips` (the stretches long enough to join, as holes are, with the
rotation each leaves unknown).
"""

import numpy as np

from .hole_kernel import CLIP_SHARE

__all__ = ['clip_stretches', 'clipped_rates', 'unclipped', 'with_clips']

# A rate within this share of the declared range is at it.
_AT_RANGE = 1e-6


def clipped_rates(gyr, p):
    """
    The rates not known (N, 3): at the gyro's range on their axis.

    At ``online.gyro_range`` where set (> 0), or at the recording's peak
    on an axis where two or more samples sit at it (a rate stuck at the
    peak: a range nobody declared).
    """
    limit = 0.0 if p.online is None else float(p.online.gyro_range)
    # One axis at a time, its sizes contiguous: numpy's reductions along a row are fast.
    clipped = np.zeros((3, len(gyr)), dtype=bool)
    size = np.empty(len(gyr))
    for axis in range(3):
        np.abs(gyr[:, axis], out=size)
        if limit > 0.0:
            clipped[axis] = size >= limit * (1.0 - _AT_RANGE)
        peak = size.max()
        if peak > 0.0:
            at_peak = size == peak
            if np.count_nonzero(at_peak) >= 2:
                clipped[axis] |= at_peak
    return clipped.T


def clip_stretches(gyr, clipped, axis, p):
    """
    The clipped stretches to join as gaps, and the rotation each leaves unknown.

    A stretch: consecutive samples with an axis at the range, from sample
    ``before + 1`` to ``after − 1``, joined as a hole is when the known
    samples beside it are at least ``join_time`` apart (a stretch at an end
    is not joined; a shorter one is bridged only, as a short hole). Per body
    axis, the online estimator's model of what a clipped axis misses
    (:data:`~ext_observer.core.ahrs.hole_kernel.CLIP_SHARE` of the range's
    rotation per clipped sample, summed along the stretch: the rate stays
    beyond the range), squared. Returns ``((before, after, length),
    variances (G, 3))``.
    """
    n = len(gyr)
    bad = clipped[:, 0] | clipped[:, 1] | clipped[:, 2]
    edges = np.diff(np.concatenate(([0], bad.astype(np.int8), [0])))
    first, last = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1) - 1
    inner = (first > 0) & (last < n - 1)
    first, last = first[inner], last[inner]
    long = axis.times[last + 1] - axis.times[first - 1] >= p.join_time
    first, last = first[long], last[long]
    if not len(first):  # none to join: no sums over the recording
        return (first - 1, last + 1, np.zeros(0)), np.zeros((0, 3))
    limit = 0.0 if p.online is None else float(p.online.gyro_range)
    top = max(limit, float(np.abs(gyr).max())) * axis.dt
    # Clipped rotation per axis along each stretch: Σ CLIP_SHARE · top · [clipped].
    c = np.concatenate((np.zeros((1, 3)), np.cumsum(clipped * top[:, None], axis=0)))
    sigma = CLIP_SHARE * (c[last + 1] - c[first])
    before, after = first - 1, last + 1
    return (before, after, axis.times[after] - axis.times[before]), np.square(sigma)


def with_clips(gaps, bridge, clip_gaps, clip_bridge):
    """
    The holes' gaps and the clipped stretches' as one ordered set, with their variances.

    A clipped stretch that overlaps a hole's gap is left out (the hole's bridge holds it).
    """
    before, after, length = gaps
    keep = np.ones(len(clip_gaps[0]), dtype=bool)
    if len(before):
        # A stretch [b, a] overlaps hole [hb, ha] unless a <= hb or b >= ha.
        at = np.searchsorted(before, clip_gaps[1], side='left')  # holes starting at/after a
        prev = np.clip(at - 1, 0, len(before) - 1)
        keep = ~((at > 0) & (after[prev] > clip_gaps[0]))
    joined = [np.concatenate((g, c[keep])) for g, c in zip(gaps, clip_gaps)]
    order = np.argsort(joined[0], kind='stable')
    return (tuple(g[order] for g in joined),
            np.concatenate((bridge, clip_bridge[keep]))[order])


def unclipped(gyr, clipped, t, reach=1):
    """
    ``gyr`` with its clipped rates (``clipped``, (N, 3)) bridged from both sides, per axis.

    Across each clipped stretch of an axis, Hermite's cubic through the
    rates beside it with their slopes (the differences to the samples
    ``reach`` before and after), at least the clipped value in size (the rate went
    beyond the range, not back). A stretch at an end keeps its values.
    """
    if not clipped.any():
        return gyr
    out = gyr.copy()
    n = len(gyr)
    index = np.arange(n)
    for axis in range(3):
        bad = clipped[:, axis]
        if not bad.any() or bad.all():
            continue
        w = gyr[:, axis]
        a = np.maximum.accumulate(np.where(bad, -1, index))[bad]
        b = np.minimum.accumulate(np.where(bad, n, index)[::-1])[::-1][bad]
        inner = (a >= 0) & (b < n)
        k, a, b = np.flatnonzero(bad)[inner], a[inner], b[inner]
        a0 = np.maximum(a - reach, 0)
        b1 = np.minimum(b + reach, n - 1)
        ma = np.where(a > a0, (w[a] - w[a0]) / (t[a] - t[a0]), 0.0)
        mb = np.where(b1 > b, (w[b1] - w[b]) / (t[b1] - t[b]), 0.0)
        span = t[b] - t[a]
        s = (t[k] - t[a]) / span
        curve = (w[a] + (w[b] - w[a]) * (s * s * (3.0 - 2.0 * s))
                 + span * (s * (1.0 - s) ** 2 * ma + s * s * (s - 1.0) * mb))
        out[k, axis] = np.sign(w[k]) * np.maximum(np.abs(curve), np.abs(w[k]))
    return out
