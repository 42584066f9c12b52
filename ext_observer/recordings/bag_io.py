"""
Reading and writing rosbag2 bags with ``rosbags``: the bag command's I/O.

:class:`BagReader` lists a bag's connections and yields its messages in the
bag's (receive) order. :class:`BagWriter` writes a new bag in batches:
``rosbags``' ``Writer.write`` takes one message per Python call (about 10 µs
in MCAP, more than the estimator's step), so a batch is handed to the
storage at once: sqlite3, one ``executemany`` of the statement
``Sqlite3Writer.write`` runs; MCAP, the message records appended to the open
chunk and indexed as ``McapWriter.write`` does (:class:`_McapBatch`). The
Writer's counts and times, which its ``metadata.yaml`` is made of, are
kept. For storage classes of another shape (another ``rosbags`` version)
it falls back to ``Writer.write``; ``test/test_recording.py`` checks that
both give the same bag. Bags are written as rosbag2 version 8, which Iron
and Jazzy read.
"""

import struct

__all__ = ['BagIOError', 'BagReader', 'BagWriter', 'BATCH', 'STORAGES']

STORAGES = ('mcap', 'sqlite3')
BAG_VERSION = 8
# Messages handed to the storage at once.
BATCH = 4096


class BagIOError(ValueError):
    """A bag that cannot be read to its end, or an output that cannot be written."""


class BagReader:
    """
    A rosbag2 bag, read with ``rosbags``.

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

    def messages(self, ids):
        """
        Yield ``(connection id, receive time ns, CDR bytes)`` of the connections ``ids``.

        In the bag's order (by receive time).

        Raises
        ------
        BagIOError
            If the bag cannot be read to its end (a truncated or corrupt file).

        """
        from rosbags.rosbag2 import Reader, ReaderError
        try:
            with Reader(self.path) as reader:
                wanted = [c for c in reader.connections if c.id in ids]
                for connection, received, raw in reader.messages(wanted):
                    yield connection.id, received, raw
        except (ReaderError, OSError, ValueError, struct.error) as error:
            raise BagIOError(f'cannot read the bag {self.path} to its end: {error}') from None


class BagWriter:
    """
    A new rosbag2 bag, written in batches.

    Parameters
    ----------
    path : str
        The bag's folder; must not exist.
    storage : {'mcap', 'sqlite3'}
    topics : sequence of (topic, msgtype, qos)
        Its connections, in order; ``qos`` a list of ``rosbags`` Qos.

    Attributes
    ----------
    ids : list of int
        The connection id of each topic.
    rows : list
        ``(connection id, receive time ns, CDR bytes)`` of the messages not
        written yet: append to it and :meth:`flush` from :data:`BATCH` rows
        on, or call :meth:`write`.
    counts : dict
        Messages written by connection id.

    Raises
    ------
    BagIOError
        If the bag cannot be created (it exists, say).

    """

    def __init__(self, path, storage, topics):
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
        self.rows = []
        self.counts = self.writer.counts
        self._connections = {}
        self.ids = [self._connection(*topic) for topic in topics]
        self._store = _batched(self.writer.storage)

    def _connection(self, topic, msgtype, qos):
        connection = self.writer.add_connection(topic, msgtype, typestore=_typestore(),
                                                offered_qos_profiles=list(qos))
        self._connections[connection.id] = connection
        return connection.id

    def write(self, cid, received, data):
        """Add one message: connection id, receive time (ns), CDR bytes."""
        self.rows.append((cid, received, data))
        if len(self.rows) >= BATCH:
            self.flush()

    def flush(self):
        """Write :attr:`rows` (a new, empty list takes their place)."""
        rows, self.rows = self.rows, []
        if not rows:
            return
        writer = self.writer
        if self._store is None:
            connections = self._connections
            for cid, received, raw in rows:
                writer.write(connections[cid], received, raw)
            return
        counts = writer.counts
        for cid, _, _ in rows:
            counts[cid] += 1
        times = [received for _, received, _ in rows]
        writer.min_timestamp = min(writer.min_timestamp, min(times))
        writer.max_timestamp = max(writer.max_timestamp, max(times))
        self._store(rows)

    def close(self):
        """Write what is left and the metadata; return :attr:`counts`."""
        self.flush()
        self.writer.close()
        return dict(self.counts)

    def abort(self):
        """Stop without the metadata (the caller removes the folder)."""
        self.writer.abort()


def _typestore():
    from rosbags.typesys import get_typestore, Stores
    return get_typestore(Stores.ROS2_JAZZY)


def _batched(storage):
    """Return the batch store for ``storage``, or None (``Writer.write`` per message)."""
    try:
        from rosbags.rosbag2.storage_mcap import McapWriter
        from rosbags.rosbag2.storage_sqlite3 import Sqlite3Writer
    except ImportError:
        return None
    if type(storage) is Sqlite3Writer and hasattr(storage, 'cursor'):
        def store(rows):
            storage.cursor.executemany(
                'INSERT INTO messages (topic_id, timestamp, data) VALUES(?, ?, ?)', rows)
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

    def __call__(self, rows):
        storage = self.storage
        record = self.RECORD.pack
        stats = storage.channel_stats
        chunk = storage.chunk
        bio, msgs = chunk.bio, chunk.msgs
        first, last = chunk.message_start_time, chunk.message_end_time
        for cid, stamp, raw in rows:
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
        times = [stamp for _, stamp, _ in rows]
        storage.message_start_time = min(storage.message_start_time, min(times))
        storage.message_end_time = max(storage.message_end_time, max(times))
