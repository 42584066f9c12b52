"""
``python -m bench.smooth_holes``: the smoothed estimate with samples lost or clipped, on BROAD.

For each dev trial (:mod:`ext_observer.broad`), the smoothed estimate
(:func:`~ext_observer.core.ahrs.smoother.smooth_attitude`) of

- ``full``: every sample (``times`` of the trial's rate);
- ``random``: 40 % of the samples lost at random (a fixed seed per trial,
  ``numpy.random.default_rng(zlib.crc32(name))``), the kept ones at their
  true times;
- ``burst``: 200 ms lost every 2 s (the first 200 ms of each 2 s);
- ``field``: every sample, the field only on every 4th one and lost from
  30 to 40 s of every 60 s (NaN rows; 9D);
- ``clipped``: every sample, the gyro clipped at ±250 °/s (robustness
  variant e, :func:`ext_observer.broad.stress.clip_gyro`; BROAD's range
  given as ``gyro_range``);

9D and 6D, scored as BROAD does (:func:`ext_observer.broad.scoring.score`)
over the kept movement samples, the mean over the tuning trials and over
the held-out ones apart (:mod:`ext_observer.broad.split`). ``--other``
scores our online estimator or an anchor instead, on the full and clipped
recordings. Settings of
:class:`~ext_observer.core.ahrs.smoother.SmoothParams` can be changed with
``--set name=value`` (for measuring the options).
"""

import argparse
import json
import sys
import zlib

import numpy as np

__all__ = ['lost', 'main', 'measure']

CASES = ('full', 'random', 'burst', 'field', 'clipped')
FIELD = (4, 30.0, 40.0, 60.0)  # a field every 4th sample; none from 30 to 40 s of every 60 s
LOST_SHARE = 0.4
BURST = (0.2, 2.0)  # s lost, every s


def lost(name, n, rate, case):
    """The samples kept (bool, N) of a trial of ``n`` samples at ``rate`` Hz."""
    if case == 'random':
        keep = np.random.default_rng(zlib.crc32(name.encode())).random(n) >= LOST_SHARE
    elif case == 'burst':
        keep = np.mod(np.arange(n) / rate, BURST[1]) >= BURST[0]
    else:
        keep = np.ones(n, dtype=bool)
    keep[0] = True
    return keep


def measure(trial, case, use_mag, params=None, other=None):
    """
    The scores of one trial's case: ``{total_rmse_deg, ...}``.

    ``other``: ``'online'`` (our online estimator) or an anchor's name
    (:func:`~ext_observer.broad.anchors.anchor_estimates`, the clipped
    case with the clipped range given) instead of the smoothed estimate;
    at the trial's rate, so for the full and clipped cases only.
    """
    from ext_observer.broad.anchors import anchor_estimates, BROAD_GYRO_RANGE
    from ext_observer.broad.scoring import score
    from ext_observer.broad.stress import clip_gyro, GYRO_RANGE
    from ext_observer.core.ahrs.ahrs_observer import AhrsObserver
    from ext_observer.core.ahrs.smoother import smooth_attitude, SmoothParams
    from ext_observer.pipeline.batch import hold_finite
    p = params if params is not None else SmoothParams()
    if case == 'clipped':
        trial = clip_gyro(trial)
    n = len(trial)
    keep = lost(trial.name, n, trial.rate, case)
    gyr = hold_finite(np.asarray(trial.gyr, dtype=float))[keep]
    acc = hold_finite(np.asarray(trial.acc, dtype=float))[keep]
    mag = hold_finite(np.asarray(trial.mag, dtype=float))[keep] if use_mag else None
    times = np.arange(n)[keep] / trial.rate
    if case == 'field' and mag is not None:
        mag = mag.copy()
        mag[(np.arange(n) % FIELD[0] != 0)
            | ((np.mod(np.arange(n) / trial.rate, FIELD[3]) >= FIELD[1])
               & (np.mod(np.arange(n) / trial.rate, FIELD[3]) < FIELD[2]))] = np.nan
    if other == 'online':
        q = AhrsObserver(p.online, use_mag=use_mag).run(gyr, acc, mag, 1.0 / trial.rate)
    elif other is not None:
        q = anchor_estimates(other, trial.gyr, trial.acc, trial.mag, trial.rate, use_mag,
                             GYRO_RANGE if case == 'clipped' else BROAD_GYRO_RANGE)
    else:
        q, _ = smooth_attitude(gyr, acc, mag, params=p, times=times)
    return score(q, trial.quat[keep], trial.movement[keep])


def _with(p, **changes):
    import dataclasses
    return dataclasses.replace(p, **changes)


def _value(text):
    if text in ('True', 'False'):
        return text == 'True'
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    return text


def main(argv=None):
    parser = argparse.ArgumentParser(prog='python -m bench.smooth_holes', description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('--data', default='../shared/broad', help='BROAD folder')
    parser.add_argument('--cases', nargs='+', choices=CASES, default=list(CASES))
    parser.add_argument('--modes', nargs='+', choices=('9D', '6D'), default=['9D', '6D'])
    parser.add_argument('--trials', nargs='*', help='trial name patterns (default: all)')
    parser.add_argument('--set', nargs='*', default=[], metavar='NAME=VALUE',
                        help='SmoothParams settings changed')
    parser.add_argument('--other', help="'online' (ours) or an anchor ('VQF', 'offline VQF') "
                        'instead of the smoothed estimate (full and clipped only)')
    parser.add_argument('--json', help='write the per-trial scores here')
    args = parser.parse_args(argv)
    from ext_observer.broad.data import find_trials, load_trial
    from ext_observer.broad.split import split_of
    from ext_observer.core.ahrs.smoother import SmoothParams
    params = SmoothParams(**{k: _value(v) for k, v in (s.split('=', 1) for s in args.set)})
    found = find_trials(args.data, args.trials)
    rows = {}
    for name, path in found:
        trial = load_trial(path, name)
        for mode in args.modes:
            for case in args.cases:
                if args.other and case not in ('full', 'clipped'):
                    continue
                rows[(name, mode, case)] = measure(trial, case, mode == '9D', params,
                                                   args.other)
        print(f'{name} done', file=sys.stderr, flush=True)
    key = {'9D': 'total_rmse_deg', '6D': 'inclination_rmse_deg'}
    print(f'{"mode":4} {"case":8} {"tuning":>8} {"held-out":>8} {"all":>8} {"÷ full":>7}')
    for mode in args.modes:
        full = None
        for case in args.cases:
            got = {s: [r[key[mode]] for (nm, m, c), r in rows.items()
                       if m == mode and c == case and (s == 'all' or split_of(nm) == s)]
                   for s in ('tuning', 'held-out', 'all')}
            if not got['all']:
                continue
            mean = {s: float(np.mean(v)) if v else float('nan') for s, v in got.items()}
            full = mean['all'] if case == 'full' else full
            ratio = mean['all'] / full if full else float('nan')
            print(f'{mode:4} {case:8} {mean["tuning"]:8.3f} {mean["held-out"]:8.3f} '
                  f'{mean["all"]:8.3f} {ratio:7.3f}')
    if args.json:
        with open(args.json, 'w', encoding='utf-8') as out:
            json.dump([{'trial': n, 'mode': m, 'case': c, **r}
                       for (n, m, c), r in rows.items()], out, indent=1)


if __name__ == '__main__':
    main()
