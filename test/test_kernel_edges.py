"""
Edges of the estimator's kernel that its other tests missed (no ROS): found by mutmut's samples.

In 9D the IMU samples come without a field (fields have their own calls, at
their own rate): a sample without one must not touch the field's state (a
kernel that ran the field's step on the zeros of a missing field would take
them as the references). A reset forgets the last field's verdict with the
rest. The gyro's increment is exact at any step size (at 100 Hz a wrong
half-angle is a third-order error no other test sees). A gyro at its range
is clipped on any axis. Fast: part of ``make mutation``'s subset of the
kernel (docs/tests.md#mutmut).
"""

import numpy as np
import pytest

from ext_observer.core.ahrs.ahrs_layout import S_HAS_REF, S_MAG_USED, S_REF
from ext_observer.core.ahrs.estimator import AhrsObserver, AhrsParams

DT = 0.01
TILTED = (1.2, -0.8, 9.7)
FIELD = (1.5e-5, 1.0e-5, -3.5e-5)


def field_state(est):
    s = est.flat_state
    return [s[S_HAS_REF], s[S_REF], s[S_REF + 1], s[S_MAG_USED]]


def test_in_9d_samples_without_a_field_leave_the_fields_state_and_the_heading():
    est = AhrsObserver(AhrsParams(), use_mag=True)
    # None yet: no references from a field that never came.
    for _ in range(50):
        est.update((0.0, 0.0, 0.0), TILTED, None, DT)
    assert field_state(est) == [0.0, 0.0, 0.0, 0.0]
    for _ in range(20):
        est.update((0.0, 0.0, 0.0), TILTED, FIELD, DT)
    before, q = field_state(est), np.array(est.q)
    assert before[0] == 1.0 and before[1] > 0.0
    for _ in range(50):
        est.update((0.0, 0.0, 0.0), TILTED, None, DT)
    assert field_state(est) == before
    assert np.allclose(est.q, q, atol=1e-9)


def test_a_reset_forgets_that_the_last_field_was_disturbed():
    est = AhrsObserver(AhrsParams(), use_mag=True)
    for _ in range(20):
        est.update((0.0, 0.0, 0.0), TILTED, FIELD, DT)
    est.update((0.0, 0.0, 0.0), TILTED, tuple(3.0 * v for v in FIELD), DT)
    assert est.mag_disturbed is True
    est.reset()
    assert est.mag_disturbed is False


def test_the_gyros_increment_is_exact_for_any_step_size():
    # Level, turning about the vertical in 6D (nothing corrects the heading)
    # with a rate that changes a little each sample (never repeated: not a
    # stuck gyro), 10 Hz: up to 0.35 rad per step. The heading is the sum of
    # the steps' angles to rounding: the increment is the exact rotation of
    # the step (the exponential map), not an approximation good only for
    # small angles.
    est = AhrsObserver(AhrsParams(), use_mag=False)
    est.update((0.0, 0.0, 0.0), (0.0, 0.0, 9.81), None, 0.1)
    heading = 0.0
    for k in range(40):
        rate = 2.5 + 0.025 * k
        q = est.update((0.0, 0.0, rate), (0.0, 0.0, 9.81), None, 0.1)
        heading += rate * 0.1
        expected = (np.cos(0.5 * heading), 0.0, 0.0, np.sin(0.5 * heading))
        assert np.allclose(q, expected, atol=1e-9) or np.allclose(q, np.negative(expected),
                                                                  atol=1e-9), k


def test_a_gyro_at_its_range_is_counted_on_any_axis_and_adds_range_dt_squared_per_axis():
    # A known range of 4 rad/s: a sample at it on one axis, or on all three,
    # is clipped; its variance is (range dt)² per clipped axis (docstring of
    # _watch_clipping), zero again on the next good sample.
    for axes in ((0,), (1,), (2,), (0, 1, 2)):
        est = AhrsObserver(AhrsParams(gyro_range=4.0), use_mag=False)
        est.update((0.0, 0.0, 0.0), TILTED, None, DT)
        rate = [0.0, 0.0, 0.0]
        for i in axes:
            rate[i] = -4.0 if i == 1 else 4.0
        est.update(tuple(rate), TILTED, None, DT)
        assert est.clipped == 1, axes
        assert est.clip_variance == pytest.approx(len(axes) * (4.0 * DT) ** 2, rel=1e-12)
        est.update((0.0, 0.0, 0.0), TILTED, None, DT)
        assert est.clipped == 1 and est.clip_variance == 0.0


def test_a_recordings_run_in_one_call_is_its_samples_one_by_one():
    # AhrsObserver.run (the kernel's loop, ahrs_run) against update per
    # sample, 6D and 9D, a second of a turning, tilted, noisy body.
    rng = np.random.default_rng(31)
    gyr = rng.normal(0.0, 0.3, (100, 3)) + (0.2, -0.5, 1.0)
    acc = rng.normal(0.0, 0.3, (100, 3)) + TILTED
    mag = rng.normal(0.0, 1e-6, (100, 3)) + FIELD
    for use_mag in (False, True):
        whole = AhrsObserver(AhrsParams(), use_mag=use_mag).run(gyr, acc, mag if use_mag else None,
                                                                DT)
        one = AhrsObserver(AhrsParams(), use_mag=use_mag)
        each = [one.update(tuple(gyr[k]), tuple(acc[k]), tuple(mag[k]) if use_mag else None, DT)
                for k in range(100)]
        assert whole.shape == (100, 4)
        assert np.allclose(whole, each, rtol=0.0, atol=1e-12)
        assert np.ptp(whole, axis=0).min() > 0.01   # every component moved


def test_a_reset_is_a_fresh_start():
    # Without a calibration (whose learned part a reset keeps on purpose):
    # after a reset, the same samples give the estimates a new estimator
    # gives, in 6D and 9D, through a turn with a gyro bias that the field
    # must correct.
    rng = np.random.default_rng(27)
    gyr = rng.normal(0.0, 0.01, (300, 3)) + (0.0, 0.0, 0.3)
    acc = rng.normal(0.0, 0.05, (300, 3)) + TILTED
    mag = rng.normal(0.0, 1e-7, (300, 3)) + FIELD
    for use_mag in (False, True):
        params = AhrsParams(mag_cal=False)
        used = AhrsObserver(params, use_mag=use_mag)
        fresh = AhrsObserver(params, use_mag=use_mag)
        for k in range(150):
            used.update(tuple(gyr[k]), tuple(acc[k]), tuple(mag[k]) if use_mag else None, DT)
        used.reset()
        for k in range(150, 300):
            m = tuple(mag[k]) if use_mag else None
            q = used.update(tuple(gyr[k]), tuple(acc[k]), m, DT)
            assert q == pytest.approx(fresh.update(tuple(gyr[k]), tuple(acc[k]), m, DT),
                                      abs=1e-12), (use_mag, k)
