"""
The node's estimator on one recording's arrays, with a record of each IMU sample.

:class:`PipelineRun` is :class:`~ext_observer.pipeline.raw_imu.RawImuPipeline`
(the node's own code) keeping what it made of each sample; :func:`run_arrays`
feeds it a recording's arrays in the node's arrival order and returns the
:class:`Recording`. :func:`~ext_observer.recordings.recording.attitude_from_imu`
checks its input and runs it; the smoother
(:mod:`ext_observer.recordings.smoothing`) runs it too, and the bag command
runs :class:`PipelineRun` itself. Conventions, arrival order and the rows
without an estimate of their own: :mod:`ext_observer.recordings.recording`.
"""

import array
import heapq
import itertools
import math

import numpy as np

from ext_observer.pipeline.batch import hold_finite
from ext_observer.pipeline.raw_imu import RawImuPipeline
from ext_observer.pipeline.health import HEALTH_STATES, HealthWatch
from ext_observer.pipeline.velocity_aid import with_velocity

__all__ = ['PipelineRun', 'Recording', 'roll_pitch_yaw', 'run_arrays', 'SECOND', 'START',
           'times_array', 'vectors_array']

SECOND = 1_000_000_000
# Stamp of the earliest sample of a recording given by times or a rate, ns:
# the node drops a stamp of zero, and only differences matter.
START = 1000 * SECOND

# The record of a sample without an estimate.
_NONE = (math.nan,) * 4
_NO_VARIANCE = (math.nan, math.nan)
_REST = 1 << HEALTH_STATES.index('at_rest')
_REJECTED = 1 << HEALTH_STATES.index('field_rejected')


class Recording:
    """
    What :func:`attitude_from_imu` (or the bag command) made of a recording.

    One row per IMU sample, in arrival order.

    Attributes
    ----------
    times : ndarray, shape (N,)
        s: as given, or ``k / rate``; from a bag, the header stamps.
    quaternions : ndarray, shape (N, 4)
        Unit, ``(w, x, y, z)``, sensor → ``world_frame``: the orientation of
        ``imu/data``. A row without an estimate of its own repeats the latest
        (module docstring).
    ambient : ndarray, shape (N, 4)
        The estimate as ``attitude_estimate`` carries it (not normalized;
        ``|q̂̄q̂ − 1|`` is what the extension term holds small), held alike.
    estimated : ndarray of bool, shape (N,)
        The node published an estimate for this sample.
    health : ndarray of uint8, shape (N,)
        The estimator's health after this sample, as bits: bit ``i`` set when
        state :data:`~ext_observer.pipeline.health.HEALTH_STATES` ``[i]`` is
        active (docs/diagnostics.md); :meth:`in_state` reads one state.
    rest : ndarray of bool, shape (N,)
        Rest detected after this sample (the gyro bias is learned then):
        ``in_state('at_rest')``.
    mag_disturbed : ndarray of bool, shape (N,)
        The latest field was rejected as disturbed: ``in_state('field_rejected')``.
    inclination_std, heading_std : ndarray, shape (N,)
        rad: the uncertainty the node publishes with this sample's estimate
        (``imu/data``'s ``orientation_covariance``, docs/covariance.md), as
        ``/diagnostics`` states it: inclination ``√(2 V_tilt)``, heading
        ``√V_heading``; NaN without an estimate of its own.
    calibration : ndarray of str, shape (N,), or None
        The magnetometer calibration's state after the latest field
        (``AhrsObserver.calibration_state``: ``'off'``, ``'learning'``,
        ``'converged'``, ``'loaded'``), where the core has one; else None.
    calibrator : ext_observer.core.ahrs.magcal.MagCalibrator or None
        The core's magnetometer calibration as it stands after the last
        sample (what ``~/save_calibration`` would write); None in 6D or with
        ``ahrs.mag_cal`` false.
    world_frame : str
    drops : dict
        Inputs dropped, by reason (:data:`ext_observer.pipeline.pairing.DROP_REASONS`).
    counts : dict
        ``imu_samples``, ``fields`` (received), ``fields_used``,
        ``estimates``.
    resets, reinitializations : dict
        Restarts of the estimator by cause, and the divergence guard's by
        reason, as the node counts them.
    units : dict
        ``kind -> (samples, text)``: magnitudes that only a wrong unit
        explains (:mod:`ext_observer.pipeline.units`), as the node warns of them.
    smoothed : bool
        :attr:`quaternions`, :attr:`ambient` (then unit, as the quaternions),
        :attr:`inclination_std` and :attr:`heading_std` are the smoothed
        estimate's, from the whole recording (``smooth=True``, ``--smooth``:
        :mod:`ext_observer.recordings.smoothing`; finite on every row); every
        other attribute is the online run's. False: all are the node's.

    """

    def __init__(self, **fields):
        self.__dict__.update(fields)

    def in_state(self, name):
        """Return where the health state ``name`` was active, bool (N,) (:attr:`health`)."""
        if name not in HEALTH_STATES:
            raise ValueError(f'unknown health state {name!r} (one of {", ".join(HEALTH_STATES)})')
        return (self.health & (1 << HEALTH_STATES.index(name))) != 0

    def health_states(self, k):
        """Return the names of the states active after sample ``k``, a tuple."""
        return tuple(name for i, name in enumerate(HEALTH_STATES) if self.health[k] >> i & 1)

    def roll_pitch_yaw(self):
        """Return roll, pitch, yaw (rad) of :attr:`quaternions`, shape (N, 3)."""
        return roll_pitch_yaw(self.quaternions)

    def dropped_text(self):
        """Return the drops as ``reason count, ...``, or ``none``."""
        dropped = [f'{reason} {count}' for reason, count in self.drops.items() if count]
        return ', '.join(dropped) if dropped else 'none'


