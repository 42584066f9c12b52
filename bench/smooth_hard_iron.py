"""
``python -m bench.smooth_hard_iron``: the smoothed 9D estimate with a hard iron of 2× the field.

Each BROAD trial's field gets an offset of twice its median norm, in a
direction fixed per trial (``numpy.random.default_rng(zlib.crc32(name))``),
added to every sample; the calibration is unknown to the estimator. Scored
over the trial's movement samples (:func:`ext_observer.broad.scoring.score`),
beside the undistorted smoothed figure and the online one, as means over the
tuning and the held-out trials apart (:mod:`ext_observer.broad.split`) and
over all (docs/offline.md). The calibration fitted on the whole recording
that was measured against it (``--calibration fit``) is in commit 5a296f0.

Beside each trial, how much its body turns the field: the spread (rad) of
the body-frame direction of a field fixed in the world, along the two
narrowest of its three principal axes (from the optical reference). A hard
iron is a constant in the body frame: only turning the field in the body
tells it from the field, so the means are also given over the trials whose
body turns (:data:`TURNING`) and those whose body hardly does.
"""

import argparse
import json
import sys
import zlib

import numpy as np

__all__ = ['field_spread', 'hard_iron', 'main', 'trial_figures']

# The offset's norm, in units of the trial's field norm.
HARD_IRON = 2.0
# rad: a trial whose field's body-frame direction spreads this much along its
# second-narrowest axis turns its body (BROAD: 0.38 or more where it rotates,
# 0.21 or less in the translation trials).
TURNING = 0.3


def hard_iron(name, mag, factor=HARD_IRON):
    """The trial's offset (3,): ``factor`` × its median field norm, direction from its name."""
    rng = np.random.default_rng(zlib.crc32(name.encode()))
    direction = rng.normal(size=3)
    direction /= np.linalg.norm(direction)
    norm = np.linalg.norm(mag, axis=1)
    return factor * float(np.median(norm[np.isfinite(norm)])) * direction


def field_spread(trial):
    """
    rad (2,): how far the body turns a world-fixed field, along the two narrowest axes.

    The field's world direction is the mean of the first 2000 scored samples
    turned by the optical reference; its body-frame direction at every scored
    sample spreads by the square roots of its covariance's eigenvalues.
    """
    from ext_observer.core.quaternion import rotation_matrices
    ok = np.isfinite(trial.quat).all(axis=1) & trial.movement.astype(bool)
    r = rotation_matrices(trial.quat[ok] / np.linalg.norm(trial.quat[ok], axis=1, keepdims=True))
    world = np.einsum('nij,nj->ni', r[:2000], trial.mag[ok][:2000]).mean(axis=0)
    body = np.einsum('nji,j->ni', r, world / np.linalg.norm(world))
    return np.sqrt(np.maximum(np.linalg.eigvalsh(np.cov(body.T)), 0.0))[:2]


def trial_figures(trial):
    """The 9D total error (°) of one trial: online and smoothed, undistorted and hard-iron."""
    from ext_observer.broad.data import Trial
    from ext_observer.broad.run import estimate_ours, smoothed_estimate
    from ext_observer.broad.scoring import score
    mag = trial.mag + hard_iron(trial.name, trial.mag)
    distorted = Trial(trial.name, trial.gyr, trial.acc, mag, trial.quat, trial.movement,
                      trial.rate)
    out = {}
    for label, t in (('undistorted', trial), ('hard_iron', distorted)):
        out[f'smoothed_{label}'] = score(smoothed_estimate(t, True), t.quat,
                                         t.movement)['total_rmse_deg']
    online = estimate_ours([distorted], ['9D'], 'extended')[0]['9D'][trial.name]
    out['online_hard_iron'] = score(online, distorted.quat, distorted.movement)['total_rmse_deg']
    out['spread_rad'] = [float(v) for v in field_spread(trial)]
    return out


def _means(rows, names):
    keys = [k for k in rows[names[0]] if k != 'spread_rad'] if names else ()
    return {k: float(np.mean([rows[n][k] for n in names])) for k in keys}


def main(argv=None):
    parser = argparse.ArgumentParser(prog='python -m bench.smooth_hard_iron', description=__doc__)
    parser.add_argument('--data', default=None, help='BROAD folder (default: as broad finds it)')
    parser.add_argument('--trials', nargs='*', help='trial name patterns (default: all)')
    parser.add_argument('--json', help='write the per-trial figures here')
    return _run(parser.parse_args(argv))


def _run(args):
    from ext_observer.broad.data import data_dir, find_trials, load_trial
    from ext_observer.broad.split import split_of
    rows = {}
    for name, path in find_trials(data_dir(args.data), args.trials):
        rows[name] = trial_figures(load_trial(path, name))
        r = rows[name]
        print(f'{name[:28]:28s} smoothed {r["smoothed_undistorted"]:6.3f}° '
              f'hard iron {r["smoothed_hard_iron"]:6.3f}° '
              f'({r["smoothed_hard_iron"] / r["smoothed_undistorted"]:4.2f}×) '
              f'online {r["online_hard_iron"]:6.2f}° '
              f'spread {r["spread_rad"][0]:.3f}, {r["spread_rad"][1]:.3f} rad', flush=True)
    turning = [n for n in rows if rows[n]['spread_rad'][1] >= TURNING]
    groups = {'tuning': [n for n in rows if split_of(n) == 'tuning'],
              'held-out': [n for n in rows if split_of(n) == 'held-out'],
              'all': list(rows),
              'turning': turning,
              'turning, tuning': [n for n in turning if split_of(n) == 'tuning'],
              'turning, held-out': [n for n in turning if split_of(n) == 'held-out'],
              'hardly turning': [n for n in rows if n not in turning]}
    summary = {}
    for label, names in groups.items():
        if not names:
            continue
        m = _means(rows, names)
        m['ratio'] = m['smoothed_hard_iron'] / m['smoothed_undistorted']
        summary[label] = m
        print(f'{label} ({len(names)}): smoothed {m["smoothed_undistorted"]:.3f}°, '
              f'hard iron {m["smoothed_hard_iron"]:.3f}° ({m["ratio"]:.2f}×), '
              f'online {m["online_hard_iron"]:.1f}°')
    if args.json:
        with open(args.json, 'w', encoding='utf-8') as f:
            json.dump({'trials': rows, 'summary': summary}, f, indent=1)
    return 0


if __name__ == '__main__':
    sys.exit(main())
