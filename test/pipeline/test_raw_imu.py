"""
The raw-IMU estimator as imu_filter_node runs it, without ROS
(``pipeline/raw_imu.py``): the divergence guard reinitializing from the
sample, the first sample of a time line, resets counted by cause, a jump
back, a forward gap's action, fields and the silence since the last, the
magnetometer's mounting (mag_mounting, the deprecated mag_frame_rpy). (The
same through DDS against the offline run: ``test_raw_imu_through_dds.py``.)
"""

import math

import numpy as np
import pytest

from ext_observer.pipeline.imu_filter_outputs import mounting_matrix, quaternion_from_rpy
from ext_observer.pipeline.imu_filter_parameters import IMU_FILTER_PARAMETERS
from ext_observer.pipeline.raw_imu import RawImuEstimator, RawImuPipeline
from ros_helpers import SECOND


def test_raw_imu_divergence_guard_reinitializes_from_the_sample():
    settings = {spec.name: spec.default for spec in IMU_FILTER_PARAMETERS}
    estimator = RawImuEstimator(settings)
    sample = ((0.0, 0.0, 0.1), (1.0, 0.0, 9.7))
    estimator.field((2e-5, 0.0, -4e-5))
    state, reason = estimator.step(*sample, 0.01)
    assert reason is None and abs(math.hypot(*state) - 1.0) < 1e-9
    for poison, expected in (((10.0, 0.0, 0.0, 0.0), 'residual_too_large'),
                             ((math.nan, 0.0, 0.0, 0.0), 'state_non_finite')):
        estimator.core.q = poison
        state, reason = estimator.step(*sample, 0.01)
        assert reason == expected
        # From gravity and the latest field again: unit, finite.
        assert abs(math.hypot(*state) - 1.0) < 1e-9


GYR, ACC, FIELD = (0.0, 0.0, 0.1), (0.1, 0.0, 9.8), (2e-5, 0.0, -4e-5)


def pipeline(**changes):
    values = {spec.name: spec.default for spec in IMU_FILTER_PARAMETERS}
    values.update(changes)
    return RawImuPipeline(values)


def test_the_first_sample_initializes_and_the_next_one_steps():
    p = pipeline()
    assert p.imu(1 * SECOND, GYR, ACC) == (None, None)
    outcome, estimate = p.imu(1 * SECOND + 10_000_000, GYR, ACC)
    assert outcome is None and estimate.stamp == 1 * SECOND + 10_000_000
    assert abs(math.hypot(*estimate.state) - 1.0) < 1e-9 and estimate.reason is None
    assert len(estimate.covariance) == 9


def test_with_a_constant_dt_the_first_sample_answers_too():
    p = pipeline(constant_dt=0.01)
    outcome, estimate = p.imu(1 * SECOND, GYR, ACC)
    assert outcome is None and estimate.stamp == 1 * SECOND


def test_a_jump_back_resets_and_a_reset_is_counted_by_its_cause():
    p = pipeline()
    for k in range(3):
        p.imu(10 * SECOND + k * 10_000_000, GYR, ACC)
    outcome, _ = p.imu(1 * SECOND, GYR, ACC)
    assert outcome == 'backward_jump' and p.resets['backward_jump'] == 1
    p.reset('service')
    assert p.resets == {'backward_jump': 1, 'clock_jump': 0, 'forward_gap': 0, 'service': 1}


@pytest.mark.parametrize('action, resets', [('propagate', 0), ('reset', 1)])
def test_a_forward_gap_resets_only_when_asked(action, resets):
    p = pipeline(forward_gap_action=action, forward_gap_threshold=0.5, max_dt=5.0)
    p.imu(1 * SECOND, GYR, ACC)
    p.imu(1 * SECOND + 10_000_000, GYR, ACC)
    p.imu(3 * SECOND, GYR, ACC)
    # The step after the 2 s without samples is the one flagged.
    _, estimate = p.imu(3 * SECOND + 10_000_000, GYR, ACC)
    assert estimate is not None and estimate.step.gap
    assert p.resets['forward_gap'] == resets


def test_the_field_silence_is_the_time_since_the_last_field():
    p = pipeline()
    assert p.field_silence() is None
    p.imu(1 * SECOND, GYR, ACC)
    assert p.field(1 * SECOND, FIELD) is None
    p.imu(1 * SECOND + 10_000_000, GYR, ACC)
    p.imu(1 * SECOND + 250_000_000, GYR, ACC)
    p.imu(1 * SECOND + 260_000_000, GYR, ACC)
    # From the latest released step's start.
    assert p.field_silence() == pytest.approx(0.25)
    assert p.field(1 * SECOND, (math.nan, 0.0, 0.0)) is not None


