"""
Checks of the benchmark's own logic (no ROS, no timing): ``pytest bench``.

The matching of estimates to steps decides "lost" and the latencies, so it
is tested on made-up records; the report must render any partial results.
"""

import numpy as np
import pytest

from bench import report
from bench.lean import check_against_core
from bench.nodes import analyze, sustained_rate
from bench.rosutil import raw_stamp_ns, write_raw_stamp

RATE = 1000.0
PERIOD = 1_000_000  # ns


def _driver(steps, start=10**18):
    stamps = start + PERIOD * np.arange(steps + 1, dtype=np.int64)
    published = stamps[:-1] + 123_000
    return stamps, published


@pytest.mark.parametrize('offset', [0, 1])
def test_analyze_matches_every_step_and_measures_latency(offset):
    stamps, published = _driver(100)
    est = stamps[offset:offset + 100]
    arrived = published + 500_000  # 0.5 ms after each publish
    result = analyze(stamps, published, est, arrived, offset, RATE)
    assert result['lost'] == 0 and result['extra'] == 0
    assert result['p50'] == pytest.approx(0.5)
    assert result['max'] == pytest.approx(0.5)
    assert result['sustained']


def test_analyze_counts_lost_extra_and_tolerates_one_ns_of_rounding():
    stamps, published = _driver(100)
    keep = np.ones(100, bool)
    keep[[3, 50]] = False
    # The observer stamps t_k + (t_k - t_{k-1}): off by a nanosecond at
    # periods that are not whole nanoseconds.
    est = stamps[1:101][keep] + 1
    arrived = published[keep] + 1_000_000
    est = np.append(est, stamps[-1] + 40 * PERIOD)  # matches no step
    arrived = np.append(arrived, arrived[-1])
    result = analyze(stamps, published, est, arrived, 1, RATE)
    assert result['lost'] == 2
    assert result['extra'] == 1
    assert not result['sustained']


def test_a_backlog_is_not_sustained():
    stamps, published = _driver(50)
    result = analyze(stamps, published, stamps[:50], published + 80_000_000, 0,
                     RATE)
    assert result['lost'] == 0 and not result['sustained']


def test_sustained_rate_is_the_highest_sustained():
    runs = [{'rate': 250, 'sustained': True}, {'rate': 500, 'sustained': False},
            {'rate': 1000, 'sustained': True}, {'rate': 2000, 'sustained': False}]
    assert sustained_rate(runs) == 1000
    assert sustained_rate([{'error': 'x'}]) is None


def test_raw_stamp_round_trip():
    data = bytearray(64)
    write_raw_stamp(data, 1_700_000_000_123_456_789)
    assert raw_stamp_ns(bytes(data)) == 1_700_000_000_123_456_789


def test_lean_prototype_equals_the_core():
    assert check_against_core(batch=50) < 1e-12


def test_report_renders_partial_results():
    machine = {'date': 'today', 'commit': 'abc', 'cores': 2, 'cpu': 'x',
               'python': '3', 'numpy': '2', 'rclpy': '7', 'rmw': 'r',
               'rmw_fastrtps_cpp': '8', 'load_start': 0.1, 'load_end': 0.2}
    text = report.render({'machine': machine, 'command': 'python -m bench'})
    assert text.startswith('# Performance')
    node_run = {'target': 'relay/single', 'label': 'relay', 'executor': 'single',
                'rate': 1000, 'steps': 10, 'lost': 0, 'extra': 0, 'p50': 0.4,
                'p99': 1.0, 'max': 2.0, 'sustained': True, 'achieved': 1000.0,
                'seconds': 1.0, 'cpu_us_per_step': 600.0, 'propagated': None,
                'dropped': None}
    text = report.render({'machine': machine, 'command': 'c',
                          'nodes': [node_run, {'target': 'observer/single',
                                               'label': 'observer',
                                               'executor': 'single',
                                               'error': 'did not start'}],
                          'rates': [1000]})
    assert '| relay/single | ✓ 0.40 |' in text
    assert 'did not start' in text
