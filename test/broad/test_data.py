"""
BROAD's data (``broad/data.py``) on temporary folders: groups from file
names, trials.json and data_mat, where the trials are found, where the data
is looked for and what the command says without it, h5py missing.
"""

import json
import os
import sys

import pytest

from broad_synthetic import NAMES
from broad_synthetic import tree  # noqa: F401 (a fixture)
from ext_observer import broad


def test_groups_from_file_names():
    assert broad.groups_from_name(NAMES[0]) == [
        'all_trials', 'undisturbed', 'rotation', 'slow', 'with_breaks']
    assert broad.groups_from_name(NAMES[1]) == [
        'all_trials', 'undisturbed', 'translation', 'fast', 'no_breaks']
    assert broad.groups_from_name(NAMES[2]) == ['all_trials', 'disturbed', 'vibration']
    assert broad.groups_from_name(NAMES[3]) == ['all_trials', 'disturbed', 'attached_magnet']


def test_trials_are_found_directly_or_under_data_hdf5(tmp_path):
    (tmp_path / 'data_hdf5').mkdir()
    for name in NAMES:
        (tmp_path / 'data_hdf5' / f'{name}.hdf5').write_bytes(b'')
    found = broad.find_trials(str(tmp_path))
    assert [n for n, _ in found] == sorted(NAMES)
    direct = broad.find_trials(str(tmp_path / 'data_hdf5'), ['26_', '*magnet*'])
    assert [n for n, _ in direct] == NAMES[2:]
    with pytest.raises(ValueError, match='no HDF5 files'):
        broad.find_trials(str(tmp_path / 'nothing'))


def test_groups_come_from_trials_json_when_found(tmp_path):
    spec = {'groups': [{'name': 'all_trials', 'level': 0}, {'name': 'undisturbed', 'level': 1},
                       {'name': 'special', 'level': 2}, {'name': 'disturbed', 'level': 1}],
            'trials': {NAMES[0]: {'groups': ['all_trials', 'undisturbed', 'special']}}}
    (tmp_path / 'data_hdf5').mkdir()
    (tmp_path / 'trials.json').write_text(json.dumps(spec))
    for data_dir in (tmp_path, tmp_path / 'data_hdf5'):
        groups = broad.find_groups(str(data_dir), NAMES[:3])
        assert groups['source'].endswith('trials.json')
        assert groups['members']['special'] == [NAMES[0]]
        # A trial trials.json does not list is grouped by its name.
        assert groups['members']['undisturbed'] == NAMES[:2]
        assert [g for g, _ in groups['order']][:4] == [
            'all_trials', 'undisturbed', 'special', 'disturbed']
    alone = tmp_path / 'alone' / 'deeper'
    alone.mkdir(parents=True)
    assert broad.find_groups(str(alone), NAMES)['source'] == 'file names'


def test_missing_h5py_names_the_fix(monkeypatch, tmp_path):
    monkeypatch.setitem(sys.modules, 'h5py', None)
    with pytest.raises(RuntimeError, match=r'pip install h5py.*make test'):
        broad.load_trial(str(tmp_path / 'x.hdf5'))


def _put_trial(folder, name=NAMES[0]):
    (folder / 'data_hdf5').mkdir(parents=True)
    (folder / 'data_hdf5' / f'{name}.hdf5').write_bytes(b'')


def test_data_folder_is_the_option_then_the_environment_then_the_defaults(tree, monkeypatch):
    shared = tree.parent / 'shared' / 'broad'
    fetched = tree / 'data' / 'broad'
    _put_trial(shared)
    assert broad.data_dir() == str(shared)
    _put_trial(fetched)
    assert broad.data_dir() == str(fetched)
    # Named on purpose: kept even without files (the error then names it).
    monkeypatch.setenv(broad.ENV_VAR, str(tree / 'elsewhere'))
    assert broad.data_dir() == str(tree / 'elsewhere')
    assert broad.data_dir('given') == 'given'
    assert broad.shown_path(str(shared)) == '../shared/broad'
    assert broad.shown_path(str(fetched)) == 'data/broad'
    # A page never holds this machine's absolute paths, typed or not.
    assert broad.shown_command(['python -m ext_observer broad', '--data', str(shared),
                                f'--json={fetched}/b.json', '--docs', 'docs', '--anchors',
                                'offline VQF']) == (
        'python -m ext_observer broad --data ../shared/broad --json=data/broad/b.json '
        '--docs docs --anchors "offline VQF"')
    assert not os.path.isabs(broad.shown_path('/elsewhere/broad'))


def test_without_data_the_command_says_how_to_get_it_in_one_line(tree, capsys):
    (tree / 'data' / 'broad').mkdir(parents=True)  # a folder without files is not data
    assert broad.main(['--no-anchors']) == 2
    err = capsys.readouterr().err
    assert err.count('\n') == 1 and err.startswith('error: no BROAD data in ')
    for needed in ('data/broad', '../shared/broad', 'make broad-data', '--data',
                   broad.ENV_VAR):
        assert needed in err


def test_groups_come_from_data_mat_as_in_a_clone_of_broad(tmp_path):
    spec = {'groups': [{'name': 'all_trials', 'level': 0}, {'name': 'special', 'level': 1}],
            'trials': {NAMES[0]: {'groups': ['all_trials', 'special']}}}
    _put_trial(tmp_path)
    (tmp_path / 'data_mat').mkdir()
    (tmp_path / 'data_mat' / 'trials.json').write_text(json.dumps(spec))
    groups = broad.find_groups(str(tmp_path), [NAMES[0]], str(tmp_path / 'data_hdf5'))
    assert groups['members']['special'] == [NAMES[0]]
