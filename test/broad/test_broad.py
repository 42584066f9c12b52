"""
Tests of the BROAD benchmark (``python -m ext_observer broad``).

The scoring, the grouping and the page run on synthetic arrays (no h5py, no
data). The anchors' frame conversions run on a synthetic static sensor
(their packages are in requirements-test.txt). Where the data is looked for
runs on temporary folders (the fetch: test_fetch.py). The command end
to end runs on two short trials of BROAD (see broad_data.py: without the data it fails, or
skips with EXT_OBSERVER_ALLOW_NO_BROAD=1).
"""

import json
import math
import os
import subprocess
import sys

import numpy as np
import pytest

from broad_data import broad_data_dir
from conftest import REPO
from docgen import broad_page, broad_plots
from ext_observer import broad
from ext_observer.broad import data
from ext_observer.core.quaternion import conjugate, multiply


def rotation(axis, angle):
    axis = np.asarray(axis, dtype=float)
    return np.r_[math.cos(angle / 2), math.sin(angle / 2) * axis / np.linalg.norm(axis)]


def in_sensor_frame(q, v):
    """Coordinates in the sensor frame of a world vector, for q sensor → world."""
    return multiply(multiply(conjugate(q), np.r_[0.0, v]), q)[1:]


@pytest.fixture
def references():
    rng = np.random.default_rng(3)
    q = rng.standard_normal((50, 4))
    return q / np.linalg.norm(q, axis=1, keepdims=True)


# --- scoring ---------------------------------------------------------------

@pytest.mark.parametrize('angle', [1e-3, 0.3, 2.0, 3.1])
def test_heading_error_is_about_the_world_vertical(references, angle):
    est = multiply(rotation((0, 0, 1), angle), references)
    total, heading, inclination = broad.error_angles(est, references)
    np.testing.assert_allclose(total, angle, atol=1e-7)
    np.testing.assert_allclose(heading, angle, atol=1e-7)
    np.testing.assert_allclose(inclination, 0.0, atol=1e-6)


@pytest.mark.parametrize('axis', [(1, 0, 0), (0, 1, 0), (1, -2, 0)])
def test_inclination_error_is_about_a_horizontal_axis(references, axis):
    est = multiply(rotation(axis, 0.4), references)
    total, heading, inclination = broad.error_angles(est, references)
    np.testing.assert_allclose(total, 0.4, atol=1e-7)
    np.testing.assert_allclose(heading, 0.0, atol=1e-7)
    np.testing.assert_allclose(inclination, 0.4, atol=1e-7)


def test_heading_and_inclination_split_a_world_frame_error(references):
    # e = R_x(φ) R_z(θ) = (cφ cθ, sφ cθ, sφ sθ, cφ sθ) in half angles: BROAD's
    # formulas give θ and φ exactly. A body-frame error would not (hence the
    # order q̂ ⊗ q_ref⁻¹).
    est = multiply(multiply(rotation((1, 0, 0), 0.2), rotation((0, 0, 1), 0.7)), references)
    _, heading, inclination = broad.error_angles(est, references)
    np.testing.assert_allclose(heading, 0.7, atol=1e-7)
    np.testing.assert_allclose(inclination, 0.2, atol=1e-7)
    body = multiply(references, rotation((1, 0, 0), 0.3))
    _, _, inclination = broad.error_angles(body, references)
    assert np.ptp(inclination) > 0.1  # the body axis is tilted in the world


def test_scoring_ignores_sign_and_norm(references):
    est = multiply(rotation((0, 1, 1), 0.5), references)
    expected = broad.error_angles(est, references)
    scaled = -2.5 * est  # an ambient estimate, off S³ and with the other sign
    for a, b in zip(broad.error_angles(scaled, references), expected):
        np.testing.assert_allclose(a, b, atol=1e-12)


def test_rmse_over_movement_skips_nan_references(references):
    n = len(references)
    angles = np.radians(np.where(np.arange(n) % 2 == 0, 1.0, 3.0))
    movement = np.arange(n) >= 10
    assert broad.rmse_deg(angles, movement) == pytest.approx(math.sqrt(5.0))
    est = multiply(rotation((0, 0, 1), math.radians(2.0)), references)
    est[:10] = multiply(rotation((0, 0, 1), math.radians(50.0)), references[:10])
    ref = references.copy()
    ref[20:30] = np.nan  # a gap of the optical reference
    est[20:30] = multiply(rotation((0, 0, 1), math.radians(90.0)), references[20:30])
    s = broad.score(est, ref, movement)
    assert set(s) == {'total_rmse_deg', 'heading_rmse_deg', 'inclination_rmse_deg'}
    assert s['total_rmse_deg'] == pytest.approx(2.0)
    assert s['heading_rmse_deg'] == pytest.approx(2.0)
    assert s['inclination_rmse_deg'] == pytest.approx(0.0, abs=1e-5)
    assert math.isnan(broad.rmse_deg(np.full(5, np.nan)))


