"""
Each sample's attitude from the whole recording: :func:`smooth_attitude`.

A strapdown integration corrected by zero-phase averages: offline VQF's
decomposition (D. Laidig, T. Seel, "VQF: Highly accurate IMU orientation
estimation with bias estimation and magnetic disturbance rejection",
Information Fusion 2023, arXiv:2203.17024, and ``offline_vqf.cpp`` of the
``vqf`` package), with our estimator in it:

1. the gyro bias from our online estimator
   (:class:`~ext_observer.core.ahrs.ahrs_observer.AhrsObserver`): its
   estimate at the end of the recording, or (``bias='both'``) each
   sample's from the passes over the recording and over the time-reversed
   one, the two (of disjoint data) weighted by their variances;
2. the strapdown attitude ``q_g`` with that bias (body → a slowly drifting
   frame I);
3. the inclination: the specific force in I averaged over a window centred
   on each sample (a uniform weight in time: the body's linear acceleration
   averages to its change of velocity over the window), turned to the
   vertical;
4. the heading (9D): the field (with the online pass's calibration where it
   applied one, from the first sample on) in the inclination-corrected
   frame, its horizontal direction averaged over a wider window, each
   sample weighted by how close its norm and dip stay to the field's at the
   start of the recording, turned north.

With ``times`` (samples lost, unevenly spaced): the strapdown integrates each
interval with its own length and bridges a hole (an interval over 1.5× the
usual one) with the rate on the straight line between its two samples; the
windows run on an even grid in time, a lost sample's time shared by its
neighbours and a longer hole holding no data (the inclination's: the force in
I on the line across it); after a hole of at least ``join_time``, the tilt
is joined from both sides (the specific force averaged on either side, weighed
against the bridge's doubt) and each stretch's heading is solved from all
stretches' fields at once, through the bridges. A NaN row of the field weighs
nothing; a gyro axis at its range is bridged across the clipped stretch
(Hermite's cubic from both sides).
docs/offline.md ("Holes, lost fields and clipped stretches") has the figures.

The windows are Gaussian-like (three box filters, cumulative sums), symmetric
in time, so without delay; everything but the online passes is numpy on
whole arrays. Conventions as the estimator's: ``(w, x, y, z)``, sensor →
ENU, SI units. What each step gave on BROAD: docs/offline.md.
"""

import dataclasses
import math
import os

import numpy as np

from ..quaternion import multiply, normalize, quaternion_from_rotation_vector
from .ahrs_filters import quat_multiply, rotate
from .ahrs_observer import AhrsObserver
from .ahrs_params import AhrsParams
from .compiled import compiled_name, wanted
from .hole_kernel import (HOLE_BRIDGE_DIVISOR, HOLE_FACTOR, HOLE_RATE_CHANGE,
                          HOLE_RATE_WALK)

__all__ = ['SmoothParams', 'smooth_attitude']


