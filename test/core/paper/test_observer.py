"""Tests of the observers and the gyro model (no ROS)."""

import subprocess
import sys

from hypothesis import given, settings
from hypothesis import strategies as st
import numpy as np
from numpy.testing import assert_allclose, assert_array_equal
import pytest

from ext_observer.core import (LuenbergerObserver, PAPER_GAIN, SimulatedGyro,
                               SingleObserver, VARIANTS)
from ext_observer.core import quaternion as quat


def test_core_imports_no_ros():
    # In a fresh interpreter: the ROS tests of this run import rclpy here.
    code = ('import sys, ext_observer.core, ext_observer.paper.reproduce; '
            'bad = [m for m in sys.modules if m.split(".")[0] in '
            '("rclpy", "rcl_interfaces", "geometry_msgs")]; '
            'assert not bad, bad')
    subprocess.run([sys.executable, '-c', code], check=True, timeout=60)


def test_variants_differ_exactly_by_their_term():
    rng = np.random.default_rng(0)
    q = rng.standard_normal((7, 4))
    theta = rng.uniform(0, 10, (7, 3))
    y = quat.random_unit_quaternions(rng, (7,))
    alpha = 0.01
    states = {}
    for variant in VARIANTS:
        obs = LuenbergerObserver(variant, alpha=alpha, batch_shape=(7,))
        obs.reset(q)
        states[variant] = obs.step(theta, y)
    E = quat.quaternion_from_rotation_vector(theta)
    plain = quat.multiply(q, E) + quat.multiply(y - q, np.array(PAPER_GAIN))
    assert_allclose(states['plain'], plain, atol=1e-14)
    term = 4 * alpha * quat.multiply(
        q * (quat.squared_norm(q) - 1)[:, None], E)
    assert_allclose(states['extended'], plain - term, atol=1e-14)
    assert_allclose(states['projected'], quat.normalize(plain), atol=1e-14)


def test_step_without_measurement_propagates_with_extension_only():
    obs = LuenbergerObserver('extended', alpha=0.01, initial=(1.2, 0, 0, 0))
    theta = np.array([0.1, 0.2, 0.3])
    E = quat.quaternion_from_rotation_vector(theta)
    expected = quat.multiply([1.2, 0, 0, 0], E) * (1 - 4 * 0.01 * (1.44 - 1))
    assert_allclose(obs.step(theta), expected)
    assert obs.measurements_used == 0
    plain = LuenbergerObserver('plain', initial=(1.2, 0, 0, 0))
    assert_allclose(plain.step(theta), quat.multiply([1.2, 0, 0, 0], E))


@pytest.mark.parametrize('gain_mode', ['constant', 'rotating', 'scheduled'])
@pytest.mark.parametrize('variant', VARIANTS)
def test_single_float_observer_matches_batched(variant, gain_mode):
    gyro = SimulatedGyro(seed=1)
    kwargs = dict(variant=variant, alpha=0.01, initial=(0.9, 0.1, 0, 0),
                  gain_mode=gain_mode, kappa=0.3, kappa_min=0.05)
    batch = LuenbergerObserver(**kwargs)
    single = SingleObserver(**kwargs)
    for k in range(60):
        s = gyro.step()
        y = None if k % 7 == 3 else s.measurement
        b = batch.step(s.increment, y)
        f = single.step(tuple(s.increment), None if y is None else tuple(y))
        assert_allclose(f, b, rtol=1e-12, atol=1e-14)


def test_rotating_gain_contracts_plain_error_by_one_minus_kappa():
    gyro = SimulatedGyro(noise_std=0.0, seed=2, batch_shape=(100,))
    kappa = 0.3
    obs = LuenbergerObserver('plain', gain_mode='rotating', kappa=kappa,
                             batch_shape=(100,))
    for _ in range(20):
        s = gyro.step()
        before = np.linalg.norm(s.attitude - obs.state, axis=-1)
        obs.step(s.increment, s.measurement)
        after = np.linalg.norm(gyro.attitude - obs.state, axis=-1)
        assert_allclose(after, (1 - kappa) * before, rtol=1e-9, atol=1e-14)


def test_scheduled_gain_averages_then_floors():
    obs = SingleObserver(gain_mode='scheduled', kappa_min=0.1)
    assert [obs.config.kappa_at(j) for j in range(12)][:3] == [1.0, 0.5, 1 / 3]
    assert obs.config.kappa_at(50) == 0.1
    # Without rotation and noise-free, κ = 1 at the first measurement
    # jumps the estimate onto it.
    y = quat.normalize(np.array([0.3, 0.4, 0.5, 0.6]))
    assert_allclose(obs.step((0.0, 0.0, 0.0), tuple(y)), y, atol=1e-12)


