"""
``python -m ext_observer bag IN --out OUT``: ``imu_filter_node`` on a rosbag2 bag, without ROS.

Reads ``sensor_msgs/Imu`` (``--imu-topic``, default ``imu/data_raw``) and
``sensor_msgs/MagneticField`` (``--mag-topic``, default ``imu/mag``) from a
rosbag2 bag, MCAP or sqlite3 (a bag folder, or one ``.mcap`` or ``.db3``
file), with the ``rosbags`` library; the stamps come from the headers, the
messages in the bag's receive order, as the node would have got them. Each
goes through :class:`~ext_observer.recording.PipelineRun` (the node's
:class:`~ext_observer.raw_imu.RawImuPipeline`), and a new bag is written
(``--out``, never over an existing path; the storage of the input unless
``--storage``) with the input topics, ``imu/data`` (the input sample with
its orientation set to the normalized estimate and
``orientation_covariance`` from ``orientation_stddev``, as the node fills
it) and ``attitude_estimate`` (``geometry_msgs/QuaternionStamped``, the
ambient estimate, ``frame_id`` from the parameter), each stamped like the
sample and written at the sample's receive time, so that ``ros2 bag play
OUT`` replays them. ``--compare TOPIC`` scores the estimate against an
orientation topic of the bag (``sensor_msgs/Imu``,
``geometry_msgs/QuaternionStamped`` or ``PoseStamped``, sensor → world in
the same world frame), matched by stamp, with BROAD's error angles
(:mod:`ext_observer.broad.scoring`). The input bag is only read.

Bad input: a missing topic or a topic of another type stops the command
with an error naming it and listing the bag's topics; samples the node would
drop (stamps out of order or repeated, NaN, zero vectors, gaps) are dropped
and counted by the pipeline, and the counts printed; a message that does not
decode (a truncated record) is counted as ``undecodable``; a storage that
cannot be read to its end (a truncated file) stops the command with the
reader's reason, and the partial output is removed.

Two processes share the work (one where ``fork`` is not available, or with
``parallel=False``): this one runs the estimator; a forked one reads the bag
and decodes its messages, then encodes the estimates and writes the new bag
(:class:`_BagSide`, with :mod:`ext_observer.cdr` and
:mod:`ext_observer.bag_io`), a batch ahead, so that reading and writing cost
little beside the estimator on a machine with a core to spare. Between them
go only numbers: the samples' kinds, stamps and values one way, the
estimates the other. The first message of every input topic is checked
against ``rosbags``' own deserializer.
"""

import argparse
import array
import collections
import gc
import math
import multiprocessing
import os
import shutil
import sys
import time

import numpy as np

from ext_observer.bag_io import BagIOError, BagReader, BagWriter, BATCH, STORAGES
from ext_observer.cdr import (decode_field, decode_orientation, FIELD_TYPE, IMU_TYPE,
                              imu_layout, ImuData, QUATERNION_TYPE, QuaternionStamped,
                              REFERENCE_TYPES, Undecodable)
from ext_observer.recording import (add_parameter_options, node_settings,
                                    parameters_from_options, PipelineRun, SECOND)

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


BagRun = collections.namedtuple('BagRun', 'recording comparison storage topics undecodable')
BagRun.__doc__ = """\
What :func:`run_bag` did.

Attributes
----------
recording : ext_observer.recording.Recording
    One row per IMU message, in receive order.
comparison : dict or None
    :func:`compare`'s result with ``topic`` and ``type``, when asked.
storage : str
    Of the output.
topics : dict
    ``role -> (topic, type, messages)`` for ``imu``, ``mag``, ``reference``,
    ``data``, ``estimate``.
undecodable : dict
    Messages that did not decode, by topic.
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


def _check_first(typestore, connection, role, raw, stamp, values):
    """The first message of a topic: our decoding against rosbags' deserializer."""
    try:
        msg = typestore.deserialize_cdr(raw, connection.msgtype)
    except Exception as error:  # noqa: BLE001 -- any failure of rosbags' decoder
        raise ValueError(f'{connection.topic}: its first message does not deserialize as '
                         f'{connection.msgtype}: {error}') from None
    if role == 'imu':
        expected = _xyz(msg.angular_velocity) + _xyz(msg.linear_acceleration)
    elif role == 'mag':
        expected = _xyz(msg.magnetic_field)
    else:
        o = (msg.pose.orientation if hasattr(msg, 'pose') else
             msg.quaternion if hasattr(msg, 'quaternion') else msg.orientation)
        expected = (o.w, o.x, o.y, o.z) if values is not None else None
    if (stamp != msg.header.stamp.sec * SECOND + msg.header.stamp.nanosec
            or (expected is None) != (values is None)
            or not (values is None or np.array_equal(expected, values, equal_nan=True))):
        raise ValueError(f'{connection.topic}: its messages do not have the layout of '
                         f'{connection.msgtype} (decoded {stamp}, {values}; rosbags: '
                         f'{msg})')


