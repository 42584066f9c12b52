"""
The raw-IMU parts of docs/performance.md: the raw-IMU node's and the compiled kernels' goals, sections 6 and 7.

Rendered from what ``python -m bench`` gathers under ``raw_imu`` (see
``bench/__main__.py``): ``node_events`` and ``node_single``
(:func:`bench.imu_filter_cpu.compare`), ``direct``
(:func:`bench.raw_imu_direct.direct`) and ``batch``
(:func:`bench.broad_batch.batch`); and under ``compiled``
(``python -m bench.compiled_kernels --json``: BROAD, the step per sample, the
start-up times), whose node row is section 6's ``node_events``. Any of them may be missing or hold an ``error``. Every
verdict is computed here from the figures, never typed.
"""

import statistics

from bench.broad_batch import BATCH_GOAL
from bench.compiled_kernels import (BROAD_GOAL, COLD_GOAL_S, COMPILED_NODE_GOAL,
                                    SCORE_TOLERANCE, STEP_GOAL_US, WARM_GOAL_S, WHOLE_AIM,
                                    WHOLE_GOAL)
from bench.machine import load_range
from bench.imu_filter_cpu import (NODE_GOAL, RAW_RELAY, SERIALIZED_GOAL, SERIALIZED_AIM,
                                  short_text, TYPED, verdict)
from docgen.compiled_page import BEGIN, END, whole_medians
from docgen.markdown import table as _table

HEADING = '6. Raw-IMU estimator (imu_filter_node)'
COMPILED_HEADING = '7. Compiled kernels'
EXECUTOR_NAMES = {'events': 'EventsExecutor (the default)', 'single': 'SingleThreadedExecutor'}
NODES = ('imu_filter_node', 'observer_node')


def _us(value):
    return '—' if value is None else f'{value:.1f} µs'


def _ok(part):
    return bool(part) and 'error' not in part


def _node_measured(node):
    ratios = node.get('round_ratios') or []
    spread = f', rounds {min(ratios):.2f}–{max(ratios):.2f}' if ratios else ''
    return (f'{node["ratio"]:.2f}× (imu_filter {_us(node["medians"]["imu_filter"])}, relay '
            f'{_us(node["medians"]["relay"])}; medians of {node["rounds"]}{spread})')


def _node_verdict(node, where=': see section 6'):
    ratios = node.get('round_ratios') or []
    text = verdict(node['met'])
    notes = []
    if ratios and min(ratios) <= node['goal'] < max(ratios):
        notes.append('rounds on both sides of the goal')
    if short_text(node):
        notes.append(f'outputs short of the samples{where}')
    return text + (f' ({"; ".join(notes)})' if notes else '')


def _serialized_row(node):
    """The serialized node against the typed relay, same run: the goal's row, or None."""
    if not _ok(node) or RAW_RELAY not in node.get('runs', {}):
        return None
    cpu = {label: [r['cpu_us_per_sample'] for r in rows] for label, rows in node['runs'].items()}
    relay = statistics.median(cpu['relay'])
    ratio = statistics.median(cpu['imu_filter']) / relay
    rounds = [f / r for f, r in zip(cpu['imu_filter'], cpu['relay'])]
    raw = statistics.median(cpu[RAW_RELAY]) / relay
    goal = (f'node CPU per IMU sample (1 kHz IMU, 100 Hz field, `serialized_io` true, the '
            f'default) ≤ {SERIALIZED_GOAL:g}× a typed rclpy relay\'s in the same run '
            f'(aim {SERIALIZED_AIM:g}×), EventsExecutor')
    measured = (f'{ratio:.2f}× (imu_filter {_us(ratio * relay)}, relay {_us(relay)}; medians '
                f'of {node["rounds"]}, rounds {min(rounds):.2f}–{max(rounds):.2f}); the relay on '
                f'bytes ({RAW_RELAY}) {raw:.2f}×')
    text = verdict(ratio <= SERIALIZED_GOAL)
    if ratio <= SERIALIZED_GOAL:
        text += f' (the aim {verdict(ratio <= SERIALIZED_AIM)})'
    return [goal, measured, text]


