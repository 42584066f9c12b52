"""
The numerical core of ext_observer: numpy only, no ROS, no processes.

``quaternion`` (scalar first ``(w, x, y, z)``), ``extension`` (the
transversal extension of Theorems 1 and 2), ``certificate`` (admissible α),
``validation`` (state checks); ``paper/`` the paper's observer and gyro;
``ahrs/`` the raw-IMU estimator. The names below are the public API.
"""

from .certificate import (GainCertificate, certified_alpha_max,
                          estimate_certificate, optimal_delta, s3_certificate)
from .extension import (ConstraintExtension, TransversalExtension,
                        so3_extension, sphere_extension, sphere_grad_V,
                        sphere_hessian_V, sphere_V)
from .paper.gyro_model import GyroSample, SimulatedGyro, Trajectory
from .ahrs.magcal import check_calibration, MagCalibrator
from .paper.observer import (GAIN_MODES, LuenbergerObserver, ObserverConfig,
                       PAPER_ALPHA, PAPER_GAIN, SingleObserver, VARIANTS)
from .quaternion import (attitude_error, check_quaternions, check_vectors,
                         conjugate, constraint_residual, exp, IDENTITY, log,
                         manifold_distance, multiply, norm, normalize,
                         quaternion_from_rotation_vector,
                         random_unit_quaternions, right_matrix,
                         rotation_vector_from_quaternion, squared_norm)

__all__ = [
    'ConstraintExtension', 'GAIN_MODES', 'GainCertificate', 'GyroSample',
    'IDENTITY', 'LuenbergerObserver', 'MagCalibrator', 'ObserverConfig', 'PAPER_ALPHA',
    'PAPER_GAIN', 'SimulatedGyro', 'SingleObserver', 'Trajectory',
    'TransversalExtension', 'VARIANTS', 'attitude_error',
    'certified_alpha_max', 'check_calibration', 'check_quaternions', 'check_vectors', 'conjugate',
    'constraint_residual', 'estimate_certificate', 'exp', 'log',
    'manifold_distance', 'multiply', 'norm', 'normalize', 'optimal_delta',
    'quaternion_from_rotation_vector', 'random_unit_quaternions',
    'right_matrix', 'rotation_vector_from_quaternion', 's3_certificate', 'so3_extension',
    'sphere_extension', 'sphere_grad_V', 'sphere_hessian_V', 'sphere_V',
    'squared_norm',
]
