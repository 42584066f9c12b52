"""
The batched bag writer (``recordings/bag_io.py``) against ``rosbags``'
``Writer.write``: the same files.
"""

import numpy as np
import pytest
from rosbags.rosbag2 import Reader

from ext_observer.recordings import bag_io
from ext_observer.recordings import cdr


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_batched_writer_equals_rosbags_writer(tmp_path, storage):
    rng = np.random.default_rng(0)
    topics = [('/a', cdr.IMU_TYPE, []), ('/b', cdr.QUATERNION_TYPE, [])]
    rows = [(1 + k % 2, 10 ** 12 + 1000 * k, rng.bytes(int(rng.integers(40, 400))))
            for k in range(20000)]
    bags = []
    for batched in (True, False):
        path = str(tmp_path / f'{batched}')
        writer = bag_io.BagWriter(path, storage, topics)
        if not batched:
            writer._store = None
        for cid, received, raw in rows:
            writer.write(writer.ids[cid - 1], received, raw)
        writer.close()
        with Reader(path) as reader:
            bags.append(([(c.topic, t, bytes(raw)) for c, t, raw in reader.messages()],
                         reader.message_count, reader.start_time, reader.end_time,
                         {c.topic: c.msgcount for c in reader.connections}))
    assert bags[0] == bags[1]
    assert len(bags[0][0]) == len(rows)
