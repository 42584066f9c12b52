"""
The raw-IMU estimator: numpy only (numba where installed), no ROS.

``estimator`` (AhrsObserver) wraps the steps of ``ahrs_kernel`` on a flat
state; ``ahrs_params`` its parameters, ``ahrs_math`` its frames and first
attitude, ``ahrs_batch`` many recordings at once. ``magcal*`` the online
magnetometer calibration, ``uncertainty*`` the estimate's covariance, and
``compiled`` the kernels compiled by numba.
"""
