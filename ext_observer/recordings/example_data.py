"""
``python -m ext_observer example-data``: a bag and a CSV to try the commands on.

Made from a BROAD excerpt shipped in ``test/data/`` (Laidig et al. 2021,
CC BY 4.0; ``test/data/README.md``): by default the 60 s of trial 01 at its
285.7 Hz, the field (T) with every third sample, written as

- ``OUT/broad_01_mcap/`` and ``OUT/broad_01_sqlite3/``: rosbag2 bags with
  ``/imu/data_raw`` (``sensor_msgs/Imu``), ``/imu/mag``
  (``sensor_msgs/MagneticField``) and ``/mocap/orientation``
  (``geometry_msgs/QuaternionStamped``: BROAD's optical reference, sensor →
  ENU, on the samples BROAD scores: those of its movement phase where the
  cameras saw the body);
- ``OUT/broad_01.csv``: the columns of :mod:`ext_observer.recordings.csvio`, the field
  only on the rows that have one.

Each IMU sample is stamped ``1000 s + round(k / rate)`` (ns) and received 1
ms after its stamp; its field (stamped like it) right after it, so that the node, a bag and
:func:`~ext_observer.recordings.recording.attitude_from_imu` all see the order of
``test/broad_replay.py``. ``--seconds``, ``--rate`` and ``--mag-every``
make a longer recording by looping the excerpt (the stamps go on).

``--speed`` measures the bag command on the bag it made against the
estimator's own time: the command as a user runs it (a new interpreter,
``python -m ext_observer bag``, wall clock), beside
:class:`~ext_observer.pipeline.raw_imu.RawImuPipeline` alone on the same samples in
the same order, in one process; medians of ``--rounds`` interleaved runs.
"""

import argparse
import os
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time

import numpy as np

from ext_observer.recordings.bag_io import BagWriter
from ext_observer.recordings.cdr import (encode_field, encode_imu, FIELD_TYPE, IMU_TYPE,
                              QUATERNION_TYPE, QuaternionStamped)
from ext_observer.recordings.recording import SECOND, START

__all__ = ['EXCERPTS', 'build_parser', 'excerpt', 'load_excerpt', 'main', 'write_bag',
           'write_csv']

DATA = os.path.join(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))),
                    'test', 'data')
EXCERPTS = ('01_undisturbed_slow_rotation_A', '28_disturbed_stationary_magnet_A')
TESLA_PER_MICROTESLA = 1e-6
LATENCY = 1_000_000  # ns from a stamp to the bag's receive time
FRAME = 'imu_link'
REFERENCE_TOPIC = '/mocap/orientation'


def load_excerpt(trial=EXCERPTS[0]):
    """Return a shipped excerpt as a dict of arrays (``test/data/README.md``)."""
    path = os.path.join(DATA, f'broad_{trial}.npz')
    if not os.path.exists(path):
        raise ValueError(f'{path} not found: the excerpts ship with the repository '
                         '(test/data/); run this from a clone')
    with np.load(path) as data:
        return {key: data[key] for key in data.files}


def excerpt(data, seconds=None, rate=None, mag_every=3):
    """
    Return a recording made of an excerpt: its samples, looped if need be.

    Parameters
    ----------
    data : dict
        :func:`load_excerpt`'s.
    seconds : float, optional
        Length; default the excerpt's.
    rate : float, optional
        IMU rate, Hz; default the excerpt's.
    mag_every : int
        The field of every ``mag_every``-th sample.

    Returns
    -------
    dict
        ``stamps`` (ns, list), ``received`` (the bag's receive times, ns),
        ``gyr``, ``acc`` (N, 3), ``field_index``
        (the samples with a field), ``field`` (T, one row per sample),
        ``reference`` (N, 4; NaN where BROAD does not score), ``rate``.

    """
    rate = float(data['rate']) if rate is None else float(rate)
    length = len(data['gyr'])
    count = length if seconds is None else int(round(seconds * rate))
    rows = np.arange(count) % length
    reference = np.asarray(data['opt_quat'], dtype=float)[rows]
    reference[~np.asarray(data['movement'], dtype=bool)[rows]] = np.nan
    stamps = [START + round(k * SECOND / rate) for k in range(count)]
    return {'stamps': stamps, 'received': [stamp + LATENCY for stamp in stamps],
            'gyr': data['gyr'][rows], 'acc': data['acc'][rows],
            'field_index': np.arange(0, count, mag_every),
            'field': data['mag'][rows] * TESLA_PER_MICROTESLA,
            'reference': reference, 'rate': rate}


