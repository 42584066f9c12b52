"""
One recording of a raw IMU through ``imu_filter_node``'s estimator, without ROS.

:func:`attitude_from_imu` takes arrays (a recording in memory, a CSV file)
and returns the attitude the node would publish for each sample, with the
flags a user needs to trust it and the node's counters. It runs
:class:`~ext_observer.pipeline.raw_imu.RawImuPipeline`, the node's own code, so its
estimates are the node's: the same input checks (a sample the node drops is
dropped and counted here), the same stamp rules (``dt`` from the integer
nanosecond stamps, ``max_dt``, backward jumps), the same frames. The bag
command (:mod:`ext_observer.recordings.bag`) runs the same :class:`PipelineRun`.

Conventions
    Angular velocity rad/s, specific force m/s² (about +9.81 along the
    world's up axis at rest), magnetic field T, time s. Quaternions scalar
    first ``(w, x, y, z)``, sensor → world, in the node's ``world_frame``
    (``enu`` by default, as imu_filter_madgwick); roll, pitch, yaw in rad
    (:func:`roll_pitch_yaw`).

Arrival order
    The IMU samples arrive in their row order. A field given per IMU row
    arrives right after its sample (as ``test/broad_replay.py`` replays
    them into the node); a field at its own times after every IMU sample
    with a stamp not later than its own (the two merged by time, the IMU
    sample first on a tie).

Rows without an estimate of their own
    The node publishes nothing for the first sample of a time line (it only
    sets ``t_0``) and for a dropped sample. So that every row has a unit
    quaternion, such a row repeats the latest estimate (before the first
    one: the first), the rule :func:`~ext_observer.pipeline.batch.estimate_batch`
    applies to its inputs; :attr:`Recording.estimated` says which rows are
    the node's own estimates.
"""

import array
import heapq
import itertools
import math
import warnings

import numpy as np

from ext_observer.pipeline.batch import hold_finite
from ext_observer.pipeline.imu_filter_parameters import (IMU_FILTER_PARAMETERS, imu_filter_settings,
                                                         mag_frame_rpy_text)
from ext_observer.pipeline.raw_imu import RawImuPipeline
from ext_observer.pipeline.health import HEALTH_STATES, HealthWatch
from ext_observer.pipeline.velocity_aid import with_velocity
from ext_observer.recordings.input_units import check_units as refuse_wrong_units

__all__ = ['PipelineRun', 'Recording', 'add_parameter_options', 'attitude_from_imu',
           'node_settings', 'parameters_from_options', 'parameters_from_yaml', 'roll_pitch_yaw',
           'run_arrays', 'smoothed_into']

SECOND = 1_000_000_000
# Stamp of the earliest sample of a recording given by times or a rate, ns:
# the node drops a stamp of zero, and only differences matter.
START = 1000 * SECOND

_SPECS = {spec.name: spec for spec in IMU_FILTER_PARAMETERS}
# The record of a sample without an estimate.
_NONE = (math.nan,) * 4
_NO_VARIANCE = (math.nan, math.nan)
_REST = 1 << HEALTH_STATES.index('at_rest')
_REJECTED = 1 << HEALTH_STATES.index('field_rejected')
# rclpy's own parameters, in a params file beside the node's.
_ROS_OWN = ('use_sim_time', 'qos_overrides.')


def node_settings(given=None, strict_types=False):
    """
    Return the settings of ``imu_filter_node`` for the given parameter values.

    Parameters
    ----------
    given : dict, optional
        Parameter values by name (``config/imu_filter.yaml``'s names:
        ``world_frame``, ``ahrs.tau_mag``, ...); the others keep their
        defaults.
    strict_types : bool
        Refuse an integer for a float parameter, as the node does (a params
        file); else take it as a float (a Python call).

    Returns
    -------
    settings : dict

    Raises
    ------
    ValueError
        Naming the parameter: unknown, of the wrong type, out of its range,
        or refused by the node's validation.

    """
    values = {name: spec.default for name, spec in _SPECS.items()}
    for name, value in (given or {}).items():
        spec = _SPECS.get(name)
        if spec is None:
            if name.startswith(_ROS_OWN):
                continue
            raise ValueError(f'unknown parameter {name!r} (imu_filter_node has: '
                             f'{", ".join(sorted(_SPECS))})')
        values[name] = _checked_value(spec, value, strict_types)
    settings = imu_filter_settings(values)
    deprecated = mag_frame_rpy_text(settings)
    if deprecated:
        # Once per process (the warnings module's default), as the node logs it once.
        warnings.warn(deprecated, FutureWarning)
    return settings


