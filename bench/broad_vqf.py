"""
VQF doing the BROAD command's work, in one process: ``python -m bench.broad_vqf``.

The yardstick of the BROAD command's whole-process time: what
``python -m ext_observer broad --no-anchors`` does for our estimator, done
for VQF (the ``vqf`` package's C++ core, one process): read the trials with
the command's own reader, estimate each in 9D and 6D, score each estimate as
BROAD does, print one line. ``bench.compiled_kernels`` times both processes whole,
interleaved.
"""

import argparse
import sys


def main(argv=None):
    """Run VQF on the trials of ``--data`` (both modes); return the exit code."""
    parser = argparse.ArgumentParser(prog='python -m bench.broad_vqf')
    parser.add_argument('--data', metavar='DIR', help='as for the broad command')
    args = parser.parse_args(argv)
    from ext_observer.broad import anchor_estimates, data_dir, find_trials, load_trial, score
    trials = [load_trial(path, name) for name, path in find_trials(data_dir(args.data))]
    scores = {}
    for mode in ('9D', '6D'):
        for t in trials:
            q = anchor_estimates('VQF', t.gyr, t.acc, t.mag, t.rate, mode == '9D')
            scores[(mode, t.name)] = score(q, t.quat, t.movement)
    mean = sum(s['total_rmse_deg'] for (m, _), s in scores.items() if m == '9D') / len(trials)
    print(f'VQF: {len(trials)} trials, 9D and 6D; 9D total RMSE, mean {mean:.2f}°')
    return 0


if __name__ == '__main__':
    sys.exit(main())
