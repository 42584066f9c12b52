"""
Holes in the stream, in batch: the BROAD trials with samples lost, ours against the anchors.

``python -m bench.load_batch [--data DIR] [--trials 02 09 ...] [--jobs 2]
[--cases none random10 ...] [--json PATH]`` removes IMU samples from each
trial (at random, or in bursts every :data:`BURST_PERIOD` s, with fixed
seeds), and runs what is left:

- ours through :func:`~ext_observer.attitude_from_imu` with the true times of
  the kept samples (``times=``), 9D and 6D, as the node would see them;
- VQF and BasicVQF (``vqf``), which take one sample time at construction:
  each kept sample's rate is given scaled by its interval over the nominal
  one, ``ω Δt / T``, so that each step integrates the rotation over the
  real interval (their rest and bias detection see that scaled rate);
- Madgwick (``ahrs``), whose update takes each kept sample's own ``dt``.

A BROAD sample carries the IMU and the field at one stamp; a lost sample
loses both (a driver that publishes them as one message, or drops both
topics at once when it falls behind). Every estimate is scored over the kept
``movement`` samples (BROAD's RMSE, :mod:`ext_observer.broad.scoring`); for
ours the published covariance's mean ``e²/σ²`` over the same samples too
(inclination in both modes, heading in 9D; pooled over the trials).

:func:`batch_rows` gives a row per trial, mode, case and algorithm;
:func:`batch_markdown` the section of docs/load.md.
"""

import argparse
import concurrent.futures
import json
import math
import sys

import numpy as np

# The cases: (name, kind, amount): the share lost at random, or the length
# (s) of a burst lost every BURST_PERIOD s.
CASES = (
    ('none', 'none', 0.0),
    ('random10', 'random', 0.10),
    ('random40', 'random', 0.40),
    ('burst50ms', 'burst', 0.050),
    ('burst200ms', 'burst', 0.200),
)
CASE_TITLES = {'none': 'none', 'random10': '10 % at random', 'random40': '40 % at random',
               'burst50ms': '50 ms every 2 s', 'burst200ms': '200 ms every 2 s'}
BURST_PERIOD = 2.0  # s
ALGORITHMS = ('ours', 'VQF', 'BasicVQF', 'Madgwick')
MODES = ('9D', '6D')
# The error each mode is judged on (BROAD's 9D total, 6D inclination).
MODE_KEY = {'9D': 'total_rmse_deg', '6D': 'inclination_rmse_deg'}
# The done-when bounds of the ratio to the full-data figure (and the goals),
# and of the covariance's mean e²/σ².
RATIO_BOUND = {'random40': 1.3, 'burst50ms': 1.3, 'burst200ms': 2.0}
RATIO_GOAL = {'random40': 1.1, 'burst50ms': 1.1, 'burst200ms': 1.5}
Z2_RANGE = (0.3, 3.0)
TESLA_PER_MICROTESLA = 1e-6
_SEED = 36


def kept_samples(count, rate, case, seed):
    """
    Return which of ``count`` samples at ``rate`` (Hz) are kept in ``case``.

    Random: each sample lost with the case's probability (the first two
    always kept: a time line needs them). Bursts: every
    :data:`BURST_PERIOD` s, from a phase drawn from ``seed``, the case's
    length of samples lost.
    """
    _, kind, amount = _case(case)
    rng = np.random.default_rng(seed)
    keep = np.ones(count, dtype=bool)
    if kind == 'random':
        keep = rng.random(count) >= amount
    elif kind == 'burst':
        t = np.arange(count) / rate
        phase = rng.uniform(0.0, BURST_PERIOD)
        keep = np.mod(t - phase, BURST_PERIOD) >= amount
    keep[:2] = True
    return keep


def trial_kept(trial, case):
    """Which of ``trial``'s samples are kept in ``case``, with the trial's and case's fixed seed."""
    return kept_samples(len(trial), trial.rate, case, _seed(trial.name, case))


def _case(name):
    for case in CASES:
        if case[0] == name:
            return case
    raise ValueError(f'unknown case {name!r}: one of {[c[0] for c in CASES]}')


def _seed(trial_name, case):
    digits = ''.join(c for c in trial_name.split('_')[0] if c.isdigit()) or '0'
    return _SEED * 1000 + int(digits) * 10 + [c[0] for c in CASES].index(case)


