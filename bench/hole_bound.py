"""
What a causal estimator can recover after a burst of lost samples: oracle figures on BROAD.

``python -m bench.hole_bound [--data DIR] [--trials 02 ...] [--json PATH]``
takes the bursts of :mod:`bench.load_batch` (same mask, same seeds; IMU and
field lost together) on every trial and measures, with the optical reference
(``opt_quat``) as the truth:

- the **oracle bridge**: each hole bridged as the estimator does
  (:func:`~ext_observer.core.ahrs.hole_kernel.hole_rate`, one step on the
  straight-line rate, no bias removed) but from the TRUE attitude at the last
  sample before it; its error at the first sample after. Beside it the same
  with the kernel's cubic end turn (:func:`hermite_turn`), and the usual
  steps through the lost samples themselves (what the gyro alone would have
  given: the floor the reference and the gyro allow);
- the **accelerometer window**: the mean over ``[end, end + T]`` of the
  specific force rotated into the world with the TRUE attitude (relative
  rotation perfect): its angle from the true vertical. In 9D, the same for
  the field's horizontal direction against the trial's mean one (undisturbed
  trials only: elsewhere the field has no clean reference);
- the **budget**: the largest time constant ``τ`` of an exponential recovery
  from the bridge's error ``e0`` that keeps the RMS over the kept samples
  within the done-when's bound, and an **oracle blend** (6D): per 10 ms since
  the hole, the best affine blend (weights summing to one, fitted on the truth
  over all holes) of the bridged vertical and the window's vertical;
- the **motion model** (:mod:`bench.hole_predictor`): the lost rates
  predicted by a linear map of the rates beside the hole, fitted on the
  even-numbered trials' gyro and scored on the odd-numbered trials' holes
  (out of sample), integrated by usual steps from the TRUE attitude; its
  error at the first sample after, and the oracle blend with its vertical
  in place of the bridge's.

Holes count where the sample after them is in ``movement``; the blend's RMS
runs over the kept ``movement`` samples, the hole's own error alone (no other
error source). Prints Markdown.
"""

import argparse
import json
import math
import sys

import numpy as np

from bench.hole_predictor import split_even_odd
from bench.load_batch import BURST_PERIOD, CASES as LOSS_CASES, RATIO_BOUND, trial_kept

CASES = ('burst50ms', 'burst200ms')
WINDOWS = (0.05, 0.1, 0.16, 0.25, 0.5, 1.0)  # s after the hole
BIN = 0.01  # s: the blend's time step
# The full-data figures the bound is a multiple of (docs/broad.md, 22 dev
# trials): 9D total, 6D inclination, degrees.
FULL_ERROR = {'9D': 1.58, '6D': 0.69}
TAU_RANGE = (1e-4, 1e3)  # s: where the budget's τ is looked for
BISECTIONS = 100
UP = np.array([0.0, 0.0, 1.0])
BURST = {name: length for name, kind, length in LOSS_CASES if kind == 'burst'}  # s


def rotate(q, v):
    """Vectors ``v`` (..., 3) rotated by the unit quaternions ``q`` (..., 4), sensor → world."""
    w, u = q[..., :1], q[..., 1:]
    c = np.cross(u, v)
    return v + 2.0 * w * c + 2.0 * np.cross(u, c)


def holes(keep):
    """Index pairs ``(last kept before, first kept after)`` of each run of lost samples."""
    lost = np.flatnonzero(np.diff(keep.astype(int)) == -1)
    back = np.flatnonzero(np.diff(keep.astype(int)) == 1) + 1
    if len(back) and len(lost) and back[0] <= lost[0]:
        back = back[1:]
    n = min(len(lost), len(back))
    return lost[:n], back[:n]


