"""
The two processes of the bag command (:mod:`ext_observer.recordings.bag`).

This process runs the estimator (:class:`BagEstimator`, the node's
:class:`~ext_observer.recordings.recording.PipelineRun`); a forked one
(:func:`forked`; this one where ``fork`` is not available, or with
``parallel=False``: :func:`in_process`) reads the bag and decodes its
messages, then encodes the estimates and writes the new bag
(:class:`BagSide`, with :mod:`ext_observer.recordings.cdr` and
:mod:`ext_observer.recordings.bag_io`), a batch ahead. Between them go only numbers:
the samples' kinds, stamps and values one way, the estimates the other.
The first message of every input topic is checked against ``rosbags``' own
deserializer (:func:`_check_first`).
"""

import array
import collections
import gc
import math
import multiprocessing

import numpy as np

from ext_observer.recordings.bag_io import BagIOError, BagWriter, BATCH
from ext_observer.recordings.cdr import (decode_field, decode_orientation, IMU_TYPE, imu_layout,
                              ImuData, QuaternionStamped, Undecodable)
from ext_observer.recordings.recording import PipelineRun, SECOND


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


def _typestore():
    from rosbags.typesys import get_typestore, Stores
    return get_typestore(Stores.ROS2_JAZZY)


def _velocity(typestore, raw, msgtype):
    """``(stamp, (x, y, z))`` of an Odometry or TwistStamped (tens of Hz: rosbags decodes it)."""
    try:
        msg = typestore.deserialize_cdr(raw, msgtype)
    except Exception as error:  # noqa: BLE001 -- any failure of rosbags' decoder
        raise Undecodable(str(error)) from None
    twist = msg.twist.twist if msgtype == ODOMETRY_TYPE else msg.twist
    return msg.header.stamp.sec * SECOND + msg.header.stamp.nanosec, _xyz(twist.linear)



# What a message is to the estimator (the kinds that cross the pipe), and
# how many values it carries.
IMU, FIELD, REFERENCE, IMU_AND_REFERENCE, VELOCITY = 0, 1, 2, 3, 7
UNDECODABLE = {'imu': 4, 'mag': 5, 'reference': 6, 'velocity': 8}
_SIZES = {IMU: 6, FIELD: 3, REFERENCE: 4, IMU_AND_REFERENCE: 10, VELOCITY: 3}
ODOMETRY_TYPE = 'nav_msgs/msg/Odometry'
TWIST_TYPE = 'geometry_msgs/msg/TwistStamped'
VELOCITY_TYPES = (ODOMETRY_TYPE, TWIST_TYPE)
_NAN4 = (math.nan,) * 4


class BagSide:
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
                kind = {'imu': IMU, 'mag': FIELD, 'reference': REFERENCE,
                        'velocity': VELOCITY}[role]
                if shared and role != 'mag':
                    kind, role = IMU_AND_REFERENCE, 'imu'
                self.kinds[c.id] = (kind, role, c)
        self._shared = shared
        if shared:
            self.topics = {role: topic for role, topic in topics.items() if role != 'reference'}
        self.total = sum(c.msgcount for _, _, c in self.kinds.values())
        self.writer = None

    def open(self):
        """Create the new bag (none with ``out`` None); its connection ids by role."""
        self.writer = (_Discard(self.topics) if self.out is None
                       else BagWriter(self.out, self.storage, list(self.topics.values())))
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
                elif kind == VELOCITY:
                    typestore = typestore or _typestore()
                    stamp, found = _velocity(typestore, raw, source.msgtype)
                    checked.add(cid)  # decoded by rosbags itself
                else:
                    stamp, q = decode_orientation(raw, source.msgtype)
                    found = _NAN4 if q is None else q
            except Undecodable:
                kind, stamp, found = UNDECODABLE[role], 0, ()
                layout = () if role == 'imu' else None
            else:
                if cid not in checked:
                    typestore = typestore or _typestore()
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


class _Discard:
    """A writer that writes nothing but counts (``run_bag`` with ``out`` None)."""

    def __init__(self, topics):
        self.ids = list(range(len(topics)))
        self.rows = []
        self._counts = collections.Counter()

    def flush(self):
        self._counts.update(cid for cid, _, _ in self.rows)
        self.rows = []

    def close(self):
        self.flush()
        return dict(self._counts)

    def abort(self):
        self.rows = []


def _width(settings):
    """Floats per estimate across the pipe: the state, and its covariance if imu/data has it."""
    # imu_filter_node fills imu/data's orientation_covariance from the
    # estimate's own covariance where the pipeline has one and the setting asks.
    return 13 if settings['covariance_estimated'] else 4


class BagEstimator:
    """This process's side: the node's steps on a batch's samples; the estimates back."""

    def __init__(self, settings, progress):
        self.run = PipelineRun(settings)
        self._none = (math.nan,) * _width(settings)
        self._wide = _width(settings) > 4
        self.progress = progress
        self.count = 0
        self.references = []
        self.undecodable = collections.Counter()
        self.velocity_drops = collections.Counter()  # by the pipeline's reason

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
            elif kind == VELOCITY:
                reason = self.run.pipeline.velocity(stamp, values[i:i + 3])
                if reason is not None:
                    self.velocity_drops[reason] += 1
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


