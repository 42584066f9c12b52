"""
Everything that imports rclpy or message types: one module per executable
(``gyro_node``, ``observer_node``, ``monitor_node``, ``imu_filter_node``),
the machinery they share (``estimator_node_base``, ``node_common``), the rclpy
declaration of the parameter rows (``ros_parameters``), the rows of the
observer, gyro and monitor nodes (``node_parameters``) and the message
conversions (``conversions``).
"""
