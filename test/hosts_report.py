"""
The figures and tables of docs/across_machines.md, from out/hosts.json.

``make test-hosts`` measures (test/test_hosts.py writes out/hosts.json);
``make hosts-report`` (``python test/hosts_report.py``) draws
docs/figures/hosts_*.png and rewrites the generated blocks of
docs/across_machines.md, those between ``<!-- BEGIN hosts-report: NAME -->``
and ``<!-- END hosts-report: NAME -->``; the prose around them is kept.
"""

import argparse
import json
import os
import re
import sys

from ext_observer.source_tree import docgen

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
PAGE = os.path.join(REPO, 'docs', 'across_machines.md')
FIGURES = os.path.join(REPO, 'docs', 'figures')
LAYOUTS = {'gyro_monitor_on_a': 'gyro, monitor on A; observer on B',
           'gyro_monitor_on_b': 'observer on A; gyro, monitor on B'}
# The observer's increments (input_reliability, queue_depth); its
# measurements are best effort in every case (the sensor-data QoS).
INPUTS = {'qos_best_effort_inputs': 'increments best effort, depth 100',
          'gyro_monitor_on_a': 'increments reliable, depth 100 (default)',
          'qos_reliable_inputs_depth_1000': 'increments reliable, depth 1000'}


def fmt(value, digits=2, unit=''):
    if value is None:
        return '–'
    if isinstance(value, float):
        return f'{value:.{digits}f}{unit}'
    return f'{value}{unit}'


def percent(value):
    return '–' if value is None else f'{100 * value:.1f} %'


# The docs' one table writer (docgen/, beside the package in a clone).
table = docgen('markdown').table


# Blocks ----------------------------------------------------------------------------

def runs_of(results, labels):
    """``(key, label, run)`` of each run of ``labels`` (key: label) that ``results`` holds."""
    for key, label in labels.items():
        run = results['runs'].get(key)
        if run is not None:
            yield key, label, run


def sweep(results, key):
    """The phases of run ``key`` that measured both subscriptions (a loss sweep's)."""
    run = results['runs'].get(key)
    if run is None:
        return []
    return [p for p in run['phases'] if 'reliable' in p]


def block_run(results):
    setup = results['setup']
    return (f'Measured on {setup.get("date", "?")} at commit `{setup.get("commit", "?")}` '
            f'({setup["cpus"]} cores, shared with other work), {setup["rate_hz"]:g} Hz, '
            f'link {setup["subnet"]}. No-fault band: {setup["band_factor"]} × the largest '
            f'{setup["smoothing_s"]} s mean attitude error of a {setup["baseline_s"]:g} s '
            'baseline before the first fault.')


def steps_cells(phase):
    steps = phase.get('steps_during') or {}
    delay = steps.get('delay_ms') or {}
    return [percent(steps.get('estimated_fraction')),
            f'{fmt(delay.get("p50"), 0)} / {fmt(delay.get("p99"), 0)}'
            if delay.get('p50') is not None else '–',
            fmt(steps.get('error_mean'), 2)]


def block_faults(results):
    setup = results['setup']
    bounds = setup['recovery_bound_s']
    rows = []
    for _, label, run in runs_of(results, LAYOUTS):
        for phase in run['phases']:
            if phase['kind'] == 'none':
                rows.append([label, f'none (band {run["band_rad"]:.2f} rad)', '–',
                             fmt(phase['estimates_per_s_during'], 0)] + steps_cells(phase)
                            + ['–', 'OK', '–', '–'])
                continue
            monitor = ('STALE after {} s, OK {} s after'.format(
                fmt(phase['monitor_stale_after_s']), fmt(phase['monitor_ok_after_s']))
                if phase['monitor_stale'] else
                'never STALE' + (f', OK {fmt(phase["monitor_ok_after_s"])} s after'
                                 if phase['monitor_ok_after_s'] is not None else ''))
            if phase['kind'] == 'restart':
                observer = 'started again'
            elif phase.get('observer_silent'):
                observer = 'silent (WARN) after {} s, cleared {} s after'.format(
                    fmt(phase['observer_silent_after_s']), fmt(phase['observer_back_after_s']))
            else:
                observer = 'never silent' if 'observer_silent' in phase else '–'
            rows.append([
                label, phase['name'], percent(phase.get('packet_loss_measured')),
                fmt(phase['estimates_per_s_during'], 0)] + (
                    steps_cells(phase) if phase['kind'] != 'restart' else ['–', '–', '–']) + [
                observer, monitor, fmt(phase['peak_error_rolling'], 2),
                f'**{fmt(phase["recovery_s"], 2)} s** (≤ {bounds[phase["kind"]]:g})'])
    return table(['hosts', 'fault', 'packets lost', 'estimates/s during',
                  'its steps with an estimate', 'their delay p50 / p99 (ms)',
                  'their error (rad)', 'observer (own host)', 'monitor (other host)',
                  'peak 0.25 s error (rad)', 'back in band after'], rows)