@dataclasses.dataclass(frozen=True)
class SmoothParams:
    """
    The smoother's settings (physical units; defaults chosen on BROAD's tuning trials).

    Attributes
    ----------
    window_acc : float
        s, σ of the window that averages the specific force in I.
    window_mag : float
        s, σ of the window that averages the field's horizontal direction.
    window_far : float
        s, σ of a wider window for the heading, for where the near one
        holds only disturbed fields.
    far_share : float
        How much the wider window's samples count against the near one's
        (per unit of window weight).
    mag_sigma : float
        A field sample whose norm deviates from the reference by this
        fraction (or whose dip does by this many rad) weighs ``exp(−1/2)``
        as much as an undisturbed one.
    ref_time : float
        s, the start of the recording that gives the field's reference
        norm and dip (its medians); 0: the most common norm and dip of the
        whole recording instead (for a recording that may start in a
        disturbed field).
    delay : float
        s, how late the sensor's samples are on the motion (e.g. the group
        delay of its low-pass filters): each sample's attitude is read
        this much later on the smoothed one, as only a smoother can. 0:
        none.
    bias : {'end', 'both'}
        The gyro bias: the online pass's at its end, for every sample; or
        each sample's from the passes over the recording and over the
        time-reversed one (for a bias that wanders; twice the time).
    bias_chunk : float
        s between two readings of the online passes' bias estimates
        (``bias='both'``).
    bridge : {'hermite', 'linear'}
        The rate across a hole or a clipped stretch: Hermite's cubic
        through the known samples on both sides with the rate's slopes
        there, or the straight line between them.
    slope_time : float
        s over which the rate's slope beside a bridge is taken.
    unclip : bool
        Bridge each gyro axis across its clipped stretches (at
        ``online.gyro_range``, or stuck at the recording's peak) from both
        sides (:func:`_unclipped`); False: the clipped rates as given.
    join : {'solve', 'chain', 'local', 'none'}
        What a hole of at least ``join_time`` changes beyond the gyro's
        bridge. ``'chain'``: the part after it is tilted to make the
        specific force averaged over ``window_acc`` s on either side agree
        (:func:`_join_tilt`, weighed against the bridge), and the heading
        (9D) is averaged within each stretch between such holes;
        ``'solve'``: as ``'chain'``, each stretch's heading then offset
        by all the others' fields through the bridges, solved at once
        (:func:`_heading_offsets`);
        ``'local'``: the inclination too is averaged within each stretch;
        ``'none'``: the bridge only, the windows across the holes.
    join_time : float
        s: the shortest hole that ``join`` treats; a shorter one's samples
        share its time in the windows (a lost sample: its neighbours'),
        a longer one is no data.
    join_tau : float
        s: the specific force's samples beside a hole count as independent
        once every ``join_tau`` (the doubt of the join's averages, weighed
        against the gyro bridge's, :func:`_bridge_variance`).
    heading_tau : float
        s: the field's directions within a stretch count as independent
        once every ``heading_tau`` (the doubt of a stretch's heading,
        weighed against the bridges', ``join='solve'``).
    online : AhrsParams or None
        The online passes' parameters (default: the shipped defaults).

    """

    window_acc: float = 2.0
    window_mag: float = 30.0
    window_far: float = 300.0
    far_share: float = 0.01
    mag_sigma: float = 0.02
    ref_time: float = 2.0
    bias: str = 'end'
    delay: float = 0.0
    bias_chunk: float = 0.5
    bridge: str = 'linear'
    slope_time: float = 0.02
    unclip: bool = True
    join: str = 'solve'
    join_time: float = 0.05
    join_tau: float = 0.01
    heading_tau: float = 0.1
    online: AhrsParams = None

    def __post_init__(self):
        for name in ('window_acc', 'window_mag', 'window_far', 'mag_sigma', 'bias_chunk'):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f'{name} must be positive and finite, got {value}')
        if not (math.isfinite(self.ref_time) and self.ref_time >= 0.0):
            raise ValueError(f'ref_time must be finite and ≥ 0, got {self.ref_time}')
        if not math.isfinite(self.delay):
            raise ValueError(f'delay must be finite, got {self.delay}')
        if self.bridge not in ('linear', 'hermite'):
            raise ValueError(f"bridge must be 'linear' or 'hermite', got {self.bridge!r}")
        if self.join not in ('solve', 'chain', 'local', 'none'):
            raise ValueError(
                f"join must be 'solve', 'chain', 'local' or 'none', got {self.join!r}")
        if not self.join_time > 0.0:
            raise ValueError(f'join_time must be positive, got {self.join_time}')
        if not (math.isfinite(self.heading_tau) and self.heading_tau > 0.0):
            raise ValueError(f'heading_tau must be positive and finite, got {self.heading_tau}')
        if not (math.isfinite(self.join_tau) and self.join_tau > 0.0):
            raise ValueError(f'join_tau must be positive and finite, got {self.join_tau}')
        if not (math.isfinite(self.slope_time) and self.slope_time >= 0.0):
            raise ValueError(f'slope_time must be finite and ≥ 0, got {self.slope_time}')
        if self.bias not in ('end', 'both'):
            raise ValueError(f"bias must be 'end' or 'both', got {self.bias!r}")
        if not (math.isfinite(self.far_share) and self.far_share >= 0.0):
            raise ValueError(f'far_share must be finite and ≥ 0, got {self.far_share}')


def smooth_attitude(gyr, acc, mag, rate=None, params=None, *, times=None):
    """
    Each sample's attitude from the whole recording (a smoothed estimate).

    Parameters
    ----------
    gyr : array_like, shape (N, 3)
        Angular rate, rad/s, body frame.
    acc : array_like, shape (N, 3)
        Specific force, m/s² (points up at rest).
    mag : array_like, shape (N, 3), or None
        Magnetic field (any unit); a row with a NaN: no field at that sample
        (its heading bridged from both sides). None: 6D (the heading follows
        the gyro from the online estimator's first attitude).
    rate : float, optional
        Sampling rate, Hz (samples evenly spaced); or ``times``.
    params : SmoothParams, optional
    times : array_like, shape (N,), optional
        Each sample's time, s, increasing (instead of ``rate``): the
        strapdown integrates each interval with its own length, the windows
        run in time (a lost stretch holds no data), and a hole (an interval
        over 1.5× the usual one) is bridged from both sides.

    Returns
    -------
    q : ndarray, shape (N, 4)
        Unit quaternions ``(w, x, y, z)``, sensor → ENU.
    cov : None
        No covariance yet (the return keeps its place).

    Raises
    ------
    ValueError
        For arrays of another shape, non-finite samples, a bad rate or bad
        times.

    Notes
    -----
    Samples at the gyro's range (``online.gyro_range``, or a rate stuck at
    the recording's peak on an axis) are a rotation not known: bridged from
    both sides as a hole.

    """
    p = params if params is not None else SmoothParams()
    gyr, acc, mag, axis = _checked(gyr, acc, mag, rate, times)
    bias, first, calibration = _bias(gyr, acc, mag, axis.dt, p)
    if p.unclip:
        gyr = _unclipped(gyr, _clipped(gyr, p), axis.times,
                         max(1, int(round(p.slope_time / axis.usual))))
    rate, dt, rows = _bridged(gyr - bias, axis, p)
    q = _strapdown(rate, dt, first)[rows]
    gaps = _gaps(axis, p.join_time)
    if p.join in ('solve', 'chain'):
        q = _inclination(_join_tilt(q, acc, gyr - bias, gaps, axis, p), acc, axis, p)
    elif p.join == 'local' and len(gaps[0]):
        bounds = np.concatenate(([0], gaps[1], [len(q)]))
        q = np.concatenate([_inclination(q[lo:hi], acc[lo:hi], axis.part(lo, hi), p)
                            for lo, hi in zip(bounds[:-1], bounds[1:])])
    else:
        q = _inclination(q, acc, axis, p)
    if mag is not None:
        bridge = (_bridge_axes(gyr - bias, gaps) if p.join == 'solve' and len(gaps[0])
                  else None)
        q = _heading(q, calibration(mag), axis, p, gaps, bridge)
    if p.delay:
        q = _ahead(q, p.delay, axis)
    return q, None


