"""
The page ``docs/performance.md``, from the results ``python -m bench`` gathers.

The machine, the speed targets and sections 1 to 5 (the paper observer
node and the batch core) here; the raw-IMU node's and the compiled
kernels' (sections 6 and 7) in :mod:`docgen.performance_raw_imu`. Every
verdict is computed from the figures, never typed.
"""

from bench.nodes import LATENCY_RATE, SHIPPED, SUSTAINED_MEDIAN_MS, sustained_rate
from docgen import performance_raw_imu as raw_imu_page
from docgen.markdown import table as _table

BATCH_TARGET = 20e6  # updates/s at batch size 100 000
REPRODUCE_TARGET = 5.0  # s
LATENCY_MARGIN_MS = 0.2


def _si(value):
    for scale, suffix in ((1e9, ' G'), (1e6, ' M'), (1e3, ' k')):
        if value >= scale:
            return f'{value / scale:.3g}{suffix}'
    return f'{value:.3g}'


def _us(value):
    if value is None:
        return '—'
    if value >= 1000:
        return f'{value / 1000:.3g} ms'
    return f'{value:.3g} µs'


def _ms(value):
    return '—' if value is None else f'{value:.2f}' if value < 10 else f'{value:.0f}'


def machine_section(m, command):
    """The header: what ran where."""
    loads = [x for x in (m.get('load_start'), m.get('load_end')) if x is not None]
    busy = []
    if loads and m.get('cores') and max(loads) > m['cores']:
        busy = ['', f'The machine was not idle: its load average reached {max(loads):g} on '
                f'{m["cores"]} cores, so other work shared the cores with every benchmark '
                'here; timings are slower, and losses at high rates more frequent, than on '
                'an idle machine.']
    return '\n'.join([
        '# Performance',
        '',
        f'Produced by `{command}` on {m["date"]}, commit `{m["commit"]}`. '
        'Regenerate with `make bench` (it rewrites this file; figures vary '
        'from run to run on shared cores, so read them as magnitudes).',
        '',
        _table(['cores', 'CPU', 'Python', 'numpy', 'rclpy', 'RMW',
                'load average (start → end)'],
               [[m['cores'], m['cpu'], m['python'], m['numpy'], m['rclpy'],
                 f'{m["rmw"]} {m["rmw_fastrtps_cpp"]}',
                 f'{m.get("load_start")} → {m.get("load_end")}']]),
    ] + busy)