def oracle_bridge(q0, g0, g1, dt, period):
    """The estimator's bridge across ``dt`` s from the attitude ``q0``, rates ``g0`` and ``g1``."""
    from ext_observer.core.ahrs.ahrs_layout import A_SIZE, C_DT, S_GYR_LAST
    from ext_observer.core.ahrs.hole_kernel import hole_rate
    from ext_observer.core.quaternion import multiply, quaternion_from_rotation_vector
    s = np.zeros(A_SIZE)
    s[C_DT] = period
    s[S_GYR_LAST:S_GYR_LAST + 3] = g0
    rate = np.array(hole_rate(s, g1[0], g1[1], g1[2], dt))
    return multiply(q0, quaternion_from_rotation_vector(rate * dt))


def hermite_turn(q, g, i0, i1, period):
    """
    ``q`` turned (body frame) by the cubic bridge's extra rotation ``T² (m₀ − m₁) / 12``.

    The slopes ``m`` from the samples beside the hole (the kernel's end
    correction, :func:`~ext_observer.core.ahrs.hole_kernel.hole_end_fix`,
    which it applies to holes up to 0.1 s only).
    """
    from ext_observer.core.ahrs.hole_kernel import HOLE_HERMITE_DIVISOR
    from ext_observer.core.quaternion import multiply, quaternion_from_rotation_vector
    dt = (i1 - i0) * period
    slopes = (g[i0] - g[i0 - 1]) - (g[i1 + 1] - g[i1])
    return multiply(q, quaternion_from_rotation_vector(dt * dt * slopes
                                                       / (HOLE_HERMITE_DIVISOR * period)))


def gyro_through(q0, gyr, period):
    """The attitude after usual steps from ``q0``, each with its closing sample's rate ``gyr``."""
    from ext_observer.core.quaternion import multiply, quaternion_from_rotation_vector
    q = q0
    for g in gyr:
        q = multiply(q, quaternion_from_rotation_vector(g * period))
    return q


def window_sums(vectors, start, count):
    """Running sums of ``vectors[start : start + count]`` (samples without truth skipped)."""
    v = vectors[start:start + count]
    return np.cumsum(np.where(np.isfinite(v), v, 0.0), axis=0)


def window_directions(vectors, start, count):
    """Unit means of :func:`window_sums` (NaN while no sample had a reference)."""
    sums = window_sums(vectors, start, count)
    with np.errstate(invalid='ignore'):
        return sums / np.linalg.norm(sums, axis=1, keepdims=True)


def angle_from_up(v):
    """Angles (rad) of the unit vectors ``v`` (..., 3) from the world vertical."""
    return np.arctan2(np.linalg.norm(v[..., :2], axis=-1), v[..., 2])


