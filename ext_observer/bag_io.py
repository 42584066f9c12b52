"""
Reading and writing rosbag2 bags with ``rosbags``, each in a process of its own.

The bag command's own work per message is small (a ``struct`` call, the
estimator's step); ``rosbags``, pure Python, spends more than that reading
and writing one. So :class:`BagReader` reads in a forked process and
:class:`BagWriter` writes in another, while the command's process decodes,
estimates and encodes: the three overlap on a machine with a core to spare.
Messages cross the pipes in batches, as columns (connection ids, receive
times, and the CDR bytes joined), which costs a copy, not a pickle per
message. Where ``fork`` is not available, or with ``parallel=False``, the
same classes work in the calling process.

Writing: ``rosbags``' ``Writer.write`` takes one message per Python call
(about 10 µs in MCAP). :class:`_BatchWriter` hands a batch to the storage at
once: sqlite3, one ``executemany`` of the statement ``Sqlite3Writer.write``
runs; MCAP, the message records appended to the open chunk and indexed as
``McapWriter.write`` does (:class:`_McapBatch`). The Writer's counts and
times, which its ``metadata.yaml`` is made of, are kept. For storage classes
of another shape (another ``rosbags`` version) it falls back to
``Writer.write``; ``test/test_recording.py`` checks that both give the same
bag.
"""

import array
import multiprocessing
import struct

__all__ = ['BagReader', 'BagWriter', 'BagIOError', 'STORAGES']

STORAGES = ('mcap', 'sqlite3')
# rosbag2 metadata version 8: what Iron and Jazzy write and read.
BAG_VERSION = 8
# Messages per batch across a pipe.
BATCH = 4096


class BagIOError(ValueError):
    """A bag that cannot be read to its end, or an output that cannot be written."""


def _fork():
    """The fork context, or None where there is none."""
    try:
        return multiprocessing.get_context('fork')
    except ValueError:
        return None


def _send(pipe, rows):
    """Send ``(connection id, receive time, CDR bytes)`` rows as columns."""
    ids, times, data = zip(*rows)
    pipe.send(('rows', len(rows)))
    pipe.send_bytes(array.array('I', ids))
    pipe.send_bytes(array.array('q', times))
    pipe.send_bytes(array.array('I', map(len, data)))
    pipe.send_bytes(b''.join(data))


def _receive(pipe):
    """Return the columns :func:`_send` sent: ids, times, data (memoryviews of one buffer)."""
    ids, times, lengths = array.array('I'), array.array('q'), array.array('I')
    for column in (ids, times, lengths):
        column.frombytes(pipe.recv_bytes())
    blob = memoryview(pipe.recv_bytes())
    data = []
    start = 0
    for length in lengths:
        data.append(blob[start:start + length])
        start += length
    return ids.tolist(), times.tolist(), data


class BagReader:
    """
    The messages of some connections of a bag, in receive order.

    Parameters
    ----------
    path : str
        A rosbag2 folder, or one ``.mcap`` or ``.db3`` file.

    Attributes
    ----------
    connections : list of rosbags.interfaces.Connection
        Every connection of the bag (topic, type, message count, QoS).

    Raises
    ------
    BagIOError
        If the bag cannot be opened (the reader's reason).

    """

    def __init__(self, path):
        from rosbags.rosbag2 import Reader, ReaderError
        self.path = path
        try:
            with Reader(path) as reader:
                self.connections = list(reader.connections)
        except (ReaderError, OSError, ValueError) as error:
            raise BagIOError(f'cannot read the bag {path}: {error}') from None

    def messages(self, connections, parallel=True):
        """
        Yield ``(connection id, receive time ns, CDR bytes)`` in the bag's order.

        Raises
        ------
        BagIOError
            If the bag cannot be read to its end (a truncated or corrupt file).

        """
        ids = {c.id for c in connections}
        context = _fork() if parallel else None
        if context is None:
            yield from self._read(ids)
            return
        ours, theirs = context.Pipe()
        process = context.Process(target=self._read_child, args=(ids, theirs), daemon=True)
        process.start()
        theirs.close()
        try:
            while True:
                tag = ours.recv()
                if tag[0] == 'end':
                    break
                if tag[0] == 'error':
                    raise BagIOError(tag[1])
                yield from zip(*_receive(ours))
        finally:
            if process.is_alive():
                process.terminate()
            process.join()
            ours.close()

    def _read(self, ids):
        from rosbags.rosbag2 import Reader, ReaderError
        try:
            with Reader(self.path) as reader:
                wanted = [c for c in reader.connections if c.id in ids]
                for connection, received, raw in reader.messages(wanted):
                    yield connection.id, received, raw
        except (ReaderError, OSError, ValueError, struct.error) as error:
            raise BagIOError(f'cannot read the bag {self.path} to its end: {error}') from None

    def _read_child(self, ids, pipe):
        try:
            rows = []
            for row in self._read(ids):
                rows.append(row)
                if len(rows) >= BATCH:
                    _send(pipe, rows)
                    rows = []
            if rows:
                _send(pipe, rows)
            pipe.send(('end',))
        except BagIOError as error:
            pipe.send(('error', str(error)))
        except BrokenPipeError:
            pass
        finally:
            pipe.close()


