"""
The benchmark's text report and JSON (``broad/report.py``): figures as
printed, NaN as null, the details beside the scores.
"""

import json
import math

from ext_observer.broad.report import fmt, text_report, write_json
from ext_observer.broad.result_keys import OURS
from ext_observer.broad.scoring import KEYS

NAME = '04_undisturbed_slow_rotation_with_breaks_A'


def result():
    row = dict(zip(KEYS, (2.0, 1.5, float('nan'))))
    return {'scores': {OURS: {'9D': {NAME: row}, '6D': {NAME: row}}},
            'norms': {'extended': {'9D': {'mean': 1e-4, 'max': 2e-3, 'samples': 3}}},
            'seconds': {OURS: 1.25}}


def groups():
    return {'order': [('all_trials', 0), ('undisturbed', 1)],
            'members': {'all_trials': [NAME], 'undisturbed': [NAME]}}


def test_figures_are_printed_with_their_decimals_and_a_dash_for_none():
    assert fmt(1.23456) == '1.23' and fmt(1.0, 3) == '1.000'
    assert fmt(None) == '–' and fmt(math.nan) == '–' and fmt(math.inf) == '–'


def test_the_report_names_the_trials_commit_and_figures():
    meta = {'trials': [NAME], 'commit': 'abc1234', 'dirty': True}
    text = text_report(result(), groups(), meta)
    lines = text.splitlines()
    assert lines[0] == 'BROAD: 1 trials, commit abc1234 (estimator modified)'
    assert '9D total undis 2.00 / all_t 2.00' in lines[1] and '6D incl all –' in lines[1]
    assert lines[2] == '  |q̂̄q̂ − 1| extended: 9D mean 0.0001 max 0.002'
    assert lines[3] == f'  time: {OURS} 1.2 s'


def test_the_json_holds_the_scores_and_the_details_beside_them(tmp_path):
    path = tmp_path / 'out' / 'broad.json'
    meta = {'trials': [NAME], 'plot_movement': [True], 'commit': 'abc'}
    write_json(str(path), result(), groups(), meta)
    scores = json.loads(path.read_text())
    assert scores[OURS]['9D'][NAME] == dict(zip(KEYS, (2.0, 1.5, None)))
    details = json.loads((tmp_path / 'out' / 'broad_details.json').read_text())
    assert set(details) == {'summary', 'norms', 'seconds', 'groups', 'meta'}
    assert details['meta'] == {'trials': [NAME], 'commit': 'abc'}
    assert details['groups']['order'] == [['all_trials', 0], ['undisturbed', 1]]
