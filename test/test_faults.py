"""
Bad input and faults through real topics: the node classes in one process.

Each test feeds the observer the steps of a simulated gyro from a probe,
injects a fault, and checks that the observer keeps running, publishes only
finite estimates, converges again on valid input, and that the right counter
rises in ``/diagnostics``.
"""

import math

from diagnostic_msgs.msg import DiagnosticStatus
from geometry_msgs.msg import QuaternionStamped, Vector3Stamped
import numpy as np
import pytest
from rclpy.parameter import Parameter
from rclpy.publisher import Publisher
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock
from std_srvs.srv import Trigger

from ext_observer.nodes.conversions import (quaternion_stamped, stamp_from_nanoseconds,
                                      vector_stamped)
from ext_observer.core import attitude_error, SimulatedGyro, SingleObserver
from ext_observer.nodes.gyro_node import GyroNode
from ext_observer.nodes.monitor_node import MonitorNode, STATUS_NAME
from ext_observer.nodes.observer_node import ObserverNode
from ros_helpers import overrides, Probe, SECOND, unit, values_of, wait_for_subscribers

nan, inf = float('nan'), float('inf')
PERIOD = SECOND // 50
OBSERVER_STATUS = 'observer: inputs'


class Driver:
    """Feed an observer node the steps of a simulated gyro, one at a time."""

    def __init__(self, spinner, probe, observer, seed=3, start=100 * SECOND):
        self.spinner, self.probe, self.observer = spinner, probe, observer
        self.gyro = SimulatedGyro(seed=seed)
        self.stamp = start
        self.truths = {}       # stamp of an estimate (t_{k+1}) -> q_{k+1}
        self.sent = {}         # stamp -> (increment, measurement) sent as valid
        self.order = []        # stamps of the estimates, in the order sent

    def steps_done(self):
        return self.observer.pairer.processed['increment']

    def step(self, before=None, scale=1.0):
        """
        Send one valid step; ``before(stamp)`` may inject inputs first.

        ``scale`` multiplies the measurement (a norm off unit, still valid).
        """
        sample = self.gyro.step()
        stamp = self.stamp
        theta = tuple(float(v) for v in sample.increment)
        y = tuple(float(v) * scale for v in sample.measurement)
        done = self.steps_done()
        if before is not None:
            before(stamp)
        self.probe.send_measurement(stamp, y)
        self.probe.send_increment(stamp, theta)
        self.sent[stamp] = (theta, y)
        self.truths[stamp + PERIOD] = tuple(float(v) for v in self.gyro.attitude)
        self.order.append(stamp + PERIOD)
        self.stamp += PERIOD
        self.spinner.spin_until(lambda: self.steps_done() > done, 5.0, f'step {stamp}')
        return stamp

    def run(self, steps):
        for _ in range(steps):
            self.step()

    def jump(self, to):
        """Go on at stamp ``to`` (a new time line, or a gap)."""
        self.stamp = to

    def step_at(self, to):
        """Jump to ``to``, send one step and wait for its estimate; its stamp."""
        self.jump(to)
        stamp = self.step()
        self.drain()
        return stamp

    def fresh_estimate(self, initial, stamp):
        """The core's estimate after the step sent at ``stamp``, started afresh at ``initial``."""
        theta, y = self.sent[stamp]
        return SingleObserver(initial=initial).step(theta, unit(y))

    def drain(self):
        """Wait for the estimate of every step sent to reach the probe."""
        self.spinner.spin_until(lambda: all(t in self.probe.estimates for t in self.order),
                                5.0, 'the estimates')

    def error(self, last=30):
        """Mean attitude error of the last ``last`` estimates against the truth."""
        self.drain()
        stamps = [t for t in self.order if t in self.probe.estimates][-last:]
        estimates = np.array([self.probe.estimates[t] for t in stamps])
        truths = np.array([self.truths[t] for t in stamps])
        return float(np.mean(attitude_error(estimates, truths)))


def observer_and_probe(spinner, context, **values):
    settings = dict(step_period=PERIOD / SECOND, diagnostic_period=0.1,
                    measurement_timeout=1.0)
    settings.update(values)
    observer = spinner.add(ObserverNode(context=context,
                                        parameter_overrides=overrides(**settings)))
    probe = spinner.add(Probe(context))
    wait_for_subscribers(spinner, probe.increment_publisher)
    wait_for_subscribers(spinner, probe.measurement_publisher)
    return observer, probe


