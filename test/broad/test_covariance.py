"""
The covariance benchmark (``broad --covariance``, ``broad/covariance.py``): its
figures on known distributions, its replay equal to the pipeline, its page and
figures, the bound margin.
"""

import math

import numpy as np
import pytest

from ext_observer.core.ahrs.ahrs_observer import AhrsParams


# The online magnetometer calibration, where the core has it: off
# where a test needs fields used at once.
HAS_CALIBRATION = 'mag_cal' in AhrsParams.DEFAULTS


def synthetic_trial(name, seconds=20.0, rate=100.0, turn=0.4):
    """A BROAD-like trial: a level body turning about the vertical, its exact reference."""
    from ext_observer.broad.data import Trial

    t = np.arange(int(seconds * rate)) / rate
    angle = turn * t
    world = np.array([0.0, 20.0, -40.0])  # µT, north and down
    c, s = np.cos(angle), np.sin(angle)
    # The body's view of the world field: R_z(angle)ᵀ m.
    mag = np.stack([c * world[0] + s * world[1], -s * world[0] + c * world[1],
                    np.full_like(t, world[2])], axis=1)
    rng = np.random.default_rng(7)
    gyr = np.tile([0.0, 0.0, turn], (len(t), 1)) + rng.normal(0.0, 0.002, (len(t), 3))
    acc = np.tile([0.0, 0.0, 9.81], (len(t), 1)) + rng.normal(0.0, 0.05, (len(t), 3))
    quat = np.stack([np.cos(angle / 2), 0 * t, 0 * t, np.sin(angle / 2)], axis=1)
    movement = t > 2.0
    return Trial(name, gyr, acc, mag, quat, movement, rate)


def test_figures_of_known_distributions():
    from ext_observer.broad.covariance import calibration_figures

    rng = np.random.default_rng(3)
    sigma = np.full(200000, 0.01)
    heading = calibration_figures([(np.abs(rng.normal(0.0, 0.01, sigma.size)), sigma)])
    assert heading['within_2sigma'] == pytest.approx(0.954, abs=0.003)
    assert heading['mean_z2'] == pytest.approx(1.0, abs=0.01)
    # A tilt of two axes of variance σ²/2 each: its angle is within 2σ 98 % of the time.
    tilt = np.hypot(*rng.normal(0.0, 0.01 / math.sqrt(2.0), (2, sigma.size)))
    inclination = calibration_figures([(tilt, sigma)])
    assert inclination['within_2sigma'] == pytest.approx(1 - math.exp(-4.0), abs=0.003)
    assert inclination['unknown'] == 0.0


def test_replay_reproduces_the_pipelines_covariance():
    from ext_observer.broad import covariance

    trials = [synthetic_trial('02_undisturbed_a'), synthetic_trial('03_undisturbed_b', 15.0)]
    for mode in ('9D', '6D'):
        runs = [covariance.run_trial(t, mode, {'ahrs.mag_cal': False} if HAS_CALIBRATION
                                     else None) for t in trials]
        for run, trial in zip(runs, trials):
            run.update({f'gyr{j}': trial.gyr[:, j] for j in range(3)})
            run.update({f'acc{j}': trial.acc[:, j] for j in range(3)})
        ahrs = AhrsParams(mag_cal=False) if HAS_CALIBRATION else None
        for run, (tilt, heading) in zip(runs, covariance.replay(runs, ahrs_params=ahrs)):
            scored = np.isfinite(run['tilt'])
            assert np.array_equal(tilt[scored], run['tilt'][scored])
            assert np.array_equal(heading[scored], run['heading'][scored])


