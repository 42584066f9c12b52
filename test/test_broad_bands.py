"""
The BROAD trials that move most when the estimator breaks, each held to ±5 % of docs/broad.md.

Chosen by a measured criterion (docs/tests.md#real-data-that-discriminates,
``mutation/trial_sensitivity.py``): for each estimator mutant of
mutation/mutants.toml that moves some trial beyond the band but does not
break every trial, the two trials it moves most. The expected values are
read from the per-trial table of docs/broad.md when the test runs, never
typed here: whoever changes the estimator regenerates the page
(``make broad``) and the bands move with it.
The 9D total RMSE and the 6D inclination RMSE of each trial, our estimator
with its shipped defaults through the benchmark's own path, must be within
5 % of the page's figure (plus its rounding to 0.01°).

Needs BROAD (as test_broad_whole_trials.py: ``make broad-data``, or
``EXT_OBSERVER_BROAD_DATA``; ``EXT_OBSERVER_ALLOW_NO_BROAD=1`` skips).
"""

import os

import pytest

from broad_data import run_against_page
from conftest import REPO
from ext_observer import broad
from test_broad_whole_trials import COLUMNS, page_figures

PAGE = os.path.join(REPO, 'docs', 'broad.md')
# The two trials each subtle mutant moves most (and 29, the only one the
# calibration's gate shows on): the lag ignored 09, 18; a field rejected
# only when both its norm and dip are off 15, 01; no gate 29.
TRIALS = ('01_undisturbed_slow_rotation_A',
          '09_undisturbed_fast_rotation_with_breaks_B',
          '15_undisturbed_fast_translation_A',
          '18_undisturbed_fast_translation_with_breaks_B',
          '29_disturbed_stationary_magnet_B')
BAND = 0.05
ROUNDING = 0.005  # the page's figures are rounded to 0.01°


def outside(measured, reported, band=BAND):
    """``(trial, mode, key, measured, expected)`` of each figure outside the band."""
    off = []
    for (mode, key), column in COLUMNS.items():
        for name, figures in measured.items():
            expected = float(reported[name][column])
            value = figures[mode][key]
            if not abs(value - expected) <= band * expected + ROUNDING:
                off.append((name, mode, key, value, expected))
    return off


def test_the_band_is_five_percent_of_the_pages_figure():
    reported = {'a': {COLUMNS[('9D', 'total_rmse_deg')]: '2.00',
                      COLUMNS[('6D', 'inclination_rmse_deg')]: '1.00'}}

    def measured(total, inclination):
        return {'a': {'9D': {'total_rmse_deg': total},
                      '6D': {'inclination_rmse_deg': inclination}}}

    assert outside(measured(2.0 * 1.05 + 0.004, 1.0), reported) == []
    assert outside(measured(2.0 * 0.95 - 0.004, 1.0 * 1.05), reported) == []
    assert [o[:2] for o in outside(measured(2.0 * 1.05 + 0.006, 1.0), reported)] == [('a', '9D')]
    assert [o[:2] for o in outside(measured(2.0, 0.94), reported)] == [('a', '6D')]


@pytest.mark.timeout(300)
def test_the_discriminating_trials_are_within_five_percent_of_the_page():
    reported, result, _ = run_against_page(TRIALS, PAGE, page_figures)
    ours = result['scores'][broad.OURS]
    measured = {name: {mode: ours[mode][name] for mode in broad.MODES} for name in TRIALS}
    off = outside(measured, reported)
    assert not off, ('outside ±5 % of docs/broad.md (a regression, or the page is stale: '
                     'make broad):\n' + '\n'.join(
                         f'{n} {m} {k}: {v:.3f}°, the page {e:.2f}°' for n, m, k, v, e in off))
