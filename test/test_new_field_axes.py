"""
A new field is accepted while the body turns about any axis, in any attitude (a fault that matters).

The field the estimator rejects as disturbed is taken as the new normal
once it has stayed consistent for ``mag_new_time`` while the body turns
faster than ``mag_new_gyr``. The turning check reads the low-passed rate;
read from the wrong slots (``S_REST_GYR + 1 … + 3``) it passed the old test,
which turns about z while level (where those slots hold the same values),
and left a sensor pitched 15° with a magnet appearing 39° off in heading.
Here the body turns about its x and its y axis, pitched, rolled and both,
with and without a field of its own: accepted on time, heading right after.
"""

import math

import pytest

from ext_observer.core.ahrs.estimator import AhrsObserver, AhrsParams
from test_ahrs_params import (angle_deg, DT, FIELD, first_index, qexp, qmul, RATE, run,
                                   simulate, turning)

# s: from here on the field is 30 % stronger (a new place); later than
# MAG_NEW_TIME, so that the references have been confirmed for longer than
# that and the new field waits the whole MAG_NEW_TIME (a new field is never
# made to wait longer than fields confirmed the references).
CHANGE = 5.0
MAG_NEW_TIME = 4.0
ATTITUDES = {'pitched': qexp((0.0, math.radians(15.0), 0.0)),
             'rolled': qexp((math.radians(15.0), 0.0, 0.0)),
             'pitched and rolled': qmul(qexp((0.0, 0.0, 0.4)),
                                        qmul(qexp((0.0, math.radians(15.0), 0.0)),
                                             qexp((math.radians(-20.0), 0.0, 0.0))))}


def stronger(k):
    return tuple(1.3 * v for v in FIELD) if k * DT >= CHANGE else FIELD


def about(axis, seconds, rate=0.5):
    """Turning about the body's ``axis`` (0: x, 1: y, 2: z) at ``rate`` rad/s."""
    rates = turning(seconds, 0.0)
    rates[:, axis] = rate
    return rates


@pytest.mark.parametrize('attitude', sorted(ATTITUDES))
@pytest.mark.parametrize('axis', [0, 1, 2])
def test_a_new_field_is_accepted_turning_about_any_axis_in_any_attitude(axis, attitude):
    seconds = CHANGE + MAG_NEW_TIME + 3.0
    truth, gyr, acc, mag = simulate(about(axis, seconds), q0=ATTITUDES[attitude],
                                    field=stronger)
    est = AhrsObserver(AhrsParams(mag_new_time=MAG_NEW_TIME, mag_new_gyr=0.45), use_mag=True)
    out = run(est, gyr, acc, mag)
    disturbed = [d for _, _, d, _ in out]
    start = round(CHANGE * RATE)
    assert first_index(disturbed) == start
    assert first_index(disturbed[start:], False) == pytest.approx(MAG_NEW_TIME * RATE, abs=2)
    assert not any(disturbed[start + round(MAG_NEW_TIME * RATE) + 2:])
    # The heading follows the new field (the same direction, stronger).
    errors = [angle_deg(q, truth[k]) for k, (q, *_) in enumerate(out)]
    assert max(errors[-round(RATE):]) < 1.0


@pytest.mark.parametrize('axis', [0, 1, 2])
def test_turning_slower_than_mag_new_gyr_about_any_axis_keeps_the_field_rejected(axis):
    # The same, turning at 0.4 rad/s under mag_new_gyr 0.45: never accepted.
    seconds = CHANGE + MAG_NEW_TIME + 3.0
    _, gyr, acc, mag = simulate(about(axis, seconds, rate=0.4), q0=ATTITUDES['pitched'],
                                field=stronger)
    est = AhrsObserver(AhrsParams(mag_new_time=MAG_NEW_TIME, mag_new_gyr=0.45), use_mag=True)
    disturbed = [d for _, _, d, _ in run(est, gyr, acc, mag)]
    start = round(CHANGE * RATE)
    assert first_index(disturbed) == start
    assert all(disturbed[start:])
