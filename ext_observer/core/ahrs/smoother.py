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
against the bridge's doubt), each stretch is then turned by the small rotation
that keeps the body's velocity bounded across all of them (``nav``,
:mod:`~ext_observer.core.ahrs.smooth_nav`), and each stretch's heading is solved
from all stretches' fields at once, through the bridges. A NaN row of the field weighs
nothing; a gyro axis at its range is bridged across the clipped stretch
(Hermite's cubic from both sides).
docs/offline.md ("Holes, lost fields and clipped stretches") has the figures.

The windows are Gaussian-like (three box filters, cumulative sums), symmetric
in time, so without delay; beside the online passes, numpy on whole arrays
and the loops over samples of
:mod:`~ext_observer.core.ahrs.smooth_strapdown` (compiled by numba where it
is wanted, else numpy to the same floats). Conventions as the estimator's:
``(w, x, y, z)``, sensor → ENU, SI units. What each step gave on BROAD: docs/offline.md.
"""

import dataclasses
import math

import numpy as np

from ..quaternion import normalize
from .ahrs_observer import AhrsObserver
from .ahrs_params import AhrsParams
from .smooth_clips import clip_stretches, clipped_rates, unclipped, with_clips
from .smooth_holes import bridge_axes, bridged, gaps_of, join_tilt
from .smooth_nav import join_velocity
from .smooth_strapdown import strapdown
from .smooth_windows import heading, inclination

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
        sides (:func:`unclipped`); False: the clipped rates as given.
    join : {'solve', 'chain', 'local', 'none'}
        What a hole of at least ``join_time`` changes beyond the gyro's
        bridge. ``'chain'``: the part after it is tilted to make the
        specific force averaged over ``window_acc`` s on either side agree
        (:func:`~ext_observer.core.ahrs.smooth_holes.join_tilt`, weighed
        against the bridge), and the heading
        (9D) is averaged within each stretch between such holes;
        ``'solve'``: as ``'chain'``, each stretch's heading then offset
        by all the others' fields through the bridges, solved at once
        (:func:`~ext_observer.core.ahrs.smooth_windows.heading_offsets`);
        ``'local'``: the inclination too is averaged within each stretch;
        ``'none'``: the bridge only, the windows across the holes.
    join_time : float
        s: the shortest hole that ``join`` treats; a shorter one's samples
        share its time in the windows (a lost sample: its neighbours'),
        a longer one is no data.
    join_tau : float
        s: the specific force's samples beside a hole count as independent
        once every ``join_tau`` (the doubt of the join's averages, weighed
        against the gyro bridge's, :func:`~ext_observer.core.ahrs.smooth_holes.bridge_variance`).
    heading_tau : float
        s: the field's directions within a stretch count as independent
        once every ``heading_tau`` (the doubt of a stretch's heading,
        weighed against the bridges', ``join='solve'``).
    nav : bool
        After the tilt's join (``join`` ``'solve'`` or ``'chain'``), each
        stretch's rotation from the velocity and the position carried
        across the holes (:func:`~ext_observer.core.ahrs.smooth_nav.join_velocity`).
    nav_speed : float
        m/s, how fast the body moves, per second of data (the bound on the
        velocity, ``nav``).
    nav_room : float
        m, how far the body goes from where it started, per second of data
        (``nav``).
    nav_accel : float
        m/s², how far the body's acceleration within a hole strays from the
        mean of the two sides' (``nav``).
    nav_tilt : float
        rad, how far each stretch's rotation may stray from the tilt's join
        (``nav``).
    nav_bridge : float
        How much less sure the gyro's bridge across a hole is in the
        ``nav`` solve than the online estimator's hole model says.
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
    nav: bool = True
    nav_speed: float = 0.5
    nav_room: float = math.inf
    nav_accel: float = 10.0
    nav_tilt: float = 0.1
    nav_bridge: float = 100.0
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
        for name in ('nav_speed', 'nav_room', 'nav_accel', 'nav_tilt', 'nav_bridge'):
            if not getattr(self, name) > 0.0:
                raise ValueError(f'{name} must be positive, got {getattr(self, name)}')
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
    clips = None
    if p.unclip:
        clipped = clipped_rates(gyr, p)
        clips = clip_stretches(gyr, clipped, axis, p)
        gyr = unclipped(gyr, clipped, axis.times,
                         max(1, int(round(p.slope_time / axis.usual))))
    unbiased = gyr - bias
    field = None if mag is None else calibration(mag)
    rate, dt, rows = bridged(unbiased, axis, p)
    q = strapdown(rate, dt, first)[rows]
    gaps = gaps_of(axis, p.join_time)
    bridge = bridge_axes(unbiased, gaps)
    if p.join in ('solve', 'chain'):
        joined = join_tilt(q, acc, unbiased, gaps, axis, p)
        if p.nav:
            joined = join_velocity(joined, q, acc, bridge, gaps, axis, p)
        q = inclination(joined, acc, axis, p)
    elif p.join == 'local' and len(gaps[0]):
        bounds = np.concatenate(([0], gaps[1], [len(q)]))
        q = np.concatenate([inclination(q[lo:hi], acc[lo:hi], axis.part(lo, hi), p)
                            for lo, hi in zip(bounds[:-1], bounds[1:])])
    else:
        q = inclination(q, acc, axis, p)
    if field is not None:
        if p.join == 'solve' and clips is not None and len(clips[0][0]):
            # A clip's heading error would spread over the heading's long
            # windows: its stretches are solved apart, as a hole's.
            gaps, bridge = with_clips(gaps, bridge, *clips)
        q = heading(q, field, axis, p, gaps,
                    bridge if p.join == 'solve' and len(gaps[0]) else None)
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
            if np.isnan(a).any():
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
        est.run(gyr[lo:hi], acc[lo:hi], field, float(dt[lo]), out=out[lo - start:hi - start])
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


# Samples per call of the online pass where only its end matters.
_CHUNK = 65536


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
    # Of the estimates only the first is kept: the pass runs in chunks (the same steps),
    # each chunk's estimates dropped, not an array of the recording's length.
    first = None
    for lo in range(0, len(gyr), _CHUNK):
        q = _online(est, gyr, acc, mag, dt, lo, min(lo + _CHUNK, len(gyr)))
        first = q[0] if first is None else first
    return np.array(est.bias), first, _calibration(est)


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
