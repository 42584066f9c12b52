"""
``make mutation``: mutmut over the raw-IMU kernels, calibration, uncertainty and pairing rules.

mutmut (requirements-mutation.txt) mutates every function of the modules
below, one small change at a time, and runs the tests that reach the
changed function (it records which tests call which function first). It
works in a copy of the tree per module, ``out/mutmut/<module>/`` (git
ignores ``out/``), kept between runs so that a second run of a module
resumes where the first stopped and only reruns what changed, and the
results of each module stay apart; the mutmut section of the copy's pyproject.toml is
written here, so the repository carries no mutmut configuration.
The tests run on the plain kernels (``EXT_OBSERVER_COMPILED=0``: numba
would compile mutmut's rewritten source, or not use it).

``python mutation/run_mutmut.py [MODULE ...]`` (default: all of
:data:`MODULES`; a module is a path or its file name) ``--max-children N``
(default 2). Each module runs in its own copy, one after the other (the
same modules given together share one copy). ``--report`` prints the
score and the survivors of what has run (``mutmut results``), per module.
Each module takes from 4 minutes (the uncertainty kernel) to about 20
(the pairing rules) on 2 cores, about 75 for all: see docs/tests.md#mutmut
for what was measured.
"""

import argparse
import os
import random
import re
import shutil
import subprocess
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(HERE)
sys.path.insert(0, HERE)
from run_mutants import files  # noqa: E402

OUT = os.path.join(REPO, 'out', 'mutmut')
# The raw-IMU kernel's subset: its steps' tests and the observer's (the
# hole's reach its bridge step).
KERNEL_TESTS = [
    'test/core/ahrs/test_ahrs_filters.py', 'test/core/ahrs/test_ahrs_kernel.py',
    'test/core/ahrs/test_hole_kernel.py',
    'test/core/ahrs/test_frames.py', 'test/core/ahrs/test_ahrs_observer.py',
    'test/core/ahrs/test_ahrs_params.py', 'test/core/ahrs/test_ahrs_observer_robust.py']