def batch_section(r):
    """Section 1: observer updates/s, the ceilings, reproduce."""
    rows = {}
    for row in r['observer_rates']:
        rows.setdefault(row['variant'], {})[row['batch']] = row
    batches = sorted({row['batch'] for row in r['observer_rates']})
    header = ['variant'] + [f'batch {b:,}' for b in batches] + [
        f'batch {batches[-1]:,}, E = exp(Ω/2) given', 'SingleObserver (floats)']
    body = []
    for variant, by_batch in rows.items():
        cells = [variant]
        for b in batches:
            x = by_batch[b]
            cells.append(f'{_si(x["updates_per_s"])}/s ({_us(x["us_per_step"])})')
        x = by_batch[batches[-1]]
        cells.append(f'{_si(x["updates_per_s_rotation_given"])}/s '
                     f'({_us(x["us_per_step_rotation_given"])})')
        cells.append(f'{_us(r["single"][variant])} per step')
        body.append(cells)
    p = r['products']
    n = p['batch']
    ceilings = [
        ['`quaternion.multiply` (our product)',
         _us(p['multiply_us']), f'{_si(n / p["multiply_us"] * 1e6)}/s'],
        ['numpy-quaternion product (external reference'
         + (f', {p["numpy_quaternion_version"]})'
            if p['numpy_quaternion_us']
            else ', not installed: `pip install numpy-quaternion`)'),
         _us(p['numpy_quaternion_us']),
         '—' if not p['numpy_quaternion_us']
         else f'{_si(n / p["numpy_quaternion_us"] * 1e6)}/s'],
        ['`quaternion_from_rotation_vector` (E = exp(Ω/2))',
         _us(p['exp_half_us']), f'{_si(n / p["exp_half_us"] * 1e6)}/s'],
        ['numpy `sin` + `cos` of the half angles alone (floor of exp)',
         _us(p['sincos_us']), f'{_si(n / p["sincos_us"] * 1e6)}/s'],
    ]
    lean = r.get('lean')
    if lean:
        ceilings.append(
            ['prototype extended step, E given (`bench/lean.py`: (4, N) '
             'layout, gain as a 4×4 matmul, `out=` buffers; equal to the core '
             f'to {lean["gap"]:.0e})',
             _us(lean['us_per_step']), f'{_si(lean["updates_per_s"])}/s'])
    lines = [
        '## 1. Batch core',
        '',
        'Observer updates per second (µs per step in brackets), '
        '`LuenbergerObserver.step` with increments and measurements of the '
        "paper's setup (increments uniform in [0, 10) rad per axis, σ = 0.1, "
        'paper gain); batch 1 is `batch_shape=()`. The last columns: the same '
        'step with `rotation=` precomputed (the experiments share it between '
        'observers), and `SingleObserver.step` on plain floats (the node\'s '
        'path).',
        '',
        _table(header, body),
        '',
        f'Ceilings, for {n:,} quaternions per call:',
        '',
        _table(['operation', 'per call', 'per second'], ceilings),
        '',
    ]
    for rep in r['reproduce']:
        if 'seconds' in rep:
            lines.append(f'- `{rep["command"]}`: {rep["seconds"]:.1f} s wall '
                         '(a fresh interpreter, imports included).')
        else:
            lines.append(f'- `{rep["command"]}`: {rep["note"]}.')
    return '\n'.join(lines)


def _cell(x):
    if 'error' in x:
        return 'error'
    if x['sustained']:
        return f'✓ {_ms(x["p50"])}'
    parts = []
    if x['lost']:
        share = 100 * x['lost'] / x['steps']
        parts.append(f'{share:.0f}% lost' if share >= 10 else f'{share:.2g}% lost')
    if x.get('propagated'):
        parts.append(f'{x["propagated"]} uncorrected')
    if x['p50'] is not None:
        parts.append(f'p50 {_ms(x["p50"])}')
    return '✗ ' + ', '.join(parts)


def _by_target(results):
    by_target = {}
    for x in results:
        by_target.setdefault(x['target'], []).append(x)
    return by_target


def nodes_section(results, rates, notes):
    """Section 2: throughput, each target against the rising rates."""
    by_target = _by_target(results)
    header = ['node/executor'] + [f'{r:g} Hz' for r in rates] + [
        'sustained', f'node CPU per step at {LATENCY_RATE} Hz']
    body = []
    for target, xs in by_target.items():
        by_rate = {x.get('rate'): x for x in xs}
        cells = [target]
        for rate in rates:
            cells.append(_cell(by_rate[rate]) if rate in by_rate else '·')
        best = sustained_rate(xs)
        cells.append('none' if best is None else f'{best:g} Hz')
        at = by_rate.get(LATENCY_RATE)
        cells.append(_us(at['cpu_us_per_step']) if at and 'error' not in at
                     else '—')
        body.append(cells)
    errors = [x for x in results if 'error' in x]
    detail = []
    for x in results:
        if 'error' in x:
            continue
        degraded = ('—' if x.get('propagated') is None
                    else f'{x["propagated"]} / {x["dropped"]}')
        detail.append([x['target'], f'{x["rate"]:g}', f'{x["achieved"]:.0f}',
                       x['steps'], x['lost'], degraded, _ms(x['p50']),
                       _ms(x['p99']), _ms(x['max']), _us(x['cpu_us_per_step']),
                       f'{_us(x.get("driver_cpu_us_per_step"))} / '
                       f'{_us(x.get("probe_cpu_us_per_step"))}'])
    lines = [
        '## 2. Node throughput',
        '',
        'Three processes on the same cores: a paced driver publishes paired '
        '`gyro/increment` and `attitude/measurement` (same stamp) at each rate, '
        'the node under test runs in its own process, and a probe process '
        'records every `attitude_estimate`. Cells: ✓ and the median latency '
        f'(ms) when the rate is *sustained* (zero lost steps and median latency '
        f'< {SUSTAINED_MEDIAN_MS:g} ms), else ✗ and why. A sweep stops after '
        'two unsustained rates (·). Node CPU per step: user + system time of '
        'the node process (all its threads) over the run, divided by the '
        'steps.',
        '',
        _table(header, body),
        '',
    ]
    lines += [f'- {note}' for note in notes]
    for x in errors:
        lines.append(f'- {x["target"]}: {x["error"].splitlines()[0]}')
    ratios = _ratios(by_target)
    if ratios:
        lines += ['', 'Sustained rate, observer / relay (the figure of merit):',
                  '']
        lines += [f'- {text}' for text in ratios]
    lines += [
        '',
        '<details><summary>Every run</summary>',
        '',
        _table(['node/executor', 'rate (Hz)', 'driver (Hz)', 'steps', 'lost',
                'uncorrected / dropped', 'p50 (ms)', 'p99 (ms)', 'max (ms)',
                'node CPU per step', 'driver / probe CPU per step'], detail),
        '',
        '"uncorrected / dropped": from the observer\'s own input counters '
        '(`/diagnostics`): steps propagated without their measurement and '
        'inputs it dropped; the relay has none.',
        '',
        '</details>',
    ]
    return '\n'.join(lines)