def trial_holes(trial, case, models=()):
    """
    Per hole after which the body moves: the bridge's errors and the windows' verticals.

    Returns a dict of arrays over the holes: ``bridge``, ``hermite`` and
    ``floor`` (total, heading, inclination, rad: the oracle bridge, it with
    the cubic end turn, the lost samples' own gyro), ``prior_up`` (3: the bridged vertical in true world
    coordinates), ``acc_up`` (holes, bins, 3: the window's vertical per
    :data:`BIN`), ``scored`` (holes, bins: a kept movement sample),
    ``heading`` (holes, bins: the field window's heading error, NaN where
    the field has no clean reference). With ``models``
    (:class:`~bench.hole_predictor.MotionModel`, by name): each one's errors
    (its predicted rates through the hole) under its name, and ``model_up``
    (holes, bins, 3): per bin the vertical of the last model whose input has
    come by then.
    """
    from ext_observer.broad.scoring import error_angles
    from ext_observer.core.quaternion import conjugate
    period = 1.0 / trial.rate
    keep = trial_kept(trial, case)
    before, after = holes(keep)
    bins = int(round(BURST_PERIOD / BIN))
    steps = np.round(np.arange(bins) * BIN * trial.rate).astype(int)
    q = trial.quat / np.linalg.norm(trial.quat, axis=1, keepdims=True)
    acc_w = rotate(q, trial.acc)
    field_ref, field_w = _field_reference(trial, q)
    out = {k: [] for k in ('bridge', 'hermite', 'floor', 'prior_up', 'acc_up', 'scored',
                           'heading', 'model_up')}
    out.update({name: [] for name in models})
    for i0, i1 in zip(before, after):
        last = i1 + steps[-1]
        if not trial.movement[i1] or last >= len(trial) or not np.isfinite(q[[i0, i1]]).all():
            continue
        qb = oracle_bridge(q[i0], trial.gyr[i0], trial.gyr[i1], (i1 - i0) * period, period)
        qf = gyro_through(q[i0], trial.gyr[i0 + 1:i1 + 1], period)
        out['bridge'].append(error_angles(qb, q[i1]))
        out['floor'].append(error_angles(qf, q[i1]))
        out['hermite'].append(error_angles(hermite_turn(qb, trial.gyr, i0, i1, period), q[i1]))
        # The bridged body's vertical, in true world coordinates: R(q_ref) R(q̂)ᵀ up.
        out['prior_up'].append(rotate(q[i1], rotate(conjugate(qb), UP)))
        windows = window_directions(acc_w, i1, steps[-1] + 1)
        out['acc_up'].append(windows[steps])
        stretch = (steps < np.argmin(keep[i1:last + 1]) if not keep[i1:last + 1].all()
                   else np.ones(bins, dtype=bool))
        out['scored'].append(stretch & trial.movement[i1 + steps] & np.isfinite(q[i1 + steps, 0]))
        out['heading'].append(_field_heading(field_w, field_ref, i1, steps))
        if models:
            _model_holes(out, models, trial.gyr, q, i0, i1, steps, period)
    return {k: np.array(v) for k, v in out.items()}


def _model_holes(out, models, gyr, q, i0, i1, steps, period):
    """Each motion model's error at ``i1``, and their vertical per bin (like ``prior_up``)."""
    from ext_observer.broad.scoring import error_angles
    from ext_observer.core.quaternion import conjugate
    up = np.full((len(steps), 3), math.nan)
    for name, model in models.items():
        lost = model.predict(gyr, i0, i1)
        qm = gyro_through(q[i0], np.concatenate([lost, gyr[i1:i1 + 1]]), period)
        out[name].append(error_angles(qm, q[i1]))
        up[steps >= model.reach(int(i1 - i0 - 1)) - 1] = rotate(q[i1], rotate(conjugate(qm), UP))
    out['model_up'].append(up)


def _field_reference(trial, q):
    """The field in the world, and its mean horizontal direction (NaN in a disturbed trial)."""
    from ext_observer.broad.data import groups_from_name
    field_w = rotate(q, trial.mag)
    if 'undisturbed' not in groups_from_name(trial.name):
        return math.nan, field_w
    mean = np.nanmean(field_w, axis=0)
    return math.atan2(mean[1], mean[0]), field_w


def _field_heading(field_w, ref, i1, steps):
    if not math.isfinite(ref):
        return np.full(len(steps), math.nan)
    sums = window_sums(field_w[:, :2], i1, steps[-1] + 1)[steps]
    return np.angle(np.exp(1j * (np.arctan2(sums[:, 1], sums[:, 0]) - ref)))


def blend_weights(prior_up, acc_up, scored):
    """
    The oracle blend's weight of the bridge per bin, fitted on the truth over the scored holes.

    ``h = a h_p + (1 − a) h_a`` of the horizontal parts (small angles) at
    its least squares in each bin (NaN in a bin without a scored hole).
    """
    prior = prior_up if prior_up.ndim == 3 else prior_up[:, None, :]  # (per bin or per hole)
    d = prior[..., :2] - acc_up[..., :2]
    w = (scored & np.isfinite(acc_up[..., 0]))[..., None]
    ha = np.where(w, acc_up[..., :2], 0.0)
    d = np.where(w, d, 0.0)
    spread = np.sum(d * d, axis=(0, 2))
    with np.errstate(invalid='ignore', divide='ignore'):
        return np.where(spread > 0.0, -np.sum(ha * d, axis=(0, 2)) / spread, math.nan)


