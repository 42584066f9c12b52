"""
The page ``docs/load.md``, from the results of ``python -m bench.load``.

The DDS cases' table, the done-criteria for every core busy with their
verdicts, what the table cannot hold, and how the run was made.
"""

import math

from bench import load_dds
from bench.load_dds import (ANSWERED_LIMIT, ANSWERED_SPEEDS, ERROR_RATIO_GOAL, ERROR_RATIO_LIMIT,
                            Z2_RANGE)
from docgen.markdown import table

TITLE = '# Lost samples and a busy machine'


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


def dds_row(row):
    """The cells of one case in the DDS table."""
    head = [f'{row["load"]} ({_num(row.get("load_average"), "g")})', f'{row["speed"]:g}×',
            _field(row)]
    if 'error' in row:
        return head + [f'failed: {row["error"]}'] + [''] * 7
    key = row['error_key']
    z2 = row['z2']
    return head + [
        f'{_pct(row["share_movement"])} / {_pct(row["share"])}', _lost(row['lost']),
        f'{_num(row["dds"][key], ".2f", "°")} ({_num(row["batch"][key], ".2f", "°")})',
        _num(row['ratio'], '.2f', '×'),
        f'{_num(z2["inclination"])} / {_num(z2.get("heading", math.nan))}',
        _num(row['cpu_us_per_sample'], '.0f'), _num(row['replay']['late_max_ms'], '.1f'),
        _diagnostics(row['diagnostics'])]


def dds_table(rows):
    """The DDS table: one line per case."""
    return table(['machine (load average)', 'speed', 'mode, field', 'answered: movement / all',
                  'lost before the node / in it / after it', 'error over the answered (batch)',
                  'ratio', 'e²/σ² inclination / heading', 'node CPU µs per sample answered',
                  'replayer late, max ms', '/diagnostics: worst; loss said (> 1 % lost)'],
                 [dds_row(row) for row in rows])


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
        'more than 1 % was lost. *CPU*: the node\'s user + system time (psutil) from the first '
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
