"""Tests of the input validation and the divergence guard (no ROS)."""

import math

from hypothesis import given, settings
from hypothesis import strategies as st
import pytest

from ext_observer.core import SingleObserver
from ext_observer.core.validation import (check_increment, check_measurement,
                                          check_state)

any_float = st.floats(allow_nan=True, allow_infinity=True, allow_subnormal=True)
# Components that make increments on both sides of the bound (20 rad).
near_bound = st.floats(-25.0, 25.0)
nan, inf = float('nan'), float('inf')


@pytest.mark.parametrize('theta, reason', [
    ((0.1, 0.2, 0.3), None),
    ((nan, 0, 0), 'non_finite'),
    ((0, -inf, 0), 'non_finite'),
    ((30.0, 0, 0), 'increment_too_large'),
    ((1e200, 1e200, 0), 'increment_too_large'),
])
def test_check_increment(theta, reason):
    assert check_increment(theta, 20.0) == reason


@pytest.mark.parametrize('y, reason', [
    ((1.0, 0, 0, 0), None),
    ((0.0, 0.0, 0.0, 1.05), None),
    ((nan, 0, 0, 0), 'non_finite'),
    ((0, 0, inf, 0), 'non_finite'),
    ((0.0, 0.0, 0.0, 0.0), 'zero_quaternion'),
    ((1e-9, 0.0, 0.0, 0.0), 'zero_quaternion'),
    ((5e-324, 0.0, 0.0, 0.0), 'zero_quaternion'),
    ((2.0, 0.0, 0.0, 0.0), 'norm_out_of_tolerance'),
    ((1e300, 1e300, 0.0, 0.0), 'norm_out_of_tolerance'),
])
def test_check_measurement(y, reason):
    unit, why = check_measurement(y, 0.1)
    assert why == reason
    if reason is None:
        assert math.isclose(math.sqrt(sum(v * v for v in unit)), 1.0)
    else:
        assert unit is None


def test_check_state():
    assert check_state((1.0, 0, 0, 0)) is None
    assert check_state((nan, 0, 0, 0)) == 'state_non_finite'
    assert check_state((3.0, 0, 0, 0), max_residual=1.0) == 'residual_too_large'
    assert check_state((1.0, 0, 0, 0), 2.5, max_innovation=2.0) == \
        'innovation_too_large'
    # A zero estimate has no attitude: the guard's last reason, after the others.
    assert check_state((0.0, 0.0, 0.0, 0.0)) == 'state_zero'
    assert check_state((1e-7, 0.0, 0.0, 0.0)) == 'state_zero'
    assert check_state((2e-6, 0.0, 0.0, 0.0)) is None
    assert check_state((0.0, 0.0, 0.0, 0.0), max_residual=0.5) == 'residual_too_large'


@settings(max_examples=500, deadline=None)
@given(st.lists(st.one_of(any_float, near_bound), min_size=3, max_size=3),
       st.lists(any_float, min_size=4, max_size=4))
def test_validated_step_stays_finite_or_rejects(theta, y):
    """Arbitrary floats: either rejected with a reason or the state stays finite."""
    obs = SingleObserver('extended')
    theta_reason = check_increment(theta, 20.0)
    unit, y_reason = check_measurement(y, 0.1)
    if theta_reason is not None:
        # Rejected for the reason the increment has (hypot neither
        # overflows nor underflows on finite components).
        if all(map(math.isfinite, theta)):
            assert theta_reason == 'increment_too_large'
            assert math.hypot(*theta) > 20.0 * (1 - 1e-12)
        else:
            assert theta_reason == 'non_finite'
        return
    assert math.hypot(*theta) <= 20.0 * (1 + 1e-12)
    for _ in range(3):
        state = obs.step(theta, unit)
    assert all(map(math.isfinite, state))
    assert check_state(state) is None
    if y_reason is not None:
        assert y_reason in ('non_finite', 'zero_quaternion', 'norm_out_of_tolerance')