def _ratios(by_target):
    sustained = {t: sustained_rate(xs) for t, xs in by_target.items()}
    relay_single = sustained.get('relay/single')
    lines = []
    executors = [t.split('/', 1)[1] for t in sustained if t.startswith('observer/')]
    for ex in executors:
        obs, relay = sustained.get(f'observer/{ex}'), sustained.get(f'relay/{ex}')
        if f'observer/{ex}' not in sustained or f'relay/{ex}' not in sustained:
            continue
        if obs and relay:
            lines.append(f'{ex}: {obs:g} / {relay:g} Hz = {obs / relay:.2g}')
        else:
            lines.append(f'{ex}: {obs or "none"} / {relay or "none"}')
    for t, rate in sustained.items():
        if t.startswith('relay/') and t != 'relay/single' and rate and relay_single:
            lines.append(f'{t} against relay/single: {rate:g} / '
                         f'{relay_single:g} Hz = {rate / relay_single:.2g}× (what '
                         'the executor and subscription path alone give)')
    best = max(((sustained[t] or 0, t) for t in sustained
                if t.startswith('observer/')), default=None)
    cpu = {t: x['cpu_us_per_step'] for t, xs in by_target.items() for x in xs
           if 'error' not in x and x['rate'] == LATENCY_RATE
           and x['cpu_us_per_step']}
    for ex in ('single', 'events'):
        obs, relay = cpu.get(f'observer/{ex}'), cpu.get(f'relay/{ex}')
        if obs and relay:
            lines.append(f'{ex}, node CPU per step at {LATENCY_RATE} Hz (steadier '
                         f'than the sustained rate): observer {_us(obs)} / relay '
                         f'{_us(relay)} = {obs / relay:.2g}')
    if best and relay_single:
        lines.append(f'best observer ({best[1]}, {best[0]:g} Hz) against the '
                     f'naive relay (relay/single, {relay_single:g} Hz): '
                     f'{best[0] / relay_single:.2g}× (goal: 2×)')
    return lines


