"""
Is the published orientation covariance honest? The BROAD trials say.

``python -m ext_observer broad --covariance`` runs every trial in 9D and 6D
through :class:`~ext_observer.pipeline.raw_imu.RawImuPipeline`, exactly as
``imu_filter_node`` runs it (stamps 1/rate apart, the field after each
sample), keeps each estimate and its covariance, and compares the claimed
σ with the error against the optical reference over the scored
(``movement``) samples:

- the fraction of samples whose error is within 2σ (the inclination angle
  against ``√(2 V_t)``, the heading against ``√V_h``), and
- the mean of ``error² / σ²``,

for each component (inclination; heading in 9D), per group (undisturbed,
disturbed) and per side of :mod:`ext_observer.broad.split` (``tuning``,
``held-out``). The coverage bounds: 90–99 % and 0.5–2.

:func:`replay` runs the uncertainty model alone again on what a run logged
(the estimator's steps do not depend on it), so other parameters are tried
in seconds (:func:`tune`). :func:`report` runs, prints and saves the
benchmark; its page is ``docgen/covariance_page.py``'s (in a clone).
"""

import json
import math
import multiprocessing

import numpy as np

from ext_observer.broad.scoring import error_angles
from ext_observer.broad.split import split_of, SPLITS
from ext_observer.core.ahrs.ahrs_params import UncertaintyParams
from ext_observer.core.ahrs.uncertainty import AttitudeUncertainty

MODES = ('9D', '6D')
GROUPS = ('undisturbed', 'disturbed')
COMPONENTS = ('inclination', 'heading')
# The coverage bounds: 90–99 % within 2σ, the mean of e²/σ² within 0.5–2.
FRACTION_RANGE = (0.90, 0.99)
MEAN_RANGE = (0.5, 2.0)
# A σ this large says the heading is unknown (before a field sets it, or while
# the magnetometer calibration has not converged), rad.
UNKNOWN_SIGMA = math.radians(30.0)
# BROAD's magnetometer is in µT; the node takes T.
TESLA_PER_MICROTESLA = 1e-6
_START_NS = 1_000_000_000


def node_settings(mode, values=None):
    """``imu_filter_node``'s settings with its defaults, 9D or 6D (and ``values``)."""
    from ext_observer.pipeline.imu_filter_parameters import (IMU_FILTER_PARAMETERS,
                                                             imu_filter_settings)
    settings = {spec.name: spec.default for spec in IMU_FILTER_PARAMETERS}
    settings.update(values or {})
    settings['use_mag'] = mode == '9D'
    return imu_filter_settings(settings)


def run_trial(trial, mode, values=None, gap=None):
    """
    Run one trial through the node's pipeline; keep the estimates, covariances and inputs.

    Parameters
    ----------
    trial : ext_observer.broad.data.Trial
    mode : {'9D', '6D'}
    values : dict, optional
        Node parameters other than the defaults.
    gap : (float, float), optional
        A field gone: no field is given from ``gap[0]`` to ``gap[1]`` s
        into the trial (9D).

    Returns
    -------
    dict of ndarray
        ``state`` (N, 4, ENU, NaN without an estimate), ``tilt`` and
        ``heading`` (N, the published variances, rad², as ``imu/data``
        carries them: before the sample's field), ``rest``, ``started`` (the
        estimator initialized at this sample), ``gain``, ``calibration`` and
        ``reference`` and ``dip`` (what the sample's field told the
        uncertainty model: NaN without one; ``gain0``, ``calibration0``,
        ``reference0`` and ``dip0`` for the field the start used),
        ``rejected`` (a field came and did not correct the heading), ``held``
        (the inclination held on the gyro, the specific force rejected),
        ``bias_var`` (the estimator's bias variance, NaN when it learns no
        bias in motion), ``clip_var`` (what a sample at the gyro's range
        added to the variances), ``dt``.

    """
    from ext_observer.pipeline.raw_imu import RawImuPipeline
    pipeline = RawImuPipeline(node_settings(mode, values))
    core, tracker = pipeline.estimator.core, pipeline.estimator.uncertainty
    n = len(trial)
    period = 1e9 / trial.rate
    out = {key: np.full(n, np.nan) for key in ('tilt', 'heading', 'gain', 'calibration',
                                               'reference', 'dip', 'gain0', 'calibration0',
                                               'reference0', 'dip0', 'bias_var', 'clip_var')}
    out['state'] = np.full((n, 4), np.nan)
    for key in ('rest', 'rejected', 'started', 'held'):
        out[key] = np.zeros(n, dtype=bool)
    gyr, acc = trial.gyr.tolist(), trial.acc.tolist()
    mag = (trial.mag * TESLA_PER_MICROTESLA).tolist() if mode == '9D' else None
    lo, hi = (math.inf, math.inf) if gap is None else (gap[0] * trial.rate, gap[1] * trial.rate)
    for k in range(n):
        stamp = _START_NS + round(k * period)
        tracker.last_field = None
        was_started = tracker.started
        estimate = pipeline.imu(stamp, gyr[k], acc[k])[1]
        if estimate is not None:
            out['state'][k] = estimate.state
            out['tilt'][k], out['heading'][k] = estimate.covariance[0], estimate.covariance[8]
            out['started'][k] = not was_started or estimate.reason is not None
            out['rest'][k] = core.rest
            out['held'][k] = core.held
            bias_var = core.bias_variance
            out['bias_var'][k] = math.nan if bias_var is None else bias_var
            out['clip_var'][k] = core.clip_variance
            if tracker.last_field is not None:
                (out['gain0'][k], out['calibration0'][k], out['reference0'][k],
                 out['dip0'][k]) = tracker.last_field[1:]
        if mag is not None and not lo <= k < hi:
            tracker.last_field = None
            pipeline.field(stamp, mag[k])
            if tracker.last_field is not None:
                (out['gain'][k], out['calibration'][k], out['reference'][k],
                 out['dip'][k]) = tracker.last_field[1:]
                out['rejected'][k] = tracker.last_field[1] == 0.0
    out['dt'] = 1.0 / trial.rate
    return out


