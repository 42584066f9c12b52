"""
``python -m ext_observer csv IN.csv --out OUT.csv``: a recording as CSV in, the attitude out.

Input: one header line naming the columns, then one line per IMU sample,
comma separated:

=========================  =====================================================
``t``                      time, s (any origin; out-of-order and repeated times are
                           dropped and counted as the node does)
``gyr_x, gyr_y, gyr_z``    angular velocity, rad/s, sensor frame
``acc_x, acc_y, acc_z``    specific force, m/s² (about +9.81 up at rest)
``mag_x, mag_y, mag_z``    optional: magnetic field, T; empty (or ``nan``) on the
                           lines without a field (a slower magnetometer)
``vel_x, vel_y, vel_z``    optional: the body's velocity, m/s (wheel odometry: the
                           velocity aid, in the frame ``velocity_mounting`` and
                           ``velocity_lever_arm`` describe), at ``t``; empty on the
                           lines without one (a slower odometry)
=========================  =====================================================

in any order, other columns ignored. Output, one line per input line:
``t`` (as given), ``qw, qx, qy, qz`` (unit, sensor → ``world_frame``, the
orientation ``imu/data`` would carry), ``roll, pitch, yaw`` (rad,
:func:`~ext_observer.recordings.recording.roll_pitch_yaw`), ``rest`` and
``mag_disturbed`` (0 or 1). The estimate is
:func:`~ext_observer.recordings.recording.attitude_from_imu`'s, so ``imu_filter_node``'s; a line
the node drops repeats the latest estimate (the counts are printed).
``--smooth``: the quaternions and angles are the smoothed estimate's, each
line's attitude from the whole recording (``attitude_from_imu(...,
smooth=True)``); ``rest`` and ``mag_disturbed`` stay the online run's.
"""

import argparse
import csv
import math
import sys

import numpy as np

from ext_observer.core.ahrs.compiled import warn_if_plain
from ext_observer.recordings.recording import (add_parameter_options, attitude_from_imu,
                                    parameters_from_options)

__all__ = ['FIELD_COLUMNS', 'IMU_COLUMNS', 'OUTPUT_COLUMNS', 'VELOCITY_COLUMNS', 'build_parser',
           'main', 'read_columns', 'read_recording', 'read_velocity', 'write_columns',
           'write_recording']

IMU_COLUMNS = ('t', 'gyr_x', 'gyr_y', 'gyr_z', 'acc_x', 'acc_y', 'acc_z')
FIELD_COLUMNS = ('mag_x', 'mag_y', 'mag_z')
VELOCITY_COLUMNS = ('vel_x', 'vel_y', 'vel_z')
OUTPUT_COLUMNS = ('t', 'qw', 'qx', 'qy', 'qz', 'roll', 'pitch', 'yaw', 'rest',
                  'mag_disturbed')


def read_columns(path, wanted):
    """
    Return the columns ``wanted`` of a CSV file with a header line, as floats.

    Empty cells are NaN.

    Returns
    -------
    columns : dict
        ``name -> ndarray`` for the wanted names the header has.

    Raises
    ------
    ValueError
        Naming the line and the column of a cell that is not a number, or a
        line with another number of cells than the header.

    """
    with open(path, newline='', encoding='utf-8-sig') as stream:
        lines = csv.reader(stream)
        header = next(lines, None)
        if header is None:
            raise ValueError(f'{path}: empty (a header line naming the columns is expected)')
        header = [name.strip() for name in header]
        where = {name: i for i, name in enumerate(header) if name in wanted}
        if len(set(header)) != len(header):
            doubled = sorted({name for name in header if header.count(name) > 1})
            raise ValueError(f'{path}: columns named twice: {", ".join(doubled)}')
        picks = list(where.values())
        values = []
        for number, line in enumerate(lines, start=2):
            if not line or (len(line) == 1 and not line[0].strip()):
                continue
            if len(line) != len(header):
                raise ValueError(f'{path}, line {number}: {len(line)} cells, the header '
                                 f'has {len(header)}')
            try:
                values.append([float(line[i]) if line[i].strip() else math.nan
                               for i in picks])
            except ValueError:
                bad = next(i for i in picks if not _number(line[i]))
                raise ValueError(f'{path}, line {number}, column {header[bad]}: '
                                 f'{line[bad]!r} is not a number') from None
    array = np.array(values, dtype=float).reshape(-1, len(picks))
    return {name: array[:, j] for j, name in enumerate(where)}


def _number(text):
    try:
        float(text) if text.strip() else None
    except ValueError:
        return False
    return True