def blended_angles(prior_up, acc_up, a):
    """The angles (rad) from the vertical of the blend with the bridge's weights ``a`` per bin."""
    prior = prior_up if prior_up.ndim == 3 else prior_up[:, None, :]
    mixed = a[None, :, None] * prior + (1.0 - a[None, :, None]) * acc_up
    return angle_from_up(mixed / np.linalg.norm(mixed, axis=-1, keepdims=True))


def rms_deg(angles, mask=None):
    angles = np.asarray(angles, dtype=float)
    if mask is not None:
        angles = angles[mask]
    angles = angles[np.isfinite(angles)]
    return math.degrees(math.sqrt(np.mean(angles ** 2))) if angles.size else math.nan


def budget_tau(e0s, e_full, ratio, kept):
    """
    Largest ``τ`` (s) of a recovery ``e0 exp(−t/τ)`` keeping the trials' mean ≤ ``ratio e_full``.

    Per trial (its bridge error ``e0`` in ``e0s``), the RMS over ``kept`` s is
    ``√(e_full² + e0² τ (1 − exp(−2 kept / τ)) / (2 kept))``, which grows
    with ``τ`` towards ``√(e_full² + e0²)``; the mean over the trials is held
    to the bound. ``inf`` where even no recovery meets it.
    """
    e0s = np.atleast_1d(np.asarray(e0s, dtype=float))

    def excess(tau):
        g = tau * (1.0 - math.exp(-2.0 * kept / tau)) / (2.0 * kept)
        return np.mean(np.sqrt(e_full ** 2 + e0s ** 2 * g)) - ratio * e_full
    if excess(TAU_RANGE[1]) <= 0.0:
        return math.inf
    lo, hi = TAU_RANGE
    for _ in range(BISECTIONS):
        mid = math.sqrt(lo * hi)
        lo, hi = (mid, hi) if excess(mid) < 0.0 else (lo, mid)
    return lo


def trial_mean(parts, figure):
    """The mean over the trials of ``figure(part)`` (degrees; trials without a figure skipped)."""
    values = np.array([figure(p) for p in parts])
    return float(np.nanmean(values)) if np.isfinite(values).any() else math.nan


def pooled_weights(parts, key):
    """The oracle blend's weights per bin of the vertical ``key`` of all the ``parts``' holes."""
    pool = {k: np.concatenate([p[k] for p in parts]) for k in (key, 'acc_up', 'scored')}
    return blend_weights(pool[key], pool['acc_up'], pool['scored'])


def scored_parts(trials, case, models=()):
    """:func:`trial_holes` of each trial with a hole, with the angles of its windows' verticals."""
    parts = [trial_holes(t, case, models) for t in trials]
    parts = [p for p in parts if len(p['bridge'])]
    for p in parts:
        p['acc'] = angle_from_up(p['acc_up'])
        p['prior'] = np.broadcast_to(angle_from_up(p['prior_up'])[:, None], p['acc'].shape)
    return parts


