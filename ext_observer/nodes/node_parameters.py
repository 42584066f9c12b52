"""
The paper's nodes' parameters (``observer_node``, ``gyro_node``, ``monitor_node``), their checks.

Each node's rows are listed once (:data:`OBSERVER_PARAMETERS`,
:data:`GYRO_PARAMETERS`, :data:`MONITOR_PARAMETERS`: the descriptors, the
tables of ``docs/parameters.md`` and ``config/ext_observer.yaml`` come from
them); its ``*_settings`` function checks a set of values together, building
the core's object from them so that the core's own checks apply.
``imu_filter_node``'s rows are plain data in
:mod:`ext_observer.pipeline.imu_filter_parameters` (the offline tools read them).
"""

import math

from rclpy.qos import ReliabilityPolicy

from ext_observer.core import (certified_alpha_max, GAIN_MODES, PAPER_ALPHA, PAPER_GAIN,
                               SimulatedGyro, SingleObserver, VARIANTS)
from ext_observer.nodes.estimator_node_base import SECOND
from ext_observer.pipeline.parameter_specs import (COMMON_PARAMETERS, common_settings,
                                                   ParameterSpec)

__all__ = ['ALIGN_SIGN_AUTO', 'CERTIFIED_EPSILON', 'GYRO_PARAMETERS', 'INCREMENT_SOURCES',
           'INCREMENT_TOPICS', 'MEASUREMENT_SOURCES', 'MEASUREMENT_TOPICS', 'MONITOR_PARAMETERS',
           'OBSERVER_PARAMETERS', 'RELIABILITIES', 'gyro_settings', 'make_gyro', 'make_observer',
           'monitor_settings', 'observer_settings', 'pairing_settings']

# The sublevel V = (q̄q − 1)² ≤ ε of Theorem 1 that certifies `alpha`.
CERTIFIED_EPSILON = 0.5

INCREMENT_SOURCES = ('increment', 'imu')
MEASUREMENT_SOURCES = ('quaternion', 'imu', 'pose')
# Input topic of each source (relative names).
INCREMENT_TOPICS = {'increment': 'gyro/increment', 'imu': 'imu/data_raw'}
MEASUREMENT_TOPICS = {'quaternion': 'attitude/measurement', 'imu': 'attitude/imu',
                      'pose': 'attitude/pose'}
# The paper's simulated setup (gyro_node): the only one where align_sign
# 'auto' means off.
PAPER_SOURCES = ('increment', 'quaternion')
RELIABILITIES = {'reliable': ReliabilityPolicy.RELIABLE,
                 'best_effort': ReliabilityPolicy.BEST_EFFORT}
