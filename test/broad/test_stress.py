"""
Tests of the robustness benchmark (``python -m ext_observer broad --stress``).

The variant builder runs on a synthetic trial (no BROAD needed): the cut,
the bias, the 50 Hz blocks and the clipping. The runner, the tables and the
page run ours and VQF on one short synthetic trial; the command end to end
runs on two short trials of BROAD (see broad_data.py).
"""

import json
import math
import subprocess
import sys

import numpy as np
import pytest

from broad_data import broad_data_dir
from conftest import REPO
from ext_observer import broad
from ext_observer.broad import stress
from docgen.robustness_page import plot_stress, stress_markdown
from ext_observer.broad.stress_run import (half_counts, ratio_to_vqf, run_stress,
                                           stress_summary, text_table)
from ext_observer.core.quaternion import conjugate, multiply

RATE = 2000.0 / 7.0  # Hz, BROAD's 285.714...


def synthetic_trial(name='07_synthetic', n=1000, rest=137, seed=1):
    """Numbered columns that show where each output sample came from."""
    rng = np.random.default_rng(seed)
    gyr = 6.0 * rng.standard_normal((n, 3))  # rad/s: often beyond the 4.36 range
    acc = rng.standard_normal((n, 3)) + (0.0, 0.0, 9.81)
    mag = rng.standard_normal((n, 3)) + (20.0, 0.0, -40.0)
    quat = rng.standard_normal((n, 4))
    quat /= np.linalg.norm(quat, axis=1, keepdims=True)
    quat[300:310] = np.nan  # a gap of the optical reference
    movement = np.ones(n, dtype=bool)
    movement[:rest] = False
    movement[600:650] = False  # a pause later on
    return broad.Trial(name, gyr, acc, mag, quat, movement, RATE)


def test_as_recorded_is_the_trial():
    t = synthetic_trial()
    assert stress.variant(t, 'a') is t


def test_cut_starts_at_the_first_movement_sample():
    t = synthetic_trial(rest=137)
    b = stress.variant(t, 'b')
    assert len(b) == len(t) - 137
    assert b.movement[0]
    for name in ('gyr', 'acc', 'mag', 'quat', 'movement'):
        np.testing.assert_array_equal(getattr(b, name), getattr(t, name)[137:])
    assert b.rate == t.rate and b.name == t.name
    # The later pause stays: only the rest before the motion goes.
    assert not b.movement[600 - 137:650 - 137].any()


def test_bias_is_one_degree_per_second_constant_and_fixed_per_trial():
    t = synthetic_trial()
    b, c = stress.variant(t, 'b'), stress.variant(t, 'c')
    added = c.gyr - b.gyr
    np.testing.assert_allclose(added, np.tile(added[0], (len(added), 1)), atol=1e-12)
    assert math.degrees(np.linalg.norm(added[0])) == pytest.approx(1.0, abs=1e-9)
    np.testing.assert_allclose(added[0], stress.bias_of(t.name), atol=1e-12)
    for name in ('acc', 'mag', 'quat', 'movement'):
        np.testing.assert_array_equal(getattr(c, name), getattr(b, name))
    # The same on every call, another direction for another trial.
    np.testing.assert_array_equal(stress.bias_of(t.name), stress.bias_of(t.name))
    other = stress.bias_of('08_other')
    assert np.degrees(np.arccos(np.dot(other, added[0]) / stress.BIAS ** 2)) > 1.0
    # The trial given is not changed.
    np.testing.assert_array_equal(t.gyr, synthetic_trial().gyr)


def test_50_hz_blocks_are_averages_with_the_right_length_and_times():
    t = synthetic_trial()
    c, d = stress.variant(t, 'c'), stress.variant(t, 'd')
    assert d.rate == 50.0
    # Complete 20 ms blocks of (c): its duration × 50 Hz, rounded down.
    assert len(d) == math.floor(len(c) * 50.0 / RATE)
    start = 0
    for k in range(len(d)):
        # Block k: the samples at times i / RATE = 7 i / 2000 s in [k, k + 1) / 50 s,
        # that is 40 k <= 7 i < 40 (k + 1), in exact integers.
        stop = start
        while stop < len(c) and 7 * stop < 40 * (k + 1):
            stop += 1
        assert 40 * k <= 7 * start < 40 * (k + 1)
        assert stop - start in (5, 6)
        for name in ('gyr', 'acc', 'mag'):
            np.testing.assert_allclose(getattr(d, name)[k],
                                       getattr(c, name)[start:stop].mean(axis=0), rtol=1e-12)
        # Reference and movement flag of the block's last sample.
        np.testing.assert_array_equal(d.quat[k], c.quat[stop - 1])
        assert d.movement[k] == c.movement[stop - 1]
        start = stop
    # What is left over is an incomplete block.
    assert 7 * len(c) < 40 * (len(d) + 1)


