"""
Reproduce the paper's simulations: ``python -m ext_observer reproduce``.

Figure 1 (Section 3.1), Figure 2 (a–d) and Table 1 (Section 3.2), printed
beside the paper's numbers, plus our rows: the ``projected`` observer and
the gain modes ``rotating`` and ``scheduled``, with exact increments and
with gyro noise, next to the accuracy limit. All maths comes from
:mod:`ext_observer.core.paper.experiments`.
"""

import argparse
import concurrent.futures
import json
import os
import sys
import time

import numpy as np

from ext_observer.core.paper.experiments import (accuracy_limit, error_table,
                                           manifold_convergence,
                                           ObserverSpec, observer_runs)
from ext_observer.core.paper.observer import GAIN_MODES, VARIANTS
# Table 1 and the paper's numbers; read from here too.
from ext_observer.paper.table1 import (COLUMNS, markdown_table, PAPER_ROWS,  # noqa: F401
                                       PAPER_TABLE, STATS)
from ext_observer.source_tree import docgen

# Gyro noise of the "with gyro errors" rows: 0.01 rad of angle noise per step.
DEFAULT_GYRO_NOISE = 0.01


class Progress:
    """A one-line progress display on stderr (plain lines when not a tty)."""

    def __init__(self, total, enabled=True, stream=sys.stderr):
        self.total = total
        self.done = 0
        self.enabled = enabled
        self.stream = stream
        self.tty = stream.isatty()
        self.start = time.perf_counter()

    def advance(self, label, units=1):
        """Mark ``units`` done and show ``label``."""
        self.done += units
        if not self.enabled:
            return
        elapsed = time.perf_counter() - self.start
        line = f'[{self.done}/{self.total}] {label} ({elapsed:.1f} s)'
        if self.tty:
            end = '\n' if self.done == self.total else ''
            self.stream.write('\r\033[K' + line + end)
        else:
            self.stream.write(line + '\n')
        self.stream.flush()


def observer_specs(alpha, modes=GAIN_MODES):
    """Return one spec per variant and gain mode."""
    return [ObserverSpec(variant, mode, alpha=alpha)
            for mode in modes for variant in VARIANTS]


def _aggregate(tables):
    """Mean and spread (std over seeds) of a list of per-seed tables."""
    mean, spread = {}, {}
    for row in tables[0]:
        mean[row], spread[row] = {}, {}
        for column in tables[0][row]:
            values = {stat: [t[row][column][stat] for t in tables]
                      for stat in STATS}
            mean[row][column] = {s: float(np.mean(v)) for s, v in values.items()}
            spread[row][column] = {s: float(np.std(v)) for s, v in values.items()}
    return mean, spread


def _run_seed(seed, runs, epochs, alpha, gyro_noise, modes, progress=None,
              histories=False):
    """Run the three experiments of one seed; return their summaries."""
    specs = observer_specs(alpha, modes)
    fig1 = manifold_convergence(runs=runs, epochs=epochs, alpha=alpha,
                                seed=seed)
    if progress:
        progress.advance(f'seed {seed}: Figure 1')
    exact = observer_runs(specs, runs=runs, epochs=epochs, seed=seed)
    if progress:
        progress.advance(f'seed {seed}: Table 1, exact increments')
    noisy = observer_runs(specs, runs=runs, epochs=epochs, seed=seed,
                          gyro_noise_std=gyro_noise)
    if progress:
        progress.advance(f'seed {seed}: gyro noise {gyro_noise} rad')
    result = {
        'seed': seed,
        'fitted_factor': fig1['fitted_factor'],
        'fitted_residual_factor': fig1['fitted_residual_factor'],
        'certificate': fig1['certificate'],
        'table': {name: error_table(h) for name, h in exact.items()},
        'noisy_table': {name: error_table(h) for name, h in noisy.items()},
    }
    if histories:
        result['histories'] = {'figure1': fig1, 'exact': exact, 'noisy': noisy}
    return result


