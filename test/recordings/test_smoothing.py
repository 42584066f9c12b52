"""
The smoothed estimate (``recordings/smoothing.py``, ``attitude_from_imu(..., smooth=True)``):
on synthetic motion with a known truth it is closer to the truth than the
online run, its σ finite on every row, and everything but the estimate is
the online run's.
"""

import numpy as np

from synthetic_motion import errors_deg, RATE, synthetic
from ext_observer.recordings.recording import attitude_from_imu
from ext_observer.recordings.smoothing import combined, time_reversed


def _rms(angles):
    return float(np.sqrt(np.mean(np.square(angles))))


def test_smoothed_is_closer_to_the_truth_than_the_online_run():
    truth, gyr, acc, mag = synthetic(seconds=10.0, accel=2.0)
    online = attitude_from_imu(gyr, acc, mag * 1e-6, rate=RATE)
    smoothed = attitude_from_imu(gyr, acc, mag * 1e-6, rate=RATE, smooth=True)
    assert smoothed.smoothed and not online.smoothed
    total, _, inclination = (_rms(e) for e in errors_deg(online.quaternions, truth))
    total_s, _, inclination_s = (_rms(e) for e in errors_deg(smoothed.quaternions, truth))
    # Measured: inclination 0.565° -> 0.402°, total 0.995° -> 0.912°.
    assert inclination_s < 0.8 * inclination and total_s < total
    for std in (smoothed.inclination_std, smoothed.heading_std):
        assert np.isfinite(std).all() and (std > 0).all()
    # Not more certain than either run: never above the online σ where it has one.
    has = np.isfinite(online.inclination_std)
    assert (smoothed.inclination_std[has] <= online.inclination_std[has] + 1e-15).all()
    np.testing.assert_allclose(np.linalg.norm(smoothed.quaternions, axis=1), 1.0, atol=1e-12)
    np.testing.assert_array_equal(smoothed.ambient, smoothed.quaternions)
    # The rest is the online run's.
    np.testing.assert_array_equal(smoothed.health, online.health)
    np.testing.assert_array_equal(smoothed.estimated, online.estimated)
    assert smoothed.counts == online.counts and smoothed.drops == online.drops


def test_time_reversed_twice_is_the_recording():
    rng = np.random.default_rng(3)
    times = np.cumsum(rng.uniform(0.004, 0.006, 50))
    gyr, acc = rng.normal(size=(50, 3)), rng.normal(size=(50, 3))
    mag, mag_times = rng.normal(size=(9, 3)), np.sort(rng.uniform(times[0], times[-1], 9))
    back_times, (back_gyr, back_acc, back_mag, back_mag_times, _, _) = time_reversed(
        times, gyr, acc, mag, mag_times)
    # The intervals are kept; the sample at t_k turns back by the rate of the one after it.
    np.testing.assert_allclose(np.diff(back_times), np.diff(times)[::-1], atol=1e-12)
    np.testing.assert_array_equal(back_gyr[::-1][:-1], -gyr[1:])
    again_times, (_, again_acc, again_mag, again_mag_times, _, _) = time_reversed(
        back_times, back_gyr, back_acc, back_mag, back_mag_times)
    np.testing.assert_allclose(again_times, times, atol=1e-12)
    np.testing.assert_allclose(again_mag_times, mag_times, atol=1e-12)
    np.testing.assert_array_equal(again_acc, acc)
    np.testing.assert_array_equal(again_mag, mag)


def test_combined_weighs_the_inclination_by_the_sigmas():
    tilt = np.radians(2.0)
    first = np.array([[1.0, 0.0, 0.0, 0.0]] * 3)
    second = np.array([[np.cos(tilt / 2), np.sin(tilt / 2), 0.0, 0.0]] * 3)
    std1 = np.array([1.0, 1.0, np.nan])
    std2 = np.array([1.0, np.sqrt(3.0), 1.0])
    q, inclination_std, heading_std = combined((first, std1, std1), (second, std2, std2),
                                               heading=False)
    # Halfway with equal σ, a quarter of the way with 3× the variance, all of it without a σ.
    _, _, inclination = errors_deg(q, first)
    np.testing.assert_allclose(inclination, [1.0, 0.5, 2.0], atol=1e-9)
    np.testing.assert_allclose(inclination_std, [np.sqrt(0.5), np.sqrt(0.75), 1.0])
    np.testing.assert_array_equal(heading_std, [1.0, 1.0, 1.0])
