"""
What the nodes run, without ROS: the input rules (``pairing``, ``pairing_terms``),
the divergence guard (``guard``), the unit checks (``units``), the raw-IMU
pipeline (``raw_imu``) and what imu_filter_madgwick publishes beside it
(``imu_filter_outputs``), the parameters as plain data (``parameter_specs``,
``imu_filter_parameters``), the compiled kernels' cache (``kernel_cache``)
and many recordings at once, in forked workers (``batch``).
"""
