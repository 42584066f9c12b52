"""
``python -m bench.smooth_holes_oracle``: how far 200 ms holes can be bridged, told by the truth.

Oracle experiments on BROAD's dev trials with ``burst`` losses (200 ms lost
every 2 s, :mod:`bench.smooth_holes`); the optical truth is used here only,
never in the estimator:

- ``bridge``: the smoother given the true rotation across each hole (a
  perfect bridge: each hole's steps turn at the constant rate whose
  rotation is the truth's from the sample before the hole to the one
  after it), with the shipped joins and with ``join='none'`` (the bridge
  trusted, the windows across the holes);
- ``stretch``: each stretch's inclination from its own specific force
  turned into the world by the true attitude (the mean over the stretch,
  taken as up): the best a per-stretch average can do; and the same with
  the holes' samples kept (2 s stretches, the full data);
- ``rotation``: per hole, the angle between the truth's rotation across
  it and the straight-line bridge of the rates beside it, and the gyro's
  own integration of the lost samples (what the lost data held);
- ``hole dv``: per hole, the horizontal change of velocity (m/s) that the
  straight-line fill of the force in the world misses (the lost samples'
  force turned by the truth);
- ``true bridge, force``: every sample kept, the gyro in each hole the
  truth's constant rate across it (a perfect bridge with the hole's force
  known).

Each figure is the mean over the tuning trials and over the held-out ones
apart (:mod:`ext_observer.broad.split`), per trial with ``--per-trial``.
"""

import argparse
import math
import sys

import numpy as np

__all__ = ['hole_rotations', 'main', 'stretch_inclination']


def _rotation_vectors(q):
    from ext_observer.core.quaternion import rotation_vector_from_quaternion
    q = np.where(q[:, :1] < 0.0, -q, q)
    good = np.isfinite(q).all(axis=1)
    out = np.full((len(q), 3), np.nan)
    out[good] = rotation_vector_from_quaternion(q[good])
    return out


def _true_turns(quat, before, after):
    """Rotation vectors (G, 3) of the truth's body rotation from ``before`` to ``after``."""
    from ext_observer.core.quaternion import conjugate, multiply
    return _rotation_vectors(multiply(conjugate(quat[before]), quat[after]))


def hole_rotations(trial, keep, bias):
    """
    Per hole: degrees between the truth's rotation and the straight-line bridge's, the lost gyro's.

    ``keep`` (N,): the kept samples; ``bias`` (3,): the gyro bias
    subtracted. Holes whose ends have no truth are skipped.
    """
    from ext_observer.core.ahrs.smooth_strapdown import strapdown
    from ext_observer.core.quaternion import conjugate, multiply
    kept = np.flatnonzero(keep)
    jump = np.flatnonzero(np.diff(kept) > 1)
    before, after = kept[jump], kept[jump + 1]
    ok = np.isfinite(trial.quat[before]).all(axis=1) & np.isfinite(trial.quat[after]).all(axis=1)
    before, after = before[ok], after[ok]
    dt = 1.0 / trial.rate
    gyr = trial.gyr - bias
    line, lost = [], []
    for a, b in zip(before, after):
        true = multiply(conjugate(trial.quat[a]), trial.quat[b])
        steps = b - a
        s = (np.arange(1, steps + 1) / steps)[:, None]
        rates = (1.0 - s) * gyr[a] + s * gyr[b]
        for rate, out in ((rates, line), (gyr[a + 1:b + 1], lost)):
            q = strapdown(rate, np.full(steps, dt), np.array([1.0, 0.0, 0.0, 0.0]))[-1]
            e = multiply(q, conjugate(true))
            out.append(2.0 * math.degrees(math.acos(min(1.0, abs(float(e[0]))))))
    return np.array(line), np.array(lost)


def hole_velocity(trial, keep):
    """
    Per hole: m/s, the horizontal change of velocity the straight-line fill of the force misses.

    The specific force turned into the world by the truth; the change of
    velocity across the hole from the lost samples (trapezoid) against the
    fill's ``h (f_a + f_b) / 2``. Holes with truth missing inside are skipped.
    """
    from ext_observer.core.ahrs.smooth_strapdown import rotate_rows
    good = np.isfinite(trial.quat).all(axis=1)
    q = np.where(good[:, None], trial.quat, np.array([1.0, 0.0, 0.0, 0.0]))
    f = rotate_rows(q / np.linalg.norm(q, axis=1, keepdims=True), trial.acc)
    kept = np.flatnonzero(keep)
    jump = np.flatnonzero(np.diff(kept) > 1)
    dt = 1.0 / trial.rate
    out = []
    for a, b in zip(kept[jump], kept[jump + 1]):
        if not good[a:b + 1].all():
            continue
        true = dt * (0.5 * (f[a] + f[b]) + f[a + 1:b].sum(axis=0))
        line = (b - a) * dt * 0.5 * (f[a] + f[b])
        out.append(float(np.hypot(*(true - line)[:2])))
    return np.array(out)