def latency_section(results):
    """Section 3: latency at the latency rate, observer beside relay."""
    rows = []
    at = {x['target']: x for x in results
          if 'error' not in x and x['rate'] == LATENCY_RATE}
    for target, x in at.items():
        rows.append([target, x['steps'], x['lost'], _ms(x['p50']),
                     _ms(x['p99']), _ms(x['max'])])
    lines = [
        f'## 3. Latency at {LATENCY_RATE} Hz',
        '',
        'From the driver\'s wall-clock time just before it publishes a '
        "step's measurement to the arrival of that step's estimate at the "
        'probe (another process; same clock), in ms.',
        '',
        _table(['node/executor', 'steps', 'lost', 'p50', 'p99', 'max'], rows),
        '',
    ]
    for ex in [t.split('/', 1)[1] for t in at if t.startswith('observer/')]:
        obs, relay = at.get(f'observer/{ex}'), at.get(f'relay/{ex}')
        if obs and relay and obs['p50'] is not None and relay['p50'] is not None:
            diff = obs['p50'] - relay['p50']
            lines.append(f'- {ex}: observer median − relay median = '
                         f'{diff:+.2f} ms (target: within '
                         f'{LATENCY_MARGIN_MS} ms).')
    return '\n'.join(lines)


def accuracy_section(a):
    """Section 4: final mean error beside the limit."""
    limit = a['limit']
    rows = [[name, f'{v["mean"]:.4f} ± {v["std"]:.4f}',
             f'{v["mean"] / limit:.2f}×']
            for name, v in sorted(a['rows'].items(),
                                  key=lambda item: item[1]['mean'])]
    return '\n'.join([
        '## 4. Accuracy beside the limit',
        '',
        f'Table 1 setup: {a["runs"]} runs × {a["epochs"]} epochs, '
        '`SimulatedGyro(increment_max=10, noise_std=0.1)`, observers started '
        'at 1 against a uniform true attitude '
        '(`experiments.observer_runs`). Final ‖q − q̂‖ (mean ± std over runs) '
        'of each variant and gain mode, next to the limit for exact '
        f'increments σ·E[χ₃]/√K = {limit:.4f} (σ = 0.1, K = {a["epochs"]}). '
        f'The {a["observers"]} observers together took {a["seconds"]:.2f} s.',
        '',
        _table(['observer', 'final ‖q − q̂‖', '/ limit'], rows),
        '',
        'Error against epoch for each gain mode, with the limit as a dashed '
        'line, exact increments and with gyro noise (0.01 rad per step): '
        '[figures/gain_modes.png](figures/gain_modes.png), made by '
        '`make reproduce`, whose [tables](reproduction.md) also give the '
        'gyro-noise rows (best mode 0.029 there, against 0.140 for the '
        "paper's constant gain). Why each mode converges and how κ and κ_min "
        'were chosen: [theory.md](theory.md).',
        '',
        '![Gain modes](figures/gain_modes.png)',
    ])


