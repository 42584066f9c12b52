"""
The ``observer`` node: the core's Luenberger-like observer on ROS topics.

Inputs, step k: ``gyro/increment`` (``Vector3Stamped``, ``θ_k`` in rad) and
``attitude/measurement`` (``QuaternionStamped``, ``y_k``), both stamped
``t_k``. Outputs: ``attitude_estimate`` (``QuaternionStamped``, the ambient
``q̂_{k+1}``, not normalized), ``attitude_estimate/unit`` (the same,
normalized; only while subscribed) and ``imu/data`` (``sensor_msgs/Imu``:
the normalized estimate, ``orientation_covariance``; only while
subscribed), stamped ``t_{k+1}``; ``/diagnostics`` every
``diagnostic_period``; the service ``~/reset`` (``std_srvs/Trigger``).

Real sensors (``increment_source``, ``measurement_source``): the increments
from the angular velocity of ``sensor_msgs/Imu`` on ``imu/data_raw``
(integrated between consecutive samples, :meth:`StepPairer.add_angular_velocity`;
``imu/data`` then passes the sample's angular velocity and acceleration
through), the measurements from the orientation of ``sensor_msgs/Imu`` on
``attitude/imu`` or of ``geometry_msgs/PoseStamped`` on ``attitude/pose``,
at their own rate: a measurement corrects the step whose interval contains
its stamp. Every input but ``gyro/increment`` (``input_reliability``) is
subscribed best effort (the sensor-data QoS at ``queue_depth``), so that
reliable and best-effort publishers both connect, overridable with
``qos_overrides``.

Raw IMU (``measurement_source: accel``, the drop-in for
``imu_filter_madgwick_node``): the raw-IMU estimator of ``core/ahrs.py`` on
``imu/data_raw`` and ``imu/mag`` instead of the paper's observer, with
``use_mag``, ``world_frame`` and the ``ahrs.*`` gains; see
:mod:`ext_observer.raw_imu` and ``docs/raw_imu.md``.

Inputs
    Every input goes through :class:`~ext_observer.pairing.StepPairer`:
    validated (``max_increment``, ``measurement_norm_tolerance``), checked
    for zero, duplicate, stale and jumping stamps, paired by equal stamps
    with a bounded wait (``measurement_timeout``) in bounded buffers
    (``queue_depth``), and counted: received = processed + dropped (by
    reason) + waiting, in ``/diagnostics``.

Faults
    A stamp older than the last step by more than ``backward_jump_threshold``
    (a bag that restarts) restarts the time line and resets the observer; so
    does a backward jump of the node's clock (rclpy's clock jump callback:
    with ``use_sim_time``, ``/clock`` going back) or a switch of its time
    source. A step more than ``forward_gap_threshold`` after the previous one
    resets the observer or just propagates (``forward_gap_action``). After
    every step :class:`~ext_observer.guard.GuardedObserver` checks the
    estimate (``divergence_max_residual``, ``divergence_max_innovation``)
    and reinitializes it from the latest valid measurement when it diverged.
    Nothing non-finite is ever published. Every reset is counted by cause
    and logged (throttled). A silent input (none for ``input_timeout``: a
    stopped driver, a wrong topic, a network partition) is a WARN status
    that names the topic, and is logged when it starts and ends.

``t_{k+1}``
    The increment covers ``[t_k, t_{k+1})`` but carries only ``t_k``. The
    estimate is published at once, stamped ``t_k + Δ`` with ``Δ`` =
    ``step_period`` when set, else the interval between the two last
    processed steps (not across a forward gap); before two steps have been
    seen (and with ``step_period`` = 0), the first estimate is stamped
    ``t_k``.
"""

import math

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import PoseStamped, QuaternionStamped, Vector3Stamped
from rclpy.clock import ClockChange, JumpThreshold
from rclpy.duration import Duration
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.qos_overriding_options import QoSOverridingOptions
from sensor_msgs.msg import Imu, MagneticField
from std_srvs.srv import Trigger

from ext_observer.conversions import (nanoseconds_from_stamp, quaternion_from_msg,
                                      STAMP_MAX, vector_from_msg)
from ext_observer.core import (certified_alpha_max, GAIN_MODES, PAPER_ALPHA, PAPER_GAIN,
                               SingleObserver, VARIANTS)
from ext_observer.guard import GUARD_REASONS, GuardedObserver
from ext_observer.node_common import (CounterDeltas, diagnostic_array, key_values,
                                      NodeParameters, ParameterError, ParameterSpec,
                                      QosWatch, run_node)
from ext_observer.pairing import BACKWARD_JUMP, DROP_REASONS, KINDS, StepPairer
from ext_observer.raw_imu import (imu_vectors, RAW_IMU_PARAMETERS, raw_imu_settings,
                                  RawImuEstimator)

__all__ = ['CERTIFIED_EPSILON', 'DROP_REASONS', 'GUARD_REASONS', 'OBSERVER_PARAMETERS',
           'RESET_CAUSES', 'STATUS_SUFFIX', 'ObserverNode', 'main', 'observer_settings']

