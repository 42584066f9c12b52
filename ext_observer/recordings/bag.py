"""
``python -m ext_observer bag IN --out OUT``: ``imu_filter_node`` on a rosbag2 bag, without ROS.

Reads ``sensor_msgs/Imu`` (``--imu-topic``, default ``imu/data_raw``) and
``sensor_msgs/MagneticField`` (``--mag-topic``, default ``imu/mag``) from a
rosbag2 bag, MCAP or sqlite3 (a bag folder, or one ``.mcap`` or ``.db3``
file), with the ``rosbags`` library; the stamps come from the headers, the
messages in the bag's receive order, as the node would have got them. Each
goes through :class:`~ext_observer.recordings.recording.PipelineRun` (the node's
:class:`~ext_observer.pipeline.raw_imu.RawImuPipeline`), and a new bag is written
(``--out``, never over an existing path; the storage of the input unless
``--storage``) with the input topics, ``imu/data`` (the input sample with
its orientation set to the normalized estimate and
``orientation_covariance`` as the node fills it: the estimate's own, or
``orientation_stddev``'s) and ``attitude_estimate`` (``geometry_msgs/QuaternionStamped``, the
ambient estimate, ``frame_id`` from the parameter), each stamped like the
sample and written at the sample's receive time, so that ``ros2 bag play
OUT`` replays them. ``--compare TOPIC`` scores the estimate against an
orientation topic of the bag (``sensor_msgs/Imu``,
``geometry_msgs/QuaternionStamped`` or ``PoseStamped``, sensor → world in
the same world frame), matched by stamp, with BROAD's error angles
(:mod:`ext_observer.broad.scoring`). ``--velocity-topic TOPIC`` takes the
body's velocity from a ``nav_msgs/Odometry`` (``twist.twist.linear``) or
``geometry_msgs/TwistStamped`` (``twist.linear``) topic, m/s, for the
velocity aid (``velocity_mounting``, ``velocity_lever_arm`` as the node's).
The input bag is only read.

Bad input: a missing topic or a topic of another type stops the command
with an error naming it and listing the bag's topics; samples the node would
drop (stamps out of order or repeated, NaN, zero vectors, gaps) are dropped
and counted by the pipeline, and the counts printed; a message that does not
decode (a truncated record) is counted as ``undecodable``; a storage that
cannot be read to its end (a truncated file) stops the command with the
reader's reason, and the partial output is removed.

Two processes share the work (:mod:`ext_observer.recordings.bag_worker`; one where
``fork`` is not available, or with ``parallel=False``): this one runs the
estimator, a forked one reads, decodes, encodes and writes a batch ahead,
so that reading and writing cost little beside the estimator on a machine
with a core to spare.

``--smooth`` writes the smoothed estimate
(:func:`~ext_observer.recordings.smoothing.smoothed_attitude`: each sample's
attitude from the whole recording), which needs the whole recording before
the first estimate is written: a first pass runs the estimator as above
and keeps the inputs as arrays (:class:`~ext_observer.recordings.bag_worker.KeepingEstimator`),
the smoother runs on them, and a second pass (in this process) reads the
bag again and writes the new one with the smoothed estimates
(:class:`~ext_observer.recordings.bag_worker.SmoothedStates`): the same
messages as without, ``imu/data``'s ``orientation_covariance`` the smoothed
σ's where it carries the estimate's own.
"""

import argparse
import collections
import math
import os
import shutil
import sys
import time

import numpy as np

from ext_observer.core.ahrs.compiled import warn_if_plain
from ext_observer.recordings.bag_io import BagReader, STORAGES
from ext_observer.recordings.bag_worker import (BagEstimator, BagSide, fork_context, forked,
                                               in_process, KeepingEstimator, SmoothedStates,
                                               VELOCITY_TYPES)
from ext_observer.recordings.cdr import FIELD_TYPE, IMU_TYPE, QUATERNION_TYPE, REFERENCE_TYPES
from ext_observer.recordings.recording import (add_parameter_options, node_settings,
                                    parameters_from_options, SECOND)

__all__ = ['BagRun', 'build_parser', 'compare', 'main', 'report', 'run_bag']

# Bags with more messages than this show progress.
PROGRESS_MIN = 20000


