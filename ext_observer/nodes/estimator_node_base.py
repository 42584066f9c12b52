"""
What the two estimator nodes share: inputs, stamps, faults, diagnostics.

``observer_node`` (the paper's observer) and ``imu_filter_node`` (the
raw-IMU estimator) differ in their estimator and their topics; everything
else is written here once, in :class:`EstimatorNode`:

- the parameters (:class:`~ext_observer.nodes.ros_parameters.NodeParameters`);
- the inputs' QoS (the sensor-data profile, overridable) and the watch for
  incompatible peers (:class:`~ext_observer.nodes.node_common.QosWatch`);
- the outputs ``attitude_estimate`` and ``imu/data``, and whether anyone
  subscribes to each (``imu/data`` goes out only then, and
  ``imu_filter_node``'s ``attitude_estimate`` too);
- resets: a backward jump of the input stamps, of the node's clock or a
  switch of its time source, a forward gap (``forward_gap_action``), the
  service ``~/reset``; reinitializations by the divergence guard; each
  counted by cause and logged (throttled);
- a silent input (none for ``input_timeout``), reported when it starts and
  ends;
- the status on ``/diagnostics``: every input accounted for
  (received = processed + dropped + waiting), the fault counters, WARN while
  any rose since the last status.

A subclass sets :attr:`pairer` (the
:class:`~ext_observer.pipeline.pairing.StepPairer` of its inputs) and the two
subscriptions, and provides :meth:`_reset_estimator`, :meth:`_estimator_values`,
:attr:`counts` and, where it has more to say, :meth:`_problems`.
"""

import math

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import QuaternionStamped
from rclpy.clock import ClockChange, JumpThreshold
from rclpy.duration import Duration
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.qos_overriding_options import QoSOverridingOptions
from sensor_msgs.msg import Imu
from std_srvs.srv import Trigger

from ext_observer.pipeline.guard import GUARD_REASONS
from ext_observer.nodes.node_common import (CounterDeltas, diagnostic_array, key_values,
                                      NodeParameters, ParameterError, ParameterSpec,
                                      QosWatch)
from ext_observer.pipeline.pairing import KINDS

__all__ = ['EstimatorNode', 'LOG_THROTTLE', 'RESET_CAUSES', 'SECOND', 'STATUS_SUFFIX']

# Why the estimator restarted from its initial state.
RESET_CAUSES = ('backward_jump', 'clock_jump', 'forward_gap', 'service')

# The status is named '<node name>: inputs'.
STATUS_SUFFIX = ': inputs'

SECOND = 1_000_000_000
# Faults are logged at most this often per kind, s.
LOG_THROTTLE = 5.0

def floor_text(seconds):
    """Return ``seconds`` rounded down to 0.01 s, as text (never more than measured)."""
    return f'{math.floor(seconds * 100.0) / 100.0:g}'


