"""
The ``monitor`` node: how far the estimate is from S³ and from the truth.

For every ``attitude_estimate`` (``QuaternionStamped``, ambient ``q̂``) it
publishes ``attitude_estimate/manifold_distance`` (``std_msgs/Float64``,
``|‖q̂‖ − 1|``). When ``attitude/ground_truth`` is published, each estimate is
paired with the truth of the same stamp (within ``stamp_tolerance``) and the
attitude error, the sign-invariant angle between the two rotations, enters
the statistics.

Every ``diagnostic_period`` it publishes a ``DiagnosticArray`` on
``/diagnostics`` with one status, ``monitor: attitude estimate``:

- STALE when no estimate arrived for ``stale_timeout`` (or none yet);
- else ERROR when the mean distance over the last ``window`` estimates
  exceeds ``error_distance``; WARN when it exceeds ``warn_distance``, when
  inputs were dropped since the last status, or while a peer with
  incompatible QoS is present; OK otherwise (a mean, because a single step
  of the paper's setup, with increments up to 10 rad, can leave S³ by 0.3
  while the estimate is fine);

with the key values listed in :data:`DIAGNOSTIC_KEYS` and
:data:`COUNTER_KEYS` (the attitude error keys only once an estimate was
paired with the ground truth).

Nothing is dropped silently: an estimate or a ground truth with a NaN or an
infinity (or a norm that overflows) is dropped and counted; a ground truth
that no estimate paired with is dropped (counted) once more than
``4 · max(queue_depth, 10)`` wait. So ``estimates_received =
estimates_processed + dropped_non_finite_estimate`` and
``ground_truth_received = ground_truth_paired + dropped_non_finite_ground_truth
+ dropped_unpaired_ground_truth + waiting_ground_truth``. A backward jump of
the node's clock (``use_sim_time`` and ``/clock`` going back) clears the
window, whose rate and age would mix two time lines (``clock_jumps``).
"""

from collections import deque
import math

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import QuaternionStamped
import numpy as np
from rclpy.clock import ClockChange, JumpThreshold
from rclpy.duration import Duration
from rclpy.node import Node
from rclpy.qos import QoSProfile
from std_msgs.msg import Float64

from ext_observer.nodes.conversions import nanoseconds_from_stamp, quaternion_from_msg
from ext_observer.core import attitude_error
from ext_observer.nodes.node_common import (CounterDeltas, diagnostic_array, key_values,
                                      NodeParameters, ParameterError, QosWatch, run_node)
from ext_observer.nodes.node_parameters import MONITOR_PARAMETERS, monitor_settings

__all__ = ['COUNTER_KEYS', 'DIAGNOSTIC_KEYS', 'DROP_REASONS', 'ERROR_KEYS',
           'MonitorNode', 'STATUS_NAME', 'main']

STATUS_NAME = 'monitor: attitude estimate'

# Why an input was dropped; reported as dropped_<reason>.
DROP_REASONS = ('non_finite_estimate', 'non_finite_ground_truth',
                'unpaired_ground_truth')

# Always present, from the first status on.
COUNTER_KEYS = (
    'estimates_received',
    'estimates_processed',
    'ground_truth_received',
    'ground_truth_paired',
    'waiting_estimates',
    'waiting_ground_truth',
    'clock_jumps',
    'qos_incompatible_events',
) + tuple(f'dropped_{reason}' for reason in DROP_REASONS)

# Present once an estimate arrived.
DIAGNOSTIC_KEYS = (
    'distance',                 # |‖q̂‖ − 1| of the last estimate
    'constraint_residual',      # |q̄q − 1| of the last estimate
    'distance_mean',            # over the last `window` estimates
    'distance_std',
    'distance_max',
    'window',                   # estimates in the statistics
    'estimate_rate_hz',         # over the window, by arrival time
    'last_estimate_age_s',      # node clock now − arrival of the last estimate
)

# Present once an estimate was paired with the ground truth; rad.
ERROR_KEYS = (
    'attitude_error',
    'attitude_error_mean',
    'attitude_error_std',
    'attitude_error_max',
)

def _statistics(values):
    array = np.asarray(values, dtype=float)
    return float(array.mean()), float(array.std()), float(array.max())


def _finite_quaternion(msg):
    """Return the message's quaternion and its norm, or None if not finite."""
    q = quaternion_from_msg(msg)
    if not all(map(math.isfinite, q)):
        return None
    # hypot scales: a finite norm for any finite components.
    n = math.hypot(*q)
    if not math.isfinite(n * n):
        return None
    return q, n