def assert_all_finite(probe):
    for store in (probe.estimates, probe.units):
        assert store
        for q in store.values():
            assert all(map(math.isfinite, q)), q


def fresh_status(spinner, probe, name, predicate=lambda values: True, timeout=5.0):
    """Wait for a status published after now that satisfies ``predicate``."""
    seen = len(probe.statuses.get(name, []))

    def found():
        for status in probe.statuses.get(name, [])[seen:]:
            if predicate(values_of(status)):
                return status
        return None
    spinner.spin_until(lambda: found() is not None, timeout, f'a fresh {name!r} status')
    return found()


def accounted(values):
    return int(values['inputs_received']) == (
        int(values['inputs_processed']) + int(values['inputs_dropped'])
        + int(values['inputs_waiting']))


# Bad values and stamps -------------------------------------------------------------

def test_bad_inputs_are_dropped_counted_and_the_observer_recovers(ros_context, spinner):
    initial = (1.3, 0.0, 0.0, 0.0)
    observer, probe = observer_and_probe(spinner, ros_context, initial_estimate=list(initial))
    driver = Driver(spinner, probe, observer)
    driver.run(20)
    assert not any(observer.drops.values())

    def send_increment(stamp, theta):
        return lambda t: probe.send_increment(t if stamp is None else stamp, theta)

    def send_measurement(stamp, y):
        return lambda t: probe.send_measurement(t if stamp is None else stamp, y)

    def last():
        return observer.pairer.last_stamp

    def send_old_increment(age):
        return lambda t: probe.send_increment(last() - age, (0.1, 0.1, 0.1))

    def send_old_measurement(age):
        return lambda t: probe.send_measurement(last() - age, (1.0, 0.0, 0.0, 0.0))

    # Each bad input goes in with a valid step, and raises its own counter.
    cases = [
        ('non_finite_increment', send_increment(None, (nan, 0.0, 0.0))),
        ('non_finite_increment', send_increment(None, (0.0, inf, 0.0))),
        ('increment_too_large', send_increment(None, (15.0, 15.0, 0.0))),
        ('increment_too_large', send_increment(None, (1e300, -1e300, 1e300))),
        ('non_finite_measurement', send_measurement(None, (0.5, nan, 0.5, 0.5))),
        ('non_finite_measurement', send_measurement(None, (-inf, 0.0, 0.0, 0.0))),
        ('zero_quaternion', send_measurement(None, (0.0, 0.0, 0.0, 0.0))),
        ('zero_quaternion', send_measurement(None, (5e-324, 0.0, 0.0, 5e-324))),
        ('norm_out_of_tolerance', send_measurement(None, (1.5, 0.0, 0.0, 0.0))),
        ('norm_out_of_tolerance', send_measurement(None, (1e308, 1e308, 0.0, 0.0))),
        ('zero_stamp_increment', send_increment(0, (0.1, 0.1, 0.1))),
        ('zero_stamp_measurement', send_measurement(0, (1.0, 0.0, 0.0, 0.0))),
        ('stale_increment', send_old_increment(PERIOD)),
        ('stale_measurement', send_old_measurement(3 * PERIOD)),
        ('duplicate_increment', send_old_increment(0)),
        ('duplicate_measurement', send_old_measurement(0)),
    ]
    expected = dict(observer.drops)
    for reason, inject in cases:
        driver.step(before=inject)
        expected[reason] += 1
        assert observer.drops == expected, reason
    # A measurement slightly off unit norm is normalized, not dropped.
    driver.step(scale=1.05)
    assert observer.counts['steps_corrected'] == driver.steps_done()
    assert observer.drops == expected

    # The status of the period names the reasons, then goes back to OK.
    status = fresh_status(spinner, probe, OBSERVER_STATUS,
                          lambda v: v['steps'] == str(driver.steps_done()))
    values = values_of(status)
    for reason, count in expected.items():
        assert values[f'dropped_{reason}'] == str(count), reason
    assert accounted(values)
    warned = [s for s in probe.statuses[OBSERVER_STATUS] if s.level == DiagnosticStatus.WARN]
    assert warned and 'dropping inputs' in warned[0].message
    assert fresh_status(spinner, probe, OBSERVER_STATUS).level == DiagnosticStatus.OK

    # Still converging on valid input; nothing non-finite was ever published.
    driver.run(60)
    assert driver.error() < 0.6
    assert_all_finite(probe)
    # Every estimate is the core's, fed the valid inputs only.
    driver.drain()
    reference = SingleObserver(initial=initial)
    for stamp in sorted(driver.sent):
        theta, y = driver.sent[stamp]
        expected_state = reference.step(theta, unit(y))
        assert probe.estimates[stamp + PERIOD] == pytest.approx(expected_state, abs=1e-12)


