"""
The command ``python -m ext_observer broad`` (``broad/cli.py``): missing data
is an error, not a traceback; end to end on two short trials of BROAD (see
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


@pytest.mark.timeout(240)
def test_command_end_to_end_on_two_short_trials(tmp_path):
    trials = ['01_undisturbed_slow_rotation_A', '28_disturbed_stationary_magnet_A']
    folder = broad_data_dir(trials)
    # 60 s: the first 30 to 48 s of each trial are rest, not scored.
    out = tmp_path / 'broad.json'
    docs = tmp_path / 'docs'
    docs.mkdir()
    done = subprocess.run(
        [sys.executable, '-m', 'ext_observer', 'broad', '--data', folder, '--trials', *trials,
         '--head', '60', '--no-anchors', '--json', str(out), '--docs', str(docs), '--quiet'],
        cwd=REPO, capture_output=True, text=True, timeout=230)
    assert done.returncode == 0, done.stderr
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