class MonitorNode(Node):
    """
    Measure the estimate's distance to S³ and its error; publish diagnostics.

    Parameters
    ----------
    node_name : str
        Default ``monitor``.
    **kwargs
        Passed to ``rclpy.node.Node`` (``context``, ``namespace``,
        ``parameter_overrides``, ...).

    Attributes
    ----------
    last_status : diagnostic_msgs.msg.DiagnosticStatus or None
        The status last published.

    Raises
    ------
    ParameterError
        If a parameter is refused at start-up.

    """

    NODE_NAME = 'monitor'

    def __init__(self, node_name=NODE_NAME, **kwargs):
        super().__init__(node_name, **kwargs)
        try:
            self.parameters = NodeParameters(self, MONITOR_PARAMETERS, monitor_settings)
        except ParameterError:
            self.destroy_node()
            raise
        settings = self.parameters.settings
        window = settings['window']
        depth = settings['queue_depth']
        self._jump_handle = None
        self.distances = deque(maxlen=window)
        self.errors = deque(maxlen=window)
        self._arrivals = deque(maxlen=window)
        self._last = None            # (distance, residual) of the last estimate
        self._last_error = None
        # Estimates and truths waiting for their pair: stamp (ns) -> quaternion.
        self._estimates = {}
        self._truths = {}
        self._pairing_limit = max(depth, 10) * 4
        self.estimates_received = 0
        self.estimates_processed = 0
        self.truths_received = 0
        self.truths_paired = 0
        self.clock_jumps = 0
        self.drops = dict.fromkeys(DROP_REASONS, 0)
        self._deltas = CounterDeltas()
        self.last_status = None
        self.qos = QosWatch(self)
        qos = QoSProfile(depth=depth)
        self.distance_publisher = self.create_publisher(
            Float64, 'attitude_estimate/manifold_distance', qos,
            event_callbacks=self.qos.publisher('attitude_estimate/manifold_distance', qos))
        diagnostics_qos = QoSProfile(depth=10)
        self.diagnostics_publisher = self.create_publisher(
            DiagnosticArray, '/diagnostics', diagnostics_qos,
            event_callbacks=self.qos.publisher('/diagnostics', diagnostics_qos))
        self.estimate_subscription = self.create_subscription(
            QuaternionStamped, 'attitude_estimate', self.estimate_callback, qos,
            event_callbacks=self.qos.subscription('attitude_estimate', qos))
        self.truth_subscription = self.create_subscription(
            QuaternionStamped, 'attitude/ground_truth', self.truth_callback, qos,
            event_callbacks=self.qos.subscription('attitude/ground_truth', qos))
        self.diagnostic_timer = self.create_timer(
            settings['diagnostic_period'], self.diagnostic_callback)
        self._jump_handle = self.get_clock().create_jump_callback(
            JumpThreshold(min_forward=None, min_backward=Duration(
                nanoseconds=-round(settings['clock_jump_threshold'] * 1e9)),
                on_clock_change=True),
            post_callback=self.clock_jump_callback)
        self.get_logger().info(
            f'watching {self.estimate_subscription.topic_name} (distance to S³: WARN above '
            f'{settings["warn_distance"]:g}, ERROR above {settings["error_distance"]:g} over '
            f'{settings["window"]} estimates; STALE after {settings["stale_timeout"]:g} s) '
            f'and {self.truth_subscription.topic_name}')

    def destroy_node(self):
        """Unregister the clock jump callback, then destroy the node."""
        if getattr(self, '_jump_handle', None) is not None:
            self._jump_handle.unregister()
            self._jump_handle = None
        super().destroy_node()

    def estimate_callback(self, msg):
        """Publish the distance to S³ and update the statistics."""
        self.estimates_received += 1
        checked = _finite_quaternion(msg.quaternion)
        if checked is None:
            self.drops['non_finite_estimate'] += 1
            return
        q, n = checked
        distance = abs(n - 1.0)
        residual = abs(n * n - 1.0)
        self.distance_publisher.publish(Float64(data=distance))
        self.estimates_processed += 1
        self.distances.append(distance)
        self._last = (distance, residual)
        self._arrivals.append(self.get_clock().now().nanoseconds)
        stamp = nanoseconds_from_stamp(msg.header.stamp)
        truth = self._take_pair(self._truths, stamp)
        if truth is None:
            self._keep(self._estimates, stamp, q)
        else:
            self.truths_paired += 1
            self._add_error(q, truth)

    def truth_callback(self, msg):
        """Pair the ground truth with the estimate of the same stamp."""
        self.truths_received += 1
        checked = _finite_quaternion(msg.quaternion)
        if checked is None:
            self.drops['non_finite_ground_truth'] += 1
            return
        q = checked[0]
        stamp = nanoseconds_from_stamp(msg.header.stamp)
        estimate = self._take_pair(self._estimates, stamp)
        if estimate is None:
            self._keep(self._truths, stamp, q, 'unpaired_ground_truth')
        else:
            self.truths_paired += 1
            self._add_error(estimate, q)

    def clock_jump_callback(self, jump):
        """Clear the window at a backward jump of the clock or a time source switch."""
        if jump.delta.nanoseconds >= 0 and jump.clock_change not in (
                ClockChange.ROS_TIME_ACTIVATED, ClockChange.ROS_TIME_DEACTIVATED):
            return
        self.clock_jumps += 1
        self.distances.clear()
        self.errors.clear()
        self._arrivals.clear()
        self._last = None
        self._last_error = None
        self.get_logger().warning('the clock jumped back or changed source: statistics '
                                  'cleared', throttle_duration_sec=5.0)

    def _take_pair(self, waiting, stamp):
        if not waiting:
            return None
        tolerance = round(self.parameters.settings['stamp_tolerance'] * 1e9)
        nearest = min(waiting, key=lambda t: abs(t - stamp))
        if abs(nearest - stamp) > tolerance:
            return None
        return waiting.pop(nearest)

    def _keep(self, waiting, stamp, q, reason=None):
        # An estimate without its truth was processed all the same (the truth
        # is optional); a truth without its estimate is dropped, counted.
        waiting[stamp] = q
        while len(waiting) > self._pairing_limit:
            del waiting[min(waiting)]
            if reason is not None:
                self.drops[reason] += 1

    def _add_error(self, estimate, truth):
        try:
            error = float(attitude_error(np.asarray(estimate), np.asarray(truth)))
        except ValueError as exc:
            # A zero or non-finite quaternion has no attitude.
            self.get_logger().warning(f'no attitude error: {exc}',
                                      throttle_duration_sec=5.0)
            return
        self.errors.append(error)
        self._last_error = error

    def diagnostic_callback(self):
        """Publish the status of the estimate on ``/diagnostics``."""
        status = self.status()
        self.last_status = status
        self.diagnostics_publisher.publish(
            diagnostic_array(self.get_clock().now().to_msg(), [status]))

    def status(self):
        """
        Return the current ``DiagnosticStatus`` of the estimate.

        Returns
        -------
        status : diagnostic_msgs.msg.DiagnosticStatus

        """
        settings = self.parameters.settings
        now = self.get_clock().now().nanoseconds
        self.qos.refresh()
        rose = self._deltas.deltas(self.drops)
        status = DiagnosticStatus(
            name=STATUS_NAME,
            hardware_id=settings['hardware_id'] or self.get_fully_qualified_name())
        counters = ([('estimates_received', self.estimates_received),
                     ('estimates_processed', self.estimates_processed),
                     ('ground_truth_received', self.truths_received),
                     ('ground_truth_paired', self.truths_paired),
                     ('waiting_estimates', len(self._estimates)),
                     ('waiting_ground_truth', len(self._truths)),
                     ('clock_jumps', self.clock_jumps)]
                    + [(f'dropped_{reason}', count) for reason, count in self.drops.items()]
                    + self.qos.key_values())
        problems = []
        if rose:
            problems.append('dropping inputs: ' + ', '.join(
                f'{reason} (+{count})' for reason, count in rose.items()))
        if self.qos.problems:
            problems.append('incompatible QoS on ' + ', '.join(sorted(self.qos.problems)))
        if self._last is None:
            status.level = DiagnosticStatus.STALE
            status.message = '; '.join(['no estimate received yet'] + problems)
            status.values = key_values(counters)
            return status
        distance, residual = self._last
        age = (now - self._arrivals[-1]) * 1e-9
        if len(self._arrivals) > 1 and self._arrivals[-1] > self._arrivals[0]:
            rate = (len(self._arrivals) - 1) / ((self._arrivals[-1] - self._arrivals[0]) * 1e-9)
        else:
            rate = 0.0
        mean, std, maximum = _statistics(self.distances)
        if age > settings['stale_timeout']:
            status.level = DiagnosticStatus.STALE
            status.message = f'no estimate for {age:.3g} s'
        elif mean > settings['error_distance']:
            status.level = DiagnosticStatus.ERROR
            status.message = (f'mean distance to S³ {mean:.3g} above '
                              f'{settings["error_distance"]:g}')
        elif mean > settings['warn_distance']:
            status.level = DiagnosticStatus.WARN
            status.message = (f'mean distance to S³ {mean:.3g} above '
                              f'{settings["warn_distance"]:g}')
        else:
            status.level = DiagnosticStatus.WARN if problems else DiagnosticStatus.OK
            status.message = f'mean distance to S³ {mean:.3g}'
        if problems:
            status.message = '; '.join([status.message] + problems)
        values = [('distance', distance), ('constraint_residual', residual),
                  ('distance_mean', mean), ('distance_std', std), ('distance_max', maximum),
                  ('window', len(self.distances)), ('estimate_rate_hz', rate),
                  ('last_estimate_age_s', age)] + counters
        if self._last_error is not None:
            error_mean, error_std, error_max = _statistics(self.errors)
            values += [('attitude_error', self._last_error),
                       ('attitude_error_mean', error_mean),
                       ('attitude_error_std', error_std),
                       ('attitude_error_max', error_max)]
            status.message += f', attitude error {self._last_error:.3g} rad'
        status.values = key_values(values)
        return status


def main(args=None):
    """Run the ``monitor`` node (``ros2 run ext_observer monitor_node``)."""
    return run_node(MonitorNode, args)


if __name__ == '__main__':
    import sys
    sys.exit(main())
