"""
The command ``python -m ext_observer broad``: options, then read, run, report.

:func:`main` checks the options, notes what runs (commit, parameters) before
the run, reads the trials, runs them (:func:`~ext_observer.broad.run.run`),
prints the short report, and writes the JSON files and the page when asked.
Errors a user can fix (no data, no h5py, a missing anchor package) end with
one line on stderr and exit code 2.
"""

import argparse
import datetime
import os
import platform
import subprocess
import sys
import time

import numpy as np

from ext_observer.broad.anchors import missing_anchor_packages
from ext_observer.broad.data import (data_dir, DEFAULT_DIRS, ENV_VAR, find_groups,
                                     find_trials, has_trials, HOW_TO_GET, load_trials,
                                     shown_command, shown_path, TREE)
from ext_observer.broad.result_keys import ANCHORS, MODES
from ext_observer.broad.report import text_report, write_json
from ext_observer.broad.run import log, run
from ext_observer.broad.stress import VARIANTS
from ext_observer.broad.stress_run import STRESS_ANCHORS
from ext_observer.core.ahrs.compiled import warn_if_plain
from ext_observer.pipeline.kernel_cache import preload
from ext_observer.source_tree import docgen

# Trial shown over time in the report: magnetically disturbed.
PLOT_TRIAL = '28_disturbed_stationary_magnet_A'
# What the figures depend on, for the "uncommitted changes" note.
_ESTIMATOR_FILES = ('ext_observer/core/ahrs/ahrs_observer.py', 'ext_observer/broad')


def build_parser():
    """Return the argument parser of ``broad``."""
    cpus = os.cpu_count() or 1
    parser = argparse.ArgumentParser(
        prog='python -m ext_observer broad',
        description='The raw-IMU estimator and the anchors (VQF, BasicVQF, Madgwick, '
                    'Mahony, Fusion) on the BROAD recordings, scored as BROAD does.')
    parser.add_argument('--data', metavar='DIR',
                        help="BROAD's HDF5 files, in DIR or DIR/data_hdf5 (default: "
                             f"${ENV_VAR}, else {' or '.join(DEFAULT_DIRS)} beside the "
                             'source tree; make broad-data fetches BROAD into data/broad)')
    parser.add_argument('--mode', choices=('6D', '9D', 'both'), default='both',
                        help='6D (no magnetometer), 9D or both (default)')
    parser.add_argument('--json', metavar='OUT',
                        help='write {algorithm: {mode: {trial: RMSEs}}} to OUT, and the '
                             'other figures (norms, times, groups) to OUT_details.json')
    parser.add_argument('--no-anchors', action='store_true',
                        help='run our estimator only')
    parser.add_argument('--plain', action='store_true',
                        help="also run our estimator without the extension term "
                             "(doubles our run time)")
    parser.add_argument('--smooth', action='store_true',
                        help='also score our smoothed estimate (each sample from the whole '
                             "recording, as 'ext_observer smoothed'; docs/offline.md; "
                             'with --docs, the generated section of DOCS_DIR/offline.md and '
                             'DOCS_DIR/figures/offline_error.png instead of the broad page)')
    parser.add_argument('--docs', metavar='DOCS_DIR',
                        help='write DOCS_DIR/broad.md and DOCS_DIR/figures/broad_*.png '
                             "(in a clone of ext_observer: the pages' writers, docgen/, "
                             'are not installed)')
    parser.add_argument('--trials', nargs='+', metavar='NAME',
                        help='only these trials (name prefixes or fnmatch patterns)')
    parser.add_argument('--head', type=float, metavar='SECONDS',
                        help='cut each trial to its first SECONDS (quick checks only; '
                             'not BROAD figures)')
    parser.add_argument('--jobs', type=int, default=cpus,
                        help=f'processes for the anchors (default: the CPUs, {cpus} here)')
    parser.add_argument('--workers', type=int, default=cpus,
                        help="processes of our estimator's one batched call "
                             '(estimate_batch(workers=N); default: the CPUs, '
                             f'{cpus} here; 1: all in this process)')
    parser.add_argument('--quiet', action='store_true', help='no progress on stderr')
    parser.add_argument('--covariance', action='store_true',
                        help='instead: is the published orientation covariance honest? (our '
                             'estimator through the node\'s pipeline; with --docs, '
                             'DOCS_DIR/covariance.md and its figures)')
    parser.add_argument('--field-gap', metavar='START:END',
                        help='with --covariance, instead of its table: each trial in 9D with '
                             'the field gone from START to END s into it (e.g. 60:120): the '
                             "heading's mean e²/σ² with the field, within 2σ without it, its "
                             'RMS error after the return against the run without a gap')
    parser.add_argument('--stress', action='store_true',
                        help='instead: the robustness benchmark, each trial (a) as recorded, '
                             '(b) cut at its first movement sample, (c) (b) plus a 1 °/s gyro '
                             'bias, (d) (c) at 50 Hz, (e) gyro clipped at ±250 °/s (--plain '
                             'is ignored); with --docs, DOCS_DIR/robustness.md and '
                             'DOCS_DIR/figures/robustness.png')
    parser.add_argument('--variants', nargs='+', choices=VARIANTS, metavar='KEY',
                        help='with --stress: only these variants (a to e; default all)')
    parser.add_argument('--param', action='append', default=[], metavar='NAME=VALUE',
                        help="with --stress: one of our estimator's parameters (AhrsParams) "
                             'set for this run, e.g. --param tau_bias=100; repeatable; the '
                             'page lists the parameters used')
    parser.add_argument('--anchors', nargs='+', choices=ANCHORS, metavar='NAME',
                        help=f'the anchors to run (of {", ".join(ANCHORS)}; default all, '
                             f'with --stress {", ".join(STRESS_ANCHORS)})')
    return parser


