"""
What the nodes share (``nodes/node_common.py``), without a running node:
diagnostic key values as written, the counters that rose since the last
period, the executor chosen on the command line. (Run by processes, with
Ctrl-C and the context going down: ``test_processes.py``.)
"""

import math

from builtin_interfaces.msg import Time
import pytest

from ext_observer.nodes.node_common import (CounterDeltas, diagnostic_array, EXECUTORS,
                                            executor_from_args, key_values)


def test_key_values_write_floats_with_six_digits_and_bools_in_lower_case():
    values = key_values([('a', 1.0 / 3.0), ('b', True), ('c', 7), ('d', math.nan), ('e', 'x')])
    assert [(v.key, v.value) for v in values] == [
        ('a', '0.333333'), ('b', 'true'), ('c', '7'), ('d', 'nan'), ('e', 'x')]
    array = diagnostic_array(Time(sec=3), [])
    assert array.header.stamp.sec == 3 and list(array.status) == []


def test_only_the_counters_that_rose_are_reported_with_their_increase():
    deltas = CounterDeltas()
    assert deltas.deltas({'a': 0, 'b': 2}) == {'b': 2}
    assert deltas.deltas({'a': 0, 'b': 2}) == {}
    assert deltas.deltas({'a': 1, 'b': 5, 'c': 1}) == {'a': 1, 'b': 3, 'c': 1}
    # A counter reset (a new estimator) is a change too.
    assert deltas.deltas({'a': 0, 'b': 5, 'c': 1}) == {'a': -1}


def test_the_executor_is_read_outside_the_ros_arguments():
    assert executor_from_args(['node']) == EXECUTORS[0]
    assert executor_from_args(['node', '--executor', 'single']) == 'single'
    assert executor_from_args(['node', '--executor=single', '--ros-args', '-p', 'x:=1']) == \
        'single'
    with pytest.raises(ValueError, match='--executor needs a value'):
        executor_from_args(['node', '--executor'])
    with pytest.raises(ValueError, match=r"--executor must be one of .* got 'multi'"):
        executor_from_args(['node', '--executor', 'multi'])