def _yaw(state):
    w, _, _, z = state
    return 2.0 * math.atan2(z, w)


def _wrapped(angle):
    return math.atan2(math.sin(angle), math.cos(angle))


@pytest.mark.parametrize('use_mag', [False, True])
def test_a_hole_too_long_to_bridge_leaves_a_heading_its_covariance_covers(use_mag):
    # A level body turning at 0.5 rad/s about the vertical; 1.5 s of samples
    # lost (over max_dt: not bridged) hide 43° of the turn. In 6D the estimate
    # keeps that error and its heading σ says so; in 9D the heading lost is
    # taken afresh from the fields after the hole.
    p = pipeline(use_mag=use_mag, **{'ahrs.mag_cal': False})
    rate, dt, norm, dip = 0.5, 10_000_000, 5e-5, math.radians(60.0)
    gyr, acc = (0.0, 0.0, rate), (0.0, 0.0, 9.80665)

    def sample(k):
        yaw = rate * k * dt * 1e-9
        if use_mag:
            north, up = norm * math.cos(dip), -norm * math.sin(dip)
            p.field(SECOND + k * dt, (north * math.sin(yaw), north * math.cos(yaw), up))
        return p.imu(SECOND + k * dt, gyr, acc), yaw

    for k in range(200):
        sample(k)
    (outcome, _), _ = sample(350)
    assert outcome == 'dt_too_large'
    for k in range(351, 401):
        (_, estimate), yaw = sample(k)
    error = abs(_wrapped(_yaw(estimate.state) - yaw))
    sigma = math.sqrt(estimate.covariance[8])
    if use_mag:
        assert error < math.radians(5.0) and sigma < math.radians(30.0)
    else:
        assert error > math.radians(40.0) and error < 2.0 * sigma


MOUNTING_RPY = (0.3, -1.1, 2.4)  # roll, pitch, yaw, rad: far from any axis


def _mounted_run(**changes):
    """A short run with a field every sample: the fields taken and the estimates."""
    p = pipeline(**changes)
    fields, states = [], []
    for k in range(200):
        stamp = 1 * SECOND + k * 10_000_000
        _, estimate = p.imu(stamp, GYR, ACC)
        p.field(stamp, FIELD)
        fields.append(p.estimator.latest_field)
        if estimate is not None:
            states.append(tuple(estimate.state))
    return fields, states


def test_mag_mounting_turns_the_field_as_the_equivalent_mag_frame_rpy():
    q = list(quaternion_from_rpy(MOUNTING_RPY))
    by_quaternion, q_states = _mounted_run(mag_mounting=q)
    by_angles, rpy_states = _mounted_run(mag_frame_rpy=list(MOUNTING_RPY))
    # The field in the IMU frame, R m: the same rotation within rounding.
    expected = np.reshape(mounting_matrix(MOUNTING_RPY), (3, 3)) @ FIELD
    assert np.allclose(by_quaternion[0], expected, rtol=0.0, atol=1e-19)
    assert np.allclose(by_angles[0], expected, rtol=0.0, atol=1e-19)
    assert np.abs(np.subtract(q_states, rpy_states)).max() < 1e-12
    # mag_frame_rpy alone: its matrix from the angles, as before, to the bit.
    r = mounting_matrix(MOUNTING_RPY)
    assert by_angles[0] == tuple(r[3 * i] * FIELD[0] + r[3 * i + 1] * FIELD[1]
                                 + r[3 * i + 2] * FIELD[2] for i in range(3))
    # The mounting matters (the test can fail), and the identity is no mounting.
    plain, plain_states = _mounted_run()
    assert np.abs(np.subtract(plain_states, q_states)).max() > 1e-3
    assert _mounted_run(mag_mounting=[1.0, 0.0, 0.0, 0.0]) == (plain, plain_states)


def test_a_quarter_turn_about_z_maps_x_to_y():
    h = math.sqrt(0.5)
    fields, _ = _mounted_run(mag_mounting=[h, 0.0, 0.0, h])
    assert np.allclose(fields[0], (0.0, 2e-5, -4e-5), rtol=0.0, atol=1e-19)
