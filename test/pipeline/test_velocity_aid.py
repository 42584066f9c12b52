"""
The velocity aid's input (``pipeline/velocity_aid.py``): velocities checked
(not finite, out of order) and handed to the estimator with the interval
since the last, moved to the IMU's frame and point; batch events with each
velocity before the first IMU sample at or after it.
"""

import math

import pytest

from ext_observer.pipeline.imu_filter_parameters import IMU_FILTER_PARAMETERS
from ext_observer.pipeline.raw_imu import RawImuEstimator
from ext_observer.pipeline.velocity_aid import VelocityInput, with_velocity

SECOND = 1_000_000_000


class Recorder(RawImuEstimator):
    """The pipeline's estimator, keeping what it was handed."""

    def __init__(self, settings):
        super().__init__(settings)
        self.handed = []

    def velocity(self, velocity, dt=None):
        self.handed.append((velocity, dt))
        super().velocity(velocity, dt)


def settings(**changes):
    values = {spec.name: spec.default for spec in IMU_FILTER_PARAMETERS}
    values.update(changes)
    return values


def test_bad_velocities_are_dropped_with_their_reason_and_the_interval_is_since_the_last():
    estimator = Recorder(settings())
    aid = VelocityInput(estimator, settings(velocity_timeout=0.7))
    assert estimator.core.velocity_timeout == 0.7
    assert aid.take(1 * SECOND, (1.0, 0.0, 0.0)) is None
    assert aid.take(1 * SECOND, (1.0, 0.0, 0.0)) == 'out_of_order'
    assert aid.take(2 * SECOND, (math.nan, 0.0, 0.0)) == 'not_finite'
    assert aid.take(2 * SECOND, (1.0, 0.0)) == 'not_finite'
    assert aid.take(SECOND + SECOND // 4, (2.0, 0.0, 0.0)) is None
    assert estimator.handed == [((1.0, 0.0, 0.0), None), ((2.0, 0.0, 0.0), 0.25)]


def test_a_velocity_in_another_frame_is_turned_into_the_imus():
    h = math.sqrt(0.5)
    values = settings(velocity_mounting=[h, 0.0, 0.0, h])
    estimator = Recorder(values)
    aid = VelocityInput(estimator, values)
    aid.take(1 * SECOND, (1.0, 2.0, 3.0))
    # Without a rate (no IMU sample yet) only the rotation: R^T v.
    assert estimator.handed[0][0] == pytest.approx((2.0, -1.0, 3.0), abs=1e-12)


def test_velocity_events_come_before_the_first_imu_sample_at_or_after_them():
    events = [(0, 0), (1, 0), (0, 1), (0, 2)]
    stamps = [10, 20, 30]
    assert list(with_velocity(events, stamps, [5, 20, 25, 40])) == [
        (2, 0), (0, 0), (1, 0), (2, 1), (0, 1), (2, 2), (0, 2)]
