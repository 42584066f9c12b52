"""
The ``observer`` node: the core's Luenberger-like observer on ROS topics.

Inputs, step k: ``gyro/increment`` (``Vector3Stamped``, ``θ_k`` in rad) and
``attitude/measurement`` (``QuaternionStamped``, ``y_k``), both stamped
``t_k``. Outputs: ``attitude_estimate`` (``QuaternionStamped``, the ambient
``q̂_{k+1}``, not normalized) and ``attitude_estimate/unit`` (the same,
normalized), both stamped ``t_{k+1}``; ``/diagnostics`` every
``diagnostic_period``.

Pairing
    Increments and measurements are paired by equal stamps and processed in
    stamp order. An increment waits at most ``measurement_timeout`` for its
    measurement; then, or as soon as a newer measurement shows that its own
    will not come (a publisher sends in stamp order), the step propagates
    with the increment only. A measurement without an increment waits until
    a step newer than it is processed (then it is dropped as unpaired) or
    until ``queue_depth`` newer measurements wait behind it.

Stamps
    An input whose stamp is not newer than the last processed step is dropped:
    ``duplicate`` if that step already used one like it, ``stale`` otherwise
    (older, or a measurement arriving after its step went on without it). So
    is a second input with the stamp of one still waiting (``duplicate``).
    Every drop is counted by reason and reported in ``/diagnostics``.

``t_{k+1}``
    The increment covers ``[t_k, t_{k+1})`` but carries only ``t_k``. The
    estimate is published at once, stamped ``t_k + Δ`` with ``Δ`` =
    ``step_period`` when set, else the interval between the two last
    processed steps; before two steps have been seen (and with
    ``step_period`` = 0), the first estimate is stamped ``t_k``.
"""

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import QuaternionStamped, Vector3Stamped
import numpy as np
from rclpy.node import Node

from ext_observer.conversions import (nanoseconds_from_stamp, quaternion_from_msg,
                                      quaternion_stamped, vector_from_msg)
from ext_observer.core import (certified_alpha_max, GAIN_MODES, norm, normalize,
                               PAPER_ALPHA, PAPER_GAIN, SingleObserver, VARIANTS)
from ext_observer.node_common import (diagnostic_array, key_values, NodeParameters,
                                      ParameterError, ParameterSpec, run_node)

__all__ = ['CERTIFIED_EPSILON', 'DROP_REASONS', 'OBSERVER_PARAMETERS',
           'ObserverNode', 'main', 'observer_settings']

# The sublevel V = (q̄q − 1)² ≤ ε of Theorem 1 that certifies `alpha`.
CERTIFIED_EPSILON = 0.5

# Why an input was dropped; every key is always reported in /diagnostics.
DROP_REASONS = (
    'stale_increment',
    'duplicate_increment',
    'stale_measurement',
    'duplicate_measurement',
    'unpaired_measurement',
    'step_failed',
)

