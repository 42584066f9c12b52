"""
Start imu_filter_node as imu_tools' imu_filter.launch.py starts imu_filter_madgwick_node.

``ros2 launch ext_observer imu_filter.launch.py`` runs the node ``imu_filter``
with the installed ``config/imu_filter.yaml``; ``params_file:=<file>`` loads
another one: imu_filter_madgwick's and imu_complementary_filter's own params
files load unchanged (docs/raw_imu.md). Copy it to start from.
"""

import os

from ament_index_python.packages import get_package_share_directory
import launch
import launch.actions
import launch.substitutions
import launch_ros.actions


def generate_launch_description():
    """Return the launch description: one imu_filter_node and its params file."""
    config = os.path.join(get_package_share_directory('ext_observer'), 'config',
                          'imu_filter.yaml')
    return launch.LaunchDescription([
        launch.actions.DeclareLaunchArgument(
            'params_file', default_value=config,
            description='params file of imu_filter_node (an imu_tools one loads too)'),
        launch_ros.actions.Node(
            package='ext_observer', executable='imu_filter_node', name='imu_filter',
            output='screen',
            parameters=[launch.substitutions.LaunchConfiguration('params_file')]),
    ])
