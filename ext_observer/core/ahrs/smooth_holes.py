"""
The smoother across holes: the gyro's bridge and the tilt joined from both sides.

Helpers of :mod:`~ext_observer.core.ahrs.smoother`: :func:`bridged` (the
strapdown's steps across a hole), :func:`gaps_of` (the holes to join),
:func:`join_tilt` (each hole's tilt from the specific force on both sides,
weighed against the bridge's doubt, :func:`bridge_variance`).
"""

import numpy as np

from ..quaternion import multiply, normalize
from .hole_kernel import (HOLE_BRIDGE_DIVISOR, HOLE_FACTOR, HOLE_RATE_CHANGE,
                          HOLE_RATE_WALK)
from .smooth_strapdown import rotate_rows, slopes, spread

__all__ = ['bridge_axes', 'bridge_variance', 'bridged', 'gaps_of', 'join_tilt', 'one_sided',
           'segment_turns', 'toward']


def bridged(gyr, axis, p):
    """
    The strapdown's steps: rates (M, 3), intervals (M,) and each sample's row in them (N,).

    A usual interval integrates its closing sample's rate, as before. An
    interval over :data:`HOLE_FACTOR` times the usual one (a hole) is
    bridged from both sides: split into steps of about the usual interval,
    each integrating the rate of a curve through the samples on either side
    (``bridge``: a straight line, or Hermite's cubic with the rate's slopes
    there, each over ``slope_time``). Without holes, the samples' own rates
    and intervals.
    """
    n = len(gyr)
    dt = axis.dt
    bridge = np.zeros(n, dtype=bool)
    bridge[1:] = dt[1:] > HOLE_FACTOR * axis.usual
    if not bridge.any():
        return gyr, dt, slice(None)
    index = np.arange(n)
    t = axis.times
    steps = np.ones(n, dtype=np.int64)
    steps[bridge] = np.maximum(1, np.rint(dt[bridge] / axis.usual).astype(np.int64))
    rows = np.cumsum(steps) - 1
    owner = np.repeat(index, steps)
    rate = gyr[owner]
    step_dt = np.repeat(dt / steps, steps)
    fine = np.flatnonzero(bridge[owner])
    k = owner[fine]
    # Each bridged step ends (i + 1) dt_k / L_k after the sample before k.
    i = fine - (rows[k] - steps[k] + 1)
    tau = t[k] - dt[k] + (i + 1) * dt[k] / steps[k]
    a, b = k - 1, k
    wa, wb = gyr[a], gyr[b]
    span = dt[k][:, None]
    s = np.clip((tau - t[a]) / dt[k], 0.0, 1.0)[:, None]
    if p.bridge == 'hermite':
        ma, mb = slopes(gyr, t, p.slope_time)
        rate[fine] = (wa + (wb - wa) * (s * s * (3.0 - 2.0 * s))
                      + span * (s * (1.0 - s) ** 2 * ma[a] + s * s * (s - 1.0) * mb[b]))
    else:
        rate[fine] = (1.0 - s) * wa + s * wb
    return rate, step_dt, rows


def gaps_of(axis, shortest):
    """
    The holes to join: ``(before, after)`` sample indices (G,) each.

    A hole: an interval at least ``shortest`` s long, from sample
    ``before`` to ``after = before + 1``.
    """
    before = np.flatnonzero(axis.dt[1:] >= shortest)
    return before, before + 1, axis.dt[before + 1]


def one_sided(x, weight, gaps, axis, window):
    """
    ``Σ w x`` and ``Σ w`` over the ``window`` s before each gap and after it (G, k), (G,).

    Each side's samples stop at the neighbouring gap.
    """
    before, after = gaps[:2]
    t = axis.times
    c = np.concatenate((np.zeros((1,) + x.shape[1:]), np.cumsum(weight[:, None] * x, axis=0)))
    cw = np.concatenate(([0.0], np.cumsum(weight)))
    prev_end = np.concatenate(([0], after[:-1]))
    next_start = np.concatenate((before[1:], [len(t) - 1]))
    lo = np.maximum(np.searchsorted(t, t[before] - window, side='left'), prev_end)
    hi = np.minimum(np.searchsorted(t, t[after] + window, side='right'), next_start + 1)
    left = (c[before + 1] - c[lo], cw[before + 1] - cw[lo])
    right = (c[hi] - c[after], cw[hi] - cw[after])
    return left, right


