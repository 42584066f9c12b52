"""
Checks of the benchmark's own logic (no ROS, no timing): ``pytest bench``.

The matching of estimates to steps decides "lost" and the latencies, so it
is tested on made-up records; the report must render any partial results.
"""

import numpy as np
import pytest

from bench import performance_page
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
    text = performance_page.render({'machine': machine, 'command': 'python -m bench'})
    assert text.startswith('# Performance')
    node_run = {'target': 'relay/single', 'label': 'relay', 'executor': 'single',
                'rate': 1000, 'steps': 10, 'lost': 0, 'extra': 0, 'p50': 0.4,
                'p99': 1.0, 'max': 2.0, 'sustained': True, 'achieved': 1000.0,
                'seconds': 1.0, 'cpu_us_per_step': 600.0, 'propagated': None,
                'dropped': None}
    text = performance_page.render({'machine': machine, 'command': 'c',
                          'nodes': [node_run, {'target': 'observer/single',
                                               'label': 'observer',
                                               'executor': 'single',
                                               'error': 'did not start'}],
                          'rates': [1000]})
    assert '| relay/single | ✓ 0.40 |' in text
    assert 'did not start' in text


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


def test_numpy_row_of_the_targets():
    row = performance_page.numpy_use_row({'numpy_use_per_step': {}, 'numpy_use_steps': 1000})
    assert row[2] == 'yes' and '1000 steps' in row[1]
    row = performance_page.numpy_use_row({'numpy_use_per_step': {
        'quaternion.py:normalize': {'per_step': 1.0, 'numpy': ['numpy asarray']}}})
    assert row[2] == 'no' and '`quaternion.py:normalize` ×1 (numpy asarray)' in row[1]
    assert performance_page.numpy_use_row({})[2] == 'not measured'


# The raw-IMU goals: verdicts computed from the figures.

def _node_runs(filter_us, relay_us):
    def run(us):
        return {'cpu_us_per_sample': us, 'samples': 8000, 'fields': 800, 'outputs': 8000,
                'achieved_rate_hz': 999.0, 'load': (1.0, 1.5)}
    return {'imu_filter': [run(x) for x in filter_us], 'relay': [run(x) for x in relay_us]}


def _node_result(filter_us, relay_us, executor='events'):
    from bench.imu_filter_cpu import summarize
    runs = _node_runs(filter_us, relay_us)
    result = {'executor': executor, 'rate': 1000.0, 'mag_rate': 100.0, 'seconds': 8.0,
              'rounds': len(filter_us), 'runs': runs}
    result.update(summarize(runs))
    return result


def test_raw_imu_node_verdict_is_the_ratio_of_the_medians_against_the_goal():
    from bench.imu_filter_cpu import goal_line, NODE_GOAL
    met = _node_result([220, 230, 260], [200, 195, 190])
    assert met['ratio'] == pytest.approx(230 / 195) and met['met']
    assert met['round_ratios'] == pytest.approx([1.1, 230 / 195, 260 / 190])
    assert goal_line(met).endswith(': met')
    assert 'on both sides of the goal' in goal_line(met)
    missed = _node_result([250, 250, 250], [200, 200, 200])
    assert missed['ratio'] == pytest.approx(1.25)
    assert missed['ratio'] > NODE_GOAL and not missed['met']
    assert goal_line(missed).endswith(': not met')


def test_raw_imu_batch_verdict():
    from bench.broad_batch import goal_line
    batch = {'trials': 22, 'goal': 10.0, 'median_seconds': 12.3, 'met': False,
             'runs': [{'workers': 2, 'seconds': 12.3, 'cpu_seconds': 24.0, 'load': (0.5, 4)}]}
    assert goal_line(batch).endswith('load average 0.5–4 on '
                                     f'{__import__("os").cpu_count()} cores): not met')