def targets_section(raw):
    """The raw-IMU node's speed targets: each goal, what was measured, met or not met."""
    rows = []
    serialized = _serialized_row(raw.get('node_events'))
    if serialized is not None:
        rows.append(serialized)
    for key in ('node_events', 'node_single'):
        node = raw.get(key)
        if node is None:
            continue
        executor = 'events' if key == 'node_events' else 'single'
        goal = (f'node CPU per IMU sample (1 kHz IMU, 100 Hz field) ≤ {NODE_GOAL:g}× the bare '
                f'relay\'s, {EXECUTOR_NAMES[executor]}')
        if _ok(node) and node.get('ratio') is not None:
            rows.append([goal, _node_measured(node), _node_verdict(node)])
        else:
            rows.append([goal, node.get('error', 'no result'), 'not measured'])
    batch = raw.get('batch')
    if batch is not None:
        goal = f'the core on all BROAD trials, both modes, batched, < {BATCH_GOAL:g} s'
        if _ok(batch):
            runs = batch['runs']
            rows.append([goal, f'{batch["median_seconds"]:.1f} s (median of {len(runs)}, '
                               f'{runs[0]["workers"]} workers, {batch["trials"]} trials; load '
                               f'average {load_range(runs)})', verdict(batch['met'])])
        else:
            rows.append([goal, batch['error'], 'not measured'])
    if not rows:
        return None
    return '\n'.join([
        '## Targets: the raw-IMU node\'s speed', '',
        f'Figures and commands: [section 6]({_anchor(HEADING)}). The load average is the '
        'machine\'s 1-minute load during the runs; above the number of cores, the other '
        'work shares them and the wall-clock figures stretch.', '',
        _table(['goal', 'measured', 'verdict'], rows)])


def _anchor(heading):
    slug = ''.join(c for c in heading.lower() if c.isalnum() or c in ' -_').replace(' ', '-')
    return '#' + slug


def _node_rows(node, executor):
    rows = []
    for label in [t for t in ('imu_filter', TYPED, RAW_RELAY, 'relay')
                  if t in node['runs']]:
        runs = node['runs'][label]
        cpu = ', '.join(f'{r["cpu_us_per_sample"]:.0f}' for r in runs)
        rows.append([f'{label} ({executor})', f'{node["medians"][label]:.1f} µs ({cpu})',
                     f'{min(r["outputs"] for r in runs)} / {runs[-1]["samples"]}',
                     f'{min(r["achieved_rate_hz"] for r in runs):.0f} Hz'])
    return rows


def section(raw):
    """Section 6: the node beside the relay, its callbacks' parts, the core's batch."""
    lines = [f'## {HEADING}', '']
    nodes = [(key.split('_')[1], raw[key]) for key in ('node_events', 'node_single')
             if _ok(raw.get(key)) and raw[key].get('ratio') is not None]
    if nodes:
        first = nodes[0][1]
        rows = [row for executor, node in nodes for row in _node_rows(node, executor)]
        lines += [
            f'`imu_filter_node` (the console script, its defaults: `use_mag` true) fed a raw '
            f'IMU at {first["rate"]:g} Hz (`sensor_msgs/Imu` on `imu/data_raw`) and a field at '
            f'{first["mag_rate"]:g} Hz (`imu/mag`), both best effort, from the BROAD excerpt '
            'of the tests (`test/data`) looped, beside `bench.imu_filter_cpu.ImuRelay`: the same '
            'message path without the maths (per sample the two outputs, `imu/data` and '
            '`attitude_estimate`; the latest field kept). Node CPU per IMU sample: user + '
            'system time of the target\'s process over the publishing window, divided by the '
            f'samples; {first["seconds"]:g} s per run, relay and filter runs interleaved, '
            'medians. `python -m bench.imu_filter_cpu --executor events|single --seconds '
            f'{first["seconds"]:g} --rounds N` prints the same table and the verdict; with '
            f'`--serialized` (the events runs here) also `{TYPED}` (the node with '
            f'`serialized_io` false) and `{RAW_RELAY}` (the relay on bytes, '
            '`bench.imu_filter_cpu.RawImuRelay`).', '',
            _table(['target (executor)', 'CPU per IMU sample, median (runs)',
                    'outputs received (fewest) / samples', 'achieved rate (slowest)'], rows), '']
        for executor, node in nodes:
            lines.append(f'- {executor}: imu_filter / relay = **{node["ratio"]:.2f}×** '
                         f'(goal ≤ {NODE_GOAL:g}×: {_node_verdict(node, where="")}); round by '
                         'round '
                         + ', '.join(f'{x:.2f}' for x in node['round_ratios']) + '.')
            if short_text(node):
                lines.append(f'- {executor}: {short_text(node)} (it may also be the driver '
                             'that fell behind): under this load the ratio is not a clean '
                             'measure.')
        lines.append('')
    direct = raw.get('direct')
    if _ok(direct):
        lines += _direct_lines(direct)
    batch = raw.get('batch')
    if _ok(batch):
        lines += _batch_lines(batch)
    for key in ('node_events', 'node_single', 'direct', 'batch'):
        if raw.get(key) is not None and not _ok(raw[key]):
            lines.append(f'- {key}: {raw[key]["error"]}')
    return '\n'.join(lines).rstrip('\n')