def _xyz(vector):
    return (vector.x, vector.y, vector.z)


def run_bag(path, out, imu_topic='imu/data_raw', mag_topic='imu/mag', compare_topic=None,
            parameters=None, storage=None, data_topic='imu/data',
            estimate_topic='attitude_estimate', progress=None, parallel=True):
    """
    Run ``imu_filter_node``'s estimator on a bag; write the new bag.

    Parameters
    ----------
    path : str
        The input bag: a rosbag2 folder, or one ``.mcap`` or ``.db3`` file.
    out : str
        The new bag's folder; must not exist.
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
    if storage not in STORAGES:
        raise ValueError(f'storage must be one of {STORAGES}, got {storage!r}')
    if not os.path.exists(path):
        raise ValueError(f'{path}: no such bag')
    if os.path.exists(out):
        raise ValueError(f'{out} exists (never overwritten: remove it or choose another '
                         '--out)')
    if os.path.abspath(out).startswith(os.path.join(os.path.abspath(path), '')):
        raise ValueError(f'{out} is inside the input bag {path}: the input is only read')
    reader = BagReader(path)
    roles = {'imu': _find(reader.connections, _absolute(imu_topic), (IMU_TYPE,), 'IMU',
                          '--imu-topic')}
    if settings['use_mag']:
        roles['mag'] = _find(reader.connections, _absolute(mag_topic), (FIELD_TYPE,),
                             'magnetic field', '--mag-topic; --no-mag for 6D')
    if compare_topic is not None:
        roles['reference'] = _find(reader.connections, _absolute(compare_topic),
                                   tuple(REFERENCE_TYPES), 'reference', '--compare')
    outputs = {'data': (_absolute(data_topic), IMU_TYPE,
                        roles['imu'][0].ext.offered_qos_profiles),
               'estimate': (_absolute(estimate_topic), QUATERNION_TYPE, [])}
    for role, connections in roles.items():
        if connections[0].topic in (outputs['data'][0], outputs['estimate'][0]):
            raise ValueError(f'{connections[0].topic} is both an input ({role}) and an '
                             'output: name the outputs with --data-topic and --estimate-topic')
    topics = {role: (cs[0].topic, cs[0].msgtype, cs[0].ext.offered_qos_profiles)
              for role, cs in roles.items()}
    topics.update(outputs)
    side = _BagSide(reader, roles, out, storage, topics, settings)
    estimator = _Estimator(settings, _Progress(side.total, progress))
    context = _fork() if parallel else None
    try:
        counts = (_in_process(side, estimator) if context is None
                  else _forked(context, side, estimator))
        recording = estimator.recording
        comparison = None
        if 'reference' in roles:
            comparison = _compare_references(recording, estimator.references,
                                             topics['reference'])
    except BaseException:
        shutil.rmtree(out, ignore_errors=True)
        raise
    return BagRun(recording, comparison, storage,
                  {role: (topic, msgtype, counts[role])
                   for role, (topic, msgtype, _) in topics.items()},
                  {topics[role][0]: n for role, n in estimator.undecodable.items()})


def _compare_references(recording, references, topic):
    name, msgtype, _ = topic
    found = [(stamp, q) for stamp, q in references if not math.isnan(q[0])]
    if not found:
        raise ValueError(f'no orientation on {name} (a sensor_msgs/Imu with '
                         'orientation_covariance[0] = -1 has none)')
    comparison = compare(recording, [stamp for stamp, _ in found], [q for _, q in found])
    comparison.update(topic=name, type=msgtype)
    return comparison


# What a message is to the estimator (the kinds that cross the pipe), and
# how many values it carries.
IMU, FIELD, REFERENCE, IMU_AND_REFERENCE = 0, 1, 2, 3
UNDECODABLE = {'imu': 4, 'mag': 5, 'reference': 6}
_SIZES = {IMU: 6, FIELD: 3, REFERENCE: 4, IMU_AND_REFERENCE: 10}
_NAN4 = (math.nan,) * 4


class _BagSide:
    """
    The bag's side of the command: read and decode a batch; write it with its estimates.

    Run in the forked process (or in this one): it opens the new bag itself.
    """

    def __init__(self, reader, roles, out, storage, topics, settings):
        self.reader = reader
        self.out = out
        self.storage = storage
        self.topics = topics
        self.settings = settings
        # The IMU's own topic may carry the reference too (an IMU with an AHRS).
        shared = roles.get('reference') == roles['imu']
        self.kinds = {}
        for role, connections in roles.items():
            for c in connections:
                kind = {'imu': IMU, 'mag': FIELD, 'reference': REFERENCE}[role]
                if shared and role != 'mag':
                    kind, role = IMU_AND_REFERENCE, 'imu'
                self.kinds[c.id] = (kind, role, c)
        self._shared = shared
        if shared:
            self.topics = {role: topic for role, topic in topics.items() if role != 'reference'}
        self.total = sum(c.msgcount for _, _, c in self.kinds.values())
        self.writer = None

    def open(self):
        """Create the new bag; its connection ids by role."""
        self.writer = BagWriter(self.out, self.storage, list(self.topics.values()))
        self.ids = dict(zip(self.topics, self.writer.ids))
        if self._shared:
            self.ids['reference'] = self.ids['imu']
        self._imu_data = ImuData(self.settings['orientation_stddev'])
        self._estimate = QuaternionStamped(self.settings['frame_id'])

    def batches(self):
        """
        Yield ``(copies, (kinds, stamps, values))`` per :data:`BATCH` messages.

        ``copies``: ``(connection id, receive time, CDR bytes, layout)`` to
        write, ``layout`` ``(order, body, stamp)`` of an IMU sample, ``()``
        for an IMU message that did not decode, None for the others; then
        the estimator's columns.
        """
        typestore = None
        checked = set()
        ids = self.ids
        copies, kinds, stamps, values = [], array.array('b'), array.array('q'), []
        for cid, received, raw in self.reader.messages(self.kinds):
            kind, role, source = self.kinds[cid]
            layout = None
            try:
                if kind == IMU or kind == IMU_AND_REFERENCE:
                    order, body, stamp, gyr, acc = imu_layout(raw)
                    layout = (order, body, stamp)
                    found = gyr + acc
                    if kind == IMU_AND_REFERENCE:
                        q = decode_orientation(raw, IMU_TYPE)[1]
                        found += _NAN4 if q is None else q
                elif kind == FIELD:
                    stamp, found = decode_field(raw)
                else:
                    stamp, q = decode_orientation(raw, source.msgtype)
                    found = _NAN4 if q is None else q
            except Undecodable:
                kind, stamp, found = UNDECODABLE[role], 0, ()
                layout = () if role == 'imu' else None
            else:
                if cid not in checked:
                    if typestore is None:
                        from rosbags.typesys import get_typestore, Stores
                        typestore = get_typestore(Stores.ROS2_JAZZY)
                    checked.add(cid)
                    _check_first(typestore, source, role, raw, stamp,
                                 found[:6] if role == 'imu' else
                                 None if role == 'reference' and math.isnan(found[0])
                                 else found)
            copies.append((ids[role], received, raw, layout))
            kinds.append(kind)
            stamps.append(stamp)
            values.extend(found)
            if len(copies) >= BATCH:
                yield copies, (kinds, stamps, array.array('d', values))
                copies, kinds, stamps, values = [], array.array('b'), array.array('q'), []
        if copies:
            yield copies, (kinds, stamps, array.array('d', values))

    def write(self, copies, states):
        """Write a batch: the copies, and after each IMU sample its estimate's two messages."""
        writer = self.writer
        rows = writer.rows
        data_id, estimate_id = self.ids['data'], self.ids['estimate']
        imu_data, estimate = self._imu_data, self._estimate
        width = _width(self.settings)
        states = states.tolist()
        j = 0
        for cid, received, raw, layout in copies:
            rows.append((cid, received, raw))
            if layout is None:
                continue
            w, x, y, z = states[j:j + 4]
            covariance = states[j + 4:j + width] or None
            j += width
            if layout and w == w:
                order, body, stamp = layout
                rows.append((data_id, received,
                             imu_data(raw, order, body, w, x, y, z, covariance)))
                rows.append((estimate_id, received, estimate(stamp, w, x, y, z)))
        if len(rows) >= BATCH:
            writer.flush()

    def close(self):
        """Write the metadata; return the messages written by role."""
        counts = self.writer.close()
        return {role: counts[cid] for role, cid in self.ids.items()}

    def abort(self):
        if self.writer is not None:
            self.writer.abort()