def test_report_renders_the_raw_imu_goals_and_section():
    from bench import report_raw_imu
    machine = {'date': 'today', 'commit': 'abc', 'cores': 2, 'cpu': 'x',
               'python': '3', 'numpy': '2', 'rclpy': '7', 'rmw': 'r',
               'rmw_fastrtps_cpp': '8', 'load_start': 0.1, 'load_end': 0.2}
    direct = {'samples': 5000, 'imu_filter_callbacks': 32.0, 'relay_callbacks': 2.0,
              'imu_filter_serialized_callbacks': 9.5, 'raw_relay_callbacks': 0.5,
              'compiled': True, 'pipeline': 15.0, 'core': 10.0, 'publish_imu': 14.0, 'publish_estimate': 10.0,
              'outputs_per_sample': {'imu_filter': 2.0, 'relay': 2.0},
              'numpy_use_per_sample': {}}
    batch = {'data': 'data/broad', 'trials': 22, 'recordings': 44, 'sample_updates': 2387574,
             'runs': [{'workers': 2, 'seconds': 8.0, 'cpu_seconds': 15.5, 'load': (0.3, 0.9)}],
             'median_seconds': 8.0, 'goal': 10.0, 'met': True, 'vectorized': None}
    raw = {'node_events': _node_result([230, 232, 236], [200, 201, 199]),
           'node_single': {'error': 'ended with exit code 1 and no result'},
           'direct': direct, 'batch': batch}
    text = performance_page.render({'machine': machine, 'command': 'python -m bench', 'raw_imu': raw})
    assert "## Targets: the raw-IMU node's speed" in text
    assert f'## {report_raw_imu.HEADING}' in text
    assert '(#6-raw-imu-estimator-imu_filter_node)' in text
    rows = [line for line in text.splitlines() if line.startswith('| node CPU per IMU')]
    assert rows[0].endswith('| met |') and '1.16×' in rows[0]
    assert rows[1].endswith('| not measured |')
    assert any(line.startswith('| the core on all BROAD') and line.endswith('| met |')
               for line in text.splitlines())
    assert 'numpy (`bench/numpy_use.py`): none.' in text
    assert 'On CDR bytes: 9.0 µs above the relay on bytes.' in text
    assert 'NOT compiled' not in text
    assert '- **Raw IMU.**' in text
    raw['batch'] = {'error': 'not run: no BROAD data'}
    text = performance_page.render({'machine': machine, 'command': 'c', 'raw_imu': raw})
    assert 'not run: no BROAD data | not measured |' in text


def _serialized_row(text):
    return next(line for line in text.splitlines() if '`serialized_io` true' in line)


def test_report_renders_the_serialized_node_against_the_typed_relay():
    from bench import report_raw_imu
    from bench.imu_filter_cpu import RAW_RELAY, summarize, TYPED
    node = _node_result([110, 130, 120], [200, 210, 190])
    extra = _node_runs([100, 105, 95], [250, 240, 260])
    node['runs'][RAW_RELAY], node['runs'][TYPED] = extra['imu_filter'], extra['relay']
    node.update(summarize(node['runs']))
    row = _serialized_row(report_raw_imu.targets_section({'node_events': node}))
    # 120 / 200: within 0.6, not within the aim 0.4; the relay on bytes 100 / 200.
    assert '0.60× (imu_filter 120.0 µs, relay 200.0 µs; medians of 3, rounds 0.55–0.63)' in row
    assert f'({RAW_RELAY}) 0.50×' in row and row.endswith('| met (the aim not met) |')
    node['runs']['imu_filter'] = extra['relay']
    node.update(summarize(node['runs']))
    row = _serialized_row(report_raw_imu.targets_section({'node_events': node}))
    assert row.endswith('| not met |')
    section = report_raw_imu.section({'node_events': node})
    assert f'| {TYPED} (events) |' in section and f'| {RAW_RELAY} (events) |' in section