def profile_section(direct, loops):
    """Section 5: where the node's per-message time goes."""
    lines = ['## 5. Where the node\'s time goes', '']
    if loops:
        names = [f'{x["node"]}/{x["executor"]}' for x in loops]
        rate = loops[0]['rate']
        rows = [
            ['node process (all threads)'] + [_us(x['process_cpu']) for x in loops],
            ['main thread'] + [_us(x['main_thread_cpu']) for x in loops],
            ['… inside the two subscription callbacks']
            + [_us(x['callbacks_cpu']) for x in loops],
            ['… executor, take and deserialize (the rest of the main thread)']
            + [_us(x['main_thread_cpu'] - x['callbacks_cpu']) for x in loops],
            ['DDS threads (process − main thread)']
            + [_us(x['process_cpu'] - x['main_thread_cpu']) for x in loops],
        ]
        lines += [
            f'CPU time per step at {rate} Hz, the node fed by the driver '
            '(the same three processes as in section 2), no profiler: '
            'the subscription callbacks are wrapped in CPU timers '
            '(`time.thread_time`).',
            '',
            _table(['per step'] + names, rows),
            '',
        ]
    if direct:
        counts = direct.get('calls_per_step') or {
            'core_step': 1, 'numpy_normalize': 1, 'build_message': 2,
            'publish': 2, 'clock_now': 3}
        parts = [
            ('`SingleObserver.step` (the maths)', 'core_step'),
            ('`normalize(np.asarray(state))` (numpy)', 'numpy_normalize'),
            ('`quaternion_stamped(...)`: build a message', 'build_message'),
            ('`Publisher.publish` (no subscriber)', 'publish'),
            ('`get_clock().now()`', 'clock_now'),
        ]
        rows = [[name, _us(direct[key]), f'×{counts[key]:.3g}',
                 _us(direct[key] * counts[key])]
                for name, key in parts if counts.get(key)]
        accounted = sum(direct[key] * counts[key] for _, key in parts
                        if counts.get(key))
        rows.append(['rest (pairing, checks, dicts, stamps, counters)', '', '',
                     _us(direct['observer_callbacks'] - accounted)])
        lines += [
            'The same callbacks called directly in a tight loop with prepared '
            'messages (no executor, no DDS receive, warm caches): '
            f'**{_us(direct["observer_callbacks"])}** per step for the observer '
            f'node, {_us(direct["relay_callbacks"])} for the bare relay. In the '
            'real loop above they cost more (cold caches after every wake-up, '
            'other processes on the same cores). The parts, each timed alone, '
            'times how often a step calls them (counted by cProfile):',
            '',
            _table(['part', 'per call', 'calls per step', 'per step'], rows),
            '',
        ]
        if direct.get('top'):
            lines += [
                'The functions with the most own time in that loop, under '
                'cProfile (inflated by its per-call cost; read the order):',
                '',
                _table(['function', 'own time per step', 'calls per step'],
                       [[f'`{t["function"]}`', _us(t['own_us']),
                         f'{t["calls"]:.3g}'] for t in direct['top']]),
                '',
            ]
    profiled = [x for x in loops if x['node'] == 'observer' and x.get('cprofile')]
    if profiled:
        keys = [k for k in profiled[0]['cprofile']['callback_parts']
                if any(x['cprofile']['callback_parts'][k] for x in profiled)]
        rows = []
        for key in keys + ['rest']:
            cells = [key.replace('_', ' ')]
            for x in profiled:
                c = x['cprofile']
                parts = c['callback_parts']
                value = (c['callbacks'] - sum(parts.values()) if key == 'rest'
                         else parts[key])
                cells.append(f'{100 * value / c["callbacks"]:.0f}%'
                             if c['callbacks'] else '—')
            rows.append(cells)
        lines += [
            'Under cProfile in the same loop (its overhead inflates Python '
            'calls, so only shares): the observer\'s callback time by part.',
            '',
            _table(['part of the callbacks'] + [f'observer/{x["executor"]}'
                                                for x in profiled], rows),
            '',
        ]
    return '\n'.join(lines)