def _checked_value(spec, value, strict_types):
    default = spec.default
    if isinstance(default, float) and isinstance(value, int) and not isinstance(value, bool):
        if strict_types:
            raise ValueError(f'{spec.name}: a float is expected, got the integer {value} '
                             f'(write {value}.0: the node refuses an integer here)')
        value = float(value)
    if type(value) is not type(default) and not (
            isinstance(default, float) and isinstance(value, float)):
        raise ValueError(f'{spec.name}: a {type(default).__name__} is expected, got '
                         f'{value!r}')
    if spec.range is not None and not spec.range[0] <= value <= spec.range[1]:
        raise ValueError(f'{spec.name} must lie in [{spec.range[0]}, {spec.range[1]}], '
                         f'got {value}')
    return value


def parameters_from_yaml(path):
    """
    Return the parameter values of ``imu_filter_node`` in a ROS params file.

    The file's section for the node is used: the only section, else those
    named for ``imu_filter`` (``/**/imu_filter``, ``imu_filter``, ...) or for
    every node (``/**``), in the file's order. Nested names are joined with
    dots (``ahrs: {tau_mag: 10.0}`` is ``ahrs.tau_mag``).

    Returns
    -------
    values : dict
        For :func:`node_settings` (with ``strict_types=True``).

    Raises
    ------
    ValueError
        If the file has no such section.

    """
    import yaml
    with open(path, encoding='utf-8') as stream:
        try:
            document = yaml.safe_load(stream)
        except yaml.YAMLError as error:
            raise ValueError(f'{path}: not YAML: {error}') from None
    sections = {name: section['ros__parameters'] for name, section in (document or {}).items()
                if isinstance(section, dict) and 'ros__parameters' in section}
    if len(sections) > 1:
        sections = {name: section for name, section in sections.items()
                    if name.rstrip('/').split('/')[-1] in ('imu_filter', '**')}
    if not sections:
        raise ValueError(f'{path}: no section with ros__parameters for imu_filter '
                         '(e.g. "/**/imu_filter:" as in config/imu_filter.yaml)')
    values = {}
    for section in sections.values():
        values.update(_flattened(section or {}))
    return values


def add_parameter_options(parser):
    """Add ``--params FILE.yaml`` and ``--no-mag`` to a command's parser."""
    parser.add_argument('--params', metavar='FILE.yaml',
                        help="imu_filter_node's parameters (config/imu_filter.yaml's format)")
    parser.add_argument('--no-mag', action='store_true',
                        help='6D, no magnetometer (use_mag false)')


def parameters_from_options(args):
    """
    Return the parameter values of :func:`add_parameter_options`' options.

    Checked as the node checks a params file (an integer for a float is
    refused), so that the file also starts the node.
    """
    values = parameters_from_yaml(args.params) if args.params else {}
    if args.no_mag:
        values['use_mag'] = False
    node_settings(values, strict_types=True)
    return values


def _flattened(section, prefix=''):
    values = {}
    for name, value in section.items():
        if isinstance(value, dict):
            values.update(_flattened(value, f'{prefix}{name}.'))
        else:
            values[prefix + name] = value
    return values


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