def test_report_renders_the_compiled_kernels_goals_from_the_figures():
    from bench import report_compiled
    from bench.compiled_kernels import as_json, markdown
    machine = {'date': 'today', 'commit': 'abc', 'cores': 2, 'cpu': 'x',
               'python': '3', 'numpy': '2', 'rclpy': '7', 'rmw': 'r',
               'rmw_fastrtps_cpp': '8', 'load_start': 0.1, 'load_end': 0.2}
    broad = {'trials': 22, 'samples': 1000, 'VQF, 1 process': 1.3, 'compiled, 1 process': 1.2,
             'compiled, 2 processes': 1.0, 'plain, 2 processes': 50.0, 'max_dq': 0.0,
             'max_dscore': 0.0}
    steps = {'samples': 100, ('9D', 'update', True): 1.4, ('9D', 'update', False): 50.0,
             ('6D', 'update', True): 2.3, ('6D', 'update', False): 9.0,
             ('9D', 'run', True): 0.4, ('6D', 'run', True): 0.2}
    starts = {'imu_filter_node to its first /diagnostics': (0.7, 0.6),
              'imu_filter_node to the compiled kernels': (25.0, 1.9),
              'observer_node to its first /diagnostics': (11.0, 0.5)}
    meta = {'command': 'python -m bench.compiled_kernels', 'commit': 'abc', 'numba': '0', 'machine': 'x'}
    whole = {'ours': [1.6, 1.2, 1.3], 'ours, 1 process': [1.5, 1.6, 1.7], 'VQF': [2.0, 2.2, 2.1],
             'first estimate': [0.7, 0.8, 0.9], 'load': [1.0, 1.5]}
    compiled = as_json(broad, steps, starts, markdown(broad, steps, starts, meta, whole=whole),
                       whole)
    node = _node_result([230, 232, 236], [200, 201, 199])  # 1.15x: not met
    text = performance_page.render({'machine': machine, 'command': 'python -m bench',
                          'raw_imu': {'node_events': node}, 'compiled': compiled})
    rows = {line.split(' | ')[0]: line for line in text.splitlines()
            if line.startswith('| ') and line.endswith(' |')}

    def row(start):
        (found,) = [line for key, line in rows.items() if key.startswith('| ' + start)]
        return found

    assert "## Targets: the compiled kernels' speed" in text
    assert f'## {report_compiled.HEADING}' in text and '(#7-compiled-kernels)' in text
    assert row('the 22 dev trials').endswith('1.00 s on 2 processes, 1.20 s on 1, VQF 1.30 s: '
                                             '0.77× | met |')
    assert row('the scores unchanged').endswith('| met |')
    # 6D's 2.3 µs is over the 2 µs goal.
    assert row("the core's step").endswith('| not met |')
    assert row('raw-IMU node').endswith('| not met |') and '1.16×' in row('raw-IMU node')
    assert row('imu_filter_node: first start').endswith('| met |')
    assert row('observer_node: first start').endswith('| not met |')
    # The whole process: the medians 1.3 and 2.1 s, 0.62x: the goal met, not the aim.
    assert row("the BROAD command's whole-process time").endswith(
        '1.30 s, VQF 2.10 s: 0.62× (medians of 3, load 1.0–1.5); to its first estimate '
        '0.80 s | met (the aim, ≤ 0.5×, not reached) |')
    assert '| ours, `--workers 1` | 1.60 | 0.76 |' in text
    assert report_compiled.BEGIN not in text
    # Without its figures, no table.
    assert report_compiled.targets_section(None, {}) == ''


def test_a_target_that_got_fewer_outputs_back_is_flagged():
    from bench.imu_filter_cpu import goal_line
    result = _node_result([230, 232, 236], [200, 201, 199])
    assert 'outputs short' not in goal_line(result)
    result['runs']['relay'][1]['outputs'] = 5294
    line = goal_line(result)
    assert line.endswith('(outputs short of the samples, fewest: relay 5294 of 8000; a target '
                         'that dropped samples did less work per sample)')
    from bench import report_raw_imu
    assert report_raw_imu.targets_section({'node_events': result}).splitlines()[-1].endswith(
        '| met (outputs short of the samples: see section 6) |')


def test_the_header_says_when_the_machine_was_not_idle():
    machine = {'date': 'today', 'commit': 'abc', 'cores': 2, 'cpu': 'x', 'python': '3',
               'numpy': '2', 'rclpy': '7', 'rmw': 'r', 'rmw_fastrtps_cpp': '8',
               'load_start': 0.4, 'load_end': 1.5}
    assert 'not idle' not in performance_page.machine_section(machine, 'c')
    machine['load_end'] = 6.02
    assert 'load average reached 6.02 on 2 cores' in performance_page.machine_section(machine, 'c')


