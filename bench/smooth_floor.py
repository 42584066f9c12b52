"""
``python -m bench.smooth_floor``: where the smoothed 6D inclination's error on BROAD comes from.

Per trial, over its movement samples: the inclination error of our smoothed
estimate and of offline VQF's (and over the rest phases that BROAD does not
score, where the estimate is the specific force's direction; the tilt there
between that direction and the reference's vertical, start and end apart,
:func:`rest_tilt`), and the RMS angle between the two estimates' verticals
(two estimators that agree far better with each other than with the truth
share the rest of their error). Each error is then split into a fixed tilt
between the estimate's body frame and the reference's (one rotation per
trial, :func:`constant_tilt`: BROAD's scoring aligns no frames,
docs/offline.md) and the rest, and the rest into frequency bands
(:func:`band_rms`). ``--delay`` reads the reference that many seconds
earlier (BROAD's timing, docs/offline.md). Means over the tuning and the
held-out trials apart (:mod:`ext_observer.broad.split`). The body-frame
vertical of an attitude ``q`` (sensor → world) is ``R(q)ᵀ z``; the
inclination error of two attitudes is the angle between their verticals.
"""

import argparse
import json
import math
import sys

import numpy as np

__all__ = ['angles', 'band_rms', 'BANDS', 'constant_tilt', 'lag_disagreement', 'main',
           'reference_earlier', 'rest_tilt', 'trial_figures', 'verticals']

# Hz, the bands' edges, high to low: above 5, 1–5, 0.1–1 and below 0.1 Hz.
BANDS = (5.0, 1.0, 0.1)
# Samples: the lags of lag_disagreement in the report (1 sample to 2 s at 286 Hz).
LAGS = (1, 14, 57, 286, 571)


def verticals(q):
    """The body-frame vertical (N, 3) of attitudes ``q`` (N, 4), sensor → world."""
    from ext_observer.core.quaternion import rotation_matrices
    return rotation_matrices(np.asarray(q, dtype=float))[:, 2, :]


def angles(a, b):
    """rad (N,): the angle between the rows of ``a`` and ``b`` (N, 3)."""
    return np.arctan2(np.linalg.norm(np.cross(a, b), axis=1), np.einsum('ij,ij->i', a, b))


def constant_tilt(est, ref):
    """
    The rotation ``M`` (3, 3) minimizing ``Σ |est_k − M ref_k|²``: a fixed tilt between frames.

    ``est``, ``ref`` (N, 3): body-frame verticals of an estimate and of the
    reference. Kabsch's solution (an SVD of ``Σ est ref ᵀ``).
    """
    u, _, vt = np.linalg.svd(np.asarray(est).T @ np.asarray(ref))
    d = np.sign(np.linalg.det(u @ vt))
    return u @ np.diag([1.0, 1.0, d]) @ vt


def band_rms(error, rate, keep, edges=BANDS):
    """
    deg: the RMS over ``keep`` of each band of ``error`` (N, 3), high to low (len(edges) + 1).

    Each band is the difference of two zero-phase low-passes (the
    smoother's Gaussian-like window of σ = 1 / (2π f) for a cut-off ``f``
    Hz); the last, what stays below the lowest edge. ``error``: a small
    rotation vector per sample (rad), 0 where the reference is missing.
    """
    from ext_observer.core.ahrs.smooth_windows import average
    out = []
    rest = np.asarray(error, dtype=float)
    ones = np.ones(len(rest))
    for f in edges:
        low = average(rest, ones, rate / (2.0 * math.pi * f))
        out.append(_rms_deg(np.linalg.norm(rest - low, axis=1)[keep]))
        rest = low
    out.append(_rms_deg(np.linalg.norm(rest, axis=1)[keep]))
    return out


def lag_disagreement(q_est, q_ref, lag, keep):
    """
    deg: RMS angle between the estimate's and the reference's rotations over ``lag`` samples.

    ``q_k⁻¹ ⊗ q_{k+lag}`` of each; over the pairs whose both samples are in
    ``keep`` and where the reference is finite.
    """
    from ext_observer.core.quaternion import conjugate, multiply
    a = multiply(conjugate(q_ref[:-lag]), q_ref[lag:])
    b = multiply(conjugate(q_est[:-lag]), q_est[lag:])
    d = multiply(conjugate(a), b)
    e = 2.0 * np.arctan2(np.linalg.norm(d[:, 1:], axis=1), np.abs(d[:, 0]))
    use = keep[:-lag] & keep[lag:] & np.isfinite(e)
    return _rms_deg(e[use])


def rest_tilt(acc, v_ref, still):
    """
    deg (3,), or None: the mean of ``v_ref × f̂`` over ``still``, body frame.

    The tilt between the specific force's direction and the reference's
    vertical over a rest phase: a constant of the sensor (its bias or its
    axes' misalignment) is the same at every rest of the same attitude.
    """
    if np.count_nonzero(still) == 0:
        return None
    f = acc[still] / np.linalg.norm(acc[still], axis=1, keepdims=True)
    return np.degrees(np.cross(v_ref[still], f).mean(axis=0)).tolist()


