"""
A shipped BROAD excerpt as the recordings' tests use it: its first 12 s with
a field every third sample (the fixtures ``data`` and ``recording``), the
Python call on it, a bag read back by ``rosbags``, a command run quietly.
"""

import hashlib
import io
import os

import numpy as np
import pytest
from rosbags.rosbag2 import Reader
from rosbags.typesys import get_typestore, Stores

from broad_replay import fields_tesla, load, TRIALS
from ext_observer.recordings.example_data import excerpt
from ext_observer.recordings.recording import attitude_from_imu


TYPESTORE = get_typestore(Stores.ROS2_JAZZY)


# The same float code on the same float64 values in the same order: equal
# to rounding (measured: 0, bit for bit).
TOLERANCE = 1e-9


SECONDS = 12.0  # of the excerpt: 10 s of rest, then 2 s of movement


MAG_EVERY = 3


def first_seconds(data, seconds):
    """The excerpt cut to its first ``seconds``, as broad_replay reads it."""
    count = int(round(seconds * float(data['rate'])))
    return {key: (value[:count] if np.ndim(value) else value) for key, value in data.items()}


def read_bag(path):
    """Every message of a bag, deserialized by rosbags: {topic: [(received, msg, raw)]}."""
    out = {}
    with Reader(path) as reader:
        for connection, received, raw in reader.messages():
            out.setdefault(connection.topic, []).append(
                (received, TYPESTORE.deserialize_cdr(raw, connection.msgtype), bytes(raw)))
    return out


def header_stamp(msg):
    return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec


def files_digest(path):
    digest = hashlib.sha256()
    for root, _, names in sorted(os.walk(path)):
        for name in sorted(names):
            with open(os.path.join(root, name), 'rb') as stream:
                digest.update(stream.read())
    return digest.hexdigest()


@pytest.fixture(scope='module')
def data():
    return first_seconds(load(TRIALS[0]), SECONDS)


@pytest.fixture(scope='module')
def recording(data):
    """The excerpt as example_data makes it (the field with every third sample)."""
    return excerpt(data, mag_every=MAG_EVERY)


def python_call(data, parameters=None):
    mag = fields_tesla(data).copy()
    mag[np.arange(len(mag)) % MAG_EVERY != 0] = np.nan
    return attitude_from_imu(data['gyr'], data['acc'], mag, rate=float(data['rate']),
                             parameters=parameters)


def quiet(main, argv, out=None):
    """Run a command's main with stdout (and stderr) captured."""
    import contextlib
    out = io.StringIO() if out is None else out
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(out):
        return main(argv)
