"""
The raw-IMU estimator: numpy only (numba where installed), no ROS.

``ahrs_observer`` (AhrsObserver) wraps the steps of ``ahrs_kernel`` on a
state with names (``ahrs_state`` assembles the groups each kernel declares;
``record`` the Group type), with ``ahrs_filters`` the arithmetic they share,
``bias_kernel`` the bias learned in motion and ``clip_and_rest`` a clipped
gyro and rest; ``ahrs_params`` the parameter table (rows of
``parameter_rows``), ``frames`` frames and first attitude.
``magcal*`` the online calibration,
``uncertainty*`` the covariance, ``compiled`` the kernels compiled by numba,
``smoother`` each sample's attitude from the whole recording.
"""
