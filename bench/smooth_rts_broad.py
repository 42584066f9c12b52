"""
The smoothed attitude (:func:`~ext_observer.core.ahrs.smoother_rts.smooth_attitude_rts`) on BROAD.

Scores each trial as ``python -m ext_observer broad`` does (the RMSEs of
:mod:`ext_observer.broad.scoring`, over the ``movement`` samples), 9D and
6D, and prints the means over the tuning and the held-out trials
(:mod:`ext_observer.broad.split`) and over all, beside the online and the
offline VQF figures, with the mean ``e²/σ²`` of the smoothed covariance
(inclination against ``2 V_t``, heading against ``V_h``) and the time
against the online estimator's::

    .venv/bin/python bench/smooth_rts_broad.py --data ../shared/broad
    .venv/bin/python bench/smooth_rts_broad.py --set mag_sigma=0.1 --set velocity_tau=2

``--cache FILE`` keeps each trial's online calibration (the first pass) between runs;
``--other`` scores :func:`~ext_observer.core.ahrs.smoother.smooth_attitude`'s estimate
instead, with this smoother's covariance (whether it could serve that estimate).
"""

import argparse
import json
import os
import pickle
import sys
import time

import numpy as np

from ext_observer.broad.data import data_dir, find_trials, load_trials
from ext_observer.broad.scoring import error_angles, score
from ext_observer.broad.split import split_of
from ext_observer.core.ahrs.ahrs_observer import AhrsObserver
from ext_observer.core.ahrs.smoother import smooth_attitude
from ext_observer.core.ahrs.smoother_rts import online_calibration, smooth_attitude_rts

# Means over the BROAD trials of each split and over all 22 (python -m ext_observer
# broad --mode both --anchors VQF "offline VQF" --json X, then averaged per split),
# degrees: 9D the total, 6D the inclination.
REFERENCE = {'ours online': {'tuning': {'9D': 1.606, '6D': 0.668},
                             'held-out': {'9D': 1.456, '6D': 0.766},
                             'all': {'9D': 1.579, '6D': 0.686}},
             'offline VQF': {'tuning': {'9D': 1.936, '6D': 0.492},
                             'held-out': {'9D': 1.335, '6D': 0.595},
                             'all': {'9D': 1.827, '6D': 0.511}}}
KEY = {'9D': 'total_rmse_deg', '6D': 'inclination_rmse_deg'}


def calibrations(trials, cache):
    """Each trial's online calibration ``(b, S, lag)`` (kept in ``cache`` if given)."""
    found = {}
    if cache and os.path.exists(cache):
        with open(cache, 'rb') as f:
            found = pickle.load(f)
    for t in trials:
        if t.name not in found:
            b, s, _, lag = online_calibration(t.gyr, t.acc, t.mag, t.rate)
            found[t.name] = (b, s, lag)
    if cache:
        with open(cache, 'wb') as f:
            pickle.dump(found, f)
    return found


def nees(q, cov, trial):
    """Mean ``e²/σ²`` of the inclination and of the heading over the scored samples."""
    _, heading, inclination = error_angles(q, trial.quat)
    keep = trial.movement & np.isfinite(inclination)
    v_t = 0.5 * (cov[:, 0, 0] + cov[:, 1, 1])
    return (float(np.mean(inclination[keep] ** 2 / (2.0 * v_t[keep]))),
            float(np.mean(heading[keep] ** 2 / cov[keep, 2, 2])))


