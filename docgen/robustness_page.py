"""
The page ``docs/robustness.md`` and its figure ``figures/robustness.png``.

Written by ``python -m ext_observer broad --stress --docs DIR`` from
:func:`~ext_observer.broad.stress_run.run_stress`'s output: what each
variant is, the tables (all trials, the tuning ones, the held-out ones), the ratio of
ours to VQF, how the run was made and the credit to BROAD.
"""

import math
import os

import numpy as np

from ext_observer.broad.anchors import BROAD_GYRO_RANGE, MADGWICK_BETA
from ext_observer.broad.result_keys import FUSION_DEFAULTS, OURS
from docgen.broad_page import fusion_text, shown_meta
from docgen.markdown import table as markdown_table
from ext_observer.broad.split import split_of
from ext_observer.broad.stress import (BIAS, DESCRIPTIONS, GYRO_RANGE, LABELS, LOW_RATE,
                                       RATIO_DONE, RATIO_GOAL, VARIANTS)
from ext_observer.broad.stress_run import (algorithms_of, half_counts, HALVES, modes_of,
                                           ratio_to_vqf, stress_summary, table_rows)

BROAD_URL = 'https://github.com/dlaidig/broad'
_TITLES = {'all': 'All trials', 'tuning': 'Tuning trials', 'held-out': 'Held-out trials'}


def stress_markdown(out, meta, figure=None, docs_dir='.'):
    """
    Return the page ``robustness.md``.

    Parameters
    ----------
    out : dict
        From ``run_stress``.
    meta : dict
        ``command``, ``commit``, ``dirty``, ``date``, ``machine``, ``data``,
        ``trials``, ``versions``, ``params``, ``head``, ``wall`` (s).
    figure : str, optional
        Path of the figure (linked relative to ``docs_dir``).
    docs_dir : str

    """
    summ = stress_summary(out['scores'])
    counts = half_counts(meta['trials'])
    keys = [k for k in VARIANTS if k in summ]
    command, data = shown_meta(meta)
    made_by = (f'**Made by** `{command}`'
               + (f' on the data in `{data}`' if data else '')
               + f' at commit `{meta["commit"]}`'
               + (' (with uncommitted changes to the estimator or this benchmark)'
                  if meta.get('dirty') else '')
               + f', {meta["date"]}, on {meta["machine"]}; the run took '
               f'{meta["wall"] / 60:.1f} min.')
    lines = [
        '# Robustness: BROAD made harder',
        '',
        "BROAD's trials start with seconds of rest, from a calibrated sensor at 286 Hz whose "
        "gyro never leaves its range. A robot's IMU is often none of that. This page runs "
        'the raw-IMU estimator (ours) and the anchors on variants of '
        'each trial that break one of those habits at a time, and scores them '
        'as [broad.md](broad.md) does. It is generated; do not edit it by hand.',
        '',
        '**Data.** BROAD (Laidig et al. 2021): D. Laidig, M. Caruso, A. Cereatti, T. Seel, '
        '"BROAD — A Benchmark for Robust Inertial Orientation Estimation", *Data* 6(7):72, '
        '2021, [doi:10.3390/data6070072](https://doi.org/10.3390/data6070072), licensed '
        f'[CC BY 4.0](https://creativecommons.org/licenses/by/4.0/) ([repository]({BROAD_URL})). '
        f'{counts["all"]} of its 39 trials; the variants are made in memory, nothing is '
        'written back.',
        '',
        made_by,
        '',
    ]
    if meta.get('head'):
        lines += [f'**Quick check only:** each trial cut to its first {meta["head"]:g} s '
                  '(`--head`) before the variants are made; these are not BROAD figures.',
                  '']
    lines += _variants() + _scoring(meta)
    for half in HALVES:
        if not counts.get(half):
            continue
        header, rows = table_rows(summ, half)
        lines += [f'## {_TITLES[half]}', '',
                  f'{counts[half]} trials: ' + ', '.join(
                      n.split('_', 1)[0] for n in meta['trials']
                      if half == 'all' or split_of(n) == half) + '.', '']
        lines += [markdown_table(header, rows, numeric=True)] + ['']
        if half == 'all':
            lines += _ratio_lines(summ, keys) + ['']
            if figure:
                link = os.path.relpath(figure, docs_dir).replace(os.sep, '/')
                lines += [f'![Mean RMSE per variant and algorithm]({link})', '']
    lines += _times(out, meta) + _reproduce(meta)
    return '\n'.join(lines)


