"""
``python -m bench.load``: the node on a busy machine, with the samples it loses.

Through DDS (:mod:`bench.load_dds`): one BROAD trial replayed into
``imu_filter_node`` at several times real time, the field at the IMU's rate
and at 100 Hz (9D) or none (6D), on the machine as it is and with every
core busy; written to ``docs/load.md`` with ``--docs docs``. The estimate
with samples removed in batch was an experiment (``bench.load_batch``, in
bench/ up to commit 7319e4b); its figures are in docs/raw_imu.md.

``--trial 09 --seconds 60 --speeds 1 2 4`` is a short run; without options
the whole trial.
Progress goes to stderr, the page to stdout. Timings never fail the run.
"""

import argparse
import json
import math
import os
import signal
import sys
import time

from bench import load_dds, machine
from bench.procs import REPO
from ext_observer.broad.data import shown_command

DEFAULT_TRIAL = '09'
# What the node should do with every core busy (the done-criteria of the
# load benchmark): answered over the movement samples, at these speeds...
ANSWERED_LIMIT = 0.99
ANSWERED_SPEEDS = (1.0, 2.0)
# ... its error over them against the batch run's, and e²/σ²'s range.
ERROR_RATIO_LIMIT = 1.5
ERROR_RATIO_GOAL = 1.2
Z2_RANGE = (0.3, 3.0)
# Added to each case's replay time in the estimate printed first, s (the
# node's start, connection and drain).
CASE_OVERHEAD = 12.0
TITLE = '# Lost samples and a busy machine'


def _log(text):
    print(text, file=sys.stderr, flush=True)


# --- the DDS table -----------------------------------------------------------

def _pct(x):
    return '—' if x is None or not math.isfinite(x) else f'{100.0 * x:.1f} %'


def _num(x, spec='.2f', unit=''):
    return '—' if x is None or not math.isfinite(x) else f'{x:{spec}}{unit}'


def _field(row):
    if row['mode'] == '6D':
        return '6D'
    rate = row['rate'] if row['field_rate'] == 'imu' else row['field_rate']
    return f'9D, field {rate:.0f} Hz'


def _lost(lost):
    parts = [lost.get(key) for key in ('before_node', 'in_node', 'after_node')]
    return ' / '.join('?' if p is None else str(p) for p in parts)


def _diagnostics(d):
    if d['worst'] is None:
        return 'no status'
    said = {None: '', True: '; loss said: yes', False: '; loss said: **no**'}
    return d['worst'] + said[d['warned_of_loss']]


def dds_row_line(row):
    """One line of the DDS table."""
    head = (f'| {row["load"]} ({_num(row.get("load_average"), "g")}) | {row["speed"]:g}× | '
            f'{_field(row)} |')
    if 'error' in row:
        return head + f' failed: {row["error"]} |' + ' |' * 7
    key = row['error_key']
    z2 = row['z2']
    return (head + f' {_pct(row["share_movement"])} / {_pct(row["share"])} | '
            f'{_lost(row["lost"])} | {_num(row["dds"][key], ".2f", "°")} '
            f'({_num(row["batch"][key], ".2f", "°")}) | {_num(row["ratio"], ".2f", "×")} | '
            f'{_num(z2["inclination"])} / {_num(z2.get("heading", math.nan))} | '
            f'{_num(row["cpu_us_per_sample"], ".0f")} | '
            f'{_num(row["replay"]["late_max_ms"], ".1f")} | {_diagnostics(row["diagnostics"])} |')


def dds_table(rows):
    """The DDS table: one line per case."""
    lines = ['| machine (load average) | speed | mode, field | answered: movement / all | '
             'lost before the node / in it / after it | error over the answered (batch) | '
             'ratio | e²/σ² inclination / heading | node CPU µs per sample answered | '
             'replayer late, max ms | /diagnostics: worst; loss said (> 1 % lost) |',
             '|---|---|---|---|---|---|---|---|---|---|---|']
    return '\n'.join(lines + [dds_row_line(row) for row in rows])