def _ahead(q, delay, axis):
    """
    ``q`` read ``delay`` s later (may be negative), held at the ends.

    Between two samples, the normalized linear interpolation (the steps are
    small).
    """
    n = len(q)
    if axis.slot is None:
        at = np.arange(n) + delay * axis.rate
    else:
        at = np.interp(axis.times + delay, axis.times, np.arange(n, dtype=float))
    at = np.clip(at, 0.0, n - 1.0)
    lo = np.minimum(np.floor(at).astype(np.int64), n - 2)
    frac = (at - lo)[:, None]
    a, b = q[lo], q[lo + 1]
    b = np.where(np.einsum('ij,ij->i', a, b)[:, None] < 0.0, -b, b)
    return normalize((1.0 - frac) * a + frac * b)


class _Axis:
    """
    The samples' time axis: each one's interval and its slot on an even grid.

    Attributes
    ----------
    dt : ndarray, shape (N,)
        s, the interval that ends at each sample (the first: the usual one).
    usual : float
        s, the usual interval (the median).
    rate : float
        Hz, ``1 / usual``.
    slot : ndarray of int, shape (N,) or None
        Each sample's index on the grid of ``usual`` steps from the first;
        None: the samples are the grid (evenly spaced).
    size : int
        The grid's length.
    times : ndarray, shape (N,)
        s, from the first sample.

    """

    def __init__(self, dt, slot=None, rate=None):
        self.dt = dt
        self.usual = float(dt[0])
        self.rate = 1.0 / self.usual if rate is None else float(rate)
        self.slot = slot
        self.size = len(dt) if slot is None else int(slot[-1]) + 1
        self.times = np.concatenate(([0.0], np.cumsum(dt[1:])))

    def grid(self, x):
        """``x`` (N, ...) summed onto the grid (size, ...): empty slots hold 0."""
        if self.slot is None:
            return x
        out = np.zeros((self.size,) + x.shape[1:])
        np.add.at(out, self.slot, x)
        return out

    def samples(self, x):
        """The grid's ``x`` (size, ...) read back at the samples (N, ...)."""
        return x if self.slot is None else x[self.slot]

    def part(self, lo, hi):
        """The axis of samples ``lo:hi``."""
        dt = self.dt[lo:hi].copy()
        dt[0] = self.usual
        if self.slot is None:
            return _Axis(dt, rate=self.rate)
        part = _Axis(dt, self.slot[lo:hi] - self.slot[lo])
        part.usual, part.rate = self.usual, self.rate
        return part

    def spans(self, longest):
        """
        Each sample's share of time in usual intervals (N,): half its intervals on both sides.

        An interval over ``longest`` s counts as none (a hole: no data); a
        shorter one as its length (a lost sample's time shared by its
        neighbours, as the trapezoid's rule does). Evenly spaced: ones.
        """
        if self.slot is None:
            return np.ones(len(self.dt))
        dt = np.where(self.dt[1:] < longest, self.dt[1:], 0.0)
        return (np.concatenate(([self.usual], dt)) + np.concatenate((dt, [self.usual]))) / (
            2.0 * self.usual)

    def slots(self):
        """Each sample's slot on the grid (N,)."""
        return np.arange(len(self.dt)) if self.slot is None else self.slot


# Intervals within this share of the usual one are the usual one (times
# rounded to a clock's tick or to floating point).
_EVEN = 1e-6


def _checked(gyr, acc, mag, rate, times=None):
    gyr = np.asarray(gyr, dtype=float)
    acc = np.asarray(acc, dtype=float)
    arrays = [('gyr', gyr), ('acc', acc)]
    if mag is not None:
        mag = np.asarray(mag, dtype=float)
        arrays.append(('mag', mag))
    for name, a in arrays:
        if a.ndim != 2 or a.shape[1] != 3:
            raise ValueError(f'{name} must have shape (N, 3), got {a.shape}')
        if a.shape[0] != gyr.shape[0]:
            raise ValueError(f'{name} has {a.shape[0]} samples, gyr {gyr.shape[0]}')
        if name == 'mag':
            # A NaN anywhere in a row: no field at that sample.
            if np.isinf(a).any():
                raise ValueError('mag has infinite samples (NaN rows: no field)')
            mag = np.where(np.isnan(a).any(axis=1, keepdims=True), np.nan, a)
        elif not np.isfinite(a).all():
            raise ValueError(f'{name} has non-finite samples')
    n = len(gyr)
    if n < 2:
        raise ValueError(f'a recording needs at least 2 samples, got {n}')
    if (rate is None) == (times is None):
        raise ValueError('give either rate or times, not both or neither')
    if times is None:
        if not (math.isfinite(rate) and rate > 0.0):
            raise ValueError(f'rate must be positive and finite, got {rate}')
        return gyr, acc, mag, _Axis(np.full(n, 1.0 / float(rate)), rate=rate)
    times = np.asarray(times, dtype=float)
    if times.shape != (n,):
        raise ValueError(f'times must have shape ({n},), got {times.shape}')
    if not np.isfinite(times).all():
        raise ValueError('times has non-finite values')
    dt = np.diff(times)
    if not (dt > 0.0).all():
        raise ValueError('times must increase strictly')
    usual = float(np.median(dt))
    dt = np.where(np.abs(dt - usual) <= _EVEN * usual, usual, dt)
    dt = np.concatenate(([usual], dt))
    if (dt == usual).all():
        return gyr, acc, mag, _Axis(dt)
    slot = np.rint((times - times[0]) / usual).astype(np.int64)
    return gyr, acc, mag, _Axis(dt, slot)


