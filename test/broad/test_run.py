"""
The benchmark's runs (``broad/run.py``) on two short synthetic trials: ours
in every mode (and plain, and smoothed), the anchors, the plotted trial's series, what
each batched call hands back, trials of different rates refused.
"""

import math

import numpy as np
import pytest

from ext_observer import broad
from ext_observer.broad.run import estimate_ours, run


def level_turn(name, seconds=6.0, rate=100.0, turn=0.5):
    """A level body turning about the vertical after 1 s of rest; its exact reference."""
    t = np.arange(int(seconds * rate)) / rate
    w = np.where(t >= 1.0, turn, 0.0)
    angle = np.cumsum(w) / rate
    c, s = np.cos(angle), np.sin(angle)
    world = (0.0, 20.0, -40.0)  # µT
    mag = np.stack([c * world[0] + s * world[1], -s * world[0] + c * world[1],
                    np.full_like(t, world[2])], axis=1)
    gyr = np.stack([0 * t, 0 * t, w], axis=1)
    acc = np.tile([0.0, 0.0, 9.81], (len(t), 1))
    quat = np.stack([np.cos(angle / 2), 0 * t, 0 * t, np.sin(angle / 2)], axis=1)
    return broad.Trial(name, gyr, acc, mag, quat, t >= 1.0, rate)


def test_ours_plain_and_an_anchor_are_scored_in_every_mode():
    trials = [level_turn('02_a'), level_turn('03_b', seconds=5.0, turn=-0.3)]
    lines = []
    result = run(trials, anchors=('VQF',), plain=True, plot_trial='03_b',
                 progress=lines.append)
    assert set(result['scores']) == {broad.OURS, broad.OURS_PLAIN, 'VQF'}
    for algorithm in result['scores'].values():
        assert set(algorithm) == {'9D', '6D'}
        for mode in algorithm.values():
            assert set(mode) == {'02_a', '03_b'}
            for row in mode.values():
                assert row['total_rmse_deg'] < 2.0 and math.isfinite(row['heading_rmse_deg'])
    assert set(result['series'][broad.OURS]) == {'9D', '6D'}
    assert len(result['series'][broad.OURS]['9D'][0]) == len(trials[1].gyr)
    assert set(result['norms']) == {'extended', 'plain'}
    assert lines


def test_our_smoothed_estimate_is_scored_beside_the_online_one():
    trials = [level_turn('02_a'), level_turn('03_b', seconds=5.0, turn=-0.3)]
    result = run(trials, anchors=(), smooth=True, progress=lambda text: None)
    assert set(result['scores']) == {broad.OURS, broad.OURS_SMOOTHED}
    for mode in ('9D', '6D'):
        for row in result['scores'][broad.OURS_SMOOTHED][mode].values():
            assert row['inclination_rmse_deg'] < 0.5
    assert result['seconds'][broad.OURS_SMOOTHED] > 0.0


def test_each_estimate_and_what_then_returns_are_keyed_by_mode_and_trial():
    trials = [level_turn('02_a', seconds=2.0), level_turn('03_b', seconds=3.0)]
    estimates, seconds, after = estimate_ours(trials, ('6D',), 'extended',
                                              then=lambda t, m, q: (t.name, m, len(q)))
    assert set(estimates) == {'6D'} and seconds > 0.0
    assert [len(estimates['6D'][t.name]) for t in trials] == [200, 300]
    assert after == {'6D': {'02_a': ('02_a', '6D', 200), '03_b': ('03_b', '6D', 300)}}


def test_trials_of_different_rates_are_refused():
    with pytest.raises(ValueError, match=r'one sampling rate, got \[100.0, 200.0\]'):
        run([level_turn('02_a'), level_turn('03_b', rate=200.0)], anchors=())