def _direct_lines(d):
    node, relay = d['imu_filter_callbacks'], d['relay_callbacks']
    rows = [
        ['`imu_filter_node`\'s two callbacks (`imu/data_raw`, `imu/mag`)', _us(node)],
        ['the relay\'s two callbacks', _us(relay)],
    ]
    if 'imu_filter_serialized_callbacks' in d:
        rows += [['`imu_filter_node`\'s two callbacks on CDR bytes (`serialized_io` true, '
                  'the default)', _us(d['imu_filter_serialized_callbacks'])],
                 ['the relay on bytes\' two callbacks', _us(d['raw_relay_callbacks'])]]
    rows += [
        ['… `RawImuPipeline` alone (input checks, stamps, unit checks, the estimator; '
         'no messages)', _us(d['pipeline'])],
        ['… … `AhrsObserver.update` and `update_mag` alone (the core\'s float step)',
         _us(d['core'])],
        ['one real `publish` of the `sensor_msgs/Imu` output (no subscriber)',
         _us(d['publish_imu'])],
        ['one real `publish` of `attitude_estimate` (no subscriber)', _us(d['publish_estimate'])],
    ]
    uses = d.get('numpy_use_per_sample') or {}
    numpy_text = ('none' if not uses else '; '.join(
        f'`{label}` ×{entry["per_step"]:.3g} per sample ({", ".join(entry["numpy"])})'
        for label, entry in sorted(uses.items())))
    return [
        'The callbacks called directly with prepared messages (`python -m '
        f'bench.raw_imu_direct`: {d["samples"]} samples at 1 kHz, a field every tenth; no '
        'executor, no DDS receive, warm caches; the best of a few passes). Publishing is '
        'replaced by a no-op in every node, which build their two outputs per sample and send '
        'none: the rows on callbacks are each node\'s own Python work per IMU sample, the '
        'filter on its compiled kernels' + ('' if d.get('compiled', True) else
                                             ' (NOT compiled here: the plain kernels)')
        + '; the parts below are timed alone.', '',
        _table(['per IMU sample', 'time'], rows), '',
        f'- What the filter adds to the relay\'s work, called directly: {_us(node - relay)} per '
        f'sample, {_us(d["pipeline"])} of it in the ROS-free pipeline ({_us(d["core"])} in the '
        'core\'s step); the rest turns messages into the pipeline\'s inputs and its estimate '
        'into the two outputs.' + (
            '' if 'imu_filter_serialized_callbacks' not in d else
            f' On CDR bytes: {_us(d["imu_filter_serialized_callbacks"] - d["raw_relay_callbacks"])}'
            ' above the relay on bytes.'),
        f'- Functions on the callbacks\' path that use numpy (`bench/numpy_use.py`): '
        f'{numpy_text}.', '']


