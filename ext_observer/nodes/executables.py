"""
The executables' entry points (setup.py's console scripts): stop signals first, then the node.

Importing a node's module takes from a few tenths of a second to seconds on
a busy machine (rclpy, numpy, the estimator); a SIGINT or SIGTERM in that
time must stop the node rather than print a ``KeyboardInterrupt``
traceback. So each entry point installs the stop handlers
(:mod:`~ext_observer.nodes.stop_signals`) before it imports its node's
module, and then runs that module's ``main``.
"""

import importlib

from ext_observer.nodes import stop_signals

__all__ = ['gyro_node', 'imu_filter_node', 'monitor_node', 'observer_node']


def _run(module):
    stop_signals.install()
    return importlib.import_module(f'ext_observer.nodes.{module}').main()


def gyro_node():
    """``gyro_node``: :func:`ext_observer.nodes.gyro_node.main`."""
    return _run('gyro_node')


def observer_node():
    """``observer_node``: :func:`ext_observer.nodes.observer_node.main`."""
    return _run('observer_node')


def monitor_node():
    """``monitor_node``: :func:`ext_observer.nodes.monitor_node.main`."""
    return _run('monitor_node')


def imu_filter_node():
    """``imu_filter_node``: :func:`ext_observer.nodes.imu_filter_node.main`."""
    return _run('imu_filter_node')