def _variants():
    return [
        '## The variants', '',
        '| variant | what | how |', '|---|---|---|',
        f'| (a) | {DESCRIPTIONS["a"]} | the trial unchanged |',
        f'| (b) | {DESCRIPTIONS["b"]} | every array from the first sample whose `movement` '
        'flag is set; the rest phases later in the trial stay |',
        f'| (c) | {DESCRIPTIONS["c"]} | (b), and {np.degrees(BIAS):g} °/s added to every '
        'gyro sample along a unit direction fixed per trial: a standard normal draw of '
        '`numpy.random.default_rng(zlib.crc32(name))`, normalized (`bias_of` in '
        '`ext_observer/broad/stress.py`) |',
        f'| (d) | {DESCRIPTIONS["d"]} | (c), then block k holds the samples of time '
        f'[k, k + 1) / {LOW_RATE:g} s from the start (5 or 6 samples at 285.7 Hz); gyro, '
        'specific force and field are the block means, the rate exactly '
        f'{LOW_RATE:g} Hz; the reference quaternion and the `movement` flag are those of '
        "the block's last sample (after a block the estimator has integrated the gyro up "
        'to it); an incomplete last block is dropped |',
        f'| (e) | {DESCRIPTIONS["e"]} | every gyro axis clipped to ±{GYRO_RANGE:.4f} rad/s '
        '(250 °/s, the default range of the MPU-6050) |',
        '',
    ]


_ANCHOR_NOTES = {
    'VQF': 'VQF (`vqf`, causal `updateBatch`)',
    'BasicVQF': 'BasicVQF (`vqf`)',
    'Madgwick': f'Madgwick (`ahrs`, β = {MADGWICK_BETA}, started from the first sample)',
    'Mahony': 'Mahony (`ahrs`)',
    # Fusion is told the range of the data it is fed: the clip in (e).
    'Fusion': fusion_text(f'{math.degrees(BROAD_GYRO_RANGE):.0f} °/s (in (e) '
                          f'{math.degrees(GYRO_RANGE):.0f} °/s, the clip)'),
    FUSION_DEFAULTS: f'{FUSION_DEFAULTS}: `imufusion`, `AhrsSettings` with the rate only',
}


def _scoring(meta):
    ran = meta.get('anchors', ())
    # Fusion's text names its package defaults too.
    anchors = [_ANCHOR_NOTES[a] for a in ran if not (a == FUSION_DEFAULTS and 'Fusion' in ran)]
    params = meta.get('params')
    overrides = meta.get('overrides')
    ours = ('ours with ' + (f'`--param {" --param ".join(overrides)}`, otherwise its shipped '
                            'defaults' if overrides else 'its shipped defaults')
            + ' (`AhrsParams`' + (': ' + ', '.join(f'{k} = {v:g}' for k, v in params.items())
                                  if params else '') + ')')
    return [
        "**Scoring**, as in [broad.md](broad.md): BROAD's RMSE over the `movement` samples "
        'of each trial, in degrees: in 6D (no magnetometer) the inclination error, in 9D '
        'the total error; then the mean over the trials, over all of them and over each '
        'side of the one split of the trials (`ext_observer/broad/split.py`): a trial on '
        'which any default of the estimator was chosen is a tuning trial (the estimator\'s '
        'first defaults: [broad_tuning.md](broad_tuning.md); the start in motion and the '
        'clipped gyro: the even-numbered trials, [raw_imu.md](raw_imu.md)), the held-out '
        'trials had no part in any.',
        '',
        f'**Algorithms**, all on the same variant in the same run: {ours}; '
        + (', '.join(anchors) + ', as in [broad.md](broad.md)' if anchors else 'no anchor')
        + '. Versions: '
        + ', '.join(f'{k} {v}' for k, v in meta.get('versions', {}).items()) + '.',
        '',
    ]


def _ratio_lines(summ, keys):
    """The ratios ours / VQF, all trials and per half, and the criterion."""
    modes = modes_of(summ)
    if OURS not in algorithms_of(summ) or 'VQF' not in algorithms_of(summ):
        return []
    lines = ['**Ours / VQF** (all trials; tuning trials; held-out trials):', '']
    for key in keys:
        parts = []
        for mode in modes:
            values = [ratio_to_vqf(summ, key, mode, h) for h in HALVES]
            parts.append(f'{mode} ' + '; '.join('–' if v is None else f'{v:.2f}×'
                                                for v in values))
        lines.append(f'- {LABELS[key]}: ' + ', '.join(parts))
    judged = [(k, m, ratio_to_vqf(summ, k, m)) for k in keys if k != 'a' for m in modes]
    judged = [(k, m, r) for k, m, r in judged if r is not None]
    if judged:
        met = [f'({k}) {m}' for k, m, r in judged if r <= RATIO_DONE]
        goal = [f'({k}) {m}' for k, m, r in judged if r <= RATIO_GOAL]
        lines += ['', f'The goal: ours at most {RATIO_DONE:g}× VQF on (b)–(e), in 6D '
                  f'and in 9D, over all trials (goal: {RATIO_GOAL:g}×). At this run: '
                  f'{len(met)} of {len(judged)} met'
                  + (f' ({", ".join(met)})' if met else '')
                  + f'; {len(goal)} at the goal'
                  + (f' ({", ".join(goal)})' if goal else '') + '.']
    return lines