# Module: the tests that check it, fast ones (seconds to a minute, no ROS).
MODULES = {
    'ext_observer/core/ahrs/uncertainty_kernel.py': [
        'test/test_orientation_covariance.py', 'test/core/ahrs/test_uncertainty.py',
        'test/core/ahrs/test_uncertainty_kernel.py'],
    'ext_observer/pipeline/pairing.py': [
        'test/pipeline/test_pairing.py'],
    # The calibration's filter (its state, prediction and update): its
    # known-answer tests, and the calibration's end to end but the slow.
    'ext_observer/core/ahrs/magcal_filter.py': [
        'test/core/ahrs/test_magcal_filter.py', 'test/core/ahrs/test_magcal.py'],
    # The calibration's steps around the filter (learn, assess, watch, reset):
    # their known-answer tests, and the calibration's fast ones.
    'ext_observer/core/ahrs/magcal_kernel.py': [
        'test/core/ahrs/test_magcal_kernel.py', 'test/core/ahrs/test_magcal.py'],
    # The kernels' vector and matrix helpers: their own tests, and the filter's.
    'ext_observer/core/ahrs/small_matrix.py': [
        'test/core/ahrs/test_small_matrix.py', 'test/core/ahrs/test_magcal_filter.py'],
    # (the calibration's learned lag, in test_magcal.py, is left out: 21 s of
    # the kernel's 99 s under mutmut's trampolines, measured)
    'ext_observer/core/ahrs/ahrs_kernel.py': KERNEL_TESTS,
    # The kernel's steps in their own modules, each with its tests and the
    # kernel's subset, which reaches the steps through the kernel.
    'ext_observer/core/ahrs/field_kernel.py': [
        'test/core/ahrs/test_field_kernel.py', *KERNEL_TESTS],
    'ext_observer/core/ahrs/gravity_kernel.py': [
        'test/core/ahrs/test_gravity_kernel.py', 'test/core/ahrs/test_accel_rejection.py',
        *KERNEL_TESTS],
    'ext_observer/core/ahrs/hole_kernel.py': KERNEL_TESTS,
    'ext_observer/core/ahrs/accel_rejection.py': [
        'test/core/ahrs/test_accel_rejection.py', *KERNEL_TESTS],
    'ext_observer/core/ahrs/velocity_kernel.py': [
        'test/core/ahrs/test_velocity_kernel.py', 'test/core/ahrs/test_accel_rejection.py'],
    # The kernel's shared arithmetic and its bias in motion (split from it).
    'ext_observer/core/ahrs/ahrs_filters.py': [
        'test/core/ahrs/test_ahrs_filters.py', 'test/core/ahrs/test_frames.py',
        'test/core/ahrs/test_ahrs_observer.py', 'test/core/ahrs/test_ahrs_params.py'],
    'ext_observer/core/ahrs/bias_kernel.py': [
        'test/core/ahrs/test_bias_kernel.py', 'test/core/ahrs/test_ahrs_observer_robust.py',
        'test/core/ahrs/test_ahrs_params.py'],
    # Its clipping and rest detection (split from it): the kernel's subset.
    'ext_observer/core/ahrs/clip_and_rest.py': [
        'test/core/ahrs/test_clip_and_rest.py', 'test/core/ahrs/test_ahrs_kernel.py',
        'test/core/ahrs/test_ahrs_observer.py', 'test/core/ahrs/test_ahrs_params.py',
        'test/core/ahrs/test_ahrs_observer_robust.py'],
}
# Tests that start ROS nodes or need numba, BROAD or the benchmark's
# packages are left out of the subsets (minutes each, or not about the
# mutated code): by name.
DESELECT = ('ros_context or spinner or fixed_mode or estimate_mode or diagnostics_before '
            'or benchmark or replay_reproduces or known_distributions'
            # the cases run compiled (numba would compile mutmut's trampolines):
            # parametrized [True] or [compiled...], or named so
            ' or [True] or compiled')
# mutmut runs, per mutant, every test of the subset that reaches the
# mutated function, and a kernel's step is reached by all of them: a
# survivor costs the whole subset. The tests of a subset that take a second
# or more on the plain kernels (long synthetic runs, the paths compared with
# one another, the 25 and 1000 Hz runs) are left out of the runs of the
# kernel and its arithmetic by name (measured, docs/tests.md).
SLOW = ('the_same_defaults_at_25_and_1000_hz or a_constant_bias_is_learned_in_motion_without_rest'
        ' or a_disturbed_field_is_rejected_and_never_tilts'
        ' or 9d_tracks_the_truth_and_learns_the_bias or translation_is_filtered_out'
        ' or float_and_batch_paths_agree or non_finite_samples_of_a_recording_are_held'
        ' or the_extension_term_holds_the_estimate_near_s3 or workers_give_the_vectorized'
        ' or a_lagging_field_is_learned_with_its_delay'
        # numba would compile mutmut's rewritten source; reading files is not the kernel's
        ' or plain_and_compiled_agree or a_bag_with_a_velocity or a_csv_with_velocity')
# (the bias's own module keeps them: its tests in motion are the slow ones)
# The calibration's slow tests (seconds each plain) left out of its modules'
# runs, where faster tests of the same functions stand for them.
MAGCAL_FILTER_SLOW = ('an_offset_that_changes_for_good or calibrate_as_the_node_would'
                      ' or a_lagging_field_is_learned or a_field_without_lag'
                      ' or learns_it_runs_6d or a_world_fixed_disturbance'
                      ' or keeps_its_own_field or broad_excerpt_with_an_offset'
                      ' or a_loaded_calibration_is_used_at_once or forked_paths_agree')