def _batch_lines(b):
    runs = b['runs']
    rows = [[r['workers'], f'{r["seconds"]:.1f} s', f'{r["cpu_seconds"]:.1f} s',
             f'{r["cpu_seconds"] / r["workers"]:.1f} s',
             f'{r["cpu_seconds"] / b["sample_updates"] * 1e6:.1f} µs', load_range([r])]
            for r in runs + ([b['vectorized']] if b.get('vectorized') else [])]
    cpu = statistics.median(r['cpu_seconds'] for r in runs)
    return [
        f'The core over the BROAD trials (`python -m bench.broad_batch`, data from '
        f'`{b["data"]}`): the one batched call `python -m ext_observer broad` makes for our '
        f'estimator (`estimate_batch`, every trial in 9D and 6D: {b["recordings"]} recordings, '
        f'{b["sample_updates"]:,} sample-updates), reading the files not timed; '
        f'{len(runs)} runs with the default workers (the CPUs)'
        + (', then one in a single process (`workers=1`)' if b.get('vectorized') else '')
        + '. CPU: user + system time of all the processes.', '',
        _table(['workers', 'wall clock', 'CPU', 'CPU / workers', 'CPU per sample-update',
                'load average (before, after)'], rows), '',
        f'- Median wall clock {b["median_seconds"]:.1f} s against the goal < {b["goal"]:g} s: '
        f'{verdict(b["met"])}. The work is {cpu:.1f} s of CPU (median); CPU / workers is the '
        'wall clock the run would take with its cores to itself.', '']


def analysis_line(raw):
    """The raw-IMU bullet of 'What limits the figures', or None."""
    direct, node = raw.get('direct'), raw.get('node_events')
    if not (_ok(direct) and _ok(node) and node.get('ratio') is not None):
        return None
    imu_filter, relay = node['medians']['imu_filter'], node['medians']['relay']
    added = direct['imu_filter_callbacks'] - direct['relay_callbacks']
    shared = ('most of it' if relay >= imu_filter - relay else 'less than what the filter adds')
    ratios = node.get('round_ratios') or []
    text = (f'- **Raw IMU.** Live, `imu_filter_node`\'s process spends {_us(imu_filter)} of CPU '
            f'per IMU sample ({node["executor"]}) against the relay\'s {_us(relay)}, which is '
            f'what the executor, DDS and the message path cost both: {shared}. What the filter '
            f'adds is {_us(added)} per sample when its callbacks are called directly: '
            f'{_us(direct["core"])} in the estimator\'s float step, '
            f'{_us(direct["pipeline"] - direct["core"])} in the rest of the pipeline (input '
            'checks, stamps, guard), the rest in the messages; live, the difference of the '
            f'medians is {_us(imu_filter - relay)}.')
    if ratios:
        text += (f' Round by round the ratio spans {min(ratios):.2f}–{max(ratios):.2f}, '
                 f'against the goal {node["goal"]:g}.')
    return text


# --- section 7: the compiled kernels ---------------------------------------

def _broad_rows(b):
    vqf, two, one = b['VQF, 1 process'], b['compiled, 2 processes'], b['compiled, 1 process']
    aim = '' if two <= vqf else ' (the aim, ≤ 1×, not reached)'
    return [(f'the {b["trials"]} dev trials × 9D and 6D from a warm cache: wall time '
             f'≤ {BROAD_GOAL:g}× VQF\'s in the same run (aim ≤ 1×)',
             f'{two:.2f} s on 2 processes, {one:.2f} s on 1, VQF {vqf:.2f} s: '
             f'{two / vqf:.2f}×', verdict(two <= BROAD_GOAL * vqf) + aim),
            ('the scores unchanged to 1e-9 (compiled against plain)',
             f'largest difference {b["max_dscore"]:.1e}° (of a quaternion component: '
             f'{b["max_dq"]:.1e})',
             verdict(b['max_dscore'] <= SCORE_TOLERANCE))]


def _step_row(steps):
    nine, six = steps['9D update compiled'], steps['6D update compiled']
    return (f'the core\'s step on floats ≤ {STEP_GOAL_US:g} µs per sample',
            f'9D (calibration on) {nine:.2f} µs, 6D {six:.2f} µs (`AhrsObserver.update`, '
            'compiled)', verdict(max(nine, six) <= STEP_GOAL_US))


