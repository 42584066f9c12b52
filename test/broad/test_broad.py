"""
The BROAD benchmark as a package (``ext_observer.broad``): every public name
importable from it, and its page and figures (docgen's ``broad_page`` and
``broad_plots``) on synthetic results. The modules' own tests sit beside
this file: test_scoring.py, test_data.py, test_anchors.py, test_cli.py
(the command end to end), test_fetch.py, test_stress.py, test_covariance.py.
"""

import os

import numpy as np
import pytest

from broad_synthetic import NAMES
from conftest import REPO
from docgen import broad_page, broad_plots, offline_page
from ext_observer import broad


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


def test_the_offline_page_fills_its_section_and_keeps_the_prose(tmp_path):
    pytest.importorskip('matplotlib')
    groups = broad.find_groups('/nonexistent', NAMES)
    result = _fake_result(NAMES)
    result['scores'][broad.OURS_SMOOTHED] = result['scores'].pop('Madgwick')
    result['scores']['offline VQF'] = result['scores'][broad.OURS_SMOOTHED]
    result['seconds'][broad.OURS_SMOOTHED] = 3.0
    n = 400
    angles = tuple(np.full(n, 0.01) for _ in range(3))
    result['series'] = {a: {'9D': angles, '6D': angles} for a in (broad.OURS,
                                                                   broad.OURS_SMOOTHED)}

    class Trial:
        name, rate, movement = NAMES[-1], 100.0, np.arange(n) > 50

        def __len__(self):
            return n

    figures = tmp_path / 'figures'
    covariance = {(m, s, c): {'mean_z2': 1.25, 'within_2sigma': 0.9}
                  for m in broad.MODES for s in ('tuning', 'held-out', 'all')
                  for c in ('inclination', 'heading')}
    page = tmp_path / 'offline.md'
    page.write_text(f'# Title\n\nProse.\n\n{offline_page.BEGIN}\nold\n{offline_page.END}\n'
                    'More prose.\n', encoding='utf-8')
    offline_page.write_page(result, groups, _meta(NAMES), [Trial()], covariance, str(tmp_path))
    text = page.read_text(encoding='utf-8')
    assert text.startswith('# Title\n\nProse.') and text.endswith('More prose.\n')
    assert '\nold\n' not in text and '**ours smoothed**' in text and 'offline VQF' in text
    assert '1.25 / 90 %' in text and 'ours smoothed 3.0 s' in text and 'tuning (4)' in text
    assert 'tuning 1.00× / 1.00×' in text and 'held-out (0)' in text
    assert (figures / offline_page.FIGURE).stat().st_size > 1000
    assert f'](figures/{offline_page.FIGURE})' in text


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
