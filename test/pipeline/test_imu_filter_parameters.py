"""
imu_filter_node's parameters without a node (``pipeline/imu_filter_parameters.py``):
which covariance ``imu/data`` carries, the velocity aid's frame, values
refused with their name and reason, the core's parameters from the
prefixed ones.
"""

import math

import numpy as np
import pytest

from ext_observer.pipeline.imu_filter_parameters import (ahrs_params, covariance_estimated,
                                                         covariance_text,
                                                         IMU_FILTER_PARAMETERS,
                                                         imu_filter_settings,
                                                         mag_frame_rpy_text,
                                                         uncertainty_params, velocity_frame)
from ext_observer.pipeline.imu_filter_outputs import (field_mounting, mounting_matrix,
                                                      quaternion_from_rpy, quaternion_matrix)


def defaults(**changes):
    values = {spec.name: spec.default for spec in IMU_FILTER_PARAMETERS}
    values.update(changes)
    return values


def test_orientation_stddev_zero_means_not_given():
    # imu_tools' default, 0.0, is "not given": the estimate's own covariance.
    assert covariance_estimated(defaults(orientation_stddev=0.0))
    assert covariance_estimated(defaults())
    # A positive value other than ours is a user's number: fixed.
    assert not covariance_estimated(defaults(orientation_stddev=0.2))
    # Asked for outright, either way.
    assert not covariance_estimated(defaults(orientation_stddev=0.0,
                                             orientation_covariance_mode='fixed'))
    assert covariance_estimated(defaults(orientation_stddev=0.2,
                                         orientation_covariance_mode='estimate'))


def test_invalid_values_are_refused_with_their_name():
    for changes, reason in (
            (dict(world_frame='ecef'), 'world_frame must be one of'),
            (dict(orientation_covariance_mode='sometimes'), 'orientation_covariance_mode must'),
            (dict(velocity_source='gps'), 'velocity_source must be one of'),
            (dict(mag_frame_rpy=[0.0, math.nan, 0.0]), 'mag_frame_rpy must be 3 finite'),
            (dict(mag_soft_iron=[1.0] * 9), r'mag_bias_\*, mag_soft_iron .*positive definite'),
            (dict(gyro_bias_y=1.0), r'gyro_bias_y must lie within ±ahrs.bias_max'),
            (dict(velocity_mounting=[1.0, 0.1, 0.0, 0.0]), 'unit quaternion'),
            (dict(mag_mounting=[1.0, 0.1, 0.0, 0.0]), 'mag_mounting must be a unit quaternion'),
            (dict(mag_mounting=[1.0, 0.0, math.inf, 0.0]), 'mag_mounting must be a unit'),
            (dict(mag_mounting=[1.0, 0.0, 0.0]), 'mag_mounting must be a unit quaternion'),
            (dict(velocity_lever_arm=[0.0, 0.0]), 'velocity_lever_arm must be 3 finite'),
            ({'ahrs.tau_acc': -1.0}, r'ahrs\.\*: tau_acc must be positive'),
            ({'covariance.acc_noise': 0.0}, r'covariance\.\*: acc_noise must be positive')):
        with pytest.raises(ValueError, match=reason):
            imu_filter_settings(defaults(**changes))
    settings = imu_filter_settings(defaults())
    assert settings['covariance_estimated'] is True


def test_the_velocity_frame_is_the_mountings_transpose_and_its_lever_arm():
    assert velocity_frame(defaults()) is None
    # The IMU turned 90° about z in the velocity's frame: R^T maps x to -y.
    h = math.sqrt(0.5)
    rt, arm = velocity_frame(defaults(velocity_mounting=[h, 0.0, 0.0, h],
                                      velocity_lever_arm=[1.0, 2.0, 3.0]))
    assert np.allclose(np.reshape(rt, (3, 3)), [[0, 1, 0], [-1, 0, 0], [0, 0, 1]], atol=1e-12)
    assert np.allclose(arm, [2.0, -1.0, 3.0], atol=1e-12)
    _, arm = velocity_frame(defaults(velocity_lever_arm=[0.5, 0.0, 0.0]))
    assert arm == (0.5, 0.0, 0.0)


def test_the_cores_parameters_come_from_the_prefixed_values():
    assert ahrs_params(defaults(**{'ahrs.tau_acc': 2.5})).tau_acc == 2.5
    assert uncertainty_params(defaults(**{'covariance.acc_noise': 0.3})).acc_noise == 0.3
    assert 'estimate\'s own' in covariance_text(defaults())
    assert 'orientation_stddev²' in covariance_text(defaults(orientation_stddev=0.2))


def test_mag_mounting_is_a_unit_quaternion_within_the_tolerance():
    # A rounded unit quaternion (norm 1 within 1e-6) is taken, as velocity_mounting's.
    imu_filter_settings(defaults(mag_mounting=[0.7071068, 0.0, 0.0, 0.7071068]))
    with pytest.raises(ValueError, match=r'mag_mounting must be a unit quaternion .*1e-06'):
        imu_filter_settings(defaults(mag_mounting=[0.5, 0.5, 0.5, 0.0]))


def test_mag_frame_rpy_and_mag_mounting_both_set_are_refused_naming_both():
    h = math.sqrt(0.5)
    with pytest.raises(ValueError, match=r'mag_mounting .* and mag_frame_rpy .* are both set'):
        imu_filter_settings(defaults(mag_mounting=[h, 0.0, 0.0, h],
                                     mag_frame_rpy=[0.0, 0.0, 0.1]))
    # Either alone is taken; the identity and zero are "not set".
    imu_filter_settings(defaults(mag_mounting=[h, 0.0, 0.0, h]))
    imu_filter_settings(defaults(mag_frame_rpy=[0.0, 0.0, 0.1]))
    imu_filter_settings(defaults(mag_mounting=[1.0, 0.0, 0.0, 0.0], mag_frame_rpy=[0.0] * 3))


def test_mag_frame_rpy_alone_is_used_as_before_with_a_warning_naming_the_quaternion():
    rpy = (0.3, -1.1, 2.4)
    values = defaults(mag_frame_rpy=list(rpy))
    # The matrix from the angles, as before (the estimates unchanged to the bit).
    assert field_mounting(values) == mounting_matrix(rpy)
    text = mag_frame_rpy_text(values)
    q = list(quaternion_from_rpy(rpy))
    assert 'mag_frame_rpy is deprecated' in text and f'mag_mounting {q}' in text
    # The quaternion named is the same rotation, within rounding.
    assert np.allclose(quaternion_matrix(q), mounting_matrix(rpy), rtol=0.0, atol=1e-15)
    assert mag_frame_rpy_text(defaults()) is None
    assert mag_frame_rpy_text(defaults(mag_mounting=list(q))) is None
    assert field_mounting(defaults(mag_mounting=list(q))) == quaternion_matrix(q)
    assert field_mounting(defaults()) is None


def test_the_velocity_frame_is_the_one_quaternion_matrix_transposed():
    q = [0.5, 0.5, -0.5, 0.5]
    rt, _ = velocity_frame(defaults(velocity_mounting=q))
    assert np.array_equal(np.reshape(rt, (3, 3)), np.reshape(quaternion_matrix(q), (3, 3)).T)