def run(trials, params, cals, modes, mag_lag=False, other=False):
    rows = []
    for t in trials:
        for mode in modes:
            start = time.perf_counter()
            if mode == '9D':
                b, s, lag = cals[t.name]
                b, s = (np.zeros(3), np.eye(3)) if b is None else (b, s)
                q, cov = smooth_attitude_rts(t.gyr, t.acc, t.mag, t.rate, params,
                                             calibration=(b, s, lag if mag_lag else 0.0))
            else:
                q, cov = smooth_attitude_rts(t.gyr, t.acc, None, t.rate, params)
            seconds = time.perf_counter() - start
            if other:
                # The smoother of smoother.py scored instead, with this one's covariance.
                q, _ = smooth_attitude(t.gyr, t.acc, t.mag if mode == '9D' else None, t.rate)
            s = score(q, t.quat, t.movement)
            rows.append({'trial': t.name, 'mode': mode, 'split': split_of(t.name),
                         'seconds': seconds, 'nees': nees(q, cov, t), **s})
    return rows


def online_seconds(trials):
    """Wall clock of the online estimator (9D) on each trial."""
    total = 0.0
    for t in trials:
        start = time.perf_counter()
        AhrsObserver(use_mag=True).run(t.gyr, t.acc, t.mag, 1.0 / t.rate)
        total += time.perf_counter() - start
    return total


def report(rows, modes):
    print(f'{"":12} {"mode":4} {"smoothed":>9} {"online":>7} {"offVQF":>7} '
          f'{"ratio":>6} {"e²/σ² inc":>9} {"e²/σ² hd":>9}')
    for split in ('tuning', 'held-out', 'all'):
        for mode in modes:
            sel = [r for r in rows if r['mode'] == mode and (split == 'all'
                                                             or r['split'] == split)]
            if not sel:
                continue
            m = float(np.mean([r[KEY[mode]] for r in sel]))
            inc = float(np.mean([r['nees'][0] for r in sel]))
            hd = float(np.mean([r['nees'][1] for r in sel]))
            ref = REFERENCE['offline VQF'][split][mode]
            print(f'{split:12} {mode:4} {m:9.3f} {REFERENCE["ours online"][split][mode]:7.3f} '
                  f'{ref:7.3f} {m / ref:6.3f} {inc:9.2f} '
                  f'{hd if mode == "9D" else float("nan"):9.2f}')


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--data', default=None)
    parser.add_argument('--trials', nargs='*', default=None, help='name patterns')
    parser.add_argument('--split', choices=('tuning', 'held-out', 'all'), default='all')
    parser.add_argument('--mode', choices=('9D', '6D', 'both'), default='both')
    parser.add_argument('--set', action='append', default=[], help='name=value')
    parser.add_argument('--cache', default=None)
    parser.add_argument('--per-trial', action='store_true')
    parser.add_argument('--timing', action='store_true', help='also time the online run')
    parser.add_argument('--json', default=None)
    parser.add_argument('--other', action='store_true',
                        help="score smoother.py's estimate against this covariance instead")
    parser.add_argument('--mag-lag', action='store_true',
                        help="take out the field's lag the online calibration learned")
    args = parser.parse_args(argv)
    params = {k: float(v) for k, v in (s.split('=', 1) for s in args.set)}
    found = find_trials(data_dir(args.data), args.trials)
    trials = load_trials([f for f in found if args.split in ('all', split_of(f[0]))])
    modes = ('9D', '6D') if args.mode == 'both' else (args.mode,)
    cals = calibrations(trials, args.cache) if '9D' in modes else {}
    rows = run(trials, params, cals, modes, args.mag_lag, args.other)
    if args.per_trial:
        for r in rows:
            print(f'{r["trial"]:45} {r["mode"]} {r[KEY[r["mode"]]]:7.3f} '
                  f'nees {r["nees"][0]:6.2f} {r["nees"][1]:6.2f}', file=sys.stderr)
    report(rows, modes)
    smoothing = sum(r['seconds'] for r in rows if r['mode'] == '9D')
    print(f'smoothing 9D: {smoothing:.2f} s (with the first online pass'
          f'{"" if args.cache is None else ", except where cached"})')
    if args.timing:
        print(f'online 9D: {online_seconds(trials):.2f} s')
    if args.json:
        with open(args.json, 'w', encoding='utf-8') as f:
            json.dump({'params': params, 'rows': rows}, f, indent=1)


if __name__ == '__main__':
    main()
