"""
Recordings without ROS: ``recording`` (attitude_from_imu, one recording
through the pipeline the node runs), rosbag2 in and out (``bag``,
``bag_worker``, ``bag_io``, ``cdr``), CSV (``csvio``), ``calibrate``,
``example_data`` and the roll/pitch/yaw plot (``recording_plot``).
"""
