"""
Apply each mutant of mutation/mutants.toml in a copy of the tree and run its tests.

``make mutation-list`` (or ``python mutation/run_mutants.py [NAME ...]``):
for each mutant, the repository's files (tracked and new, not ignored) are
copied to a temporary folder, the mutant's snippet is replaced there, and
its tests run in that copy (``python -m pytest -x``, the copy first on the
path, the plain kernels: ``EXT_OBSERVER_COMPILED=0`` runs the mutated
source as it is, with no compilation of it). A mutant is *killed* when its
tests fail, *survived* when they pass. Every snippet is checked first: one
that is not found exactly once stops the run (exit 2) before anything runs,
so a list that no longer fits the code cannot pass silently.

First the tests of all the mutants run once on the tree as it is, the same
way (they must pass, or a kill would say nothing; ``--no-baseline`` skips
it). Prints one line per mutant and a summary; exits 0 only when every
mutant run was killed. ``--json FILE`` writes the results. Needs BROAD for a test
on real data (the folder the tests would use, passed on).
"""

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
import tomllib

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(HERE)
LIST = os.path.join(HERE, 'mutants.toml')


def load(path=LIST):
    """The mutants: a list of dicts (name, file, original, replacement, why, tests)."""
    with open(path, 'rb') as f:
        mutants = tomllib.load(f)['mutant']
    names = [m['name'] for m in mutants]
    if len(set(names)) != len(names):
        raise ValueError(f'{path}: names repeat')
    return mutants


def check(mutants, root=REPO):
    """Return the problems: each snippet must occur exactly once in its file."""
    problems = []
    for m in mutants:
        path = os.path.join(root, m['file'])
        if not os.path.exists(path):
            problems.append(f"{m['name']}: {m['file']} does not exist")
            continue
        with open(path, encoding='utf-8') as f:
            count = f.read().count(m['original'])
        if count != 1:
            problems.append(f"{m['name']}: its snippet occurs {count} times in {m['file']}")
        for test in m['tests']:
            if not os.path.exists(os.path.join(root, test.split('::')[0])):
                problems.append(f"{m['name']}: no test file {test}")
    return problems


def files(root=REPO):
    """The tree's files: tracked and new ones, not ignored."""
    out = subprocess.run(['git', 'ls-files', '-z', '--cached', '--others', '--exclude-standard'],
                         cwd=root, check=True, capture_output=True).stdout
    return [name for name in out.decode().split('\0') if name and os.path.isfile(
        os.path.join(root, name))]


def copy_tree(dest, root=REPO):
    for name in files(root):
        target = os.path.join(dest, name)
        os.makedirs(os.path.dirname(target), exist_ok=True)
        shutil.copy2(os.path.join(root, name), target)


def apply(mutant, tree):
    path = os.path.join(tree, mutant['file'])
    with open(path, encoding='utf-8') as f:
        text = f.read()
    assert text.count(mutant['original']) == 1, mutant['name']
    with open(path, 'w', encoding='utf-8') as f:
        f.write(text.replace(mutant['original'], mutant['replacement']))


def environment(tree):
    env = dict(os.environ)
    env['PYTHONPATH'] = tree + (os.pathsep + env['PYTHONPATH'] if env.get('PYTHONPATH') else '')
    env['EXT_OBSERVER_COMPILED'] = '0'
    env['EXT_OBSERVER_CACHE'] = os.path.join(tree, '.cache')
    env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    if 'EXT_OBSERVER_BROAD_DATA' not in env:
        sys.path.insert(0, REPO)
        from ext_observer import broad
        try:
            env['EXT_OBSERVER_BROAD_DATA'] = os.path.abspath(broad.data_dir())
        except ValueError:
            pass
    return env


def run_one(mutant, timeout, extra=()):
    """Return ``(outcome, seconds, tail of the output)``: killed, survived, timeout or error."""
    with tempfile.TemporaryDirectory(prefix=f"mutant-{mutant['name']}-") as tree:
        copy_tree(tree)
        if mutant['original'] is not None:
            apply(mutant, tree)
        env = environment(tree)
        # The copy, not the editable install, must be what runs.
        where = subprocess.run([sys.executable, '-c', 'import ext_observer; '
                                'print(ext_observer.__file__)'], cwd=tree, env=env,
                               capture_output=True, text=True).stdout.strip()
        if not where.startswith(tree):
            return 'error', 0.0, f'the copy is not imported ({where})'
        start = time.monotonic()
        try:
            done = subprocess.run([sys.executable, '-m', 'pytest', '-x', '-q',
                                   '-p', 'no:cacheprovider', *extra, *mutant['tests']],
                                  cwd=tree, env=env, capture_output=True, text=True,
                                  timeout=timeout)
        except subprocess.TimeoutExpired:
            return 'timeout', time.monotonic() - start, ''
        seconds = time.monotonic() - start
        tail = '\n'.join((done.stdout + done.stderr).strip().splitlines()[-3:])
        # pytest: 0 all passed, 1 some failed; else an error (collection, usage).
        outcome = {0: 'survived', 1: 'killed'}.get(done.returncode, 'error')
        return outcome, seconds, tail


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('names', nargs='*', help='mutants to run (default: all)')
    parser.add_argument('--list', action='store_true', help='check and list, run nothing')
    parser.add_argument('--timeout', type=float, default=1200.0, help='per mutant (s)')
    parser.add_argument('--json', help='write the results here')
    parser.add_argument('--no-baseline', action='store_true',
                        help='skip the run of the tests on the tree as it is')
    args = parser.parse_args(argv)
    mutants = load()
    problems = check(mutants)
    if problems:
        print('mutants.toml no longer fits the code:\n  ' + '\n  '.join(problems))
        return 2
    if args.names:
        unknown = set(args.names) - {m['name'] for m in mutants}
        if unknown:
            print(f'unknown mutants: {sorted(unknown)}')
            return 2
        mutants = [m for m in mutants if m['name'] in args.names]
    if args.list:
        for m in mutants:
            print(f"{m['name']}: {m['file']} ({' '.join(m['tests'])})")
        return 0
    if not args.no_baseline:
        # The tests must pass on the tree as it is, the same way, or a
        # "kill" says nothing.
        tests = sorted({t for m in mutants for t in m['tests']})
        outcome, seconds, tail = run_one(dict(name='baseline', original=None, tests=tests),
                                         args.timeout)
        verdict = 'pass' if outcome == 'survived' else outcome
        print(f'baseline: the tests on the tree as it is: {verdict} ({seconds:.0f} s)',
              flush=True)
        if outcome != 'survived':
            print('    ' + tail.replace('\n', '\n    '))
            return 2
    results = []
    for m in mutants:
        outcome, seconds, tail = run_one(m, args.timeout)
        results.append(dict(name=m['name'], outcome=outcome, seconds=round(seconds, 1),
                            tests=m['tests'], tail=tail))
        print(f"{outcome:8s} {m['name']} ({seconds:.0f} s)"
              + ('' if outcome == 'killed' else '\n    ' + tail.replace('\n', '\n    ')),
              flush=True)
    killed = sum(r['outcome'] == 'killed' for r in results)
    print(f'{killed} of {len(results)} mutants killed')
    if args.json:
        with open(args.json, 'w', encoding='utf-8') as f:
            json.dump(results, f, indent=1)
    return 0 if killed == len(results) else 1


if __name__ == '__main__':
    sys.exit(main())
