"""
What the nodes run, without ROS: the input rules (``pairing``, ``steps``),
the divergence guard (``guard``), the unit checks (``units``), the raw-IMU
pipeline (``raw_imu``), the parameters as plain data (``parameter_specs``,
``imu_filter_parameters``), the compiled kernels' cache (``kernel_cache``)
and many recordings at once, in forked workers (``batch``).
"""