def _times(out, meta):
    lines = ['## Run time', '',
             'Wall clock per variant (our batched call, '
             f'{meta.get("workers", 1)} processes; the anchors, {meta.get("jobs", 1)} '
             'processes; the machine may be shared):', '']
    rows = []
    for key, seconds in out['seconds'].items():
        rows.append([f'({key})', f'{out["rates"][key]:.1f}', str(out['samples'][key]),
                     f'{seconds.get(OURS, float("nan")):.1f}',
                     f'{seconds.get("anchors_wall", 0.0):.1f}', f'{seconds["wall"]:.1f}'])
    lines += [markdown_table(['variant', 'rate (Hz)', 'samples (per mode)', 'ours (s)',
                     'anchors (s)', 'total (s)'], rows, numeric=True)] + ['']
    return lines


def _reproduce(meta):
    return [
        '## Reproduce', '',
        '```shell',
        'make broad-data   # once: BROAD into data/broad/',
        'make broad BROAD_ARGS="--stress --json out/robustness.json"',
        '```',
        '',
        'runs `python -m ext_observer broad --stress --json out/robustness.json --docs docs` '
        '(with `--data DIR` when `BROAD_DATA=DIR` is given; see [broad.md](broad.md) for '
        'where the data is looked for). Options: `--variants b c` for some variants only, '
        '`--anchors VQF` for fewer anchors (Madgwick is pure Python and the slowest), '
        '`--no-anchors` for ours alone, `--mode 6D|9D|both`, `--trials NAME...`, `--jobs N` '
        "and `--workers N` as for `broad`. From a script, "
        '`ext_observer.broad.variant(trial, key)` returns variant `key` of a trial read by '
        '`ext_observer.broad.load_trial`, and `ext_observer.broad.run_stress(trials)` '
        'scores them all.',
        '',
    ]


def plot_stress(out, path):
    """Write the figure: bars per variant and algorithm, 6D and 9D; return ``path``."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    import matplotlib.ticker

    summ = stress_summary(out['scores'])
    algorithms = algorithms_of(summ)
    modes = modes_of(summ)
    keys = [k for k in VARIANTS if k in summ]
    colors = {a: f'C{i}' for i, a in enumerate(a for a in algorithms if a != OURS)}
    colors[OURS] = 'k'
    os.makedirs(os.path.dirname(path) or '.', exist_ok=True)
    fig, axes = plt.subplots(len(modes), 1, figsize=(10, 3.4 * len(modes)), squeeze=False)
    width = 0.8 / max(len(algorithms), 1)
    x = np.arange(len(keys))
    titles = {'6D': '6D inclination RMSE', '9D': '9D total RMSE'}
    for ax, mode in zip(axes[:, 0], modes):
        for i, a in enumerate(algorithms):
            values = [summ[k].get(a, {}).get(mode, {}).get('all', np.nan) for k in keys]
            ax.bar(x + (i - (len(algorithms) - 1) / 2) * width, values, width, label=a,
                   color=colors[a])
        ax.set_xticks(x)
        ax.set_xticklabels([LABELS[k] for k in keys], fontsize=8)
        ax.set_ylabel('mean RMSE (°)')
        ax.set_yscale('log')
        shown = [summ[k].get(a, {}).get(mode, {}).get('all') for k in keys for a in algorithms]
        shown = [v for v in shown if v is not None and v > 0.0]
        if shown:  # room above the bars for the ratios
            ax.set_ylim(min(shown) / 1.5, max(shown) * 2.0)
        ax.yaxis.set_major_locator(matplotlib.ticker.LogLocator(subs=(1.0, 2.0, 5.0)))
        ax.yaxis.set_major_formatter(matplotlib.ticker.FormatStrFormatter('%g'))
        ax.yaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
        ratios = [ratio_to_vqf(summ, k, mode) for k in keys]
        for xi, r, k in zip(x, ratios, keys):
            if r is not None:
                top = max(summ[k].get(a, {}).get(mode, {}).get('all', 0.0) for a in algorithms)
                ax.annotate(f'ours/VQF {r:.2f}', (xi, top), xytext=(0, 3),
                            textcoords='offset points', ha='center', fontsize=7)
        ax.set_title(f'{titles[mode]}, mean over the trials, per variant')
        ax.grid(axis='y', alpha=0.3, which='both')
    axes[0, 0].legend(ncol=len(algorithms), fontsize=8, loc='upper left')
    fig.subplots_adjust(left=0.08, right=0.99, top=0.93, bottom=0.08, hspace=0.35)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path
