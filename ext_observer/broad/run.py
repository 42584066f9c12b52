"""
The run: our estimator and the anchors on the trials, each estimate scored.

Our estimator runs as one batched call over every trial and mode
(``estimate_batch`` of :mod:`ext_observer.core.ahrs.ahrs_observer`, with its shipped
defaults); the anchors, and our smoothed estimate when asked
(:func:`~ext_observer.core.ahrs.smoother.smooth_attitude`), run one
recording per task, in processes when ``jobs > 1``. Only the scores, the
norms of our raw estimates, the times and the per-sample errors of one
trial (for the figure) are kept.
"""

import sys
import time

import numpy as np

from ext_observer.broad.anchors import anchor_estimates, BROAD_GYRO_RANGE
from ext_observer.broad.result_keys import ANCHORS, MODES, OURS, OURS_PLAIN, OURS_SMOOTHED
from ext_observer.broad.scoring import combined_norms, error_angles, norm_parts, score


def log(text):
    """Print a progress line on stderr."""
    print(text, file=sys.stderr, flush=True)


def _plural(count, word):
    return f'{count} {word}{"es" if count > 1 else ""}'


def estimate_ours(trials, modes, variant, workers=1, params=None, then=None):
    """
    Run our estimator on every trial in every mode, in one batched call.

    Parameters
    ----------
    trials : list of Trial
    modes : sequence of {'9D', '6D'}
    variant : {'extended', 'plain'}
        With the extension term, or without it.
    workers : int
        ``estimate_batch``'s processes (1: all in this process).
    params : AhrsParams, optional
        Default: the shipped defaults.
    then : callable, optional
        ``then(trial, mode, q)`` on each estimate where it is made (a
        worker, with ``workers > 1``), as ``estimate_batch``'s ``then``.

    Returns
    -------
    estimates : dict
        ``{mode: {trial: ndarray, shape (N, 4)}}``, the raw estimates
        (``(w, x, y, z)``, sensor → ENU, not normalized).
    seconds : float
        Wall clock of the call.
    after : dict
        Only with ``then``: ``{mode: {trial: what then returned}}``.

    """
    from ext_observer.pipeline.batch import estimate_batch
    streams = [(t, m) for m in modes for t in trials]
    start = time.perf_counter()
    each = None if then is None else (lambda i, q: then(streams[i][0], streams[i][1], q))
    out = estimate_batch([t.gyr for t, _ in streams], [t.acc for t, _ in streams],
                         [t.mag for t, _ in streams], [t.rate for t, _ in streams],
                         [m == '9D' for _, m in streams], params=params, variant=variant,
                         workers=workers, then=each)
    seconds = time.perf_counter() - start
    out, results = (out, None) if then is None else out
    estimates = {m: {} for m in modes}
    for (t, m), q in zip(streams, out):
        estimates[m][t.name] = q
    if then is None:
        return estimates, seconds
    after = {m: {} for m in modes}
    for (t, m), result in zip(streams, results):
        after[m][t.name] = result
    return estimates, seconds, after


def run(trials, modes=MODES, anchors=ANCHORS, plain=False, jobs=1, workers=1,
        plot_trial=None, progress=log, params=None, gyro_range=BROAD_GYRO_RANGE,
        smooth=False):
    """
    Score the estimator (and the anchors) on the trials.

    Parameters
    ----------
    trials : list of Trial
    modes : sequence of {'9D', '6D'}
    anchors : sequence of str
        Anchors to run (empty: ours only).
    plain : bool
        Also run ``variant='plain'`` (no extension term), for comparison.
    jobs : int
        Processes for the anchors.
    workers : int
        Processes of our estimator's batched call (``estimate_batch``'s
        ``workers``; 1: all in this process).
    plot_trial : str, optional
        Keep the per-sample errors of this trial (for ``plot``).
    progress : callable
    params : AhrsParams, optional
        Our estimator's parameters (default: the shipped defaults).
    gyro_range : float
        The range of the gyro that recorded the trials, rad/s, for the
        anchors that are told it (Fusion); default BROAD's sensor's.
    smooth : bool
        Also score our smoothed estimate (each sample from the whole
        recording), as ``OURS_SMOOTHED``.

    Returns
    -------
    dict
        ``scores`` (``{algorithm: {mode: {trial: {..._rmse_deg}}}}``),
        ``norms``, ``seconds``, and ``series`` for ``plot_trial``.

    """
    rates = {t.rate for t in trials}
    if len(rates) != 1:
        raise ValueError(f'all trials must share one sampling rate, got {sorted(rates)}')
    result = {'scores': {}, 'norms': {}, 'seconds': {}, 'series': {}}
    by_name = {t.name: t for t in trials}

    def scored(name, q):
        t = by_name[name]
        return score(q, t.quat, t.movement), (error_angles(q, t.quat) if name == plot_trial
                                              else None)

    def keep(algorithm, mode, name, q, scores=None):
        scores, series = scores if scores is not None else scored(name, q)
        result['scores'].setdefault(algorithm, {}).setdefault(mode, {})[name] = scores
        if series is not None:
            result['series'].setdefault(algorithm, {})[mode] = series

    _run_ours(trials, modes, plain, workers, result, keep, scored, progress, params)
    tasks = ([(OURS_SMOOTHED, t, m, gyro_range) for m in modes for t in trials] if smooth
             else [])
    tasks += [(a, t, m, gyro_range) for a in anchors for m in modes for t in trials]
    _run_tasks(tasks, jobs, result, keep, progress)
    return result