def test_norm_deviation():
    q = [np.array([[1.0, 0, 0, 0], [0, 1.1, 0, 0]]), np.array([[0.0, 0, 0.9, 0]])]
    d = broad.norm_deviation(q)
    assert d['samples'] == 3
    assert d['mean'] == pytest.approx((0.0 + 0.21 + 0.19) / 3)
    assert d['max'] == pytest.approx(0.21)


def test_attitude_from_acc_and_field():
    q = multiply(rotation((0, 0, 1), 0.8), rotation((1, 1, 0), 0.5))
    acc = in_sensor_frame(q, (0.0, 0.0, 9.81))
    mag = in_sensor_frame(q, (0.0, 20.0, -40.0))  # µT, north and down
    q0 = broad.attitude_from_acc_mag(acc, mag)
    assert abs(np.dot(q0, q)) == pytest.approx(1.0, abs=1e-12)
    _, _, inclination = broad.error_angles(broad.attitude_from_acc_mag(acc), q)
    assert inclination == pytest.approx(0.0, abs=1e-7)


# --- trials and groups -----------------------------------------------------

NAMES = ['04_undisturbed_slow_rotation_with_breaks_A', '15_undisturbed_fast_translation_A',
         '26_disturbed_phone_vibration_A', '32_disturbed_attached_magnet_1cm']


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


def test_group_means_average_the_trials():
    groups = broad.find_groups('/nonexistent', NAMES)
    scores = {name: {'total_rmse_deg': float(i + 1)} for i, name in enumerate(NAMES)}
    means = broad.group_means(scores, groups, 'total_rmse_deg')
    assert means['all_trials'] == pytest.approx(2.5)
    assert means['undisturbed'] == pytest.approx(1.5)
    assert means['disturbed'] == pytest.approx(3.5)
    assert means['vibration'] == pytest.approx(3.0)


# --- the page --------------------------------------------------------------

def _fake_result(names):
    rng = np.random.default_rng(0)
    scores = {}
    for algorithm in (broad.OURS, 'VQF', 'Madgwick'):
        for mode in broad.MODES:
            scores.setdefault(algorithm, {})[mode] = {
                n: {k: float(rng.uniform(0.5, 5.0)) for k in
                    ('total_rmse_deg', 'heading_rmse_deg', 'inclination_rmse_deg')}
                for n in names}
    norms = {'extended': {m: {'mean': 1e-4, 'max': 1e-3, 'samples': 10}
                          for m in ('9D', '6D', 'all')}}
    return {'scores': scores, 'norms': norms,
            'seconds': {broad.OURS: 1.0, 'VQF': 0.1, 'Madgwick': 9.0}, 'series': {}}


def _meta(names):
    return {'command': 'python -m ext_observer broad --data x', 'commit': 'abc1234',
            'dirty': False, 'date': '2025-01-01 00:00 UTC', 'machine': 'test machine',
            'versions': {'vqf': '0'}, 'params': {'alpha': 0.05}, 'trials': names,
            'groups_source': 'the file names', 'plot_trial': names[-1], 'rate': 100.0,
            'head': None}


@pytest.mark.parametrize('tuning', [False, True])
def test_page_opens_with_a_sentence_credits_broad_and_leaves_the_tuning_place(tmp_path, tuning):
    groups = broad.find_groups('/nonexistent', NAMES)
    page = broad_page.markdown(_fake_result(NAMES), groups, _meta(NAMES), {}, str(tmp_path),
                          str(tmp_path / 'broad_tuning.md') if tuning else None)
    lines = [line for line in page.splitlines() if line.strip()]
    assert lines[0] == '# Real data: the BROAD benchmark'
    assert lines[1].startswith('This page ')
    for needed in ('Laidig et al. 2021', 'doi:10.3390/data6070072', 'CC BY 4.0',
                   '## How the defaults were chosen', '## Summary', 'abc1234',
                   '9D total, undisturbed', '6D inclination, all', '|q̂̄q̂ − 1|',
                   '- 9D, undisturbed average', '- 6D, inclination over all trials'):
        assert needed in page
    section = page.split('## How the defaults were chosen')[1].split('\n## ')[0]
    if tuning:
        assert '](broad_tuning.md)' in section
    else:
        assert 'Filled by the tuning' in section and 'broad_tuning.md' in section


