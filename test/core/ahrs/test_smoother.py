"""
The smoothed estimate (``core/ahrs/smoother.py``) on synthetic motion with a known
truth: ahead of the online estimator, a gyro bias recovered from both directions,
the strapdown (compiled, blocked) equal to the plain product, zero-phase windows, bad
input refused.
"""

import numpy as np
import pytest

from ext_observer.core import quaternion as quat
from ext_observer.core.ahrs import smooth_strapdown, smooth_windows, smoother
from ext_observer.core.ahrs.smoother import smooth_attitude, SmoothParams
from ext_observer.pipeline.batch import estimate_batch
from synthetic_motion import errors_deg, RATE, synthetic

BIAS = (0.01, -0.015, 0.008)  # rad/s


@pytest.fixture(scope='module')
def moving():
    """60 s of rotation with 3 m/s² of translation and a gyro bias."""
    return synthetic(seconds=60.0, accel=3.0, bias=BIAS, seed=3)


def rms(x):
    return float(np.sqrt(np.mean(np.square(x))))


@pytest.mark.parametrize('use_mag', [False, True])
def test_the_smoothed_estimate_is_ahead_of_the_online_one(moving, use_mag):
    truth, gyr, acc, mag = moving
    field = mag if use_mag else None
    q, cov = smooth_attitude(gyr, acc, field, RATE)
    online = estimate_batch([gyr], [acc], [mag], [RATE], [use_mag])[0]
    assert q.shape == truth.shape and cov is None
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-12)
    smoothed, ours = errors_deg(q, truth), errors_deg(online, truth)
    assert rms(smoothed[2]) < 0.8 * rms(ours[2])  # inclination
    if use_mag:
        assert rms(smoothed[0]) < rms(ours[0]) and rms(smoothed[0]) < 1.0  # total


def test_a_field_disturbed_at_the_start_leaves_the_heading_right():
    truth, gyr, acc, mag = synthetic(seconds=30.0, accel=1.0, seed=4, disturb=(0.0, 8.0, 30.0))
    online = estimate_batch([gyr], [acc], [mag], [RATE], [True])[0]
    for ref_time in (2.0, 0.0):  # the start's field, the most common one
        q, _ = smooth_attitude(gyr, acc, mag, RATE, SmoothParams(ref_time=ref_time))
        assert rms(errors_deg(q, truth)[1]) < min(0.5, rms(errors_deg(online, truth)[1]))


def test_a_constant_gyro_bias_is_recovered_from_both_directions(moving):
    _, gyr, acc, mag = moving
    p = SmoothParams(bias='both')
    bias, _, _ = smoother._bias(gyr, acc, mag, 1.0 / RATE, p)
    assert bias.shape == gyr.shape
    # Every sample's: from the forward pass at the end, the reversed one at the start.
    error = np.abs(bias - BIAS)
    assert error.max() < 5e-3 and error.mean() < 5e-4
    end, _, _ = smoother._bias(gyr, acc, mag, 1.0 / RATE, SmoothParams())
    np.testing.assert_allclose(end, BIAS, atol=1.5e-3)


def test_the_strapdown_compiled_and_blocked_is_the_running_product():
    rng = np.random.default_rng(1)
    rate = rng.normal(0.0, 2.0, (1001, 3))
    rate[5] = 0.0
    first = quat.normalize(rng.normal(size=4))
    expected = np.empty((len(rate), 4))
    expected[0] = first
    steps = quat.quaternion_from_rotation_vector(rate * 0.01)
    for k in range(1, len(rate)):
        expected[k] = quat.multiply(expected[k - 1], steps[k])
    # The compiled loop where numba is wanted, and numpy's blocked scan.
    np.testing.assert_allclose(smooth_strapdown.strapdown(rate, 0.01, first), expected, atol=1e-12)
    np.testing.assert_allclose(smooth_strapdown.strapdown_blocked(rate, 0.01, first), expected,
                               atol=1e-12)


