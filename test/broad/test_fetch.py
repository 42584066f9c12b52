"""
The fetch of BROAD (``make broad-data``, and ``make test``'s first step), from a local repository.

No network: a bare git repository made here stands in for BROAD's, laid
out like it (``data_hdf5/*.hdf5`` small but real HDF5 files, ``data_mat/``
with ``trials.json``, videos, the top-level files), and is reached through
``EXT_OBSERVER_BROAD_URL`` or ``--url`` as a ``file://`` URL. An
unreachable URL stands for a machine without network.
"""

import os
import shutil
import subprocess
import sys

import numpy as np
import pytest

import broad_data
from broad_synthetic import tree  # noqa: F401 (a fixture)
from conftest import REPO
from ext_observer import broad
from ext_observer.broad import data, fetch

pytestmark = pytest.mark.skipif(shutil.which('git') is None, reason='needs git')

# The trials the tests read, and two more that a partial fetch must leave out.
OTHERS = ('02_undisturbed_slow_rotation_B', '26_disturbed_phone_vibration_A')
ALL = tuple(sorted(broad_data.TRIALS + OTHERS))
# Nothing listens on the discard port: git fails at once, as without network.
UNREACHABLE = 'http://127.0.0.1:9/broad.git'


def _git(*args, cwd):
    subprocess.run(['git', '-c', 'user.name=t', '-c', 'user.email=t@t', *args], cwd=cwd,
                   check=True, capture_output=True)


def _write_trial(path, n=40, rate=286.0):
    import h5py
    rng = np.random.default_rng(len(path))
    q = rng.standard_normal((n, 4))
    with h5py.File(path, 'w') as f:
        f['imu_gyr'] = 0.01 * rng.standard_normal((n, 3))
        f['imu_acc'] = np.tile((0.0, 0.0, 9.81), (n, 1))
        f['imu_mag'] = np.tile((20.0, 0.0, -40.0), (n, 1))
        f['opt_quat'] = q / np.linalg.norm(q, axis=1, keepdims=True)
        f['movement'] = np.arange(n) > n // 2
        f.attrs['sampling_rate'] = rate


@pytest.fixture(scope='module')
def upstream(tmp_path_factory):
    """A bare repository laid out like BROAD's; its ``file://`` URL."""
    root = tmp_path_factory.mktemp('upstream')
    work = root / 'work'
    for folder in ('data_hdf5', 'data_mat', 'animations'):
        (work / folder).mkdir(parents=True)
    for name in ALL:
        _write_trial(str(work / 'data_hdf5' / f'{name}.hdf5'))
        (work / 'data_mat' / f'{name}.mat').write_bytes(b'mat')
    (work / 'data_mat' / 'trials.json').write_text('{"groups": [], "trials": {}}')
    (work / 'animations' / 'trial.mp4').write_bytes(b'video')
    (work / 'README.md').write_text('# BROAD\n')
    (work / 'LICENSE').write_text('CC BY 4.0\n')
    _git('init', '-q', cwd=work)
    _git('add', '.', cwd=work)
    _git('commit', '-qm', 'data', cwd=work)
    _git('clone', '-q', '--bare', str(work), str(root / 'broad.git'), cwd=root)
    return (root / 'broad.git').as_uri()


def _files(folder):
    return sorted(str(p.relative_to(folder)) for p in folder.rglob('*') if p.is_file())


def test_fetch_takes_the_hdf5_files_and_credits_broad(tmp_path, upstream, capsys):
    dest = tmp_path / 'data' / 'broad'
    assert fetch.main([str(dest), '--url', upstream]) == 0
    assert _files(dest) == ['CREDIT.md', 'LICENSE', 'README.md',
                            *(f'data_hdf5/{name}.hdf5' for name in ALL), 'trials.json']
    credit = (dest / 'CREDIT.md').read_text()
    for needed in ('Laidig', 'doi:10.3390/data6070072', 'CC BY 4.0', upstream):
        assert needed in credit
    assert broad.has_trials(str(dest)) and not (tmp_path / 'data' / 'broad.partial').exists()
    trial = broad.load_trial(str(dest / 'data_hdf5' / f'{ALL[0]}.hdf5'))
    assert len(trial) == 40 and trial.rate == 286.0
    # A second run leaves the folder as it is.
    assert fetch.main([str(dest), '--url', UNREACHABLE]) == 0
    assert 'nothing to do' in capsys.readouterr().out


