"""
imu_tools' own files and habits, unchanged, start imu_filter_node and do what they say.

The params files of imu_filter_madgwick and imu_complementary_filter
(``test/data/imu_tools/``, copied unchanged) start the installed node over
DDS; each option they name does here what it does there, or is named in
the start-up warning with what replaces it (docs/raw_imu.md).
"""

import math
import os
import time

from diagnostic_msgs.msg import DiagnosticArray
import numpy as np
import pytest
from sensor_msgs.msg import Imu

from ext_observer.nodes.conversions import nanoseconds_from_stamp
from ext_observer.nodes.imu_filter_parameters import (covariance_estimated,
                                                      IMU_FILTER_PARAMETERS)
from ros_helpers import installed, SECOND
from test_raw_imu import Driver

DATA = os.path.join(os.path.dirname(os.path.abspath(__file__)), 'data', 'imu_tools')
MADGWICK_FILE = os.path.join(DATA, 'imu_filter.yaml')
COMPLEMENTARY_FILE = os.path.join(DATA, 'filter_config.yaml')
START = 1_700_000_000 * SECOND


def defaults(**changes):
    values = {spec.name: spec.default for spec in IMU_FILTER_PARAMETERS}
    values.update(changes)
    return values


def start_process(ros_processes, spinner, ros_context, argv, topic='imu/data'):
    """Start the installed node; return it, a Driver and the imu/data messages by stamp."""
    process = ros_processes([installed('imu_filter_node'), '--ros-args'] + argv)
    driver = spinner.add(Driver(ros_context))
    spinner.spin_until(lambda: driver.imu_publisher.get_subscription_count() == 1
                       and process.process.poll() is None, 20.0, 'imu_filter_node')
    filtered = {}
    driver.create_subscription(Imu, topic, lambda msg: filtered.__setitem__(
        nanoseconds_from_stamp(msg.header.stamp), msg), 1000)
    statuses = []
    driver.create_subscription(DiagnosticArray, '/diagnostics',
                               lambda msg: statuses.extend(msg.status), 10)
    # The process's own status reached this node: discovery is done both ways.
    spinner.spin_until(lambda: driver.count_publishers(topic) == 1
                       and any(st.name == 'imu_filter: inputs' for st in statuses), 20.0,
                       'imu/data and the status of the process')
    return process, driver, filtered


def send_each(spinner, driver, filtered, samples, field=(2e-5, 1e-5, -4e-5)):
    """Publish each sample once the estimate of the one before has come back."""
    for k, (stamp, gyr, acc) in enumerate(samples):
        if field is not None:
            driver.send_field(stamp, field)
        driver.send_imu(stamp, gyr, acc)
        if k:
            spinner.spin_until(lambda: stamp in filtered, 10.0, f'estimate {k}')


def test_orientation_stddev_zero_means_not_given():
    # imu_tools' default, 0.0, is "not given": the estimate's own covariance.
    assert covariance_estimated(defaults(orientation_stddev=0.0))
    assert covariance_estimated(defaults())
    # A positive value other than ours is a user's number: fixed.
    assert not covariance_estimated(defaults(orientation_stddev=0.2))
    # Asked for outright, either way.
    assert not covariance_estimated(defaults(orientation_stddev=0.0,
                                             orientation_covariance_mode='fixed'))
    assert covariance_estimated(defaults(orientation_stddev=0.2,
                                         orientation_covariance_mode='estimate'))


def test_imu_filter_madgwick_own_file_starts_with_a_covariance_and_names_publish_tf(
        ros_processes, ros_context, spinner):
    with open(MADGWICK_FILE) as f:
        text = f.read()
    assert 'orientation_stddev: 0.0' in text and 'publish_tf: true' in text
    process, driver, filtered = start_process(
        ros_processes, spinner, ros_context, ['--params-file', MADGWICK_FILE])
    samples = [(START + k * SECOND // 100, (0.0, 0.0, 0.2), (0.5, -0.3, 9.7))
               for k in range(60)]
    send_each(spinner, driver, filtered, samples)
    assert len(filtered) == len(samples) - 1
    assert process.process.poll() is None, process.output
    # The estimate's own covariance: positive on the diagonal, never zeros.
    for msg in filtered.values():
        c = np.reshape(msg.orientation_covariance, (3, 3))
        assert np.all(np.diag(c) > 0.0) and np.all(np.isfinite(c)), c
    out = process.output
    assert "orientation_covariance of imu/data: the estimate's own" in out, out
    assert 'orientation_stddev 0.0 means not given' in out, out
    assert 'publish_tf' in out, out