def _width(settings):
    """Floats per estimate across the pipe: the state, and its covariance if imu/data has it."""
    # imu_filter_node fills imu/data's orientation_covariance from the
    # estimate's own covariance where the pipeline has one and the setting asks.
    return 13 if settings['covariance_estimated'] else 4


class _Estimator:
    """This process's side: the node's steps on a batch's samples; the estimates back."""

    def __init__(self, settings, progress):
        self.run = PipelineRun(settings)
        self._none = (math.nan,) * _width(settings)
        self._wide = _width(settings) > 4
        self.progress = progress
        self.count = 0
        self.references = []
        self.undecodable = collections.Counter()

    def __call__(self, kinds, stamps, values):
        """Return the estimates (4 floats, NaN for none) of the batch's IMU messages."""
        imu, field = self.run.imu, self.run.field
        values = values.tolist()
        states = []
        extend = states.extend
        none, wide = self._none, self._wide
        i = 0
        for kind, stamp in zip(kinds.tolist(), stamps.tolist()):
            if kind == IMU or kind == IMU_AND_REFERENCE:
                estimate = imu(stamp, values[i:i + 3], values[i + 3:i + 6])
                if estimate is None:
                    extend(none)
                else:
                    extend(estimate.state)
                    if wide:
                        extend(estimate.covariance)
                if kind == IMU_AND_REFERENCE:
                    self.references.append((stamp, values[i + 6:i + 10]))
                    i += 4
                i += 6
            elif kind == FIELD:
                field(stamp, values[i:i + 3])
                i += 3
            else:
                i = self._other(kind, stamp, values, i, extend)
        self.count += len(kinds)
        if self.count >= self.progress.next:
            self.progress(self.count)
        return array.array('d', states)

    def _other(self, kind, stamp, values, i, extend):
        """A reference, or a message that did not decode."""
        if kind == REFERENCE:
            self.references.append((stamp, values[i:i + 4]))
        else:
            role = next(r for r, k in UNDECODABLE.items() if k == kind)
            self.undecodable[role] += 1
            if role == 'imu':
                extend(self._none)
        return i + _SIZES.get(kind, 0)

    def finish(self):
        """After the last batch: the progress's end, and the :class:`Recording`."""
        self.progress.finish(self.count)
        self.recording = self.run.recording()


