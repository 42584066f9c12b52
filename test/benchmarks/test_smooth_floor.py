"""Checks of bench/smooth_floor.py's decomposition on made-up verticals (no data, no ROS)."""

import math

import numpy as np
import pytest

from bench.smooth_floor import (angles, band_rms, constant_tilt, reference_earlier, rest_tilt,
                                verticals)
from ext_observer.core.quaternion import quaternion_from_rotation_vector
from ext_observer.core.quaternion import rotation_matrices


def test_constant_tilt_finds_a_fixed_rotation_and_leaves_only_the_rest():
    rng = np.random.default_rng(3)
    ref = verticals(quaternion_from_rotation_vector(rng.normal(scale=0.6, size=(2000, 3))))
    tilt = rotation_matrices(quaternion_from_rotation_vector(np.array([[0.004, -0.003, 0.002]])))[0]
    noise = rng.normal(scale=1e-4, size=ref.shape)
    est = ref @ tilt.T + noise
    est /= np.linalg.norm(est, axis=1, keepdims=True)
    m = constant_tilt(est, ref)
    np.testing.assert_allclose(m, tilt, atol=2e-5)
    before = np.sqrt(np.mean(np.square(angles(est, ref))))
    after = np.sqrt(np.mean(np.square(angles(est, ref @ m.T))))
    assert before > 20 * after


def test_band_rms_puts_a_tone_in_its_band():
    rate = 200.0
    t = np.arange(int(60 * rate)) / rate
    error = np.zeros((len(t), 3))
    error[:, 0] = 0.01 * np.sin(2 * math.pi * 0.3 * t)  # 0.3 Hz: the 0.1–1 Hz band
    keep = np.ones(len(t), dtype=bool)
    keep[:int(10 * rate)] = keep[-int(10 * rate):] = False  # away from the ends
    bands = band_rms(error, rate, keep)
    assert len(bands) == 4
    whole = math.degrees(0.01 / math.sqrt(2))
    assert bands[2] == pytest.approx(whole, rel=0.2)
    assert max(bands[0], bands[1], bands[3]) < 0.35 * whole


def test_reference_earlier_by_one_sample_is_the_previous_sample():
    q = quaternion_from_rotation_vector(np.outer(np.linspace(0, 1, 50), [0.0, 0.0, 1.0]))
    out = reference_earlier(q, 100.0, 0.01)
    np.testing.assert_allclose(out[1:], q[:-1], atol=1e-12)


def test_rest_tilt_is_the_tilt_of_the_force_from_the_reference_s_vertical():
    v_ref = np.tile([0.0, 0.0, 1.0], (100, 1))
    acc = np.tile([0.0, 9.81 * math.sin(math.radians(0.2)), 9.81 * math.cos(math.radians(0.2))],
                  (100, 1))
    still = np.arange(100) < 60
    tilt = rest_tilt(acc, v_ref, still)
    np.testing.assert_allclose(tilt, [-0.2, 0.0, 0.0], atol=1e-6)
    assert rest_tilt(acc, v_ref, np.zeros(100, dtype=bool)) is None