class BagWriter:
    """
    A new bag, written in batches (in a process of its own when ``parallel``).

    Parameters
    ----------
    path : str
        The bag's folder; must not exist.
    storage : {'mcap', 'sqlite3'}
    topics : sequence of (topic, msgtype, qos)
        Its connections, in order; ``qos`` a list of ``rosbags`` Qos.
    parallel : bool

    Attributes
    ----------
    ids : list of int
        The connection id of each topic.
    rows : list
        ``(connection id, receive time ns, CDR bytes)`` of the messages not
        written yet: append to it, and :meth:`flush` when it is long (from
        :data:`BATCH` on), or call :meth:`write`.
    counts : dict
        Messages written by connection id, after :meth:`close`.

    Raises
    ------
    BagIOError
        If the bag cannot be created (it exists, say).

    """

    def __init__(self, path, storage, topics, parallel=True):
        self.path = path
        self.counts = None
        self.rows = []
        context = _fork() if parallel else None
        self._process = None
        if context is None:
            self._writer = _BatchWriter(path, storage)
            self.ids = [self._writer.connection(*topic) for topic in topics]
            return
        self._pipe, theirs = context.Pipe()
        self._process = context.Process(target=_write_child,
                                        args=(path, storage, topics, theirs), daemon=True)
        self._process.start()
        theirs.close()
        self.ids = self._answer('ready')

    def write(self, cid, received, data):
        """Add one message: connection id, receive time (ns), CDR bytes."""
        self.rows.append((cid, received, data))
        if len(self.rows) >= BATCH:
            self.flush()

    def flush(self):
        """Hand :attr:`rows` to the writer (a new, empty list takes their place)."""
        rows, self.rows = self.rows, []
        if not rows:
            return
        if self._process is None:
            self._writer.store(*zip(*rows))
            return
        try:
            _send(self._pipe, rows)
        except BrokenPipeError:
            self._answer('closed')

    def close(self):
        """Write what is left and the metadata; return :attr:`counts`."""
        self.flush()
        if self._process is None:
            self.counts = self._writer.close()
        else:
            self._pipe.send(('close',))
            self.counts = self._answer('closed')
            self._process.join()
        return self.counts

    def abort(self):
        """Stop without the metadata (the caller removes the folder)."""
        if self._process is None:
            self._writer.abort()
            return
        if self._process.is_alive():
            self._process.terminate()
        self._process.join()

    def _answer(self, expected):
        try:
            tag = self._pipe.recv()
        except EOFError:
            tag = ('error', f'the writer of {self.path} stopped')
        if tag[0] == 'error':
            self._process.join()
            raise BagIOError(tag[1])
        assert tag[0] == expected, tag
        return tag[1]


def _write_child(path, storage, topics, pipe):
    """The writer's process: connections, then batches until 'close'."""
    writer = None
    try:
        writer = _BatchWriter(path, storage)
        pipe.send(('ready', [writer.connection(*topic) for topic in topics]))
        while True:
            tag = pipe.recv()
            if tag[0] == 'close':
                pipe.send(('closed', writer.close()))
                return
            writer.store(*_receive(pipe))
    except EOFError:
        # The command stopped without closing: no metadata.
        if writer is not None:
            writer.abort()
    except Exception as error:  # noqa: BLE001 -- whatever it is, the command says it
        if writer is not None:
            writer.abort()
        pipe.send(('error', str(error) if isinstance(error, BagIOError)
                   else f'writing {path}: {type(error).__name__}: {error}'))
    finally:
        pipe.close()