class EstimatorNode(Node):
    """
    The machinery of an estimator node; see the module docstring.

    Parameters
    ----------
    node_name : str
    specs : sequence of ParameterSpec
        The node's parameters
        (:data:`~ext_observer.pipeline.parameter_specs.COMMON_PARAMETERS` among them).
    validate : callable
        ``validate(values) -> settings``, raising ``ValueError``.
    **kwargs
        Passed to ``rclpy.node.Node``.

    Attributes
    ----------
    parameters : ext_observer.nodes.ros_parameters.NodeParameters
    resets : dict
        Restarts, by cause (:data:`RESET_CAUSES`).
    reinitializations : dict
        Restarts by the divergence guard, by reason
        (:data:`~ext_observer.pipeline.guard.GUARD_REASONS`).

    Raises
    ------
    ParameterError
        If a parameter is refused at start-up.

    """

    # What the inputs of each kind are called in a warning.
    INPUT_WORDS = {'increment': 'increments', 'measurement': 'measurements'}

    def __init__(self, node_name, specs, validate, **kwargs):
        super().__init__(node_name, **kwargs)
        self._jump_handle = None
        try:
            self.parameters = NodeParameters(self, specs, validate, self._apply_parameters)
        except ParameterError:
            self.destroy_node()
            raise
        settings = self.parameters.settings
        self.resets = dict.fromkeys(RESET_CAUSES, 0)
        self.reinitializations = dict.fromkeys(GUARD_REASONS, 0)
        self._deltas = CounterDeltas()
        self._clock = self.get_clock()
        # Per kind: (inputs received, node clock at the first status that
        # saw that count). Nothing came since then, so the input has been
        # silent for at least now minus that time.
        self._heard = dict.fromkeys(KINDS, (0, self._clock.now().nanoseconds))
        self._quiet = set()     # the kinds reported silent at the last status
        self.qos = QosWatch(self)
        depth = settings['queue_depth']
        output_qos = QoSProfile(depth=depth)
        self.estimate_publisher = self.create_publisher(
            QuaternionStamped, 'attitude_estimate', output_qos,
            event_callbacks=self.qos.publisher('attitude_estimate', output_qos,
                                               matched=self.estimate_matched_callback))
        self._publish_estimate = self.estimate_publisher.get_subscription_count() > 0
        self.imu_publisher = self.create_publisher(
            Imu, 'imu/data', output_qos,
            event_callbacks=self.qos.publisher('imu/data', output_qos,
                                               matched=self.imu_matched_callback))
        self._publish_imu = self.imu_publisher.get_subscription_count() > 0
        diagnostics_qos = QoSProfile(depth=10)
        self.diagnostics_publisher = self.create_publisher(
            DiagnosticArray, '/diagnostics', diagnostics_qos,
            event_callbacks=self.qos.publisher('/diagnostics', diagnostics_qos))
        self.reset_service = self.create_service(Trigger, '~/reset', self.reset_callback)
        self._watch_clock(settings)
        self.diagnostic_timer = self.create_timer(
            settings['diagnostic_period'], self.diagnostic_callback)

    def destroy_node(self):
        """Unregister the clock jump callback, then destroy the node."""
        if getattr(self, '_jump_handle', None) is not None:
            self._jump_handle.unregister()
            self._jump_handle = None
        super().destroy_node()

    # What a subclass provides ---------------------------------------------

    def _reset_estimator(self):
        """Forget the estimate (a reset)."""
        raise NotImplementedError

    def _reset_message(self):
        """Return what ``~/reset`` answers."""
        raise NotImplementedError

    def _estimator_values(self):
        """Return the estimator's diagnostic pairs."""
        raise NotImplementedError

    def _problems(self, steps):
        """Return further WARN texts for this status (``steps`` processed so far)."""
        return []

    def _silent_texts(self, silent, timeout):
        """Return ``{kind: text}`` for the inputs silent for ``timeout`` or more."""
        quiet = {}
        if silent['increment'] >= timeout:
            quiet['increment'] = (
                f'no {self.INPUT_WORDS["increment"]} on '
                f'{self.increment_subscription.topic_name} for '
                f'{floor_text(silent["increment"])} s or more')
        return quiet

    def _forget_samples(self):
        """Drop whatever the subclass keeps of the inputs of the old time line."""

    # Inputs ---------------------------------------------------------------

    def _subscribe(self, msg_type, topic, callback, reliability=None, raw=False, lost=None):
        """
        Subscribe to an input at ``queue_depth``.

        With ``reliability`` (a ``ReliabilityPolicy``), exactly that; without,
        the sensor-data profile (best effort, volatile: it takes reliable and
        best-effort publishers alike), overridable with
        ``qos_overrides.<topic>.subscription.*``. With ``raw`` the callback
        gets the serialized message (CDR bytes); ``lost(info)``, if given, is
        rmw's message-lost event of the subscription.
        """
        depth = self.parameters.settings['queue_depth']
        if reliability is not None:
            qos = QoSProfile(depth=depth, reliability=reliability)
            hint = ("set this node's input_reliability to best_effort"
                    if reliability == ReliabilityPolicy.RELIABLE else '')
            return self.create_subscription(
                msg_type, topic, callback, qos, raw=raw,
                event_callbacks=self.qos.subscription(topic, qos, hint, lost))
        qos = QoSProfile(depth=depth, history=HistoryPolicy.KEEP_LAST,
                         reliability=ReliabilityPolicy.BEST_EFFORT,
                         durability=DurabilityPolicy.VOLATILE)
        name = self.resolve_topic_name(topic)
        return self.create_subscription(
            msg_type, topic, callback, qos, raw=raw,
            qos_overriding_options=QoSOverridingOptions.with_default_policies(),
            event_callbacks=self.qos.subscription(
                topic, qos, f'set qos_overrides.{name}.subscription.reliability to '
                'best_effort', lost))

    def imu_matched_callback(self, info):
        """A subscription to ``imu/data`` came or went."""
        self._publish_imu = info.current_count > 0

    def estimate_matched_callback(self, info):
        """A subscription to ``attitude_estimate`` came or went."""
        self._publish_estimate = info.current_count > 0

    # Resets ---------------------------------------------------------------

    def _reset(self, cause):
        self._reset_estimator()
        self.resets[cause] += 1

    def _backward_jump(self, stamp, reset=True):
        """Log a restarted time line; reset unless the caller did (``reset``)."""
        self._forget_samples()
        if reset:
            self._reset('backward_jump')
        self.get_logger().warning(
            f'input stamp {stamp * 1e-9:.9f} s is more than '
            f'{self.parameters.settings["backward_jump_threshold"]:g} s older than the last '
            'step: the time line restarted (a bag that loops?); estimator reset',
            throttle_duration_sec=LOG_THROTTLE)

    def _forward_gap(self, step, reset=True):
        """Log a step after a forward gap; reset if ``forward_gap_action`` says so."""
        action = self.parameters.settings['forward_gap_action']
        if action == 'reset' and reset:
            self._reset('forward_gap')
        self.get_logger().warning(
            f'{(step.stamp - step.previous) * 1e-9:.3f} s since the previous step: '
            + ('estimator reset' if action == 'reset' else 'propagating'),
            throttle_duration_sec=LOG_THROTTLE)

    def _reinitialized(self, reason, stamp, source, count=True):
        """Log a reinitialization by the divergence guard; count it unless done."""
        if count:
            self.reinitializations[reason] += 1
        self.get_logger().warning(
            f'divergence guard ({reason}) at stamp {stamp} ns: estimator reinitialized '
            f'from {source}', throttle_duration_sec=LOG_THROTTLE)

    def clock_jump_callback(self, jump):
        """Reset at a backward jump of the node's clock or a switch of its time source."""
        change = jump.clock_change
        if change in (ClockChange.ROS_TIME_ACTIVATED, ClockChange.ROS_TIME_DEACTIVATED):
            what = ('the clock switched to ROS time (/clock)'
                    if change == ClockChange.ROS_TIME_ACTIVATED
                    else 'the clock switched back to system time')
        elif jump.delta.nanoseconds < 0:
            what = f'the clock jumped back by {-jump.delta.nanoseconds * 1e-9:.3f} s'
        else:
            return
        discarded = self.pairer.restart()
        self._forget_samples()
        self._reset('clock_jump')
        self.get_logger().warning(
            f'{what}: estimator reset, {discarded} waiting inputs discarded',
            throttle_duration_sec=LOG_THROTTLE)

    def _watch_clock(self, settings):
        # rcl calls jump callbacks when ROS time (use_sim_time) is set or
        # switched on or off; system time never jumps for it, so the stamps
        # are checked too (StepPairer).
        if self._jump_handle is not None:
            self._jump_handle.unregister()
        threshold = JumpThreshold(
            min_forward=None,
            min_backward=Duration(nanoseconds=-round(
                settings['backward_jump_threshold'] * SECOND)),
            on_clock_change=True)
        self._jump_handle = self.get_clock().create_jump_callback(
            threshold, post_callback=self.clock_jump_callback)

    def reset_callback(self, request, response):
        """Service ``~/reset``: restart the estimator."""
        self._reset('service')
        response.success = True
        response.message = self._reset_message()
        self.get_logger().info(response.message)
        return response

    def _apply_parameters(self, settings, changed):
        """Take a runtime change; a subclass extends this."""
        if 'backward_jump_threshold' in changed:
            self._watch_clock(settings)

    # Diagnostics ----------------------------------------------------------

    def faults(self):
        """
        Return every fault counter by its diagnostic key.

        Returns
        -------
        counters : dict
            ``dropped_<reason>``, ``resets_<cause>``, ``reinitialized_<reason>``,
            ``forward_gaps``, ``early_releases``.

        """
        pairer = self.pairer
        counters = {f'dropped_{reason}': count for reason, count in pairer.drops.items()}
        counters.update((f'resets_{cause}', count) for cause, count in self.resets.items())
        counters.update((f'reinitialized_{reason}', count)
                        for reason, count in self.reinitializations.items())
        counters['forward_gaps'] = pairer.events['forward_gaps']
        counters['early_releases'] = pairer.events['early_releases']
        return counters

    def status(self):
        """
        Return the current ``DiagnosticStatus`` of the inputs.

        WARN while faults happen: any fault counter that rose since the last
        status, an incompatible QoS peer present now, a silent input, or what
        the subclass reports (:meth:`_problems`); OK otherwise.

        Returns
        -------
        status : diagnostic_msgs.msg.DiagnosticStatus

        """
        self.qos.refresh()
        faults = self.faults()
        rose = self._deltas.deltas(faults)
        pairer = self.pairer
        status = DiagnosticStatus(name=f'{self.get_name()}{STATUS_SUFFIX}',
                                  hardware_id=self.get_fully_qualified_name())
        steps = pairer.processed['increment']
        parts = []
        dropping = [key for key in rose if key.startswith('dropped_')]
        if dropping:
            parts.append('dropping inputs: ' + ', '.join(
                f'{key[len("dropped_"):]} (+{rose[key]})' for key in dropping))
        others = [key for key in rose if not key.startswith('dropped_')]
        if others:
            parts.append(', '.join(f'{key} (+{rose[key]})' for key in others))
        if self.qos.problems:
            parts.append('incompatible QoS on ' + ', '.join(sorted(self.qos.problems)))
        parts.extend(self._problems(steps))
        silent = self._silence()
        timeout = self.parameters.settings['input_timeout']
        quiet = {}
        if timeout > 0 and pairer.received['increment'] > 0:
            quiet = self._silent_texts(silent, timeout)
        logger = self.get_logger()
        for kind in quiet.keys() - self._quiet:
            logger.warning(quiet[kind])
        for kind in self._quiet - quiet.keys():
            logger.info(f'{self.INPUT_WORDS[kind]} arriving again')
        self._quiet = set(quiet)
        parts.extend(quiet.values())
        if parts:
            status.level = DiagnosticStatus.WARN
            status.message = '; '.join(parts)
        else:
            status.level = DiagnosticStatus.OK
            status.message = f'{steps} steps' if steps else 'waiting for inputs'
        received = sum(pairer.received.values())
        processed = sum(pairer.processed.values())
        dropped = sum(pairer.dropped(kind) for kind in KINDS)
        waiting = sum(pairer.waiting(kind) for kind in KINDS)
        state = self.state
        status.values = key_values(
            self._estimator_values() + [('steps', steps)]
            + list(self.counts.items())
            + [('inputs_received', received), ('inputs_processed', processed),
               ('inputs_dropped', dropped), ('inputs_waiting', waiting),
               ('waiting_increments', pairer.waiting('increment')),
               ('waiting_measurements', pairer.waiting('measurement')),
               ('increments_silent_s', silent['increment']),
               ('measurements_silent_s', silent['measurement'])]
            + list(faults.items())
            + self.qos.key_values()
            + [('estimate_norm', math.nan if state is None
                else math.sqrt(sum(v * v for v in state)))])
        return status

    def _silence(self):
        """
        Return, per kind, how long no input of it arrived, s (a lower bound).

        Counted at each status, so that no input callback reads a clock: an
        input counted at the status of time T arrived by T. 0 while they
        come; a backward jump of the node clock starts the count over.
        """
        now = self._clock.now().nanoseconds
        silent = {}
        for kind in KINDS:
            count = self.pairer.received[kind]
            heard, since = self._heard[kind]
            if count != heard or now < since:
                self._heard[kind] = (count, now)
                silent[kind] = 0.0
            else:
                silent[kind] = (now - since) * 1e-9
        return silent

    def diagnostic_callback(self):
        """Publish :meth:`status` on ``/diagnostics``."""
        # The outputs go out while someone subscribes: the matched events say
        # so at once, this keeps it right should one be missed.
        self._publish_imu = self.imu_publisher.get_subscription_count() > 0
        self._publish_estimate = self.estimate_publisher.get_subscription_count() > 0
        self.diagnostics_publisher.publish(
            diagnostic_array(self.get_clock().now().to_msg(), [self.status()]))
