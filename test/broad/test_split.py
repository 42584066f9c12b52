"""
The one split of the BROAD trials (``ext_observer/broad/split.py``), and that it stays the only one.

A second rule for which trials tune and which judge drifts from the first
(two did: the even-numbered trials and every other sorted name), so the
source tree is scanned for the shapes such a rule takes outside the module.
"""

import ast
import os
import re

import pytest

from conftest import REPO
from ext_observer.broad import split
from ext_observer.broad.stress_run import half_counts

FOLDER = ['01_undisturbed_slow_rotation_A', '02_undisturbed_slow_rotation_B',
          '09_undisturbed_fast_rotation_with_breaks_B', '11_undisturbed_slow_translation_B',
          '28_disturbed_stationary_magnet_A', '29_disturbed_stationary_magnet_B',
          '35_disturbed_attached_magnet_4cm']


def test_a_trial_is_held_out_when_no_default_was_chosen_on_it():
    assert split.split_of('28_disturbed_stationary_magnet_A') == 'tuning'
    assert split.split_of('09_undisturbed_fast_rotation_with_breaks_B') == 'held-out'
    # A trial that is not in BROAD's folder chose nothing.
    assert split.split_of('07_undisturbed_fast_rotation_B') == 'held-out'
    assert split.split_of('synthetic') is None
    assert split.held_out_trials(FOLDER) == [FOLDER[i] for i in (2, 3, 5, 6)]
    assert split.tuning_trials(FOLDER) == [FOLDER[i] for i in (0, 1, 4)]
    assert half_counts(['01_a', '09_b', '11_c', 'made_up']) == {
        'all': 4, 'tuning': 1, 'held-out': 2}


def test_a_side_does_not_depend_on_the_other_trials_of_a_run():
    alone = [split.split_of(name) for name in FOLDER]
    assert [split.split_of(name) for name in reversed(FOLDER)] == alone[::-1]
    assert split.tuning_trials(FOLDER[2:]) == split.tuning_trials(FOLDER)[2:]


def test_the_trials_of_the_sweep_on_broad_tuning_md_are_tuning_trials():
    with open(os.path.join(REPO, 'docs', 'broad_tuning.md'), encoding='utf-8') as f:
        row = re.search(r'^\| tuning \(11\) \| (.*) \|$', f.read(), re.M).group(1)
    sweep = re.findall(r'\b\d\d\b', row)
    assert len(sweep) == 11 and set(sweep) <= set(split.TUNING)


# --- no second definition --------------------------------------------------

_TRIALISH = re.compile(r'trial|name|number|digit', re.I)
_DEFINITIONS = {'split', 'split_of', 'half_of', 'tuning_trials', 'held_out_trials',
                'trial_number'}


def second_definitions(source):
    """The lines of ``source`` (Python) that hold a rule of the split of their own."""
    found = []
    for node in ast.walk(ast.parse(source)):
        shape = None
        if (isinstance(node, ast.BinOp) and isinstance(node.op, ast.Mod)
                and isinstance(node.right, ast.Constant) and node.right.value == 2
                and _TRIALISH.search(ast.unparse(node.left))):
            shape = 'even/odd trial numbers'
        elif (isinstance(node, ast.Subscript) and isinstance(node.slice, ast.Slice)
              and isinstance(node.slice.step, ast.Constant) and node.slice.step.value == 2
              and _TRIALISH.search(ast.unparse(node.value))):
            shape = 'every other trial'
        elif (isinstance(node, ast.FunctionDef) and node.args.args
              and (node.name.lstrip('_') in _DEFINITIONS or 'even_odd' in node.name)
              and _TRIALISH.search(node.args.args[0].arg)):
            shape = f'a function {node.name}()'
        elif (isinstance(node, (ast.Tuple, ast.List, ast.Set)) and len(node.elts) >= 3
              and all(isinstance(e, ast.Constant) and isinstance(e.value, str)
                      and re.fullmatch(r'\d\d', e.value) for e in node.elts)):
            shape = 'a list of trial numbers'
        elif (isinstance(node, ast.Compare) and any(
                isinstance(c, ast.Constant) and c.value in ('dev', 'report')
                for c in node.comparators)):
            shape = "a split label of its own ('dev', 'report')"
        if shape:
            found.append((node.lineno, shape))
    return found


@pytest.mark.parametrize('source', [
    "def split_of(name):\n    digits = name[:2]\n    return 'dev' if int(digits) % 2 == 0 else 'x'\n",
    "def half_of(name):\n    return 'tuning' if trial_number(name) % 2 == 0 else 'report'\n",
    "even = [t for t in trials if trial_number(t.name) % 2 == 0]\n",
    "def split(names):\n    names = sorted(names)\n    return names[0::2], names[1::2]\n",
    "HELD_OUT = ('09', '11', '29', '35')\n",
])
def test_the_scan_finds_the_rules_the_tree_had(source):
    assert second_definitions(source)


def test_no_rule_of_the_split_is_written_outside_its_module():
    own = {os.path.join('ext_observer', 'broad', 'split.py'),
           os.path.join('test', 'broad', 'test_split.py')}
    found = []
    for top in ('ext_observer', 'bench', 'docgen', 'test', 'mutation'):
        for folder, _, files in os.walk(os.path.join(REPO, top)):
            for file in sorted(f for f in files if f.endswith('.py')):
                path = os.path.join(folder, file)
                if os.path.relpath(path, REPO) in own:
                    continue
                with open(path, encoding='utf-8') as f:
                    found += [f'{os.path.relpath(path, REPO)}:{line}: {shape}'
                              for line, shape in second_definitions(f.read())]
    assert not found, ('the split of the trials is ext_observer.broad.split\'s alone; '
                       'found another:\n' + '\n'.join(found))