def main(argv=None):
    """Run ``broad``; return the exit code."""
    argv = sys.argv[1:] if argv is None else list(argv)
    args = build_parser().parse_args(argv)
    warn_if_plain()
    progress = (lambda text: None) if args.quiet else log
    default_anchors = STRESS_ANCHORS if args.stress else ANCHORS
    anchors = () if args.no_anchors or args.covariance else tuple(
        args.anchors or default_anchors)
    problem = _check(args, anchors)
    if problem:
        print(f'error: {problem}', file=sys.stderr)
        return 2
    # What runs is what is on disk now: commit, changes and parameters are
    # read before the run (others may commit while it runs).
    source = _source()
    try:
        folder = data_dir(args.data)
        trials, groups = _read(folder, args, progress)
        if args.covariance:
            return _covariance(args, argv, source, folder, trials, groups, progress)
        if args.stress:
            return _stress(args, argv, source, folder, trials, anchors, progress)
        names = [t.name for t in trials]
        plot_trial = PLOT_TRIAL if PLOT_TRIAL in names else next(
            (n for n in names if 'magnet' in n), names[0])
        load = _load()
        modes = MODES if args.mode == 'both' else (args.mode,)
        result = run(trials, modes, anchors, plain=args.plain, jobs=args.jobs,
                     workers=args.workers, plot_trial=plot_trial if args.docs else None,
                     progress=progress, smooth=args.smooth)
        result['load'] = (load, _load())
    except (ValueError, RuntimeError) as error:
        print(f'error: {error}', file=sys.stderr)
        return 2
    meta = dict(
        source,
        command=shown_command(['python -m ext_observer broad', *argv]),
        data=shown_path(folder),
        machine=_machine(),
        versions=_versions(),
        trials=names,
        groups_source=('trials.json' if groups['source'] != 'file names'
                       else 'the file names'),
        plot_trial=plot_trial,
        rate=trials[0].rate,
        head=args.head,
        load=result.get('load'),
        workers=args.workers,
        jobs=args.jobs,
    )
    print(text_report(result, groups, meta))
    if args.json:
        write_json(args.json, result, groups, meta)
    if args.docs and args.smooth:
        page = docgen('offline_page')
        covariance = page.covariance_summary(trials, modes, workers=args.jobs,
                                             progress=progress)
        page.write_page(result, groups, meta, trials, covariance, args.docs, progress)
    elif args.docs:
        meta['plot_movement'] = next(t.movement for t in trials if t.name == plot_trial)
        _write_page(args.docs, result, groups, meta, progress)
    return 0