def stretch_inclination(trial, keep):
    """
    Degrees per sample (N,): the tilt of its stretch's mean specific force in the true world.

    Stretches: the kept samples between two holes; the force turned by the
    truth (samples without truth left out of the mean).
    """
    from ext_observer.core.ahrs.smooth_strapdown import rotate_rows
    good = np.isfinite(trial.quat).all(axis=1)
    q = np.where(good[:, None], trial.quat, np.array([1.0, 0.0, 0.0, 0.0]))
    f = rotate_rows(q / np.linalg.norm(q, axis=1, keepdims=True), trial.acc)
    kept = np.flatnonzero(keep)
    stretch = np.zeros(len(keep), dtype=np.int64)
    stretch[kept[1:][np.diff(kept) > 1]] = 1
    stretch = np.cumsum(stretch)
    use = keep & good
    total = np.zeros((stretch[-1] + 1, 3))
    np.add.at(total, stretch[use], f[use])
    up = total[:, 2] / np.maximum(np.linalg.norm(total, axis=1), np.finfo(float).tiny)
    angle = np.degrees(np.arccos(np.clip(up, -1.0, 1.0)))
    return angle[stretch]


def _rms(x, mask):
    x = x[mask & np.isfinite(x)]
    return float(np.sqrt(np.mean(x * x))) if x.size else float('nan')


def _true_bridge(quat, keep):
    """``bridged`` with each hole's steps at the truth's constant rate across it."""
    from ext_observer.core.ahrs import smooth_holes
    plain = smooth_holes.bridged
    kept = np.flatnonzero(keep)

    def bridged(gyr, axis, p):
        rate, step_dt, rows = plain(gyr, axis, p)
        if isinstance(rows, slice):
            return rate, step_dt, rows
        hole = np.flatnonzero(axis.dt[1:] > smooth_holes.HOLE_FACTOR * axis.usual) + 1
        turns = _true_turns(quat, kept[hole - 1], kept[hole])
        for k, turn in zip(hole, turns):
            if np.isfinite(turn).all():
                steps = rows[k] - rows[k - 1]
                rate[rows[k] - steps + 1:rows[k] + 1] = turn / axis.dt[k]
        return rate, step_dt, rows
    return bridged


def _smoothed(trial, keep, use_mag, params, quat=None):
    from ext_observer.broad.scoring import score
    from ext_observer.core.ahrs import smoother
    from ext_observer.pipeline.batch import hold_finite
    times = np.flatnonzero(keep) / trial.rate
    mag = hold_finite(trial.mag)[keep] if use_mag else None
    plain = smoother.bridged
    if quat is not None:
        smoother.bridged = _true_bridge(quat, keep)
    try:
        q, _ = smoother.smooth_attitude(hold_finite(trial.gyr)[keep], hold_finite(trial.acc)[keep],
                                        mag, params=params, times=times)
    finally:
        smoother.bridged = plain
    return score(q, trial.quat[keep], trial.movement[keep])


def _with_true_rates(trial, keep, use_mag, params):
    """
    Scores with every sample kept, the gyro in each hole the truth's constant rate across it.

    The smoother then holds the truth's rotation across each hole and the
    specific force in it: what a perfect bridge leaves of the holes' loss.
    """
    from ext_observer.broad.scoring import score
    from ext_observer.core.ahrs.smoother import smooth_attitude
    from ext_observer.pipeline.batch import hold_finite
    kept = np.flatnonzero(keep)
    jump = np.flatnonzero(np.diff(kept) > 1)
    before, after = kept[jump], kept[jump + 1]
    turns = _true_turns(trial.quat, before, after)
    gyr = hold_finite(trial.gyr).copy()
    bias = _online_bias(trial, params)
    for a, b, turn in zip(before, after, turns):
        if np.isfinite(turn).all():
            # The bias put back: the smoother removes its own estimate.
            gyr[a + 1:b + 1] = turn * trial.rate / (b - a) + bias
    mag = hold_finite(trial.mag) if use_mag else None
    q, _ = smooth_attitude(gyr, hold_finite(trial.acc), mag, trial.rate, params)
    return score(q, trial.quat, trial.movement & keep)


