"""
Scoring as BROAD does it (its ``example_code/broad_utils.py``).

Both quaternions normalized, ``e = q̂ ⊗ q_ref⁻¹`` (the error in the world
frame), total angle ``2 acos(min(|e_w|, 1))``, heading
``2 atan(|e_z / e_w|)`` (about the world vertical), inclination
``2 acos(min(√(e_w² + e_z²), 1))``; the RMSE of each over the ``movement``
samples, NaN reference samples skipped, in degrees; trials are averaged per
group. Then the averages the done-criteria read
(:func:`summary`, :func:`criteria`).

Quaternions scalar first ``(w, x, y, z)``, sensor → world.
"""

import math

import numpy as np

from ext_observer.broad.result_keys import algorithms_in, OURS
from ext_observer.core.quaternion import conjugate, multiply

KEYS = ('total_rmse_deg', 'heading_rmse_deg', 'inclination_rmse_deg')
# The goal: ours at most this times VQF's average.
VQF_RATIO_GOAL = 1.1
# The others ours should be below on the 9D averages.
OTHERS = ('BasicVQF', 'Madgwick', 'Mahony', 'Fusion')


def error_angles(q_est, q_ref):
    """
    Return BROAD's error angles of ``q_est`` against ``q_ref`` (radians).

    Parameters
    ----------
    q_est, q_ref : array_like, shape (..., 4)
        ``(w, x, y, z)``, sensor → world, any nonzero norm (both are
        normalized first); NaN in ``q_ref`` gives NaN angles.

    Returns
    -------
    total, heading, inclination : ndarray, shape (...)
        Angle of ``e = q̂ ⊗ q_ref⁻¹`` (world frame), of its rotation about
        the world vertical, and of the rest.

    """
    q_est = np.asarray(q_est, dtype=float)
    q_ref = np.asarray(q_ref, dtype=float)
    q_est = q_est / np.linalg.norm(q_est, axis=-1, keepdims=True)
    q_ref = q_ref / np.linalg.norm(q_ref, axis=-1, keepdims=True)
    e = multiply(q_est, conjugate(q_ref))
    w = np.abs(e[..., 0])
    z = np.abs(e[..., 3])
    with np.errstate(invalid='ignore'):
        total = 2.0 * np.arccos(np.clip(w, 0.0, 1.0))
        # 2 atan(|z / w|), also where w = 0.
        heading = 2.0 * np.arctan2(z, w)
        inclination = 2.0 * np.arccos(np.clip(np.sqrt(w * w + z * z), 0.0, 1.0))
    return total, heading, inclination


def rmse_deg(angles, movement=None):
    """RMSE in degrees of ``angles`` (rad) over ``movement``, NaN skipped."""
    angles = np.asarray(angles, dtype=float)
    if movement is not None:
        angles = angles[np.asarray(movement, dtype=bool)]
    finite = angles[np.isfinite(angles)]
    if finite.size == 0:
        return float('nan')
    return math.degrees(math.sqrt(float(np.mean(finite * finite))))


def score(q_est, q_ref, movement):
    """Return ``{total_rmse_deg, heading_rmse_deg, inclination_rmse_deg}``."""
    total, heading, inclination = error_angles(q_est, q_ref)
    return {'total_rmse_deg': rmse_deg(total, movement),
            'heading_rmse_deg': rmse_deg(heading, movement),
            'inclination_rmse_deg': rmse_deg(inclination, movement)}


def norm_deviation(estimates):
    """
    Return the mean and max of ``|q̂̄q̂ − 1|`` over every sample given.

    Parameters
    ----------
    estimates : list of ndarray, shape (N_i, 4)

    """
    return combined_norms([norm_parts(q) for q in estimates])


def norm_parts(q):
    """``(sum, max, count)`` of ``|q̂̄q̂ − 1|`` over one recording's estimates, shape (N, 4)."""
    d = np.abs(np.einsum('ij,ij->i', q, q) - 1.0)
    return float(np.sum(d)), float(np.max(d)) if d.size else float('nan'), int(d.size)


def combined_norms(parts):
    """:func:`norm_deviation` from the :func:`norm_parts` of its recordings."""
    count = sum(n for _, _, n in parts)
    if not count:
        return {'mean': float('nan'), 'max': float('nan'), 'samples': 0}
    return {'mean': sum(s for s, _, _ in parts) / count,
            'max': max(m for _, m, n in parts if n), 'samples': count}


def group_means(scores, groups, key):
    """
    Average one score per group, as BROAD does (mean over the group's trials).

    Parameters
    ----------
    scores : dict
        ``{trial: {key: value}}``.
    groups : dict
        As returned by ``find_groups``.
    key : str

    Returns
    -------
    dict
        ``{group: mean}`` for the groups with at least one scored trial.

    """
    means = {}
    for group, _ in groups['order']:
        values = [scores[t][key] for t in groups['members'][group] if t in scores]
        values = [v for v in values if math.isfinite(v)]
        if values:
            means[group] = float(np.mean(values))
    return means


def summary(result, groups):
    """
    Return the averages the done-criteria use.

    ``{algorithm: {mode: {group: {total_rmse_deg, heading_rmse_deg,
    inclination_rmse_deg}}}}`` for the groups ``all_trials``,
    ``undisturbed`` and ``disturbed``.
    """
    out = {}
    for algorithm in algorithms_in(result):
        out[algorithm] = {}
        for mode, per_trial in result['scores'][algorithm].items():
            out[algorithm][mode] = {}
            for key in KEYS:
                means = group_means(per_trial, groups, key)
                for group in ('all_trials', 'undisturbed', 'disturbed'):
                    if group in means:
                        out[algorithm][mode].setdefault(group, {})[key] = means[group]
    return out


def criteria(summ):
    """
    Return the done-criteria, read off :func:`summary`'s averages.

    Returns
    -------
    list of dict
        One per criterion that has our figure: ``mode``, ``group``,
        ``value`` (ours, degrees), ``vqf`` (VQF's, or None), ``ratio``
        (ours / VQF, or None), ``met`` (``ratio ≤ VQF_RATIO_GOAL``, or
        None); in 9D also ``others`` (the anchors of :data:`OTHERS` run)
        and ``beaten`` (those above ours). 9D total error on the
        undisturbed and on the disturbed average, then 6D inclination over
        all trials.

    """
    ours = summ.get(OURS, {})
    vqf = summ.get('VQF', {})
    others = [a for a in OTHERS if a in summ]
    found = []
    for mode, group, key in (('9D', 'undisturbed', 'total_rmse_deg'),
                             ('9D', 'disturbed', 'total_rmse_deg'),
                             ('6D', 'all_trials', 'inclination_rmse_deg')):
        value = ours.get(mode, {}).get(group, {}).get(key)
        if value is None:
            continue
        reference = vqf.get(mode, {}).get(group, {}).get(key)
        ratio = value / reference if reference else None
        row = {'mode': mode, 'group': group, 'value': value, 'vqf': reference,
               'ratio': ratio, 'met': None if ratio is None else ratio <= VQF_RATIO_GOAL}
        if mode == '9D':
            row['others'] = others
            row['beaten'] = [a for a in others
                             if summ[a].get(mode, {}).get(group, {}).get(key, -1.0) > value]
        found.append(row)
    return found
