"""
Offline magnetometer calibration: ``python -m ext_observer calibrate``.

Runs the raw-IMU estimator of :mod:`ext_observer.core.ahrs.ahrs_observer` in 9D over a
recording, with the online calibration of :mod:`ext_observer.core.ahrs.magcal`,
and writes what it learned as a ROS 2 params file for ``imu_filter_node``::

    imu_filter:
      ros__parameters:
        mag_bias_x: ...        # T
        mag_bias_y: ...
        mag_bias_z: ...
        mag_soft_iron: [...]   # 9 floats, row-major

with ``m_raw = S m + b`` (``b`` = ``mag_bias_*``, ``S`` = ``mag_soft_iron``),
which the node loads with ``--params-file`` and refines online.

The estimation takes plain arrays (:func:`estimate_calibration`: gyro
``(N, 3)`` rad/s, specific force ``(N, 3)`` m/s², field ``(N, 3)`` and the
rate); reading a file is apart (:data:`READERS`, by extension): HDF5 in
BROAD's layout (``imu_gyr``, ``imu_acc``, ``imu_mag`` in µT, attribute
``sampling_rate``; needs h5py) and ``.npz`` with ``gyr``, ``acc``, ``mag``,
``rate`` (the excerpts in ``test/data``). A CSV file (``python -m
ext_observer csv``'s columns) or a rosbag2 bag (``python -m ext_observer
bag``'s topics) has its own times and a field in T: it runs through
``imu_filter_node``'s pipeline (:func:`calibration_from_recording`), its
stamp rules included, and the calibration is the one the node would have
learned from it.

No ROS is imported; PyYAML only to read a params file back
(:func:`read_params`).
"""

import argparse
import math
import os
import sys

import numpy as np

from ext_observer.core.ahrs.ahrs_observer import AhrsObserver, AhrsParams
from ext_observer.core.ahrs.magcal import check_calibration

__all__ = ['Calibration', 'NODE', 'READERS', 'UNITS', 'calibration_from_recording',
           'estimate_calibration', 'is_node_recording', 'main', 'params_text', 'read_bag',
           'read_csv', 'read_hdf5', 'read_npz', 'read_params', 'read_recording',
           'write_params']

NODE = 'imu_filter'
# Tesla per unit of the recording's field.
UNITS = {'T': 1.0, 'mT': 1e-3, 'uT': 1e-6, 'nT': 1e-9, 'gauss': 1e-4}


class Calibration:
    """
    What the calibration learned from a recording.

    Attributes
    ----------
    bias : ndarray, shape (3,)
        Hard-iron offset ``b``, in the recording's unit.
    soft_iron : ndarray, shape (3, 3)
        Soft-iron matrix ``S`` (``m_raw = S m + b``).
    state : str
        The calibration's state at the end: ``'converged'`` or ``'learning'``.
    applied : bool
        Whether the learned calibration turns the heading by more than
        ``mag_cal_deadband`` from the field as given (false: the sensor is
        calibrated already, and ``bias`` and ``soft_iron`` are the identity).
    quality : float
        Heading error its uncertainty causes at the end, rad (1σ).
    converged_at : float or None
        Seconds from the start to convergence.
    heading_turn : float
        RMS turn of the heading by the learned calibration (rad).
    delay : float
        The field's lag behind the gyro, s.
    counts : dict of int
        Fields given, used, gated, refused, invalid; restarts.
    learned_bias, learned_soft_iron : ndarray
        What was learned, even when not applied.

    """

    def __init__(self, cal, seconds, converged_at, applied):
        self.state = cal.state
        self.applied = bool(applied)
        self.learned_bias = np.array(cal.bias)
        self.learned_soft_iron = np.array(cal.soft_iron)
        if self.applied:
            self.bias, self.soft_iron = self.learned_bias, self.learned_soft_iron
        else:
            self.bias, self.soft_iron = np.zeros(3), np.eye(3)
        self.quality = float(cal.quality)
        self.converged_at = converged_at
        self.heading_turn = math.sqrt(float(cal._shift[0]))
        self.delay = float(cal.delay)
        self.counts = {key: int(v[0]) for key, v in cal.counts.items()}
        self.seconds = seconds

    def summary(self, unit='uT'):
        """A few lines for the terminal."""
        b = ', '.join(f'{v:.4g}' for v in self.learned_bias)
        s = np.array2string(self.learned_soft_iron, precision=4, suppress_small=True)
        turn = (f'the learned calibration turns the heading by '
                f'{math.degrees(self.heading_turn):.1f}° RMS: ')
        turn += ('applied' if self.applied
                 else 'within the deadband, the field is used as given (identity written)')
        lines = [f'state: {self.state} after {self.seconds:.1f} s'
                 + ('' if self.converged_at is None
                    else f' (converged at {self.converged_at:.1f} s)'),
                 f'heading error from the calibration\'s uncertainty: '
                 f'{math.degrees(self.quality):.2f}° (1σ)', turn,
                 f'learned hard-iron offset b: [{b}] {unit}',
                 'learned soft-iron matrix S: ' + s.replace('\n', ''),
                 f'field lag behind the gyro: {1e3 * self.delay:.1f} ms',
                 'field samples: ' + ', '.join(f'{k} {v}' for k, v in self.counts.items())]
        return '\n'.join(lines)