class KeepingEstimator(BagEstimator):
    """
    :class:`BagEstimator` that also keeps its inputs as arrays: the first pass of ``--smooth``.

    After :meth:`finish`, :meth:`inputs` gives them to
    :func:`~ext_observer.recordings.smoothing.smoothed_attitude`: one row
    per decoded IMU message (the recording's rows), the fields and the
    velocities with their stamps. About 56 bytes a sample.
    """

    def __init__(self, settings, progress):
        super().__init__(settings, progress)
        self._kept = {kind: (array.array('q'), array.array('d')) for kind in (IMU, FIELD,
                                                                            VELOCITY)}

    def __call__(self, kinds, stamps, values):
        """Keep the batch's inputs, then estimate them (:class:`BagEstimator`)."""
        kind = np.frombuffer(kinds, dtype=np.int8)
        stamp = np.frombuffer(stamps, dtype=np.int64)
        value = np.frombuffer(values, dtype=float)
        starts = np.concatenate([[0], np.cumsum(_WIDTHS[kind])[:-1]]).astype(np.intp)
        for keep, (found, width) in ((IMU, ((IMU, IMU_AND_REFERENCE), 6)),
                                     (FIELD, ((FIELD,), 3)), (VELOCITY, ((VELOCITY,), 3))):
            rows = np.flatnonzero(np.isin(kind, found))
            kept_stamps, kept_values = self._kept[keep]
            kept_stamps.frombytes(stamp[rows].tobytes())
            kept_values.frombytes(value[starts[rows, None] + np.arange(width)].tobytes())
        return super().__call__(kinds, stamps, values)

    def inputs(self):
        """
        Return what the smoother takes: ``(stamps, gyr, acc, fields, velocities)``.

        ``stamps`` ns (N,); ``gyr``, ``acc`` (N, 3); ``fields`` and
        ``velocities`` ``(stamps (M,), values (M, 3))``. The arrays are given
        up here (the estimator keeps none).
        """
        kept, self._kept = self._kept, None
        out = {}
        for kind, width in ((IMU, 6), (FIELD, 3), (VELOCITY, 3)):
            stamps, values = kept.pop(kind)
            out[kind] = (np.frombuffer(stamps, dtype=np.int64),
                         np.frombuffer(values, dtype=float).reshape(-1, width))
        stamps, imu = out[IMU]
        return stamps, imu[:, :3], imu[:, 3:], out[FIELD], out[VELOCITY]


# Floats each kind of message carries across the pipe, by kind.
_WIDTHS = np.zeros(max(max(_SIZES), max(UNDECODABLE.values())) + 1, dtype=np.intp)
for _kind, _size in _SIZES.items():
    _WIDTHS[_kind] = _size


class SmoothedStates:
    """
    The second pass of ``--smooth``: each IMU message's smoothed estimate, from arrays.

    Stands where :class:`BagEstimator` stands (:func:`in_process`), so the
    new bag is written as the online one is: the
    same messages (an estimate where the online run published one), with
    the smoothed quaternion and, where ``imu/data`` carries the estimate's
    covariance, ``diag(σ_i² / 2, σ_i² / 2, σ_h²)``.

    Parameters
    ----------
    recording : ext_observer.recordings.recording.Recording
        Smoothed (one row per decoded IMU message).
    settings : dict
    progress : callable
        As :class:`BagEstimator`'s.

    """

    def __init__(self, recording, settings, progress):
        self._width = _width(settings)
        self._next = 0
        self.recording = recording
        self.progress = progress
        self.count = 0

    def _states(self, start, stop):
        """Rows ``start:stop`` of the recording as the pipe carries them (NaN: no estimate)."""
        recording = self.recording
        states = np.full((stop - start, self._width), math.nan)
        rows = recording.estimated[start:stop]
        states[rows, :4] = recording.quaternions[start:stop][rows]
        if self._width > 4:
            tilt = 0.5 * recording.inclination_std[start:stop][rows] ** 2
            states[rows, 4:13] = 0.0
            states[rows, 4] = states[rows, 8] = tilt
            states[rows, 12] = recording.heading_std[start:stop][rows] ** 2
        return states

    def __call__(self, kinds, stamps, values):
        """Return the smoothed estimates of the batch's IMU messages (NaN: none)."""
        kind = np.frombuffer(kinds, dtype=np.int8)
        kind = kind[np.isin(kind, (IMU, IMU_AND_REFERENCE, UNDECODABLE['imu']))]
        decoded = kind != UNDECODABLE['imu']
        out = np.full((len(kind), self._width), math.nan)
        taken = int(decoded.sum())
        out[decoded] = self._states(self._next, self._next + taken)
        self._next += taken
        self.count += len(kinds)
        if self.count >= self.progress.next:
            self.progress(self.count)
        return array.array('d', out.tobytes())

    def finish(self):
        """After the last batch: the progress's end."""
        self.progress.finish(self.count)


def fork_context():
    try:
        return multiprocessing.get_context('fork')
    except ValueError:
        return None


def in_process(side, estimator):
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


def forked(context, side, estimator):
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
    """The forked process: :class:`BagSide`, talking to :func:`forked`."""
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


