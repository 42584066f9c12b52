"""
The observer node (``nodes/observer_node.py``) through real topics, launch-free:
``attitude/unit_estimate`` only while subscribed, pairing by stamp with a
bounded wait and drop counters, an uncertified α only with its switch,
runtime changes refused with their reason or applied.
"""

import math
import time

from diagnostic_msgs.msg import DiagnosticStatus
import numpy as np
import pytest
from rclpy.parameter import Parameter

from ext_observer.nodes.conversions import (nanoseconds_from_stamp, quaternion_stamped,
                                      vector_stamped)
from ext_observer.core import certified_alpha_max, quaternion_from_rotation_vector, SingleObserver
from ext_observer.nodes.observer_node import DROP_REASONS, ObserverNode
from ros_helpers import overrides, Probe, SECOND, values_of, wait_for_subscribers


# A measurement_timeout no pair published together outlasts, s (the
# largest allowed is 60): a step is corrected whatever the load.
LATE = 30.0


ALPHA_MAX = certified_alpha_max(0.5)


def test_unit_estimate_goes_out_only_while_subscribed(ros_context, spinner):
    from geometry_msgs.msg import QuaternionStamped, Vector3Stamped
    from rclpy.node import Node

    observer = spinner.add(ObserverNode(context=ros_context, parameter_overrides=overrides(
        step_period=0.01)))
    driver = spinner.add(Node('driver', context=ros_context))
    listener = spinner.add(Node('listener', context=ros_context))
    increments = driver.create_publisher(Vector3Stamped, 'gyro/increment', 10)
    measurements = driver.create_publisher(QuaternionStamped, 'attitude/measurement', 10)
    estimates, units = {}, {}
    driver.create_subscription(
        QuaternionStamped, 'attitude_estimate',
        lambda msg: estimates.setdefault(nanoseconds_from_stamp(msg.header.stamp), msg), 10)
    wait_for_subscribers(spinner, increments)
    wait_for_subscribers(spinner, measurements)
    # Every unit estimate the node hands to its publisher (the publisher still
    # sends it): the only record of one published while no one listens.
    handed = []
    publish = observer.unit_publisher.publish

    def counted(msg):
        handed.append(nanoseconds_from_stamp(msg.header.stamp))
        publish(msg)

    observer.unit_publisher.publish = counted
    y = (1.0, 0.0, 0.0, 0.0)

    def step(seconds):
        """One corrected step at ``seconds``; return the stamp of its estimate."""
        before = observer.counts['measurements']
        measurements.publish(quaternion_stamped(y, seconds * SECOND, 'world'))
        spinner.spin_until(lambda: observer.counts['measurements'] > before, 5.0,
                           'the measurement')
        increments.publish(vector_stamped((0.1, 0.0, 0.0), seconds * SECOND, 'base_link'))
        stamp = seconds * SECOND + SECOND // 100
        spinner.spin_until(lambda: stamp in estimates, 5.0, f'the estimate at {seconds} s')
        return stamp

    # No subscriber: the estimate goes out, its unit form does not.
    step(1)
    assert handed == []
    # A subscriber: the unit form of the next estimate reaches it.
    subscription = listener.create_subscription(
        QuaternionStamped, 'attitude_estimate/unit',
        lambda msg: units.setdefault(nanoseconds_from_stamp(msg.header.stamp), msg), 10)
    spinner.spin_until(lambda: observer._publish_unit, 5.0, 'the unit output switched on')
    stamp = step(2)
    spinner.spin_until(lambda: stamp in units, 5.0, 'the unit estimate')
    assert handed == [stamp] and list(units) == [stamp]
    q = estimates[stamp].quaternion
    n = math.sqrt(q.w ** 2 + q.x ** 2 + q.y ** 2 + q.z ** 2)
    assert units[stamp].quaternion.w == pytest.approx(q.w / n, abs=1e-15)
    # Gone again: not handed to the publisher any more.
    listener.destroy_subscription(subscription)
    spinner.spin_until(lambda: not observer._publish_unit, 5.0,
                       'the unit output switched off')
    step(3)
    assert handed == [stamp]