def test_jumps_gaps_and_the_reset_service(ros_context, spinner):
    initial = (1.3, 0.0, 0.0, 0.0)
    observer, probe = observer_and_probe(spinner, ros_context, initial_estimate=list(initial))
    driver = Driver(spinner, probe, observer)
    driver.run(40)
    assert driver.error() < 0.6

    # A bag that restarts: stamps 90 s back. The observer starts over from
    # initial_estimate on the new time line and converges again.
    first = driver.step_at(10 * SECOND)
    assert observer.resets['backward_jump'] == 1
    assert probe.estimates[first + PERIOD] == driver.fresh_estimate(initial, first)
    driver.run(40)
    assert driver.error() < 0.6

    # A forward gap of 5 s: counted, and by default the observer goes on.
    driver.jump(driver.stamp + 5 * SECOND)
    driver.step()
    assert observer.pairer.events['forward_gaps'] == 1
    assert observer.resets['forward_gap'] == 0
    # With forward_gap_action = reset, it starts over.
    [result] = observer.set_parameters([Parameter('forward_gap_action', value='reset')])
    assert result.successful
    gap = driver.step_at(driver.stamp + 5 * SECOND)
    assert observer.resets['forward_gap'] == 1
    assert probe.estimates[gap + PERIOD] == driver.fresh_estimate(initial, gap)

    # The reset service.
    client = probe.create_client(Trigger, '/observer/reset')
    spinner.spin_until(client.service_is_ready, 5.0, 'the reset service')
    future = client.call_async(Trigger.Request())
    spinner.spin_until(future.done, 5.0, 'the reset answer')
    assert future.result().success
    assert 'initial estimate' in future.result().message
    assert observer.resets['service'] == 1
    assert observer.observer.state == initial
    driver.run(80)
    assert driver.error() < 0.6

    status = fresh_status(spinner, probe, OBSERVER_STATUS,
                          lambda v: v['steps'] == str(driver.steps_done()))
    values = values_of(status)
    assert (values['resets_backward_jump'], values['resets_forward_gap'],
            values['resets_service'], values['forward_gaps']) == ('1', '1', '1', '2')
    assert values['resets_clock_jump'] == '0'
    assert accounted(values)
    assert_all_finite(probe)


def test_a_silent_input_warns_with_its_topic_and_clears(ros_context, spinner):
    observer, probe = observer_and_probe(spinner, ros_context, input_timeout=0.3,
                                         measurement_timeout=0.02)
    driver = Driver(spinner, probe, observer)
    # Before the first increment the node is only waiting: no warning.
    status = fresh_status(spinner, probe, OBSERVER_STATUS)
    assert status.level == DiagnosticStatus.OK, status.message
    driver.run(20)

    def silent(kind, at_least):
        return lambda v: float(v[f'{kind}s_silent_s']) >= at_least

    # The gyro stops: WARN, naming the topic, once 0.3 s have passed. (The
    # statuses come every 0.1 s and the value is written with 6 digits: the
    # one that reads 0.3 may be 0.2999996, still below the timeout.)
    status = fresh_status(spinner, probe, OBSERVER_STATUS, silent('increment', 0.35))
    assert status.level == DiagnosticStatus.WARN
    assert 'no increments on /gyro/increment for' in status.message, status.message
    assert 'no measurements' not in status.message, status.message
    # It comes back: OK, the silence 0 again.
    driver.run(5)
    status = fresh_status(spinner, probe, OBSERVER_STATUS,
                          lambda v: v['steps'] == str(driver.steps_done()))
    assert status.level == DiagnosticStatus.OK, status.message
    assert float(values_of(status)['increments_silent_s']) < 0.3

    # Increments without measurements: the steps propagate, and say why.
    corrected = observer.counts['steps_corrected']

    def warned():
        probe.send_increment(driver.stamp, (0.01, 0.0, 0.0))
        driver.stamp += PERIOD
        spinner.spin_for(0.05)
        last = probe.last_status(OBSERVER_STATUS)
        return last.level == DiagnosticStatus.WARN and 'no measurements' in last.message
    spinner.spin_until(warned, 5.0, 'a warning about the measurements')
    status = probe.last_status(OBSERVER_STATUS)
    assert ('no measurements on /attitude/measurement for' in status.message
            and 'steps propagate' in status.message), status.message
    assert float(values_of(status)['measurements_silent_s']) >= 0.3
    assert observer.counts['steps_corrected'] == corrected
    assert observer.counts['steps_propagated'] > 0
    assert accounted(values_of(status))