def replay(runs, params=None, ahrs_params=None):
    """
    Run the uncertainty model again on logged runs, all at once (arrays across them).

    Parameters
    ----------
    runs : list of dict
        :func:`run_trial`'s outputs, one mode each; all with the same ``dt``.
    params : UncertaintyParams, optional
    ahrs_params : ext_observer.core.ahrs.ahrs_observer.AhrsParams, optional
        The estimator's (its time constants); default its defaults.

    Returns
    -------
    list of (tilt, heading)
        The variances each run would publish with ``params``.

    """
    from ext_observer.core.ahrs.ahrs_observer import AhrsParams
    dt = runs[0]['dt']
    lengths = [len(r['tilt']) for r in runs]
    n = max(lengths)

    def stack(key, fill):
        a = np.full((n, len(runs)), fill, dtype=float)
        for i, r in enumerate(runs):
            a[:len(r[key]), i] = r[key]
        return a

    use_mag = np.array([bool(np.isfinite(r['gain']).any()) for r in runs])
    mag = bool(use_mag.any())
    tracker = AttitudeUncertainty.for_estimator(ahrs_params or AhrsParams(), params,
                                                use_mag=use_mag)
    states = np.full((n, 4, len(runs)), np.nan)
    for i, r in enumerate(runs):
        states[:len(r['state']), :, i] = r['state']
    gyr = np.stack([stack(f'gyr{j}', 0.0) for j in range(3)], axis=1)
    # The specific force, where every run logged it: how unsure the start is.
    acc = (np.stack([stack(f'acc{j}', 0.0) for j in range(3)], axis=1)
           if all('acc0' in r for r in runs) else None)
    rest, started = stack('rest', 0.0), stack('started', 0.0)
    held = stack('held', 0.0) if all('held' in r for r in runs) else None
    bias_var = stack('bias_var', np.nan) if all('bias_var' in r for r in runs) else None
    if bias_var is not None and not np.isfinite(bias_var).any():
        bias_var = None
    clip_var = stack('clip_var', 0.0) if all('clip_var' in r for r in runs) else None
    first = int(np.argmax(started.any(axis=1)))
    if not np.all(started[first]) or started[first + 1:].any():
        raise ValueError('replay needs runs that all start at the same sample and never restart')
    tilt, heading = np.full((n, len(runs)), np.nan), np.full((n, len(runs)), np.nan)

    def dips(key):
        return stack(key, np.nan) if all(key in r for r in runs) else np.full((n, len(runs)),
                                                                               np.nan)

    gains = [(stack('gain0', np.nan), stack('calibration0', 0.0), stack('reference0', np.nan),
              dips('dip0')),
             (stack('gain', np.nan), stack('calibration', 0.0), stack('reference', np.nan),
              dips('dip'))]

    def apply(which, k):
        g, c, u, d = (a[k] for a in gains[which])
        seen = np.isfinite(g)
        if mag and seen.any():
            tracker.field(dt, np.where(seen, g, 0.0), np.where(seen, c, 0.0),
                          np.where(seen, u, np.nan), np.where(seen, d, np.nan))

    tracker.start(dt, None if acc is None else acc[first])
    apply(0, first)
    for k in range(first, n):
        if k > first:
            tracker.step(dt, gyr[k], states[k], rest[k] > 0.5,
                         None if bias_var is None else np.nan_to_num(bias_var[k]),
                         None if clip_var is None else np.nan_to_num(clip_var[k]),
                         None if acc is None else acc[k],
                         held=None if held is None else held[k] > 0.5)
        cov = tracker.covariance
        tilt[k], heading[k] = cov[0], cov[8]
        apply(1, k)
    return [(tilt[:m, i], heading[:m, i]) for i, m in enumerate(lengths)]


