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

import warnings

from ext_observer.pipeline.imu_filter_parameters import (IMU_FILTER_PARAMETERS,
                                                         imu_filter_settings, mag_frame_rpy_text)
# The online run's machinery; PipelineRun, Recording, roll_pitch_yaw and SECOND are this
# module's API too.
from ext_observer.recordings.pipeline_run import (PipelineRun, Recording, roll_pitch_yaw,
                                                  run_arrays, SECOND, START, times_array,
                                                  vectors_array)
from ext_observer.recordings.input_units import check_units as refuse_wrong_units

__all__ = ['PipelineRun', 'Recording', 'add_parameter_options', 'attitude_from_imu',
           'node_settings', 'parameters_from_options', 'parameters_from_yaml', 'roll_pitch_yaw',
           'run_arrays', 'smoothed_into']

_SPECS = {spec.name: spec for spec in IMU_FILTER_PARAMETERS}
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
    gyr, acc = _imu_arrays(gyr, acc)
    count = len(gyr)
    settings = node_settings(parameters)
    mag = _field_rows(mag, mag_times, count)
    if check_units:
        refuse_wrong_units(gyr, acc, mag)
    if (rate is None) == (times is None):
        raise ValueError('give the IMU rate (Hz) or its times (s), one of them')
    if mag_times is not None:
        mag_times = times_array(mag_times, len(mag), 'mag_times')
    inputs = (gyr, acc, mag, mag_times, velocity, velocity_times)
    recording = run_arrays(settings, rate, times, *inputs)
    recording.smoothed = bool(smooth)
    if smooth:
        from ext_observer.recordings.smoothing import smoothed_attitude
        field = mag if settings['use_mag'] else None
        smoothed_into(recording, smoothed_attitude(
            gyr, acc, field, recording.times, settings,
            mag_times=None if field is None else mag_times, velocity=velocity,
            velocity_times=velocity_times,
            online_std=(recording.inclination_std, recording.heading_std)))
    return recording


def _imu_arrays(gyr, acc):
    """``gyr`` and ``acc`` as (N, 3) float arrays of one length, N ≥ 2, or a ValueError."""
    gyr = vectors_array(gyr, 'gyr')
    acc = vectors_array(acc, 'acc')
    count = len(gyr)
    if len(acc) != count:
        raise ValueError(f'gyr and acc must have one row per IMU sample, got {count} and '
                         f'{len(acc)} rows')
    if count < 2:
        raise ValueError(f'at least 2 IMU samples are needed (the first only sets t_0), '
                         f'got {count}')
    return gyr, acc


def smoothed_into(recording, smoothed):
    """Put a smoothed estimate (quaternions, inclination σ, heading σ) in ``recording``."""
    quaternions, inclination_std, heading_std = smoothed
    recording.quaternions = quaternions
    recording.ambient = quaternions.copy()
    recording.inclination_std = inclination_std
    recording.heading_std = heading_std
    recording.smoothed = True


def _field_rows(mag, mag_times, count):
    """The fields as an (M, 3) array, checked against the IMU's ``count``; None without."""
    if mag is None:
        if mag_times is not None:
            raise ValueError('mag_times given without mag')
        return None
    mag = vectors_array(mag, 'mag')
    if mag_times is None and len(mag) != count:
        raise ValueError(f'mag has {len(mag)} rows and gyr {count}: without mag_times '
                         'row k of mag is the field at IMU sample k (NaN: none)')
    return mag