def case_figures(trials, case):
    """All the figures of one case: per trial over its holes, then the mean over the trials."""
    parts = scored_parts(trials, case)
    weights = pooled_weights(parts, 'prior_up')
    kept = BURST_PERIOD - BURST[case]
    bins_at = {t: int(round(t / BIN)) for t in WINDOWS}

    def kept_rms(angles):
        return trial_mean(parts, lambda p: rms_deg(angles(p), p['scored']))
    fig = {'case': case, 'holes': int(sum(len(p['bridge']) for p in parts)),
           'bridge': [trial_mean(parts, lambda p: rms_deg(p['bridge'][:, k])) for k in range(3)],
           'hermite': [trial_mean(parts, lambda p: rms_deg(p['hermite'][:, k])) for k in range(3)],
           'floor': [trial_mean(parts, lambda p: rms_deg(p['floor'][:, k])) for k in range(3)],
           'acc_window': {t: trial_mean(parts, lambda p: rms_deg(p['acc'][:, b]))
                          for t, b in bins_at.items()},
           'field_window': {t: trial_mean(parts, lambda p: rms_deg(p['heading'][:, b]))
                            for t, b in bins_at.items()},
           'blend_weight': {t: float(weights[b]) for t, b in bins_at.items()},
           'kept_rms_6d': {
               'prior': kept_rms(lambda p: p['prior']),
               'window': kept_rms(lambda p: p['acc']),
               'blend': kept_rms(lambda p: blended_angles(p['prior_up'], p['acc_up'], weights)),
               'blend_per_trial': kept_rms(lambda p: blended_angles(
                   p['prior_up'], p['acc_up'], blend_weights(p['prior_up'], p['acc_up'],
                                                             p['scored'])))}}
    fig['budget'] = {}
    for mode, k in (('9D', 0), ('6D', 2)):
        e0s = [rms_deg(p['bridge'][:, k]) for p in parts]
        tau = budget_tau(e0s, FULL_ERROR[mode], RATIO_BOUND[case], kept)
        at = int(round(tau / BIN)) if tau < kept else None  # (no window beyond the stretch)
        fig['budget'][mode] = {
            'e0': fig['bridge'][k], 'tau': tau,
            'acc_at_tau': math.nan if at is None else trial_mean(
                parts, lambda p: rms_deg(p['acc'][:, at])),
            'field_at_tau': math.nan if at is None else trial_mean(
                parts, lambda p: rms_deg(p['heading'][:, at]))}
    return fig


def held_out_figures(train, test, case):
    """
    The motion models fitted on ``train``'s gyro, scored on ``test``'s holes beside the bridge.

    Per shape (:data:`~bench.hole_predictor.SHAPES`) its error at the first
    sample after (total, heading, inclination) with the ``K`` and ridge the
    training trials chose, and with each ``K`` alone; the 6D oracle blends
    (fitted on ``test``'s truth) of the bridge's and the models' verticals
    with the accelerometer's window, over the kept movement samples.
    """
    from bench.hole_predictor import KS, MotionModel, SHAPES
    models = {shape: MotionModel(train, shape) for shape in SHAPES}
    parts = scored_parts(test, case, models)
    kept = BURST_PERIOD - BURST[case]

    def errors(ps, key):
        return [trial_mean(ps, lambda p: rms_deg(p[key][:, k])) for k in range(3)]
    fig = {'case': case, 'trials': len(test), 'holes': int(sum(len(p['bridge']) for p in parts)),
           'chosen': {s: {n: c for n, c in m.chosen.items()} for s, m in models.items()},
           'per_k': {}, 'kept_rms_6d': {}, 'tau': {}}
    fig.update({key: errors(parts, key) for key in ('bridge', 'hermite', 'floor') + SHAPES})
    for k in KS:
        alone = {shape: MotionModel(train, shape, ks=(k,)) for shape in SHAPES}
        ps = scored_parts(test, case, alone)
        fig['per_k'][k] = {shape: errors(ps, shape) for shape in SHAPES}
    # In sample: fitted on the scored trials themselves, what a linear map could do at best.
    ps = scored_parts(test, case, {shape: MotionModel(test, shape) for shape in SHAPES})
    fig['per_k']['in sample'] = {shape: errors(ps, shape) for shape in SHAPES}
    for key, name in (('prior_up', 'bridge'), ('model_up', 'model')):
        w = pooled_weights(parts, key)
        fig['kept_rms_6d'][name] = trial_mean(parts, lambda p: rms_deg(np.broadcast_to(
            angle_from_up(p[key]).reshape(len(p['acc']), -1), p['acc'].shape), p['scored']))
        fig['kept_rms_6d'][name + '_blend'] = trial_mean(
            parts, lambda p: rms_deg(blended_angles(p[key], p['acc_up'], w), p['scored']))
        fig['kept_rms_6d'][name + '_weight'] = {t: float(w[int(round(t / BIN))]) for t in WINDOWS}
    for mode, k in (('9D', 0), ('6D', 2)):
        fig['tau'][mode] = {key: budget_tau([rms_deg(p[key][:, k]) for p in parts],
                                            FULL_ERROR[mode], RATIO_BOUND[case], kept)
                            for key in ('bridge',) + SHAPES}
    return fig


