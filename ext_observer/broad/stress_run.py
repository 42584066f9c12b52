"""
The robustness benchmark's run: every variant of every trial, scored (``broad --stress``).

Each variant of :mod:`ext_observer.broad.stress` goes through the same
:func:`~ext_observer.broad.run.run` as ``broad`` itself (ours in one batched
call, the anchors in processes), so the scoring is BROAD's: the RMSE over
the ``movement`` samples of the 6D inclination and of the 9D total error.
Then the means per variant, algorithm and mode, over all trials, the
tuning ones and the held-out ones (:mod:`ext_observer.broad.split`), and
the ratio of ours to VQF.
"""

import json
import math
import os
import time

import numpy as np

from ext_observer.broad.anchors import BROAD_GYRO_RANGE
from ext_observer.broad.result_keys import ALGORITHMS, FUSION_DEFAULTS, MODES, OURS
from ext_observer.broad.run import log, run
from ext_observer.broad.split import split_of, SPLITS
from ext_observer.broad.stress import DESCRIPTIONS, GYRO_RANGE, LABELS, variant, VARIANTS

# The anchors run by default: the best (VQF), its plain twin, the usual ROS
# one (Madgwick, imu_filter_madgwick's algorithm), and Fusion, the one told
# the gyro's range (at its README's settings and at its package defaults).
STRESS_ANCHORS = ('VQF', 'BasicVQF', 'Madgwick', 'Fusion', FUSION_DEFAULTS)
# The gyro range of each variant's data (rad/s): the clipped one's is the clip.
GYRO_RANGES = {key: GYRO_RANGE if key == 'e' else BROAD_GYRO_RANGE for key in VARIANTS}
# The score each mode is judged on.
MODE_KEYS = {'6D': 'inclination_rmse_deg', '9D': 'total_rmse_deg'}
# The trials a mean is taken over: all, then each side of the split.
HALVES = ('all',) + SPLITS


def run_stress(trials, keys=VARIANTS, modes=MODES, anchors=STRESS_ANCHORS, jobs=1,
               workers=1, progress=log, params=None):
    """
    Score ours and the anchors on the variants of the trials.

    Parameters
    ----------
    trials : list of Trial
        As read by ``load_trial``.
    keys : sequence of str
        Variants (:data:`~ext_observer.broad.stress.VARIANTS`).
    modes : sequence of {'9D', '6D'}
    anchors : sequence of str
        The anchors to run beside ours (empty: ours only).
    jobs, workers : int
        Processes of the anchors and of our batched call, as in ``run``.
    progress : callable
    params : AhrsParams, optional
        Our estimator's parameters (default: the shipped defaults).

    Returns
    -------
    dict
        ``scores``: ``{variant: {algorithm: {mode: {trial: {..._rmse_deg}}}}}``;
        ``seconds``: ``{variant: {algorithm or 'wall': s}}``; ``samples``:
        ``{variant: samples over the trials}``; ``rates``: ``{variant: Hz}``.

    """
    out = {'scores': {}, 'seconds': {}, 'samples': {}, 'rates': {}}
    for key in keys:
        start = time.perf_counter()
        varied = [variant(t, key) for t in trials]
        progress(f'variant {key}: {DESCRIPTIONS[key]} ...')
        result = run(varied, modes, anchors, jobs=jobs, workers=workers, progress=progress,
                     params=params, gyro_range=GYRO_RANGES[key])
        out['scores'][key] = result['scores']
        out['seconds'][key] = dict(result['seconds'], wall=time.perf_counter() - start)
        out['samples'][key] = int(sum(len(t) for t in varied))
        out['rates'][key] = varied[0].rate
    return out


def stress_summary(scores):
    """
    Return the mean RMSE per variant, algorithm, mode and half of the trials.

    Parameters
    ----------
    scores : dict
        ``run_stress(...)['scores']``.

    Returns
    -------
    dict
        ``{variant: {algorithm: {mode: {half: mean}}}}`` in degrees, for the
        halves of :data:`HALVES` that have trials; the score is the 6D
        inclination or the 9D total RMSE (:data:`MODE_KEYS`).

    """
    out = {}
    for key, per_algorithm in scores.items():
        out[key] = {}
        for algorithm in [a for a in ALGORITHMS if a in per_algorithm]:
            out[key][algorithm] = {}
            for mode, per_trial in per_algorithm[algorithm].items():
                means = {}
                for half in HALVES:
                    values = [s[MODE_KEYS[mode]] for name, s in per_trial.items()
                              if half == 'all' or split_of(name) == half]
                    values = [v for v in values if math.isfinite(v)]
                    if values:
                        means[half] = float(np.mean(values))
                out[key][algorithm][mode] = means
    return out