def _clipped(gyr, p):
    """
    The rates not known (N, 3): at the gyro's range on their axis.

    At ``online.gyro_range`` where set (> 0), or at the recording's peak
    on an axis where two or more samples sit at it (a rate stuck at the
    peak: a range nobody declared).
    """
    size = np.abs(gyr)
    clipped = np.zeros(gyr.shape, dtype=bool)
    limit = 0.0 if p.online is None else float(p.online.gyro_range)
    if limit > 0.0:
        clipped |= size >= limit * (1.0 - _EVEN)
    peak = size.max(axis=0)
    at_peak = (size == peak) & (peak > 0.0)
    clipped |= at_peak & (at_peak.sum(axis=0) >= 2)
    return clipped


def _unclipped(gyr, clipped, t, reach=1):
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


def _online(est, gyr, acc, mag, dt, start=0, end=None):
    """
    ``est`` over samples ``start:end``, each step fed its own interval ``dt[k]`` (s).

    One call of the kernels' loop per run of samples of one interval and
    with a field or without (a NaN row of ``mag``: that sample's field is not
    given). Returns the estimates (end − start, 4).
    """
    end = len(gyr) if end is None else end
    has = None if mag is None else ~np.isnan(mag[:, 0])
    change = np.flatnonzero((dt[start + 1:end] != dt[start:end - 1])
                            | (False if has is None else has[start + 1:end] != has[start:end - 1]))
    bounds = np.concatenate(([start], start + 1 + change, [end]))
    out = np.empty((end - start, 4))
    for lo, hi in zip(bounds[:-1], bounds[1:]):
        field = None if has is None or not has[lo] else mag[lo:hi]
        out[lo - start:hi - start] = est.run(gyr[lo:hi], acc[lo:hi], field, float(dt[lo]))
    return out


def _bias_pass(gyr, acc, mag, dt, p):
    """
    The online estimator over the recording, its bias read every ``bias_chunk``.

    ``dt`` (N,): each sample's interval. Returns the sample index of each
    reading (K,), the biases (K, 3), their variances (K, 3), the first
    estimate (4,) and the estimator (its state at the end).
    """
    est = AhrsObserver(p.online, use_mag=mag is not None)
    n = len(gyr)
    step = max(1, int(round(p.bias_chunk / dt[0])))
    ends = np.append(np.arange(step, n, step), n)
    biases, variances = np.empty((len(ends), 3)), np.empty((len(ends), 3))
    start, first = 0, None
    for i, end in enumerate(ends):
        q = _online(est, gyr, acc, mag, dt, start, end)
        if first is None:
            first = q[0]
        biases[i] = est.bias
        variances[i] = np.square(est.bias_std)
        start = end
    return ends - 1, biases, variances, first, est


def _bias(gyr, acc, mag, dt, p):
    """
    The gyro bias (N, 3) or (3,), the first attitude and the field's calibration.

    ``dt``: the interval (s) before each sample (N,), or one for all.
    ``bias='end'``: one online pass; its bias at the end (it has seen the
    whole recording) for every sample. ``'both'``: :func:`_bias_both_ways`.
    """
    dt = np.broadcast_to(np.asarray(dt, dtype=float), (len(gyr),))
    if p.bias == 'both':
        return _bias_both_ways(gyr, acc, mag, dt, p)
    est = AhrsObserver(p.online, use_mag=mag is not None)
    q = _online(est, gyr, acc, mag, dt)
    return np.array(est.bias), q[0], _calibration(est)