def test_clock_jump_resets_observer_and_monitor(ros_context, spinner):
    observer, probe = observer_and_probe(spinner, ros_context, use_sim_time=True,
                                         measurement_timeout=30.0)
    monitor = spinner.add(MonitorNode(context=ros_context, parameter_overrides=overrides(
        use_sim_time=True, diagnostic_period=0.1)))
    clock = probe.create_publisher(Clock, '/clock', 10)
    wait_for_subscribers(spinner, clock, 2)

    def set_clock(seconds):
        clock.publish(Clock(clock=stamp_from_nanoseconds(round(seconds * SECOND))))
        spinner.spin_until(
            lambda: observer.get_clock().now().nanoseconds == round(seconds * SECOND)
            and monitor.get_clock().now().nanoseconds == round(seconds * SECOND),
            5.0, f'the clock at {seconds} s')

    def status_after_ticks(name, predicate=lambda values: True):
        # Timers run on ROS time: the clock must move for a status to come.
        seen = len(probe.statuses.get(name, []))
        now = observer.get_clock().now().nanoseconds / SECOND
        for tick in range(1, 40):
            set_clock(now + 0.05 * tick)
            spinner.spin_for(0.02)
            for status in probe.statuses.get(name, [])[seen:]:
                if predicate(values_of(status)):
                    return status
        pytest.fail(f'no {name!r} status')

    set_clock(100.0)
    driver = Driver(spinner, probe, observer)
    driver.run(30)
    wait_for_subscribers(spinner, probe.estimate_publisher)
    spinner.spin_until(lambda: monitor.estimates_received > 0, 5.0, 'an estimate')
    # An increment waits for its measurement when the clock goes back 50 s
    # (a bag that restarts): discarded, counted, and the observer starts over.
    probe.send_increment(driver.stamp, (0.1, 0.2, 0.3))
    spinner.spin_until(lambda: observer.pairer.waiting('increment') == 1, 5.0,
                       'the waiting increment')
    set_clock(50.0)
    assert observer.resets['clock_jump'] == 1
    assert observer.drops['discarded_increment'] == 1
    assert observer.observer.state == (1.0, 0.0, 0.0, 0.0)
    assert monitor.clock_jumps == 1
    assert len(monitor.distances) == 0
    # A jump forward is not a fault.
    set_clock(80.0)
    assert observer.resets['clock_jump'] == 1 and monitor.clock_jumps == 1

    driver.jump(50 * SECOND)
    driver.run(40)
    assert driver.error() < 0.6
    status = status_after_ticks(OBSERVER_STATUS)
    assert values_of(status)['resets_clock_jump'] == '1'
    assert values_of(status)['dropped_discarded_increment'] == '1'
    assert accounted(values_of(status))
    status = status_after_ticks(STATUS_NAME)
    assert values_of(status)['clock_jumps'] == '1'


def test_divergence_guard_reinitializes_and_the_observer_recovers(ros_context, spinner):
    # A gain that makes the plain observer diverge.
    observer, probe = observer_and_probe(spinner, ros_context, variant='plain',
                                         gain=[2.5, 0.0, 0.0, 0.0])
    driver = Driver(spinner, probe, observer)
    driver.run(40)
    reinitialized = observer.reinitializations['residual_too_large']
    assert reinitialized > 0
    assert_all_finite(probe)
    for q in probe.estimates.values():
        assert abs(sum(v * v for v in q) - 1.0) <= 15.0
    status = fresh_status(spinner, probe, OBSERVER_STATUS,
                          lambda v: v['steps'] == str(driver.steps_done()))
    assert int(values_of(status)['reinitialized_residual_too_large']) == reinitialized
    assert any(s.level == DiagnosticStatus.WARN and 'reinitialized_residual_too_large'
               in s.message for s in probe.statuses[OBSERVER_STATUS])
    # The paper's gain again: it converges.
    [result] = observer.set_parameters([Parameter('gain', value=[0.11, -0.18, -0.18, -0.18])])
    assert result.successful
    driver.run(90)
    assert observer.reinitializations['residual_too_large'] == reinitialized
    assert driver.error() < 0.6