def run_ours(trial, mode, keep, parameters=None):
    """Our estimate of the kept samples (their times), and its inclination and heading σ."""
    from ext_observer.recordings.recording import attitude_from_imu
    times = np.flatnonzero(keep) / trial.rate
    params = dict(parameters or {})
    params['use_mag'] = mode == '9D'
    rec = attitude_from_imu(trial.gyr[keep], trial.acc[keep],
                            trial.mag[keep] * TESLA_PER_MICROTESLA, times=times,
                            parameters=params)
    q = np.where(rec.estimated[:, None], rec.quaternions, np.nan)
    return q, rec.inclination_std, rec.heading_std


def run_anchor(anchor, trial, mode, keep):
    """An anchor's estimate of the kept samples, sensor → ENU (see the module docstring)."""
    from ext_observer.broad import anchors
    index = np.flatnonzero(keep)
    period = 1.0 / trial.rate
    dt = np.diff(index, prepend=index[0] - 1) * period
    gyr, acc, mag = trial.gyr[keep], trial.acc[keep], trial.mag[keep]
    use_mag = mode == '9D'
    if anchor in ('VQF', 'BasicVQF'):
        import vqf
        cls = vqf.BasicVQF if anchor == 'BasicVQF' else vqf.VQF
        scaled = np.ascontiguousarray(gyr * (dt / period)[:, None])
        out = cls(period).updateBatch(scaled, np.ascontiguousarray(acc),
                                      np.ascontiguousarray(mag) if use_mag else None)
        return out['quat9D' if use_mag else 'quat6D']
    if anchor == 'Madgwick':
        from ahrs.filters import Madgwick
        from ext_observer.core.quaternion import conjugate, multiply
        f = Madgwick(frequency=trial.rate, gain=anchors.MADGWICK_BETA)
        q = np.empty((len(gyr), 4))
        q[0] = multiply(conjugate(np.asarray(anchors.NWU_TO_ENU)),
                        anchors.attitude_from_acc_mag(acc[0], mag[0] if use_mag else None))
        for k in range(1, len(gyr)):
            q[k] = (f.updateMARG(q[k - 1], gyr[k], acc[k], mag[k], dt=dt[k]) if use_mag
                    else f.updateIMU(q[k - 1], gyr[k], acc[k], dt=dt[k]))
        return multiply(np.asarray(anchors.NWU_TO_ENU), q)
    raise ValueError(f'unknown algorithm {anchor!r}')


_TRIALS = {}


def _trial(path, name):
    from ext_observer.broad import load_trial
    if path not in _TRIALS:
        _TRIALS.clear()  # one trial in memory per worker
        _TRIALS[path] = load_trial(path, name)
    return _TRIALS[path]


def _task(task):
    """One row: ``(path, name, mode, case, algorithm, parameters)``."""
    from ext_observer.broad.covariance import split_of
    from ext_observer.broad.scoring import error_angles, score
    path, name, mode, case, algorithm, parameters = task
    trial = _trial(path, name)
    keep = trial_kept(trial, case)
    movement, ref = trial.movement[keep], trial.quat[keep]
    row = {'trial': name, 'split': 'dev' if split_of(name) == 'dev' else 'held-out',
           'mode': mode, 'case': case, 'algorithm': algorithm,
           'kept': float(keep.mean()), 'samples': int(keep.sum())}
    if algorithm == 'ours':
        q, inc_std, head_std = run_ours(trial, mode, keep, parameters)
    else:
        q = run_anchor(algorithm, trial, mode, keep)
    row.update(score(q, ref, movement))
    if algorithm == 'ours':
        _, heading, inclination = error_angles(q, ref)
        scored = movement & np.isfinite(inclination) & np.isfinite(inc_std)
        row['n_scored'] = int(scored.sum())
        row['z2_inclination'] = float(np.mean((inclination[scored] / inc_std[scored]) ** 2))
        row['z2_heading'] = (float(np.mean((heading[scored] / head_std[scored]) ** 2))
                             if mode == '9D' else math.nan)
    return row