def ratio_to_vqf(summ, key, mode, half='all'):
    """Ours over VQF in one cell of :func:`stress_summary`, or None."""
    ours = summ.get(key, {}).get(OURS, {}).get(mode, {}).get(half)
    vqf = summ.get(key, {}).get('VQF', {}).get(mode, {}).get(half)
    return ours / vqf if ours is not None and vqf else None


def algorithms_of(summ):
    """The algorithms of a summary, in table order."""
    found = {a for per_algorithm in summ.values() for a in per_algorithm}
    return [a for a in ALGORITHMS if a in found]


def modes_of(summ):
    """The modes of a summary, in the order 6D, 9D (the page's table)."""
    found = {m for per_algorithm in summ.values() for per_mode in per_algorithm.values()
             for m in per_mode}
    return [m for m in ('6D', '9D') if m in found]


def table_rows(summ, half='all'):
    """
    Return the header and rows of the table of one half of the trials.

    One row per variant; per mode (6D, 9D) the mean of each algorithm and,
    when VQF ran, the ratio ours / VQF. Numbers as text with two decimals.
    """
    algorithms = algorithms_of(summ)
    modes = modes_of(summ)
    header = ['variant']
    for mode in modes:
        header += [f'{mode} {a}' for a in algorithms]
        if OURS in algorithms and 'VQF' in algorithms:
            header.append(f'{mode} ours/VQF')
    rows = []
    for key in [k for k in VARIANTS if k in summ]:
        row = [LABELS[key]]
        for mode in modes:
            for a in algorithms:
                row.append(_fmt(summ[key].get(a, {}).get(mode, {}).get(half)))
            if OURS in algorithms and 'VQF' in algorithms:
                row.append(_fmt(ratio_to_vqf(summ, key, mode, half)))
        rows.append(row)
    return header, rows


def _fmt(value):
    return '–' if value is None or not math.isfinite(value) else f'{value:.2f}'


def text_table(summ, counts):
    """
    Return the tables printed on stdout: all trials, the tuning ones, the held-out ones.

    ``counts`` is ``{half: number of trials}``; a half without trials is left out.
    """
    lines = []
    for half in HALVES:
        if not counts.get(half):
            continue
        header, rows = table_rows(summ, half)
        widths = [max(len(r[i]) for r in [header] + rows) for i in range(len(header))]
        title = {'all': 'all trials', 'tuning': 'tuning trials',
                 'held-out': 'held-out trials'}[half]
        lines.append(f'mean RMSE (°; 6D inclination, 9D total), {title}, '
                     f'{counts[half]} trials:')
        for row in [header] + rows:
            lines.append('  ' + '  '.join(c.ljust(w) if i == 0 else c.rjust(w)
                                          for i, (c, w) in enumerate(zip(row, widths))))
    return '\n'.join(lines)


def half_counts(names):
    """``{half: number of trials}`` of :data:`HALVES` for the trial names."""
    return {half: len(names) if half == 'all' else sum(split_of(n) == half for n in names)
            for half in HALVES}


def write_stress_json(path, out, meta):
    """Write the scores, the summary, the times and how the run was made to ``path``."""
    folder = os.path.dirname(path)
    if folder:
        os.makedirs(folder, exist_ok=True)

    def finite(value):
        if isinstance(value, dict):
            return {k: finite(v) for k, v in value.items()}
        if isinstance(value, (list, tuple)):
            return [finite(v) for v in value]
        if isinstance(value, float) and not math.isfinite(value):
            return None
        return value

    summ = stress_summary(out['scores'])
    ratios = {key: {mode: {half: ratio_to_vqf(summ, key, mode, half) for half in HALVES}
                    for mode in modes_of(summ)} for key in summ}
    with open(path, 'w', encoding='utf-8') as f:
        json.dump(finite({'variants': {k: DESCRIPTIONS[k] for k in out['scores']},
                          'summary': summ, 'ratio_to_vqf': ratios,
                          'scores': out['scores'], 'seconds': out['seconds'],
                          'samples': out['samples'], 'rates': out['rates'],
                          'meta': meta}), f, indent=1)
        f.write('\n')