def run(runs=1000, epochs=100, seed=0, seeds=1, alpha=0.01,
        gyro_noise=DEFAULT_GYRO_NOISE, modes=GAIN_MODES, progress=None,
        keep_histories=True, on_histories=None):
    """
    Run every experiment over ``seeds`` consecutive seeds.

    ``on_histories``, if given, is called with the first seed's histories
    (in the form :func:`plot` takes) while the other seeds still run.

    Returns
    -------
    result : dict
        The JSON-ready summary, and (``keep_histories``) the first seed's
        per-epoch histories under ``'_histories'`` for the figures.

    """
    start = time.perf_counter()
    settings = dict(runs=runs, epochs=epochs, alpha=alpha,
                    gyro_noise=gyro_noise, modes=modes)
    all_seeds = list(range(seed, seed + seeds))
    results = _run_seeds(all_seeds, settings, progress, keep_histories, on_histories)
    results.sort(key=lambda r: r['seed'])
    histories = results[0].pop('histories', {})
    result = _summary(results, settings, all_seeds)
    result['seconds'] = time.perf_counter() - start
    if keep_histories:
        result['_histories'] = histories
    return result


def _run_seeds(all_seeds, settings, progress, keep_histories, on_histories):
    """
    Run the experiments of each seed; return their results in the order they end.

    The first seed runs here (its histories feed the figures); the others
    run in worker processes, one per core, and return only their tables.
    """
    results = []
    pool = None
    others = len(all_seeds) - 1
    if others > 0 and (os.cpu_count() or 1) > 1:
        pool = concurrent.futures.ProcessPoolExecutor(max_workers=min(others, os.cpu_count()))
    try:
        futures = ([pool.submit(_run_seed, s, **settings) for s in all_seeds[1:]]
                   if pool else [])
        results.append(_run_seed(all_seeds[0], progress=progress,
                                 histories=keep_histories, **settings))
        if on_histories and keep_histories:
            on_histories({'_histories': results[0]['histories'],
                          'epochs': settings['epochs'],
                          'gyro_noise_std': settings['gyro_noise'],
                          'limit': accuracy_limit(0.1, settings['epochs'])})
        if pool:
            for future in concurrent.futures.as_completed(futures):
                results.append(future.result())
                if progress:
                    progress.advance(f'seed {results[-1]["seed"]}: all tables', units=3)
        else:
            for s in all_seeds[1:]:
                results.append(_run_seed(s, progress=progress, **settings))
    finally:
        if pool:
            pool.shutdown(cancel_futures=True)
    return results


def _summary(results, settings, all_seeds):
    """The JSON-ready summary of the seeds' results (sorted by seed)."""
    tables = [r['table'] for r in results]
    table, spread = _aggregate(tables)
    noisy_table, noisy_spread = _aggregate([r['noisy_table'] for r in results])
    fig1_factors = [r['fitted_factor'] for r in results]
    cert = results[0]['certificate']
    return {
        'runs': settings['runs'], 'epochs': settings['epochs'], 'seeds': list(all_seeds),
        'alpha': settings['alpha'],
        'table': table,
        'table_spread': spread,
        'table_gyro_noise': noisy_table,
        'table_gyro_noise_spread': noisy_spread,
        'gyro_noise_std': settings['gyro_noise'],
        'paper': PAPER_TABLE,
        'limit': accuracy_limit(0.1, settings['epochs']),
        'figure1': {
            'fitted_factor': float(np.mean(fig1_factors)),
            'fitted_factor_spread': float(np.std(fig1_factors)),
            'fitted_residual_factor': float(np.mean(
                [r['fitted_residual_factor'] for r in results])),
            'certified_factor': cert.factor,
            'certificate': cert.to_dict(),
        },
        'best_mode': min(table, key=lambda row: table[row]['error']['mean']),
    }


