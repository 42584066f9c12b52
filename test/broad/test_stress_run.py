"""
The robustness benchmark's runner (``broad/stress_run.py``): ours and VQF (and
Fusion, told each variant's gyro range) scored on every variant of short
synthetic trials, its tables, ratios and page.
"""

import math

import numpy as np
import pytest

from ext_observer import broad
from ext_observer.broad import stress
from docgen.robustness_page import plot_stress, stress_markdown
from ext_observer.broad.stress_run import (half_counts, ratio_to_vqf, run_stress,
                                           stress_summary, text_table)
from ext_observer.core.quaternion import conjugate, multiply


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
    trials = [rotating_trial('02_synthetic'), rotating_trial('09_synthetic')]
    out = run_stress(trials, anchors=('VQF',), progress=lambda text: None)
    assert list(out['scores']) == list(stress.VARIANTS)
    assert out['rates']['d'] == 50.0 and out['rates']['a'] == 100.0
    summ = stress_summary(out['scores'])
    for key in stress.VARIANTS:
        for algorithm in (broad.OURS, 'VQF'):
            for mode in ('6D', '9D'):
                cell = summ[key][algorithm][mode]
                assert set(cell) == {'all', 'tuning', 'held-out'}
                assert 0.0 <= cell['all'] < 30.0
        assert ratio_to_vqf(summ, key, '6D') > 0.0
    # Noise-free and within range: as recorded both are near exact; the bias
    # of (c) costs something.
    assert summ['a'][broad.OURS]['6D']['all'] < 1.0
    assert summ['c']['VQF']['6D']['all'] > summ['b']['VQF']['6D']['all']
    # At 40 °/s the clipping changes nothing.
    assert summ['e'][broad.OURS]['9D'] == summ['a'][broad.OURS]['9D']
    table = text_table(summ, half_counts([t.name for t in trials]))
    assert 'held-out trials, 1 trials' in table and 'ours/VQF' in table
    meta = {'command': 'python -m ext_observer broad --stress', 'commit': 'abc1234',
            'date': 'today', 'machine': 'here', 'trials': [t.name for t in trials],
            'anchors': ['VQF'], 'versions': {}, 'wall': 1.0}
    figure = plot_stress(out, str(tmp_path / 'figures' / 'robustness.png'))
    page = stress_markdown(out, meta, figure, str(tmp_path))
    assert page.startswith('# Robustness: BROAD made harder')
    assert 'CC BY 4.0' in page and 'Laidig' in page and '`abc1234`' in page
    for title in ('## All trials', '## Tuning trials', '## Held-out trials'):
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