def dds_notes(rows):
    """What the table cannot hold: drop reasons, the node's words and loss keys, failures."""
    notes = []
    messages = []
    for row in rows:
        if 'error' in row:
            continue
        label = f'{row["load"]}, {row["speed"]:g}×, {_field(row)}'
        h = row.get('holes')
        if h and h['count']:
            notes.append(f'{label}: {h["count"]} holes, the longest {h["longest_ms"]:.0f} ms, '
                         f'the first {h["first_s"]:.1f} s into the trial')
        drops = row['lost']['node_drops']
        if drops:
            notes.append(f'{label}: the node dropped '
                         + ', '.join(f'`{k}` {v}' for k, v in sorted(drops.items())))
        keys = row['diagnostics']['loss_keys']
        if keys:
            notes.append(f'{label}: the node\'s last status: '
                         + ', '.join(f'`{k}` {v:g}' for k, v in sorted(keys.items())))
        messages += [m for m in row['diagnostics']['warn_messages'] if m not in messages]
    if rows and not any(row['diagnostics']['loss_keys'] for row in rows if 'error' not in row):
        notes.append('The node\'s status has no key about lost samples (none with '
                     + ', '.join(f'`{w}`' for w in load_dds.LOSS_WORDS) + ' in its name).')
    if messages:
        notes.append('The node\'s WARN messages in these cases: '
                     + '; '.join(f'"{m}"' for m in messages) + '.')
    return notes


def verdicts(rows):
    """The criteria for every core busy, each with ``met``/``not met`` (or not measured)."""
    busy = [r for r in rows if r['load'] == 'busy' and 'error' not in r]
    if not busy:
        return ['Every core busy: not measured.']

    def word(ok):
        return 'met' if ok else '**not met**'

    out = []
    for speeds, what in ((ANSWERED_SPEEDS, 'limit'),
                         (tuple(sorted({r['speed'] for r in busy} - set(ANSWERED_SPEEDS))),
                          'goal')):
        chosen = [r for r in busy if r['speed'] in speeds]
        if chosen:
            low = min(r['share_movement'] for r in chosen)
            out.append(f'Answered ≥ {100 * ANSWERED_LIMIT:g} % of the movement samples at '
                       + ', '.join(f'{s:g}×' for s in speeds) + f' ({what}): lowest '
                       f'{_pct(low)}, {word(low >= ANSWERED_LIMIT)}.')
    worst = max(r['ratio'] for r in busy)
    out.append(f'Error over the answered samples ≤ {ERROR_RATIO_LIMIT:g}× the batch run\'s '
               f'(goal {ERROR_RATIO_GOAL:g}×): worst {_num(worst, ".2f", "×")}, '
               f'{word(worst <= ERROR_RATIO_LIMIT)}'
               + (' (goal met)' if worst <= ERROR_RATIO_GOAL else '') + '.')
    z2 = [v for r in busy for v in r['z2'].values() if math.isfinite(v)]
    if z2:
        inside = all(Z2_RANGE[0] <= v <= Z2_RANGE[1] for v in z2)
        out.append(f'e²/σ² within {Z2_RANGE[0]:g}–{Z2_RANGE[1]:g}: from {min(z2):.2f} to '
                   f'{max(z2):.2f}, {word(inside)}.')
    said = [r['diagnostics']['warned_of_loss'] for r in rows if 'error' not in r]
    said = [s for s in said if s is not None]
    out.append('/diagnostics at WARN whenever more than 1 % was lost: '
               + (f'{sum(said)} of {len(said)} such cases, {word(all(said))}.' if said
                  else 'no case lost more than 1 %.'))
    return out