# QoS ------------------------------------------------------------------------------

def test_incompatible_qos_is_reported_with_the_fix(ros_context, spinner):
    observer = spinner.add(ObserverNode(context=ros_context, parameter_overrides=overrides(
        diagnostic_period=0.1)))
    monitor = spinner.add(MonitorNode(context=ros_context, parameter_overrides=overrides(
        diagnostic_period=0.1)))
    gyro = spinner.add(GyroNode(context=ros_context, parameter_overrides=overrides(
        diagnostic_period=0.1, steps=1)))
    probe = spinner.add(Probe(ros_context))
    best_effort = QoSProfile(depth=10, reliability=ReliabilityPolicy.BEST_EFFORT)
    transient = QoSProfile(depth=10, durability=DurabilityPolicy.TRANSIENT_LOCAL)
    # A sensor-data style publisher into the observer and into the monitor, and
    # a latching subscriber on the observer's and the gyro's outputs.
    bad = [probe.create_publisher(Vector3Stamped, 'gyro/increment', best_effort),
           probe.create_publisher(QuaternionStamped, 'attitude_estimate', best_effort),
           probe.create_subscription(QuaternionStamped, 'attitude_estimate/unit',
                                     lambda msg: None, transient),
           probe.create_subscription(QuaternionStamped, 'attitude/ground_truth',
                                     lambda msg: None, transient)]

    def problems(node):
        return node.qos.problems

    spinner.spin_until(lambda: '/gyro/increment' in problems(observer)
                       and '/attitude_estimate/unit' in problems(observer)
                       and '/attitude_estimate' in problems(monitor)
                       and '/attitude/ground_truth' in problems(gyro), 10.0,
                       'the incompatible QoS events')
    text = observer.qos.problems['/gyro/increment']
    assert 'publisher /probe on /gyro/increment: publisher is BEST_EFFORT, subscription ' \
           'is RELIABLE: publish with RELIABLE reliability, or set this node\'s ' \
           'input_reliability to best_effort' in text
    assert 'subscribe with VOLATILE durability' in observer.qos.problems[
        '/attitude_estimate/unit']
    assert 'publish with RELIABLE reliability' in monitor.qos.problems['/attitude_estimate']
    assert 'subscribe with VOLATILE durability' in gyro.qos.problems['/attitude/ground_truth']

    for name in (OBSERVER_STATUS, STATUS_NAME, 'gyro: outputs'):
        status = fresh_status(spinner, probe, name,
                              lambda v: int(v['qos_incompatible_events']) > 0)
        # At least WARN: the monitor may be at ERROR for the gyro's one step, or
        # STALE once that step is older than its stale_timeout (a loaded machine).
        assert status.level in (DiagnosticStatus.WARN, DiagnosticStatus.ERROR,
                                DiagnosticStatus.STALE), name
        assert status.level != DiagnosticStatus.STALE or name == STATUS_NAME, name
        assert 'incompatible QoS on' in status.message
        assert any(key.startswith('qos_incompatible:/') for key in values_of(status))
    values = values_of(fresh_status(spinner, probe, OBSERVER_STATUS))
    assert 'set this node\'s input_reliability' in values['qos_incompatible:/gyro/increment']

    # The incompatible peers leave: back to OK, the count stays.
    for endpoint in bad:
        if isinstance(endpoint, Publisher):
            probe.destroy_publisher(endpoint)
        else:
            probe.destroy_subscription(endpoint)
    status = fresh_status(spinner, probe, OBSERVER_STATUS,
                          lambda v: not any(k.startswith('qos_incompatible:') for k in v),
                          timeout=10.0)
    assert status.level == DiagnosticStatus.OK
    assert int(values_of(status)['qos_incompatible_events']) >= 2


