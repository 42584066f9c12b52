"""
Which BROAD trials move most when the estimator breaks: the criterion of test_broad_bands.py.

``python mutation/trial_sensitivity.py [--json out/trial_sensitivity.json]``:
the estimator's mutants of mutation/mutants.toml (those in core/ahrs, which
BROAD's scores can see), each applied in a copy of the tree, and the tree
unchanged, run on every BROAD trial in 9D and 6D (``ext_observer.broad.run``,
our estimator only, shipped defaults). Per trial and mutant, the relative
move of the 9D total RMSE and of the 6D inclination RMSE from the unchanged
tree's; a mutant *shows* on a trial when either moves by more than the
band of the test (5 %). Prints, per trial, how many mutants show on it and
the median move, sorted by that; docs/tests.md has the result and the
trials chosen. Takes about a minute per mutant on 2 cores.
"""

import argparse
import json
import os
import subprocess
import sys
import tempfile

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
from run_mutants import apply, copy_tree, environment, load  # noqa: E402

BAND = 0.05
SCORE = r'''
import json, os, sys
from ext_observer import broad
folder = broad.data_dir()
names = [name for name, _ in broad.find_trials(folder)]
trials = [broad.load_trial(path, name) for name, path in broad.find_trials(folder, names)]
result = broad.run(trials, broad.MODES, anchors=(), workers=1, progress=lambda text: None)
ours = result['scores'][broad.OURS]
json.dump({name: [ours['9D'][name]['total_rmse_deg'], ours['6D'][name]['inclination_rmse_deg']]
           for name in names}, sys.stdout)
'''


def scores(mutant=None):
    """``{trial: [9D total, 6D inclination]}`` of the tree with ``mutant`` applied (or none)."""
    with tempfile.TemporaryDirectory(prefix='sensitivity-') as tree:
        copy_tree(tree)
        if mutant is not None:
            apply(mutant, tree)
        env = environment(tree)
        env['EXT_OBSERVER_COMPILED'] = '1'  # compiled from the mutated source (a cold cache)
        done = subprocess.run([sys.executable, '-c', SCORE], cwd=tree, env=env,
                              capture_output=True, text=True)
        if done.returncode != 0 and mutant is not None:
            return None  # the estimator failed (diverged): it shows on every trial
        if done.returncode != 0:
            raise RuntimeError(done.stderr)
        return json.loads(done.stdout)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('--json', help='write every score here')
    args = parser.parse_args(argv)
    mutants = [m for m in load() if m['file'].startswith('ext_observer/core/ahrs/')
               and 'uncertainty' not in m['file']]
    base = scores()
    moves = {}
    for m in mutants:
        got = scores(m)
        moves[m['name']] = {t: [np.inf, np.inf] if got is None else
                            [abs(a / b - 1.0) if np.isfinite(a) else np.inf
                             for a, b in zip(got[t], base[t])] for t in base}
        print(f"{m['name']}: " + ', '.join(f'{t[:2]} {max(v):.0%}' for t, v in
                                           moves[m['name']].items() if max(v) > BAND),
              flush=True)
    rows = []
    for t in base:
        each = [max(moves[name][t]) for name in moves]
        rows.append((sum(v > BAND for v in each), float(np.median(each)), t))
    rows.sort(reverse=True)
    print(f'\ntrial: mutants moving it by more than {BAND:.0%} (of {len(moves)}), median move')
    for shown, median, t in rows:
        print(f'{t}: {shown}, {median:.1%}')
    if args.json:
        with open(args.json, 'w', encoding='utf-8') as f:
            json.dump({'base': base, 'moves': moves}, f, indent=1, default=str)


if __name__ == '__main__':
    main()
