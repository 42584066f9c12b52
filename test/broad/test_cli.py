"""
The command ``python -m ext_observer broad`` (``broad/cli.py``): missing data
is an error, not a traceback; options that do not go together refused; the
benchmark and ``--stress`` end to end on two short trials of BROAD (see
broad_data.py: without the data it fails, or skips with
EXT_OBSERVER_ALLOW_NO_BROAD=1).
"""

import json
import subprocess
import sys

import pytest

from broad_data import broad_data_dir
from conftest import REPO
from ext_observer import broad


def test_missing_data_is_an_error_not_a_traceback(tmp_path, capsys):
    assert broad.main(['--data', str(tmp_path), '--no-anchors']) == 2
    err = capsys.readouterr().err
    assert 'no HDF5 files' in err and 'make broad-data' in err


TRIALS = ['01_undisturbed_slow_rotation_A', '28_disturbed_stationary_magnet_A']


def _broad(tmp_path, out, *args):
    """Run the command on :data:`TRIALS` (``--json out``, ``--docs tmp_path/docs``); its output."""
    docs = tmp_path / 'docs'
    docs.mkdir()
    done = subprocess.run(
        [sys.executable, '-m', 'ext_observer', 'broad', '--data', broad_data_dir(TRIALS),
         '--trials', *TRIALS, *args, '--json', str(out), '--docs', str(docs), '--quiet'],
        cwd=REPO, capture_output=True, text=True, timeout=230)
    assert done.returncode == 0, done.stderr
    return done, docs


@pytest.mark.timeout(240)
def test_command_end_to_end_on_two_short_trials(tmp_path):
    trials = TRIALS
    # 60 s: the first 30 to 48 s of each trial are rest, not scored.
    out = tmp_path / 'broad.json'
    done, docs = _broad(tmp_path, out, '--head', '60', '--no-anchors')
    assert 'ext_observer' in done.stdout and 'time:' in done.stdout
    scores = json.loads(out.read_text())
    assert list(scores) == [broad.OURS]
    assert set(scores[broad.OURS]) == {'9D', '6D'}
    for mode in ('9D', '6D'):
        assert set(scores[broad.OURS][mode]) == set(trials)
        for row in scores[broad.OURS][mode].values():
            assert set(row) == {'total_rmse_deg', 'heading_rmse_deg', 'inclination_rmse_deg'}
            assert 0.0 <= row['inclination_rmse_deg'] < 30.0
    details = json.loads((tmp_path / 'broad_details.json').read_text())
    assert details['norms']['extended']['all']['max'] < 0.5
    page = (docs / 'broad.md').read_text()
    assert page.startswith('# Real data: the BROAD benchmark')
    assert 'Quick check only' in page
    for target in ('figures/broad_groups.png', 'figures/broad_disturbed_trial.png'):
        assert f']({target})' in page and (docs / target).is_file()


@pytest.mark.timeout(240)
def test_stress_command_end_to_end_on_two_short_trials(tmp_path):
    trials = TRIALS
    out = tmp_path / 'robustness.json'
    done, docs = _broad(tmp_path, out, '--stress', '--head', '50', '--anchors', 'VQF',
                        '--variants', 'b', 'd', '--param', 'tau_bias=100')
    assert 'ours/VQF' in done.stdout and '(d) (c) at 50 Hz' in done.stdout
    assert 'The goal: ours at most 1× VQF' in (docs / 'robustness.md').read_text()
    figures = json.loads(out.read_text())
    assert set(figures['scores']) == {'b', 'd'}
    assert set(figures['scores']['d']) == {broad.OURS, 'VQF'}
    assert figures['rates']['d'] == 50.0
    for key in ('b', 'd'):
        for mode in ('6D', '9D'):
            assert set(figures['scores'][key][broad.OURS][mode]) == set(trials)
            assert figures['ratio_to_vqf'][key][mode]['all'] > 0.0
    page = (docs / 'robustness.md').read_text()
    assert '`--param tau_bias=100`' in page and 'tau_bias = 100,' in page
    assert 'Quick check only' in page and (docs / 'figures' / 'robustness.png').is_file()


def test_stress_options_that_do_not_go_together(capsys):
    assert broad.main(['--stress', '--covariance']) == 2
    assert broad.main(['--field-gap', '60:120']) == 2
    assert '--field-gap goes with --covariance' in capsys.readouterr().err
    assert broad.main(['--covariance', '--field-gap', '120:60']) == 2
    assert '--field-gap: ' in capsys.readouterr().err
    assert broad.main(['--variants', 'b']) == 2
    assert broad.main(['--param', 'tau_bias=100']) == 2
    assert '--variants and --param go with --stress' in capsys.readouterr().err
    assert broad.main(['--stress', '--param', 'no_such=1']) == 2
    assert 'unknown parameters' in capsys.readouterr().err
    assert broad.main(['--stress', '--param', 'tau_bias']) == 2
    assert 'NAME=VALUE' in capsys.readouterr().err
    assert broad.main(['--stress', '--smooth']) == 2
    assert '--smooth goes with the accuracy benchmark' in capsys.readouterr().err