def _node_row(node):
    medians, ratio = node['medians'], node['ratio']
    ratios = node.get('round_ratios') or []
    measured = (f'{ratio:.2f}× (imu_filter {medians["imu_filter"]:.1f} µs, relay '
                f'{medians["relay"]:.1f} µs; medians of {node["rounds"]}')
    if ratios:
        measured += f', rounds {min(ratios):.2f}–{max(ratios):.2f}'
    measured += ')'
    text = verdict(ratio <= COMPILED_NODE_GOAL)
    if ratios and min(ratios) <= COMPILED_NODE_GOAL < max(ratios):
        text += ' (rounds on both sides of the goal)'
    return (f'raw-IMU node, 1 kHz IMU + 100 Hz field: CPU per sample ≤ '
            f'{COMPILED_NODE_GOAL:g}× a '
            'bare relay\'s (EventsExecutor)', measured, text)


def _start_rows(starts):
    rows = []
    for name in NODES:
        key = f'{name} to its first /diagnostics'
        if key not in starts:
            continue
        cold, warm = starts[key]
        measured = f'cold {cold:.2f} s, warm {warm:.2f} s'
        compiled = starts.get(f'{name} to the compiled kernels')
        if compiled:
            measured += (f' (on the plain kernels until the compiled ones: cold '
                         f'{compiled[0]:.2f} s, warm {compiled[1]:.2f} s)')
        rows.append((f'{name}: first start under {COLD_GOAL_S:g} s cold, under '
                     f'{WARM_GOAL_S:g} s warm', measured,
                     verdict(cold < COLD_GOAL_S and warm < WARM_GOAL_S)))
    return rows


def compiled_targets_section(compiled, raw):
    """The compiled kernels' speed targets: each goal, measured, met or not; '' without figures."""
    rows = []
    if _ok(compiled):
        if compiled.get('broad'):
            rows += _broad_rows(compiled['broad'])
        if compiled.get('steps'):
            rows.append(_step_row(compiled['steps']))
    node = (raw or {}).get('node_events')
    if _ok(node) and node.get('ratio') is not None:
        rows.append(_node_row(node))
    if _ok(compiled) and compiled.get('starts'):
        rows += _start_rows(compiled['starts'])
    if _ok(compiled) and compiled.get('whole'):
        rows.append(_whole_row(compiled['whole']))
    if not rows:
        return ''
    return ('## Targets: the compiled kernels\' speed\n\n'
            'Figures: [section 7](#7-compiled-kernels) and, for the node, '
            '[section 6](#6-raw-imu-estimator-imu_filter_node).\n\n'
            + _table(['goal', 'measured', 'verdict'], rows))


def _whole_row(whole):
    m = whole_medians(whole)
    ratio = m['ours'] / m['VQF']
    aim = '' if ratio <= WHOLE_AIM else f' (the aim, ≤ {WHOLE_AIM:g}×, not reached)'
    return (f'the BROAD command\'s whole-process time, 22 trials × 9D and 6D, warm cache: '
            f'≤ {WHOLE_GOAL:g}× VQF\'s time for the same work (aim ≤ {WHOLE_AIM:g}×)',
            f'{m["ours"]:.2f} s, VQF {m["VQF"]:.2f} s: {ratio:.2f}× (medians of '
            f'{len(whole["VQF"])}, load {whole["load"][0]:.1f}–{whole["load"][1]:.1f}); '
            f'to its first estimate {m["first estimate"]:.2f} s',
            verdict(ratio <= WHOLE_GOAL) + aim)


def compiled_section(compiled):
    """Section 7: what ``python -m bench.compiled_kernels`` printed (as in docs/compiled.md)."""
    if not compiled:
        return ''
    if 'error' in compiled:
        return f'## {COMPILED_HEADING}\n\nNot measured: {compiled["error"]}'
    body = [line for line in compiled['section'].splitlines() if line not in (BEGIN, END)]
    return (f'## {COMPILED_HEADING}\n\nThe raw-IMU estimator\'s steps compiled by numba '
            '([compiled.md](compiled.md): how, and what is not met).\n\n'
            + '\n'.join(body).strip())
