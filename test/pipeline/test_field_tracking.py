"""
What the covariance is told of each field (``pipeline/field_tracking.py``): the gain
the core applied after a hole, and a restart of the fields' count.
"""

import math

from ext_observer.pipeline.imu_filter_parameters import IMU_FILTER_PARAMETERS
from ext_observer.pipeline.raw_imu import RawImuEstimator


def test_after_a_hole_the_covariance_follows_the_fields_raised_heading_gain():
    # A level body at rest with a fixed field; a 0.45 s hole hides a turn of
    # 16°. The first fields after it correct the heading with the Kalman gain
    # of the doubt the hole left, far above tau_mag's: the published heading
    # variance follows that gain, not the usual one (which would keep it
    # near the hole's for seconds).
    settings = {spec.name: spec.default for spec in IMU_FILTER_PARAMETERS}
    settings.update({'ahrs.mag_cal': False})
    estimator = RawImuEstimator(settings, compiled=False)
    dt, norm, dip = 0.01, 5e-5, math.radians(60.0)

    def field_at(yaw):
        # The world field (north, up: ENU) seen by a level body turned by yaw.
        north, up = norm * math.cos(dip), -norm * math.sin(dip)
        return (north * math.sin(yaw), north * math.cos(yaw), up)

    still, level = (0.0, 0.0, 0.0), (0.0, 0.0, 9.80665)
    estimator.field(field_at(0.0))
    for _ in range(300):
        estimator.step(still, level, dt)
        estimator.field(field_at(0.0), dt)
    turn = math.radians(16.0)
    estimator.step(still, level, 0.45)
    assert estimator.core.holes == 1
    after_hole = estimator.uncertainty.heading_variance
    estimator.field(field_at(turn), 0.45)
    applied = estimator.core.field('doubt_gain')
    usual = estimator.uncertainty.heading_gain(10_000, dt)
    assert applied > 10.0 * usual
    assert estimator.uncertainty.last_field[1] == applied
    assert estimator.fields.fields_used > 300
    for _ in range(100):
        estimator.step(still, level, dt)
        estimator.field(field_at(turn), dt)
    assert estimator.uncertainty.heading_variance < 0.5 * after_hole



def test_a_restart_counts_the_fields_from_one_again():
    settings = {spec.name: spec.default for spec in IMU_FILTER_PARAMETERS}
    settings.update({'ahrs.mag_cal': False})
    estimator = RawImuEstimator(settings, compiled=False)
    field, level = (2e-5, 0.0, -4e-5), (0.0, 0.0, 9.80665)
    estimator.field(field)
    for _ in range(5):
        estimator.step((0.0, 0.0, 0.0), level, 0.01)
        estimator.field(field, 0.01)
    tracker = estimator.fields
    assert tracker.fields_used >= 5
    assert tracker.uncertainty.last_field[1] == tracker.uncertainty.heading_gain(
        tracker.fields_used, 0.01)
    tracker.restart()
    assert (tracker.fields_used, tracker.calibrated) == (0, True)
    estimator.field(field, 0.01)
    # The first field after a restart sets the heading: a gain of one.
    assert tracker.fields_used == 1 and tracker.uncertainty.last_field[1] == 1.0