def dds_section(dds):
    """The page's DDS section from :func:`run_dds`'s result."""
    lines = ['## Through DDS: a BROAD trial into imu_filter_node', '']
    if 'missing' in dds:
        return '\n'.join(lines + [dds['missing']])
    rows, t = dds['rows'], dds['trial']
    lines += [
        f'BROAD trial `{t["name"]}`, {t["seconds"]:.0f} s from {t.get("start", 0):g} s '
        f'into it ({t["samples"]} '
        f'IMU samples at {t["rate"]:.1f} Hz, {t["movement"]} of them scored movement '
        'samples), serialized before the replay and published as bytes with the trial\'s '
        'stamps at 1/rate, paced by the monotonic clock at each speed, into '
        '`imu_filter_node` (the installed executable, its defaults, `use_mag` by the mode) '
        'started afresh for each case in a ROS domain of its own; a recorder process keeps '
        '`imu/data` and `/diagnostics`. *busy*: one busy loop per core at normal priority '
        'meanwhile. The load average is the 1-minute one before the replay.', '',
        dds_table(rows), '',
        '*answered*: samples with an `imu/data` (by stamp), of the scored movement samples '
        'and of all. *lost*: sent but not counted by the node (`imu_samples` of its last '
        'status); counted but not stepped (`steps`; the first sample only starts the time '
        'line); stepped but not recorded. *error*: BROAD\'s RMSE over the answered movement '
        'samples (9D total, 6D inclination), in parentheses the batch run of the same '
        'samples and fields (`attitude_from_imu`) over all of them. *e²/σ²*: the mean over '
        'the answered movement samples of the error² over the variance that `imu/data` '
        'carried (inclination √(2 V_t), heading √V_h: [covariance.md](covariance.md)). '
        '*loss said*: a status at WARN that speaks of lost or dropped samples, where '
        'more than 1 % was lost. *CPU*: the node\'s utime + stime (`/proc`) from the first '
        'sample sent until its output stopped, over the samples answered.', '']
    lines += [f'- {v}' for v in verdicts(rows)]
    notes = dds_notes(rows)
    if notes:
        lines += [''] + [f'- {n}' for n in notes]
    # Every sample but the first (which only starts the time line) answered.
    whole = [r for r in rows if 'error' not in r and r['answered'] == r['sent'] - 1]
    if whole:
        lines += ['', f'In the {len(whole)} cases where every sample was answered, the '
                  'estimates were at most '
                  f'{max(r["apart_max_deg"] for r in whole):.2g}° from the batch run\'s.']
    return '\n'.join(lines)


def render(results):
    """The whole page from the results :func:`main` saves with ``--json``."""
    m = results['machine']
    sections = [
        TITLE, '',
        'How the estimate holds when IMU samples are lost, and how much of a stream '
        '`imu_filter_node` answers when the machine is busy ([diagnostics.md](diagnostics.md) '
        'for the status it publishes, [performance.md](performance.md) for its cost per '
        'message). Generated by `python -m bench.load --docs docs` (`make bench` runs it; '
        '[How it was made](#how-it-was-made) gives this run\'s command); do not edit by hand. '
        'Data: BROAD (Laidig et al. 2021, CC BY 4.0).', '',
        '## In batch: holes in the stream', '',
        'Measured with `python -m bench.load_batch`, an experiment that answered its '
        'question and left bench/ after commit 7319e4b: '
        '[raw_imu.md](raw_imu.md#holes-in-the-stream).', '',
        dds_section(results['dds']), '',
        '## How it was made', '',
        f'- Command: `{results["command"]}`, {results["seconds"]:.0f} s.',
        f'- Commit {m["commit"]}, {m["date"]}; {m["cores"]} cores ({m["cpu"]}), Python '
        f'{m["python"]}, numpy {m["numpy"]}, rclpy {m["rclpy"]}, {m["rmw"]}.',
        f'- 1-minute load average {m["load_start"]} at the start, {m.get("load_end")} at the end.']
    if results.get('note'):
        sections.append(f'- {results["note"]}')
    return '\n'.join(sections) + '\n'


# --- running -----------------------------------------------------------------

def cut(trial, start=0.0, seconds=None):
    """The part of ``trial`` from ``start`` s on, ``seconds`` long (None: to its end)."""
    from ext_observer.broad.data import Trial
    first = int(round(start * trial.rate))
    last = len(trial) if seconds is None else first + int(round(seconds * trial.rate))
    part = slice(first, last)
    return Trial(trial.name, trial.gyr[part], trial.acc[part], trial.mag[part],
                 trial.quat[part], trial.movement[part], trial.rate)