def roll_pitch_yaw(q):
    """
    Return the roll, pitch and yaw of sensor → world quaternions, rad.

    ``R = R_z(yaw) R_y(pitch) R_x(roll)`` (about the world's z, then the new
    y, then x: the order of ``tf2``'s ``getRPY``); pitch in [−π/2, π/2].

    Parameters
    ----------
    q : array_like, shape (..., 4)
        ``(w, x, y, z)``, any nonzero norm.

    Returns
    -------
    angles : ndarray, shape (..., 3)

    """
    q = np.asarray(q, dtype=float)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = np.moveaxis(q, -1, 0)
    roll = np.arctan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    pitch = np.arcsin(np.clip(2.0 * (w * y - z * x), -1.0, 1.0))
    yaw = np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return np.stack([roll, pitch, yaw], axis=-1)


class PipelineRun:
    """
    :class:`~ext_observer.pipeline.raw_imu.RawImuPipeline` with a record of each IMU sample.

    Parameters
    ----------
    settings : dict
        The node's settings (:func:`node_settings`).

    Attributes
    ----------
    pipeline : ext_observer.pipeline.raw_imu.RawImuPipeline

    """

    def __init__(self, settings):
        self.settings = settings
        self.pipeline = RawImuPipeline(settings, depth=settings['queue_depth'])
        self._core = self.pipeline.estimator.core
        # Per IMU sample: its stamp, its estimate (NaN: none), its health's
        # bits, the calibration's state. Flat arrays of numbers, not
        # a tuple per sample: hundreds of thousands of live tuples would make
        # Python's garbage collector the largest cost of a long recording.
        self._stamps = array.array('q')
        self._states = array.array('d')
        self._variances = array.array('d')
        self._flags = bytearray()
        self._health = HealthWatch()
        self._calibrations = []
        self._take = self.pipeline.imu
        # The magnetometer calibration's state, where the core has one: it
        # changes with the fields only.
        self._calibration = getattr(self._core, 'calibration_state', None)

    def imu(self, stamp, gyr, acc):
        """Take one IMU sample (ns, rad/s, m/s²); return its Estimate or None."""
        estimate = self._take(stamp, gyr, acc)[1]
        self._stamps.append(stamp)
        if estimate is None:
            self._states.extend(_NONE)
            self._variances.extend(_NO_VARIANCE)
        else:
            self._states.extend(estimate.state)
            covariance = estimate.covariance
            self._variances.extend((covariance[0], covariance[8]))
        self._flags.append(self._health.mask(self.pipeline))
        if self._calibration is not None:
            self._calibrations.append(self._calibration)
        return estimate

    def field(self, stamp, field):
        """Take one field (ns, T); return the pipeline's outcome."""
        outcome = self.pipeline.field(stamp, field)
        if self._calibration is not None:
            self._calibration = self._core.calibration_state
        return outcome

    def recording(self, times=None):
        """
        Return the :class:`Recording` of the samples taken so far.

        Parameters
        ----------
        times : ndarray, optional
            The samples' times, s; default: their stamps.

        Raises
        ------
        ValueError
            If no sample gave an estimate.

        """
        count = len(self._stamps)
        ambient = np.frombuffer(self._states, dtype=float).reshape(count, 4).copy()
        estimated = ~np.isnan(ambient[:, 0])
        flags = np.frombuffer(self._flags, dtype=np.uint8)
        pipeline = self.pipeline
        pairer = pipeline.pairer
        if not estimated.any():
            dropped = [f'{reason} {n}' for reason, n in pairer.drops.items() if n]
            raise ValueError(
                f'no estimate from {count} IMU samples: the first sample of a time line '
                'only sets t_0 and the node drops what it cannot use'
                + (f' (dropped: {", ".join(dropped)})' if dropped else ''))
        ambient = hold_finite(ambient)
        variances = np.frombuffer(self._variances, dtype=float).reshape(count, 2)
        units = pipeline.units
        return Recording(
            times=(np.frombuffer(self._stamps, dtype=np.int64) * 1e-9 if times is None
                   else np.asarray(times, dtype=float)),
            quaternions=ambient / np.linalg.norm(ambient, axis=1, keepdims=True),
            ambient=ambient, estimated=estimated,
            inclination_std=np.sqrt(2.0 * variances[:, 0]), heading_std=np.sqrt(variances[:, 1]),
            health=flags.copy(), rest=(flags & _REST) != 0, mag_disturbed=(flags & _REJECTED) != 0,
            calibration=(None if self._calibration is None
                         else np.array(self._calibrations, dtype=object)),
            calibrator=getattr(self._core, 'calibration', None),
            world_frame=self.settings['world_frame'],
            drops=dict(pairer.drops),
            counts={'imu_samples': pairer.received['increment'],
                    'fields': pairer.received['measurement'],
                    'fields_used': pairer.processed['measurement'],
                    'estimates': int(estimated.sum())},
            resets=dict(pipeline.resets), reinitializations=dict(pipeline.reinitializations),
            units={kind: (n, units.findings[kind]) for kind, n in units.counts.items() if n},
            smoothed=False)


