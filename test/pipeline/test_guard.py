"""
The divergence guard without ROS (GuardedObserver): what it reinitializes
from (the measurement carried by the increments since, or the initial
estimate) and the reason it gives.
"""

import math

import pytest

from ext_observer.core import SingleObserver
from ext_observer.pipeline.guard import GUARD_REASONS, GuardedObserver

Y = (1.0, 0.0, 0.0, 0.0)
THETA = (0.1, 0.2, 0.3)
nan = float('nan')


def test_guard_reinitializes_from_the_carried_measurement():
    guarded = GuardedObserver(SingleObserver('plain'), max_residual=1.0)
    y = (0.0, 1.0, 0.0, 0.0)
    state, reason = guarded.step(THETA, y)
    assert reason is None
    guarded.observer.state = (3.0, 0.0, 0.0, 0.0)     # as if it had diverged
    theta = (0.0, 0.0, math.pi)
    state, reason = guarded.step(theta)
    assert reason == 'residual_too_large'
    # y, carried by the two increments since it arrived: y ⊗ exp(θ₁/2) ⊗ exp(θ₂/2).
    carried = SingleObserver('projected', gain_mode='rotating', kappa=1.0, initial=y)
    carried.step(THETA)
    expected = carried.step(theta)
    assert state == pytest.approx(expected, abs=1e-12)
    assert guarded.observer.measurements_used == 0


def test_guard_reasons():
    # Innovation: an estimate far from a unit measurement.
    guarded = GuardedObserver(SingleObserver('plain'), max_residual=100.0,
                              max_innovation=2.5)
    guarded.observer.state = (-2.0, 0.0, 0.0, 0.0)
    state, reason = guarded.step(THETA, Y)
    assert reason == 'innovation_too_large'
    assert math.hypot(*state) == pytest.approx(1.0)
    # No measurement yet: back to the initial estimate.
    guarded = GuardedObserver(SingleObserver('plain', initial=(0.0, 0.0, 1.0, 0.0)))
    guarded.observer.state = (0.0, 0.0, 0.0, 0.0)
    assert guarded.step(THETA) == ((0.0, 0.0, 1.0, 0.0), 'state_zero')
    guarded.observer.state = (nan, 0.0, 0.0, 0.0)
    assert guarded.step(THETA) == ((0.0, 0.0, 1.0, 0.0), 'state_non_finite')
    # The projected update raises at zero.
    guarded = GuardedObserver(SingleObserver('projected'))
    guarded.observer.state = (0.0, 0.0, 0.0, 0.0)
    assert guarded.step(THETA) == (Y, 'step_failed')
    assert set(GUARD_REASONS) == {'residual_too_large', 'innovation_too_large',
                                  'state_non_finite', 'state_zero', 'step_failed'}