def batch_rows(data_dir=None, trials=None, jobs=2, cases=None, algorithms=ALGORITHMS,
               modes=MODES, parameters=None, progress=None):
    """
    Run every trial, mode, case and algorithm; return one row each.

    Parameters
    ----------
    data_dir : str, optional
        BROAD's files (default: as ``python -m ext_observer broad`` finds them).
    trials : list of str, optional
        Trial name patterns (a number prefix, ``'02'``); default all.
    jobs : int
        Processes.
    cases : sequence of str, optional
        Names of :data:`CASES` (default all).
    algorithms, modes : sequence of str
    parameters : dict, optional
        Ours: ``imu_filter_node`` parameter values.
    progress : callable, optional

    Returns
    -------
    list of dict
        ``trial``, ``split`` (``dev`` even-numbered, ``held-out``), ``mode``,
        ``case``, ``algorithm``, ``kept`` (share), ``samples``, BROAD's
        ``total_rmse_deg``, ``heading_rmse_deg``, ``inclination_rmse_deg``;
        ours also ``n_scored``, ``z2_inclination``, ``z2_heading`` (NaN in 6D).

    """
    from ext_observer.broad import data_dir as find_data, find_trials
    cases = [c[0] for c in CASES] if cases is None else [_case(c)[0] for c in cases]
    found = find_trials(find_data(data_dir), trials)
    tasks = [(path, name, mode, case, algorithm, parameters) for name, path in found
             for algorithm in algorithms for mode in modes for case in cases]
    rows = []
    if jobs > 1:
        with concurrent.futures.ProcessPoolExecutor(jobs) as pool:
            for row in pool.map(_task, tasks, chunksize=1):
                rows.append(row)
                _progress(progress, row, len(rows), len(tasks))
    else:
        for task in tasks:
            rows.append(_task(task))
            _progress(progress, rows[-1], len(rows), len(tasks))
    return rows


def _progress(progress, row, done, total):
    if progress:
        progress(f'[{done}/{total}] {row["trial"]} {row["mode"]} {row["case"]} '
                 f'{row["algorithm"]}: {row[MODE_KEY[row["mode"]]]:.2f}°')


def summary(rows, split='all'):
    """
    Mean over the trials per (algorithm, mode, case); ours' pooled e²/σ².

    Returns
    -------
    dict
        ``{(algorithm, mode, case): {'error': mean of the mode's error (°),
        'trials': count, 'z2_inclination', 'z2_heading'}}``.

    """
    out = {}
    groups = {}
    for row in rows:
        if split != 'all' and row['split'] != split:
            continue
        groups.setdefault((row['algorithm'], row['mode'], row['case']), []).append(row)
    for key, members in groups.items():
        figure = {'error': float(np.mean([r[MODE_KEY[key[1]]] for r in members])),
                  'trials': len(members)}
        if key[0] == 'ours':
            n = np.array([r['n_scored'] for r in members], dtype=float)
            for name in ('z2_inclination', 'z2_heading'):
                z2 = np.array([r[name] for r in members])
                figure[name] = (float(np.sum(z2 * n) / np.sum(n))
                                if np.isfinite(z2).all() else math.nan)
        out[key] = figure
    return out


def verdicts(rows):
    """The done-when per mode and case, all trials: ``{(mode, case): (ratio, z2s, met)}``."""
    summ = summary(rows)
    out = {}
    for (algorithm, mode, case), figure in summ.items():
        full = summ.get((algorithm, mode, 'none'))
        if algorithm != 'ours' or case not in RATIO_BOUND or full is None:
            continue
        ratio = figure['error'] / full['error']
        z2s = [z for z in (figure['z2_inclination'], figure['z2_heading']) if z == z]
        met = ratio <= RATIO_BOUND[case] and all(Z2_RANGE[0] <= z <= Z2_RANGE[1] for z in z2s)
        out[(mode, case)] = (ratio, z2s, met)
    return out


def _split_text(rows):
    splits = {r['split'] for r in rows}
    return [s for s in ('all', 'dev', 'held-out') if s == 'all' or s in splits]