def write_bag(path, recording, storage='mcap', reference=True):
    """Write a recording (:func:`excerpt`) as a rosbag2 bag; return its path."""
    topics = [('/imu/data_raw', IMU_TYPE, []), ('/imu/mag', FIELD_TYPE, [])]
    if reference:
        topics.append((REFERENCE_TOPIC, QUATERNION_TYPE, []))
    writer = BagWriter(path, storage, topics)
    imu, mag = writer.ids[:2]
    has_field = np.zeros(len(recording['stamps']), dtype=bool)
    has_field[recording['field_index']] = True
    scored = np.isfinite(recording['reference']).all(axis=1) & reference
    optical = QuaternionStamped('world')
    for stamp, received, gyr, acc, field, with_field, q, with_q in zip(
            recording['stamps'], recording['received'], recording['gyr'].tolist(),
            recording['acc'].tolist(), recording['field'].tolist(), has_field,
            recording['reference'].tolist(), scored):
        writer.write(imu, received, encode_imu(stamp, FRAME, gyr, acc))
        if with_field:
            writer.write(mag, received + 1000, encode_field(stamp, FRAME, field))
        if with_q:
            writer.write(writer.ids[2], received + 2000, optical(stamp, *q))
    writer.close()
    return path


def write_csv(path, recording):
    """Write a recording (:func:`excerpt`) as a CSV of ``csvio``'s columns."""
    from ext_observer.recordings.csvio import write_columns
    count = len(recording['stamps'])
    mag = np.full((count, 3), np.nan)
    mag[recording['field_index']] = recording['field'][recording['field_index']]
    times = (np.array(recording['stamps'], dtype=np.int64) - START) * 1e-9
    write_columns(path, ('t', 'gyr_x', 'gyr_y', 'gyr_z', 'acc_x', 'acc_y', 'acc_z',
                         'mag_x', 'mag_y', 'mag_z'),
                  np.column_stack([times, recording['gyr'], recording['acc'], mag]))
    return path


def estimator_seconds(recording, params=None):
    """
    Time RawImuPipeline alone on a recording's samples, in the bag's order: wall, CPU (s).

    ``params``: a params file of ``imu_filter_node`` (None: the defaults).
    """
    from ext_observer.pipeline.raw_imu import RawImuPipeline
    from ext_observer.recordings.recording import node_settings, parameters_from_yaml
    settings = node_settings(parameters_from_yaml(params) if params else None,
                             strict_types=True)
    stamps = recording['stamps']
    gyr, acc = recording['gyr'].tolist(), recording['acc'].tolist()
    field = recording['field'].tolist()
    with_field = np.zeros(len(stamps), dtype=bool)
    with_field[recording['field_index']] = True
    with_field = with_field.tolist()
    pipeline = RawImuPipeline(settings, depth=settings['queue_depth'])
    imu, take_field = pipeline.imu, pipeline.field
    start, cpu = time.perf_counter(), time.process_time()
    for k, stamp in enumerate(stamps):
        imu(stamp, gyr[k], acc[k])
        if with_field[k]:
            take_field(stamp, field[k])
    return time.perf_counter() - start, time.process_time() - cpu


def _speed(bag, recording, rounds, storage, params=None):
    """Medians of interleaved runs: the bag command and the estimator alone, wall and CPU."""
    given = ['--params', params] if params else []
    command, estimator = [], []
    with tempfile.TemporaryDirectory() as scratch:
        for i in range(rounds):
            out = os.path.join(scratch, f'out{i}')
            before = resource.getrusage(resource.RUSAGE_CHILDREN)
            start = time.perf_counter()
            done = subprocess.run([sys.executable, '-m', 'ext_observer', 'bag', bag, '--out',
                                   out] + given, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                                  text=True)
            wall = time.perf_counter() - start
            after = resource.getrusage(resource.RUSAGE_CHILDREN)
            if done.returncode:
                raise ValueError(f'the bag command failed: {done.stderr.strip()}')
            shutil.rmtree(out)
            command.append((wall, after.ru_utime + after.ru_stime - before.ru_utime
                            - before.ru_stime))
            estimator.append(estimator_seconds(recording, params))
            print(f'  round {i + 1}: bag command {command[-1][0]:.2f} s (CPU '
                  f'{command[-1][1]:.2f} s), estimator {estimator[-1][0]:.2f} s (CPU '
                  f'{estimator[-1][1]:.2f} s)', file=sys.stderr)
        split = _split(bag, os.path.join(scratch, 'split'), params)
    wall = [statistics.median(run[0] for run in runs) for runs in (command, estimator)]
    cpu = [statistics.median(run[1] for run in runs) for runs in (command, estimator)]
    print(f'{storage} bag, {len(recording["stamps"])} IMU samples at {recording["rate"]:g} Hz, '
          f'{len(recording["field_index"])} fields: bag command {wall[0]:.2f} s, estimator '
          f'alone {wall[1]:.2f} s: {wall[0] / wall[1]:.2f}x (wall clock, medians of {rounds}); '
          f'CPU {cpu[0]:.2f} s (both processes) and {cpu[1]:.2f} s: {cpu[0] / cpu[1]:.2f}x; '
          f'load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs')
    print(f'one run in this process: the estimator\'s process {split[0]:.2f} s CPU, the bag '
          f'process (reading, decoding, encoding, writing) {split[1]:.2f} s CPU, '
          f'{split[2]:.2f} s wall')


