"""The simulated gyro of the paper's experiments (no ROS): seeds, kinematics, noise, errors."""

import numpy as np
from numpy.testing import assert_allclose

from ext_observer.core import PAPER_GAIN, SimulatedGyro
from ext_observer.core import quaternion as quat


def test_gyro_is_reproducible_from_its_seed():
    a = SimulatedGyro(seed=7, batch_shape=(3,)).simulate(10)
    b = SimulatedGyro(seed=7, batch_shape=(3,)).simulate(10)
    c = SimulatedGyro(seed=8, batch_shape=(3,)).simulate(10)
    for x, y in zip(a, b):
        assert_allclose(x, y)
    assert not np.allclose(a.increments, c.increments)
    assert a.increments.shape == (10, 3, 3) and a.attitudes.shape == (10, 3, 4)


def test_gyro_kinematics_and_noise():
    gyro = SimulatedGyro(increment_max=0.5, noise_std=0.1, seed=9,
                         batch_shape=(20000,))
    s = gyro.step()
    assert np.all((s.increment >= 0) & (s.increment <= 0.5))
    assert_allclose(gyro.attitude, quat.multiply(
        s.attitude, quat.quaternion_from_rotation_vector(s.increment)), atol=1e-12)
    # y = q ⊗ exp(ν): the vector part of q̄y is sin|ν| ν/|ν| ≈ ν, σ = 0.1.
    nu = quat.log(quat.multiply(quat.conjugate(s.attitude), s.measurement))[:, 1:]
    assert_allclose(nu.std(axis=0), 0.1, rtol=0.03)
    assert_allclose(nu.mean(axis=0), 0.0, atol=0.003)


def test_paper_gain_is_the_mean_increment_quaternion():
    """L = (0.11, −0.18, −0.18, −0.18) is the mean of exp(Ω/2), Ω ∈ (0, 10)³."""
    gyro = SimulatedGyro(increment_max=10.0, seed=10, batch_shape=(200000,))
    E = quat.quaternion_from_rotation_vector(gyro.step().increment)
    assert_allclose(E.mean(axis=0), PAPER_GAIN, atol=0.01)


def test_gyro_errors_perturb_only_the_reported_increment():
    clean = SimulatedGyro(seed=11, batch_shape=(1000,))
    noisy = SimulatedGyro(seed=11, batch_shape=(1000,), gyro_noise_std=0.01,
                          gyro_bias=(0.02, 0.0, 0.0))
    a, b = clean.step(), noisy.step()
    assert_allclose(a.attitude, b.attitude)
    assert_allclose(a.measurement, b.measurement)
    err = b.increment - a.increment
    assert_allclose(err.mean(axis=0), [0.02, 0, 0], atol=0.002)
    assert_allclose(err.std(axis=0), 0.01, rtol=0.1)
    assert_allclose(clean.attitude, noisy.attitude)
