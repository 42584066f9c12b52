"""Helpers of the ROS tests: a probe node and small utilities."""

import os
import sys

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import QuaternionStamped, Vector3Stamped
import psutil
import pytest
from rclpy.node import Node
from rclpy.parameter import Parameter
from std_msgs.msg import Float64

from ext_observer.nodes.conversions import (nanoseconds_from_stamp, quaternion_from_msg,
                                      quaternion_stamped, vector_from_msg, vector_stamped)
from ext_observer.core.validation import check_measurement

SECOND = 1_000_000_000


def installed(name):
    """Return the console script ``name`` that pip installed next to this Python."""
    path = os.path.join(os.path.dirname(sys.executable), name)
    if not os.path.exists(path):
        pytest.fail(f'{name} is not installed next to {sys.executable}; run `make test`')
    return path


def cpu_seconds(pid):
    """Return the user + system CPU time of a process (all its threads), s."""
    times = psutil.Process(pid).cpu_times()
    return times.user + times.system


def unit(y, tolerance=0.1):
    """Return ``y`` as the observer uses it: validated and normalized."""
    normalized, reason = check_measurement(y, tolerance)
    assert reason is None, reason
    return normalized


def overrides(**values):
    """Return ``parameter_overrides`` for a node."""
    return [Parameter(name, value=value) for name, value in values.items()]


class Probe(Node):
    """Publish inputs and record every output, keyed by stamp."""

    def __init__(self, context):
        super().__init__('probe', context=context)
        self.estimates = {}
        self.units = {}
        self.truths = {}
        self.increments = {}
        self.measurements = {}
        self.distances = []
        self.statuses = {}
        sub = self.create_subscription
        sub(QuaternionStamped, 'attitude_estimate', self._keep(self.estimates), 100)
        sub(QuaternionStamped, 'attitude_estimate/unit', self._keep(self.units), 100)
        sub(QuaternionStamped, 'attitude/ground_truth', self._keep(self.truths), 100)
        sub(QuaternionStamped, 'attitude/measurement', self._keep(self.measurements), 100)
        sub(Vector3Stamped, 'gyro/increment', self._keep(self.increments), 100)
        sub(Float64, 'attitude_estimate/manifold_distance',
            lambda msg: self.distances.append(msg.data), 100)
        sub(DiagnosticArray, '/diagnostics', self.diagnostics_callback, 100)
        self.increment_publisher = self.create_publisher(Vector3Stamped, 'gyro/increment', 100)
        self.measurement_publisher = self.create_publisher(
            QuaternionStamped, 'attitude/measurement', 100)
        self.estimate_publisher = self.create_publisher(
            QuaternionStamped, 'attitude_estimate', 100)
        self.truth_publisher = self.create_publisher(
            QuaternionStamped, 'attitude/ground_truth', 100)

    @staticmethod
    def _keep(store):
        def callback(msg):
            values = (vector_from_msg(msg.vector) if isinstance(msg, Vector3Stamped)
                      else quaternion_from_msg(msg.quaternion))
            store[nanoseconds_from_stamp(msg.header.stamp)] = values
        return callback

    def diagnostics_callback(self, msg):
        for status in msg.status:
            self.statuses.setdefault(status.name, []).append(status)

    def last_status(self, name):
        return self.statuses.get(name, [None])[-1]

    def send_increment(self, stamp, theta):
        self.increment_publisher.publish(vector_stamped(theta, stamp, 'base_link'))

    def send_measurement(self, stamp, q):
        self.measurement_publisher.publish(quaternion_stamped(q, stamp, 'world'))


def values_of(status):
    return {kv.key: kv.value for kv in status.values}


def wait_for_subscribers(spinner, publisher, count=1):
    spinner.spin_until(lambda: publisher.get_subscription_count() >= count, 10.0,
                       f'{publisher.topic_name} to be matched')
