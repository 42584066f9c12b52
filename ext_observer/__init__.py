"""
ext_observer: attitude observers with a transversally stable extension.

The numerical core lives in :mod:`ext_observer.core` (numpy only); the ROS 2
nodes (``gyro_node``, ``observer_node``, ``monitor_node``) are thin wrappers
around it. Importing this package imports neither rclpy nor numpy.
"""

__version__ = '0.1.0'


def __getattr__(name):
    # ext_observer.attitude_from_imu, the Python call for one recording
    # (docs/library.md), imported on first use so that the package stays light.
    if name == 'attitude_from_imu':
        from ext_observer.recordings.recording import attitude_from_imu
        return attitude_from_imu
    raise AttributeError(f'module {__name__!r} has no attribute {name!r}')