def test_named_trials_only_then_more_then_all(tmp_path, upstream, monkeypatch):
    monkeypatch.setenv(fetch.URL_VAR, upstream)
    dest = tmp_path / 'broad'
    fetch.fetch(str(dest), trials=[ALL[0]])
    assert _files(dest / 'data_hdf5') == [f'{ALL[0]}.hdf5']
    assert (dest / fetch.SUBSET).read_text() == f'{ALL[0]}\n'
    assert fetch.holds(str(dest), [ALL[0]]) and not fetch.holds(str(dest))
    assert not fetch.holds(str(dest), [ALL[1]])
    # More trials: the ones held are kept.
    fetch.fetch(str(dest), trials=[ALL[1]])
    assert _files(dest / 'data_hdf5') == [f'{name}.hdf5' for name in ALL[:2]]
    assert 'listed in `FETCHED_TRIALS`' in (dest / 'CREDIT.md').read_text()
    # make broad-data on a partial copy fetches the whole.
    assert fetch.main([str(dest)]) == 0
    assert _files(dest / 'data_hdf5') == [f'{name}.hdf5' for name in ALL]
    assert not (dest / fetch.SUBSET).exists() and fetch.holds(str(dest))
    assert not any(p.name.endswith(('.partial', '.old')) for p in tmp_path.iterdir())


def test_a_trial_the_repository_lacks_is_an_error(tmp_path, upstream, capsys):
    dest = tmp_path / 'broad'
    assert fetch.main([str(dest), '--url', upstream, '--trials', '99_nothing']) == 1
    assert "no ['99_nothing'] under data_hdf5/" in capsys.readouterr().err
    assert not dest.exists()


def test_fetch_failure_is_one_error_and_no_folder(tmp_path, capsys):
    dest = tmp_path / 'broad'
    assert fetch.main([str(dest), '--url', str(tmp_path / 'nowhere')]) == 1
    err = capsys.readouterr().err
    assert err.startswith('error: cannot fetch BROAD from ') and err.count('\n') == 1
    assert not dest.exists()


def test_make_test_fetches_what_the_tests_read_from_the_url_it_is_given(
        tree, upstream, monkeypatch, capsys):
    monkeypatch.setenv(fetch.URL_VAR, upstream)
    assert broad_data.main() == 0
    fetched = tree / 'data' / 'broad'
    assert _files(fetched / 'data_hdf5') == sorted(f'{n}.hdf5' for n in broad_data.TRIALS)
    assert broad.data_dir() == str(fetched)
    capsys.readouterr()
    # Found now: nothing fetched, nothing said.
    monkeypatch.setenv(fetch.URL_VAR, UNREACHABLE)
    assert broad_data.main() == 0
    assert capsys.readouterr() == ('', '')


def test_make_test_uses_data_found_beside_the_tree_and_never_fetches_into_a_named_folder(
        tree, monkeypatch, capsys):
    monkeypatch.setenv(fetch.URL_VAR, UNREACHABLE)
    shared = tree.parent / 'shared' / 'broad' / 'data_hdf5'
    shared.mkdir(parents=True)
    for name in broad_data.TRIALS:
        (shared / f'{name}.hdf5').write_bytes(b'')
    assert broad_data.main() == 0
    monkeypatch.setenv(broad.ENV_VAR, str(tree / 'mine'))
    assert broad_data.main() == 0
    assert capsys.readouterr() == ('', '') and not (tree / 'data').exists()