def run_dds(args):
    """The DDS run's result: the trial, its rows (or ``missing``)."""
    from ext_observer.broad.data import data_dir, find_trials, HOW_TO_GET, load_trial
    try:
        name, path = find_trials(data_dir(args.data), [args.trial])[0]
    except ValueError:
        return {'missing': f'No BROAD trial `{args.trial}` found ({HOW_TO_GET}).'}
    trial = cut(load_trial(path, name), args.start, args.seconds)
    case_list = load_dds.cases(args.speeds, args.fields, args.loads, args.modes)
    estimate = sum(len(trial) / trial.rate / c[1] + CASE_OVERHEAD for c in case_list)
    _log(f'DDS: {len(case_list)} cases on {name} ({len(trial) / trial.rate:.0f} s), about '
         f'{estimate / 60:.0f} min')
    rows = load_dds.dds_rows(trial, case_list, args.log_dir, progress=_log)
    return {'trial': {'name': name, 'samples': len(trial), 'rate': trial.rate,
                      'seconds': len(trial) / trial.rate, 'movement': int(trial.movement.sum()),
                      'start': args.start},
            'rows': rows}


def _field_rate(text):
    return 'imu' if text == 'imu' else float(text)


def build_parser():
    """The parser of ``python -m bench.load``."""
    parser = argparse.ArgumentParser(prog='python -m bench.load', description=__doc__.split(
        '\n\n')[0].strip())
    parser.add_argument('--data', help='folder of BROAD\'s HDF5 files (default: as make broad)')
    parser.add_argument('--trial', default=DEFAULT_TRIAL,
                        help=f'the trial (name or prefix; default {DEFAULT_TRIAL})')
    parser.add_argument('--start', type=float, default=0.0,
                        help='replay the trial from this second on (default 0)')
    parser.add_argument('--seconds', type=float,
                        help='replay only this many seconds of the trial (default: to its end)')
    parser.add_argument('--speeds', type=float, nargs='+', default=list(load_dds.SPEEDS),
                        help='times real time')
    parser.add_argument('--fields', type=_field_rate, nargs='+',
                        default=list(load_dds.FIELD_RATES),
                        help='9D field rates: imu (after every sample) or Hz')
    parser.add_argument('--loads', nargs='+', choices=load_dds.LOADS,
                        default=list(load_dds.LOADS))
    parser.add_argument('--modes', nargs='+', choices=load_dds.MODES,
                        default=list(load_dds.MODES))
    parser.add_argument('--docs', metavar='DIR', help='write DIR/load.md')
    parser.add_argument('--json', metavar='PATH', help='also write the results there')
    parser.add_argument('--render', metavar='JSON', help='only render results saved by --json')
    parser.add_argument('--note', help='a sentence for "How it was made" (the machine\'s state)')
    parser.add_argument('--log-dir', default=os.path.join(REPO, 'out', 'bench'),
                        help='the node\'s and the recorder\'s stderr')
    return parser


def main(argv=None):
    """Run the cases asked for; print the page, write it with ``--docs``; return 0."""
    argv = sys.argv[1:] if argv is None else list(argv)
    args = build_parser().parse_args(argv)
    if args.render:
        with open(args.render) as saved:
            return machine.write_page(render(json.load(saved)), _page(args))
    # SIGTERM ends the run through the finally blocks that stop the children.
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))
    start = time.monotonic()
    results = {'machine': machine.describe(),
               'command': shown_command(['python -m bench.load', *argv]),
               'note': args.note}
    results['dds'] = run_dds(args)
    results['seconds'] = time.monotonic() - start
    results['machine']['load_end'] = machine.load()
    if args.json:
        with open(args.json, 'w') as out:
            json.dump(results, out, indent=1)
    return machine.write_page(render(results), _page(args))


def _page(args):
    return os.path.join(args.docs, 'load.md') if args.docs else None


if __name__ == '__main__':
    sys.exit(main())