# (one line between: the filter's and the kernel's are chosen apart)
MAGCAL_KERNEL_SLOW = ('an_offset_that_changes_for_good or a_csv_and_a_bag'
                      ' or a_lagging_field_is_learned or a_field_without_lag'
                      ' or the_estimator_learns_it_runs_6d or the_broad_excerpt_with_an_offset'
                      ' or a_world_fixed_disturbance or a_calibrated_sensor_keeps_its_own_field'
                      ' or a_loaded_calibration_is_used_at_once or float_vectorized_and_forked')
# Module: the tests left out of its runs, besides DESELECT.
SLOW_OF = {
    'ext_observer/core/ahrs/ahrs_kernel.py': SLOW,
    'ext_observer/core/ahrs/ahrs_filters.py': SLOW,
    'ext_observer/core/ahrs/clip_and_rest.py': SLOW,
    'ext_observer/core/ahrs/field_kernel.py': SLOW,
    'ext_observer/core/ahrs/gravity_kernel.py': SLOW,
    'ext_observer/core/ahrs/hole_kernel.py': SLOW,
    'ext_observer/core/ahrs/accel_rejection.py': SLOW,
    'ext_observer/core/ahrs/velocity_kernel.py': SLOW,
    'ext_observer/core/ahrs/magcal_filter.py': MAGCAL_FILTER_SLOW,
    'ext_observer/core/ahrs/magcal_kernel.py': MAGCAL_KERNEL_SLOW,
}


def tree_of(modules):
    """The copy of the tree where these modules are mutated."""
    return os.path.join(OUT, '+'.join(sorted(
        os.path.splitext(os.path.basename(m))[0] for m in modules)))


def prepare(modules):
    """Refresh the copy of the tree and write its mutmut section."""
    tree = tree_of(modules)
    os.makedirs(tree, exist_ok=True)
    for name in files():
        source, target = os.path.join(REPO, name), os.path.join(tree, name)
        if (not os.path.exists(target)
                or open(source, 'rb').read() != open(target, 'rb').read()):
            os.makedirs(os.path.dirname(target), exist_ok=True)
            shutil.copy2(source, target)
    tests = sorted({t for m in modules for t in MODULES[m]})
    pyproject = os.path.join(tree, 'pyproject.toml')
    with open(os.path.join(REPO, 'pyproject.toml'), encoding='utf-8') as f:
        text = f.read()
    text = re.sub(r'\n\[tool\.mutmut\].*', '', text, flags=re.S)
    deselect = ' or '.join([DESELECT] + sorted({SLOW_OF[m] for m in modules if SLOW_OF.get(m)}))
    text += ('\n[tool.mutmut]\n'
             'source_paths = ["ext_observer"]\n'
             f'only_mutate = {modules!r}\n'.replace("'", '"')
             + f'pytest_add_cli_args_test_selection = {tests!r}\n'.replace("'", '"')
             + 'pytest_add_cli_args = ["-p", "no:cacheprovider", "-p", "fast_first", "-q", '
             '"-k", "not ('
             + deselect + ')"]\n'
             'also_copy = ["config", "resource", "package.xml", "setup.py"]\n')
    with open(pyproject, 'w', encoding='utf-8') as f:
        f.write(text)
    # mutmut keeps its mutants and its map of which test reaches which
    # function across runs, also when other modules are to be mutated: then
    # it generates none for them, or finds no test for them, and stops
    # (measured). A new set of modules starts afresh (its results lost:
    # report before changing the modules).
    chosen = os.path.join(tree, '.modules')
    before = (open(chosen, encoding='utf-8').read().strip() if os.path.exists(chosen)
              else None)
    if before != repr(sorted(modules)):
        shutil.rmtree(os.path.join(tree, 'mutants'), ignore_errors=True)
        with open(chosen, 'w', encoding='utf-8') as f:
            f.write(repr(sorted(modules)))
    # mutants/ exists before mutmut starts: a directory of PYTHONPATH that is
    # missing when Python starts is never searched by that process (its
    # finder is cached as None), and a first run then finds no test reaching
    # any mutant (measured).
    os.makedirs(os.path.join(tree, 'mutants'), exist_ok=True)