def run_arrays(settings, rate, times, gyr, acc, mag, mag_times=None, velocity=None,
               velocity_times=None):
    """
    Return the online :class:`Recording` of checked arrays (:func:`attitude_from_imu`'s run).

    ``gyr``, ``acc`` (N, 3) and ``mag`` (rows per IMU sample, or at
    ``mag_times``) as :func:`attitude_from_imu` has checked them; ``rate``
    (Hz) or ``times`` (s), one of them; ``settings`` :func:`node_settings`'.
    """
    count = len(gyr)
    times, stamps, clock = _imu_stamps(rate, times, count, mag_times)
    gyr, acc = _Rows(gyr), _Rows(acc)
    field_stamps, fields, events = _field_events(mag if settings['use_mag'] else None,
                                                 mag_times, count, stamps, clock)
    velocity, velocity_stamps, events = _velocity_input(velocity, velocity_times, count, stamps,
                                                        clock, events)
    run = PipelineRun(settings)
    imu, field, aid = run.imu, run.field, run.pipeline.velocity
    for kind, i in events:
        if kind == 1:
            field(field_stamps[i], fields[i])
        elif kind == 2:
            aid(velocity_stamps[i], velocity[i])
        else:
            imu(stamps[i], gyr[i], acc[i])
    return run.recording(times)


