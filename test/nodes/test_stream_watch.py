"""
A sensor stream's health in a node (``nodes/stream_watch.py``), on a real
rclpy node without traffic: the WARN text of samples lost, the keys before
and after the first status, rmw's queue losses counted, and the likely
cause: the node behind its input, or the samples lost before it. (Through
imu_filter_node over DDS: ``nodes/test_imu_filter_node.py``.)
"""

import math
from types import SimpleNamespace

import numpy as np
import pytest
from rclpy.node import Node

from ext_observer.nodes.stream_watch import BEFORE, BEHIND, CPU_BUSY, StreamWatch

MS = 1_000_000
SECOND = 1_000_000_000
START = 1_700_000_000 * SECOND


@pytest.fixture
def node(ros_context):
    node = Node('stream_watch_test', context=ros_context)
    try:
        yield node
    finally:
        node.destroy_node()


def test_a_hole_warns_with_its_share_and_the_keys_say_it(node):
    watch = StreamWatch(node, 'IMU samples')
    values = dict(watch.key_values())
    assert values['samples_lost'] == 0 and math.isnan(values['samples_lost_share'])
    kept = np.concatenate([np.arange(400), np.arange(450, 1000)])
    for stamp in START + kept * MS:
        watch.sample(int(stamp))
    watch.message_lost(SimpleNamespace(total_count_change=3))
    [text] = watch.problems(START + SECOND)
    assert text == ('5.0% of the IMU samples lost over the last 2 s (50 of 1000; longest '
                    'hole 51 ms)')
    values = dict(watch.key_values())
    assert values['samples_lost'] == 50 and values['samples_lost_queue'] == 3
    assert values['longest_hole_s'] == pytest.approx(0.051)
    assert values['lag_s'] == pytest.approx(0.001)


def test_the_cause_is_the_node_when_it_lags_loses_in_its_queue_or_is_busy(node):
    watch = StreamWatch(node, 'IMU samples')
    watch.cpu_share = 0.2
    keeping_up = SimpleNamespace(lag=0.001)
    assert watch.cause(keeping_up, 0) == BEFORE.format(why='1 ms behind the stamps, 20% of a core')
    assert watch.cause(SimpleNamespace(lag=-5.0), 0) == BEFORE.format(
        why='stamps not on the node clock, lag unknown, 20% of a core')
    assert watch.cause(SimpleNamespace(lag=0.2), 2) == BEHIND.format(
        why='2 lost in its queue; 200 ms behind the stamps')
    watch.cpu_share = CPU_BUSY + 0.05
    assert watch.cause(keeping_up, 0) == BEHIND.format(why='95% of a core')