class _Progress:
    """Messages read so far, on stderr: in place on a terminal, else every 10 %."""

    def __init__(self, total, stream=None):
        self.total = total
        self.stream = sys.stderr if stream is None else stream
        self.tty = self.stream.isatty()
        self.step = max(1, total // (100 if self.tty else 10))
        self.next = self.step if total >= PROGRESS_MIN else float('inf')
        self.shown = 0
        self.start = time.monotonic()

    def __call__(self, done):
        """Show ``done`` messages of the total."""
        self.next = done + self.step
        self.shown = done
        text = (f'bag: {100 * done // self.total:3d} % ({done} / {self.total} messages, '
                f'{time.monotonic() - self.start:.1f} s)')
        print(('\r' + text) if self.tty else text, end='' if self.tty else '\n',
              file=self.stream, flush=True)

    def finish(self, done):
        """Show the end (when progress was shown)."""
        if self.total >= PROGRESS_MIN:
            if done != self.shown:
                self(done)
            if self.tty:
                print(file=self.stream)


BagRun = collections.namedtuple('BagRun', 'recording comparison storage topics undecodable '
                                'velocity_drops')
BagRun.__doc__ = """\
What :func:`run_bag` did.

Attributes
----------
recording : ext_observer.recordings.recording.Recording
    One row per IMU message, in receive order.
comparison : dict or None
    :func:`compare`'s result with ``topic`` and ``type``, when asked.
storage : str
    Of the output.
topics : dict
    ``role -> (topic, type, messages)`` for ``imu``, ``mag``, ``reference``,
    ``velocity``, ``data``, ``estimate``.
undecodable : dict
    Messages that did not decode, by topic.
velocity_drops : dict
    Velocities the pipeline dropped, by reason (``not_finite``, ``out_of_order``).
"""


def _absolute(topic):
    return topic if topic.startswith('/') else '/' + topic


def _storage_of(path):
    if os.path.isdir(path):
        names = os.listdir(path)
        for storage, suffix in (('mcap', '.mcap'), ('sqlite3', '.db3')):
            if any(name.endswith(suffix) or name.endswith(suffix + '.zstd') for name in names):
                return storage
        return 'mcap'
    return 'sqlite3' if path.endswith('.db3') else 'mcap'


def _find(connections, topic, types, role, option):
    """Return the connections of ``topic`` with one of ``types``."""
    found = [c for c in connections if c.topic == topic]
    listing = ', '.join(sorted({f'{c.topic} ({c.msgtype})' for c in connections})) or 'none'
    if not found:
        raise ValueError(f'no topic {topic} in the bag (the {role}, {option}); its topics: '
                         f'{listing}')
    usable = [c for c in found if c.msgtype in types]
    if not usable:
        raise ValueError(f'topic {topic} carries {", ".join(sorted({c.msgtype for c in found}))}'
                         f'; the {role} must be {" or ".join(types)}')
    return usable


def run_bag(path, out, imu_topic='imu/data_raw', mag_topic='imu/mag', compare_topic=None,
            parameters=None, storage=None, data_topic='imu/data',
            estimate_topic='attitude_estimate', progress=None, parallel=True,
            velocity_topic=None, smooth=False):
    """
    Run ``imu_filter_node``'s estimator on a bag; write the new bag.

    Parameters
    ----------
    path : str
        The input bag: a rosbag2 folder, or one ``.mcap`` or ``.db3`` file.
    out : str or None
        The new bag's folder; must not exist. None: no new bag (the run and
        its recording only, as ``calibrate`` uses it).
    imu_topic, mag_topic : str
        ``sensor_msgs/Imu`` and ``sensor_msgs/MagneticField`` (relative names
        are taken from the root: ``/imu/data_raw``); ``mag_topic`` is not
        read when ``use_mag`` is false.
    compare_topic : str, optional
        An orientation topic to score the estimate against (:func:`compare`);
        it may be the IMU's own.
    parameters : dict, optional
        ``imu_filter_node`` parameter values (a params file's types).
    storage : {'mcap', 'sqlite3'}, optional
        Of the output; default: the input's.
    data_topic, estimate_topic : str
        The outputs (the node's ``imu/data`` and ``attitude_estimate``).
    progress : file, optional
        Where progress goes (default stderr; shown from :data:`PROGRESS_MIN`
        messages on).
    parallel : bool
        Read and write in a forked process (module docstring).
    velocity_topic : str, optional
        ``nav_msgs/Odometry`` or ``geometry_msgs/TwistStamped``: the body's
        velocity for the velocity aid.
    smooth : bool
        Write the smoothed estimate (module docstring, ``--smooth``): the
        recording and the comparison are the smoothed estimate's.

    Returns
    -------
    BagRun

    Raises
    ------
    ValueError
        A missing topic, a topic of another type, a bag that cannot be read
        to its end, an existing output, a parameter.

    """
    settings = node_settings(parameters, strict_types=True)
    storage = storage or _storage_of(str(path))
    _check_paths(path, out, storage)
    reader = BagReader(path)
    roles, topics = _roles_and_topics(reader, settings, (imu_topic, mag_topic, compare_topic,
                                                         velocity_topic),
                                      (data_topic, estimate_topic))
    side = BagSide(reader, roles, None if smooth else out, storage, topics, settings)
    estimator = (KeepingEstimator if smooth else BagEstimator)(
        settings, _Progress(side.total, progress))
    context = fork_context() if parallel else None
    try:
        counts = (in_process(side, estimator) if context is None
                  else forked(context, side, estimator))
        if smooth:
            counts = _write_smoothed(estimator, BagSide(reader, roles, out, storage, topics,
                                                        settings),
                                     settings, progress)
        recording = estimator.recording
        comparison = (_compare_references(recording, estimator.references, topics['reference'])
                      if 'reference' in roles else None)
    except BaseException:
        if out is not None:
            shutil.rmtree(out, ignore_errors=True)
        raise
    return _bag_run(recording, comparison, storage, topics, counts, estimator)


def _bag_run(recording, comparison, storage, topics, counts, estimator):
    """The :class:`BagRun`: each role's topic, type and messages, what was not decoded."""
    return BagRun(recording, comparison, storage,
                  {role: (topic, msgtype, counts[role])
                   for role, (topic, msgtype, _) in topics.items()},
                  {topics[role][0]: n for role, n in estimator.undecodable.items()},
                  dict(estimator.velocity_drops))


def _write_smoothed(estimator, side, settings, progress):
    """
    The second and third steps of ``--smooth``: smooth the kept inputs, write the new bag.

    Puts the smoothed estimate in ``estimator.recording``; returns the
    messages written by role.
    """
    from ext_observer.recordings.recording import smoothed_into
    from ext_observer.recordings.smoothing import smoothed_attitude
    recording = estimator.recording
    estimator.run = None  # the online pipeline's own records, no longer needed
    stamps, gyr, acc, (field_stamps, fields), (velocity_stamps, velocities) = (
        estimator.inputs())
    start = int(stamps[0])

    def seconds(values):
        return (values - start) * 1e-9

    use_mag = settings['use_mag'] and len(fields) > 0
    smoothed_into(recording, smoothed_attitude(
        gyr, acc, fields if use_mag else None, seconds(stamps), settings,
        mag_times=seconds(field_stamps) if use_mag else None,
        velocity=velocities if len(velocities) else None,
        velocity_times=seconds(velocity_stamps) if len(velocities) else None,
        online_std=(recording.inclination_std, recording.heading_std)))
    del gyr, acc, fields, velocities
    # In this process: the estimates are ready, so a forked writer would gain nothing, and it
    # would hold a copy of this process's pages (about 0.5 kB a sample) while it writes.
    return in_process(side, SmoothedStates(recording, settings, _Progress(side.total, progress)))


def _check_paths(path, out, storage):
    """Refuse an unknown storage, a missing input, and an output that exists or lies inside it."""
    if storage not in STORAGES:
        raise ValueError(f'storage must be one of {STORAGES}, got {storage!r}')
    if not os.path.exists(path):
        raise ValueError(f'{path}: no such bag')
    if out is not None and os.path.exists(out):
        raise ValueError(f'{out} exists (never overwritten: remove it or choose another '
                         '--out)')
    if out is not None and os.path.abspath(out).startswith(
            os.path.join(os.path.abspath(path), '')):
        raise ValueError(f'{out} is inside the input bag {path}: the input is only read')


def _roles_and_topics(reader, settings, inputs, outputs):
    """
    Find the input connections by role and name every topic of the run.

    ``inputs`` are the IMU, field, reference and velocity topics (the last
    two may be None), ``outputs`` the data and estimate topics. Returns
    ``roles`` (role: the connections) and ``topics`` (role: name, type, QoS).
    """
    imu_topic, mag_topic, compare_topic, velocity_topic = inputs
    roles = {'imu': _find(reader.connections, _absolute(imu_topic), (IMU_TYPE,), 'IMU',
                          '--imu-topic')}
    if settings['use_mag']:
        roles['mag'] = _find(reader.connections, _absolute(mag_topic), (FIELD_TYPE,),
                             'magnetic field', '--mag-topic; --no-mag for 6D')
    if compare_topic is not None:
        roles['reference'] = _find(reader.connections, _absolute(compare_topic),
                                   tuple(REFERENCE_TYPES), 'reference', '--compare')
    if velocity_topic is not None:
        roles['velocity'] = _find(reader.connections, _absolute(velocity_topic),
                                  VELOCITY_TYPES, 'velocity', '--velocity-topic')
    data_topic, estimate_topic = outputs
    written = {'data': (_absolute(data_topic), IMU_TYPE,
                        roles['imu'][0].ext.offered_qos_profiles),
               'estimate': (_absolute(estimate_topic), QUATERNION_TYPE, [])}
    for role, connections in roles.items():
        if connections[0].topic in (written['data'][0], written['estimate'][0]):
            raise ValueError(f'{connections[0].topic} is both an input ({role}) and an '
                             'output: name the outputs with --data-topic and --estimate-topic')
    topics = {role: (cs[0].topic, cs[0].msgtype, cs[0].ext.offered_qos_profiles)
              for role, cs in roles.items()}
    topics.update(written)
    return roles, topics


def _compare_references(recording, references, topic):
    name, msgtype, _ = topic
    found = [(stamp, q) for stamp, q in references if not math.isnan(q[0])]
    if not found:
        raise ValueError(f'no orientation on {name} (a sensor_msgs/Imu with '
                         'orientation_covariance[0] = -1 has none)')
    comparison = compare(recording, [stamp for stamp, _ in found], [q for _, q in found])
    comparison.update(topic=name, type=msgtype)
    return comparison

def compare(recording, stamps, quaternions, tolerance=None):
    """
    Score a recording's estimates against reference orientations, matched by stamp.

    Each estimate is paired with the reference nearest in stamp, within
    ``tolerance``; the error angles are BROAD's
    (:func:`ext_observer.broad.scoring.error_angles`: total, heading about
    the world's vertical, inclination), their RMSE over the pairs.

    Parameters
    ----------
    recording : ext_observer.recordings.recording.Recording
    stamps : sequence of int
        The references' stamps, ns.
    quaternions : array_like, shape (R, 4)
        ``(w, x, y, z)``, sensor → world (the recording's world frame).
    tolerance : int, optional
        ns; default half the median interval of the IMU samples (an equal
        stamp always matches).

    Returns
    -------
    result : dict
        ``matched`` (pairs), ``total_rmse_deg``, ``heading_rmse_deg``,
        ``inclination_rmse_deg``, ``total_max_deg``, and ``times`` (s),
        ``total``, ``heading``, ``inclination`` (deg) per pair, for a plot.

    """
    from ext_observer.broad.scoring import error_angles, score
    ours = np.flatnonzero(recording.estimated)
    our_stamps = np.round(recording.times[ours] * SECOND).astype(np.int64)
    ref_stamps = np.asarray(stamps, dtype=np.int64)
    ref = np.asarray(quaternions, dtype=float).reshape(-1, 4)
    order = np.argsort(ref_stamps, kind='stable')
    ref_stamps, ref = ref_stamps[order], ref[order]
    if tolerance is None:
        tolerance = (np.median(np.diff(our_stamps)) // 2 if len(our_stamps) > 1 else 0)
    right = np.clip(np.searchsorted(ref_stamps, our_stamps), 0, len(ref_stamps) - 1)
    left = np.clip(right - 1, 0, len(ref_stamps) - 1)
    nearest = np.where(np.abs(ref_stamps[left] - our_stamps)
                       <= np.abs(ref_stamps[right] - our_stamps), left, right)
    matched = (np.abs(ref_stamps[nearest] - our_stamps) <= tolerance) & np.isfinite(
        ref[nearest]).all(axis=1)
    q = recording.quaternions[ours[matched]]
    r = ref[nearest[matched]]
    result = {'matched': int(matched.sum()), 'references': len(ref_stamps)}
    if not result['matched']:
        raise ValueError(f'no reference stamp within {tolerance * 1e-9:.3g} s of an estimate '
                         f'({len(ref_stamps)} references)')
    result.update(score(q, r, None))
    total, heading, inclination = (np.degrees(a) for a in error_angles(q, r))
    result.update(total_max_deg=float(np.max(total)), times=recording.times[ours[matched]],
                  total=total, heading=heading, inclination=inclination)
    return result


def build_parser():
    """Return the parser of ``python -m ext_observer bag``."""
    parser = argparse.ArgumentParser(
        prog='python -m ext_observer bag',
        description="imu_filter_node's estimator on a rosbag2 bag (MCAP or sqlite3), without "
                    'ROS: a new bag with the input topics, imu/data and attitude_estimate.')
    parser.add_argument('bag', help='the input bag: a folder, or one .mcap or .db3 file')
    parser.add_argument('--out', required=True, help='the new bag (a folder; must not exist)')
    parser.add_argument('--imu-topic', default='imu/data_raw',
                        help='sensor_msgs/Imu topic (default imu/data_raw)')
    parser.add_argument('--mag-topic', default='imu/mag',
                        help='sensor_msgs/MagneticField topic, T (default imu/mag)')
    parser.add_argument('--compare', metavar='TOPIC',
                        help='score the estimate against this orientation topic '
                             '(sensor_msgs/Imu, geometry_msgs/QuaternionStamped or PoseStamped)')
    parser.add_argument('--velocity-topic', metavar='TOPIC',
                        help="the body's velocity, m/s, for the velocity aid: "
                             'nav_msgs/Odometry or geometry_msgs/TwistStamped')
    add_parameter_options(parser)
    parser.add_argument('--storage', choices=STORAGES,
                        help="of the new bag (default: the input's)")
    parser.add_argument('--data-topic', default='imu/data', help='default imu/data')
    parser.add_argument('--estimate-topic', default='attitude_estimate',
                        help='default attitude_estimate')
    parser.add_argument('--plot', metavar='FILE.png',
                        help='roll, pitch, yaw, the flags and the comparison error')
    parser.add_argument('--smooth', action='store_true',
                        help='write the smoothed estimate: each sample from the whole '
                             'recording, the samples after it too (reads the bag twice)')
    return parser


def report(run, out):
    """Return the summary lines of a :class:`BagRun`."""
    recording = run.recording
    topics = run.topics
    lines = [f'wrote {out} ({run.storage}): '
             + ', '.join(f'{topic} {count}' for topic, _, count in topics.values())]
    counts = recording.counts
    lines.append(f'  IMU samples {counts["imu_samples"]}, estimates {counts["estimates"]}, '
                 f'fields {counts["fields"]} (used {counts["fields_used"]})')
    lines.append(f'  dropped: {recording.dropped_text()}')
    if recording.smoothed:
        lines.append('  smoothed: the estimates written are from the whole recording')
    resets = ', '.join(f'{cause} {n}' for cause, n in recording.resets.items() if n)
    if resets:
        lines.append(f'  resets: {resets}')
    for kind, (n, text) in recording.units.items():
        lines.append(f'  {n} samples of implausible {kind}: {text}')
    if run.velocity_drops:
        lines.append('  velocities dropped: ' + ', '.join(
            f'{reason} {n}' for reason, n in sorted(run.velocity_drops.items())))
    for topic, n in run.undecodable.items():
        lines.append(f'  {topic}: {n} messages did not decode (skipped)')
    comparison = run.comparison
    if comparison is not None:
        lines.append(
            f'  against {comparison["topic"]} ({comparison["type"]}), {comparison["matched"]} '
            f'samples matched by stamp: RMSE total {comparison["total_rmse_deg"]:.3f}°, '
            f'inclination {comparison["inclination_rmse_deg"]:.3f}°, heading '
            f'{comparison["heading_rmse_deg"]:.3f}°; max total '
            f'{comparison["total_max_deg"]:.3f}°')
    return lines


def main(argv=None):
    """Run ``python -m ext_observer bag``; return the exit code."""
    args = build_parser().parse_args(argv)
    warn_if_plain()
    try:
        parameters = parameters_from_options(args)
        run = run_bag(args.bag, args.out, imu_topic=args.imu_topic, mag_topic=args.mag_topic,
                      compare_topic=args.compare, parameters=parameters,
                      storage=args.storage, data_topic=args.data_topic,
                      estimate_topic=args.estimate_topic,
                      velocity_topic=args.velocity_topic, smooth=args.smooth)
    except (ValueError, OSError) as error:
        print(f'error: {error}', file=sys.stderr)
        return 2
    print('\n'.join(report(run, args.out)))
    if args.plot:
        from ext_observer.recordings.recording_plot import plot_recording
        plot_recording(run.recording, args.plot, title=f'{args.bag}: {args.imu_topic}',
                       comparison=run.comparison)
        print(f'  plot: {args.plot}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