OBSERVER_PARAMETERS = (
    ParameterSpec('variant', 'extended',
                  "Observer of Section 3.2: 'extended' (with the extension term), "
                  "'plain' (without) or 'projected' (plain, then normalized).",
                  constraints=f'One of {", ".join(VARIANTS)}.'),
    ParameterSpec('allow_uncertified_alpha', False,
                  'Accept an alpha outside the range certified by Theorem 1.'),
    ParameterSpec('alpha', PAPER_ALPHA,
                  'Gain α of the extension term (the paper: 0.01).', (0.0, 1.0),
                  constraints=f'Must lie in (0, certified_alpha_max({CERTIFIED_EPSILON}))'
                  ' ≈ (0, 0.078) unless allow_uncertified_alpha is true.'),
    ParameterSpec('gain', list(PAPER_GAIN),
                  "The paper's gain quaternion L as w, x, y, z (constant mode).",
                  constraints='4 finite numbers.'),
    ParameterSpec('gain_mode', 'constant',
                  "'constant' (L), 'rotating' (κ exp(θ/2)) or 'scheduled' "
                  '(running average, then κ_min exp(θ/2)).',
                  constraints=f'One of {", ".join(GAIN_MODES)}.'),
    ParameterSpec('kappa', 0.5, 'κ of the rotating mode.', (0.0, 1.0),
                  constraints='In (0, 1].'),
    ParameterSpec('kappa_min', 0.02, 'Floor κ_min of the scheduled mode.', (0.0, 1.0),
                  constraints='In (0, 1].'),
    ParameterSpec('initial_estimate', [1.0, 0.0, 0.0, 0.0],
                  'Initial estimate q̂_0 as w, x, y, z (ambient, need not be unit).',
                  read_only=True, constraints='4 finite numbers, not all zero.'),
    ParameterSpec('frame_id', 'world', 'frame_id of the published estimates.'),
    ParameterSpec('measurement_timeout', 0.1,
                  'Longest wait of an increment for its measurement, s; then the step '
                  'propagates without correction.', (0.0, 60.0)),
    ParameterSpec('step_period', 0.0,
                  't_{k+1} − t_k used to stamp the estimate, s; 0 = the interval '
                  'between the two last steps.', (0.0, 3600.0)),
    ParameterSpec('queue_depth', 10,
                  'History depth of every subscription and publisher (reliable, keep '
                  'last), and the most inputs waiting for their pair.', (1, 10000),
                  read_only=True),
    ParameterSpec('diagnostic_period', 1.0, 'Period of /diagnostics, s.', (0.01, 3600.0),
                  read_only=True),
)


def observer_settings(values):
    """
    Validate the observer's parameters.

    Parameters
    ----------
    values : dict
        Every parameter of :data:`OBSERVER_PARAMETERS` by name.

    Returns
    -------
    settings : dict
        ``values``, checked.

    Raises
    ------
    ValueError
        With the reason.

    """
    alpha = values['alpha']
    if not values['allow_uncertified_alpha']:
        alpha_max = certified_alpha_max(CERTIFIED_EPSILON)
        if not 0.0 < alpha < alpha_max:
            raise ValueError(
                f'alpha = {alpha:g} is outside the range certified by Theorem 1, '
                f'(0, {alpha_max:.4g}) for epsilon = {CERTIFIED_EPSILON}; set '
                'allow_uncertified_alpha to true to use it anyway')
    try:
        _make_observer(values)
    except ValueError as error:
        raise ValueError(f'the observer refuses these parameters: {error}') from None
    return dict(values)


def _make_observer(settings, initial=None):
    return SingleObserver(
        variant=settings['variant'], alpha=settings['alpha'], gain=settings['gain'],
        initial=settings['initial_estimate'] if initial is None else initial,
        gain_mode=settings['gain_mode'], kappa=settings['kappa'],
        kappa_min=settings['kappa_min'])


