"""
The raw-IMU core over every BROAD trial in both modes, batched, against its speed goal.

``python -m bench.broad_batch [--data DIR] [--runs 3] [--workers N]
[--vectorized] [--json PATH]`` reads the trials (BROAD's HDF5 files, found
as ``python -m ext_observer broad`` finds them) and times the one batched
call that command makes for our estimator
(:func:`ext_observer.broad.estimate_ours`: every trial in 9D and 6D,
``estimate_batch`` with ``--workers`` processes, default the CPUs), ``--runs``
times. It prints the wall clock of each run and their median, the CPU time
of all the processes, and the verdict against :data:`BATCH_GOAL` s, ``met``
or ``not met``. ``--vectorized`` adds one run in this process
(``workers=1``), for comparison. Reading the files is not timed.
"""

import argparse
import os
import statistics
import sys

from bench.imu_filter_cpu import verdict
from bench.machine import load, load_range, log, save_json

# The raw-IMU speed goal: the core over all 22 trials, both modes, batched, in under this (s).
BATCH_GOAL = 10.0


def _timed(trials, workers):
    from ext_observer.broad import estimate_ours, MODES
    load_before, before = load(), os.times()
    _, seconds = estimate_ours(trials, MODES, 'extended', workers=workers)
    after = os.times()
    cpu = sum(after[i] - before[i] for i in range(4))  # user, system, and the children's
    return {'workers': workers, 'seconds': seconds, 'cpu_seconds': cpu,
            'load': (load_before, load())}


def batch(data=None, runs=3, workers=None, vectorized=False, progress=None):
    """
    Time the batched call; return the runs and the verdict.

    Returns
    -------
    dict
        ``data``, ``trials``, ``recordings``, ``sample_updates``, ``runs``
        (``workers``, ``seconds``, ``cpu_seconds``, ``load``: the 1-minute
        load average before and after, each), ``median_seconds``,
        ``goal``, ``met``, and ``vectorized`` (one run, or None).

    """
    from ext_observer.broad import data_dir, find_trials, load_trial, MODES, shown_path
    workers = workers or os.cpu_count() or 1
    folder = data_dir(data)
    trials = [load_trial(path, name) for name, path in find_trials(folder)]
    result = {'data': shown_path(folder), 'trials': len(trials),
              'recordings': len(trials) * len(MODES),
              'sample_updates': sum(len(t) for t in trials) * len(MODES), 'runs': []}
    for k in range(runs):
        if progress:
            progress(f'broad batch: run {k + 1}/{runs}, {len(trials)} trials × {len(MODES)} '
                     f'modes, {workers} workers ...')
        result['runs'].append(_timed(trials, workers))
    result['median_seconds'] = statistics.median(r['seconds'] for r in result['runs'])
    result['goal'] = BATCH_GOAL
    result['met'] = result['median_seconds'] < BATCH_GOAL
    result['vectorized'] = None
    if vectorized:
        if progress:
            progress('broad batch: one vectorized run (workers=1) ...')
        result['vectorized'] = _timed(trials, 1)
    return result


def goal_line(result):
    """The sentence that states the goal and whether it is met."""
    return (f'goal (raw-IMU node): the core on all {result["trials"]} trials, both modes, '
            f'batched, < {result["goal"]:g} s: {result["median_seconds"]:.1f} s (median of '
            f'{len(result["runs"])}, {result["runs"][0]["workers"]} workers, load average '
            f'{load_range(result["runs"])} on {os.cpu_count()} cores): '
            f'{verdict(result["met"])}')


def main(argv=None):
    """Time the batch; print the runs and the verdict; return 0 (2 without data)."""
    parser = argparse.ArgumentParser(prog='python -m bench.broad_batch')
    parser.add_argument('--data', metavar='DIR',
                        help='BROAD\'s HDF5 files (default: as python -m ext_observer broad)')
    parser.add_argument('--runs', type=int, default=3)
    parser.add_argument('--workers', type=int, help='default: the CPUs')
    parser.add_argument('--vectorized', action='store_true',
                        help='also one run in this process (workers=1)')
    parser.add_argument('--json', metavar='PATH', help='also write the results there')
    args = parser.parse_args(argv)
    if args.runs < 1:
        parser.error('--runs must be at least 1')
    try:
        result = batch(args.data, args.runs, args.workers, args.vectorized,
                       log)
    except ValueError as error:
        print(f'error: {error}', file=sys.stderr)
        save_json(args.json, {'error': f'not run: {error}'})
        return 2
    for run in result['runs'] + ([result['vectorized']] if result['vectorized'] else []):
        print(f'workers {run["workers"]}: {run["seconds"]:.1f} s wall, '
              f'{run["cpu_seconds"]:.1f} s CPU')
    print(f'{result["sample_updates"]} sample-updates ({result["recordings"]} recordings)')
    print(goal_line(result))
    save_json(args.json, result)
    return 0


if __name__ == '__main__':
    sys.exit(main())