# The sublevel V = (q̄q − 1)² ≤ ε of Theorem 1 that certifies `alpha`.
CERTIFIED_EPSILON = 0.5

# Why the observer restarted from its initial estimate.
RESET_CAUSES = ('backward_jump', 'clock_jump', 'forward_gap', 'service')

FORWARD_GAP_ACTIONS = ('propagate', 'reset')
INCREMENT_SOURCES = ('increment', 'imu')
MEASUREMENT_SOURCES = ('quaternion', 'imu', 'pose', 'accel')
# Input topic of each source (relative names); 'accel' takes its
# measurements from the increments' own sensor_msgs/Imu, and the field from
# MAG_TOPIC.
INCREMENT_TOPICS = {'increment': 'gyro/increment', 'imu': 'imu/data_raw'}
MEASUREMENT_TOPICS = {'quaternion': 'attitude/measurement', 'imu': 'attitude/imu',
                      'pose': 'attitude/pose', 'accel': 'imu/data_raw'}
MAG_TOPIC = 'imu/mag'
# gyro/increment keeps input_reliability; every other input is subscribed
# with the sensor-data QoS (qos_profile_sensor_data: best effort, volatile)
# at queue_depth, which takes reliable and best-effort publishers alike,
# overridable by qos_overrides.<topic>.subscription.<policy>.
SENSOR_SOURCES = {'imu', 'pose', 'quaternion', 'accel'}
# The paper's simulated setup (gyro_node): the only one without align_sign
# by default.
PAPER_SOURCES = ('increment', 'quaternion')
RELIABILITIES = {'reliable': ReliabilityPolicy.RELIABLE,
                 'best_effort': ReliabilityPolicy.BEST_EFFORT}

# The status is named '<node name>: inputs'.
STATUS_SUFFIX = ': inputs'