def test_the_magcal_yardstick_recovers_a_known_calibration_from_known_attitudes():
    """bench.calibration's least-squares yardstick: ``A y − c`` is the field again, up to scale."""
    from bench.calibration import oracle_calibration
    from ext_observer.core.quaternion import random_unit_quaternions
    rng = np.random.default_rng(3)
    q = random_unit_quaternions(rng, (400,))
    w, x, y, z = q.T
    r = np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
                  2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
                  2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
                 axis=1).reshape(-1, 3, 3)
    world = np.array([0.0, 16.0, -41.0])
    field = np.einsum('nji,j->ni', r, world)  # Rᵀ m_w, body frame
    soft = np.array([[1.08, 0.05, -0.03], [0.05, 0.95, 0.02], [-0.03, 0.02, 1.04]])
    bias = np.array([30.0, -50.0, 20.0])
    raw = field @ soft.T + bias + rng.normal(scale=0.3, size=field.shape)
    raw[::50] += 40.0  # a magnet near the path: the robust refit drops these
    a, c = oracle_calibration(q, raw)
    calibrated = raw @ a.T - c
    scale = np.median(np.linalg.norm(calibrated, axis=1) / np.linalg.norm(field, axis=1))
    good = np.ones(len(raw), dtype=bool)
    good[::50] = False
    error = np.linalg.norm(calibrated[good] / scale - field[good], axis=1)
    assert np.max(error) < 0.05 * np.linalg.norm(world)
    np.testing.assert_allclose(a / scale, np.linalg.inv(soft), atol=0.01)


def test_the_magcal_floor_is_the_start_error_held_for_t_then_the_undistorted_figure():
    """bench.calibration --floor on a synthetic trial with a known field and attitude."""
    from bench.calibration import floor_figures
    from ext_observer.broad.data import Trial
    rate, n = 100.0, 10000  # 100 s, all of it movement
    angle = np.linspace(0.0, 20.0, n)  # a turn about the vertical
    quat = np.stack([np.cos(angle / 2), 0 * angle, 0 * angle, np.sin(angle / 2)], axis=1)
    world = np.array([0.0, 20.0, -40.0])
    c, s = np.cos(angle), np.sin(angle)
    mag = np.stack([c * world[0] + s * world[1], -s * world[0] + c * world[1],
                    np.full(n, world[2])], axis=1)  # Rᵀ m_w
    gyr = np.zeros((n, 3))
    gyr[:, 2] = 20.0 / (n / rate)
    trial = Trial('synthetic', gyr, np.tile([0.0, 0.0, 9.81], (n, 1)), mag, quat,
                  np.ones(n, dtype=bool), rate)
    f = floor_figures([trial], levels=(0.0, 3.0), undistorted=1.0)
    assert f['movement_s'] == [100.0]
    # No offset: only the ±10 % soft iron turns the field, by a few degrees;
    # a 3 |m| offset leaves the heading nearly uniform (RMS about 104°).
    assert f['start_error_deg'][0.0] < 10.0 < 60.0 < f['start_error_deg'][3.0]
    e2 = f['start_error_deg'][3.0] ** 2
    for t, bound in f['floor'][3.0].items():
        assert bound == pytest.approx(np.sqrt((t * e2 + (100.0 - t) * 1.0) / 100.0))
    bounds = list(f['floor'][3.0].values())
    assert bounds == sorted(bounds) and bounds[0] > 2.0
    # Twice the undistorted figure is reached after needed_s of a wrong heading.
    t = f['needed_s'][3.0]
    assert 0.0 < t < 0.1
    assert np.sqrt((t * e2 + (100.0 - t)) / 100.0) == pytest.approx(2.0, rel=1e-6)
    assert f['turned_deg'][1.0] == pytest.approx(np.degrees(0.2), rel=0.05)