def plot(result, out_dir):
    """Write the figures as PNG files in ``out_dir``; return their paths."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    os.makedirs(out_dir, exist_ok=True)
    hist = result['_histories']
    paths = []
    epochs = np.arange(result['epochs'] + 1)

    fig1 = hist['figure1']
    fig, ax = plt.subplots(figsize=(6, 4))
    residual = fig1['residual']
    ax.fill_between(epochs, residual.min(axis=1), residual.max(axis=1),
                    color='0.8', label='spread (min–max)')
    ax.semilogy(epochs, residual.mean(axis=1), 'k', label='mean')
    rho = np.sqrt(fig1['certified_factor'])
    ax.semilogy(epochs, residual.mean(axis=1)[0] * rho ** epochs, 'k--',
                label=f'certified rate √(1 − bc) = {rho:.3f}')
    ax.set_xlabel('epoch k')
    ax.set_ylabel('|q̄q − 1| (distance to S³)')
    ax.set_title('Figure 1: extended kinematics converge to S³')
    ax.legend()
    # Fixed margins: tight_layout costs about a second per run.
    fig.subplots_adjust(left=0.14, right=0.97, top=0.9, bottom=0.13)
    paths.append(os.path.join(out_dir, 'figure1.png'))
    fig.savefig(paths[-1], dpi=110)
    plt.close(fig)

    exact = hist['exact']
    fig, axes = plt.subplots(2, 2, figsize=(10, 7), sharex=True)
    panels = [('error', 'mean', '(a) mean ‖q − q̂‖'),
              ('error', 'max', '(b) worst run ‖q − q̂‖'),
              ('residual', 'mean', '(c) mean |q̂̄q̂ − 1|'),
              ('residual', 'max', '(d) worst run |q̂̄q̂ − 1|')]
    for ax, (key, how, title) in zip(axes.flat, panels):
        # projected sits on S³ by construction (residual ~1e-16): left out of
        # the distance panels so that the two paper rows stay readable.
        rows = PAPER_ROWS if key == 'error' else PAPER_ROWS[:2]
        for row, style in zip(rows, ('C0', 'C1', 'C2')):
            values = exact[row][key]
            curve = values.mean(axis=1) if how == 'mean' else values.max(axis=1)
            # The observers start at 1, on S³: the distance panels begin at k = 1.
            first = 0 if key == 'error' else 1
            ax.semilogy(epochs[first:], curve[first:], style, label=row)
        ax.set_title(title)
        ax.set_xlabel('epoch k')
    axes[0, 0].legend()
    fig.suptitle('Figure 2: Luenberger-like observers on S³')
    fig.subplots_adjust(left=0.08, right=0.98, top=0.9, bottom=0.08,
                        hspace=0.25, wspace=0.2)
    paths.append(os.path.join(out_dir, 'figure2.png'))
    fig.savefig(paths[-1], dpi=110)
    plt.close(fig)

    fig, axes = plt.subplots(1, 2, figsize=(11, 4), sharey=True)
    for ax, key, title in ((axes[0], 'exact', 'exact increments'),
                           (axes[1], 'noisy',
                            f'gyro noise {result["gyro_noise_std"]} rad/step')):
        for row, values in hist[key].items():
            if row.startswith('extended'):
                ax.semilogy(epochs, values['error'].mean(axis=1), label=row)
        ax.axhline(result['limit'], color='k', ls='--',
                   label=f'limit σE[χ₃]/√K = {result["limit"]:.4f}')
        ax.set_title(f'Mean ‖q − q̂‖ per gain mode, {title}')
        ax.set_xlabel('epoch k')
    axes[0].legend()
    fig.subplots_adjust(left=0.07, right=0.98, top=0.9, bottom=0.13,
                        wspace=0.08)
    paths.append(os.path.join(out_dir, 'gain_modes.png'))
    fig.savefig(paths[-1], dpi=110)
    plt.close(fig)
    return paths


def report(result):
    """Return the human-readable summary (Markdown)."""
    f1 = result['figure1']
    n = len(result['seeds'])
    lines = [
        f"Runs {result['runs']} × epochs {result['epochs']}, seeds "
        f"{result['seeds'][0]}..{result['seeds'][-1]} ({n}), α = {result['alpha']}"
        + (' (± is the std over seeds)' if n > 1 else ''),
        '',
        '## Figure 1: convergence to S³',
        f"fitted factor on V per epoch: {f1['fitted_factor']:.4f}   "
        f"certified 1 − bc: {f1['certified_factor']:.4f}   "
        f"(fitted on |q̄q − 1|: {f1['fitted_residual_factor']:.4f})",
        '',
        '## Table 1 (paper rows; distance = |q̂̄q̂ − 1| as in the paper)',
        markdown_table(result['table'], result['table_spread'] if n > 1 else None,
                       rows=PAPER_ROWS),
        '',
        '## Both distances to S³ (|q̂̄q̂ − 1| and the Euclidean |‖q̂‖ − 1|)',
        markdown_table(result['table'], None, rows=PAPER_ROWS,
                       columns=('distance', 'euclidean_distance'), paper={}),
        '',
        f"## Gain modes, exact increments (limit σE[χ₃]/√K = {result['limit']:.4f})",
        markdown_table(result['table'], None, paper={}),
        '',
        f"## Gain modes, gyro noise {result['gyro_noise_std']} rad per step",
        markdown_table(result['table_gyro_noise'], None, paper={}),
        '',
        f"Best mode (exact increments): {result['best_mode']}, final mean error "
        f"{result['table'][result['best_mode']]['error']['mean']:.4f}",
        f"Time: {result['seconds']:.2f} s",
    ]
    return '\n'.join(lines)


def build_parser():
    """Return the argument parser of ``reproduce``."""
    parser = argparse.ArgumentParser(
        prog='python -m ext_observer reproduce',
        description="Reproduce the paper's Figure 1, Figure 2 and Table 1.")
    parser.add_argument('--runs', type=int, default=1000,
                        help='Monte Carlo runs (default 1000)')
    parser.add_argument('--epochs', type=int, default=100,
                        help='steps per run (default 100)')
    parser.add_argument('--seed', type=int, default=0, help='first seed')
    parser.add_argument('--seeds', type=int, default=1,
                        help='repeat with N consecutive seeds, report mean ± std')
    parser.add_argument('--alpha', type=float, default=0.01,
                        help='extension gain α (default 0.01, the paper)')
    parser.add_argument('--gyro-noise', type=float, default=DEFAULT_GYRO_NOISE,
                        help='gyro angle noise of the gyro-error rows, rad/step')
    parser.add_argument('--out', default='out/reproduce',
                        help='folder for the PNG figures (default out/reproduce)')
    parser.add_argument('--no-plots', action='store_true',
                        help='skip the figures')
    parser.add_argument('--json', metavar='PATH',
                        help="also write the JSON summary ('-' for stdout)")
    parser.add_argument('--docs', metavar='DIR',
                        help='write DIR/reproduction.md with the figures in '
                             'DIR/figures (implies --out DIR/figures; in a clone of '
                             'ext_observer: the page writer, docgen/, is not installed)')
    parser.add_argument('--quiet', action='store_true',
                        help='no progress display and no report')
    return parser


def main(argv=None):
    """Run ``reproduce``; return the exit code."""
    args = build_parser().parse_args(argv)
    for name in ('runs', 'epochs', 'seeds'):
        if getattr(args, name) < 1:
            print(f'error: --{name} must be at least 1', file=sys.stderr)
            return 2
    if args.epochs <= 25:
        print('error: --epochs must exceed 25 (Max/Min are over k > 25)',
              file=sys.stderr)
        return 2
    try:
        page = docgen('reproduction_page') if args.docs else None
    except RuntimeError as error:
        print(f'error: {error}', file=sys.stderr)
        return 2
    progress = Progress(3 * args.seeds, enabled=not args.quiet)
    if args.docs:
        args.out = os.path.join(args.docs, 'figures')
    want_plots = not args.no_plots or bool(args.docs)
    figures = []
    try:
        # The figures are drawn while the worker processes run the other seeds.
        result = run(args.runs, args.epochs, args.seed, args.seeds, args.alpha,
                     args.gyro_noise, progress=progress,
                     keep_histories=want_plots,
                     on_histories=lambda partial: figures.extend(
                         plot(partial, args.out)))
    except ValueError as error:
        print(f'error: {error}', file=sys.stderr)
        return 2
    if want_plots:
        result['figures'] = figures
    if args.docs:
        command = 'python -m ext_observer reproduce ' + ' '.join(
            sys.argv[2:] if argv is None else argv)
        with open(os.path.join(args.docs, 'reproduction.md'), 'w') as f:
            f.write(page.docs_markdown(result, result['figures'], command.strip(),
                                       args.docs))
    result.pop('_histories', None)
    if not args.quiet:
        print(report(result))
        if 'figures' in result:
            print('Figures: ' + ', '.join(result['figures']))
    if args.json:
        text = json.dumps(result, indent=2)
        if args.json == '-':
            print(text)
        else:
            with open(args.json, 'w') as f:
                f.write(text + '\n')
    return 0


if __name__ == '__main__':
    sys.exit(main())