def attitude_from_imu(gyr, acc, mag=None, *, rate=None, times=None, mag_times=None,
                      parameters=None, check_units=True, velocity=None, velocity_times=None,
                      smooth=False):
    """
    Estimate the attitude of one recording as ``imu_filter_node`` does.

    Parameters
    ----------
    gyr : array_like, shape (N, 3)
        Angular velocity, rad/s, sensor frame.
    acc : array_like, shape (N, 3)
        Specific force, m/s² (about +9.81 up at rest).
    mag : array_like, shape (M, 3), optional
        Magnetic field, T. With ``mag_times``, at its own times; without,
        row ``k`` belongs to IMU sample ``k`` (M = N) and a row of NaN means
        no field at that sample (a slower magnetometer).
    rate : float, optional
        Sampling rate of the IMU, Hz: sample ``k`` at ``k / rate``.
    times : array_like, shape (N,), optional
        Time of each IMU sample, s (instead of ``rate``). Out-of-order and
        repeated times are dropped and counted as the node does.
    mag_times : array_like, shape (M,), optional
        Time of each field, s, on the same clock as ``times`` (or the rate's).
    velocity : array_like, shape (V, 3), optional
        The body's velocity, m/s (e.g. wheel odometry; ``velocity_*`` settings: its
        frame, timeout): the velocity aid (docs/raw_imu.md). With ``velocity_times``,
        at its own times; without, row ``k`` is at IMU sample ``k`` (V = N).
    velocity_times : array_like, shape (V,), optional
        Time of each velocity, s, on the IMU's clock.
    parameters : dict, optional
        ``imu_filter_node`` parameter values (``use_mag``, ``world_frame``,
        ``ahrs.tau_mag``, ...: ``config/imu_filter.yaml``).
    check_units : bool
        Refuse magnitudes that only a wrong unit explains (:mod:`ext_observer.pipeline.units`).
    smooth : bool
        Each sample's attitude from the whole recording, the samples after it
        too (:func:`~ext_observer.recordings.smoothing.smoothed_attitude`):
        the online run first, as without (its drops, units, health, counts,
        calibration are the recording's), then :attr:`Recording.quaternions`,
        ``ambient``, ``inclination_std`` and ``heading_std`` are the smoothed
        estimate's (docs/own_data.md: what it costs). Not for a live stream:
        it needs the whole recording.

    Returns
    -------
    recording : Recording

    Raises
    ------
    ValueError
        A shape, a missing or doubled time base, a non-finite time, a unit
        (``tesla expected, is it µT?``), a parameter; or no estimate at all.

    """
    gyr = _vectors(gyr, 'gyr')
    acc = _vectors(acc, 'acc')
    count = len(gyr)
    if len(acc) != count:
        raise ValueError(f'gyr and acc must have one row per IMU sample, got {count} and '
                         f'{len(acc)} rows')
    if count < 2:
        raise ValueError(f'at least 2 IMU samples are needed (the first only sets t_0), '
                         f'got {count}')
    settings = node_settings(parameters)
    mag = _field_rows(mag, mag_times, count)
    if check_units:
        refuse_wrong_units(gyr, acc, mag)
    if (rate is None) == (times is None):
        raise ValueError('give the IMU rate (Hz) or its times (s), one of them')
    if mag_times is not None:
        mag_times = _times(mag_times, len(mag), 'mag_times')
    inputs = (gyr, acc, mag, mag_times, velocity, velocity_times)
    recording = run_arrays(settings, rate, times, *inputs)
    recording.smoothed = bool(smooth)
    if smooth:
        from ext_observer.recordings.smoothing import smoothed_attitude
        field = mag if settings['use_mag'] else None
        smoothed_into(recording, smoothed_attitude(
            gyr, acc, field, recording.times, settings,
            mag_times=None if field is None else mag_times, velocity=velocity,
            velocity_times=velocity_times))
    return recording


def smoothed_into(recording, smoothed):
    """Put a smoothed estimate (quaternions, inclination σ, heading σ) in ``recording``."""
    quaternions, inclination_std, heading_std = smoothed
    recording.quaternions = quaternions
    recording.ambient = quaternions.copy()
    recording.inclination_std = inclination_std
    recording.heading_std = heading_std
    recording.smoothed = True


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
    gyr, acc = gyr.tolist(), acc.tolist()
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


def _field_rows(mag, mag_times, count):
    """The fields as an (M, 3) array, checked against the IMU's ``count``; None without."""
    if mag is None:
        if mag_times is not None:
            raise ValueError('mag_times given without mag')
        return None
    mag = _vectors(mag, 'mag')
    if mag_times is None and len(mag) != count:
        raise ValueError(f'mag has {len(mag)} rows and gyr {count}: without mag_times '
                         'row k of mag is the field at IMU sample k (NaN: none)')
    return mag


def _velocity_input(velocity, velocity_times, count, stamps, clock, events):
    """The velocities as lists, their stamps (ns) and the events with them; checked."""
    if velocity is None:
        if velocity_times is not None:
            raise ValueError('velocity_times given without velocity')
        return None, None, events
    velocity = _vectors(velocity, 'velocity')
    if velocity_times is None:
        if len(velocity) != count:
            raise ValueError(f'velocity has {len(velocity)} rows and gyr {count}: without '
                             'velocity_times row k of velocity is the velocity at IMU sample k')
        velocity_stamps = list(stamps)
    else:
        velocity_stamps = clock(_times(velocity_times, len(velocity), 'velocity_times'))
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
    times = _times(times, count, 'times')
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


class _Clock:
    """Times in s to stamps in ns: ``START + round((t − t_0) · 1e9)``."""

    def __init__(self, t0):
        self.t0 = t0

    def __call__(self, times):
        return (START + np.round((np.asarray(times) - self.t0) * SECOND)).astype(
            np.int64).tolist()


def _vectors(values, name):
    array = np.asarray(values, dtype=float)
    if array.ndim != 2 or array.shape[1] != 3:
        hint = (' (one row per sample: transpose it?)'
                if array.ndim == 2 and array.shape[0] == 3 else '')
        raise ValueError(f'Expected `{name}` to have shape (N, 3), got {array.shape}{hint}')
    return array


def _times(values, count, name):
    array = np.asarray(values, dtype=float)
    if array.shape != (count,):
        raise ValueError(f'Expected `{name}` to have shape ({count},), got {array.shape}')
    bad = np.flatnonzero(~np.isfinite(array))
    if bad.size:
        raise ValueError(f'{name}[{bad[0]}] is {array[bad[0]]}: times must be finite (s)')
    return array
