"""
The page docs/performance.md (``docgen/performance_page.py``, ``docgen/performance_raw_imu.py``).

From made-up results: any partial run renders, and every verdict is computed
from the figures.
"""

from bench.compiled_kernels import as_json
from docgen.compiled_page import BEGIN, markdown
from bench.imu_filter_cpu import RAW_RELAY, summarize, TYPED
from bench_results import MACHINE, node_result, node_runs
from docgen import performance_page
from docgen import performance_raw_imu as raw_imu_page


def test_report_renders_partial_results():
    machine = MACHINE
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


def test_numpy_row_of_the_targets():
    row = performance_page.numpy_use_row({'numpy_use_per_step': {}, 'numpy_use_steps': 1000})
    assert row[2] == 'yes' and '1000 steps' in row[1]
    row = performance_page.numpy_use_row({'numpy_use_per_step': {
        'quaternion.py:normalize': {'per_step': 1.0, 'numpy': ['numpy asarray']}}})
    assert row[2] == 'no' and '`quaternion.py:normalize` ×1 (numpy asarray)' in row[1]
    assert performance_page.numpy_use_row({})[2] == 'not measured'


def test_report_renders_the_raw_imu_goals_and_section():
    machine = MACHINE
    direct = {'samples': 5000, 'imu_filter_callbacks': 32.0, 'relay_callbacks': 2.0,
              'imu_filter_serialized_callbacks': 9.5, 'raw_relay_callbacks': 0.5,
              'compiled': True, 'pipeline': 15.0, 'core': 10.0, 'publish_imu': 14.0, 'publish_estimate': 10.0,
              'outputs_per_sample': {'imu_filter': 2.0, 'relay': 2.0},
              'numpy_use_per_sample': {}}
    batch = {'data': 'data/broad', 'trials': 22, 'recordings': 44, 'sample_updates': 2387574,
             'runs': [{'workers': 2, 'seconds': 8.0, 'cpu_seconds': 15.5, 'load': (0.3, 0.9)}],
             'median_seconds': 8.0, 'goal': 10.0, 'met': True, 'vectorized': None}
    raw = {'node_events': node_result([230, 232, 236], [200, 201, 199]),
           'node_single': {'error': 'ended with exit code 1 and no result'},
           'direct': direct, 'batch': batch}
    text = performance_page.render({'machine': machine, 'command': 'python -m bench', 'raw_imu': raw})
    assert "## Targets: the raw-IMU node's speed" in text
    assert f'## {raw_imu_page.HEADING}' in text
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
    node = node_result([110, 130, 120], [200, 210, 190])
    extra = node_runs([100, 105, 95], [250, 240, 260])
    node['runs'][RAW_RELAY], node['runs'][TYPED] = extra['imu_filter'], extra['relay']
    node.update(summarize(node['runs']))
    row = _serialized_row(raw_imu_page.targets_section({'node_events': node}))
    # 120 / 200: within 0.6, not within the aim 0.4; the relay on bytes 100 / 200.
    assert '0.60× (imu_filter 120.0 µs, relay 200.0 µs; medians of 3, rounds 0.55–0.63)' in row
    assert f'({RAW_RELAY}) 0.50×' in row and row.endswith('| met (the aim not met) |')
    node['runs']['imu_filter'] = extra['relay']
    node.update(summarize(node['runs']))
    row = _serialized_row(raw_imu_page.targets_section({'node_events': node}))
    assert row.endswith('| not met |')
    section = raw_imu_page.section({'node_events': node})
    assert f'| {TYPED} (events) |' in section and f'| {RAW_RELAY} (events) |' in section


def test_report_renders_the_compiled_kernels_goals_from_the_figures():
    machine = MACHINE
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
    node = node_result([230, 232, 236], [200, 201, 199])  # 1.15x: not met
    text = performance_page.render({'machine': machine, 'command': 'python -m bench',
                          'raw_imu': {'node_events': node}, 'compiled': compiled})
    rows = {line.split(' | ')[0]: line for line in text.splitlines()
            if line.startswith('| ') and line.endswith(' |')}

    def row(start):
        (found,) = [line for key, line in rows.items() if key.startswith('| ' + start)]
        return found

    assert "## Targets: the compiled kernels' speed" in text
    assert f'## {raw_imu_page.COMPILED_HEADING}' in text and '(#7-compiled-kernels)' in text
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
    assert BEGIN not in text
    # Without its figures, no table.
    assert raw_imu_page.compiled_targets_section(None, {}) == ''


def test_the_header_says_when_the_machine_was_not_idle():
    machine = dict(MACHINE, load_start=0.4, load_end=1.5)
    assert 'not idle' not in performance_page.machine_section(machine, 'c')
    machine['load_end'] = 6.02
    assert 'load average reached 6.02 on 2 cores' in performance_page.machine_section(machine, 'c')


def test_a_target_that_got_fewer_outputs_back_is_flagged_in_the_goals():
    result = node_result([230, 232, 236], [200, 201, 199])
    result['runs']['relay'][1]['outputs'] = 5294
    assert raw_imu_page.targets_section({'node_events': result}).splitlines()[-1].endswith(
        '| met (outputs short of the samples: see section 6) |')
