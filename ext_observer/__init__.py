"""
ext_observer: attitude observers with a transversally stable extension.

The numerical core lives in :mod:`ext_observer.core` (numpy only); the ROS 2
nodes (``gyro_node``, ``observer_node``, ``monitor_node``) are thin wrappers
around it. Importing this package imports neither rclpy nor numpy.
"""

__version__ = '0.1.0'
