"""
The parameters of ``observer_node`` (the paper's observer) and their validation.

:data:`OBSERVER_PARAMETERS` lists them once (the descriptors, the tables of
``docs/parameters.md`` and ``config/ext_observer.yaml`` come from it);
:func:`observer_settings` checks a set of values together, building the
core's observer from them so that the core's own checks apply.
"""

import math

from rclpy.qos import ReliabilityPolicy

from ext_observer.core import (certified_alpha_max, GAIN_MODES, PAPER_ALPHA, PAPER_GAIN,
                               SingleObserver, VARIANTS)
from ext_observer.nodes.estimator_node_base import SECOND
from ext_observer.pipeline.parameter_specs import (COMMON_PARAMETERS, common_settings,
                                                   ParameterSpec)

__all__ = ['ALIGN_SIGN_AUTO', 'CERTIFIED_EPSILON', 'INCREMENT_SOURCES', 'INCREMENT_TOPICS',
           'MEASUREMENT_SOURCES', 'MEASUREMENT_TOPICS', 'OBSERVER_PARAMETERS',
           'RELIABILITIES', 'make_observer', 'observer_settings', 'pairing_settings']

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