def test_blocks_of_rates_that_divide():
    block, count = stress.blocks(10, 100.0, 50.0)
    np.testing.assert_array_equal(block, [0, 0, 1, 1, 2, 2, 3, 3, 4, 4])
    assert count == 5
    block, count = stress.blocks(9, 100.0, 50.0)
    assert count == 4
    with pytest.raises(ValueError, match='low_rate'):
        stress.blocks(10, 40.0, 50.0)


def test_clipping_clips_exactly_at_the_range_per_axis_and_leaves_the_rest():
    t = synthetic_trial()
    e = stress.variant(t, 'e')
    limit = math.radians(250.0)
    assert limit == pytest.approx(4.363, abs=5e-4)
    inside = np.abs(t.gyr) <= limit
    assert inside.any() and (~inside).any()
    np.testing.assert_array_equal(e.gyr[inside], t.gyr[inside])
    np.testing.assert_array_equal(e.gyr[~inside], np.sign(t.gyr[~inside]) * limit)
    for name in ('acc', 'mag', 'quat', 'movement'):
        np.testing.assert_array_equal(getattr(e, name), getattr(t, name))


def test_unknown_variant_and_trial_without_movement_are_errors():
    t = synthetic_trial()
    with pytest.raises(ValueError, match='variant must be one of'):
        stress.variant(t, 'f')
    still = broad.Trial('09_still', t.gyr, t.acc, t.mag, t.quat, np.zeros(len(t), bool), RATE)
    with pytest.raises(ValueError, match='no movement'):
        stress.variant(still, 'b')


def test_halves_are_even_and_odd_trial_numbers():
    assert stress.half_of('28_disturbed_stationary_magnet_A') == 'tuning'
    assert stress.half_of('01_undisturbed_slow_rotation_A') == 'report'
    assert stress.half_of('synthetic') is None
    assert half_counts(['01_a', '02_b', '04_c']) == {'all': 3, 'tuning': 2, 'report': 1}


# --- the runner on synthetic data --------------------------------------------

def rotating_trial(name, seconds=24.0, rate=100.0, speed=40.0):
    """A sensor turning about a tilted axis at ``speed`` °/s after 4 s of rest, ENU field."""
    n = int(seconds * rate)
    t = np.arange(n) / rate
    axis = np.array([0.3, -0.2, 1.0]) / np.linalg.norm([0.3, -0.2, 1.0])
    w = np.where(t >= 4.0, math.radians(speed), 0.0)
    gyr = w[:, None] * axis
    angle = np.cumsum(w) / rate
    half = 0.5 * angle
    # Body-frame rotation about a fixed body axis from a tilted start.
    q0 = np.array([math.cos(0.2), math.sin(0.2), 0.0, 0.0])
    turn = np.column_stack([np.cos(half), np.sin(half)[:, None] * axis])
    quat = multiply(q0, turn)
    conj = conjugate(quat)
    up = np.array([0.0, 0.0, 0.0, 9.81])
    field = np.array([0.0, 0.0, 20.0, -40.0])
    acc = multiply(multiply(conj, up), quat)[:, 1:]
    mag = multiply(multiply(conj, field), quat)[:, 1:]
    return broad.Trial(name, gyr, acc, mag, quat, t >= 4.0, rate)


