"""
The compiled kernels' part of docs/performance.md: their speed goals and section 7.

Rendered from what ``python -m bench`` gathers under ``compiled``
(``python -m bench.compiled_kernels --json``: BROAD, the step per sample, the
start-up times) and, for the node's CPU, the raw-IMU run of section 6
(``raw_imu['node_events']``, with the ``step_only`` floor). Either may be
missing or hold an ``error``. Every verdict is computed here from the
figures, never typed.
"""

from bench.compiled_kernels import BEGIN, END, COMPILED_NODE_GOAL
from bench.imu_filter_cpu import FLOOR, verdict

HEADING = '7. Compiled kernels'
# The compiled kernels' speed goals: BROAD's wall time within this factor of VQF's (aim: 1),
# the scores unchanged to this many degrees, the step on floats within this
# many µs, a node's first start within these seconds (cold, warm).
BROAD_GOAL = 3.0
SCORE_TOLERANCE = 1e-9
STEP_GOAL_US = 2.0
COLD_GOAL_S = 10.0
WARM_GOAL_S = 2.0
# The BROAD command's whole process within this factor of VQF's
# doing the same work (aim: the second).
WHOLE_GOAL = 1.0
WHOLE_AIM = 0.5
NODES = ('imu_filter_node', 'observer_node')


def _ok(part):
    return bool(part) and 'error' not in part


def _table(rows):
    lines = ['| goal | measured | verdict |', '|---|---|---|']
    lines += [f'| {goal} | {measured} | {text} |' for goal, measured, text in rows]
    return '\n'.join(lines)


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
    if medians.get(FLOOR) and medians.get('relay'):
        measured += (f'; {FLOOR}, the estimate\'s arithmetic alone: '
                     f'{medians[FLOOR] / medians["relay"]:.2f}×')
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


def targets_section(compiled, raw):
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
            f'Figures: [section 7](#7-compiled-kernels) and, for the node, '
            '[section 6](#6-raw-imu-estimator-imu_filter_node).\n\n' + _table(rows))


def _whole_row(whole):
    from bench.compiled_kernels import whole_medians
    m = whole_medians(whole)
    ratio = m['ours'] / m['VQF']
    aim = '' if ratio <= WHOLE_AIM else f' (the aim, ≤ {WHOLE_AIM:g}×, not reached)'
    return (f'the BROAD command\'s whole-process time, 22 trials × 9D and 6D, warm cache: '
            f'≤ {WHOLE_GOAL:g}× VQF\'s time for the same work (aim ≤ {WHOLE_AIM:g}×)',
            f'{m["ours"]:.2f} s, VQF {m["VQF"]:.2f} s: {ratio:.2f}× (medians of '
            f'{len(whole["VQF"])}, load {whole["load"][0]:.1f}–{whole["load"][1]:.1f}); '
            f'to its first estimate {m["first estimate"]:.2f} s',
            verdict(ratio <= WHOLE_GOAL) + aim)


def section(compiled):
    """Section 7: what ``python -m bench.compiled_kernels`` printed (as in docs/compiled.md)."""
    if not compiled:
        return ''
    if 'error' in compiled:
        return f'## {HEADING}\n\nNot measured: {compiled["error"]}'
    body = [line for line in compiled['section'].splitlines() if line not in (BEGIN, END)]
    return (f'## {HEADING}\n\nThe raw-IMU estimator\'s steps compiled by numba '
            '([compiled.md](compiled.md): how, and what is not met).\n\n'
            + '\n'.join(body).strip())