SECOND = 1_000_000_000
# Faults are logged at most this often per kind, s.
LOG_THROTTLE = 5.0

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
                  f' ≈ (0, {certified_alpha_max(CERTIFIED_EPSILON):.4f}) unless '
                  'allow_uncertified_alpha is true.'),
    ParameterSpec('gain', list(PAPER_GAIN),
                  "The paper's gain quaternion L as w, x, y, z (constant mode).",
                  constraints='4 finite numbers.'),
    ParameterSpec('gain_mode', 'constant',
                  "'constant' (L), 'rotating' (κ exp(θ/2)) or 'scheduled' "
                  '(running average, then κ_min exp(θ/2)).',
                  constraints=f'One of {", ".join(GAIN_MODES)}.'),
    ParameterSpec('kappa', 0.05, 'κ of the rotating mode.', (0.0, 1.0),
                  constraints='In (0, 1].'),
    ParameterSpec('kappa_min', 0.02, 'Floor κ_min of the scheduled mode.', (0.0, 1.0),
                  constraints='In (0, 1].'),
    ParameterSpec('align_sign', Parameter.Type.BOOL,
                  'Flip each measurement y to the hemisphere of the estimate (y and −y '
                  'are the same rotation); for sources that publish w ≥ 0 or flip sign. '
                  'Unset: on for every real source; off only for the paper\'s simulated '
                  'setup (increment_source increment with measurement_source quaternion, '
                  'what gyro_node publishes), which keeps the paper\'s exact, unaligned '
                  'update. Not used by measurement_source accel.', example=True),
    ParameterSpec('initial_estimate', [1.0, 0.0, 0.0, 0.0],
                  'Initial estimate q̂_0 as w, x, y, z (ambient, need not be unit); '
                  'also the estimate after a reset.',
                  read_only=True, constraints='4 finite numbers, not all zero, with a '
                  'residual |q̂̄q̂ − 1| at most divergence_max_residual.'),
    ParameterSpec('frame_id', 'world', 'frame_id of the published estimates.'),
    ParameterSpec('measurement_timeout', 0.1,
                  'Longest wait of an increment for its measurement, s; then the step '
                  'propagates without correction.', (0.0, 60.0)),
    ParameterSpec('step_period', 0.0,
                  't_{k+1} − t_k used to stamp the estimate, s; 0 = the interval '
                  'between the two last steps.', (0.0, 3600.0)),
    ParameterSpec('max_increment', 20.0,
                  'Largest accepted increment angle ‖θ_k‖, rad; larger increments are '
                  'dropped (the paper\'s reach ‖θ‖ ≈ 17.3).', (0.0, 1000.0),
                  constraints='Positive.'),
    ParameterSpec('measurement_norm_tolerance', 0.1,
                  'Largest accepted |‖y_k‖ − 1|; within it the measurement is '
                  'normalized, beyond it dropped.', (0.0, 1.0)),
    ParameterSpec('backward_jump_threshold', 1.0,
                  'An input stamp older than the last step by more than this, or a '
                  'backward jump of the node clock by more than this, restarts the '
                  'time line and resets the observer, s; smaller: stale, dropped.',
                  (0.001, 3600.0)),
    ParameterSpec('forward_gap_threshold', 1.0,
                  'A step more than this after the previous one is a forward gap, s.',
                  (0.001, 3600.0)),
    ParameterSpec('forward_gap_action', 'propagate',
                  "At a forward gap: 'propagate' (go on from the current estimate) or "
                  "'reset' (restart from initial_estimate).",
                  constraints=f'One of {", ".join(FORWARD_GAP_ACTIONS)}.'),
    ParameterSpec('divergence_max_residual', 15.0,
                  'Divergence guard: reinitialize from the latest measurement when the '
                  'residual |q̂̄q̂ − 1| exceeds this after a step (the paper\'s setup peaks '
                  'at 7.5).', (0.01, 1000.0)),
    ParameterSpec('divergence_max_innovation', 5.0,
                  'Divergence guard: reinitialize from the latest measurement when the '
                  'innovation ‖y − q̂‖ exceeds this (at most 1 + ‖q̂‖; the paper\'s setup '
                  'peaks at 3.6).', (0.01, 1000.0)),
    ParameterSpec('increment_source', Parameter.Type.STRING,
                  "Where the increments come from: 'increment' (θ_k on gyro/increment, "
                  "geometry_msgs/Vector3Stamped) or 'imu' (sensor_msgs/Imu on "
                  'imu/data_raw: θ_k = ½ (ω_k + ω_{k+1}) Δt between consecutive samples). '
                  "Unset: 'imu' with measurement_source accel, else 'increment'.",
                  read_only=True, constraints=f'One of {", ".join(INCREMENT_SOURCES)}; imu '
                  'with measurement_source accel.', example='imu'),
    ParameterSpec('measurement_source', 'quaternion',
                  "Where the measurements come from: 'quaternion' "
                  '(geometry_msgs/QuaternionStamped on attitude/measurement), '
                  "'imu' (the orientation of sensor_msgs/Imu on attitude/imu), 'pose' "
                  "(the orientation of geometry_msgs/PoseStamped on attitude/pose) or 'accel' "
                  '(raw IMU, the drop-in for imu_filter_madgwick: gyro and accelerometer of '
                  'sensor_msgs/Imu on imu/data_raw, the field of sensor_msgs/MagneticField on '
                  'imu/mag, the ahrs.* estimator of core/ahrs.py; see docs/raw_imu.md).',
                  read_only=True, constraints=f'One of {", ".join(MEASUREMENT_SOURCES)}.'),
    ParameterSpec('max_dt', 0.1,
                  'increment_source imu: largest interval between two IMU samples, s; '
                  'after a longer one the integration starts over from the new sample '
                  '(dropped: dt_too_large).', (0.0001, 10.0)),
    ParameterSpec('constant_dt', 0.0,
                  'increment_source imu: Δt of every increment (measurement_source accel: '
                  'of every sample), s, instead of the interval between the stamps; 0 = from '
                  'the stamps (as imu_filter_madgwick).', (0.0, 10.0)),
    ParameterSpec('orientation_covariance', [0.0025, 0.0, 0.0, 0.0, 0.0025, 0.0,
                                             0.0, 0.0, 0.0025],
                  'orientation_covariance of imu/data, row-major 3×3 about x, y, z, '
                  'rad² (default: 0.05 rad standard deviation per axis).',
                  constraints='9 finite numbers with a positive diagonal.'),
    ParameterSpec('input_reliability', 'reliable',
                  "Reliability of the subscription to gyro/increment: 'reliable' or "
                  "'best_effort' (which also accepts BEST_EFFORT publishers). Every other "
                  'input (attitude/measurement, imu/data_raw, imu/mag, attitude/imu, '
                  'attitude/pose) is subscribed best effort, the sensor-data QoS, so that '
                  'reliable and best-effort publishers both connect; see qos_overrides.',
                  read_only=True, constraints=f'One of {", ".join(RELIABILITIES)}.'),
    ParameterSpec('queue_depth', 100,
                  'History depth of every subscription and publisher (keep last), and '
                  'the most inputs of each kind waiting for their pair.', (1, 10000),
                  read_only=True),
    ParameterSpec('diagnostic_period', 1.0, 'Period of /diagnostics, s.', (0.01, 3600.0),
                  read_only=True),
    ParameterSpec('input_timeout', 2.0,
                  'WARN when no increment has arrived for this long (after the first), '
                  'or no measurement while increments come (not with measurement_source '
                  'accel), s; checked at each status, by the node clock; 0 = never.',
                  (0.0, 3600.0)),
) + RAW_IMU_PARAMETERS


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
    for name, choices in (('forward_gap_action', FORWARD_GAP_ACTIONS),
                          ('input_reliability', tuple(RELIABILITIES)),
                          ('measurement_source', MEASUREMENT_SOURCES)):
        if values[name] not in choices:
            raise ValueError(f'{name} must be one of {choices}, got {values[name]!r}')
    covariance = values['orientation_covariance']
    if len(covariance) != 9 or not all(map(math.isfinite, covariance)):
        raise ValueError('orientation_covariance must be 9 finite numbers, got '
                         f'{covariance}')
    if not min(covariance[0], covariance[4], covariance[8]) > 0.0:
        raise ValueError('orientation_covariance must have a positive diagonal (all '
                         'zeros means "unknown" in sensor_msgs/Imu), got '
                         f'{covariance}')
    values = dict(values)
    if values['increment_source'] is None:
        values['increment_source'] = 'imu' if values['measurement_source'] == 'accel' \
            else 'increment'
    if values['increment_source'] not in INCREMENT_SOURCES:
        raise ValueError(f'increment_source must be one of {INCREMENT_SOURCES}, got '
                         f'{values["increment_source"]!r}')
    if values['measurement_source'] == 'accel':
        if values['increment_source'] != 'imu':
            raise ValueError('measurement_source accel takes the increments from the same '
                             'sensor_msgs/Imu: increment_source must be imu (or unset), got '
                             f'{values["increment_source"]!r}')
        raw_imu_settings(values)
    if values['align_sign'] is None:
        values['align_sign'] = PAPER_SOURCES != (values['increment_source'],
                                                 values['measurement_source'])
    if not values['max_increment'] > 0.0:
        raise ValueError(f'max_increment must be positive, got {values["max_increment"]}')
    try:
        observer = _make_observer(values)
    except ValueError as error:
        raise ValueError(f'the observer refuses these parameters: {error}') from None
    residual = abs(sum(v * v for v in observer.state) - 1.0)
    if residual > values['divergence_max_residual']:
        raise ValueError(
            f'initial_estimate has |q̂̄q̂ − 1| = {residual:.4g}, above '
            f'divergence_max_residual ({values["divergence_max_residual"]:g}): the guard '
            'would reinitialize it at the first step')
    return dict(values)