@pytest.mark.timeout(120)
def test_runner_scores_ours_and_vqf_on_every_variant(tmp_path):
    trials = [rotating_trial('02_synthetic'), rotating_trial('03_synthetic')]
    out = run_stress(trials, anchors=('VQF',), progress=lambda text: None)
    assert list(out['scores']) == list(stress.VARIANTS)
    assert out['rates']['d'] == 50.0 and out['rates']['a'] == 100.0
    summ = stress_summary(out['scores'])
    for key in stress.VARIANTS:
        for algorithm in (broad.OURS, 'VQF'):
            for mode in ('6D', '9D'):
                cell = summ[key][algorithm][mode]
                assert set(cell) == {'all', 'tuning', 'report'}
                assert 0.0 <= cell['all'] < 30.0
        assert ratio_to_vqf(summ, key, '6D') > 0.0
    # Noise-free and within range: as recorded both are near exact; the bias
    # of (c) costs something.
    assert summ['a'][broad.OURS]['6D']['all'] < 1.0
    assert summ['c']['VQF']['6D']['all'] > summ['b']['VQF']['6D']['all']
    # At 40 °/s the clipping changes nothing.
    assert summ['e'][broad.OURS]['9D'] == summ['a'][broad.OURS]['9D']
    table = text_table(summ, half_counts([t.name for t in trials]))
    assert 'odd-numbered trials (report), 1 trials' in table and 'ours/VQF' in table
    meta = {'command': 'python -m ext_observer broad --stress', 'commit': 'abc1234',
            'date': 'today', 'machine': 'here', 'trials': [t.name for t in trials],
            'anchors': ['VQF'], 'versions': {}, 'wall': 1.0}
    figure = plot_stress(out, str(tmp_path / 'figures' / 'robustness.png'))
    page = stress_markdown(out, meta, figure, str(tmp_path))
    assert page.startswith('# Robustness: BROAD made harder')
    assert 'CC BY 4.0' in page and 'Laidig' in page and '`abc1234`' in page
    for title in ('## All trials', '## Even-numbered trials (tuning)',
                  '## Odd-numbered trials (report)'):
        assert title in page
    assert '](figures/robustness.png)' in page
    assert (tmp_path / 'figures' / 'robustness.png').stat().st_size > 1000


def test_fusion_runs_in_both_rows_and_is_told_each_variants_gyro_range():
    assert broad.STRESS_ANCHORS[-2:] == ('Fusion', broad.FUSION_DEFAULTS)
    assert broad.GYRO_RANGES == {**{k: broad.BROAD_GYRO_RANGE for k in stress.VARIANTS},
                                 'e': stress.GYRO_RANGE}
    # Turning at 300 °/s: clipped at 250 °/s in (e), where Fusion is told
    # that range (and restarts on the clipped samples), not BROAD's sensor's.
    trial = rotating_trial('02_fast', seconds=12.0, speed=300.0)
    out = run_stress([trial], keys=('a', 'e'), modes=('6D',),
                     anchors=('Fusion', broad.FUSION_DEFAULTS), progress=lambda text: None)
    for key in ('a', 'e'):
        for anchor in ('Fusion', broad.FUSION_DEFAULTS):
            assert 0.0 <= out['scores'][key][anchor]['6D']['02_fast']['inclination_rmse_deg'] < 90

    def clipped(gyro_range):
        result = broad.run([stress.variant(trial, 'e')], ('6D',), ('Fusion',),
                           progress=lambda text: None, gyro_range=gyro_range)
        return result['scores']['Fusion']['6D']['02_fast']
    assert out['scores']['e']['Fusion']['6D']['02_fast'] == clipped(stress.GYRO_RANGE)
    assert out['scores']['e']['Fusion']['6D']['02_fast'] != clipped(broad.BROAD_GYRO_RANGE)


# --- end to end ------------------------------------------------------------

@pytest.mark.timeout(240)
def test_stress_command_end_to_end_on_two_short_trials(tmp_path):
    trials = ['01_undisturbed_slow_rotation_A', '28_disturbed_stationary_magnet_A']
    folder = broad_data_dir(trials)
    out = tmp_path / 'robustness.json'
    docs = tmp_path / 'docs'
    done = subprocess.run(
        [sys.executable, '-m', 'ext_observer', 'broad', '--stress', '--data', folder,
         '--trials', *trials, '--head', '50', '--anchors', 'VQF', '--variants', 'b', 'd',
         '--param', 'tau_bias=100', '--json', str(out), '--docs', str(docs), '--quiet'],
        cwd=REPO, capture_output=True, text=True, timeout=230)
    assert done.returncode == 0, done.stderr
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
    assert broad.main(['--variants', 'b']) == 2
    assert broad.main(['--param', 'tau_bias=100']) == 2
    assert '--variants and --param go with --stress' in capsys.readouterr().err
    assert broad.main(['--stress', '--param', 'no_such=1']) == 2
    assert 'unknown parameters' in capsys.readouterr().err
    assert broad.main(['--stress', '--param', 'tau_bias']) == 2
    assert 'NAME=VALUE' in capsys.readouterr().err