def _typestore():
    from rosbags.typesys import get_typestore, Stores
    return get_typestore(Stores.ROS2_JAZZY)


class _BatchWriter:
    """A ``rosbags`` Writer whose messages are stored a batch at a time (module docstring)."""

    def __init__(self, path, storage):
        from rosbags.rosbag2 import StoragePlugin, Writer, WriterError
        if storage not in STORAGES:
            raise BagIOError(f'storage must be one of {STORAGES}, got {storage!r}')
        try:
            self.writer = Writer(path, version=BAG_VERSION,
                                 storage_plugin=StoragePlugin[storage.upper()])
            self.writer.open()
        except (WriterError, OSError) as error:
            raise BagIOError(f'{error} (never overwritten: remove it or choose another '
                             'output)') from None
        self._connections = {}
        self._store = _batched(self.writer.storage)

    def connection(self, topic, msgtype, qos=()):
        """Add a topic; return its connection id."""
        connection = self.writer.add_connection(topic, msgtype, typestore=_typestore(),
                                                offered_qos_profiles=list(qos))
        self._connections[connection.id] = connection
        return connection.id

    def store(self, ids, times, data):
        """Write a batch: connection ids, receive times (ns), CDR bytes."""
        writer = self.writer
        if self._store is None:
            connections = self._connections
            for cid, received, raw in zip(ids, times, data):
                writer.write(connections[cid], received, raw)
            return
        counts = writer.counts
        for cid in ids:
            counts[cid] += 1
        writer.min_timestamp = min(writer.min_timestamp, min(times))
        writer.max_timestamp = max(writer.max_timestamp, max(times))
        self._store(ids, times, data)

    def close(self):
        """Write the metadata; return the messages written by connection id."""
        self.writer.close()
        return dict(self.writer.counts)

    def abort(self):
        """Stop without the metadata."""
        self.writer.abort()


def _batched(storage):
    """Return the batch store for ``storage``, or None (``Writer.write`` per message)."""
    try:
        from rosbags.rosbag2.storage_mcap import McapWriter
        from rosbags.rosbag2.storage_sqlite3 import Sqlite3Writer
    except ImportError:
        return None
    if type(storage) is Sqlite3Writer and hasattr(storage, 'cursor'):
        def store(ids, times, data):
            storage.cursor.executemany(
                'INSERT INTO messages (topic_id, timestamp, data) VALUES(?, ?, ?)',
                zip(ids, times, data))
        return store
    if type(storage) is McapWriter and all(
            hasattr(storage, name) for name in ('chunk', 'close_chunk', 'channel_stats',
                                                'message_start_time', 'message_end_time')):
        return _McapBatch(storage)
    return None


class _McapBatch:
    """Message records appended to ``rosbags``' open MCAP chunk, as ``McapWriter.write`` does."""

    # opcode 0x05, record length, channel id, sequence, log time, publish time
    RECORD = struct.Struct('<BQHIQQ')
    CHUNK_SIZE = 2 ** 20

    def __init__(self, storage):
        self.storage = storage

    def __call__(self, ids, times, data):
        storage = self.storage
        record = self.RECORD.pack
        stats = storage.channel_stats
        chunk = storage.chunk
        bio, msgs = chunk.bio, chunk.msgs
        first, last = chunk.message_start_time, chunk.message_end_time
        for cid, stamp, raw in zip(ids, times, data):
            first = stamp if stamp < first else first
            last = stamp if stamp > last else last
            stats[cid] += 1
            msgs[cid].append((stamp, bio.tell()))
            bio.write(record(5, 22 + len(raw), cid, 0, stamp, stamp))
            bio.write(raw)
            if bio.tell() > self.CHUNK_SIZE:
                chunk.message_start_time, chunk.message_end_time = first, last
                storage.close_chunk()
                chunk = storage.chunk
                bio, msgs = chunk.bio, chunk.msgs
                first, last = chunk.message_start_time, chunk.message_end_time
        chunk.message_start_time, chunk.message_end_time = first, last
        storage.message_start_time = min(storage.message_start_time, min(times))
        storage.message_end_time = max(storage.message_end_time, max(times))
