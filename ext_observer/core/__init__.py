"""
The numerical core of ext_observer: numpy only, no ROS.

Modules
-------
quaternion
    Batched quaternion algebra, scalar first ``(w, x, y, z)``.
extension
    The transversal extension of Theorems 1 and 2 (S³ and SO(3) built in).
certificate
    The gain certificate: admissible α and the certified contraction.
observer
    The extended, plain and projected Luenberger-like observers.
gyro_model
    The simulated gyro and attitude sensor.
magcal, magcal_model
    Online magnetometer calibration (hard and soft iron) from the gyro; the
    check of a saved calibration.
ahrs, ahrs_params, ahrs_math, ahrs_batch
    The raw-IMU estimator, its parameters, its world frames and first
    attitude, and many recordings at once.
ahrs_kernel, magcal_kernel, magcal_filter, magcal_layout, compiled
    The estimator's steps and the calibration's filter as functions on a
    flat state (one source; the filter's steps and the state's slots in
    their own modules), and their compiled form (numba, optional).
uncertainty
    The variance of the raw-IMU estimate's inclination and heading.
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