def _covariance(args, argv, source, folder, trials, groups, progress):
    """The covariance benchmark (``--covariance``) on the trials read."""
    from ext_observer.broad.covariance import report
    from ext_observer.broad.field_gap import field_gap, gap_table, parse_gap
    if args.field_gap is not None:
        gap = parse_gap(args.field_gap)
        print(gap_table(field_gap(trials, groups, gap, workers=args.workers,
                                  progress=progress), gap))
        return 0
    meta = dict(source, command=shown_command(['python -m ext_observer broad', *argv]),
                data=shown_path(folder), machine=_machine())
    # The covariance is the node's: its pipeline and uncertainty model count too.
    meta['dirty'] = bool(_git('status', '--porcelain', '--', *_ESTIMATOR_FILES,
                              'ext_observer/core/ahrs/uncertainty.py',
                              'ext_observer/pipeline/raw_imu.py'))
    modes = MODES if args.mode == 'both' else (args.mode,)
    summary, runs = report(trials, groups, meta, modes, workers=args.workers,
                           json_path=args.json, progress=progress)
    if args.docs:
        docgen('covariance_page').write_page(trials, runs, groups, summary, meta, args.docs,
                                             progress)
    return 0


def _stress(args, argv, source, folder, trials, anchors, progress):
    """The robustness benchmark (``--stress``) on the trials read."""
    from ext_observer.broad.stress_run import (half_counts, run_stress, stress_summary,
                                               text_table, write_stress_json)
    modes = MODES if args.mode == 'both' else (args.mode,)
    keys = tuple(args.variants) if args.variants else VARIANTS
    start = time.perf_counter()
    load = _load()
    params = _params(args.param)
    if params is not None:
        source = dict(source, params=params.as_dict(), overrides=list(args.param))
    out = run_stress(trials, keys, modes, anchors, jobs=args.jobs, workers=args.workers,
                     progress=progress, params=params)
    names = [t.name for t in trials]
    meta = dict(source,
                command=shown_command(['python -m ext_observer broad', *argv]),
                data=shown_path(folder), machine=_machine(), versions=_versions(),
                trials=names, anchors=list(anchors), variants=list(keys), head=args.head,
                workers=args.workers, jobs=args.jobs, wall=time.perf_counter() - start,
                load=(load, _load()))
    print(f'BROAD robustness: {len(names)} trials, commit {meta["commit"]}'
          + (' (estimator modified)' if meta['dirty'] else ''))
    print(text_table(stress_summary(out['scores']), half_counts(names)))
    print(f'  time: {meta["wall"]:.1f} s (' + ', '.join(
        f'({k}) {s["wall"]:.1f} s' for k, s in out['seconds'].items()) + ')')
    if args.json:
        write_stress_json(args.json, out, meta)
    if args.docs:
        writer = docgen('robustness_page')
        figure = writer.plot_stress(out, os.path.join(args.docs, 'figures', 'robustness.png'))
        page = os.path.join(args.docs, 'robustness.md')
        with open(page, 'w', encoding='utf-8') as f:
            f.write(writer.stress_markdown(out, meta, figure, args.docs))
        progress(f'wrote {page} and {figure}')
    return 0


def _params(settings):
    """``AhrsParams`` from ``NAME=VALUE`` settings, or None for the shipped defaults."""
    if not settings:
        return None
    from ext_observer.core.ahrs.ahrs_observer import AhrsParams
    values = {}
    for setting in settings:
        name, sep, value = setting.partition('=')
        if not sep or not name:
            raise ValueError(f'--param wants NAME=VALUE, got {setting!r}')
        words = {'true': True, 'false': False}
        values[name.strip()] = words.get(value.strip().lower(), value.strip())
    return AhrsParams(**values)