def targets_section(r):
    """The paper observer node's speed targets, met or not, from the measured figures."""
    rows = []
    batch = r.get('batch') or {'observer_rates': [], 'reproduce': []}
    largest = max((x['batch'] for x in batch['observer_rates']), default=None)
    if largest == 100_000:
        best = max((x for x in batch['observer_rates'] if x['batch'] == largest),
                   key=lambda x: x['updates_per_s'])
        value = best['updates_per_s']
        rows.append([f'≥ {_si(BATCH_TARGET)} observer updates/s at batch 100 000',
                     f'{_si(value)}/s ({best["variant"]}, best variant; '
                     f'{_si(best["updates_per_s_rotation_given"])}/s with E '
                     'given)',
                     _verdict(value >= BATCH_TARGET,
                              f'{BATCH_TARGET / value:.1f}× short')])
    for rep in batch['reproduce']:
        if rep['command'].endswith('reproduce --seeds 5'):
            if 'seconds' in rep:
                rows.append(['`reproduce --seeds 5` under 5 s',
                             f'{rep["seconds"]:.1f} s',
                             _verdict(rep['seconds'] < REPRODUCE_TARGET,
                                      f'{rep["seconds"] - REPRODUCE_TARGET:.1f} s over')])
            else:
                rows.append(['`reproduce --seeds 5` under 5 s', rep['note'],
                             'not measured'])
    nodes = r.get('nodes')
    if nodes:
        by_target = _by_target(nodes)
        at = {x['target']: x for x in nodes
              if 'error' not in x and x.get('rate') == LATENCY_RATE}
        obs = at.get(SHIPPED) or at.get('observer/single')
        if obs:
            rows.append([f'observer node (as shipped): zero loss at {LATENCY_RATE} Hz',
                         f'{obs["lost"]} lost, {obs.get("propagated") or 0} '
                         f'uncorrected of {obs["steps"]}',
                         _verdict(obs['lost'] == 0 and not obs.get('propagated'),
                                  'steps lost')])
            relay = at.get('relay/single')
            if relay and obs['p50'] is not None and relay['p50'] is not None:
                diff = obs['p50'] - relay['p50']
                rows.append(['median latency within 0.2 ms of the relay\'s '
                             f'({obs["target"]} against relay/single)', f'{diff:+.2f} ms',
                             _verdict(diff <= LATENCY_MARGIN_MS,
                                      f'{diff - LATENCY_MARGIN_MS:.2f} ms over')])
        sustained = {t: sustained_rate(xs) for t, xs in by_target.items()}
        relay = sustained.get('relay/single')
        shipped = SHIPPED if SHIPPED in sustained else 'observer/single'
        if shipped in sustained and relay:
            obs_rate = sustained[shipped] or 0
            rows.append(['sustained rate ≥ the relay\'s (observer as shipped, '
                         f'{shipped}, against relay/single)',
                         f'{obs_rate:g} vs {relay:g} Hz',
                         _verdict(obs_rate >= relay, f'{obs_rate / relay:.2g}×')])
            best = max((sustained[t] or 0, t) for t in sustained
                       if t.startswith('observer/'))
            rows.append(['goal: twice the relay\'s sustained rate',
                         f'{best[0]:g} Hz ({best[1]}) vs 2 × {relay:g} Hz',
                         _verdict(best[0] >= 2 * relay,
                                  f'{best[0] / relay:.2g}×')])
    direct = r.get('profile_direct')
    if direct:
        rows.append(numpy_use_row(direct))
        rows.append(['node hot path: profiled and reported',
                     f'callbacks {_us(direct["observer_callbacks"])} per step '
                     f'(maths {_us(direct["core_step"])})', 'yes (section 5)'])
    return '\n'.join(['## Targets: the paper observer node\'s speed', '',
                      _table(['target', 'measured', 'met'], rows)])


def numpy_use_row(direct):
    """The target row 'no per-message numpy allocation', from the profile's check."""
    target = 'node hot path: no per-message numpy allocation'
    uses = direct.get('numpy_use_per_step')
    if uses is None:
        return [target, 'not checked (results of an older `python -m bench`)', 'not measured']
    if not uses:
        return [target, 'no function on the callbacks\' path calls numpy or holds a numpy '
                f'object (`bench/numpy_use.py`, on {direct.get("numpy_use_steps")} steps)',
                'yes']
    listed = '; '.join(f'`{label}` ×{entry["per_step"]:.3g} ({", ".join(entry["numpy"])})'
                       for label, entry in sorted(uses.items()))
    return [target, f'per step: {listed}', 'no']