def _deg(v):
    return '' if not math.isfinite(v) else f'{v:.2f}'


def _ms(tau):
    return '∞' if math.isinf(tau) else f'{1000.0 * tau:.0f} ms' if tau < 1.0 else f'{tau:.3g} s'


def markdown(figures, count):
    """The tables of :func:`case_figures` for each case."""
    titles = {'burst50ms': '50 ms', 'burst200ms': '200 ms'}
    lines = [f'{count} BROAD trials, bursts every {BURST_PERIOD:g} s '
             '(`bench.load_batch`\'s mask); each trial\'s RMS over the holes the body moves '
             'after, then the mean over the trials, degrees. '
             'Command: `python -m bench.hole_bound`.',
             '', '| bursts | holes | oracle bridge: total / heading / incl. '
             '| with the cubic end turn | the lost samples\' own gyro |', '|---|---|---|---|---|']
    for f in figures:
        b, h, g = (' / '.join(f'{v:.2f}' for v in f[k]) for k in ('bridge', 'hermite', 'floor'))
        lines.append(f'| {titles[f["case"]]} | {f["holes"]} | {b} | {h} | {g} |')
    lines += ['', '| bursts | window after the hole, true attitude | '
              + ' | '.join(f'{t:g} s' for t in WINDOWS) + ' |',
              '|---|---|' + '---|' * len(WINDOWS)]
    rows = (('acc_window', 'accelerometer: vertical'),
            ('field_window', 'field: heading (undisturbed trials)'),
            ('blend_weight', 'oracle blend: the bridge\'s weight'))
    for f in figures:
        for key, title in rows:
            lines.append(f'| {titles[f["case"]]} | {title} | '
                         + ' | '.join(_deg(f[key][t]) for t in WINDOWS) + ' |')
    lines += ['', '| bursts | mode | full data | bound | e0 (bridge) | largest τ | '
              'accelerometer window of τ | field window of τ |',
              '|---|---|---|---|---|---|---|---|']
    for f in figures:
        for mode, b in f['budget'].items():
            lines.append(f'| {titles[f["case"]]} | {mode} | {FULL_ERROR[mode]:.2f} '
                         f'| {RATIO_BOUND[f["case"]] * FULL_ERROR[mode]:.2f} | {b["e0"]:.2f} '
                         f'| {_ms(b["tau"])} | {_deg(b["acc_at_tau"])} '
                         f'| {_deg(b["field_at_tau"])} |')
    lines += ['', '| bursts | 6D bound | over the kept movement samples, the hole\'s error alone: '
              'bridge kept | window alone | oracle blend | blend, weights per trial '
              '| √(full² + blend²) |', '|---|---|---|---|---|---|---|']
    for f in figures:
        k = f['kept_rms_6d']
        lines.append(f'| {titles[f["case"]]} | {RATIO_BOUND[f["case"]] * FULL_ERROR["6D"]:.2f} '
                     f'| {k["prior"]:.2f} | {k["window"]:.2f} | {k["blend"]:.2f} '
                     f'| {k["blend_per_trial"]:.2f} '
                     f'| {math.hypot(FULL_ERROR["6D"], k["blend"]):.2f} |')
    return '\n'.join(lines)