class ObserverNode(Node):
    """
    Estimate the attitude from gyro increments and attitude measurements.

    Parameters
    ----------
    node_name : str
        Default ``observer``.
    **kwargs
        Passed to ``rclpy.node.Node`` (``context``, ``namespace``,
        ``parameter_overrides``, ...).

    Attributes
    ----------
    observer : ext_observer.core.SingleObserver
    drops : dict
        Inputs dropped, by reason (:data:`DROP_REASONS`).
    counts : dict
        ``increments``, ``measurements`` received; ``steps_corrected``,
        ``steps_propagated`` processed.

    Raises
    ------
    ParameterError
        If a parameter is refused at start-up.

    """

    NODE_NAME = 'observer'

    def __init__(self, node_name=NODE_NAME, **kwargs):
        super().__init__(node_name, **kwargs)
        try:
            self.parameters = NodeParameters(self, OBSERVER_PARAMETERS,
                                             observer_settings, self._apply_parameters)
        except ParameterError:
            self.destroy_node()
            raise
        settings = self.parameters.settings
        self.observer = _make_observer(settings)
        self.drops = dict.fromkeys(DROP_REASONS, 0)
        self.counts = dict.fromkeys(
            ('increments', 'measurements', 'steps_corrected', 'steps_propagated'), 0)
        self._drops_reported = dict(self.drops)
        # stamp (ns) -> (increment, deadline in ns of the node clock)
        self._increments = {}
        # stamp (ns) -> measurement
        self._measurements = {}
        self._last_stamp = None
        self._last_interval = None
        self._last_corrected = False
        depth = settings['queue_depth']
        self.estimate_publisher = self.create_publisher(
            QuaternionStamped, 'attitude_estimate', depth)
        self.unit_publisher = self.create_publisher(
            QuaternionStamped, 'attitude_estimate/unit', depth)
        self.diagnostics_publisher = self.create_publisher(
            DiagnosticArray, '/diagnostics', 10)
        self.increment_subscription = self.create_subscription(
            Vector3Stamped, 'gyro/increment', self.increment_callback, depth)
        self.measurement_subscription = self.create_subscription(
            QuaternionStamped, 'attitude/measurement', self.measurement_callback, depth)
        self._timeout_timer = None
        self._start_timeout_timer(settings)
        self.diagnostic_timer = self.create_timer(
            settings['diagnostic_period'], self.diagnostic_callback)
        self.get_logger().info(
            f'{settings["variant"]} observer, alpha {settings["alpha"]:g}, '
            f'{settings["gain_mode"]} gain {settings["gain"]}')

    # Inputs ---------------------------------------------------------------

    def increment_callback(self, msg):
        """Queue ``θ_k`` and process every step that is ready."""
        self.counts['increments'] += 1
        stamp = nanoseconds_from_stamp(msg.header.stamp)
        if self._refuse(stamp, self._increments, 'increment'):
            return
        deadline = (self.get_clock().now().nanoseconds
                    + round(self.parameters.settings['measurement_timeout'] * 1e9))
        self._increments[stamp] = (vector_from_msg(msg.vector), deadline)
        self._process()

    def measurement_callback(self, msg):
        """Queue ``y_k`` and process every step that is ready."""
        self.counts['measurements'] += 1
        stamp = nanoseconds_from_stamp(msg.header.stamp)
        if self._refuse(stamp, self._measurements, 'measurement'):
            return
        self._measurements[stamp] = quaternion_from_msg(msg.quaternion)
        depth = self.parameters.settings['queue_depth']
        while len(self._measurements) > depth:
            del self._measurements[min(self._measurements)]
            self.drops['unpaired_measurement'] += 1
        self._process()

    def _refuse(self, stamp, waiting, kind):
        # A measurement for the last step, which went on without one, came
        # too late: stale, not a duplicate.
        used = kind == 'increment' or self._last_corrected
        if stamp in waiting or (stamp == self._last_stamp and used):
            self.drops[f'duplicate_{kind}'] += 1
            return True
        if self._last_stamp is not None and stamp <= self._last_stamp:
            self.drops[f'stale_{kind}'] += 1
            return True
        return False

    def timeout_callback(self):
        """Propagate the steps whose measurement did not come in time."""
        self._process()

    # Steps ----------------------------------------------------------------

    def _process(self):
        now = self.get_clock().now().nanoseconds
        while self._increments:
            stamp = min(self._increments)
            increment, deadline = self._increments[stamp]
            measurement = self._measurements.pop(stamp, None)
            if measurement is None:
                newer = any(t > stamp for t in self._measurements)
                if not newer and now < deadline:
                    return
            del self._increments[stamp]
            self._step(stamp, increment, measurement)

    def _step(self, stamp, increment, measurement):
        try:
            state = self.observer.step(increment, measurement)
            unit = normalize(np.asarray(state))
        except ValueError as error:
            self.drops['step_failed'] += 1
            self.get_logger().warning(f'step at stamp {stamp} ns failed: {error}',
                                      throttle_duration_sec=5.0)
            return
        self.counts['steps_corrected' if measurement is not None
                    else 'steps_propagated'] += 1
        if self._last_stamp is not None:
            self._last_interval = stamp - self._last_stamp
        self._last_stamp = stamp
        self._last_corrected = measurement is not None
        for old in [t for t in self._measurements if t <= stamp]:
            del self._measurements[old]
            self.drops['unpaired_measurement'] += 1
        stamp_next = stamp + self._interval()
        frame_id = self.parameters.settings['frame_id']
        self.estimate_publisher.publish(quaternion_stamped(state, stamp_next, frame_id))
        self.unit_publisher.publish(quaternion_stamped(unit, stamp_next, frame_id))

    def _interval(self):
        period = self.parameters.settings['step_period']
        if period > 0.0:
            return round(period * 1e9)
        return self._last_interval or 0

    # Parameters -----------------------------------------------------------

    def _start_timeout_timer(self, settings):
        if self._timeout_timer is not None:
            self.destroy_timer(self._timeout_timer)
        # Deadlines are checked four times per timeout (at most at 200 Hz).
        # With no timeout at all an increment never waits, so a slow check is
        # enough.
        timeout = settings['measurement_timeout']
        period = min(max(timeout / 4.0, 0.005), 0.25) if timeout > 0.0 else 0.25
        self._timeout_timer = self.create_timer(period, self.timeout_callback)

    def _apply_parameters(self, settings, changed):
        structural = {'variant', 'alpha', 'gain', 'gain_mode', 'kappa', 'kappa_min'}
        if changed & structural:
            # Keep the current estimate: a new gain acts from the next step on.
            observer = _make_observer(settings, initial=self.observer.state)
            observer.measurements_used = self.observer.measurements_used
            self.observer = observer
            self.get_logger().info(
                f'now {settings["variant"]} observer, alpha {settings["alpha"]:g}, '
                f'{settings["gain_mode"]} gain {settings["gain"]}')
        if 'measurement_timeout' in changed:
            self._start_timeout_timer(settings)

    # Diagnostics ----------------------------------------------------------

    def diagnostic_callback(self):
        """Publish the input counters on ``/diagnostics``."""
        new_drops = {reason: self.drops[reason] - self._drops_reported[reason]
                     for reason in self.drops}
        self._drops_reported = dict(self.drops)
        dropping = [reason for reason, count in new_drops.items() if count]
        status = DiagnosticStatus(name=f'{self.get_name()}: inputs',
                                  hardware_id=self.get_fully_qualified_name())
        steps = self.counts['steps_corrected'] + self.counts['steps_propagated']
        if dropping:
            status.level = DiagnosticStatus.WARN
            status.message = 'dropping inputs: ' + ', '.join(
                f'{reason} (+{new_drops[reason]})' for reason in dropping)
        elif steps == 0:
            status.level = DiagnosticStatus.OK
            status.message = 'waiting for inputs'
        else:
            status.level = DiagnosticStatus.OK
            status.message = f'{steps} steps'
        settings = self.parameters.settings
        status.values = key_values(
            [('variant', settings['variant']), ('alpha', settings['alpha']),
             ('gain_mode', settings['gain_mode']), ('steps', steps)]
            + list(self.counts.items())
            + [(f'dropped_{reason}', count) for reason, count in self.drops.items()]
            + [('waiting_increments', len(self._increments)),
               ('waiting_measurements', len(self._measurements)),
               ('estimate_norm', float(norm(np.asarray(self.observer.state))))])
        self.diagnostics_publisher.publish(
            diagnostic_array(self.get_clock().now().to_msg(), [status]))


def main(args=None):
    """Run the ``observer`` node (``ros2 run ext_observer observer_node``)."""
    return run_node(ObserverNode, args)


if __name__ == '__main__':
    import sys
    sys.exit(main())