def errors(trial, run):
    """BROAD's inclination and heading errors (rad) of a run, and its scored samples."""
    _, heading, inclination = error_angles(run['state'], trial.quat)
    scored = trial.movement & np.isfinite(inclination)
    return inclination, heading, scored


def calibration_figures(samples):
    """
    The two coverage figures for pooled samples.

    Parameters
    ----------
    samples : list of (error, sigma)
        ndarrays of the scored samples (rad).

    Returns
    -------
    dict
        ``n``, ``within_2sigma`` (fraction), ``mean_z2``, ``rms_error``,
        ``rms_sigma`` (rad); ``unknown``, the share of samples with σ of
        :data:`UNKNOWN_SIGMA` or more, and ``within_2sigma_known``,
        ``mean_z2_known`` over the others (NaN if none).

    """
    e = np.concatenate([s[0] for s in samples])
    sigma = np.concatenate([s[1] for s in samples])
    z2 = (e / sigma) ** 2
    known = sigma < UNKNOWN_SIGMA
    return {'n': int(e.size), 'within_2sigma': float(np.mean(z2 <= 4.0)),
            'mean_z2': float(np.mean(z2)), 'rms_error': float(np.sqrt(np.mean(e * e))),
            'rms_sigma': float(np.sqrt(np.mean(sigma * sigma))),
            'unknown': float(np.mean(~known)),
            'within_2sigma_known': float(np.mean(z2[known] <= 4.0)) if known.any() else math.nan,
            'mean_z2_known': float(np.mean(z2[known])) if known.any() else math.nan}


def scored_pairs(trial, run, variances=None):
    """``{component: (error, sigma)}`` over the scored samples of one run."""
    inclination, heading, scored = errors(trial, run)
    tilt, head = variances if variances is not None else (run['tilt'], run['heading'])
    pairs = {'inclination': (inclination[scored], np.sqrt(2.0 * tilt[scored]))}
    if np.isfinite(run['gain']).any():
        pairs['heading'] = (heading[scored], np.sqrt(head[scored]))
    return pairs


def summarize(trials, runs, groups, variances=None):
    """
    The figures per mode, split, group and component.

    Parameters
    ----------
    trials : list of Trial
    runs : dict
        ``{mode: {trial name: run}}``.
    groups : dict
        ``find_groups``'s output.
    variances : dict, optional
        ``{mode: {trial name: (tilt, heading)}}`` replacing the runs' own.

    Returns
    -------
    dict
        ``{(mode, split, group, component): calibration_figures(...)}``.

    """
    member = {name: g for g in GROUPS for name in groups['members'].get(g, [])}
    pooled = {}
    for mode, by_name in runs.items():
        for trial in trials:
            run = by_name.get(trial.name)
            if run is None or trial.name not in member:
                continue
            v = None if variances is None else variances[mode][trial.name]
            for component, pair in scored_pairs(trial, run, v).items():
                for split in [s for s in (split_of(trial.name), 'all') if s]:
                    key = (mode, split, member[trial.name], component)
                    pooled.setdefault(key, []).append(pair)
    return {key: calibration_figures(pairs) for key, pairs in pooled.items()}


def verdict(figures):
    """Whether both figures are within the coverage bounds."""
    lo, hi = FRACTION_RANGE
    mlo, mhi = MEAN_RANGE
    return lo <= figures['within_2sigma'] <= hi and mlo <= figures['mean_z2'] <= mhi


def text_table(summary):
    """The figures as a text table, one row per mode, split, group and component."""
    lines = [f'{"mode":4} {"split":8} {"group":11} {"component":11} {"samples":>8} '
             f'{"within 2σ":>9} {"mean e²/σ²":>10} {"RMS error":>9} {"RMS σ":>7}  in bounds  '
             f'{"σ ≥ 30°":>7} {"known: 2σ":>9} {"mean":>5}']
    for key in sorted(summary, key=_order):
        f = summary[key]
        mode, split, group, component = key
        lines.append(
            f'{mode:4} {split:8} {group:11} {component:11} {f["n"]:8d} '
            f'{100 * f["within_2sigma"]:8.1f}% {f["mean_z2"]:10.2f} '
            f'{math.degrees(f["rms_error"]):8.2f}° {math.degrees(f["rms_sigma"]):6.2f}°  '
            f'{"yes" if verdict(f) else "NO ":9} {100 * f["unknown"]:6.1f}% '
            f'{100 * f["within_2sigma_known"]:8.1f}% {f["mean_z2_known"]:5.2f}')
    return '\n'.join(lines)