def calibration_from_recording(recording):
    """
    The :class:`Calibration` a :class:`~ext_observer.recordings.recording.Recording` ends with.

    Raises
    ------
    ValueError
        When the recording's estimator learned none (6D, ``ahrs.mag_cal``
        false, or no field).

    """
    cal = recording.calibrator
    if cal is None or recording.counts['fields_used'] == 0:
        raise ValueError('no magnetometer calibration was learned: the recording needs its '
                         'field (mag_* columns, or the field topic) and ahrs.mag_cal true')
    times = recording.times
    states = recording.calibration
    converged = np.flatnonzero(states == 'converged') if states is not None else []
    converged_at = float(times[converged[0]] - times[0]) if len(converged) else None
    return Calibration(cal, float(times[-1] - times[0]), converged_at, cal.applied)


def read_csv(path):
    """
    A CSV recording (:mod:`ext_observer.recordings.csvio`) through the node's pipeline.

    Returns its ``Calibration``.
    """
    from ext_observer.recordings.csvio import read_recording as read_columns
    from ext_observer.recordings.recording import attitude_from_imu
    times, gyr, acc, mag = read_columns(path)
    if mag is None:
        raise ValueError(f'{path}: no mag_x, mag_y, mag_z columns: nothing to calibrate')
    return calibration_from_recording(attitude_from_imu(gyr, acc, mag, times=times))


def read_bag(path, imu_topic='imu/data_raw', mag_topic='imu/mag'):
    """A rosbag2 bag (MCAP or sqlite3) through the bag command's run: ``Calibration``."""
    from ext_observer.recordings.bag import run_bag
    with open(os.devnull, 'w') as quiet:
        # Only what the estimator learned counts: no new bag is written.
        run = run_bag(path, None, imu_topic=imu_topic, mag_topic=mag_topic, progress=quiet,
                      parallel=False)
    return calibration_from_recording(run.recording)


def is_node_recording(path):
    """True for the recordings that run through the node's pipeline (CSV, bags; field in T)."""
    ext = os.path.splitext(path)[1].lower()
    return ext in ('.csv', '.mcap', '.db3') or os.path.isdir(path)


def estimate_calibration(gyr, acc, mag, rate, params=None):
    """
    Learn the magnetometer's calibration from a recording.

    Parameters
    ----------
    gyr, acc, mag : array_like, shape (N, 3)
        rad/s, m/s², the field (any unit; the result is in it). Rows with a
        non-finite value are skipped (the estimator never sees them).
    rate : float
        Sampling rate, Hz.
    params : AhrsParams, optional
        The estimator's parameters (``mag_cal`` must be on).

    Returns
    -------
    Calibration

    Raises
    ------
    ValueError
        For arrays of other shapes, a bad rate, or ``mag_cal`` off.

    """
    gyr, acc, mag = (np.asarray(a, dtype=float) for a in (gyr, acc, mag))
    for name, a in (('gyr', gyr), ('acc', acc), ('mag', mag)):
        if a.ndim != 2 or a.shape[1] != 3:
            raise ValueError(f'Expected `{name}` to have shape (N, 3), got {a.shape}')
    if not len(gyr) == len(acc) == len(mag):
        raise ValueError(f'gyr, acc and mag must have one row per sample, got '
                         f'{len(gyr)}, {len(acc)}, {len(mag)}')
    rate = float(rate)
    if not (math.isfinite(rate) and rate > 0.0):
        raise ValueError(f'the rate must be positive, got {rate}')
    params = params if params is not None else AhrsParams()
    if not params.mag_cal:
        raise ValueError('mag_cal is off: nothing to learn')
    keep = (np.isfinite(gyr).all(axis=1) & np.isfinite(acc).all(axis=1)
            & np.isfinite(mag).all(axis=1))
    g, a, m = gyr[keep].tolist(), acc[keep].tolist(), mag[keep].tolist()
    est = AhrsObserver(params, use_mag=True)
    dt = 1.0 / rate
    converged_at = None
    for k in range(len(g)):
        est.update(g[k], a[k], m[k], dt)
        if converged_at is None and est.calibration.converged:
            converged_at = k * dt
    return Calibration(est.calibration, len(g) * dt, converged_at, est.calibration.applied)


