"""Packaging of ext_observer: the ament_python layout of ``ros2 pkg create``."""

from glob import glob

from setuptools import find_packages, setup

package_name = 'ext_observer'

setup(
    name=package_name,
    version='0.1.0',
    packages=find_packages(exclude=['test', 'test.*', 'bench', 'bench.*', 'docgen', 'docgen.*']),
    data_files=[
        ('share/ament_index/resource_index/packages', ['resource/' + package_name]),
        ('share/' + package_name, ['package.xml']),
        ('share/' + package_name + '/config', sorted(glob('config/*.yaml'))),
        # For colcon users, as imu_tools ships its own (ros2 launch ext_observer ...).
        ('share/' + package_name + '/launch', sorted(glob('launch/*.launch.py'))),
    ],
    # The ROS client libraries come from a ROS installation or from the wheels
    # in requirements.txt; listing them here would make colcon's entry-point
    # scripts refuse to start on a ROS machine without those wheels.
    install_requires=['setuptools'],
    zip_safe=True,
    maintainer='ext_observer maintainers',
    maintainer_email='maintainers@example.com',
    description='Attitude observers on S3 with a transversally stable extension',
    license='Apache-2.0',
    # Each executable installs its stop signals' handlers before it imports its
    # node (ext_observer/nodes/executables.py).
    entry_points={
        'console_scripts': [
            'gyro_node = ext_observer.nodes.executables:gyro_node',
            'observer_node = ext_observer.nodes.executables:observer_node',
            'imu_filter_node = ext_observer.nodes.executables:imu_filter_node',
            'monitor_node = ext_observer.nodes.executables:monitor_node',
        ],
    },
)