def _bias_both_ways(gyr, acc, mag, dt, p):
    """
    The bias at each sample from the recording up to it and after it.

    Time-reversed, the gyro reads ``−ω − b``: the reversed pass's bias is
    negated back. Each sample takes the variance-weighted mean of the two
    (VQF's offline form does so with its own filter). Also returns the
    forward pass's first estimate and the field's calibration (a function
    of the raw field).
    """
    n = len(gyr)
    index_f, b_f, v_f, first, forward = _bias_pass(gyr, acc, mag, dt, p)
    # Reversed, the interval before sample j is the one after sample n − 1 − j.
    back_dt = np.concatenate((dt[:1], dt[1:][::-1]))
    index_b, b_b, v_b, _, _ = _bias_pass(-gyr[::-1], acc[::-1],
                                         None if mag is None else mag[::-1], back_dt, p)
    # Reading i of the reversed pass holds the samples from n − 1 − index_b[i] on.
    index_b = (n - 1 - index_b)[::-1]
    b_b, v_b = -b_b[::-1], v_b[::-1]
    samples = np.arange(n)
    bias = np.empty((n, 3))
    for axis in range(3):
        bf = np.interp(samples, index_f, b_f[:, axis])
        vf = np.interp(samples, index_f, v_f[:, axis])
        bb = np.interp(samples, index_b, b_b[:, axis])
        vb = np.interp(samples, index_b, v_b[:, axis])
        bias[:, axis] = (bf * vb + bb * vf) / (vf + vb)
    return bias, first, _calibration(forward)


def _calibration(est):
    """
    The raw field → the calibrated field, by the online pass's calibration at its end.

    That calibration has seen the whole recording; it applies from the first
    sample. Where the online pass applied none (off, or not worth applying:
    ``mag_cal_deadband``), the field as given.
    """
    cal = est.calibration
    if cal is None or not cal.applied:
        return lambda mag: mag
    inverse = np.linalg.inv(cal.soft_iron)
    offset = cal.bias
    return lambda mag: (mag - offset) @ inverse.T


def _bridged(gyr, axis, p):
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
        ma, mb = _slopes(gyr, t, p.slope_time)
        rate[fine] = (wa + (wb - wa) * (s * s * (3.0 - 2.0 * s))
                      + span * (s * (1.0 - s) ** 2 * ma[a] + s * s * (s - 1.0) * mb[b]))
    else:
        rate[fine] = (1.0 - s) * wa + s * wb
    return rate, step_dt, rows


def _gaps(axis, shortest):
    """
    The holes to join: ``(before, after)`` sample indices (G,) each.

    A hole: an interval at least ``shortest`` s long, from sample
    ``before`` to ``after = before + 1``.
    """
    before = np.flatnonzero(axis.dt[1:] >= shortest)
    return before, before + 1, axis.dt[before + 1]


def _one_sided(x, weight, gaps, axis, window):
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


def _segment_turns(q, turns, gaps):
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


def _bridge_variance(gyr, gaps):
    """
    rad², how unsure the gyro's bridge across each gap is (G,): the online estimator's model.

    Per axis, :data:`HOLE_RATE_CHANGE` of the rate's change across the gap
    times its length, squared, and a rate random walk's Brownian bridge
    (:func:`~ext_observer.core.ahrs.hole_kernel.hole_variance`'s terms),
    summed over the axes.
    """
    return np.sum(_bridge_axes(gyr, gaps), axis=1)


def _bridge_axes(gyr, gaps):
    """rad², :func:`_bridge_variance` per body axis (G, 3)."""
    before, after = gaps[:2]
    return (np.square(HOLE_RATE_CHANGE * (gyr[after] - gyr[before])) * np.square(gaps[2])[:, None]
            + HOLE_RATE_WALK * gaps[2][:, None] ** 3 / HOLE_BRIDGE_DIVISOR)


def _toward(turn, share):
    """Unit quaternions (G, 4) turned ``share`` (G,) of the way from identity to ``turn``."""
    half = np.arccos(np.clip(np.abs(turn[:, 0]), 0.0, 1.0)) * share
    axis = turn[:, 1:] * np.sign(turn[:, :1] + (turn[:, :1] == 0.0))
    axis = axis / np.maximum(np.linalg.norm(axis, axis=1, keepdims=True), np.finfo(float).tiny)
    return np.concatenate((np.cos(half)[:, None], np.sin(half)[:, None] * axis), axis=1)


def _join_tilt(q, acc, gyr, gaps, axis, p):
    """
    ``q`` with each gap's tilt taken from both sides: the specific force in I averaged over
    ``window_acc`` s before the gap and after it, the part after turned by the smallest
    rotation that makes the two agree.
    """
    if len(gaps[0]) == 0:
        return q
    f = _rotate(q, acc)
    x = np.concatenate((f, np.einsum('ij,ij->i', f, f)[:, None]), axis=1)
    (sl, nl), (sr, nr) = _one_sided(x, np.ones(len(q)), gaps, axis, p.window_acc)
    ul = sl[:, :3] / np.maximum(np.linalg.norm(sl[:, :3], axis=1, keepdims=True),
                                np.finfo(float).tiny)
    ur = sr[:, :3] / np.maximum(np.linalg.norm(sr[:, :3], axis=1, keepdims=True),
                                np.finfo(float).tiny)
    # The smallest rotation taking ur to ul: (1 + ur·ul, ur × ul), normalized.
    turn = normalize(np.concatenate((1.0 + np.einsum('ij,ij->i', ur, ul)[:, None],
                                     np.cross(ur, ul)), axis=1))
    # The averages' doubt: the specific force's spread over each side, its
    # samples counting as independent once every join_tau s.
    var = (_spread(sl, nl) * p.join_tau / np.maximum(nl * axis.usual, axis.usual)
           + _spread(sr, nr) * p.join_tau / np.maximum(nr * axis.usual, axis.usual))
    var = var / np.maximum(np.square(0.5 * (np.linalg.norm(sl[:, :3], axis=1) / np.maximum(nl, 1.0)
                                             + np.linalg.norm(sr[:, :3], axis=1)
                                             / np.maximum(nr, 1.0))), np.finfo(float).tiny)
    bridge = _bridge_variance(gyr, gaps)
    share = bridge / np.maximum(bridge + var, np.finfo(float).tiny)
    return _segment_turns(q, _toward(turn, share), gaps)