def segment_turns(q, turns, gaps):
    """
    ``D_s ⊗ q``: each sample after gap ``j`` turned by ``turns[0] ⊗ … ⊗ turns[j]`` (G, 4).

    ``D_{j+1} = D_j ⊗ turns[j]``: each turn is measured in the frame of
    the samples before its gap as they were (uncorrected).
    """
    before, after = gaps[:2]
    if len(before) == 0:
        return q
    total = np.empty((len(turns) + 1, 4))
    total[0] = (1.0, 0.0, 0.0, 0.0)
    for j, turn in enumerate(turns):
        total[j + 1] = normalize(multiply(total[j], turn))
    segment = np.searchsorted(after, np.arange(len(q)), side='right')
    return normalize(multiply(total[segment], q))


def bridge_variance(gyr, gaps):
    """
    rad², how unsure the gyro's bridge across each gap is (G,): the online estimator's model.

    Per axis, :data:`HOLE_RATE_CHANGE` of the rate's change across the gap
    times its length, squared, and a rate random walk's Brownian bridge
    (:func:`~ext_observer.core.ahrs.hole_kernel.hole_variance`'s terms),
    summed over the axes.
    """
    return np.sum(bridge_axes(gyr, gaps), axis=1)


def bridge_axes(gyr, gaps):
    """rad², :func:`bridge_variance` per body axis (G, 3)."""
    before, after = gaps[:2]
    return (np.square(HOLE_RATE_CHANGE * (gyr[after] - gyr[before])) * np.square(gaps[2])[:, None]
            + HOLE_RATE_WALK * gaps[2][:, None] ** 3 / HOLE_BRIDGE_DIVISOR)


def toward(turn, share):
    """Unit quaternions (G, 4) turned ``share`` (G,) of the way from identity to ``turn``."""
    half = np.arccos(np.clip(np.abs(turn[:, 0]), 0.0, 1.0)) * share
    axis = turn[:, 1:] * np.sign(turn[:, :1] + (turn[:, :1] == 0.0))
    axis = axis / np.maximum(np.linalg.norm(axis, axis=1, keepdims=True), np.finfo(float).tiny)
    return np.concatenate((np.cos(half)[:, None], np.sin(half)[:, None] * axis), axis=1)


def join_tilt(q, acc, gyr, gaps, axis, p):
    """
    ``q`` with each gap's tilt taken from both sides: the specific force in I averaged over
    ``window_acc`` s before the gap and after it, the part after turned by the smallest
    rotation that makes the two agree.
    """
    if len(gaps[0]) == 0:
        return q
    f = rotate_rows(q, acc)
    x = np.concatenate((f, np.einsum('ij,ij->i', f, f)[:, None]), axis=1)
    (sl, nl), (sr, nr) = one_sided(x, np.ones(len(q)), gaps, axis, p.window_acc)
    ul = sl[:, :3] / np.maximum(np.linalg.norm(sl[:, :3], axis=1, keepdims=True),
                                np.finfo(float).tiny)
    ur = sr[:, :3] / np.maximum(np.linalg.norm(sr[:, :3], axis=1, keepdims=True),
                                np.finfo(float).tiny)
    # The smallest rotation taking ur to ul: (1 + ur·ul, ur × ul), normalized.
    turn = normalize(np.concatenate((1.0 + np.einsum('ij,ij->i', ur, ul)[:, None],
                                     np.cross(ur, ul)), axis=1))
    # The averages' doubt: the specific force's spread over each side, its
    # samples counting as independent once every join_tau s.
    var = (spread(sl, nl) * p.join_tau / np.maximum(nl * axis.usual, axis.usual)
           + spread(sr, nr) * p.join_tau / np.maximum(nr * axis.usual, axis.usual))
    var = var / np.maximum(np.square(0.5 * (np.linalg.norm(sl[:, :3], axis=1) / np.maximum(nl, 1.0)
                                             + np.linalg.norm(sr[:, :3], axis=1)
                                             / np.maximum(nr, 1.0))), np.finfo(float).tiny)
    bridge = bridge_variance(gyr, gaps)
    share = bridge / np.maximum(bridge + var, np.finfo(float).tiny)
    return segment_turns(q, toward(turn, share), gaps)