ALIGN_SIGN_AUTO = 'auto'

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
    ParameterSpec('align_sign', ALIGN_SIGN_AUTO,
                  'Flip each measurement y to the hemisphere of the estimate (y and −y '
                  'are the same rotation); for sources that publish w ≥ 0 or flip sign. '
                  "'auto': on for every real source; off only for the paper's simulated "
                  'setup (increment_source increment with measurement_source quaternion, '
                  "what gyro_node publishes), which keeps the paper's exact, unaligned "
                  'update.', dynamic=True, constraints="true, false or 'auto'."),
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
) + COMMON_PARAMETERS + (
    ParameterSpec('divergence_max_residual', 15.0,
                  'Divergence guard: reinitialize from the latest measurement when the '
                  'residual |q̂̄q̂ − 1| exceeds this after a step (the paper\'s setup peaks '
                  'at 7.5).', (0.01, 1000.0)),
    ParameterSpec('divergence_max_innovation', 5.0,
                  'Divergence guard: reinitialize from the latest measurement when the '
                  'innovation ‖y − q̂‖ exceeds this (at most 1 + ‖q̂‖; the paper\'s setup '
                  'peaks at 3.6).', (0.01, 1000.0)),
    ParameterSpec('increment_source', 'increment',
                  "Where the increments come from: 'increment' (θ_k on gyro/increment, "
                  "geometry_msgs/Vector3Stamped) or 'imu' (sensor_msgs/Imu on "
                  'imu/data_raw: θ_k = ½ (ω_k + ω_{k+1}) Δt between consecutive samples).',
                  read_only=True, constraints=f'One of {", ".join(INCREMENT_SOURCES)}.'),
    ParameterSpec('measurement_source', 'quaternion',
                  "Where the measurements come from: 'quaternion' "
                  '(geometry_msgs/QuaternionStamped on attitude/measurement), '
                  "'imu' (the orientation of sensor_msgs/Imu on attitude/imu) or 'pose' "
                  '(the orientation of geometry_msgs/PoseStamped on attitude/pose). For a '
                  'raw IMU (gyro, accelerometer, magnetometer) run imu_filter_node.',
                  read_only=True, constraints=f'One of {", ".join(MEASUREMENT_SOURCES)}.'),
    ParameterSpec('max_dt', 0.1,
                  'increment_source imu: largest interval between two IMU samples, s; '
                  'after a longer one the integration starts over from the new sample '
                  '(dropped: dt_too_large).', (0.0001, 10.0)),
    ParameterSpec('constant_dt', 0.0,
                  'increment_source imu: Δt of every increment, s, instead of the '
                  'interval between the stamps; 0 = from the stamps.', (0.0, 10.0)),
    ParameterSpec('orientation_covariance', [0.0025, 0.0, 0.0, 0.0, 0.0025, 0.0,
                                             0.0, 0.0, 0.0025],
                  'orientation_covariance of imu/data, row-major 3×3 about x, y, z, '
                  'rad² (default: 0.05 rad standard deviation per axis).',
                  constraints='9 finite numbers with a positive diagonal.'),
    ParameterSpec('input_reliability', 'reliable',
                  "Reliability of the subscription to gyro/increment: 'reliable' or "
                  "'best_effort' (which also accepts BEST_EFFORT publishers). Every other "
                  'input (attitude/measurement, imu/data_raw, attitude/imu, '
                  'attitude/pose) is subscribed best effort, the sensor-data QoS, so that '
                  'reliable and best-effort publishers both connect; see qos_overrides.',
                  read_only=True, constraints=f'One of {", ".join(RELIABILITIES)}.'),
    ParameterSpec('input_timeout', 2.0,
                  'WARN when no increment has arrived for this long (after the first), '
                  'or no measurement while increments come, s; checked at each status, '
                  'by the node clock; 0 = never.', (0.0, 3600.0)),
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
        ``values``, checked; ``align_sign`` resolved to a bool.

    Raises
    ------
    ValueError
        With the reason.

    """
    common_settings(values)
    alpha = values['alpha']
    if not values['allow_uncertified_alpha']:
        alpha_max = certified_alpha_max(CERTIFIED_EPSILON)
        if not 0.0 < alpha < alpha_max:
            raise ValueError(
                f'alpha = {alpha:g} is outside the range certified by Theorem 1, '
                f'(0, {alpha_max:.4g}) for epsilon = {CERTIFIED_EPSILON}; set '
                'allow_uncertified_alpha to true to use it anyway')
    for name, choices in (('input_reliability', tuple(RELIABILITIES)),
                          ('increment_source', INCREMENT_SOURCES),
                          ('measurement_source', MEASUREMENT_SOURCES)):
        if values[name] not in choices:
            hint = ('; for a raw IMU (measurement_source accel before) run imu_filter_node'
                    if values[name] == 'accel' else '')
            raise ValueError(f'{name} must be one of {choices}, got {values[name]!r}{hint}')
    covariance = values['orientation_covariance']
    if len(covariance) != 9 or not all(map(math.isfinite, covariance)):
        raise ValueError('orientation_covariance must be 9 finite numbers, got '
                         f'{covariance}')
    if not min(covariance[0], covariance[4], covariance[8]) > 0.0:
        raise ValueError('orientation_covariance must have a positive diagonal (all '
                         'zeros means "unknown" in sensor_msgs/Imu), got '
                         f'{covariance}')
    values = dict(values)
    align = values['align_sign']
    if align == ALIGN_SIGN_AUTO:
        values['align_sign'] = PAPER_SOURCES != (values['increment_source'],
                                                 values['measurement_source'])
    elif not isinstance(align, bool):
        raise ValueError(f"align_sign must be true, false or 'auto', got {align!r}")
    if not values['max_increment'] > 0.0:
        raise ValueError(f'max_increment must be positive, got {values["max_increment"]}')
    try:
        observer = make_observer(values)
    except ValueError as error:
        raise ValueError(f'the observer refuses these parameters: {error}') from None
    residual = abs(sum(v * v for v in observer.state) - 1.0)
    if residual > values['divergence_max_residual']:
        raise ValueError(
            f'initial_estimate has |q̂̄q̂ − 1| = {residual:.4g}, above '
            f'divergence_max_residual ({values["divergence_max_residual"]:g}): the guard '
            'would reinitialize it at the first step')
    return values


def make_observer(settings, initial=None):
    return SingleObserver(
        variant=settings['variant'], alpha=settings['alpha'], gain=settings['gain'],
        initial=settings['initial_estimate'] if initial is None else initial,
        gain_mode=settings['gain_mode'], kappa=settings['kappa'],
        kappa_min=settings['kappa_min'], align_sign=settings['align_sign'])


def pairing_settings(settings):
    return dict(timeout=round(settings['measurement_timeout'] * SECOND),
                max_increment=settings['max_increment'],
                norm_tolerance=settings['measurement_norm_tolerance'],
                backward_jump=round(settings['backward_jump_threshold'] * SECOND),
                forward_gap=round(settings['forward_gap_threshold'] * SECOND),
                max_dt=round(settings['max_dt'] * SECOND),
                constant_dt=settings['constant_dt'])


# --- gyro_node: the paper's simulated gyro and attitude sensor ---------------------

INT32_MAX = 2 ** 31 - 1

GYRO_PARAMETERS = (
    ParameterSpec('rate_hz', 20.0, 'Steps per second, Hz.', (0.1, 10000.0)),
    ParameterSpec('increment_max', 10.0,
                  'Upper bound of the uniform increment θ_k per axis, rad per step '
                  '(the paper: 10).', (0.0, 100.0), read_only=True),
    ParameterSpec('measurement_noise_std', 0.1,
                  'σ of the measurement noise ν_k, rad (the paper: 0.1).',
                  (0.0, 10.0), read_only=True),
    ParameterSpec('gyro_noise_std', 0.0,
                  'σ_g of the noise added to each reported increment, rad per step per '
                  'axis (0: exact increments, the paper).', (0.0, 10.0), read_only=True),
    ParameterSpec('gyro_bias', [0.0, 0.0, 0.0],
                  'Initial bias of the reported increment as x, y, z, rad per step.',
                  read_only=True, constraints='3 finite numbers.'),
    ParameterSpec('bias_walk_std', 0.0,
                  'Random-walk step of the bias, rad per step per step (0: constant '
                  'bias).', (0.0, 10.0), read_only=True),
    ParameterSpec('seed', -1, 'Seed of the random stream; -1 = fresh from the OS.',
                  (-1, INT32_MAX), read_only=True),
    ParameterSpec('initial_attitude', [0.0, 0.0, 0.0, 0.0],
                  'True attitude q_0 as w, x, y, z (normalized); all zeros = uniform '
                  'random on S³.', read_only=True,
                  constraints='4 finite numbers.'),
    ParameterSpec('steps', 0, 'Steps to publish, then stop publishing; 0 = no end.',
                  (0, INT32_MAX), read_only=True),
    ParameterSpec('wait_for_subscribers', 0,
                  'Publish nothing until gyro/increment and attitude/measurement each '
                  'have this many subscribers (so that no step is published before '
                  'discovery has matched them); 0 = start at once.', (0, 1000),
                  read_only=True),
    ParameterSpec('frame_id', 'world',
                  'frame_id of the attitude messages (the reference frame).'),
    ParameterSpec('body_frame_id', 'base_link',
                  'frame_id of the increment (a rotation of the body frame).'),
    ParameterSpec('queue_depth', 100, 'History depth of the publishers (reliable, '
                  'keep last).', (1, 10000), read_only=True),
    ParameterSpec('diagnostic_period', 1.0, 'Period of /diagnostics, s.', (0.01, 3600.0),
                  read_only=True),
)


def gyro_settings(values):
    """
    Validate the gyro's parameters.

    Parameters
    ----------
    values : dict
        Every parameter of :data:`GYRO_PARAMETERS` by name.

    Returns
    -------
    settings : dict
        ``values`` with ``initial_attitude`` as ``None`` (random) or 4 floats.

    Raises
    ------
    ValueError
        With the reason.

    """
    settings = dict(values)
    initial = values['initial_attitude']
    if len(initial) != 4:
        raise ValueError('initial_attitude must have 4 elements (w, x, y, z; all zeros: '
                         f'random), got {len(initial)}')
    if not any(initial):
        settings['initial_attitude'] = None
    if len(values['gyro_bias']) != 3:
        raise ValueError('gyro_bias must have 3 elements (x, y, z), '
                         f'got {len(values["gyro_bias"])}')
    if not values['rate_hz'] > 0.0:
        raise ValueError(f'rate_hz must be positive, got {values["rate_hz"]}')
    # The core's constructor is the reference for what it accepts.
    try:
        make_gyro(settings)
    except ValueError as error:
        raise ValueError(f'the simulated gyro refuses these parameters: {error}') from None
    return settings


def make_gyro(settings):
    """The core's simulated gyro of validated ``settings`` (:func:`gyro_settings`)."""
    seed = settings['seed']
    return SimulatedGyro(increment_max=settings['increment_max'],
                         noise_std=settings['measurement_noise_std'],
                         seed=None if seed < 0 else seed,
                         initial_attitude=settings['initial_attitude'],
                         gyro_noise_std=settings['gyro_noise_std'],
                         gyro_bias=settings['gyro_bias'],
                         bias_walk_std=settings['bias_walk_std'])


# --- monitor_node: the estimate against the ground truth ---------------------------

MONITOR_PARAMETERS = (
    ParameterSpec('diagnostic_period', 1.0, 'Period of /diagnostics, s.',
                  (0.01, 3600.0), read_only=True),
    ParameterSpec('stale_timeout', 2.0,
                  'STALE when no estimate arrived for this long, s.', (0.0, 3600.0)),
    ParameterSpec('warn_distance', 0.15,
                  'WARN when the mean distance |‖q̂‖ − 1| over the window exceeds this.',
                  (0.0, 100.0)),
    ParameterSpec('error_distance', 0.3,
                  'ERROR when the mean distance over the window exceeds this (0.307: '
                  '‖q̂‖² = 1 + √0.5, the outer edge of the certified set V ≤ 0.5).',
                  (0.0, 100.0), constraints='Not below warn_distance.'),
    ParameterSpec('window', 50, 'Estimates in the running statistics and the level.',
                  (1, 1000000), read_only=True),
    ParameterSpec('stamp_tolerance', 0.001,
                  'Largest stamp difference between an estimate and the ground truth '
                  'paired with it, s.', (0.0, 10.0)),
    ParameterSpec('hardware_id', '', "hardware_id of the status; '' = the node's full "
                  "name (/monitor), as the other nodes' statuses."),
    ParameterSpec('queue_depth', 100, 'History depth of the subscriptions and the '
                  'publisher (reliable, keep last).', (1, 10000), read_only=True),
    ParameterSpec('clock_jump_threshold', 1.0,
                  'A backward jump of the node clock by more than this clears the '
                  'statistics, s.', (0.001, 3600.0), read_only=True),
)


def monitor_settings(values):
    """
    Validate the monitor's parameters.

    Parameters
    ----------
    values : dict
        Every parameter of :data:`MONITOR_PARAMETERS` by name.

    Returns
    -------
    settings : dict

    Raises
    ------
    ValueError
        With the reason.

    """
    if values['error_distance'] < values['warn_distance']:
        raise ValueError(f'error_distance ({values["error_distance"]:g}) must not be '
                         f'below warn_distance ({values["warn_distance"]:g})')
    return dict(values)