def test_the_benchmark_writes_its_page_and_figures(tmp_path, capsys):
    from docgen.covariance_page import write_page
    from ext_observer.broad.covariance import report

    trials = [synthetic_trial('02_undisturbed_a'),
              synthetic_trial('32_disturbed_attached_magnet_1cm'),
              synthetic_trial('29_disturbed_b')]
    groups = {'members': {'undisturbed': [trials[0].name],
                          'disturbed': [trials[1].name, trials[2].name]}}
    meta = dict(command='test', commit='abc', dirty=False, date='today', machine='here',
                data='synthetic')
    summary, runs = report(trials, groups, meta, json_path=str(tmp_path / 'c.json'))
    write_page(trials, runs, groups, summary, meta, str(tmp_path))
    assert ('9D', 'tuning', 'undisturbed', 'heading') in summary
    assert ('6D', 'held-out', 'disturbed', 'inclination') in summary
    assert 'within the coverage bounds' in capsys.readouterr().out
    page = (tmp_path / 'covariance.md').read_text()
    assert page.startswith('# The orientation covariance')
    for figure in ('covariance_reliability.png', 'covariance_magnet.png'):
        assert (tmp_path / 'figures' / figure).stat().st_size > 10000
        assert f'figures/{figure}' in page


def test_the_bound_margin_is_a_share_of_each_range_and_the_smaller_counts():
    from ext_observer.broad.covariance import bound_margin
    centre = {'within_2sigma': 0.945, 'mean_z2': 1.0}
    assert bound_margin(centre) == pytest.approx(0.5)
    # On a bound: 0; outside: negative; the figure nearer its bound decides.
    assert bound_margin({'within_2sigma': 0.90, 'mean_z2': 1.0}) == pytest.approx(0.0)
    assert bound_margin({'within_2sigma': 0.945, 'mean_z2': 0.25}) == pytest.approx(-0.5)
    assert bound_margin({'within_2sigma': 0.981, 'mean_z2': 1.0}) == pytest.approx(0.1)


def test_the_field_gap_benchmark_judges_each_trial_and_pools_the_magnet_trials(capsys):
    from ext_observer.broad.field_gap import (field_gap, gap_figures, gap_table, MAGNET_GROUP,
                                              parse_gap)

    trials = [synthetic_trial('02_undisturbed_a', 30.0),
              synthetic_trial('35_disturbed_attached_magnet_4cm', 30.0),
              synthetic_trial('04_short', 8.0)]
    groups = {'members': {MAGNET_GROUP: [trials[1].name]}}
    gap = parse_gap('10:20')
    rows = dict(field_gap(trials, groups, gap))
    assert set(rows) >= {t.name for t in trials} | {'held-out: every trial',
                                                      f'held-out: {MAGNET_GROUP}',
                                                      f'all: {MAGNET_GROUP}'}
    for name in trials[0].name, trials[1].name:
        f = rows[name]
        assert f['gone_ok'] and f['back_ok'] and f['present_ok'] is not None
        # A level body and an exact field: the heading back as it was.
        assert f['back_rms'] < max(1.5 * f['back_rms_ref'], f['back_rms_ref'] + 0.01)
    # A trial over before the gap: nothing to judge there.
    assert rows['04_short']['gone_ok'] is None and rows['04_short']['back_ok'] is None
    print(gap_table(list(rows.items()), gap))
    assert '35_disturbed_attached_magnet_4cm' in capsys.readouterr().out
    # The pass rules on known figures.
    part = {'present': np.array([1.0, 3.0]), 'gone': np.array([1.0, 5.0]),
            'back': np.array([0.03, 0.03]), 'back_ref': np.array([0.01, 0.01])}
    f = gap_figures([part])
    assert f['present_mean_z2'] == 2.0 and f['present_ok']
    assert f['gone_within_2sigma'] == 0.5 and not f['gone_ok']
    assert f['back_rms'] == pytest.approx(0.03) and f['back_ok']  # 0.01 + 1.5° allows it
    with pytest.raises(ValueError, match='START:END'):
        parse_gap('60-120')
    with pytest.raises(ValueError, match='START < END'):
        parse_gap('120:60')