def block_accounting(results):
    rows = []
    for _, label, run in runs_of(results, LAYOUTS):
        final = run['observer_final']
        drops = ', '.join(f'{k[len("dropped_"):]} {v}' for k, v in final.items()
                          if k.startswith('dropped_')) or 'none'
        rows.append([label, run['observer_statuses_checked'], run['monitor_statuses_checked'],
                     final.get('inputs_received', '0'), final.get('inputs_processed', '0'),
                     final.get('inputs_dropped', '0'), drops, run['escaped_packets']])
    return table(['hosts', 'observer statuses checked', 'monitor statuses checked',
                  'last observer: received', 'processed', 'dropped', 'by reason',
                  'packets that tried to leave the /24'], rows)


def qos_row(results, key, loss):
    return next((phase for phase in sweep(results, key) if phase.get('loss_percent') == loss),
                None)


def block_qos(results):
    rows = []
    for key, inputs in INPUTS.items():
        phase = qos_row(results, key, 20)
        if phase is None:
            continue
        for subscription in ('reliable', 'best_effort'):
            found = phase[subscription]
            latency, reception = found['latency_ms'], found['reception_latency_ms']
            rows.append([inputs, subscription.replace('_', ' '),
                         percent(phase.get('packet_loss_measured')),
                         percent(found['delivered_fraction']),
                         f'{fmt(latency["p50"], 1)} / {fmt(latency["p99"], 1)}',
                         f'{fmt(reception["p50"], 1)} / {fmt(reception["p99"], 1)}'])
    return table(['observer inputs', 'attitude_estimate subscription', 'packets lost',
                  'estimates delivered', 'latency p50 / p99 (ms)',
                  'in the middleware p50 / p99 (ms)'], rows)


def block_inputs(results):
    rows = []
    for key, inputs, _ in runs_of(results, INPUTS):
        for phase in sweep(results, key):
            loss = phase.get('loss_percent')
            propagated = phase.get('propagated_fraction')
            if propagated is None and phase.get('observer_steps'):
                propagated = phase['observer_steps_propagated'] / phase['observer_steps']
            gap = phase.get('longest_gap_s', phase.get('longest_gap_during_s'))
            rows.append([inputs, f'{loss or 0} %', percent(phase.get('packet_loss_measured'))]
                        + steps_cells(phase) + [percent(propagated), fmt(gap, 2)])
    return table(['observer inputs', 'loss set', 'packets lost', 'steps with an estimate',
                  'estimate delay p50 / p99 (ms)', 'attitude error (rad)',
                  'steps without a measurement', 'longest pause in publishing (s)'], rows)


# Figures ---------------------------------------------------------------------------