def _run_ours(trials, modes, plain, workers, result, keep, scored, progress, params=None):
    samples = sum(len(t) for t in trials)
    variants = [('extended', OURS)] + ([('plain', OURS_PLAIN)] if plain else [])
    for variant, algorithm in variants:
        progress(f'{algorithm}: {len(trials)} trials × {len(modes)} modes in one batched call, '
                 f'{_plural(workers, "process")} ({samples} samples each mode) ...')
        # Each estimate is scored where it is made (in the workers too).
        estimates, seconds, after = estimate_ours(
            trials, modes, variant, workers, params,
            then=lambda t, mode, q: (scored(t.name, q), norm_parts(q)))
        result['seconds'][algorithm] = seconds
        progress(f'{algorithm}: {seconds:.1f} s')
        norms = {m: combined_norms([after[m][t.name][1] for t in trials]) for m in modes}
        norms['all'] = combined_norms([after[m][t.name][1] for m in modes for t in trials])
        result['norms'][variant] = norms
        for mode in modes:
            for name, q in estimates[mode].items():
                keep(algorithm, mode, name, q, after[mode][name][0])


def _anchor_task(task):
    anchor, trial, mode, gyro_range = task
    start = time.perf_counter()
    if anchor == OURS_SMOOTHED:
        q = smoothed_estimate(trial, mode == '9D')
    else:
        q = anchor_estimates(anchor, trial.gyr, trial.acc, trial.mag, trial.rate,
                             mode == '9D', gyro_range)
    return q, time.perf_counter() - start


def smoothed_estimate(trial, use_mag):
    """
    Our smoothed estimate of a trial (shipped settings), sensor → ENU, shape (N, 4).

    Non-finite samples are held from the last finite one, as our online
    estimator's batched call does.
    """
    from ext_observer.core.ahrs.smoother import smooth_attitude
    from ext_observer.pipeline.batch import hold_finite
    mag = hold_finite(np.asarray(trial.mag, dtype=float)) if use_mag else None
    q, _ = smooth_attitude(hold_finite(np.asarray(trial.gyr, dtype=float)),
                           hold_finite(np.asarray(trial.acc, dtype=float)), mag, trial.rate)
    return q


def _run_tasks(tasks, jobs, result, keep, progress):
    """The anchors' runs and our smoothed estimate's, one recording per task."""
    if not tasks:
        return
    names = list(dict.fromkeys(a for a, _, _, _ in tasks))
    progress(f'{", ".join(names)} ({len(tasks)} runs, {_plural(jobs, "process")}) ...')
    start = time.perf_counter()
    if jobs > 1:
        import concurrent.futures
        with concurrent.futures.ProcessPoolExecutor(jobs) as pool:
            outputs = pool.map(_anchor_task, tasks, chunksize=1)
            done = list(_progress_iter(outputs, tasks, progress))
    else:
        done = list(_progress_iter(map(_anchor_task, tasks), tasks, progress))
    for (anchor, t, mode, _), (q, seconds) in zip(tasks, done):
        keep(anchor, mode, t.name, q)
        result['seconds'][anchor] = result['seconds'].get(anchor, 0.0) + seconds
    result['seconds']['anchors_wall'] = time.perf_counter() - start


def _progress_iter(outputs, tasks, progress):
    last = None
    for (anchor, _, mode, _), out in zip(tasks, outputs):
        if (anchor, mode) != last:
            progress(f'  {anchor} {mode} ...')
            last = (anchor, mode)
        yield out