def _order(key):
    mode, split, group, component = key
    return (MODES.index(mode), (*SPLITS, 'all').index(split), GROUPS.index(group),
            COMPONENTS.index(component))


# --- running every trial ---------------------------------------------------

_JOB = None


def _run_job(index):
    trials, modes, values, gap = _JOB
    trial, mode = trials[index // len(modes)], modes[index % len(modes)]
    run = run_trial(trial, mode, values, gap)
    # The gyro and the accelerometer ride along for replays.
    for j in range(3):
        run[f'gyr{j}'] = trial.gyr[:, j]
        run[f'acc{j}'] = trial.acc[:, j]
    return index, run


def run_all(trials, modes=MODES, values=None, workers=1, progress=None, gap=None):
    """
    Run every trial in every mode (forked processes when ``workers > 1``).

    ``values`` and ``gap`` as :func:`run_trial` takes them.

    Returns
    -------
    dict
        ``{mode: {trial name: run}}``.

    """
    global _JOB
    _JOB = (trials, tuple(modes), values, gap)
    count = len(trials) * len(modes)
    # Longest first, so the last job is a short one.
    order = sorted(range(count), key=lambda i: -len(trials[i // len(modes)]))
    runs = {mode: {} for mode in modes}
    try:
        if workers > 1:
            with multiprocessing.get_context('fork').Pool(workers) as pool:
                done = pool.imap_unordered(_run_job, order)
                for i, (index, run) in enumerate(done, 1):
                    _keep(runs, trials, modes, index, run, i, count, progress)
        else:
            for i, index in enumerate(order, 1):
                _keep(runs, trials, modes, *_run_job(index), i, count, progress)
    finally:
        _JOB = None
    return runs


def _keep(runs, trials, modes, index, run, i, count, progress):
    trial, mode = trials[index // len(modes)], modes[index % len(modes)]
    runs[mode][trial.name] = run
    if progress:
        progress(f'  {i}/{count} {trial.name} {mode}')


# --- choosing the defaults -------------------------------------------------

# What the tuning aims at, inside the coverage bounds: 2σ covering 95 % (for a
# two-dimensional Gaussian error an RMS σ covers 98 %), the mean of e²/σ²
# near 1.
TARGET_FRACTION, FRACTION_SCALE = 0.95, 0.025
TARGET_MEAN, MEAN_SCALE = 1.1, math.log(1.6)


def report(trials, groups, meta, modes=MODES, workers=1, json_path=None, progress=None):
    """
    Run the covariance benchmark, print its table, write the JSON if asked.

    Parameters
    ----------
    trials : list of Trial
    groups : dict
        ``find_groups``'s output.
    meta : dict
        ``command``, ``commit``, ``dirty``, ``date``, ``machine``, ``data``.
    modes : sequence of {'9D', '6D'}
    workers : int
    json_path : str, optional

    Returns
    -------
    summary : dict
        :func:`summarize`'s.
    runs : dict
        :func:`run_all`'s, for the page (``docgen.covariance_page``).

    """
    if progress:
        progress(f'{len(trials)} trials × {len(modes)} modes through RawImuPipeline, '
                 f'{workers} process{"es" if workers > 1 else ""} ...')
    runs = run_all(trials, modes, workers=workers, progress=progress)
    summary = summarize(trials, runs, groups)
    print(text_table(summary))
    missed = [key for key, f in summary.items() if key[1] != 'all' and not verdict(f)]
    print(f'{len(summary) - len(missed) - sum(k[1] == "all" for k in summary)} of '
          f'{sum(k[1] != "all" for k in summary)} rows within the coverage bounds '
          f'(90–99 % within 2σ, mean e²/σ² 0.5–2)'
          + ('' if not missed else '; outside: ' + ', '.join(' '.join(k) for k in missed)))
    if json_path:
        with open(json_path, 'w', encoding='utf-8') as f:
            json.dump({'meta': meta, 'params': UncertaintyParams().as_dict(),
                       'figures': [dict(zip(('mode', 'split', 'group', 'component'), key),
                                        **value) for key, value in sorted(summary.items())]},
                      f, indent=1)
    return summary, runs


def tuning_cost(summary):
    """
    How far the figures of every group and component are from the targets (0: on them).

    ``Σ ((f − 0.95) / 0.025)² + (log(m / 1.1) / log 1.6)²`` over the
    ``(mode, split, group, component)`` rows of :func:`summarize` (the
    ``all`` rows excluded), ``f`` the fraction within 2σ, ``m`` the mean of
    ``e² / σ²``.
    """
    cost = 0.0
    for key, f in summary.items():
        if key[1] == 'all':
            continue
        cost += ((f['within_2sigma'] - TARGET_FRACTION) / FRACTION_SCALE) ** 2
        cost += (math.log(f['mean_z2'] / TARGET_MEAN) / MEAN_SCALE) ** 2
    return cost


def bound_margin(figures):
    """
    How deep a row's two figures lie inside the coverage bounds: the smaller of the two.

    The fraction within 2σ on a linear scale, the mean of ``e² / σ²`` on a
    log scale, each as a share of its range: 0.5 in the middle of both, 0 on
    a bound, negative outside.
    """
    lo, hi = FRACTION_RANGE
    mlo, mhi = MEAN_RANGE
    f, m = figures['within_2sigma'], figures['mean_z2']
    inside = min(f - lo, hi - f) / (hi - lo)
    centred = min(math.log(m / mlo), math.log(mhi / m)) / math.log(mhi / mlo)
    return min(inside, centred)


def choose_heading_floor(trials, runs, groups, floors, start=None, ahrs_params=None):
    """
    The ``heading_floor`` whose heading rows lie deepest inside the bounds.

    For each candidate the logged runs are replayed with it (the other
    parameters at ``start``), and the smallest :func:`bound_margin` over the
    heading rows is kept; the candidate with the largest wins. Pass the tuning
    trials only (:func:`ext_observer.broad.split.tuning_trials`): the held-out
    ones judge the result.

    Returns
    -------
    floor : float
    margins : dict
        ``{candidate: smallest margin}``.

    """
    base = dict(start or UncertaintyParams.DEFAULTS)
    replayed = replayed_summary(trials, runs, groups, ahrs_params)
    margins = {}
    for floor in floors:
        summary = replayed(dict(base, heading_floor=floor))
        margins[floor] = min(bound_margin(f) for key, f in summary.items()
                             if key[1] != 'all' and key[3] == 'heading')
    return max(margins, key=margins.get), margins


def replayed_summary(trials, runs, groups, ahrs_params=None):
    """
    Return ``summary(values)``: :func:`summarize` of the runs replayed with other parameters.

    ``values`` is a dict of :class:`UncertaintyParams` values; the runs are
    those of ``trials`` in ``runs`` (``{mode: {trial name: run}}``).
    """
    keys = [(m, t.name) for m in runs for t in trials if t.name in runs[m]]
    logged = [runs[m][name] for m, name in keys]

    def summary(values):
        out = replay(logged, UncertaintyParams(**values), ahrs_params)
        variances = {m: {} for m in runs}
        for (m, name), v in zip(keys, out):
            variances[m][name] = v
        return summarize(trials, runs, groups, variances)

    return summary


def tune(trials, runs, groups, names, start=None, factors=(0.7, 0.85, 1.2, 1.4), rounds=2,
         ahrs_params=None, progress=None):
    """
    Coordinate search of some :class:`UncertaintyParams` on logged runs.

    Each round tries every factor on each name in turn and keeps what lowers
    :func:`tuning_cost`. Pass the tuning trials only
    (:func:`ext_observer.broad.split.tuning_trials`): the held-out ones judge
    the result.

    Parameters
    ----------
    trials : list of Trial
    runs : dict
        ``{mode: {trial name: run}}`` (:func:`run_all`).
    groups : dict
    names : sequence of str
        The parameters searched; the others keep their ``start`` values.
    start : dict, optional
        Default: :attr:`UncertaintyParams.DEFAULTS`.

    Returns
    -------
    values : dict
    cost : float

    """
    values = dict(start or UncertaintyParams.DEFAULTS)
    replayed = replayed_summary(trials, runs, groups, ahrs_params)

    def cost(candidate):
        return tuning_cost(replayed(candidate))

    best = cost(values)
    for _ in range(rounds):
        for name in names:
            for factor in factors:
                candidate = dict(values, **{name: values[name] * factor})
                c = cost(candidate)
                if c < best:
                    best, values = c, candidate
            if progress:
                progress(f'  {name} = {values[name]:.4g} (cost {best:.3f})')
    return values, best