def _fork():
    try:
        return multiprocessing.get_context('fork')
    except ValueError:
        return None


def _in_process(side, estimator):
    """Read, estimate and write a batch at a time, here."""
    try:
        side.open()
        for copies, columns in side.batches():
            side.write(copies, estimator(*columns))
        estimator.finish()
        return side.close()
    except BaseException:
        side.abort()
        raise


def _forked(context, side, estimator):
    """
    The bag's side in a forked process, a batch ahead of the estimator.

    The child sends a batch's columns, then (while this process estimates
    them) reads the next batch; it takes the estimates, sends the next
    columns and writes the batch. Each direction is used in turn, so
    neither side waits on a full pipe while the other does.
    """
    ours, theirs = context.Pipe()
    process = context.Process(target=_bag_process, args=(side, theirs), daemon=True)
    process.start()
    theirs.close()
    try:
        while True:
            tag = _receive(ours, process)
            if tag[0] == 'end':
                break
            columns = [array.array(code) for code in 'bqd']
            for column in columns:
                column.frombytes(ours.recv_bytes())
            try:
                ours.send_bytes(estimator(*columns))
            except BrokenPipeError:
                _receive(ours, process)
                raise
        # While the child writes the last batch.
        estimator.finish()
        ours.send(('close',))
        return _receive(ours, process)[1]
    finally:
        if process.is_alive():
            process.terminate()
        process.join()
        ours.close()