def test_without_network_make_test_says_so_in_one_line(tree, monkeypatch, capsys):
    monkeypatch.setenv(fetch.URL_VAR, UNREACHABLE)
    assert broad_data.main() == 1
    err = capsys.readouterr().err
    assert err.count('\n') == 1
    assert err.startswith(f'error: no BROAD data for the tests and cannot fetch BROAD from '
                          f'{UNREACHABLE}: ')
    for needed in (fetch.URL_VAR, broad.ENV_VAR, broad_data.ALLOW_NO_DATA):
        assert needed in err
    assert not (tree / 'data' / 'broad').exists()
    monkeypatch.setenv(broad_data.ALLOW_NO_DATA, '1')
    assert broad_data.main() == 0
    assert capsys.readouterr().err.startswith('warning: no BROAD data for the tests and ')


def test_make_test_runs_the_fetch_before_the_suite():
    with open(os.path.join(REPO, 'Makefile'), encoding='utf-8') as f:
        makefile = f.read()
    recipe = makefile.split('\ntest: ', 1)[1].split('\n\n', 1)[0]
    assert recipe.index('test/broad_data.py') < recipe.index('-m pytest')


def test_the_fetch_runs_on_the_standard_library_alone(tmp_path):
    # make broad-data runs it with the system's python3, before any install.
    done = subprocess.run([sys.executable, '-I', '-S', fetch.__file__, '--help'],
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 0 and 'EXT_OBSERVER_BROAD_URL' in done.stdout


def test_trials_read_after_other_work_equal_those_read_alone(tmp_path):
    # The broad command loads its kernels, then reads the trials
    # (broad.data.load_trials): the same arrays as load_trial.
    for i, name in enumerate(ALL[:3]):
        _write_trial(str(tmp_path / f'{name}.hdf5'), n=40 + i)
    found = broad.find_trials(str(tmp_path))
    called = []
    trials = data.load_trials(found, meanwhile=lambda: called.append(os.getpid()))
    assert called == [os.getpid()]
    for (name, path), trial in zip(found, trials):
        alone = broad.load_trial(path, name)
        assert trial.name == name and trial.rate == alone.rate
        for key in ('gyr', 'acc', 'mag', 'quat', 'movement'):
            np.testing.assert_array_equal(getattr(trial, key), getattr(alone, key))
    # A file that is not HDF5: the reader's error, as with load_trial.
    (tmp_path / 'broken.hdf5').write_bytes(b'not hdf5')
    with pytest.raises(OSError):
        data.load_trials(broad.find_trials(str(tmp_path)))
    with pytest.raises(OSError):
        data.load_trials(broad.find_trials(str(tmp_path)), meanwhile=lambda: None)


def test_a_read_that_fails_in_the_forked_reader_is_raised_here(tmp_path):
    # With meanwhile, a forked child reads the data while this process works:
    # a file whose layout reads but whose data does not (a compressed
    # dataset with its bytes damaged) gives the reader's error here.
    import h5py
    path = tmp_path / '01_damaged.hdf5'
    n = 20000
    with h5py.File(path, 'w') as f:
        for key, width in (('imu_gyr', 3), ('imu_acc', 3), ('imu_mag', 3), ('opt_quat', 4)):
            f.create_dataset(key, data=np.random.default_rng(1).standard_normal((n, width)),
                             compression='gzip', chunks=(1000, width))
        f['movement'] = np.ones(n, dtype=bool)
        f.attrs['sampling_rate'] = 286.0
    raw = bytearray(path.read_bytes())
    middle = len(raw) // 2
    raw[middle:middle + 4096] = bytes(4096)
    path.write_bytes(bytes(raw))
    found = broad.find_trials(str(tmp_path))
    with pytest.raises(OSError):
        broad.load_trial(str(path))
    called = []
    with pytest.raises(OSError):
        data.load_trials(found, meanwhile=lambda: called.append(os.getpid()))
    assert called == [os.getpid()]