def read_recording(path):
    """
    Return ``times, gyr, acc, mag`` (``mag`` None without the field's columns).

    Raises
    ------
    ValueError
        Naming a missing column (``mag_*``: all three or none).

    """
    columns = read_columns(path, IMU_COLUMNS + FIELD_COLUMNS)
    missing = [name for name in IMU_COLUMNS if name not in columns]
    field = [name for name in FIELD_COLUMNS if name in columns]
    if field and len(field) < 3:
        missing += [name for name in FIELD_COLUMNS if name not in columns]
    if missing:
        raise ValueError(f'{path}: no column {", ".join(missing)} (the header must name '
                         f'{", ".join(IMU_COLUMNS)}[, {", ".join(FIELD_COLUMNS)}])')

    def stack(names):
        return np.column_stack([columns[name] for name in names])

    return (columns['t'], stack(IMU_COLUMNS[1:4]), stack(IMU_COLUMNS[4:]),
            stack(FIELD_COLUMNS) if field else None)


def read_velocity(path):
    """
    Return ``times, velocity`` of the lines with a velocity (None, None without its columns).

    Raises
    ------
    ValueError
        Naming a missing column (``vel_*``: all three or none), or a line with
        only some of the three.

    """
    columns = read_columns(path, ('t',) + VELOCITY_COLUMNS)
    found = [name for name in VELOCITY_COLUMNS if name in columns]
    if not found:
        return None, None
    if len(found) < 3:
        missing = [name for name in VELOCITY_COLUMNS if name not in columns]
        raise ValueError(f'{path}: no column {", ".join(missing)} (vel_x, vel_y, vel_z: all '
                         'three or none)')
    velocity = np.column_stack([columns[name] for name in VELOCITY_COLUMNS])
    given = ~np.isnan(velocity)
    partial = np.flatnonzero(given.any(axis=1) & ~given.all(axis=1))
    if len(partial):
        t = float(columns['t'][partial[0]])
        raise ValueError(f'{path}, the line of t = {t!r}: a velocity with only some of vel_x, '
                         'vel_y, vel_z')
    rows = given.all(axis=1)
    return columns['t'][rows], velocity[rows]


def write_columns(path, names, array):
    """Write ``array`` (rows) under a header line of ``names``; floats in full (repr)."""
    with open(path, 'w', encoding='utf-8') as stream:
        stream.write(','.join(names) + '\n')
        stream.writelines(','.join(map(repr, row)) + '\n' for row in array.tolist())


def write_recording(path, recording):
    """Write a :class:`~ext_observer.recordings.recording.Recording`: :data:`OUTPUT_COLUMNS`."""
    table = np.column_stack([recording.times, recording.quaternions,
                             recording.roll_pitch_yaw(), recording.rest.astype(float),
                             recording.mag_disturbed.astype(float)])
    with open(path, 'w', encoding='utf-8') as stream:
        stream.write(','.join(OUTPUT_COLUMNS) + '\n')
        stream.writelines(','.join(map(repr, row[:8])) + f',{row[8]:.0f},{row[9]:.0f}\n'
                          for row in table.tolist())


def build_parser():
    """Return the parser of ``python -m ext_observer csv``."""
    parser = argparse.ArgumentParser(
        prog='python -m ext_observer csv',
        description="imu_filter_node's estimator on a CSV recording: columns t, gyr_x, gyr_y, "
                    'gyr_z, acc_x, acc_y, acc_z[, mag_x, mag_y, mag_z][, vel_x, vel_y, vel_z] '
                    '(s, rad/s, m/s², T, m/s) in; t, qw, qx, qy, qz, roll, pitch, yaw, rest, '
                    'mag_disturbed out.')
    parser.add_argument('csv', help='the input CSV file')
    parser.add_argument('--out', required=True, help='the output CSV file')
    add_parameter_options(parser)
    parser.add_argument('--plot', metavar='FILE.png', help='roll, pitch, yaw and the flags')
    parser.add_argument('--smooth', action='store_true',
                        help='the smoothed estimate: each line from the whole recording, the '
                             'lines after it too')
    return parser


def main(argv=None):
    """Run ``python -m ext_observer csv``; return the exit code."""
    args = build_parser().parse_args(argv)
    warn_if_plain()
    try:
        parameters = parameters_from_options(args)
        times, gyr, acc, mag = read_recording(args.csv)
        velocity_times, velocity = read_velocity(args.csv)
        recording = attitude_from_imu(gyr, acc, mag, times=times, parameters=parameters,
                                      velocity=velocity, velocity_times=velocity_times,
                                      smooth=args.smooth)
        write_recording(args.out, recording)
    except (ValueError, OSError) as error:
        print(f'error: {error}', file=sys.stderr)
        return 2
    counts = recording.counts
    print(f'wrote {args.out}: {counts["imu_samples"]} lines, {counts["estimates"]} estimates, '
          f'fields {counts["fields"]} (used {counts["fields_used"]}); dropped: '
          f'{recording.dropped_text()}' + ('; smoothed' if recording.smoothed else ''))
    if args.plot:
        from ext_observer.recordings.recording_plot import plot_recording
        plot_recording(recording, args.plot, title=args.csv)
        print(f'  plot: {args.plot}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