def _check(args, anchors):
    """Return what is wrong with the options before anything runs, or None."""
    if args.stress and args.covariance:
        return '--stress and --covariance are two benchmarks: one at a time'
    if (args.variants or args.param) and not args.stress:
        return '--variants and --param go with --stress'
    if args.field_gap is not None:
        if not args.covariance or args.docs:
            return '--field-gap goes with --covariance (and writes no page)'
        from ext_observer.broad.field_gap import parse_gap
        try:
            parse_gap(args.field_gap)
        except ValueError as error:
            return f'--field-gap: {error}'
    if args.smooth and (args.stress or args.covariance):
        return '--smooth goes with the accuracy benchmark, not --stress or --covariance'
    try:
        _params(args.param)
    except ValueError as error:
        return f'--param: {error}'
    if args.jobs < 1 or args.workers < 1:
        return '--jobs and --workers must be at least 1'
    if args.head is not None and not args.head > 0.0:
        return '--head must be positive'
    if args.docs:
        try:
            docgen('broad_page')
        except RuntimeError as error:
            return str(error)
    missing = missing_anchor_packages() if anchors else []
    if missing:
        return (f'the anchors need {", ".join(missing)}: pip install -r '
                'requirements-test.txt (or make test), or run with --no-anchors')
    return None


def _source():
    """The commit, whether the estimator has uncommitted changes, the date, the params."""
    from ext_observer.core.ahrs.ahrs_observer import AhrsParams
    return {
        'commit': _git('rev-parse', '--short', 'HEAD') or 'unknown',
        'dirty': bool(_git('status', '--porcelain', '--', *_ESTIMATOR_FILES)),
        'date': datetime.datetime.now(datetime.timezone.utc).strftime('%Y-%m-%d %H:%M UTC'),
        'params': AhrsParams().as_dict(),
    }


def _read(folder, args, progress):
    """Read the trials of ``folder`` (``--trials``, ``--head``) and their groups."""
    if not has_trials(folder):
        raise ValueError(f'no HDF5 files (*.hdf5) in {folder} nor in '
                         f'{os.path.join(folder, "data_hdf5")}: {HOW_TO_GET}')
    found = find_trials(folder, args.trials)
    start = time.perf_counter()
    # The estimator's compiled kernels load (numba's import and cache)
    # while the trials are read, so the estimates start at once after.
    trials = load_trials(found, meanwhile=lambda: preload(node=False))
    if args.head:
        trials = [t.head(args.head) for t in trials]
    progress(f'{len(trials)} trials read in {time.perf_counter() - start:.1f} s (the '
             'kernels loaded meanwhile)')
    groups = find_groups(folder, [t.name for t in trials], os.path.dirname(found[0][1]))
    return trials, groups


def _write_page(docs, result, groups, meta, progress):
    """Write the figures and ``docs/broad.md`` (linking the tuning page if there)."""
    figures = docgen('broad_plots').plot(result, groups, meta, os.path.join(docs, 'figures'))
    tuning = os.path.join(docs, 'broad_tuning.md')
    tuning = tuning if os.path.isfile(tuning) else None
    page = os.path.join(docs, 'broad.md')
    with open(page, 'w', encoding='utf-8') as f:
        f.write(docgen('broad_page').markdown(result, groups, meta, figures, docs, tuning))
    progress(f'wrote {page} and {", ".join(sorted(figures.values()))}')


def _versions():
    from importlib import metadata
    out = {'numpy': np.__version__}
    for name in ('vqf', 'ahrs', 'imufusion', 'h5py'):
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = 'not installed'
    return out


def _git(*args):
    try:
        done = subprocess.run(['git', *args], cwd=TREE, capture_output=True, text=True,
                              timeout=10)
    except (OSError, subprocess.TimeoutExpired):
        return None
    return done.stdout.strip() if done.returncode == 0 else None


def _load():
    """The 1-minute load average (other work on the machine skews the times)."""
    try:
        return round(os.getloadavg()[0], 2)
    except OSError:
        return None


def _machine():
    cpu = platform.processor() or 'unknown CPU'
    try:
        with open('/proc/cpuinfo') as f:
            for line in f:
                if line.startswith('model name'):
                    cpu = line.split(':', 1)[1].strip()
                    break
    except OSError:
        pass
    return f'{cpu}, {os.cpu_count()} cores, Python {platform.python_version()}'
