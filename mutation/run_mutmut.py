"""
``make mutation``: mutmut over the raw-IMU kernels, calibration, uncertainty and pairing rules.

mutmut (requirements-mutation.txt) mutates every function of the modules
below, one small change at a time, and runs the tests that reach the
changed function (it records which tests call which function first). It
works in a copy of the tree, ``out/mutmut/`` (git ignores ``out/``), kept
between runs so that a second run resumes where the first stopped and only
reruns what changed; the mutmut section of the copy's pyproject.toml is
written here, so the repository carries no mutmut configuration.
The tests run on the plain kernels (``EXT_OBSERVER_COMPILED=0``: numba
would compile mutmut's rewritten source, or not use it).

``python mutation/run_mutmut.py [MODULE ...]`` (default: all of
:data:`MODULES`; a module is a path or its file name) ``--max-children N``
(default 2). The same modules again resume; other modules start afresh. Then ``--report`` prints the score and the survivors of what
has run (``mutmut results``). Each module takes from minutes (the
uncertainty kernel) to hours (the estimator's kernel) on 2 cores: see
docs/tests.md#mutmut for what was measured.
"""

import argparse
import os
import re
import shutil
import subprocess
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(HERE)
sys.path.insert(0, HERE)
from run_mutants import files  # noqa: E402

TREE = os.path.join(REPO, 'out', 'mutmut')
# Module: the tests that check it, fast ones (seconds to a minute, no ROS).
MODULES = {
    'ext_observer/core/ahrs/uncertainty_kernel.py': [
        'test/test_covariance.py', 'test/test_mutants_killed.py'],
    'ext_observer/pipeline/pairing.py': [
        'test/test_pairing.py', 'test/test_mutants_killed.py'],
    'ext_observer/core/ahrs/magcal_filter.py': [
        'test/test_magcal_lag.py', 'test/test_magcal_gate.py', 'test/test_core_magcal.py'],
    'ext_observer/core/ahrs/magcal_kernel.py': [
        'test/test_magcal_lag.py', 'test/test_magcal_gate.py', 'test/test_core_magcal.py'],
    'ext_observer/core/ahrs/ahrs_kernel.py': [
        'test/test_core_ahrs.py', 'test/test_core_ahrs_params.py',
        'test/test_core_ahrs_robust.py', 'test/test_new_field_axes.py',
        'test/test_magcal_lag.py'],
    # The kernel's shared arithmetic and its bias in motion (split from it).
    'ext_observer/core/ahrs/ahrs_filters.py': [
        'test/test_core_ahrs.py', 'test/test_core_ahrs_params.py'],
    'ext_observer/core/ahrs/bias_kernel.py': [
        'test/test_core_ahrs_robust.py', 'test/test_core_ahrs_params.py'],
}
# Tests that start ROS nodes or need numba, BROAD or the benchmark's
# packages are left out of the subsets (minutes each, or not about the
# mutated code): by name.
DESELECT = ('ros_context or spinner or fixed_mode or estimate_mode or diagnostics_before '
            'or benchmark or replay_reproduces or known_distributions')


def prepare(modules):
    """Refresh the copy of the tree and write its mutmut section."""
    os.makedirs(TREE, exist_ok=True)
    for name in files():
        source, target = os.path.join(REPO, name), os.path.join(TREE, name)
        if (not os.path.exists(target)
                or open(source, 'rb').read() != open(target, 'rb').read()):
            os.makedirs(os.path.dirname(target), exist_ok=True)
            shutil.copy2(source, target)
    tests = sorted({t for m in modules for t in MODULES[m]})
    pyproject = os.path.join(TREE, 'pyproject.toml')
    with open(os.path.join(REPO, 'pyproject.toml'), encoding='utf-8') as f:
        text = f.read()
    text = re.sub(r'\n\[tool\.mutmut\].*', '', text, flags=re.S)
    text += ('\n[tool.mutmut]\n'
             'source_paths = ["ext_observer"]\n'
             f'only_mutate = {modules!r}\n'.replace("'", '"')
             + f'pytest_add_cli_args_test_selection = {tests!r}\n'.replace("'", '"')
             + 'pytest_add_cli_args = ["-p", "no:cacheprovider", "-q", "-k", "not ('
             + DESELECT + ')"]\n'
             'also_copy = ["config", "resource", "package.xml", "setup.py"]\n')
    with open(pyproject, 'w', encoding='utf-8') as f:
        f.write(text)
    # mutmut keeps its mutants and its map of which test reaches which
    # function across runs, also when other modules are to be mutated: then
    # it generates none for them, or finds no test for them, and stops
    # (measured). A new set of modules starts afresh (its results lost:
    # report before changing the modules).
    chosen = os.path.join(TREE, '.modules')
    before = (open(chosen, encoding='utf-8').read().strip() if os.path.exists(chosen)
              else None)
    if before != repr(sorted(modules)):
        shutil.rmtree(os.path.join(TREE, 'mutants'), ignore_errors=True)
        with open(chosen, 'w', encoding='utf-8') as f:
            f.write(repr(sorted(modules)))


def environment():
    env = dict(os.environ)
    env['EXT_OBSERVER_COMPILED'] = '0'
    env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    env['PYTHONPATH'] = os.path.join(TREE, 'mutants')
    return env


def mutmut(*args):
    command = [os.path.join(os.path.dirname(sys.executable), 'mutmut'), *args]
    return subprocess.run(command, cwd=TREE, env=environment())


def report():
    """Print mutmut's results of what has run, and the score."""
    out = subprocess.run([os.path.join(os.path.dirname(sys.executable), 'mutmut'), 'results',
                          '--all', 'true'], cwd=TREE, env=environment(),
                         capture_output=True, text=True).stdout
    counts = {}
    survivors = []
    for line in out.splitlines():
        if ':' not in line:
            continue
        name, status = (part.strip() for part in line.rsplit(':', 1))
        counts[status] = counts.get(status, 0) + 1
        if status == 'survived':
            survivors.append(name)
    killed = counts.get('killed', 0) + counts.get('timeout', 0)
    judged = killed + counts.get('survived', 0)
    print(', '.join(f'{k} {v}' for k, v in sorted(counts.items())))
    if judged:
        print(f'score: {killed} of {judged} killed ({100.0 * killed / judged:.1f} %)')
    for name in survivors:
        print(f'survived: {name}')
    return counts


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('modules', nargs='*', help='default: all of MODULES')
    parser.add_argument('--max-children', type=int, default=2)
    parser.add_argument('--report', action='store_true', help='only print the results so far')
    args = parser.parse_args(argv)
    chosen = []
    for given in args.modules or list(MODULES):
        match = [m for m in MODULES if m == given or os.path.basename(m) == given]
        if not match:
            parser.error(f'{given}: not one of {sorted(MODULES)}')
        chosen += match
    if not args.report:
        prepare(chosen)
        mutmut('run', '--max-children', str(args.max_children))
    report()


if __name__ == '__main__':
    main()
