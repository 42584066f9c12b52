"""
What the nodes run, without ROS: the input rules (``pairing``, ``steps``),
the divergence guard (``guard``), the unit checks (``units``) and the
raw-IMU pipeline of imu_filter_node (``raw_imu``). Imports no rclpy.
"""