def environment(tree):
    env = dict(os.environ)
    env['EXT_OBSERVER_COMPILED'] = '0'
    env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    # The mutated package first; then fast_first.py, the plugin that orders
    # a mutant's tests.
    env['PYTHONPATH'] = os.pathsep.join([os.path.join(tree, 'mutants'), HERE])
    return env


def mutmut(tree, *args):
    command = [os.path.join(os.path.dirname(sys.executable), 'mutmut'), *args]
    return subprocess.run(command, cwd=tree, env=environment(tree))


def results(tree):
    """mutmut's ``(mutant, status)`` of every mutant of ``tree``."""
    if not os.path.isdir(os.path.join(tree, 'mutants')):
        return []
    out = subprocess.run([os.path.join(os.path.dirname(sys.executable), 'mutmut'), 'results',
                          '--all', 'true'], cwd=tree, env=environment(tree),
                         capture_output=True, text=True).stdout
    return [tuple(part.strip() for part in line.rsplit(':', 1))
            for line in out.splitlines() if ':' in line]


def survivors(tree):
    return [name for name, status in results(tree) if status == 'survived']


def sample(tree, count, max_children=None):
    """``count`` of the module's mutants drawn at random, always the same ones.

    The mutants must exist: with ``max_children``, a first call generates
    them (``mutmut run`` of no mutant that exists: it generates, collects
    the stats, and stops there).
    """
    names = sorted(name for name, _ in results(tree))
    if not names and max_children:
        mutmut(tree, 'run', '--max-children', str(max_children), 'no_such_mutant')
        names = sorted(name for name, _ in results(tree))
    return random.Random(31).sample(names, min(count, len(names)))


def report(tree, names=None):
    """Print mutmut's results of what has run in ``tree`` (of ``names``), and the score."""
    if not os.path.isdir(os.path.join(tree, 'mutants')):
        print(f'{os.path.basename(tree)}: not run')
        return {}
    counts = {}
    chosen = None if names is None else set(names)
    for name, status in results(tree):
        if chosen is None or name in chosen:
            counts[status] = counts.get(status, 0) + 1
    if chosen is not None:
        print(f'a sample of {len(chosen)} mutants (seed 31):')
    killed = counts.get('killed', 0) + counts.get('timeout', 0)
    judged = killed + counts.get('survived', 0)
    print(f'{os.path.basename(tree)}:', ', '.join(f'{k} {v}' for k, v in sorted(counts.items())))
    if judged:
        print(f'score: {killed} of {judged} killed ({100.0 * killed / judged:.1f} %)')
    for name in survivors(tree):
        if chosen is None or name in chosen:
            print(f'survived: {name}')
    return counts


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('modules', nargs='*', help='default: all of MODULES')
    parser.add_argument('--max-children', type=int, default=2)
    parser.add_argument('--report', action='store_true', help='only print the results so far')
    parser.add_argument('--survivors', action='store_true',
                        help='rerun only the survivors of the last run (after adding tests)')
    parser.add_argument('--sample', type=int, metavar='N',
                        help='run only N mutants drawn at random (seed 31) of each module, '
                             'and report their score (of a module too large to run whole)')
    args = parser.parse_args(argv)
    chosen = []
    for given in args.modules or list(MODULES):
        match = [m for m in MODULES if m == given or os.path.basename(m) == given]
        if not match:
            parser.error(f'{given}: not one of {sorted(MODULES)}')
        chosen += match
    for module in chosen:
        tree = tree_of([module])
        if not args.report:
            # Survivors of the last run, before prepare() copies the tests again.
            names = survivors(tree) if args.survivors else []
            prepare([module])
            if args.sample and not args.survivors:
                names = sample(tree, args.sample, args.max_children)
            if not args.survivors or names:
                mutmut(tree, 'run', '--max-children', str(args.max_children), *names)
        report(tree, sample(tree, args.sample) if args.sample else None)


if __name__ == '__main__':
    main()