def held_out_markdown(figures, count):
    """The tables of :func:`held_out_figures` for each case."""
    from bench.hole_predictor import KS, SHAPES
    titles = {'burst50ms': '50 ms', 'burst200ms': '200 ms'}
    lines = [f'Motion models fitted on the {count[0]} even-numbered trials\' gyro, scored on the '
             f'{count[1]} odd-numbered trials\' holes (the same mask); total / heading / '
             'inclination at the first sample after, degrees.',
             '', '| bursts | holes | straight-line bridge | cubic end turn | motion model, causal '
             '| motion model, two-sided | the lost samples\' own gyro '
             '| K, ridge (causal; two-sided) |',
             '|---|---|---|---|---|---|---|---|']
    for f in figures:
        cells = [' / '.join(f'{v:.2f}' for v in f[k])
                 for k in ('bridge', 'hermite') + SHAPES + ('floor',)]
        chosen = '; '.join(' or '.join(sorted({f'{k}, {r:g}'
                                               for k, r, _ in f['chosen'][s].values()}))
                           for s in SHAPES)
        lines.append(f'| {titles[f["case"]]} | {f["holes"]} | ' + ' | '.join(cells)
                     + f' | {chosen} |')
    lines += ['', '| bursts | K | causal: total / incl. | two-sided: total / incl. |',
              '|---|---|---|---|']
    for f in figures:
        for k in KS + ('in sample',):
            lines.append(f'| {titles[f["case"]]} | {k} | ' + ' | '.join(
                f'{f["per_k"][k][s][0]:.2f} / {f["per_k"][k][s][2]:.2f}' for s in SHAPES) + ' |')
    lines += ['', '| bursts | 6D bound | over the kept movement samples, the hole\'s error alone: '
              'bridge kept | oracle blend with the bridge | motion model kept '
              '| oracle blend with the motion model | √(full² + blend²): bridge; model '
              '| largest τ, 9D; 6D: bridge, two-sided model |',
              '|---|---|---|---|---|---|---|---|']
    for f in figures:
        k, tau = f['kept_rms_6d'], f['tau']
        lines.append(
            f'| {titles[f["case"]]} | {RATIO_BOUND[f["case"]] * FULL_ERROR["6D"]:.2f} '
            f'| {k["bridge"]:.2f} | {k["bridge_blend"]:.2f} | {k["model"]:.2f} '
            f'| {k["model_blend"]:.2f} | {math.hypot(FULL_ERROR["6D"], k["bridge_blend"]):.2f}; '
            f'{math.hypot(FULL_ERROR["6D"], k["model_blend"]):.2f} | '
            + '; '.join(f'{_ms(t["bridge"])}, {_ms(t["two-sided"])}' for t in tau.values())
            + ' |')
    return '\n'.join(lines)


def main(argv=None):
    """Measure; print the Markdown; return 0 (2 without data)."""
    from ext_observer.broad import data_dir, find_trials, load_trial
    parser = argparse.ArgumentParser(prog='python -m bench.hole_bound')
    parser.add_argument('--data', metavar='DIR')
    parser.add_argument('--trials', nargs='*', help='name patterns (default: all)')
    parser.add_argument('--json', metavar='PATH', help='also write the figures there')
    args = parser.parse_args(argv)
    try:
        found = find_trials(data_dir(args.data), args.trials)
    except ValueError as error:
        print(f'error: {error}', file=sys.stderr)
        return 2
    trials = [load_trial(path, name) for name, path in found]
    figures = [case_figures(trials, case) for case in CASES]
    print(markdown(figures, len(trials)))
    train, test = split_even_odd(trials)
    held_out = [held_out_figures(train, test, case) for case in CASES] if train and test else []
    if held_out:
        print('\n' + held_out_markdown(held_out, (len(train), len(test))))
    if args.json:
        with open(args.json, 'w') as out:
            json.dump({'all': figures, 'held_out': held_out}, out, indent=1, default=str)
    return 0


if __name__ == '__main__':
    sys.exit(main())