def test_figures_are_written(tmp_path):
    pytest.importorskip('matplotlib')
    groups = broad.find_groups('/nonexistent', NAMES)
    result = _fake_result(NAMES)
    n = 400
    angles = tuple(np.full(n, 0.01) for _ in range(3))
    result['series'] = {broad.OURS: {'9D': angles, '6D': angles}, 'VQF': {'9D': angles}}
    meta = dict(_meta(NAMES), plot_movement=np.arange(n) > 50)
    figures = broad_plots.plot(result, groups, meta, str(tmp_path / 'figures'))
    assert set(figures) == {'groups', 'trial'}
    for path in figures.values():
        assert os.path.basename(path).startswith('broad_') and os.path.getsize(path) > 1000


def test_missing_h5py_names_the_fix(monkeypatch, tmp_path):
    monkeypatch.setitem(sys.modules, 'h5py', None)
    with pytest.raises(RuntimeError, match=r'pip install h5py.*make test'):
        broad.load_trial(str(tmp_path / 'x.hdf5'))


def test_missing_data_is_an_error_not_a_traceback(tmp_path, capsys):
    assert broad.main(['--data', str(tmp_path), '--no-anchors']) == 2
    err = capsys.readouterr().err
    assert 'no HDF5 files' in err and 'make broad-data' in err


# --- where the data is -----------------------------------------------------

@pytest.fixture
def tree(tmp_path, monkeypatch):
    """A source tree of its own, without BROAD beside it nor in the environment."""
    folder = tmp_path / 'work' / 'main'
    folder.mkdir(parents=True)
    monkeypatch.setattr(data, 'TREE', str(folder))
    monkeypatch.delenv(broad.ENV_VAR, raising=False)
    return folder


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
                                f'--json={fetched}/b.json', '--docs', 'docs']) == (
        'python -m ext_observer broad --data ../shared/broad --json=data/broad/b.json '
        '--docs docs')
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


# Every public name of the module ext_observer/broad.py had, before it became
# a package (but its page and figures, now docgen's).
FORMER_NAMES = (
    'ALGORITHMS', 'ANCHORS', 'ANCHOR_PACKAGES', 'IDENTITY', 'MADGWICK_BETA', 'MAHONY_KI',
    'MAHONY_KP', 'MODES', 'NWU_TO_ENU', 'OURS', 'OURS_PLAIN', 'PLOT_TRIAL',
    'STANDARD_GRAVITY', 'Trial', 'anchor_estimates', 'attitude_from_acc_mag', 'build_parser',
    'error_angles', 'find_groups', 'find_trials', 'group_means', 'groups_from_name',
    'load_trial', 'main', 'missing_anchor_packages', 'norm_deviation',
    'rmse_deg', 'run', 'score', 'summary', 'text_report')


def test_every_public_name_is_importable_from_the_package():
    import importlib
    import inspect
    missing = [n for n in FORMER_NAMES if not hasattr(broad, n)]
    for module in ('result_keys', 'data', 'scoring', 'anchors', 'run', 'report', 'cli', 'stress',
                   'stress_run'):
        found = importlib.import_module(f'ext_observer.broad.{module}')
        missing += [f'{module}.{name}' for name, value in vars(found).items()
                    if not name.startswith('_') and (inspect.isfunction(value)
                                                     or inspect.isclass(value))
                    and value.__module__ == found.__name__ and not hasattr(broad, name)]
    assert not missing, f'not importable from ext_observer.broad: {missing}'
    assert set(broad.__all__) <= set(vars(broad))


# --- the anchors' frames ---------------------------------------------------

@pytest.mark.parametrize('anchor', broad.ANCHORS)
@pytest.mark.parametrize('mode', broad.MODES)
def test_anchor_frames_on_a_static_sensor(anchor, mode):
    """
    A static sensor, tilted and turned: each anchor's converted output is q.

    The specific force points up, the field north and down (ENU); after 20 s
    at 100 Hz each anchor, brought to ENU by its fixed factor, must give the
    attitude (9D) or its inclination (6D). A wrong world frame (NWU read as
    ENU) gives 90° of heading, a conjugate or a scalar-last reading tens of
    degrees of inclination.
    """
    # The anchors are in requirements-test.txt: a missing one fails here.
    q = multiply(rotation((0, 0, 1), math.radians(30.0)),
                 multiply(rotation((1, 0, 0), math.radians(10.0)),
                          rotation((0, 1, 0), math.radians(-15.0))))
    rate, n = 100.0, 2000
    rng = np.random.default_rng(0)
    acc = in_sensor_frame(q, (0.0, 0.0, 9.81)) + 0.01 * rng.standard_normal((n, 3))
    mag = in_sensor_frame(q, (0.0, 20.0, -40.0)) + 0.1 * rng.standard_normal((n, 3))
    # Some gyro noise: Madgwick and Mahony skip samples with a zero rate.
    gyr = 1e-3 * rng.standard_normal((n, 3))
    est = broad.anchor_estimates(anchor, gyr, acc, mag, rate, mode == '9D')
    assert est.shape == (n, 4)
    total, _, inclination = broad.error_angles(est[-200:], np.tile(q, (200, 1)))
    assert np.degrees(inclination).max() < 1.0
    if mode == '9D':
        assert np.degrees(total).max() < 1.0