def _make_observer(settings, initial=None):
    return SingleObserver(
        variant=settings['variant'], alpha=settings['alpha'], gain=settings['gain'],
        initial=settings['initial_estimate'] if initial is None else initial,
        gain_mode=settings['gain_mode'], kappa=settings['kappa'],
        kappa_min=settings['kappa_min'], align_sign=settings['align_sign'])


def _pairing_settings(settings):
    # The raw IMU's steps wait for nothing: the accelerometer comes with the
    # increment, the field is used when it arrives.
    timeout = 0 if settings['measurement_source'] == 'accel' else round(
        settings['measurement_timeout'] * SECOND)
    return dict(timeout=timeout,
                max_increment=settings['max_increment'],
                norm_tolerance=settings['measurement_norm_tolerance'],
                backward_jump=round(settings['backward_jump_threshold'] * SECOND),
                forward_gap=round(settings['forward_gap_threshold'] * SECOND),
                max_dt=round(settings['max_dt'] * SECOND),
                constant_dt=settings['constant_dt'])


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
    guarded : ext_observer.guard.GuardedObserver
        The core's observer with the divergence guard.
    pairer : ext_observer.pairing.StepPairer
        Validation, stamps, pairing and the input counters.
    resets : dict
        Restarts from the initial estimate, by cause (:data:`RESET_CAUSES`).
    reinitializations : dict
        Restarts from the latest measurement by the divergence guard, by
        reason (:data:`~ext_observer.guard.GUARD_REASONS`).

    Raises
    ------
    ParameterError
        If a parameter is refused at start-up.

    """

    NODE_NAME = 'observer'

    def __init__(self, node_name=NODE_NAME, **kwargs):
        super().__init__(node_name, **kwargs)
        self._jump_handle = None
        try:
            self.parameters = NodeParameters(self, OBSERVER_PARAMETERS,
                                             observer_settings, self._apply_parameters)
        except ParameterError:
            self.destroy_node()
            raise
        settings = self.parameters.settings
        depth = settings['queue_depth']
        self.increment_source = settings['increment_source']
        self.measurement_source = settings['measurement_source']
        # One estimator: the paper's observer with its divergence guard, or
        # the raw-IMU estimator (measurement_source accel).
        self.guarded = self.raw = None
        if self.measurement_source == 'accel':
            self.raw = RawImuEstimator(settings)
        else:
            self.guarded = GuardedObserver(_make_observer(settings),
                                           settings['divergence_max_residual'],
                                           settings['divergence_max_innovation'])
        self.pairer = StepPairer(depth=depth, **_pairing_settings(settings))
        self.resets = dict.fromkeys(RESET_CAUSES, 0)
        self.reinitializations = dict.fromkeys(GUARD_REASONS, 0)
        self._deltas = CounterDeltas()
        self._status_steps = self._status_fields = 0
        # Per kind: (inputs received, node clock at the first status that
        # saw that count). Nothing came since then, so the input has been
        # silent for at least now minus that time.
        self._heard = dict.fromkeys(KINDS, (0, self.get_clock().now().nanoseconds))
        self._quiet = set()     # the kinds reported silent at the last status
        self._last_interval = None
        self.qos = QosWatch(self)
        output_qos = QoSProfile(depth=depth)
        input_qos = QoSProfile(depth=depth,
                               reliability=RELIABILITIES[settings['input_reliability']])
        hint = ("set this node's input_reliability to best_effort"
                if settings['input_reliability'] == 'reliable' else '')
        self.estimate_publisher = self.create_publisher(
            QuaternionStamped, 'attitude_estimate', output_qos,
            event_callbacks=self.qos.publisher('attitude_estimate', output_qos))
        self.unit_publisher = self.create_publisher(
            QuaternionStamped, 'attitude_estimate/unit', output_qos,
            event_callbacks=self.qos.publisher('attitude_estimate/unit', output_qos,
                                               matched=self.unit_matched_callback))
        diagnostics_qos = QoSProfile(depth=10)
        self.diagnostics_publisher = self.create_publisher(
            DiagnosticArray, '/diagnostics', diagnostics_qos,
            event_callbacks=self.qos.publisher('/diagnostics', diagnostics_qos))
        self.imu_publisher = self.create_publisher(
            Imu, 'imu/data', output_qos,
            event_callbacks=self.qos.publisher('imu/data', output_qos,
                                               matched=self.imu_matched_callback))
        # Every source is subscribed through one place: gyro/increment with
        # input_reliability, the others best effort (overridable).
        increment_type, increment_callback = {
            'increment': (Vector3Stamped, self.increment_callback),
            'imu': (Imu, self.imu_data_raw_callback)}[self.increment_source]
        self.increment_subscription = self._subscribe(
            increment_type, INCREMENT_TOPICS[self.increment_source], increment_callback,
            self.increment_source in SENSOR_SOURCES, input_qos, hint)
        if self.raw is None:
            measurement_type, measurement_topic, measurement_callback = (
                {'quaternion': QuaternionStamped, 'imu': Imu,
                 'pose': PoseStamped}[self.measurement_source],
                MEASUREMENT_TOPICS[self.measurement_source],
                {'quaternion': self.measurement_callback,
                 'imu': self.attitude_imu_callback,
                 'pose': self.attitude_pose_callback}[self.measurement_source])
        elif settings['use_mag']:
            # The accelerometer comes with the increments; the field on its own.
            measurement_type, measurement_topic, measurement_callback = (
                MagneticField, MAG_TOPIC, self.imu_mag_callback)
        else:
            measurement_type = None
        self.measurement_subscription = None if measurement_type is None else \
            self._subscribe(measurement_type, measurement_topic, measurement_callback,
                            True, input_qos, hint)
        self.reset_service = self.create_service(Trigger, '~/reset', self.reset_callback)
        # The per-step path reads no parameter and builds no message: the
        # settings it needs are cached (_cache_settings), the outputs are
        # built once and their fields set in place before each publish.
        self._clock = self.get_clock()
        self._now = self._clock.now().nanoseconds
        self._estimate_msg = QuaternionStamped()
        self._stamp = Time()  # of a step with no sample of its own
        self._unit_msg = QuaternionStamped()
        # imu/data of a step without an IMU sample at hand (the increments
        # come from gyro/increment, or the sample was pushed out of the
        # queue): its rates are not known, -1 in the first element of their
        # covariances (sensor_msgs/Imu).
        self._imu_msg = Imu()
        self._imu_msg.angular_velocity_covariance[0] = -1.0
        self._imu_msg.linear_acceleration_covariance[0] = -1.0
        # IMU samples by stamp, (message, ω, None), until the step their
        # stamp ends is published (the message goes out on imu/data with the
        # estimate). The raw IMU keeps none: its steps run at once.
        self._imu_samples = {}
        self._body_frame_id = ''
        self._cache_settings(settings)
        self._publish_unit = self.unit_publisher.get_subscription_count() > 0
        self._publish_imu = self.imu_publisher.get_subscription_count() > 0
        self._watch_clock(settings)
        self._timeout_timer = None
        self._start_timeout_timer(settings)
        self.diagnostic_timer = self.create_timer(
            settings['diagnostic_period'], self.diagnostic_callback)
        if self.raw is not None:
            self.get_logger().info(
                f'raw IMU on {self.resolve_topic_name(INCREMENT_TOPICS["imu"])}'
                + (f' and {self.resolve_topic_name(MAG_TOPIC)}' if settings['use_mag']
                   else ' (use_mag false: heading free)')
                + f', world frame {settings["world_frame"]}, {self.raw.core.params}')
        else:
            self.get_logger().info(
                f'{settings["variant"]} observer, alpha {settings["alpha"]:g}, '
                f'{settings["gain_mode"]} gain {self._gain_text(settings)}')

    @property
    def observer(self):
        """
        The core's estimator.

        :class:`~ext_observer.core.SingleObserver`, or with ``measurement_source
        accel`` :class:`~ext_observer.core.ahrs.AhrsObserver`.
        """
        return self.guarded.observer if self.raw is None else self.raw.core

    @property
    def state(self):
        """The current estimate (ambient, w, x, y, z; None before the raw IMU's first step)."""
        return self.guarded.state if self.raw is None else self.raw.state

    @property
    def drops(self):
        """Inputs dropped, by reason (:data:`DROP_REASONS`)."""
        return self.pairer.drops

    @property
    def counts(self):
        """
        The inputs and what came of them.

        ``increments``, ``measurements`` received; ``steps_corrected``,
        ``steps_propagated``. Raw IMU: ``imu_samples`` and ``fields``
        received, ``fields_used``.
        """
        received, processed = self.pairer.received, self.pairer.processed
        if self.raw is not None:
            return {'imu_samples': received['increment'], 'fields': received['measurement'],
                    'fields_used': processed['measurement']}
        return {'increments': received['increment'],
                'measurements': received['measurement'],
                'steps_corrected': processed['measurement'],
                'steps_propagated': processed['increment'] - processed['measurement']}

    @staticmethod
    def _gain_text(settings):
        mode = settings['gain_mode']
        if mode == 'constant':
            return f'L = {settings["gain"]}'
        if mode == 'rotating':
            return f'kappa {settings["kappa"]:g}'
        return f'kappa_min {settings["kappa_min"]:g}'

    def destroy_node(self):
        """Unregister the clock jump callback, then destroy the node."""
        if getattr(self, '_jump_handle', None) is not None:
            self._jump_handle.unregister()
            self._jump_handle = None
        super().destroy_node()

    # Inputs ---------------------------------------------------------------

    def _subscribe(self, msg_type, topic, callback, sensor, input_qos, hint):
        if not sensor:
            return self.create_subscription(
                msg_type, topic, callback, input_qos,
                event_callbacks=self.qos.subscription(topic, input_qos, hint))
        qos = QoSProfile(depth=self.parameters.settings['queue_depth'],
                         history=HistoryPolicy.KEEP_LAST,
                         reliability=ReliabilityPolicy.BEST_EFFORT,
                         durability=DurabilityPolicy.VOLATILE)
        name = self.resolve_topic_name(topic)
        return self.create_subscription(
            msg_type, topic, callback, qos,
            qos_overriding_options=QoSOverridingOptions.with_default_policies(),
            event_callbacks=self.qos.subscription(
                topic, qos, f'set qos_overrides.{name}.subscription.reliability to '
                'best_effort'))

    def increment_callback(self, msg):
        """Take ``θ_k`` and process every step that is ready."""
        # The clock is read once per step, here: the increment's deadline
        # needs it. A measurement releases steps by stamps, not by time, so
        # its callback uses this reading; the timeout timer reads the clock
        # again for the deadlines.
        now = self._now = self._clock.now().nanoseconds
        stamp = nanoseconds_from_stamp(msg.header.stamp)
        self._body_frame_id = msg.header.frame_id
        if self.pairer.add_increment(stamp, vector_from_msg(msg.vector), now) == BACKWARD_JUMP:
            self._backward_jump(stamp)
        self._process(now)

    def imu_data_raw_callback(self, msg):
        """Take an IMU sample ``ω`` (rad/s); its successor makes the increment."""
        stamp = nanoseconds_from_stamp(msg.header.stamp)
        pairer = self.pairer
        if self.raw is not None:
            # Raw IMU: the acceleration is checked with the sample. Its steps
            # wait for nothing (timeout 0, no deadline, so the clock is not
            # read): the step this sample closes is released at once and runs
            # on it.
            omega, acceleration = imu_vectors(msg)
            if pairer.add_angular_velocity(stamp, omega, 0, acceleration) == BACKWARD_JUMP:
                self._backward_jump(stamp)
            for step in pairer.pop_ready(0):
                self._step(step, (msg, omega, acceleration) if step.end == stamp else None)
            return
        now = self._now = self._clock.now().nanoseconds
        self._body_frame_id = msg.header.frame_id
        omega = vector_from_msg(msg.angular_velocity)
        if pairer.add_angular_velocity(stamp, omega, now) == BACKWARD_JUMP:
            self._imu_samples.clear()
            self._backward_jump(stamp)
        if pairer.pending_stamp == stamp:
            # Taken (a dropped sample is never kept, nor replaces one).
            samples = self._imu_samples
            samples[stamp] = (msg, omega, None)
            if len(samples) > 2 * self._depth + 2:
                del samples[next(iter(samples))]
        self._process(now)

    def imu_mag_callback(self, msg):
        """Raw IMU: take a magnetic field (T) and correct the heading with it at once."""
        field = self.raw.field_from_msg(msg)
        stamp = nanoseconds_from_stamp(msg.header.stamp)
        previous = self.pairer.field_stamp
        if self.pairer.add_field(stamp, field) is None:
            # The first field of a time line (or after a jump back) has no interval.
            self.raw.field(field, None if previous is None or stamp <= previous
                           else (stamp - previous) * 1e-9)

    def attitude_imu_callback(self, msg):
        """Take ``y`` from the orientation of a ``sensor_msgs/Imu``."""
        if msg.orientation_covariance[0] == -1.0:
            # The driver says it has no orientation (sensor_msgs/Imu).
            self.pairer.reject('measurement', 'no_orientation')
            return
        self._measurement(msg.header.stamp, msg.orientation)

    def attitude_pose_callback(self, msg):
        """Take ``y`` from the orientation of a ``geometry_msgs/PoseStamped``."""
        self._measurement(msg.header.stamp, msg.pose.orientation)

    def measurement_callback(self, msg):
        """Take ``y_k`` and process every step that is ready."""
        self._measurement(msg.header.stamp, msg.quaternion)

    def _measurement(self, header_stamp, quaternion):
        stamp = nanoseconds_from_stamp(header_stamp)
        if self.pairer.add_measurement(stamp, quaternion_from_msg(quaternion)) \
                == BACKWARD_JUMP:
            self._imu_samples.clear()
            self._backward_jump(stamp)
        self._process(self._now)

    def timeout_callback(self):
        """Propagate the steps whose measurement did not come in time."""
        now = self._now = self._clock.now().nanoseconds
        # attitude_estimate/unit goes out only while someone subscribes to
        # it: the matched event says so at once, this timer keeps it right.
        self._publish_unit = self.unit_publisher.get_subscription_count() > 0
        self._publish_imu = self.imu_publisher.get_subscription_count() > 0
        self._process(now)

    def unit_matched_callback(self, info):
        """A subscription to ``attitude_estimate/unit`` came or went."""
        self._publish_unit = info.current_count > 0

    def imu_matched_callback(self, info):
        """A subscription to ``imu/data`` came or went."""
        self._publish_imu = info.current_count > 0

    def _backward_jump(self, stamp):
        self._reset_observer('backward_jump')
        self.get_logger().warning(
            f'input stamp {stamp * 1e-9:.9f} s is more than '
            f'{self.parameters.settings["backward_jump_threshold"]:g} s older than the last '
            'step: the time line restarted (a bag that loops?); observer reset',
            throttle_duration_sec=LOG_THROTTLE)

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
        self._imu_samples.clear()
        self._reset_observer('clock_jump')
        self.get_logger().warning(
            f'{what}: observer reset, {discarded} waiting inputs discarded',
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
        """Service ``~/reset``: restart the observer from its initial estimate."""
        self._reset_observer('service')
        response.success = True
        response.message = (
            f'observer reset to the initial estimate {list(self.guarded.state)}'
            if self.raw is None else
            'raw-IMU estimator reset: the next sample initializes it from gravity')
        self.get_logger().info(response.message)
        return response

    def _reset_observer(self, cause):
        (self.guarded or self.raw).reset()
        self.resets[cause] += 1

    # Steps ----------------------------------------------------------------

    def _process(self, now):
        for step in self.pairer.pop_ready(now):
            self._step(step)

    def _step(self, step, taken=None):
        """Run one released step; ``taken``: the IMU sample that closed it, if known."""
        if step.gap:
            settings = self.parameters.settings
            gap = (step.stamp - step.previous) * 1e-9
            if settings['forward_gap_action'] == 'reset':
                self._reset_observer('forward_gap')
            self.get_logger().warning(
                f'{gap:.3f} s since the previous step: '
                + ('observer reset' if settings['forward_gap_action'] == 'reset'
                   else 'propagating'), throttle_duration_sec=LOG_THROTTLE)
        elif step.previous is not None:
            self._last_interval = step.stamp - step.previous
        # The sample stamped t_{k+1} closed the step: it goes out with q̂_{k+1}
        # (the raw IMU: the step runs on it).
        if taken is None and step.end is not None and self.raw is None:
            taken = self._take_imu_sample(step.end)
        sample = None if taken is None else taken[0]
        if self.raw is None:
            state, reason = self.guarded.step(step.increment, step.measurement)
        elif sample is None:
            # Cannot happen: a raw step is released by the sample that closes it.
            return
        else:
            state, reason = self.raw.step(
                taken[1], taken[2], self._constant_dt or (step.end - step.stamp) * 1e-9)
        if reason is not None:
            self.reinitializations[reason] += 1
            self.get_logger().warning(
                f'divergence guard ({reason}) at stamp {step.stamp} ns: observer '
                'reinitialized from ' + ('the latest measurement' if self.raw is None
                                         else 'the sample'),
                throttle_duration_sec=LOG_THROTTLE)
        if step.early:
            self.get_logger().warning(
                f'{self.parameters.settings["queue_depth"]} increments waiting: stepping '
                'without waiting for measurements', throttle_duration_sec=LOG_THROTTLE)
        msg = self._estimate_msg
        if sample is not None:
            # Stamped t_{k+1}, the sample's own stamp.
            stamp = msg.header.stamp = sample.header.stamp
        else:
            end = step.end
            if end is None:
                end = min(step.stamp + (self._period or self._last_interval or 0), STAMP_MAX)
            stamp = self._stamp
            stamp.sec, stamp.nanosec = divmod(end, SECOND)
            msg.header.stamp = stamp
        w, x, y, z = state
        q = msg.quaternion
        q.w, q.x, q.y, q.z = w, x, y, z
        self.estimate_publisher.publish(msg)
        if self._publish_unit or self._publish_imu:
            n = math.sqrt(w * w + x * x + y * y + z * z)
            w, x, y, z = w / n, x / n, y / n, z / n
        if self._publish_unit:
            msg = self._unit_msg
            msg.header.stamp = stamp
            q = msg.quaternion
            q.w, q.x, q.y, q.z = w, x, y, z
            self.unit_publisher.publish(msg)
        if self._publish_imu:
            if sample is not None:
                # The sample itself goes out, its header, rates and
                # covariances passed through (as imu_filter_madgwick does):
                # the message is this node's once its callback has run.
                msg = sample
                msg.orientation_covariance = self._orientation_covariance
            else:
                msg = self._imu_msg
                msg.header.stamp = stamp
                msg.header.frame_id = self._body_frame_id
            q = msg.orientation
            q.w, q.x, q.y, q.z = w, x, y, z
            self.imu_publisher.publish(msg)

    def _take_imu_sample(self, stamp):
        """Remove and return the kept sample stamped ``stamp`` (and older ones), or None."""
        samples = self._imu_samples
        while samples:
            first = next(iter(samples))
            if first > stamp:
                return None
            sample = samples.pop(first)
            if first == stamp:
                return sample
        return None

    def _cache_settings(self, settings):
        # step_period in ns (0: the interval between the two last steps).
        self._period = round(settings['step_period'] * SECOND)
        self._depth = settings['queue_depth']
        self._constant_dt = settings['constant_dt']
        self._imu_msg.orientation_covariance = [
            float(v) for v in settings['orientation_covariance']]
        # The same (numpy) array goes into every sample passed through.
        self._orientation_covariance = self._imu_msg.orientation_covariance
        self._estimate_msg.header.frame_id = settings['frame_id']
        self._unit_msg.header.frame_id = settings['frame_id']

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
        structural = {'variant', 'alpha', 'gain', 'gain_mode', 'kappa', 'kappa_min',
                      'align_sign'}
        if self.raw is not None:
            self.raw.configure(settings)
        elif changed & structural:
            # Keep the current estimate: a new gain acts from the next step on.
            observer = _make_observer(settings, initial=self.observer.state)
            observer.measurements_used = self.observer.measurements_used
            self.guarded.observer = observer
            self.get_logger().info(
                f'now {settings["variant"]} observer, alpha {settings["alpha"]:g}, '
                f'{settings["gain_mode"]} gain {self._gain_text(settings)}')
        self._cache_settings(settings)
        if self.guarded is not None:
            self.guarded.max_residual = settings['divergence_max_residual']
            self.guarded.max_innovation = settings['divergence_max_innovation']
        self.pairer.configure(**_pairing_settings(settings))
        if 'measurement_timeout' in changed:
            self._start_timeout_timer(settings)
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
        status, or an incompatible QoS peer present now; OK otherwise.

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
        fields = pairer.processed['measurement']
        if (self.raw is not None and self.measurement_subscription is not None
                and steps > self._status_steps and fields == self._status_fields):
            parts.append(f'no magnetic field on {self.measurement_subscription.topic_name} '
                         'since the last status: heading not corrected')
        self._status_steps, self._status_fields = steps, fields
        silent = self._silence()
        timeout = self.parameters.settings['input_timeout']
        quiet = {}
        if timeout > 0 and pairer.received['increment'] > 0:
            if silent['increment'] >= timeout:
                quiet['increment'] = (f'no increments on '
                                      f'{self.increment_subscription.topic_name} for '
                                      f'{silent["increment"]:.3g} s or more')
            elif self.raw is None and silent['measurement'] >= timeout:
                quiet['measurement'] = (f'no measurements on '
                                        f'{self.measurement_subscription.topic_name} for '
                                        f'{silent["measurement"]:.3g} s or more: steps '
                                        'propagate')
        logger = self.get_logger()
        for kind in quiet.keys() - self._quiet:
            logger.warning(quiet[kind])
        for kind in self._quiet - quiet.keys():
            logger.info(f'{kind}s arriving again')
        self._quiet = set(quiet)
        parts.extend(quiet.values())
        if parts:
            status.level = DiagnosticStatus.WARN
            status.message = '; '.join(parts)
        else:
            status.level = DiagnosticStatus.OK
            status.message = f'{steps} steps' if steps else 'waiting for inputs'
        settings = self.parameters.settings
        received = sum(pairer.received.values())
        processed = sum(pairer.processed.values())
        dropped = sum(pairer.dropped(kind) for kind in KINDS)
        waiting = sum(pairer.waiting(kind) for kind in KINDS)
        state = self.state
        estimator = (self.raw.key_values() if self.raw is not None else
                     [('variant', settings['variant']), ('alpha', settings['alpha']),
                      ('gain_mode', settings['gain_mode']),
                      ('align_sign', settings['align_sign'])])
        status.values = key_values(
            estimator
            + [('increment_source', self.increment_source),
               ('measurement_source', self.measurement_source), ('steps', steps)]
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
        self.diagnostics_publisher.publish(
            diagnostic_array(self.get_clock().now().to_msg(), [self.status()]))


def main(args=None):
    """Run the ``observer`` node (``ros2 run ext_observer observer_node``)."""
    return run_node(ObserverNode, args)


if __name__ == '__main__':
    import sys
    sys.exit(main())