def _matrices(q):
    """The rotation matrices (N, 3, 3) of unit quaternions ``q`` (N, 4)."""
    w, x, y, z = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
    return np.stack((
        np.stack((1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)), axis=1),
        np.stack((2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)), axis=1),
        np.stack((2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)), axis=1)),
        axis=1)


def _spread(s, count):
    """The mean squared deviation from their mean of vectors given by sums ``(Σx, Σ|x|²)``."""
    count = np.maximum(count, 1.0)
    mean = s[:, :-1] / count[:, None]
    return np.maximum(s[:, -1] / count - np.einsum('ij,ij->i', mean, mean), 0.0)


def _slopes(gyr, t, span):
    """
    The rate's slope (rad/s²) ending at each sample and starting at it (N, 3) each.

    The difference to the sample about ``span`` s before (after); 0 where
    there is none.
    """
    index = np.arange(len(gyr))
    tk, wk = t, gyr
    back = np.searchsorted(tk, tk - span, side='right') - 1
    ahead = np.searchsorted(tk, tk + span, side='left')
    back = np.where(back >= np.arange(len(tk)), np.arange(len(tk)) - 1, back)
    ahead = np.where(ahead <= np.arange(len(tk)), np.arange(len(tk)) + 1, ahead)
    out_back, out_ahead = np.zeros_like(gyr), np.zeros_like(gyr)
    ok = back >= 0
    out_back[index[ok]] = (wk[ok] - wk[back[ok]]) / (tk[ok] - tk[back[ok]])[:, None]
    ok = ahead < len(tk)
    out_ahead[index[ok]] = (wk[ahead[ok]] - wk[ok]) / (tk[ahead[ok]] - tk[ok])[:, None]
    return out_back, out_ahead


def _strapdown(rate, dt, first):
    """
    ``q_k = q_{k−1} ⊗ exp(ω_k dt_k / 2)`` from ``q_0 = first``, each normalized.

    ``dt``: s, one for all steps or each step's (N,).

    One compiled loop where numba is wanted (:func:`_integrate`); else
    :func:`_strapdown_blocked`, numpy on whole arrays. The two agree to
    rounding.
    """
    loop = _compiled_loop()
    if loop is None:
        return _strapdown_blocked(rate, dt, first)
    out = np.empty((len(rate), 4))
    first = normalize(np.asarray(first, dtype=float))
    dt = np.ascontiguousarray(np.broadcast_to(np.asarray(dt, dtype=float), (len(rate),)))
    loop(np.ascontiguousarray(rate, dtype=float), dt, first[0], first[1], first[2],
         first[3], out)
    return out