def _tilted_for_a_while(gyro_noise, rate=100.0, rest=10.0, pushed=3.0):
    """A level sensor at rest, then pushed sideways: its specific force 30° off up."""
    rng = np.random.default_rng(1)
    n, m = int((rest + pushed) * rate), int(pushed * rate)
    acc = np.tile((0.0, 0.0, 9.81), (n, 1))
    acc[-m:] = 9.81 * np.array([math.sin(math.radians(30.0)), 0.0, math.cos(math.radians(30.0))])
    return (gyro_noise * rng.standard_normal((n, 3)), acc + 0.01 * rng.standard_normal((n, 3)),
            np.tile((0.0, 20.0, -40.0), (n, 1)))


def _inclination_at_end(est):
    return math.degrees(broad.error_angles(est[-1], (1.0, 0.0, 0.0, 0.0))[2])


def test_fusion_runs_at_its_readmes_settings_and_at_its_package_defaults():
    imufusion = pytest.importorskip('imufusion')
    assert broad.ANCHORS[-2:] == ('Fusion', broad.FUSION_DEFAULTS)
    assert broad.ANCHOR_PACKAGES[broad.FUSION_DEFAULTS] == 'imufusion'
    readme = broad.fusion_settings(250.0)
    assert readme == pytest.approx({'sample_rate': 250.0, 'gain': 0.5, 'gyroscope_range': 2000.0,
                                    'acceleration_rejection': 10.0, 'magnetic_rejection': 10.0,
                                    'rejection_timeout': 5.0})
    assert broad.fusion_settings(50.0, math.radians(250.0))['gyroscope_range'] == pytest.approx(
        250.0)
    assert broad.fusion_settings(250.0, readme=False) == {'sample_rate': 250.0}
    # The names are the package's: each setting reads back as given.
    given = imufusion.AhrsSettings(**readme)
    assert {k: getattr(given, k) for k in readme} == pytest.approx(readme)


def test_fusions_settings_reach_the_filter():
    """
    Pushed sideways for 3 s, Fusion at its README's settings rejects the accelerometer.

    At the package defaults it follows it; a gyro range below the gyro's
    noise restarts Fusion at every sample (no rejection while it starts),
    one above it does not: the range is passed, and in °/s.
    """
    gyr, acc, mag = _tilted_for_a_while(gyro_noise=math.radians(0.1))

    def inclination(anchor, **kw):
        return _inclination_at_end(broad.anchor_estimates(anchor, gyr, acc, mag, 100.0, False,
                                                          **kw))
    assert inclination('Fusion') < 2.0
    assert inclination('Fusion', gyro_range=math.radians(1.0)) < 2.0
    assert inclination('Fusion', gyro_range=math.radians(0.02)) > 15.0
    assert inclination(broad.FUSION_DEFAULTS) > 15.0


def test_pages_name_no_absolute_path_and_fusions_settings():
    command = ('python -m ext_observer broad --data /work/shared/broad --json=/tmp/x/broad.json '
               '--docs docs --trials 01')
    shown, folder = broad_page.shown_meta({'command': command, 'data': '/work/shared/broad'})
    assert not any(os.path.isabs(word.split('=')[-1]) for word in shown.split()) \
        and not os.path.isabs(folder)
    assert shown.endswith(' --docs docs --trials 01') and '--json=' in shown
    assert os.path.normpath(os.path.join(REPO, folder)) == '/work/shared/broad'
    assert broad_page.shown_meta({'command': 'x --data ../shared/broad', 'data': '../shared/broad'}) \
        == ('x --data ../shared/broad', '../shared/broad')
    groups = broad.find_groups('/nonexistent', NAMES)
    meta = dict(_meta(NAMES), command=command, data='/work/shared/broad')
    page = broad_page.markdown(_fake_result(NAMES), groups, meta, {}, REPO)
    made_by = next(line for line in page.splitlines() if line.startswith('**Made by**'))
    assert f'on the data in `{folder}`' in made_by and not any(
        os.path.isabs(word.strip('`')) for word in made_by.split())
    for needed in ("Fusion (`imufusion`) at its README's settings: gain 0.5, gyro range 2000 °/s",
                   'acceleration rejection 10°, magnetic rejection 10°',
                   'rejection timeout (recovery trigger period) 5 s', '`Bias`',
                   f'"{broad.FUSION_DEFAULTS}"'):
        assert needed in page


# --- end to end ------------------------------------------------------------

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