# --- reading recordings -----------------------------------------------------

def read_hdf5(path):
    """BROAD's layout: ``(gyr, acc, mag, rate, unit)``, the field in µT."""
    try:
        import h5py
    except ImportError as error:
        raise RuntimeError('reading HDF5 needs h5py: pip install h5py') from error
    with h5py.File(path, 'r') as f:
        missing = [k for k in ('imu_gyr', 'imu_acc', 'imu_mag') if k not in f]
        if missing or 'sampling_rate' not in f.attrs:
            missing = missing or ['sampling_rate']
            raise ValueError(f'{path}: expected imu_gyr, imu_acc, imu_mag and the attribute '
                             f'sampling_rate (BROAD\'s layout); missing {missing}')
        return (f['imu_gyr'][()], f['imu_acc'][()], f['imu_mag'][()],
                float(np.squeeze(f.attrs['sampling_rate'])), 'uT')


def read_npz(path):
    """``gyr``, ``acc``, ``mag`` (µT) and ``rate``, as in ``test/data``."""
    with np.load(path) as f:
        missing = [k for k in ('gyr', 'acc', 'mag', 'rate') if k not in f]
        if missing:
            raise ValueError(f'{path}: missing {missing}')
        return f['gyr'], f['acc'], f['mag'], float(f['rate']), 'uT'


READERS = {'.hdf5': read_hdf5, '.h5': read_hdf5, '.npz': read_npz}


def read_recording(path):
    """``(gyr, acc, mag, rate, unit)`` of a recording, by its extension (:data:`READERS`)."""
    ext = os.path.splitext(path)[1].lower()
    if ext not in READERS:
        raise ValueError(f'{path}: no reader for {ext!r} files (known: {", ".join(READERS)})')
    return READERS[ext](path)


# --- the params file --------------------------------------------------------

def params_text(bias_tesla, soft_iron, node=NODE, comment='', gyro_bias=None):
    """
    The ROS 2 params file of a calibration.

    Parameters
    ----------
    bias_tesla : sequence of 3 floats or None
        ``b`` in T; None: no magnetometer calibration in the file.
    soft_iron : array_like, shape (3, 3) or (9,)
        ``S`` (with ``bias_tesla``).
    node : str
        The node's name in the file.
    comment : str
        Lines put first, as YAML comments.
    gyro_bias : sequence of 3 floats, optional
        The gyro bias, rad/s (``gyro_bias_*`` of ``imu_filter_node``).

    """
    lines = [f'# {line}' for line in comment.splitlines()]
    lines += [f'{node}:', '  ros__parameters:']
    if bias_tesla is not None:
        b, s = check_calibration(bias_tesla, soft_iron)
        lines += [f'    mag_bias_x: {float(b[0])!r}', f'    mag_bias_y: {float(b[1])!r}',
                  f'    mag_bias_z: {float(b[2])!r}',
                  '    mag_soft_iron: [' + ', '.join(repr(float(v)) for v in s.ravel()) + ']']
    if gyro_bias is not None:
        lines += [f'    gyro_bias_{axis}: {float(v)!r}' for axis, v in zip('xyz', gyro_bias)]
    return '\n'.join(lines) + '\n'