def analysis_section(r):
    """What limits each figure, in the measured numbers of this run."""
    lines = ['## What limits the figures', '']
    batch = r.get('batch')
    if batch and batch.get('products'):
        p = batch['products']
        n = p['batch']
        text = (f'- **Batch.** One `quaternion.multiply` of {n:,} quaternions '
                f'costs {_us(p["multiply_us"])} ({_si(n / p["multiply_us"] * 1e6)}'
                '/s): numpy works on the strided components of `(N, 4)` arrays '
                'and allocates a temporary per operation, and a constant-gain '
                'step does two general products, the exponential and the '
                'extension term.')
        if p.get('numpy_quaternion_us'):
            text += (f' numpy-quaternion\'s compiled product takes '
                     f'{_us(p["numpy_quaternion_us"])}.')
        text += (f' With increments, `exp(Ω/2)` alone costs '
                 f'{_us(p["exp_half_us"])}, {_us(p["sincos_us"])} of it in '
                 "numpy's float64 `sin` and `cos`, so that path stays under "
                 f'{_si(n / p["sincos_us"] * 1e6)} updates/s whatever the rest '
                 'costs.')
        lean = batch.get('lean')
        if lean:
            text += (f' The same extended step with E given, in a `(4, N)` '
                     'layout with the gain as a 4×4 matmul and `out=` buffers '
                     f'(`bench/lean.py`), runs at {_si(lean["updates_per_s"])}'
                     '/s in this run.')
        lines.append(text)
    loops = {f'{x["node"]}/{x["executor"]}': x
             for x in r.get('profile_loops') or []}
    direct = r.get('profile_direct')
    if loops.get('observer/single') and loops.get('observer/events'):
        single, events = loops['observer/single'], loops['observer/events']
        relay = loops.get('relay/events')
        text = ('- **Node.** On the SingleThreadedExecutor the observer\'s main '
                f'thread spends {_us(single["main_thread_cpu"])} per step at '
                f'{single["rate"]} Hz, '
                f'{_us(single["main_thread_cpu"] - single["callbacks_cpu"])} of '
                'it in rclpy\'s executor (wait-set rebuilding, take, '
                'deserialization) and '
                f'{_us(single["callbacks_cpu"])} in the node\'s callbacks. The '
                'EventsExecutor cuts the executor\'s part to '
                f'{_us(events["main_thread_cpu"] - events["callbacks_cpu"])}; '
                f'then the callbacks ({_us(events["callbacks_cpu"])}')
        if relay:
            text += f', against the relay\'s {_us(relay["callbacks_cpu"])}'
        text += ') are most of the per-step cost.'
        if direct:
            counts = direct.get('calls_per_step', {})
            named = [(n, counts.get(key, 0)) for n, key in (
                ('message builds', 'build_message'), ('publishes', 'publish'),
                ('numpy normalizations', 'numpy_normalize'),
                ('clock reads', 'clock_now'))]
            listed = ', '.join(f'{c:.2g} {n}' for n, c in named if c)
            text += (f' Of the callbacks, the maths is {_us(direct["core_step"])}; '
                     f'the rest is {listed} per step, and the pairing '
                     '(section 5).')
        lines.append(text)
    raw_line = raw_imu_page.analysis_line(r.get('raw_imu') or {})
    if raw_line:
        lines.append(raw_line)
    if r.get('nodes'):
        lines.append(
            '- **Cores.** Driver, node and probe share 2 cores (with whatever '
            'else runs: see the load average); a node process that is '
            'descheduled for a few ms overflows a queue of depth 10 at a few '
            'kHz, so losses at the top rates come and go from run to run.')
    return '\n'.join(lines)


def _verdict(ok, shortfall):
    return 'yes' if ok else f'no ({shortfall})'


def render(r):
    """The whole report."""
    sections = [machine_section(r['machine'], r['command'])]
    sections.append(targets_section(r))
    raw = r.get('raw_imu')
    if raw and raw_imu_page.targets_section(raw):
        sections.append(raw_imu_page.targets_section(raw))
    if raw_imu_page.compiled_targets_section(r.get('compiled'), raw):
        sections.append(raw_imu_page.compiled_targets_section(r.get('compiled'), raw))
    if r.get('batch'):
        sections.append(batch_section(r['batch']))
    if r.get('nodes') is not None:
        sections.append(nodes_section(r['nodes'], r['rates'],
                                      r.get('node_notes', [])))
        sections.append(latency_section(r['nodes']))
    if r.get('accuracy'):
        sections.append(accuracy_section(r['accuracy']))
    if r.get('profile_direct') or r.get('profile_loops'):
        sections.append(profile_section(r.get('profile_direct'),
                                        r.get('profile_loops', [])))
    if raw:
        sections.append(raw_imu_page.section(raw))
    if r.get('compiled'):
        sections.append(raw_imu_page.compiled_section(r['compiled']))
    sections.append(analysis_section(r))
    if r.get('notes'):
        sections.append('## Notes\n\n' + '\n'.join(f'- {n}' for n in r['notes']))
    return '\n\n'.join(sections) + '\n'
