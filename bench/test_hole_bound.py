"""
Checks of the holes' oracle figures (``pytest bench/test_hole_bound.py``), no data, no ROS.

A made-up body turning at a constant rate about a fixed point: the bridge's
straight-line rate is exact there and the specific force is gravity alone,
so the oracle bridge and the accelerometer's window both show no error; a
truth tilted off gravity, which the window sees and the blend weighs out;
the budget's time constant, which meets its bound exactly; and the fitted
motion model, exact on rates quadratic in time and far better than the
straight line on a few slow sines.
"""

import math

import numpy as np

from bench import hole_bound, hole_predictor
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


def _smooth_trial(name, seed):
    """A body whose rates are a few slow sines per axis; its truth their usual steps (no error)."""
    rng = np.random.default_rng(seed)
    t = np.arange(int(SECONDS * RATE)) / RATE
    freq, phase = rng.uniform(0.3, 2.0, (3, 3)), rng.uniform(0.0, 2.0 * math.pi, (3, 3))
    gyr = np.sum(np.sin(2.0 * math.pi * freq * t[:, None, None] + phase), axis=2)  # rad/s
    q = [quaternion_from_rotation_vector(np.array([0.4, 0.2, 1.0]))]
    for g in gyr[1:]:
        q.append(hole_bound.gyro_through(q[-1], [g], 1.0 / RATE))
    q = np.array(q)
    into_body = conjugate(q)
    acc = hole_bound.rotate(into_body, np.array([0.0, 0.0, GRAVITY]))
    mag = hole_bound.rotate(into_body, FIELD)
    return Trial(name, gyr, acc, mag, q, np.ones(len(t), dtype=bool), RATE)


def test_the_fitted_map_carries_a_quadratic_rate_across_a_hole_exactly():
    # Quadratics in time are a shift-invariant space: any window of one is a
    # sum of windows of others, so a map fitted on two trials holds on a third.
    t = np.arange(int(SECONDS * RATE)) / RATE

    def quadratic(name, seed):
        c = np.random.default_rng(seed).normal(size=(3, 3))
        gyr = c[0] + c[1] * t[:, None] / SECONDS + c[2] * (t[:, None] / SECONDS) ** 2
        return Trial(name, gyr, gyr, gyr, np.ones((len(t), 4)), np.ones(len(t), dtype=bool), RATE)
    # (A ridge far below the default's: the windows of a slow quadratic are nearly collinear.)
    model = hole_predictor.MotionModel([quadratic('02_a', 1), quadratic('04_b', 2)], 'causal',
                                       ks=(3,), ridges=(1e-14,))
    gyr = quadratic('01_c', 3).gyr
    i0, i1 = 500, 521
    lost = model.predict(gyr, i0, i1)
    np.testing.assert_allclose(lost, gyr[i0 + 1:i1], atol=1e-6)
    straight = gyr[i0] + np.outer(np.arange(1, i1 - i0) / (i1 - i0), gyr[i1] - gyr[i0])
    assert np.abs(straight - gyr[i0 + 1:i1]).max() > 1e-4  # (the line misses the curve)


def test_a_fitted_motion_model_beats_the_straight_line_on_a_smooth_turn():
    train = [_smooth_trial('02_made_up', 1), _smooth_trial('04_made_up', 2)]
    models = {shape: hole_predictor.MotionModel(train, shape, ks=(3, 10))
              for shape in hole_predictor.SHAPES}
    found = hole_bound.trial_holes(_smooth_trial('01_undisturbed_made_up', 3), 'burst200ms',
                                   models)
    assert len(found['bridge']) >= 4
    assert np.abs(found['floor']).max() < 1e-6  # rad (the error's angle from a rounded cosine)
    bridge = hole_bound.rms_deg(found['bridge'][:, 0])
    assert bridge > 1.0  # degrees: the sines turn within 200 ms
    assert hole_bound.rms_deg(found['causal'][:, 0]) < 0.5 * bridge
    assert hole_bound.rms_deg(found['two-sided'][:, 0]) < 0.1 * bridge
    # The two-sided model's vertical is known only once its samples after the hole have come.
    reach = models['two-sided'].reach(20 - 1)
    assert reach > 1
    assert found['model_up'].shape == found['acc_up'].shape