def write_params(path, bias_tesla, soft_iron, node=NODE, comment='', gyro_bias=None):
    """Write :func:`params_text` to ``path``."""
    text = params_text(bias_tesla, soft_iron, node, comment, gyro_bias)
    with open(path, 'w', encoding='utf-8') as f:
        f.write(text)


def read_params(path, node=NODE):
    """
    Read a calibration back from a params file.

    Returns
    -------
    bias_tesla : ndarray, shape (3,)
    soft_iron : ndarray, shape (3, 3)

    Raises
    ------
    ValueError
        When the node, a parameter, or a valid value is missing.

    """
    import yaml
    with open(path, encoding='utf-8') as f:
        doc = yaml.safe_load(f)
    try:
        values = doc[node]['ros__parameters']
    except (KeyError, TypeError):
        raise ValueError(f'{path}: no {node}: ros__parameters: section') from None
    missing = [k for k in ('mag_bias_x', 'mag_bias_y', 'mag_bias_z', 'mag_soft_iron')
               if k not in values]
    if missing:
        raise ValueError(f'{path}: missing {missing}')
    return check_calibration([values['mag_bias_x'], values['mag_bias_y'], values['mag_bias_z']],
                             values['mag_soft_iron'])


# --- the command ------------------------------------------------------------

def build_parser():
    """Return the argument parser of ``python -m ext_observer calibrate``."""
    parser = argparse.ArgumentParser(
        prog='python -m ext_observer calibrate',
        description='Learn the magnetometer\'s hard- and soft-iron calibration from a '
                    'recording and write it as a params file for imu_filter_node.')
    parser.add_argument('--data', required=True, metavar='FILE',
                        help=f'the recording: {", ".join(READERS)} (HDF5 in BROAD\'s layout), '
                             '.csv (python -m ext_observer csv\'s columns, field in T) or a '
                             'rosbag2 bag (a folder, .mcap or .db3)')
    parser.add_argument('--imu-topic', default='imu/data_raw',
                        help='of a bag: the sensor_msgs/Imu topic (default imu/data_raw)')
    parser.add_argument('--mag-topic', default='imu/mag',
                        help='of a bag: the sensor_msgs/MagneticField topic (default imu/mag)')
    parser.add_argument('--out', default='mag_calibration.yaml', metavar='FILE',
                        help='the params file to write (default mag_calibration.yaml)')
    parser.add_argument('--unit', choices=sorted(UNITS), default=None,
                        help='unit of the recording\'s field (default: the reader\'s, µT for '
                             'BROAD; a CSV or a bag is in T, as the node takes it); the file '
                             'holds T')
    parser.add_argument('--node', default=NODE, help=f'node name in the file (default {NODE})')
    parser.add_argument('--force', action='store_true',
                        help='write the file even when the calibration has not converged')
    return parser


def main(argv=None):
    """Run the command; return the exit code (1: not converged, 2: bad input)."""
    args = build_parser().parse_args(argv)
    try:
        if is_node_recording(args.data):
            unit = 'T'
            result = (read_csv(args.data) if args.data.lower().endswith('.csv')
                      else read_bag(args.data, args.imu_topic, args.mag_topic))
        else:
            gyr, acc, mag, rate, unit = read_recording(args.data)
            unit = args.unit or unit
            result = estimate_calibration(gyr, acc, mag, rate)
    except (ValueError, RuntimeError, OSError) as error:
        print(f'error: {error}', file=sys.stderr)
        return 2
    print(result.summary(unit))
    if result.state != 'converged' and not args.force:
        print(f'error: the calibration has not converged (heading error '
              f'{math.degrees(result.quality):.1f}° from its uncertainty); turn the body about '
              'more axes for longer, or write it anyway with --force', file=sys.stderr)
        return 1
    comment = (f'Magnetometer calibration learned from {os.path.basename(args.data)}\n'
               'by python -m ext_observer calibrate: m_raw = S m + b, b = mag_bias_* (T),\n'
               f'S = mag_soft_iron (row-major). State {result.state}, heading error from its\n'
               f'uncertainty {math.degrees(result.quality):.2f}°'
               + ('.' if result.applied else '; the sensor looked calibrated: the identity.'))
    write_params(args.out, result.bias * UNITS[unit], result.soft_iron, args.node, comment)
    print(f'wrote {args.out}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