def _strapdown_blocked(rate, dt, first):
    """
    :func:`_strapdown` on whole arrays: a blocked scan.

    The running products within blocks of about √N samples (one product per
    column, over all blocks at once), then the blocks' running products, then
    each block's products from its start's.
    """
    n = len(rate)
    dt = np.broadcast_to(np.asarray(dt, dtype=float), (n,))
    step = quaternion_from_rotation_vector(rate * dt[:, None])
    step[0] = normalize(np.asarray(first, dtype=float))
    size = max(1, int(math.ceil(math.sqrt(n))))
    blocks = -(-n // size)
    padded = np.zeros((blocks * size, 4))
    padded[:, 0] = 1.0
    padded[:n] = step
    # Column j holds the j-th sample of every block, contiguous.
    within = np.ascontiguousarray(padded.reshape(blocks, size, 4).transpose(1, 0, 2))
    for j in range(1, size):
        within[j] = multiply(within[j - 1], within[j])
    before = np.empty((blocks, 4))
    before[0] = (1.0, 0.0, 0.0, 0.0)
    for i in range(1, blocks):
        before[i] = multiply(before[i - 1], within[-1, i - 1])
    q = multiply(before[None, :, :], within).transpose(1, 0, 2).reshape(-1, 4)[:n]
    return normalize(q)


def _integrate(rate, dt, w, x, y, z, out):
    """
    The strapdown loop over samples: ``q_k`` into ``out`` (N, 4) from ``q_0 = (w, x, y, z)``.

    ``dt`` (N,): each step's interval, s.

    Compiled by :func:`_compiled_loop` (``_product``: the kernels' quaternion
    product, compiled).
    """
    out[0, 0], out[0, 1], out[0, 2], out[0, 3] = w, x, y, z
    for k in range(1, rate.shape[0]):
        vx, vy, vz = rate[k, 0] * dt[k], rate[k, 1] * dt[k], rate[k, 2] * dt[k]
        angle = math.sqrt(vx * vx + vy * vy + vz * vz)
        # sin(a / 2) / a, its limit 1/2 below a rounding error's angle.
        s = math.sin(0.5 * angle) / angle if angle > 1e-8 else 0.5
        w, x, y, z = _product(w, x, y, z, math.cos(0.5 * angle), s * vx, s * vy, s * vz)
        scale = 1.0 / math.sqrt(w * w + x * x + y * y + z * z)
        w, x, y, z = w * scale, x * scale, y * scale, z * scale
        out[k, 0], out[k, 1], out[k, 2], out[k, 3] = w, x, y, z


_product = quat_multiply
_LOOP = []


def _compiled_loop():
    """
    :func:`_integrate` compiled by numba, or None where numba is not wanted.

    Cached on disk beside the kernels' compiled code, in a folder of its own
    (the kernels' twin of ``quat_multiply`` has the same file and name) for
    this version of the kernel files
    (:func:`~ext_observer.core.ahrs.compiled.compiled_name`).
    """
    global _product
    if not _LOOP:
        loop = None
        if wanted(None)[0]:
            import numba
            name, folder = compiled_name()
            saved = numba.config.CACHE_DIR
            numba.config.CACHE_DIR = os.path.join(folder, f'{name}_smoother')
            try:
                _product = numba.njit(cache=True)(quat_multiply)
                loop = numba.njit(cache=True)(_integrate)
            finally:
                numba.config.CACHE_DIR = saved
        _LOOP.append(loop)
    return _LOOP[0]


def _rotate(q, v):
    """
    The vectors ``v`` (N, 3) rotated by the quaternions ``q`` (N, 4): ``q ⊗ v ⊗ q̄ / |q|²``.

    The kernels' rotation (:func:`~ext_observer.core.ahrs.ahrs_filters.rotate`),
    on columns.
    """
    out = np.empty((len(v), 3))
    out[:, 0], out[:, 1], out[:, 2] = rotate(q[:, 0], q[:, 1], q[:, 2], q[:, 3],
                                             v[:, 0], v[:, 1], v[:, 2])
    return out


def _about_vertical(angle):
    """Unit quaternions (N, 4) of rotations by ``angle`` (N,) rad about the world's z axis."""
    r = np.zeros((len(angle), 4))
    r[:, 0] = np.cos(0.5 * angle)
    r[:, 3] = np.sin(0.5 * angle)
    return r


def _box(x, h):
    """Sums of ``x`` (along axis 0) over ``[k − h, k + h]`` at each sample ``k``, truncated."""
    n = len(x)
    c = np.empty((n + 2 * h + 1,) + x.shape[1:])
    c[:h + 1] = 0.0
    np.cumsum(x, axis=0, out=c[h + 1:n + h + 1])
    c[n + h + 1:] = c[n + h]
    # c[h + 1 + k] is the sum up to sample k; before the first, 0; past the last, all.
    return c[2 * h + 1:] - c[:n]


def _sums(x, weight, sigma_samples, axis=None):
    """
    ``Σ K w x`` and ``Σ K w`` over a Gaussian-like window ``K`` of σ samples.

    Three centred box filters of ``2 h + 1`` samples (``h`` ≈ σ: a window of
    variance σ²), applied alike to ``weight x`` and ``weight``: zero phase,
    truncated at the ends. ``axis`` (:class:`_Axis`): on its even grid, in
    usual intervals (a lost sample: a slot of weight 0), read back at the
    samples.
    """
    h = max(1, int(round(sigma_samples)))
    num = weight[:, None] * x
    den = weight
    if axis is not None:
        num, den = axis.grid(num), axis.grid(den)
    for _ in range(3):
        num = _box(num, h)
        den = _box(den, h)
    if axis is not None:
        num, den = axis.samples(num), axis.samples(den)
    return num, den


def _average(x, weight, sigma_samples, far=None, axis=None):
    """
    The weighted mean of ``x`` (N, k) over a window of σ samples around each.

    ``far``: ``(σ_far, share)``, a second, wider window whose weights count
    ``share`` as much (per unit of window weight): where the near window
    holds no weight, the far one decides. ``axis``: the windows in time
    (:func:`_sums`), σ in usual intervals.
    """
    num, den = _sums(x, weight, sigma_samples, axis)
    if far is not None and far[1] > 0.0:
        num_far, den_far = _sums(x, weight, far[0], axis)
        scale = far[1] * sigma_samples / far[0]
        num = num + scale * num_far
        den = den + scale * den_far
    return num / np.maximum(den, np.finfo(float).tiny)[:, None]


def _inclination(q, acc, axis, p):
    """
    ``c ⊗ q``: ``c``, the smallest rotation turning the averaged specific force in I up.

    With samples lost (``axis.slot``), a sample weighs its share of time
    (:meth:`_Axis.spans`), and the slots of each hole of at least
    ``join_time`` hold the force in I on the straight line between the
    hole's two samples: the window weighs time uniformly across the hole
    too, so that the body's linear acceleration still averages to its change
    of velocity over the window.
    """
    a_i = _rotate(q, acc)
    if axis.slot is None:
        mean = _average(a_i, np.ones(len(q)), p.window_acc * axis.rate)
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
        mean = _average(x, den, p.window_acc * axis.rate)[axis.slot]
    up = mean / np.linalg.norm(mean, axis=1, keepdims=True)
    # (1 + up·z, up × z) normalized: the rotation by the angle between up and z about up × z.
    c = np.stack((1.0 + up[:, 2], up[:, 1], -up[:, 0], np.zeros(len(up))), axis=1)
    return normalize(multiply(normalize(c), q))


def _heading(q, mag, axis, p, gaps=None, bridge=None):
    """
    ``r ⊗ q``: ``r``, about the vertical, turns the averaged horizontal field north (+y).

    A NaN row of ``mag`` (no field) weighs 0: its heading comes from the
    fields on both sides. ``gaps`` (:func:`_gaps`; ``join`` not
    ``'none'``): the averages within each stretch between two gaps (the
    gyro's bridge across a long hole does not hold the heading); with
    ``join='solve'`` and ``bridge`` (the bridges' variances per body axis,
    (G, 3), rad²), each stretch's turn then offset by the other stretches'
    fields through the bridges (:func:`_heading_offsets`).
    """
    got = _field_weights(q, mag, axis, p)
    if got is None:
        return q  # no field, no heading: the strapdown's
    unit, weight = got
    has_gaps = gaps is not None and len(gaps[0]) > 0
    if has_gaps and p.join in ('local', 'chain', 'solve'):
        bounds = np.concatenate(([0], gaps[1], [len(q)]))
        mean = np.concatenate([
            _average(unit[lo:hi], weight[lo:hi], p.window_mag * axis.rate,
                     (p.window_far * axis.rate, p.far_share), axis.part(lo, hi))
            for lo, hi in zip(bounds[:-1], bounds[1:])])
    else:
        mean = _average(unit, weight, p.window_mag * axis.rate,
                        (p.window_far * axis.rate, p.far_share), axis)
    # The rotation by δ about z takes (sin δ, cos δ)·|h| to (0, |h|): north.
    turn = np.arctan2(mean[:, 0], mean[:, 1])
    if has_gaps and p.join == 'solve':
        turn = turn + _heading_offsets(q, turn, unit, weight, axis, p, gaps, bridge)
    return normalize(multiply(_about_vertical(turn), q))


def _heading_offsets(q, turn, unit, weight, axis, p, gaps, bridge):
    """
    rad (N,): each stretch's offset to its own heading ``turn`` (N,), all stretches at once.

    Each stretch (between two gaps) holds its own heading, ``turn`` (its
    fields averaged within it): its offset is 0, doubted by the directions'
    spread over it (``1 − R̄²``, ``R̄`` the weighted mean's length), the
    samples independent once every ``heading_tau`` s. Across each gap, the
    strapdown's heading holds up to the bridge's error about the vertical
    (``bridge`` (G, 3), rad² per body axis, turned into I): the two sides'
    turns plus their offsets should agree. The offsets minimizing both come
    from one tridiagonal linear system (:func:`_tridiagonal`).
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
    vertical = _matrices(q[gaps[1]])[:, 2, :]
    link = 1.0 / np.maximum(np.sum(np.square(vertical) * bridge, axis=1), 1e-12)
    jump = np.angle(np.exp(1j * (turn[gaps[1]] - turn[gaps[0]])))
    # Σ info c_s² + Σ link (c_{s+1} − c_s + jump)²: its normal equations.
    rhs = np.zeros(count)
    rhs[:-1] += link * jump
    rhs[1:] -= link * jump
    diagonal = info + _PRIOR + np.concatenate((link, [0.0])) + np.concatenate(([0.0], link))
    offset = _tridiagonal(diagonal, -link, rhs)
    return offset[np.searchsorted(bounds, np.arange(n), side='right') - 1]


def _field_weights(q, mag, axis, p):
    """
    The field's horizontal direction in I (N, 2) and each sample's weight (N,), or None.

    A sample weighs by how close its norm and dip stay to the reference's
    (``ref_time``, ``mag_sigma``) and by its share of time; 0 without a field.
    None: no horizontal field at all.
    """
    lost = np.isnan(mag[:, 0])
    m = _rotate(q, np.where(lost[:, None], 0.0, mag))
    norm = np.linalg.norm(m, axis=1)
    horizontal = np.hypot(m[:, 0], m[:, 1])
    dip = np.arctan2(m[:, 2], horizontal)
    if not np.any(horizontal > 0.0):
        return None
    start = (axis.slots() < max(1, int(round(p.ref_time * axis.rate)))) & ~lost
    if p.ref_time > 0.0 and start.any() and np.median(norm[start]) > 0.0:
        ref_norm = float(np.median(norm[start]))
        ref_dip = float(np.median(dip[start]))
    else:
        ref_norm, ref_dip = _most_common(norm, dip, p.mag_sigma)
    z = (np.square((norm - ref_norm) / (p.mag_sigma * ref_norm))
         + np.square((dip - ref_dip) / p.mag_sigma))
    weight = np.where(lost, 0.0, np.exp(-0.5 * np.minimum(z, 1400.0)) * axis.spans(p.join_time))
    unit = m[:, :2] / np.maximum(horizontal, np.finfo(float).tiny)[:, None]
    return unit, weight


_SPREAD = 1e-9
# rad⁻², a weak pull of every stretch's offset to none (no stretch with a
# field: no offsets).
_PRIOR = 1e-9


def _tridiagonal(diagonal, off, rhs):
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


def _most_common(norm, dip, sigma, candidates=64, samples=20000):
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