def _receive(pipe, process):
    """The child's next message; its error raised here."""
    try:
        tag = pipe.recv()
    except EOFError:
        tag = ('error', f'the reading and writing process stopped (exit code '
                        f'{process.exitcode})')
    if tag[0] == 'error':
        raise BagIOError(tag[1])
    return tag


def _send_columns(pipe, columns):
    pipe.send(('batch',))
    for column in columns:
        pipe.send_bytes(column)


def _bag_process(side, pipe):
    """The forked process: :class:`_BagSide`, talking to :func:`_forked`."""
    # What it inherited lives as long as it does: kept out of the garbage
    # collector's full passes, which otherwise cost about 0.5 s of its 3 s.
    gc.freeze()
    try:
        side.open()
        batches = side.batches()
        pending = next(batches, None)
        if pending is not None:
            _send_columns(pipe, pending[1])
        else:
            pipe.send(('end',))
        while pending is not None:
            # The next batch is read while the estimator runs this one.
            following = next(batches, None)
            states = array.array('d')
            states.frombytes(pipe.recv_bytes())
            if following is not None:
                _send_columns(pipe, following[1])
            else:
                pipe.send(('end',))
            side.write(pending[0], states)
            pending = following
        pipe.recv()
        pipe.send(('closed', side.close()))
    except (EOFError, BrokenPipeError):
        side.abort()
    except Exception as error:  # noqa: BLE001 -- whatever it is, the command says it
        side.abort()
        try:
            pipe.send(('error', str(error) if isinstance(error, ValueError)
                       else f'{type(error).__name__}: {error}'))
        except (BrokenPipeError, OSError):
            pass
    finally:
        pipe.close()


def compare(recording, stamps, quaternions, tolerance=None):
    """
    Score a recording's estimates against reference orientations, matched by stamp.

    Each estimate is paired with the reference nearest in stamp, within
    ``tolerance``; the error angles are BROAD's
    (:func:`ext_observer.broad.scoring.error_angles`: total, heading about
    the world's vertical, inclination), their RMSE over the pairs.

    Parameters
    ----------
    recording : ext_observer.recording.Recording
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
    add_parameter_options(parser)
    parser.add_argument('--storage', choices=STORAGES,
                        help="of the new bag (default: the input's)")
    parser.add_argument('--data-topic', default='imu/data', help='default imu/data')
    parser.add_argument('--estimate-topic', default='attitude_estimate',
                        help='default attitude_estimate')
    parser.add_argument('--plot', metavar='FILE.png',
                        help='roll, pitch, yaw, the flags and the comparison error')
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
    resets = ', '.join(f'{cause} {n}' for cause, n in recording.resets.items() if n)
    if resets:
        lines.append(f'  resets: {resets}')
    for kind, (n, text) in recording.units.items():
        lines.append(f'  {n} samples of implausible {kind}: {text}')
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
    try:
        parameters = parameters_from_options(args)
        run = run_bag(args.bag, args.out, imu_topic=args.imu_topic, mag_topic=args.mag_topic,
                      compare_topic=args.compare, parameters=parameters,
                      storage=args.storage, data_topic=args.data_topic,
                      estimate_topic=args.estimate_topic)
    except (ValueError, OSError) as error:
        print(f'error: {error}', file=sys.stderr)
        return 2
    print('\n'.join(report(run, args.out)))
    if args.plot:
        from ext_observer.recording_plot import plot_recording
        plot_recording(run.recording, args.plot, title=f'{args.bag}: {args.imu_topic}',
                       comparison=run.comparison)
        print(f'  plot: {args.plot}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