def test_extended_observer_beats_plain_on_the_paper_setup():
    gyro = SimulatedGyro(increment_max=10.0, noise_std=0.1, seed=3,
                         batch_shape=(500,))
    obs = {v: LuenbergerObserver(v, batch_shape=(500,)) for v in VARIANTS}
    for _ in range(100):
        s = gyro.step()
        for o in obs.values():
            o.step(s.increment, s.measurement)
    err = {v: np.linalg.norm(gyro.attitude - o.state, axis=-1).mean()
           for v, o in obs.items()}
    dist = {v: quat.constraint_residual(o.state).mean() for v, o in obs.items()}
    assert err['extended'] < err['plain']
    assert dist['extended'] < dist['plain']
    assert dist['projected'] < 1e-12
    assert 0.1 < err['extended'] < 0.2


@pytest.mark.parametrize('kwargs, reason', [
    (dict(variant='kalman'), 'variant must be one of'),
    (dict(alpha=0.0), 'alpha must be positive'),
    (dict(alpha=float('nan')), 'alpha must be positive'),
    (dict(gain=(1, 2, 3)), 'gain must have 4 elements'),
    (dict(gain=(0, float('inf'), 0, 0)), 'gain must be finite'),
    (dict(initial=(0, 0, 0, 0)), 'nonzero'),
    (dict(gain_mode='adaptive'), 'gain_mode must be one of'),
    (dict(kappa=1.5), r'kappa must be in \(0, 1\]'),
])
def test_invalid_parameters_are_refused_with_reason(kwargs, reason):
    for cls in (LuenbergerObserver, SingleObserver):
        with pytest.raises(ValueError, match=reason):
            cls(**kwargs)


@settings(max_examples=300, deadline=None)
@given(st.lists(st.floats(-20, 20, allow_nan=False), min_size=3, max_size=3),
       st.lists(st.floats(-2, 2, allow_nan=False), min_size=4, max_size=4))
def test_observer_step_stays_finite_for_bounded_inputs(theta, y):
    obs = SingleObserver('extended')
    for _ in range(5):
        state = obs.step(theta, y)
    assert all(np.isfinite(state))


def test_sign_alignment_makes_flipped_measurements_harmless():
    """y and −y are one rotation: with align_sign the estimate ignores the flip."""
    runs = 300
    gyro = SimulatedGyro(increment_max=0.5, noise_std=0.02, seed=12,
                         batch_shape=(runs,))
    rng = np.random.default_rng(13)
    kwargs = dict(variant='extended', gain_mode='rotating', kappa=0.2,
                  batch_shape=(runs,))
    aligned = LuenbergerObserver(align_sign=True, **kwargs)
    naive = LuenbergerObserver(align_sign=False, **kwargs)
    single = SingleObserver('extended', gain_mode='rotating', kappa=0.2,
                            align_sign=True)
    for _ in range(80):
        s = gyro.step()
        flip = np.where(rng.uniform(size=(runs, 1)) < 0.5, -1.0, 1.0)
        y = s.measurement * flip
        aligned.step(s.increment, y)
        naive.step(s.increment, y)
        single.step(tuple(s.increment[0]), tuple(y[0]))
    assert_allclose(single.state, aligned.state[0], rtol=1e-10, atol=1e-12)
    angle_aligned = quat.attitude_error(gyro.attitude, aligned.state)
    angle_naive = quat.attitude_error(gyro.attitude, naive.state)
    assert np.max(angle_aligned) < 0.1
    assert np.mean(angle_naive) > 5 * np.mean(angle_aligned)
    assert np.mean(angle_naive) > 0.1


def test_batch_broadcasts_a_shared_increment_and_measurement():
    rng = np.random.default_rng(14)
    q0 = rng.standard_normal((3, 5, 4))
    theta = rng.uniform(0, 1, 3)
    y = quat.random_unit_quaternions(rng, (5,))
    obs = LuenbergerObserver('extended', batch_shape=(3, 5))
    inputs = dict(q0=q0, theta=theta, y=y)
    copies = {name: a.copy() for name, a in inputs.items()}
    obs.reset(q0)
    new = obs.step(theta, y)
    assert new.shape == (3, 5, 4)
    single = SingleObserver('extended', initial=tuple(q0[2, 4]))
    assert_allclose(new[2, 4], single.step(tuple(theta), tuple(y[4])),
                    rtol=1e-12)
    # The caller's arrays are never modified: the inputs (also a shared
    # rotation and a measurement whose sign is flipped), and an estimate
    # returned earlier.
    returned = new.copy()
    rotation = quat.quaternion_from_rotation_vector(theta)
    flipped = -y
    for name, a in (('rotation', rotation), ('flipped', flipped)):
        inputs[name], copies[name] = a, a.copy()
    flipping = LuenbergerObserver('extended', batch_shape=(3, 5), gain_mode='rotating',
                                  align_sign=True)
    flipping.reset(q0)
    for observer in (obs, flipping):
        observer.step(theta, flipped)
        observer.step(None, y, rotation=rotation)
        observer.step(theta)
    for name, a in inputs.items():
        assert_array_equal(a, copies[name], err_msg=name)
    assert_array_equal(new, returned)