def test_the_compiled_loops_give_numpys_floats(monkeypatch):
    pytest.importorskip('numba')
    rng = np.random.default_rng(2)
    q = quat.normalize(rng.normal(size=(500, 4)))
    r = rng.normal(size=(500, 4))
    v = rng.normal(size=(500, 3))
    field = v.copy()
    field[::7] = np.nan  # no field
    q[5], field[5] = (1.0, 0.0, 0.0, 0.0), (0.0, 0.0, 2.0)  # no horizontal part

    def run():
        return (smooth_strapdown.rotate_rows(q, v), smooth_strapdown.box3(v, 7),
                smooth_strapdown.box3(v[:, 0], 600), smooth_strapdown.box3(v[:2], 1),
                *smooth_strapdown.field_parts(q, field),
                smooth_strapdown.turned(r, q), smooth_strapdown.turned(r, q, first=True),
                smooth_strapdown.turned_about_vertical(v[:, 0], q), smooth_strapdown.tilted(v, q))

    monkeypatch.setenv('EXT_OBSERVER_COMPILED', '1')
    monkeypatch.setattr(smooth_strapdown, '_LOOPS', [])
    compiled = run()
    monkeypatch.setattr(smooth_strapdown, '_LOOPS', [None])
    plain = run()
    for a, b in zip(compiled[:-4], plain[:-4]):
        np.testing.assert_array_equal(a, b)
    # Equal to the bit where numpy's einsum sums four floats in two lanes (x86-64).
    for a, b in zip(compiled[-4:], plain[-4:]):
        np.testing.assert_allclose(a, b, rtol=0.0, atol=1e-15)
    for loops in ([], [None]):  # upside down: no smallest rotation to turn it up
        monkeypatch.setattr(smooth_strapdown, '_LOOPS', loops)
        with pytest.raises(ValueError, match='zero or not finite'):
            smooth_strapdown.tilted(np.array([[0.0, 0.0, -1.0]]), q[:1])


def test_the_windows_are_zero_phase_and_normalized_by_their_weights():
    n = 2001
    t = np.arange(n, dtype=float)
    ramp = np.stack((t, -2.0 * t), axis=1)
    mean = smooth_windows.average(ramp, np.ones(n), 50.0)
    # A ramp is kept where the window is whole: no delay.
    np.testing.assert_allclose(mean[200:-200], ramp[200:-200], atol=1e-9)
    # A sample of weight 0 is not seen; a constant stays itself to the ends.
    weight = np.ones(n)
    weight[1000] = 0.0
    spiked = np.ones((n, 1))
    spiked[1000] = 1e6
    np.testing.assert_allclose(smooth_windows.average(spiked, weight, 50.0, (400.0, 0.1)), 1.0,
                               rtol=1e-9)


def test_a_sensor_delay_reads_each_attitude_later(moving):
    truth, gyr, acc, _ = moving
    early, _ = smooth_attitude(gyr, acc, None, RATE)
    late, _ = smooth_attitude(gyr, acc, None, RATE, SmoothParams(delay=2.0 / RATE))
    np.testing.assert_allclose(np.abs(np.einsum('ij,ij->i', late[:-2], early[2:])), 1.0,
                               atol=1e-12)


@pytest.mark.parametrize('args, match', [
    ((np.zeros((10, 2)), np.zeros((10, 3)), None, 100.0), r'gyr must have shape \(N, 3\)'),
    ((np.zeros((10, 3)), np.zeros((9, 3)), None, 100.0), 'acc has 9 samples, gyr 10'),
    ((np.zeros((10, 3)), np.full((10, 3), np.nan), None, 100.0), 'acc has non-finite'),
    ((np.zeros((10, 3)), np.zeros((10, 3)), None, 0.0), 'rate must be positive'),
])
def test_bad_input_is_refused(args, match):
    with pytest.raises(ValueError, match=match):
        smooth_attitude(*args)


def test_bad_settings_are_refused():
    with pytest.raises(ValueError, match='window_acc must be positive'):
        SmoothParams(window_acc=0.0)
    with pytest.raises(ValueError, match='ref_time must be finite and ≥ 0'):
        SmoothParams(ref_time=-1.0)
    with pytest.raises(ValueError, match="bias must be 'end' or 'both'"):
        SmoothParams(bias='middle')


def test_times_evenly_spaced_give_the_rate_result_to_the_bit(moving):
    truth, gyr, acc, mag = moving
    rate = 128.0  # an interval of 1/128 s: the times' differences exact
    times = 3.0 + np.arange(len(gyr)) / rate
    for field in (None, mag):
        by_rate, _ = smooth_attitude(gyr, acc, field, rate)
        by_times, _ = smooth_attitude(gyr, acc, field, times=times)
        np.testing.assert_array_equal(by_times, by_rate)