def reference_earlier(q, rate, delay):
    """
    ``q`` (N, 4) read ``delay`` s earlier: ``q(t − delay)``, NaN where a neighbour is NaN.

    The normalized linear interpolation between the two samples around;
    held at the first sample.
    """
    q = np.asarray(q, dtype=float)
    n = len(q)
    at = np.clip(np.arange(n) - delay * rate, 0.0, n - 1.0)
    lo = np.minimum(np.floor(at).astype(np.int64), n - 2)
    frac = (at - lo)[:, None]
    a, b = q[lo], q[lo + 1]
    b = np.where(np.einsum('ij,ij->i', a, b)[:, None] < 0.0, -b, b)
    out = (1.0 - frac) * a + frac * b
    return out / np.linalg.norm(out, axis=1, keepdims=True)


def _rms_deg(x):
    return math.degrees(math.sqrt(float(np.mean(np.square(x))))) if len(x) else float('nan')


def trial_figures(trial, delay=0.0):
    """The figures of one trial (dict, degrees): see the module's docstring."""
    from ext_observer.broad.anchors import anchor_estimates
    from ext_observer.broad.result_keys import OFFLINE_VQF
    from ext_observer.broad.run import smoothed_estimate
    ref = reference_earlier(trial.quat, trial.rate, delay) if delay else trial.quat
    keep = np.asarray(trial.movement, dtype=bool) & np.isfinite(ref).all(axis=1)
    v_ref = verticals(np.nan_to_num(ref))
    estimates = {'ours': smoothed_estimate(trial, False),
                 'offline_vqf': anchor_estimates(OFFLINE_VQF, trial.gyr, trial.acc, trial.mag,
                                                 trial.rate, False)}
    v = {k: verticals(q) for k, q in estimates.items()}
    out = {'agree': _rms_deg(angles(v['ours'], v['offline_vqf'])[keep])}
    still = ~np.asarray(trial.movement, dtype=bool) & np.isfinite(ref).all(axis=1)
    for key, v_est in v.items():
        out[key] = _rms_deg(angles(v_est, v_ref)[keep])
        out[f'{key}_at_rest'] = _rms_deg(angles(v_est, v_ref)[still])
        m = constant_tilt(v_est[keep], v_ref[keep])
        out[f'{key}_constant'] = math.degrees(math.acos(min(1.0, (np.trace(m) - 1.0) / 2.0)))
        v_turned = v_ref @ m.T
        out[f'{key}_rest'] = _rms_deg(angles(v_est, v_turned)[keep])
        error = np.where(keep[:, None], np.cross(v_turned, v_est), 0.0)
        for name, value in zip(_band_names(), band_rms(error, trial.rate, keep)):
            out[f'{key}_{name}'] = value
    first_move = int(np.argmax(trial.movement)) if np.any(trial.movement) else len(ref)
    for end, part in (('start', slice(0, first_move)), ('end', slice(first_move, None))):
        out[f'rest_tilt_{end}'] = rest_tilt(trial.acc[part], v_ref[part], still[part])
    for lag in LAGS:
        out[f'lag_{lag}'] = lag_disagreement(estimates['ours'], ref, lag, keep)
    return out


def _xy(tilt):
    return '-' if tilt is None else f'({tilt[0]:+.2f}, {tilt[1]:+.2f})°'


def _band_names():
    edges = [f'{e:g}' for e in BANDS]
    return ([f'above_{edges[0]}_hz'] + [f'{lo}_{hi}_hz' for hi, lo in zip(edges, edges[1:])]
            + [f'below_{edges[-1]}_hz'])


def main(argv=None):
    parser = argparse.ArgumentParser(prog='python -m bench.smooth_floor', description=__doc__)
    parser.add_argument('--data', default=None, help='BROAD folder (default: as broad finds it)')
    parser.add_argument('--trials', nargs='*', help='trial name patterns (default: all)')
    parser.add_argument('--delay', type=float, default=0.0,
                        help='s, read the reference this much earlier (default 0)')
    parser.add_argument('--json', help='write the per-trial figures and the means here')
    args = parser.parse_args(argv)
    from ext_observer.broad.data import data_dir, find_trials, load_trial
    from ext_observer.broad.split import split_of
    rows = {}
    for name, path in find_trials(data_dir(args.data), args.trials):
        rows[name] = r = trial_figures(load_trial(path, name), args.delay)
        print(f'{name[:28]:28s} ours {r["ours"]:.3f}° offline VQF {r["offline_vqf"]:.3f}° '
              f'apart {r["agree"]:.3f}° fixed tilt {r["ours_constant"]:.3f}° '
              f'rest {r["ours_rest"]:.3f}° tilt at rest, start / end (x, y) '
              f'{_xy(r["rest_tilt_start"])} / {_xy(r["rest_tilt_end"])}', flush=True)
    summary = {}
    for label in ('tuning', 'held-out', 'all'):
        names = [n for n in rows if label == 'all' or split_of(n) == label]
        if names:
            summary[label] = {k: float(np.mean([rows[n][k] for n in names]))
                              for k in rows[names[0]] if not k.startswith('rest_tilt')}
            print(f'{label} ({len(names)}): ' + ', '.join(
                f'{k} {v:.3f}' for k, v in summary[label].items()))
    if args.json:
        with open(args.json, 'w', encoding='utf-8') as f:
            json.dump({'delay': args.delay, 'trials': rows, 'summary': summary}, f, indent=1)
    return 0


if __name__ == '__main__':
    sys.exit(main())