def _online_bias(trial, params):
    """The gyro bias (3,) the smoother takes: its online pass's at the end (6D, every sample)."""
    from ext_observer.core.ahrs.ahrs_observer import AhrsObserver
    from ext_observer.pipeline.batch import hold_finite
    est = AhrsObserver(params.online, use_mag=False)
    est.run(hold_finite(trial.gyr), hold_finite(trial.acc), None, 1.0 / trial.rate)
    return np.array(est.bias)


def measure(trial):
    """The oracle figures of one trial: ``{name: degrees}``."""
    import dataclasses

    from bench.smooth_holes import lost
    from ext_observer.core.ahrs.smoother import SmoothParams
    p = SmoothParams()
    n = len(trial)
    keep = lost(trial.name, n, trial.rate, 'burst')
    full = np.ones(n, dtype=bool)
    out = {}
    for mode, use_mag, key in (('9D', True, 'total_rmse_deg'),
                               ('6D', False, 'inclination_rmse_deg')):
        out[f'{mode} full'] = _smoothed(trial, full, use_mag, p)[key]
        out[f'{mode} burst'] = _smoothed(trial, keep, use_mag, p)[key]
        out[f'{mode} true bridge'] = _smoothed(trial, keep, use_mag, p, trial.quat)[key]
        out[f'{mode} true bridge, none'] = _smoothed(
            trial, keep, use_mag, dataclasses.replace(p, join='none'), trial.quat)[key]
        out[f'{mode} true bridge, force'] = _with_true_rates(trial, keep, use_mag, p)[key]
    move = trial.movement
    out['6D stretch truth'] = _rms(stretch_inclination(trial, keep), keep & move)
    out['6D 2 s stretch truth'] = _rms(_two_second(trial), move)
    bias = _online_bias(trial, p)
    line, lost_gyro = hole_rotations(trial, keep, bias)
    out['hole line'] = float(np.sqrt(np.mean(line ** 2)))
    out['hole lost gyro'] = float(np.sqrt(np.mean(lost_gyro ** 2)))
    out['hole dv (m/s)'] = float(np.sqrt(np.mean(hole_velocity(trial, keep) ** 2)))
    return out


def _two_second(trial):
    """:func:`stretch_inclination` over 2 s stretches of every sample (holes' samples kept)."""
    n = len(trial)
    keep = np.ones(n, dtype=bool)
    angle = np.empty(n)
    edges = np.flatnonzero(np.mod(np.arange(n) / trial.rate, 2.0) < 1.0 / trial.rate)
    edges = np.concatenate((edges, [n]))
    for lo, hi in zip(edges[:-1], edges[1:]):
        angle[lo:hi] = stretch_inclination(_Part(trial, lo, hi), keep[lo:hi])
    return angle


class _Part:
    def __init__(self, trial, lo, hi):
        self.quat, self.acc = trial.quat[lo:hi], trial.acc[lo:hi]


def main(argv=None):
    parser = argparse.ArgumentParser(prog='python -m bench.smooth_holes_oracle',
                                     description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('--data', default='../shared/broad', help='BROAD folder')
    parser.add_argument('--trials', nargs='*', help='trial name patterns (default: all)')
    parser.add_argument('--per-trial', action='store_true', help='print each trial')
    args = parser.parse_args(argv)
    from ext_observer.broad.data import find_trials, load_trial
    from ext_observer.broad.split import split_of
    rows = {}
    for name, path in find_trials(args.data, args.trials):
        rows[name] = measure(load_trial(path, name))
        print(f'{name} done', file=sys.stderr, flush=True)
    keys = list(next(iter(rows.values())))
    if args.per_trial:
        print('trial ' + ' '.join(f'{k[:11]:>11}' for k in keys))
        for name, r in rows.items():
            print(f'{name[:5]} ' + ' '.join(f'{r[k]:11.3f}' for k in keys))
    print(f'{"figure (°)":24} {"tuning":>8} {"held-out":>8} {"all":>8}')
    for k in keys:
        got = {s: [r[k] for n, r in rows.items() if s == 'all' or split_of(n) == s]
               for s in ('tuning', 'held-out', 'all')}
        print(f'{k:24} ' + ' '.join(f'{np.mean(v):8.3f}' for v in got.values()))


if __name__ == '__main__':
    main()