def figures(results, folder):
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    os.makedirs(folder, exist_ok=True)
    written = []

    def save(fig, name):
        fig.tight_layout()
        path = os.path.join(folder, name)
        fig.savefig(path, dpi=110)
        plt.close(fig)
        written.append(path)

    styles = {'qos_best_effort_inputs': ('tab:red', 'o'),
              'gyro_monitor_on_a': ('tab:blue', 's'),
              'qos_reliable_inputs_depth_1000': ('tab:green', '^')}

    def loss_of(phase):
        return 100 * (phase.get('packet_loss_measured') or 0)

    # 1. Loss rate -> delivered fraction; the observer's steps, their delay, error.
    fig, axes = plt.subplots(2, 2, figsize=(11, 7.5))
    axes = axes.ravel()
    phases = sweep(results, 'qos_best_effort_inputs')
    for subscription, color in (('reliable', 'tab:blue'), ('best_effort', 'tab:red')):
        axes[0].plot([loss_of(p) for p in phases],
                     [100 * p[subscription]['delivered_fraction'] for p in phases],
                     marker='o', color=color, label=subscription.replace('_', ' '))
    axes[0].plot([0, 50], [100, 50], color='grey', lw=0.8, ls=':', label='1 − loss')
    axes[0].set(title='attitude_estimate across the link', xlabel='packets lost (%)',
                ylabel='estimates delivered (%)', ylim=(40, 102))
    axes[0].legend(title='subscription', fontsize=8)
    for key, label in INPUTS.items():
        phases = sweep(results, key)
        color, marker = styles[key]
        steps = [p.get('steps_during') or {} for p in phases]
        losses = [loss_of(p) for p in phases]
        axes[1].plot(losses, [100 * (s.get('estimated_fraction') or 0) for s in steps],
                     marker=marker, color=color, label=label)
        axes[2].plot(losses, [max((s.get('delay_ms') or {}).get('p99') or 0, 0.1)
                              for s in steps], marker=marker, color=color, label=label)
        axes[3].plot(losses, [s.get('error_mean') for s in steps], marker=marker,
                     color=color, label=label)
    axes[1].set(title="the observer's increments across the link", xlabel='packets lost (%)',
                ylabel='gyro steps with an estimate (%)', ylim=(40, 102))
    axes[2].set(title='delay of the estimate after the step (p99)', xlabel='packets lost (%)',
                ylabel='ms', yscale='log')
    axes[3].set(title="the estimates' attitude error", xlabel='packets lost (%)',
                ylabel='mean attitude error (rad)', ylim=(0, None))
    for axis in axes[1:]:
        axis.legend(fontsize=7)
    for axis in axes:
        axis.grid(alpha=0.3, which='both')
    save(fig, 'hosts_delivery.png')

    # 2. Latency p50 / p99 by loss, reliable vs best effort.
    fig, axis = plt.subplots(figsize=(6.5, 4))
    phases = sweep(results, 'qos_best_effort_inputs')
    for subscription, color in (('reliable', 'tab:blue'), ('best_effort', 'tab:red')):
        for quantile, style in (('p50', '-'), ('p99', '--')):
            axis.plot([loss_of(p) for p in phases],
                      [max(p[subscription]['latency_ms'][quantile] or 0, 0.01)
                       for p in phases], marker='o', color=color, ls=style,
                      label=f'{subscription.replace("_", " ")} {quantile}')
    axis.set(yscale='log', xlabel='packets lost (%)', ylabel='latency (ms)',
             title='attitude_estimate latency across the link\n(the sweep with best-effort increments)')
    axis.grid(alpha=0.3, which='both')
    axis.legend(fontsize=8)
    save(fig, 'hosts_latency.png')

    # 3. The error through the faults, with the band and the recovery times.
    runs = [(layout, run) for layout, _, run in runs_of(results, LAYOUTS)]
    fig, axes = plt.subplots(len(runs), 1, figsize=(12, 3.2 * len(runs)), squeeze=False)
    for axis, (layout, run) in zip(axes[:, 0], runs):
        # No line across a time without estimates (a partition, a restart).
        t, error = [], []
        for time_s, value in zip(run['series']['t'], run['series']['rolling_error']):
            if t and time_s - t[-1] > 0.25:
                t.append(time_s)
                error.append(float('nan'))
            t.append(time_s)
            error.append(value)
        axis.plot(t, error, lw=0.8, color='tab:blue', label='attitude error, 0.25 s mean')
        axis.axhline(run['band_rad'], color='tab:green', ls='--', lw=1,
                     label=f'no-fault band {run["band_rad"]:.2f} rad')
        for span, phase in zip(run['timeline_s'][1:], run['phases'][1:]):
            axis.axvspan(span['start'], max(span['end'], span['start'] + 0.15),
                         color='tab:red', alpha=0.15)
            axis.text(span['start'], 3.25, f'{phase["name"]}\nback in {phase["recovery_s"]:.2f} s',
                      fontsize=7, va='top')
        axis.set(ylim=(0, 3.3), xlabel='time since the baseline started (s)',
                 ylabel='rad', title=LAYOUTS[layout])
        axis.legend(loc='center right', fontsize=7)
        axis.grid(alpha=0.3)
    save(fig, 'hosts_recovery.png')
    return written


BLOCKS = {'run': block_run, 'faults': block_faults, 'accounting': block_accounting,
          'qos': block_qos, 'inputs': block_inputs}


def rewrite(text, results):
    """Return ``text`` with every generated block filled from ``results``."""
    def fill(match):
        name = match.group(1)
        return (f'<!-- BEGIN hosts-report: {name} -->\n{BLOCKS[name](results)}\n'
                f'<!-- END hosts-report: {name} -->')
    pattern = re.compile(r'<!-- BEGIN hosts-report: (\w+) -->.*?<!-- END hosts-report: \1 -->',
                         re.DOTALL)
    found = set(pattern.findall(text))
    missing = set(BLOCKS) - found
    if missing:
        raise SystemExit(f'{PAGE} lacks the blocks {sorted(missing)}')
    return pattern.sub(fill, text)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--json', default=os.path.join(REPO, 'out', 'hosts.json'))
    parser.add_argument('--page', default=PAGE)
    parser.add_argument('--figures', default=FIGURES)
    args = parser.parse_args(argv)
    try:
        with open(args.json) as file:
            results = json.load(file)
    except FileNotFoundError:
        print(f'no {args.json}: run make test-hosts first', file=sys.stderr)
        return 1
    with open(args.page, encoding='utf-8') as file:
        text = file.read()
    text = rewrite(text, results)
    with open(args.page, 'w', encoding='utf-8') as file:
        file.write(text)
    for path in figures(results, args.figures):
        print(f'wrote {os.path.relpath(path, REPO)}')
    print(f'rewrote {os.path.relpath(args.page, REPO)}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
