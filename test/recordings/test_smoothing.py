"""
The smoothed estimate (``recordings/smoothing.py``, ``attitude_from_imu(..., smooth=True)``):
on synthetic motion with a known truth it is closer to the truth than the
online run, its σ finite on every row, and everything but the estimate is
the online run's.
"""

import numpy as np

from synthetic_motion import errors_deg, RATE, synthetic
from ext_observer.core.ahrs.frames import world_from_enu
from ext_observer.recordings.recording import attitude_from_imu
from ext_observer.recordings.smoothing import combined_std, field_per_sample, time_reversed


def _rms(angles):
    return float(np.sqrt(np.mean(np.square(angles))))


def test_smoothed_is_closer_to_the_truth_than_the_online_run():
    truth, gyr, acc, mag = synthetic(seconds=10.0, accel=2.0)
    online = attitude_from_imu(gyr, acc, mag * 1e-6, rate=RATE)
    smoothed = attitude_from_imu(gyr, acc, mag * 1e-6, rate=RATE, smooth=True)
    assert smoothed.smoothed and not online.smoothed
    total, _, inclination = (_rms(e) for e in errors_deg(online.quaternions, truth))
    total_s, _, inclination_s = (_rms(e) for e in errors_deg(smoothed.quaternions, truth))
    # Measured (smooth_attitude): inclination 0.565° -> 0.392°, total 0.995° -> 0.623°.
    assert inclination_s < 0.8 * inclination and total_s < 0.8 * total
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


def test_the_smoothed_estimate_is_in_the_world_frame_and_takes_fields_at_their_times():
    truth, gyr, acc, mag = synthetic(seconds=6.0, accel=1.0)
    times = np.arange(len(gyr)) / RATE
    enu = attitude_from_imu(gyr, acc, mag * 1e-6, times=times, smooth=True)
    ned = attitude_from_imu(gyr, acc, mag * 1e-6, times=times, smooth=True,
                            parameters={'world_frame': 'ned'})
    np.testing.assert_allclose(ned.quaternions, world_from_enu(enu.quaternions, 'ned'),
                               atol=1e-12)
    # A field every fourth sample, at its own times: at the sample at or after it.
    slow = attitude_from_imu(gyr, acc, mag[::4] * 1e-6, times=times, mag_times=times[::4],
                             smooth=True)
    assert _rms(errors_deg(slow.quaternions, truth)[0]) < 1.5 * _rms(
        errors_deg(enu.quaternions, truth)[0])
    rows = field_per_sample(np.arange(6.0).reshape(2, 3), np.array([0.25, 0.5]),
                            np.array([0.0, 0.25, 0.3, 0.5, 0.75]))
    np.testing.assert_array_equal(rows[[0, 2, 4]], np.nan)
    np.testing.assert_array_equal(rows[[1, 3]], [[0, 1, 2], [3, 4, 5]])
    # Two fields before one sample: the later; one after the last sample: none.
    rows = field_per_sample(np.arange(9.0).reshape(3, 3), np.array([0.1, 0.2, 0.9]),
                            np.array([0.0, 0.25, 0.5]))
    np.testing.assert_array_equal(rows[1], [3, 4, 5])
    assert np.isnan(rows[[0, 2]]).all()


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


def test_two_runs_sigmas_combine_as_independent_estimates():
    std1 = np.array([1.0, 1.0, np.nan, np.nan])
    std2 = np.array([1.0, np.sqrt(3.0), 1.0, np.nan])
    # Equal σ: 1/√2; 3× the variance: √(3/4); one without a σ: the other's; neither: held.
    np.testing.assert_allclose(combined_std(std1, std2),
                               [np.sqrt(0.5), np.sqrt(0.75), 1.0, 1.0])


def test_a_hole_is_bridged_and_a_repeated_stamp_shows_the_estimate_before_it():
    truth, gyr, acc, mag = synthetic(seconds=8.0, accel=1.0)
    times = np.arange(len(gyr)) / RATE
    full = attitude_from_imu(gyr, acc, mag * 1e-6, times=times, smooth=True)
    # 50 ms lost at 4 s, and one sample stamped again as the one before it.
    keep = (times < 4.0) | (times >= 4.05)
    t, g, a, m = times[keep], gyr[keep], acc[keep], mag[keep]
    k = np.flatnonzero(t > 6.0)[0]
    t = t.copy()
    t[k] = t[k - 1]
    holed = attitude_from_imu(g, a, m * 1e-6, times=t, smooth=True)
    assert sum(holed.drops.values()) >= 1, holed.drops  # the node drops the repeated stamp
    np.testing.assert_array_equal(holed.quaternions[k], holed.quaternions[k - 1])
    error = _rms(errors_deg(holed.quaternions, truth[keep])[0])
    assert error < 1.5 * _rms(errors_deg(full.quaternions, truth)[0]) + 0.05
