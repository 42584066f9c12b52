"""The smoothed attitude (smoother_rts) on a synthetic recording whose truth is known."""

import numpy as np
import pytest

from ext_observer.broad.scoring import error_angles
from ext_observer.core.ahrs.ahrs_observer import AhrsObserver
from ext_observer.core.ahrs.smoother_rts import smooth_attitude_rts
from ext_observer.core.quaternion import conjugate, multiply, quaternion_from_rotation_vector

RATE = 100.0
BIAS = np.array([0.02, -0.01, 0.015])  # rad/s
FIELD = np.array([0.0, 20.0, -40.0])  # ENU, µT: north and down


def _rotate(q, v):
    """``R(q) v`` row by row."""
    pure = np.concatenate([np.zeros((len(v), 1)), v], axis=1)
    return multiply(multiply(q, pure), conjugate(q))[:, 1:]


def recording(seconds=60.0, seed=3):
    """A body that turns and sways: truth (N, 4) and gyr, acc, mag with noise and a gyro bias."""
    rng = np.random.default_rng(seed)
    count = int(seconds * RATE)
    t = np.arange(count) / RATE
    omega = np.stack([0.8 * np.sin(0.7 * t + 0.3), 0.6 * np.sin(0.45 * t + 1.1),
                      0.9 * np.sin(0.3 * t + 2.0)], axis=1)
    # The gyro of sample n turns the body from n − 1 to n (the estimators' convention).
    steps = quaternion_from_rotation_vector(omega / RATE)
    truth = np.empty((count, 4))
    truth[0] = (1.0, 0.0, 0.0, 0.0)
    for n in range(1, count):
        truth[n] = multiply(truth[n - 1], steps[n])
    # A velocity that stays small: 0.3 m/s swaying in each world axis.
    accel = np.stack([0.3 * w * np.cos(w * t) for w in (1.3, 0.9, 1.7)], axis=1)
    inverse = conjugate(truth)
    acc = _rotate(inverse, accel + (0.0, 0.0, 9.81))
    mag = _rotate(inverse, np.broadcast_to(FIELD, (count, 3)))
    gyr = omega + BIAS + rng.normal(0.0, 0.005, (count, 3))
    acc = acc + rng.normal(0.0, 0.05, (count, 3))
    mag = mag + rng.normal(0.0, 0.3, (count, 3))
    return truth, gyr, acc, mag


def _rms(angles, start=int(5 * RATE)):
    return float(np.sqrt(np.mean(angles[start:] ** 2)))


@pytest.fixture(scope='module')
def synthetic():
    return recording()


@pytest.mark.parametrize('mode', ['9D', '6D'])
def test_the_smoothed_error_is_below_the_online_one(synthetic, mode):
    truth, gyr, acc, mag = synthetic
    field = mag if mode == '9D' else None
    q, _ = smooth_attitude_rts(gyr, acc, field, RATE, calibration=(np.zeros(3), np.eye(3)))
    online = AhrsObserver(use_mag=mode == '9D').run(gyr, acc, field, 1.0 / RATE)
    pick = 0 if mode == '9D' else 2  # the total in 9D, the inclination in 6D
    smoothed = _rms(error_angles(q, truth)[pick])
    causal = _rms(error_angles(online, truth)[pick])
    assert smoothed < 0.7 * causal, (smoothed, causal)
    assert np.allclose(np.linalg.norm(q, axis=1), 1.0)


def test_a_constant_gyro_bias_is_recovered(synthetic):
    truth, gyr, acc, mag = synthetic
    _, _, details = smooth_attitude_rts(gyr, acc, mag, RATE, details=True,
                                        calibration=(np.zeros(3), np.eye(3)))
    bias = details['gyro_bias']
    assert bias.shape == (len(details['steps']), 3)
    # Everywhere, not only at the end: the smoother's bias uses the whole recording.
    assert np.max(np.abs(bias - BIAS)) < 0.003, np.max(np.abs(bias - BIAS), axis=0)


# The recording's own noises (per-sample σ over √RATE; the field's heading per
# sample), the field telling the tilt too: the model then matches the recording.
MATCHED = {'gyro_noise': 0.0005, 'heading_noise': 0.0005, 'acc_noise': 0.005,
           'velocity_sigma': 0.2, 'velocity_tau': 1.0, 'mag_sigma': 0.015, 'mag_tau': 0.01,
           'mag_tilt': 1.0}


def test_the_covariance_tells_the_size_of_the_error(synthetic):
    truth, gyr, acc, mag = synthetic
    q, cov = smooth_attitude_rts(gyr, acc, mag, RATE, MATCHED,
                                 calibration=(np.zeros(3), np.eye(3)))
    _, heading, inclination = error_angles(q, truth)
    tilt_var = 0.5 * (cov[:, 0, 0] + cov[:, 1, 1])
    assert 0.3 < np.mean(inclination ** 2 / (2.0 * tilt_var)) < 3.0
    assert 0.3 < np.mean(heading ** 2 / cov[:, 2, 2]) < 3.0
    assert np.all(np.linalg.eigvalsh(cov) > 0.0)


def test_a_hard_iron_the_online_pass_learns_is_applied_from_the_first_sample(synthetic):
    truth, gyr, acc, mag = synthetic
    offset = 2.0 * np.linalg.norm(FIELD) * np.array([0.6, -0.48, 0.64])
    q, _ = smooth_attitude_rts(gyr, acc, mag + offset, RATE)
    clean, _ = smooth_attitude_rts(gyr, acc, mag, RATE, calibration=(np.zeros(3), np.eye(3)))
    total, clean_total = error_angles(q, truth)[0], error_angles(clean, truth)[0]
    assert _rms(total, 0) < 1.2 * _rms(clean_total, 0) + np.radians(0.2)


def test_plain_and_compiled_give_the_same_bits(synthetic):
    pytest.importorskip('numba')
    truth, gyr, acc, mag = synthetic
    part = slice(0, 300)
    args = (gyr[part], acc[part], mag[part], RATE)
    kept = {'calibration': (np.zeros(3), np.eye(3))}
    q_plain, cov_plain = smooth_attitude_rts(*args, compiled=False, **kept)
    q_compiled, cov_compiled = smooth_attitude_rts(*args, compiled=True, **kept)
    np.testing.assert_array_equal(q_plain, q_compiled)
    np.testing.assert_array_equal(cov_plain, cov_compiled)


def test_bad_input_is_refused():
    gyr = np.zeros((10, 3))
    acc = np.tile((0.0, 0.0, 9.81), (10, 1))
    with pytest.raises(ValueError, match='acc of shape'):
        smooth_attitude_rts(gyr, acc[:5], None, RATE)
    with pytest.raises(ValueError, match='rate must be positive'):
        smooth_attitude_rts(gyr, acc, None, 0.0)
    with pytest.raises(ValueError, match='unknown smoother settings'):
        smooth_attitude_rts(gyr, acc, None, RATE, params={'speed': 1.0})
    with pytest.raises(ValueError, match='mag_sigma must be > 0'):
        smooth_attitude_rts(gyr, acc, None, RATE, params={'mag_sigma': 0.0})