def test_observer_with_best_effort_inputs_takes_a_best_effort_publisher(ros_context, spinner):
    observer = spinner.add(ObserverNode(context=ros_context, parameter_overrides=overrides(
        input_reliability='best_effort', measurement_timeout=0.0)))
    probe = spinner.add(Probe(ros_context))
    publisher = probe.create_publisher(
        Vector3Stamped, 'gyro/increment',
        QoSProfile(depth=10, reliability=ReliabilityPolicy.BEST_EFFORT))
    wait_for_subscribers(spinner, publisher)
    spinner.spin_for(0.2)
    publisher.publish(vector_stamped((0.1, 0.2, 0.3), SECOND, 'base_link'))
    spinner.spin_until(lambda: observer.pairer.processed['increment'] == 1, 5.0, 'a step')
    assert not observer.qos.problems


# The monitor ----------------------------------------------------------------------

def test_monitor_drops_non_finite_estimates_and_counts_them(ros_context, spinner):
    monitor = spinner.add(MonitorNode(context=ros_context, parameter_overrides=overrides(
        diagnostic_period=0.1)))
    probe = spinner.add(Probe(ros_context))
    wait_for_subscribers(spinner, probe.estimate_publisher)
    wait_for_subscribers(spinner, probe.truth_publisher)
    stamp = SECOND
    for q in [(1.0, 0.0, 0.0, 0.0), (nan, 0.0, 0.0, 0.0), (inf, 0.0, 0.0, 0.0),
              (1e200, 1e200, 0.0, 0.0), (0.0, 1.0, 0.0, 0.0)]:
        stamp += SECOND // 10
        probe.truth_publisher.publish(quaternion_stamped(q, stamp, 'world'))
        probe.estimate_publisher.publish(quaternion_stamped(q, stamp, 'world'))
    spinner.spin_until(lambda: monitor.estimates_received == 5
                       and monitor.truths_received == 5, 5.0, 'the estimates')
    assert monitor.drops['non_finite_estimate'] == 3
    assert monitor.drops['non_finite_ground_truth'] == 3
    spinner.spin_until(lambda: len(probe.distances) == 2, 5.0, 'the distances')
    assert all(map(math.isfinite, probe.distances))
    status = fresh_status(spinner, probe, STATUS_NAME)
    values = values_of(status)
    assert any(s.level == DiagnosticStatus.WARN and 'non_finite_estimate' in s.message
               for s in probe.statuses[STATUS_NAME])
    assert (values['estimates_received'], values['estimates_processed'],
            values['dropped_non_finite_estimate'], values['ground_truth_paired']) == (
                '5', '2', '3', '2')
    assert float(values['attitude_error_max']) == pytest.approx(0.0, abs=1e-9)
    assert fresh_status(spinner, probe, STATUS_NAME).level == DiagnosticStatus.OK


def test_monitor_drops_the_oldest_unpaired_ground_truth(ros_context, spinner):
    # queue_depth 1: at most 4 · max(1, 10) = 40 ground truths wait for an estimate.
    monitor = spinner.add(MonitorNode(context=ros_context, parameter_overrides=overrides(
        diagnostic_period=0.1, queue_depth=1)))
    probe = spinner.add(Probe(ros_context))
    # Two subscribers each: the probe's own and the monitor's.
    wait_for_subscribers(spinner, probe.truth_publisher, 2)
    wait_for_subscribers(spinner, probe.estimate_publisher, 2)
    for k in range(1, 46):
        probe.truth_publisher.publish(quaternion_stamped((1.0, 0.0, 0.0, 0.0), k * SECOND,
                                                         'world'))
        spinner.spin_until(lambda: monitor.truths_received == k, 5.0, f'truth {k}')
    assert monitor.drops['unpaired_ground_truth'] == 5
    values = values_of(fresh_status(spinner, probe, STATUS_NAME))
    assert (values['ground_truth_received'], values['dropped_unpaired_ground_truth'],
            values['waiting_ground_truth'], values['ground_truth_paired']) == (
                '45', '5', '40', '0')
    # The oldest went: the truth of stamp 6 s still pairs, that of 5 s not.
    # (One at a time: the monitor's reader history holds one message.)
    for k in (5, 6):
        probe.estimate_publisher.publish(quaternion_stamped((1.0, 0.0, 0.0, 0.0),
                                                            k * SECOND, 'world'))
        spinner.spin_until(lambda: monitor.estimates_received == k - 4, 5.0, 'an estimate')
    assert monitor.truths_paired == 1