def _velocity_input(velocity, velocity_times, count, stamps, clock, events):
    """The velocities as lists, their stamps (ns) and the events with them; checked."""
    if velocity is None:
        if velocity_times is not None:
            raise ValueError('velocity_times given without velocity')
        return None, None, events
    velocity = vectors_array(velocity, 'velocity')
    if velocity_times is None:
        if len(velocity) != count:
            raise ValueError(f'velocity has {len(velocity)} rows and gyr {count}: without '
                             'velocity_times row k of velocity is the velocity at IMU sample k')
        velocity_stamps = list(stamps)
    else:
        velocity_stamps = clock(times_array(velocity_times, len(velocity), 'velocity_times'))
    return velocity.tolist(), velocity_stamps, with_velocity(events, stamps, velocity_stamps)


def _imu_stamps(rate, times, count, mag_times):
    """The IMU's times (s), its stamps (ns) and the clock from one to the other."""
    if rate is not None:
        rate = float(rate)
        if not (math.isfinite(rate) and rate > 0.0):
            raise ValueError(f'rate must be positive (Hz), got {rate}')
        # As test/broad_replay.py stamps its samples, so that dt is the same.
        return (np.arange(count) / rate, [START + round(k * SECOND / rate) for k in range(count)],
                _Clock(0.0))
    times = times_array(times, count, 'times')
    clock = _Clock(float(np.min(times)) if mag_times is None
                   else min(float(np.min(times)), float(np.min(mag_times))))
    return times, clock(times), clock


def _field_events(mag, mag_times, count, stamps, clock):
    """The fields' stamps and rows, and the events (kind, index) in the order they are taken."""
    if mag is None:
        return [], [], ((0, k) for k in range(count))
    if mag_times is None:
        rows = np.flatnonzero(~np.isnan(mag).all(axis=1))
        return ([stamps[k] for k in rows], mag[rows].tolist(),
                _after_their_samples(count, rows.tolist()))
    field_stamps, fields = clock(mag_times), mag.tolist()
    # (stamp, kind, index): on a tie the IMU sample (kind 0) first.
    return field_stamps, fields, ((kind, i) for _, kind, i in heapq.merge(
        zip(stamps, itertools.repeat(0), range(count)),
        zip(field_stamps, itertools.repeat(1), range(len(fields)))))


def _after_their_samples(count, rows):
    """(0, k) for IMU sample k, each followed by (1, j) for the field of row ``rows[j] = k``."""
    j = 0
    for k in range(count):
        yield 0, k
        while j < len(rows) and rows[j] == k:
            yield 1, j
            j += 1


class _Rows:
    """
    The rows of an (N, 3) array as lists of floats, made a block at a time.

    Read in increasing order, as the events are: lists of all the rows at
    once would take about 160 bytes a sample each, the largest part of a
    long recording's memory.
    """

    BLOCK = 1 << 16

    def __init__(self, array):
        self.array = array
        self.start = 0
        self.rows = []

    def __getitem__(self, k):
        j = k - self.start
        if not 0 <= j < len(self.rows):
            self.start = k - k % self.BLOCK
            self.rows = self.array[self.start:self.start + self.BLOCK].tolist()
            j = k - self.start
        return self.rows[j]


class _Clock:
    """Times in s to stamps in ns: ``START + round((t − t_0) · 1e9)``."""

    def __init__(self, t0):
        self.t0 = t0

    def __call__(self, times):
        return (START + np.round((np.asarray(times) - self.t0) * SECOND)).astype(
            np.int64).tolist()


def vectors_array(values, name):
    """``values`` as an (N, 3) float array; ValueError naming ``name`` otherwise."""
    array = np.asarray(values, dtype=float)
    if array.ndim != 2 or array.shape[1] != 3:
        hint = (' (one row per sample: transpose it?)'
                if array.ndim == 2 and array.shape[0] == 3 else '')
        raise ValueError(f'Expected `{name}` to have shape (N, 3), got {array.shape}{hint}')
    return array


def times_array(values, count, name):
    """``values`` as a finite (count,) float array of s; ValueError naming ``name`` otherwise."""
    array = np.asarray(values, dtype=float)
    if array.shape != (count,):
        raise ValueError(f'Expected `{name}` to have shape ({count},), got {array.shape}')
    bad = np.flatnonzero(~np.isfinite(array))
    if bad.size:
        raise ValueError(f'{name}[{bad[0]}] is {array[bad[0]]}: times must be finite (s)')
    return array
