"""
What the gyro's own samples say (``clip_and_rest.py``): a rate at the sensor's range, a body at rest.

Each function is called on an estimator's state record (plain kernels, one
sample of a level body first, so that the coefficients are set) and its
fields compared with what its docstring states: a clipped axis adds
``(range dt)²`` and counts the sample once; without a known range a rate
repeated at the largest magnitude seen is clipped from its second repeat;
rest is the low-passed rate and the specific force still for
``rest_time``, and at rest the bias moves toward the low-passed rate,
within ``bias_max``. No ROS.
"""

import math

import pytest

from ext_observer.core.ahrs.ahrs_observer import AhrsObserver, AhrsParams
from ext_observer.core.ahrs.clip_and_rest import clipped_variance, detect_rest

DT = 0.01
LEVEL = (0.0, 0.0, 9.81)
STILL = (0.0, 0.0, 0.0)


def state(**params):
    """The state record of a plain estimator after one still, level sample at ``DT``."""
    est = AhrsObserver(AhrsParams(**params), use_mag=False, compiled=False)
    est.update(STILL, LEVEL, None, DT)
    s = est.state[0]
    assert s.coef.dt == DT
    return s


# --- a rate at the gyro's range ------------------------------------------------

def test_each_axis_at_a_known_range_adds_range_dt_squared_and_counts_the_sample_once():
    s = state(gyro_range=4.0)
    clips = s.gyro.clips
    assert clipped_variance(s, 4.0, -1.0, 0.5) == pytest.approx((4.0 * DT) ** 2, rel=1e-15)
    assert s.gyro.clipped == pytest.approx((4.0 * DT) ** 2, rel=1e-15)
    assert s.gyro.clips == clips + 1.0
    assert clipped_variance(s, -4.0, 4.0, -4.0) == pytest.approx(3 * (4.0 * DT) ** 2, rel=1e-15)
    assert s.gyro.clips == clips + 2.0
    # Below the range: nothing added, nothing counted, the slot cleared.
    assert clipped_variance(s, 3.9, -3.9, 0.0) == 0.0
    assert s.gyro.clipped == 0.0 and s.gyro.clips == clips + 2.0


def test_a_rate_within_a_ten_thousandth_of_the_range_is_at_it():
    s = state(gyro_range=4.0)
    assert clipped_variance(s, 4.0 * (1.0 - 0.9e-4), 0.0, 0.0) > 0.0
    assert clipped_variance(s, 4.0 * (1.0 - 1.1e-4), 0.0, 0.0) == 0.0


def test_with_the_range_unknown_the_top_is_the_largest_rate_seen():
    s = state()
    # Rates that move are never stuck, whatever their size.
    for g in (5.0, 6.0, 6.5):
        assert clipped_variance(s, g, 0.0, 0.0) == 0.0
    assert s.gyro.peak == 6.5
    # The largest rate repeated: stuck from the second repeat, the top 6.5 dt.
    assert clipped_variance(s, 6.5, 0.0, 0.0) == 0.0
    assert s.gyro.stuck[0] == 1.0
    assert clipped_variance(s, 6.5, 0.0, 0.0) == pytest.approx((6.5 * DT) ** 2, rel=1e-15)
    assert s.gyro.stuck[0] == 2.0
    # A new value ends it.
    assert clipped_variance(s, 6.4, 0.0, 0.0) == 0.0
    assert s.gyro.stuck[0] == 0.0


@pytest.mark.parametrize('axis', [0, 1, 2])
def test_a_rate_below_any_gyros_range_repeated_is_not_stuck(axis):
    s = state()
    rate = [0.0, 0.0, 0.0]
    rate[axis] = -1.9  # rad/s: below the smallest range a gyro has (±125 °/s)
    for _ in range(10):
        assert clipped_variance(s, *rate) == 0.0
    assert s.gyro.stuck[axis] == 0.0


def test_each_sample_keeps_the_last_two_rates_for_a_holes_end():
    s = state()
    clipped_variance(s, 0.1, 0.2, 0.3)
    clipped_variance(s, 0.4, 0.5, 0.6)
    assert list(s.gyro.prev) == [0.1, 0.2, 0.3]
    assert list(s.gyro.last) == [0.4, 0.5, 0.6]