def _split(bag, out, params=None):
    """CPU of the two processes of one bag command run from here: (ours, the child's, wall)."""
    from ext_observer.recordings.bag import run_bag
    from ext_observer.recordings.recording import parameters_from_yaml
    parameters = parameters_from_yaml(params) if params else None
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu, start = time.process_time(), time.perf_counter()
    with open(os.devnull, 'w') as quiet:
        run_bag(bag, out, parameters=parameters, progress=quiet)
    wall, cpu = time.perf_counter() - start, time.process_time() - cpu
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return cpu, after.ru_utime + after.ru_stime - before.ru_utime - before.ru_stime, wall


def build_parser():
    """Return the parser of ``python -m ext_observer example-data``."""
    parser = argparse.ArgumentParser(
        prog='python -m ext_observer example-data',
        description='A bag (MCAP and sqlite3) and a CSV made from a shipped BROAD excerpt.')
    parser.add_argument('--out', default='out/example', help='folder (default out/example)')
    parser.add_argument('--trial', choices=EXCERPTS, default=EXCERPTS[0])
    parser.add_argument('--seconds', type=float,
                        help="length, s (default the excerpt's 60 s; longer loops it)")
    parser.add_argument('--rate', type=float, help="IMU rate, Hz (default the excerpt's)")
    parser.add_argument('--mag-every', type=int, default=3,
                        help='a field with every N-th sample (default 3)')
    parser.add_argument('--storage', choices=('mcap', 'sqlite3', 'both'), default='both')
    parser.add_argument('--no-csv', action='store_true', help='bags only')
    parser.add_argument('--no-reference', action='store_true',
                        help=f'no {REFERENCE_TOPIC} topic (IMU and field only)')
    parser.add_argument('--speed', action='store_true',
                        help="time the bag command on the bag against the estimator's own "
                             'time (one storage)')
    parser.add_argument('--rounds', type=int, default=3, help='with --speed (default 3)')
    parser.add_argument('--params', metavar='FILE.yaml',
                        help="with --speed: imu_filter_node's parameters for both the bag "
                             'command and the estimator alone (default: the defaults)')
    return parser


def main(argv=None):
    """Run ``python -m ext_observer example-data``; return the exit code."""
    args = build_parser().parse_args(argv)
    try:
        recording = excerpt(load_excerpt(args.trial), args.seconds, args.rate, args.mag_every)
    except ValueError as error:
        print(f'error: {error}', file=sys.stderr)
        return 2
    os.makedirs(args.out, exist_ok=True)
    name = f'broad_{args.trial[:2]}'
    storages = ('mcap', 'sqlite3') if args.storage == 'both' else (args.storage,)
    for storage in storages:
        path = os.path.join(args.out, f'{name}_{storage}')
        if os.path.exists(path):
            shutil.rmtree(path)
        write_bag(path, recording, storage, reference=not args.no_reference)
        print(f'wrote {path} ({storage}): /imu/data_raw, /imu/mag'
              + ('' if args.no_reference else f', {REFERENCE_TOPIC}'))
    if not args.no_csv:
        path = write_csv(os.path.join(args.out, f'{name}.csv'), recording)
        print(f'wrote {path}')
    if args.speed:
        try:
            _speed(os.path.join(args.out, f'{name}_{storages[0]}'), recording, args.rounds,
                   storages[0], args.params)
        except ValueError as error:
            print(f'error: {error}', file=sys.stderr)
            return 2
    return 0


if __name__ == '__main__':
    sys.exit(main())
