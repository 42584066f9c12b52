"""
Checks of the holes' oracle figures (``pytest bench/test_hole_bound.py``), no data, no ROS.

A made-up body turning at a constant rate about a fixed point: the bridge's
straight-line rate is exact there and the specific force is gravity alone,
so the oracle bridge and the accelerometer's window both show no error; a
truth tilted off gravity, which the window sees and the blend weighs out;
and the budget's time constant, which meets its bound exactly.
"""

import math

import numpy as np

from bench import hole_bound
from ext_observer.broad.data import Trial
from ext_observer.core.quaternion import conjugate, multiply, quaternion_from_rotation_vector

RATE = 100.0  # Hz
SECONDS = 12.0
RATE_VECTOR = np.array([0.3, -0.5, 0.8])  # rad/s, body frame
GRAVITY = 9.81
FIELD = np.array([20.0, 0.0, -40.0])  # µT, world
TOLERANCE = math.radians(1e-6)


def _turning_trial():
    """A body turning at :data:`RATE_VECTOR` from a tilted start, its sensors without noise."""
    t = np.arange(int(SECONDS * RATE)) / RATE
    start = quaternion_from_rotation_vector(np.array([0.4, 0.2, 1.0]))
    q = multiply(start, quaternion_from_rotation_vector(t[:, None] * RATE_VECTOR))
    into_body = conjugate(q)
    acc = hole_bound.rotate(into_body, np.array([0.0, 0.0, GRAVITY]))
    mag = hole_bound.rotate(into_body, FIELD)
    gyr = np.tile(RATE_VECTOR, (len(t), 1))
    return Trial('02_undisturbed_made_up', gyr, acc, mag, q, np.ones(len(t), dtype=bool), RATE)


def test_a_constant_turn_leaves_neither_the_bridge_nor_the_windows_an_error():
    found = hole_bound.trial_holes(_turning_trial(), 'burst200ms')
    assert len(found['bridge']) >= 4
    assert np.abs(found['bridge']).max() < TOLERANCE
    assert np.abs(found['floor']).max() < TOLERANCE
    assert np.abs(hole_bound.angle_from_up(found['acc_up'])).max() < TOLERANCE
    assert np.abs(found['heading']).max() < TOLERANCE
    # Every bin of the 1.8 s after a 200 ms hole is a kept sample, none beyond.
    assert found['scored'].sum(axis=1).max() == round(1.8 / hole_bound.BIN)


def test_a_wrong_vertical_is_seen_by_the_window_and_weighed_out_by_the_blend():
    trial = _turning_trial()
    tilt = quaternion_from_rotation_vector(np.array([math.radians(5.0), 0.0, 0.0]))
    trial.quat = multiply(tilt, trial.quat)  # the truth tilted: the specific force is off by 5°
    found = hole_bound.trial_holes(trial, 'burst200ms')
    acc = hole_bound.angle_from_up(found['acc_up'])
    np.testing.assert_allclose(acc, math.radians(5.0), atol=1e-9)
    weights = hole_bound.blend_weights(found['prior_up'], found['acc_up'], found['scored'])
    scored = found['scored'].any(axis=0)
    np.testing.assert_allclose(weights[scored], 1.0, atol=1e-9)
    assert np.isnan(weights[~scored]).all()


def test_the_budgets_time_constant_meets_the_bound_exactly():
    e0, full, ratio, kept = 12.0, 0.7, 2.0, 1.8
    tau = hole_bound.budget_tau([e0], full, ratio, kept)
    g = tau * (1.0 - math.exp(-2.0 * kept / tau)) / (2.0 * kept)
    assert math.isclose(math.sqrt(full ** 2 + e0 ** 2 * g), ratio * full, rel_tol=1e-6)
    assert 0.0 < tau < 0.1
    assert hole_bound.budget_tau([1.0], full, ratio, kept) == math.inf