def test_observer_pairs_by_stamp_waits_and_counts_drops(ros_context, spinner):
    observer = spinner.add(ObserverNode(context=ros_context, parameter_overrides=overrides(
        measurement_timeout=0.2, step_period=0.01, diagnostic_period=0.1)))
    probe = spinner.add(Probe(ros_context))
    wait_for_subscribers(spinner, probe.increment_publisher)
    wait_for_subscribers(spinner, probe.measurement_publisher)
    reference = SingleObserver()
    theta = (0.1, -0.2, 0.3)
    y = tuple(quaternion_from_rotation_vector(np.array([0.2, 0.1, 0.0])))

    def steps():
        return observer.counts['steps_corrected'] + observer.counts['steps_propagated']

    def received(kind, count):
        spinner.spin_until(lambda: observer.counts[kind] == count, 5.0, f'{count} {kind}')

    # Inputs on two topics arrive in either order: each input the order
    # matters for is sent once the one before it has arrived.

    # A pair: one corrected step, published at t + step_period.
    probe.send_measurement(1 * SECOND, y)
    received('measurements', 1)
    probe.send_increment(1 * SECOND, theta)
    spinner.spin_until(lambda: len(probe.estimates) == 1, 5.0, 'the first estimate')
    assert probe.estimates == {SECOND + SECOND // 100: reference.step(theta, y)}

    # An increment alone waits measurement_timeout (at least: load only
    # lengthens the wait), then propagates.
    sent = time.monotonic()
    probe.send_increment(2 * SECOND, theta)
    spinner.spin_until(lambda: steps() == 2, 5.0, 'the timeout')
    assert time.monotonic() - sent >= 0.2 * 0.99
    assert observer.counts['steps_propagated'] == 1
    spinner.spin_until(lambda: len(probe.estimates) == 2, 5.0, 'the second estimate')
    assert probe.estimates[2 * SECOND + SECOND // 100] == reference.step(theta)

    # From here on no step may wait out a timeout: what ends a wait is an input.
    [result] = observer.set_parameters([Parameter('measurement_timeout', value=LATE)])
    assert result.successful, result.reason

    # Duplicate and stale inputs are dropped and counted; so is a measurement
    # that comes after its step went on without it.
    probe.send_increment(2 * SECOND, theta)
    probe.send_measurement(SECOND + SECOND // 2, y)
    probe.send_measurement(2 * SECOND, y)
    spinner.spin_until(lambda: observer.counts['measurements'] == 3, 5.0, 'the inputs')
    received('increments', 3)
    assert observer.drops['duplicate_increment'] == 1
    assert observer.drops['stale_measurement'] == 2
    assert steps() == 2

    # A measurement may come first; one without increment is dropped as unpaired
    # once a newer step is processed.
    probe.send_measurement(3 * SECOND, y)
    probe.send_measurement(4 * SECOND, y)
    received('measurements', 5)
    probe.send_increment(4 * SECOND, theta)
    spinner.spin_until(lambda: steps() == 3, 5.0, 'the third step')
    assert observer.counts['steps_corrected'] == 2
    assert observer.drops['unpaired_measurement'] == 1
    # The measurement of a corrected step, again: a duplicate.
    probe.send_measurement(4 * SECOND, y)
    spinner.spin_until(lambda: observer.drops['duplicate_measurement'] == 1, 5.0,
                       'the duplicate measurement')

    # A newer measurement shows that an older one will not come: the step goes
    # on at once, long before its timeout (LATE).
    probe.send_increment(5 * SECOND, theta)
    received('increments', 5)
    assert steps() == 3
    probe.send_measurement(6 * SECOND, y)
    spinner.spin_until(lambda: steps() == 4, 5.0, 'step 5, released by the newer measurement')
    probe.send_increment(6 * SECOND, theta)
    spinner.spin_until(lambda: steps() == 5, 5.0, 'step 6')
    assert observer.counts['steps_propagated'] == 2
    assert observer.counts['steps_corrected'] == 3

    spinner.spin_until(
        lambda: values_of(probe.last_status('observer: inputs')).get('steps') == '5',
        5.0, 'an observer status after the last step')
    values = values_of(probe.last_status('observer: inputs'))
    assert {f'dropped_{reason}' for reason in DROP_REASONS} <= set(values)
    assert values['dropped_duplicate_increment'] == '1'
    assert values['dropped_stale_measurement'] == '2'
    assert values['dropped_unpaired_measurement'] == '1'
    assert values['dropped_duplicate_measurement'] == '1'
    warned = [s for s in probe.statuses['observer: inputs']
              if s.level == DiagnosticStatus.WARN]
    assert warned and 'dropping inputs' in warned[0].message


def test_uncertified_alpha_needs_the_switch(ros_context):
    node = ObserverNode(context=ros_context, parameter_overrides=overrides(
        alpha=0.5, allow_uncertified_alpha=True))
    try:
        assert node.observer.config.alpha == 0.5
    finally:
        node.destroy_node()
    assert 0.07 < ALPHA_MAX < 0.08


def test_invalid_runtime_change_is_refused_and_valid_one_applied(ros_context, spinner):
    node = spinner.add(ObserverNode(context=ros_context))
    node.observer.step((0.1, 0.2, 0.3), (0.0, 1.0, 0.0, 0.0))
    state = node.observer.state

    def refused(name, value, reason):
        [result] = node.set_parameters([Parameter(name, value=value)])
        assert not result.successful
        assert reason in result.reason
        return result

    refused('alpha', 0.5, 'outside the range certified by Theorem 1')
    refused('variant', 'kalman', 'variant must be one of')
    refused('gain', [1.0, 2.0], 'gain must have 4 elements')
    refused('initial_estimate', [0.5, 0.5, 0.5, 0.5], 'read-only')
    refused('queue_depth', 20, 'read-only')
    refused('measurement_timeout', -1.0, 'out of range')
    assert node.get_parameter('alpha').value == 0.01
    assert node.observer.config.alpha == 0.01

    # Both together: the switch and the value it allows.
    result = node.set_parameters_atomically([
        Parameter('allow_uncertified_alpha', value=True), Parameter('alpha', value=0.2)])
    assert result.successful, result.reason
    assert node.observer.config.alpha == 0.2
    # Another observer from the current estimate on, not a reset.
    [result] = node.set_parameters([Parameter('variant', value='projected')])
    assert result.successful, result.reason
    assert node.observer.config.variant == 'projected'
    assert node.observer.state == state
    # Switching the guard back off with an uncertified alpha in place is refused.
    refused('allow_uncertified_alpha', False, 'outside the range certified')