@pytest.mark.parametrize('use_mag', [False, True])
def test_holes_are_bridged_from_both_sides(moving, use_mag):
    truth, gyr, acc, mag = moving
    field = mag if use_mag else None
    times = np.arange(len(gyr)) / RATE
    full, _ = smooth_attitude(gyr, acc, field, RATE)
    random = np.random.default_rng(5).random(len(gyr)) >= 0.4
    random[0] = True
    q, _ = smooth_attitude(gyr[random], acc[random], None if field is None else field[random],
                           times=times[random])
    kept, whole = errors_deg(q, truth[random]), errors_deg(full[random], truth[random])
    # 40 % lost at random: within 1.2× the full data's error over the kept samples
    # (the total: 1.3×, its three holes of 50 ms joined as long ones).
    assert rms(kept[2]) < 1.2 * rms(whole[2]) + 0.02  # inclination
    if use_mag:
        assert rms(kept[0]) < 1.3 * rms(whole[0]) + 0.02  # total
    # 200 ms lost every 2 s: bridged (the closing rate over each hole alone, the
    # heading would wander by tens of degrees), short of the full data's figure
    # (1.4° here; 1.6° and 1.9° without the force filled across the holes).
    burst = np.mod(times, 2.0) >= 0.2
    burst[0] = True
    q, _ = smooth_attitude(gyr[burst], acc[burst], None if field is None else field[burst],
                           times=times[burst])
    kept = errors_deg(q, truth[burst])
    assert rms(kept[2]) < 1.5 and (not use_mag or rms(kept[0]) < 1.5)


def test_lost_fields_weigh_nothing_and_the_heading_is_bridged(moving):
    truth, gyr, acc, mag = moving
    full, _ = smooth_attitude(gyr, acc, mag, RATE)
    lost = mag.copy()
    lost[np.random.default_rng(6).random(len(mag)) < 0.5] = np.nan  # a slower magnetometer
    lost[int(20 * RATE):int(30 * RATE), 1] = np.nan  # 10 s without a field
    q, _ = smooth_attitude(gyr, acc, lost, RATE)
    assert np.isfinite(q).all()
    assert rms(errors_deg(q, truth)[0]) < 1.2 * rms(errors_deg(full, truth)[0]) + 0.05


def test_a_clipped_gyro_is_bridged_across_its_stretches(moving):
    truth, gyr, acc, _ = moving
    limit = 0.8 * np.abs(gyr).max()
    clipped = np.clip(gyr, -limit, limit)
    assert (np.abs(gyr) > limit).sum() > 10
    whole, _ = smooth_attitude(gyr, acc, None, RATE)
    held, _ = smooth_attitude(clipped, acc, None, RATE)  # stuck at its peak: found so
    ignored = smoother.clipped_rates
    try:
        smoother.clipped_rates = lambda g, p: np.zeros(g.shape, dtype=bool)
        naive, _ = smooth_attitude(clipped, acc, None, RATE)
    finally:
        smoother.clipped_rates = ignored
    err = [rms(errors_deg(q, truth)[2]) for q in (whole, held, naive)]
    # Bridged from both sides, nearer the truth than the clipped rates as given.
    assert err[1] < 0.95 * err[2], err


def test_a_clipped_stretch_is_a_heading_of_its_own(moving):
    truth, gyr, acc, mag = moving
    limit = 0.5 * np.abs(gyr).max()
    clipped = np.clip(gyr, -limit, limit)
    apart, _ = smooth_attitude(clipped, acc, mag, RATE)
    joined = smoother.with_clips
    try:
        smoother.with_clips = lambda gaps, bridge, *clips: (gaps, bridge)
        across, _ = smooth_attitude(clipped, acc, mag, RATE)
    finally:
        smoother.with_clips = joined
    err = [rms(errors_deg(q, truth)[1]) for q in (apart, across)]
    # A clip's heading error stays in its stretch, not over the heading's windows.
    assert err[0] < 0.8 * err[1], err


@pytest.mark.parametrize('kwargs, match', [
    ({'rate': 100.0, 'times': np.arange(10.0)}, 'either rate or times'),
    ({'times': np.arange(9.0)}, r'times must have shape \(10,\)'),
    ({'times': np.r_[0.0, 1.0, 1.0, np.arange(3.0, 10.0)]}, 'times must increase'),
    ({'times': np.r_[np.nan, np.arange(1.0, 10.0)]}, 'times has non-finite'),
])
def test_bad_times_are_refused(kwargs, match):
    with pytest.raises(ValueError, match=match):
        smooth_attitude(np.zeros((10, 3)), np.tile([0.0, 0.0, 9.81], (10, 1)), None, **kwargs)