def batch_markdown(rows):
    """The section of docs/load.md: the tables of :func:`summary`, per split, and the verdicts."""
    cases = [c[0] for c in CASES if any(r['case'] == c[0] for r in rows)]
    algorithms = [a for a in ALGORITHMS if any(r['algorithm'] == a for r in rows)]
    modes = [m for m in MODES if any(r['mode'] == m for r in rows)]
    trials = sorted({r['trial'] for r in rows})
    lines = ['## In batch: samples lost', '',
             f'{len(trials)} BROAD trials; a lost sample loses its IMU reading and its field '
             'together (BROAD has one of each per stamp). Ours runs through '
             '`attitude_from_imu(..., times=...)` with the true times of the kept samples; '
             'VQF and BasicVQF take one sample time, so each kept rate is given scaled by its '
             'interval over the nominal one (`ω Δt / T`); Madgwick takes each sample\'s `dt`. '
             'Error in degrees over the kept `movement` samples, mean over the trials '
             '(9D total, 6D inclination, as BROAD scores them); × the same algorithm\'s '
             'figure on the full data; e²/σ² the mean over those samples of ours\' '
             'published covariance (inclination; heading in 9D). '
             'Command: `python -m bench.load_batch`.', '']
    for split in _split_text(rows):
        summ = summary(rows, split)
        count = len({r['trial'] for r in rows if split == 'all' or r['split'] == split})
        title = {'all': 'all trials', 'dev': 'even-numbered (tuned on)',
                 'held-out': 'odd-numbered (held out)'}[split]
        lines += [f'### {title} ({count})', '',
                  '| lost | mode | ' + ' | '.join(algorithms) + ' | e²/σ² incl. | e²/σ² head. |',
                  '|---|---|' + '---|' * (len(algorithms) + 2)]
        for case in cases:
            for mode in modes:
                cells = []
                for a in algorithms:
                    f, full = summ.get((a, mode, case)), summ.get((a, mode, 'none'))
                    if f is None:
                        cells.append('')
                    elif case == 'none' or full is None:
                        cells.append(f'{f["error"]:.2f}')
                    else:
                        cells.append(f'{f["error"]:.2f} ({f["error"] / full["error"]:.2f}×)')
                ours = summ.get(('ours', mode, case), {})
                z = [ours.get(k, math.nan) for k in ('z2_inclination', 'z2_heading')]
                lines.append(f'| {CASE_TITLES[case]} | {mode} | ' + ' | '.join(cells) + ' | '
                             + ' | '.join('' if v != v else f'{v:.2f}' for v in z) + ' |')
        lines.append('')
    found = verdicts(rows)
    if found:
        lines += ['Done-when (all trials, ours): error ≤ 1.3× the full-data figure with 40 % '
                  'lost at random and with 50 ms bursts, ≤ 2× with 200 ms bursts; '
                  f'e²/σ² within {Z2_RANGE[0]:g}–{Z2_RANGE[1]:g}.', '']
        for (mode, case), (ratio, z2s, met) in sorted(found.items()):
            z = ', '.join(f'{v:.2f}' for v in z2s)
            lines.append(f'- {mode}, {CASE_TITLES[case]}: {ratio:.2f}× '
                         f'(bound {RATIO_BOUND[case]:g}×, goal {RATIO_GOAL[case]:g}×), '
                         f'e²/σ² {z}: {"met" if met else "not met"}')
        lines.append('')
    return '\n'.join(lines)


def main(argv=None):
    """Run the batch; print the Markdown; return 0 (2 without data)."""
    parser = argparse.ArgumentParser(prog='python -m bench.load_batch')
    parser.add_argument('--data', metavar='DIR')
    parser.add_argument('--trials', nargs='*', help='name patterns (default: all)')
    parser.add_argument('--jobs', type=int, default=2)
    parser.add_argument('--cases', nargs='*', choices=[c[0] for c in CASES])
    parser.add_argument('--algorithms', nargs='*', choices=ALGORITHMS, default=list(ALGORITHMS))
    parser.add_argument('--modes', nargs='*', choices=MODES, default=list(MODES))
    parser.add_argument('--set', nargs='*', default=[], metavar='NAME=VALUE',
                        help='ours: imu_filter_node parameter values (numbers)')
    parser.add_argument('--json', metavar='PATH', help='also write the rows there')
    args = parser.parse_args(argv)
    parameters = {k: float(v) for k, v in (item.split('=', 1) for item in args.set)}
    try:
        rows = batch_rows(args.data, args.trials, args.jobs, args.cases, args.algorithms,
                          args.modes, parameters or None,
                          progress=lambda t: print(t, file=sys.stderr, flush=True))
    except ValueError as error:
        print(f'error: {error}', file=sys.stderr)
        return 2
    print(batch_markdown(rows))
    if args.json:
        with open(args.json, 'w') as out:
            json.dump(rows, out, indent=1)
    return 0


if __name__ == '__main__':
    sys.exit(main())