# --- rest -----------------------------------------------------------------------

def still_for(s, seconds, rate=(0.0, 0.0, 0.0)):
    for _ in range(round(seconds / DT)):
        s.rest.acc_still = 1.0
        detect_rest(s, *rate)


def test_rest_comes_after_rest_time_of_a_still_gyro_and_specific_force():
    params = AhrsParams()
    s = state()
    still_for(s, params.rest_time - 2 * DT)
    assert s.rest.detected == 0.0
    still_for(s, 3 * DT)
    assert s.rest.detected == 1.0
    # A specific force that moves ends it at once, and the time starts over.
    s.rest.acc_still = 0.0
    detect_rest(s, 0.0, 0.0, 0.0)
    assert s.rest.detected == 0.0 and s.rest.time == 0.0


def test_a_rate_that_leaves_the_low_pass_by_more_than_rest_gyr_ends_rest():
    params = AhrsParams()
    s = state()
    still_for(s, params.rest_time + 0.1)
    assert s.rest.detected == 1.0
    s.rest.acc_still = 1.0
    detect_rest(s, 0.0, 0.0, 1.2 * params.rest_gyr / (1.0 - s.coef.k_rest))
    assert s.rest.detected == 0.0 and s.rest.time == 0.0


def test_the_rate_is_low_passed_with_the_rests_gain():
    s = state()
    k = s.coef.k_rest
    assert k == pytest.approx(1.0 - math.exp(-DT / AhrsParams().tau_rest), rel=1e-12)
    before = list(s.rest.gyr_lp)
    s.rest.acc_still = 1.0
    detect_rest(s, 0.01, -0.02, 0.03)
    for i, g in enumerate((0.01, -0.02, 0.03)):
        assert s.rest.gyr_lp[i] == pytest.approx(before[i] + k * (g - before[i]), rel=1e-15)


def test_at_rest_the_bias_moves_toward_the_low_passed_rate_within_bias_max():
    params = AhrsParams()
    s = state()
    bias = (0.004, -0.006, 0.02)  # rad/s, within rest_gyr of a zero bias
    still_for(s, params.rest_time + 20 * params.tau_rest, rate=bias)
    assert s.rest.detected == 1.0
    assert list(s.bias.rate) == pytest.approx(bias, abs=1e-6)
    # Out of rest the bias stays where it is.
    held = list(s.bias.rate)
    s.rest.acc_still = 0.0
    detect_rest(s, 0.0, 0.0, 0.0)
    assert list(s.bias.rate) == held


def test_a_bias_learned_at_rest_is_clipped_at_bias_max():
    # A bias already at bias_max (learned in motion): a rate beyond it by less
    # than half of rest_gyr is still rest, and the bias stays at bias_max.
    params = AhrsParams()
    s = state()
    s.bias.rate[2] = params.bias_max
    rate = params.bias_max + 0.4 * params.rest_gyr
    still_for(s, params.rest_time + 10 * params.tau_rest, rate=(0.0, 0.0, rate))
    assert s.rest.detected == 1.0
    assert s.bias.rate[2] == params.bias_max
    # Beyond it by more than half of rest_gyr: a steady turn, never rest.
    s = state()
    s.bias.rate[2] = params.bias_max
    still_for(s, params.rest_time + 10 * params.tau_rest,
              rate=(0.0, 0.0, params.bias_max + 0.6 * params.rest_gyr))
    assert s.rest.detected == 0.0


def test_a_steady_rate_farther_than_rest_gyr_from_the_bias_is_not_rest():
    # Within bias_max + rest_gyr / 2 (no steady turn), but farther than
    # rest_gyr from the bias learned so far: not rest, the bias unchanged.
    params = AhrsParams()
    s = state()
    rate = 1.3 * params.rest_gyr
    assert rate < params.bias_max + 0.5 * params.rest_gyr
    still_for(s, params.rest_time + 10 * params.tau_rest, rate=(0.0, 0.0, rate))
    assert s.rest.detected == 0.0 and s.bias.rate[2] == 0.0
