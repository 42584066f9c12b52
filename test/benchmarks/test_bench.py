"""
Checks of the benchmark's own logic (no ROS, no timing): ``pytest bench``.

The matching of estimates to steps decides "lost" and the latencies, so it
is tested on made-up records; the goals' verdicts on made-up figures (the
page they go to: test/test_performance_page.py).
"""

import numpy as np
import pytest

from bench.lean import check_against_core
from bench.nodes import analyze, sustained_rate
from bench.rosutil import raw_stamp_ns, write_raw_stamp
from bench_results import node_result

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


# What uses numpy on the hot path: by what a function does, not its module.

def _floats_only():
    from ext_observer.core.quaternion import multiply_floats
    q = (1.0, 0.0, 0.0, 0.0)
    return multiply_floats(multiply_floats(q, (0.0, 1.0, 0.0, 0.0)), q)


def _numpy_from_floats():
    from ext_observer.core.quaternion import normalize
    return normalize(np.asarray((1.0, 2.0, 3.0, 4.0)))


def test_numpy_use_counts_what_a_function_calls_not_its_module():
    from bench.numpy_use import numpy_use

    def step():
        _floats_only()
        return float(_numpy_from_floats()[0])

    uses, result = numpy_use(step)
    assert result == pytest.approx(0.18257418583505536)
    # multiply_floats lives in core/quaternion.py beside numpy functions; it
    # works on floats and must not count (the rule by module counted it).
    assert not any(label.endswith(':multiply_floats') for label in uses)
    assert '_floats_only' not in {label.split(':')[1] for label in uses}
    assert uses['quaternion.py:normalize']['calls'] == 1
    assert 'numpy asarray' in uses['test_bench.py:_numpy_from_floats']['numpy']


def test_the_node_s_float_step_uses_no_numpy_per_step():
    # The check of the targets' row 'no per-message numpy allocation', on the
    # node's core step: SingleObserver.step calls quaternion.multiply_floats
    # twice per step on floats. The rule by module counted those calls as
    # numpy and turned the row to 'no'.
    from bench.numpy_use import numpy_use_per_step
    from ext_observer.core import SingleObserver

    def loop(observer, steps):
        for _ in range(steps):
            observer.step((0.001, -0.002, 0.003), (1.0, 0.0, 0.0, 0.0))

    assert numpy_use_per_step(100, loop, SingleObserver(), 100) == {}

    def loop_with_numpy(observer, steps):
        for _ in range(steps):
            observer.step((0.001, -0.002, 0.003), (1.0, 0.0, 0.0, 0.0))
            _numpy_from_floats()

    uses = numpy_use_per_step(100, loop_with_numpy, SingleObserver(), 100)
    assert uses['quaternion.py:normalize']['per_step'] == 1.0
    assert not any(label.endswith(':multiply_floats') for label in uses)
    assert not any(label.endswith(':loop_with_numpy') for label in uses)


def test_numpy_use_sees_ufuncs_and_operators_that_a_profiler_does_not():
    from bench.numpy_use import numpy_use

    def ufunc(a):
        return np.sqrt(a)

    def operator(a):
        return float((a * 2.0)[0])

    def caller(values):
        a = np.array(values)
        return ufunc(a), operator(a)

    uses, _ = numpy_use(lambda: [caller([1.0, 4.0]) for _ in range(3)])
    assert uses['test_bench.py:ufunc']['calls'] == 3
    assert uses['test_bench.py:operator']['calls'] == 3
    assert 'numpy array' in uses['test_bench.py:caller']['numpy']
    assert numpy_use(_floats_only)[0] == {}


# The raw-IMU goals: verdicts computed from the figures.

def test_raw_imu_node_verdict_is_the_ratio_of_the_medians_against_the_goal():
    from bench.imu_filter_cpu import goal_line, NODE_GOAL
    met = node_result([220, 230, 260], [200, 195, 190])
    assert met['ratio'] == pytest.approx(230 / 195) and met['met']
    assert met['round_ratios'] == pytest.approx([1.1, 230 / 195, 260 / 190])
    assert goal_line(met).endswith(': met')
    assert 'on both sides of the goal' in goal_line(met)
    missed = node_result([250, 250, 250], [200, 200, 200])
    assert missed['ratio'] == pytest.approx(1.25)
    assert missed['ratio'] > NODE_GOAL and not missed['met']
    assert goal_line(missed).endswith(': not met')


def test_raw_imu_batch_verdict():
    from bench.broad_batch import goal_line
    batch = {'trials': 22, 'goal': 10.0, 'median_seconds': 12.3, 'met': False,
             'runs': [{'workers': 2, 'seconds': 12.3, 'cpu_seconds': 24.0, 'load': (0.5, 4)}]}
    assert goal_line(batch).endswith('load average 0.5–4 on '
                                     f'{__import__("os").cpu_count()} cores): not met')


def test_a_target_that_got_fewer_outputs_back_is_flagged():
    from bench.imu_filter_cpu import goal_line
    result = node_result([230, 232, 236], [200, 201, 199])
    assert 'outputs short' not in goal_line(result)
    result['runs']['relay'][1]['outputs'] = 5294
    line = goal_line(result)
    assert line.endswith('(outputs short of the samples, fewest: relay 5294 of 8000; a target '
                         'that dropped samples did less work per sample)')
