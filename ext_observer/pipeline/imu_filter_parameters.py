"""
The parameters of ``imu_filter_node``: the raw-IMU estimator's, and imu_tools'.

A params file or launch file written for ``imu_filter_madgwick_node`` or
imu_complementary_filter's ``complementary_filter_node`` starts
``imu_filter_node`` unchanged: every parameter of both is declared here.
Those with the same meaning are honoured (``use_mag``, ``world_frame``,
``constant_dt``, ``mag_bias_*``, ``orientation_stddev``, ``declination``,
``yaw_offset``, :data:`IMU_TOOLS_OPTIONS`); those of their filters' gains
(:data:`IMU_TOOLS_UNUSED`: ``gain``, ``zeta``, ``gain_acc``,
``do_bias_estimation``, ...) are accepted, and named in one start-up warning
with what replaces each (:func:`unused_text`). The estimator's own gains are
the ``ahrs.*`` parameters and the
noise of the model behind the published covariance the ``covariance.*``
ones: each a row of the core's table
(:data:`~ext_observer.core.ahrs.ahrs_params.AHRS_TABLE`,
:data:`~ext_observer.core.ahrs.ahrs_params.UNCERTAINTY_TABLE`), range and
all. Plain data, no ROS: :mod:`ext_observer.nodes.imu_filter_node` declares them.
"""

import math

from ext_observer.core.ahrs.ahrs_observer import WORLD_FRAMES
from ext_observer.core.ahrs.magcal import check_calibration
from ext_observer.core.ahrs.ahrs_params import (AHRS_TABLE, AhrsParams, UNCERTAINTY_TABLE,
                                                UncertaintyParams)
from ext_observer.core.constants import STANDARD_GRAVITY
from ext_observer.core.ahrs.velocity_kernel import VELOCITY_TIMEOUT
from ext_observer.pipeline.imu_filter_outputs import (IDENTITY_MOUNTING, quaternion_from_rpy,
                                                      quaternion_matrix)
from ext_observer.pipeline.parameter_specs import (COMMON_PARAMETERS, common_settings,
                                                   ParameterSpec, spec_from_tunable)

__all__ = ['AHRS_PREFIX', 'COMPLEMENTARY_UNUSED', 'COVARIANCE_MODES', 'COVARIANCE_PREFIX',
           'IMU_FILTER_OWN', 'IMU_FILTER_PARAMETERS', 'IMU_TOOLS_OPTIONS', 'IMU_TOOLS_UNUSED',
           'MADGWICK_UNUSED', 'REPLACED_BY', 'ahrs_params', 'covariance_estimated',
           'covariance_text', 'imu_filter_settings', 'mag_frame_rpy_text',
           'uncertainty_params', 'unused_text',
           'velocity_frame', 'VELOCITY_SOURCES']

# Where the velocity aid's velocity comes from (velocity_source).
VELOCITY_SOURCES = ('none', 'odom', 'twist')
# A mounting quaternion's (mag_mounting, velocity_mounting) norm may differ from 1 by
# this much (rounded input).
_UNIT_TOLERANCE = 1e-6
# The core's parameters are the node's parameters ahrs.<name>.
AHRS_PREFIX = 'ahrs.'
# The uncertainty model's are covariance.<name>.
COVARIANCE_PREFIX = 'covariance.'


def _prefixed(values, prefix, cls):
    given = {name[len(prefix):]: value for name, value in values.items()
             if name.startswith(prefix)}
    try:
        return cls(**given)
    except ValueError as error:
        raise ValueError(f'{prefix}*: {error}') from None


def ahrs_params(values):
    """
    Return the core's parameters from the node's ``ahrs.*`` values.

    Parameters
    ----------
    values : dict
        Parameter values by name (the node's).

    Returns
    -------
    params : ext_observer.core.ahrs.ahrs_observer.AhrsParams

    Raises
    ------
    ValueError
        With the parameter's name and the core's reason.

    """
    return _prefixed(values, AHRS_PREFIX, AhrsParams)


def uncertainty_params(values):
    """
    Return the uncertainty model's parameters from the node's ``covariance.*`` values.

    Returns
    -------
    params : ext_observer.core.ahrs.ahrs_params.UncertaintyParams

    Raises
    ------
    ValueError
        With the parameter's name and the reason.

    """
    return _prefixed(values, COVARIANCE_PREFIX, UncertaintyParams)


# orientation_covariance of imu/data: the estimate's own, or orientation_stddev²;
# 'auto' is 'fixed' when orientation_stddev is set to a positive value other
# than ours (a user asks for that number), else 'estimate': imu_tools' own
# params files say 0.0, their default, which means "not given" here.
COVARIANCE_MODES = ('auto', 'estimate', 'fixed')
ORIENTATION_STDDEV = 0.05
# s: the longest hole bridged. On the even-numbered BROAD trials' movement the
# bridge's error is 14° RMS across 0.2 s, 59° across 0.5 s and 83° across 1 s,
# where not bridging costs 42°, 76° and 86°; across 2 s it is worse (100° against 92°).
MAX_DT = 1.0

# imu_tools' options that this node honours as imu_filter_madgwick does.
IMU_TOOLS_OPTIONS = (
    ParameterSpec('publish_debug_topics', False,
                  'Publish imu/rpy/filtered and imu/rpy/raw (geometry_msgs/Vector3Stamped: '
                  "roll, pitch, yaw, rad, about fixed x, y, z as tf2's getRPY), as "
                  "imu_filter_madgwick: filtered is imu/data's orientation, with its header; "
                  "raw the attitude of the sample's accelerometer and the latest field alone "
                  '(no filter), in the same world frame. Also imu/steady_state '
                  "(std_msgs/Bool: rest detected), as imu_complementary_filter's.",
                  read_only=True),
    ParameterSpec('publish_tf', False,
                  "Broadcast the orientation of imu/data on /tf, as imu_filter_madgwick: from "
                  "fixed_frame to the sample's frame_id, stamped with the sample, no "
                  'translation. Needs tf2_ros (a ROS installation); without it (the pip '
                  'wheels) one WARN at start says so. Default false here (true in '
                  "imu_filter_madgwick, whose own params file sets it).", read_only=True),
    ParameterSpec('reverse_tf', False,
                  'With publish_tf: the inverse transform, from the sensor frame to '
                  'fixed_frame (as imu_filter_madgwick).'),
    ParameterSpec('fixed_frame', 'odom', 'With publish_tf: the parent frame of the transform '
                  '(as imu_filter_madgwick).'),
    ParameterSpec('remove_gravity_vector', False,
                  f'linear_acceleration of imu/data without gravity ({STANDARD_GRAVITY} m/s² '
                  'along the estimated vertical), in the sensor frame, as imu_filter_madgwick; '
                  'false: as measured.'),
)

# imu_filter_madgwick's parameters that this node accepts and does not use,
# with the value that says what this node does (or Madgwick's default).
MADGWICK_UNUSED = (
    ParameterSpec('gain', 0.1, "imu_filter_madgwick's filter gain β: not used (the "
                  'gains here are the ahrs.* time constants).'),
    ParameterSpec('zeta', 0.0, "imu_filter_madgwick's gyro drift gain: not used (the bias "
                  'is learned at rest, ahrs.tau_rest; in motion, ahrs.tau_bias).'),
    ParameterSpec('stateless', False, "imu_filter_madgwick's stateless mode: not used "
                  '(imu/rpy/raw gives the attitude of each sample alone).'),
)

# imu_complementary_filter's own parameters: accepted, not used, and named
# whenever given ('' is "not given": its users' files repeat its defaults,
# and they are told what replaces each all the same).
NOT_GIVEN = ''
COMPLEMENTARY_UNUSED = tuple(
    ParameterSpec(name, NOT_GIVEN, f"imu_complementary_filter's {what}: not used "
                  f"(docs/raw_imu.md); '' = not given.", dynamic=True)
    for name, what in (('gain_acc', 'accelerometer gain'),
                       ('gain_mag', 'magnetometer gain'),
                       ('bias_alpha', 'gyro bias gain'),
                       ('do_bias_estimation', 'gyro bias estimation switch'),
                       ('do_adaptive_gain', 'adaptive accelerometer gain switch')))

# What replaces each parameter of imu_tools' filters that is not used here
# (the start-up warning says it beside the name).
REPLACED_BY = {
    'gain': 'ahrs.tau_acc_gain and ahrs.tau_mag, time constants in s',
    'zeta': 'the gyro bias learned at rest, ahrs.tau_rest, and in motion, ahrs.tau_bias; '
            'gyro_bias_learning switches it',
    'stateless': 'none: always filtered; imu/rpy/raw is the attitude of each sample alone',
    'gain_acc': 'ahrs.tau_acc_gain, s',
    'gain_mag': 'ahrs.tau_mag, s',
    'bias_alpha': 'ahrs.tau_rest, s',
    'do_bias_estimation': 'the gyro bias learned at rest and in motion, ahrs.tau_bias; '
                          'gyro_bias_learning switches it',
    'do_adaptive_gain': 'the accelerometer low-passed in a frame the gyro moves, '
                        'ahrs.tau_acc: no gain to adapt',
}

# The node's own parameters (config/imu_filter.yaml lists these).
IMU_FILTER_OWN = (
    ParameterSpec('use_mag', True,
                  'Correct the heading from the magnetometer on imu/mag '
                  '(sensor_msgs/MagneticField, T), as imu_filter_madgwick; false: gyro and '
                  'accelerometer only (6D, heading free). With no field yet the estimate '
                  'runs 6D and the node warns.', read_only=True),
    ParameterSpec('world_frame', 'enu',
                  "World frame of the estimate: 'enu' (x east, y north, z up; REP-103), "
                  "'nwu' or 'ned', as imu_filter_madgwick.",
                  read_only=True, constraints=f'One of {", ".join(WORLD_FRAMES)}.'),
    ParameterSpec('declination', 0.0,
                  'Magnetic declination, rad, east positive: the heading is turned from '
                  'magnetic to true north (as imu_filter_madgwick).', (-3.1416, 3.1416)),
    ParameterSpec('yaw_offset', 0.0,
                  'Turn of the published orientation about the world frame\'s z axis, rad '
                  '(as imu_filter_madgwick: with enu, R_z(yaw_offset − declination) ⊗ q).',
                  (-6.2832, 6.2832)),
    ParameterSpec('mag_bias_x', 0.0,
                  'Hard-iron offset b of the field, x, T, in m_raw = S m + b: with the '
                  'online calibration (ahrs.mag_cal, 9D) the saved value it starts from '
                  'and refines; without, subtracted as it is (imu_filter_madgwick).',
                  (-1.0, 1.0)),
    ParameterSpec('mag_bias_y', 0.0, 'The same, y, T.', (-1.0, 1.0)),
    ParameterSpec('mag_bias_z', 0.0, 'The same, z, T.', (-1.0, 1.0)),
    ParameterSpec('mag_soft_iron', [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
                  'Soft-iron matrix S of the field, row-major, in m_raw = S m + b; as '
                  'mag_bias_*. python -m ext_observer calibrate and the ~/save_calibration '
                  'service write both.',
                  constraints='9 finite numbers: symmetric, positive definite.'),
    ParameterSpec('mag_mounting', list(IDENTITY_MOUNTING),
                  "The magnetometer's mounting: the orientation of the field's frame "
                  "(imu/mag's frame_id) in the IMU's (imu/data_raw's), a unit quaternion w, "
                  "x, y, z (as velocity_mounting; static_transform_publisher's --qw --qx "
                  "--qy --qz with --frame-id the IMU's, --child-frame-id the field's): "
                  'm_imu = R m_mag, the field turned into '
                  'the IMU frame before mag_bias_* and mag_soft_iron, which are then the '
                  "IMU frame's. The node cannot look the transform up on /tf (tf2 is not on "
                  'PyPI): it warns once when the two frame_ids differ and this is the '
                  'identity.',
                  constraints='4 finite numbers of norm 1 (within 1e-6).'),
    ParameterSpec('mag_frame_rpy', [0.0, 0.0, 0.0],
                  'Deprecated: mag_mounting. The same mounting as roll, pitch, yaw (rad, '
                  "about the fixed x, y, z axes, as tf2's setRPY); still used when set (not "
                  'zero) and mag_mounting is the identity, with a warning naming the '
                  'quaternion it is; both set is refused.',
                  constraints='3 finite numbers; zero when mag_mounting is set.'),
    ParameterSpec('mag_timeout', 1.0,
                  'A field lost: after this long without one (s, on the IMU\'s stamps) the '
                  'node warns (/diagnostics and the log, once per episode) and runs 6D, '
                  "the gyro holding the heading, its variance growing; the field's return "
                  'brings the heading back at the Kalman gain of that variance, then of '
                  'tau_mag, without a step '
                  '(docs/raw_imu.md#the-magnetometers-frame-and-a-lost-field). 0 = never warn.',
                  (0.0, 3600.0)),
    ParameterSpec('calibration_file', 'mag_calibration.yaml',
                  'Where ~/save_calibration writes the learned calibration (a params '
                  'file for this node: mag_bias_*, mag_soft_iron once the magnetometer '
                  'calibration has one, and gyro_bias_*), relative to the '
                  "node's working directory."),
    ParameterSpec('gyro_bias_x', 0.0,
                  'Gyro bias the estimate starts from (at start and after each reset), x, '
                  'rad/s, body frame: a saved or known one (~/save_calibration writes the '
                  "learned one; VQF's setBiasEstimate). Learned from there while "
                  'gyro_bias_learning; set at runtime, it replaces the current estimate.',
                  (-1.0, 1.0), constraints='Within ±ahrs.bias_max.'),
    ParameterSpec('gyro_bias_y', 0.0, 'The same, y, rad/s.', (-1.0, 1.0),
                  constraints='Within ±ahrs.bias_max.'),
    ParameterSpec('gyro_bias_z', 0.0, 'The same, z, rad/s.', (-1.0, 1.0),
                  constraints='Within ±ahrs.bias_max.'),
    ParameterSpec('gyro_bias_learning', True,
                  'Learn the gyro bias (at rest, and in motion with ahrs.tau_bias); false '
                  'holds it where it is (ros2 param set switches it at runtime).'),
    ParameterSpec('orientation_covariance_mode', 'auto',
                  "orientation_covariance of imu/data: 'estimate' (the estimate's own "
                  'covariance, row-major, rad², about the world frame\'s x, y, z axes: '
                  "docs/covariance.md), 'fixed' (orientation_stddev squared on the "
                  "diagonal, as imu_filter_madgwick) or 'auto': 'fixed' when "
                  'orientation_stddev is set to a positive value other than its default, '
                  "else 'estimate' (0, imu_tools' own default, means not given).",
                  constraints=f'One of {", ".join(COVARIANCE_MODES)}.'),
    ParameterSpec('orientation_stddev', ORIENTATION_STDDEV,
                  "With orientation_covariance_mode 'fixed' (or 'auto' and a positive value "
                  'other than this default): standard deviation of the orientation, rad; '
                  'orientation_covariance of imu/data is its square on the diagonal (as '
                  "imu_filter_madgwick). 0 (imu_tools' default) with 'auto': not given, the "
                  "estimate's own covariance; with 'fixed': zeros.",
                  (0.0, 10.0)),
    ParameterSpec('constant_dt', 0.0,
                  'Δt of every sample, s, instead of the interval between the stamps: '
                  'every sample is used, in the order it arrives, repeated or older stamps '
                  'included (as imu_filter_madgwick); 0 = from the stamps.', (0.0, 10.0)),
    ParameterSpec('max_dt', MAX_DT,
                  'Longest hole between two IMU samples that the estimator bridges, s (the '
                  'rotation across it from the samples on both sides, its covariance grown: '
                  'docs/raw_imu.md#holes-in-the-stream); after a longer one it goes on from '
                  'the new sample (dropped: dt_too_large), the estimate held and its '
                  'covariance grown by the rotation the hole may have hidden.',
                  (0.0001, 10.0)),
    ParameterSpec('frame_id', 'world', 'frame_id of attitude_estimate (imu/data keeps the '
                  "sample's frame_id)."),
    # The velocity aid (docs/raw_imu.md#a-velocity-aid-vehicles): the node's
    # velocity topic, the batch API's velocity array.
    ParameterSpec('velocity_source', 'none',
                  "Velocity aid: the body's velocity from 'odom' (nav_msgs/Odometry, its "
                  "twist.twist.linear in child_frame_id), 'twist' (geometry_msgs/"
                  "TwistStamped on velocity, its linear part) or 'none'. The acceleration "
                  'it implies is removed from the specific force (vehicles in turns).',
                  read_only=True, constraints="'none', 'odom' or 'twist'."),
    ParameterSpec('velocity_timeout', VELOCITY_TIMEOUT,
                  "Velocity aid (velocity_source, attitude_from_imu's velocity): a body "
                  'velocity older than this, s, is not used, and the specific force is taken '
                  'as it is measured; the node drops one stamped this much before the latest '
                  'IMU sample (stale).',
                  (0.001, 10.0)),
    ParameterSpec('velocity_mounting', [1.0, 0.0, 0.0, 0.0],
                  "Velocity aid: the IMU's orientation in the velocity's frame (e.g. the "
                  "odometry's child frame), a unit quaternion w, x, y, z: v_imu = R^T v.",
                  read_only=True, constraints='4 finite numbers of norm 1 (within 1e-6).'),
    ParameterSpec('velocity_frame', '',
                  "Velocity aid: the frame velocity_mounting and velocity_lever_arm place the "
                  "IMU in, which the velocity must come in (Odometry's child_frame_id, "
                  "TwistStamped's frame_id); '': the IMU's own (imu/data_raw's frame_id). "
                  'A velocity in another frame is still used; the node warns once and counts '
                  'it (velocity_frame_mismatches).',
                  read_only=True),
    ParameterSpec('velocity_lever_arm', [0.0, 0.0, 0.0],
                  "Velocity aid: the IMU's position in the velocity's frame, m: the IMU's "
                  'own velocity is v + ω × r (its acceleration gains ω̇ × r + ω × (ω × r)).',
                  read_only=True, constraints='3 finite numbers.'),
) + COMMON_PARAMETERS + (
    ParameterSpec('divergence_max_residual', 15.0,
                  'Divergence guard: reinitialize from the sample at hand when the '
                  'residual |q̂̄q̂ − 1| exceeds this after a step.', (0.01, 1000.0)),
    ParameterSpec('input_timeout', 2.0,
                  'WARN when no IMU sample has arrived for this long (after the first), s; '
                  'checked at each status, by the node clock; 0 = never.', (0.0, 3600.0)),
    ParameterSpec('serialized_io', True,
                  'Take imu/data_raw and imu/mag as CDR bytes, read by the node itself, '
                  'and publish imu/data and attitude_estimate as bytes: the same estimates '
                  'and messages for about half the CPU per sample (docs/nodes.md); false: '
                  'rclpy deserializes and serializes message objects.', read_only=True),
) + tuple(
    spec_from_tunable(row, AHRS_PREFIX, 'Estimator') for row in AHRS_TABLE) + tuple(
    spec_from_tunable(row, COVARIANCE_PREFIX, 'Covariance model (docs/covariance.md)')
    for row in UNCERTAINTY_TABLE)

IMU_FILTER_PARAMETERS = (IMU_FILTER_OWN + IMU_TOOLS_OPTIONS + MADGWICK_UNUSED
                         + COMPLEMENTARY_UNUSED)
IMU_TOOLS_UNUSED = MADGWICK_UNUSED + COMPLEMENTARY_UNUSED


def imu_filter_settings(values):
    """
    Validate the parameters of ``imu_filter_node``.

    Parameters
    ----------
    values : dict
        Every parameter of :data:`IMU_FILTER_PARAMETERS` by name.

    Returns
    -------
    settings : dict
        ``values``, checked.

    Raises
    ------
    ValueError
        With the reason.

    """
    common_settings(values)
    try:
        check_calibration((values['mag_bias_x'], values['mag_bias_y'], values['mag_bias_z']),
                          values['mag_soft_iron'])
    except ValueError as error:
        raise ValueError(f'mag_bias_*, mag_soft_iron (the saved magnetometer calibration): '
                         f'{error}') from None
    rpy = values['mag_frame_rpy']
    if len(rpy) != 3 or not all(math.isfinite(float(v)) for v in rpy):
        raise ValueError(f'mag_frame_rpy must be 3 finite numbers (roll, pitch, yaw, rad), '
                         f'got {list(rpy)}')
    q = _unit_quaternion(values, 'mag_mounting')
    if q != IDENTITY_MOUNTING and any(float(v) != 0.0 for v in rpy):
        raise ValueError(f'mag_mounting ({list(q)}) and mag_frame_rpy ({list(rpy)}) are both '
                         'set: give the magnetometer\'s mounting once, as mag_mounting (a unit '
                         'quaternion w, x, y, z); mag_frame_rpy is deprecated')
    if values['world_frame'] not in WORLD_FRAMES:
        raise ValueError(f'world_frame must be one of {tuple(WORLD_FRAMES)}, got '
                         f'{values["world_frame"]!r}')
    if values['orientation_covariance_mode'] not in COVARIANCE_MODES:
        raise ValueError(f'orientation_covariance_mode must be one of {COVARIANCE_MODES}, '
                         f'got {values["orientation_covariance_mode"]!r}')
    if values['velocity_source'] not in VELOCITY_SOURCES:
        raise ValueError(f'velocity_source must be one of {VELOCITY_SOURCES}, got '
                         f'{values["velocity_source"]!r}')
    velocity_frame(values)
    params = ahrs_params(values)
    for axis in 'xyz':
        if abs(values[f'gyro_bias_{axis}']) > params.bias_max:
            raise ValueError(f'gyro_bias_{axis} must lie within ±ahrs.bias_max '
                             f'({params.bias_max:g} rad/s), got {values[f"gyro_bias_{axis}"]}')
    uncertainty_params(values)
    settings = dict(values)
    settings['covariance_estimated'] = covariance_estimated(values)
    return settings


def velocity_frame(values):
    """
    The velocity aid's frame: ``R^T`` (9 floats, row-major) and ``R^T r``, or None for the IMU's.

    Raises
    ------
    ValueError
        For a mounting that is not a finite unit quaternion, a lever arm not 3 finite numbers.
    """
    q = _unit_quaternion(values, 'velocity_mounting')
    r = [float(c) for c in values['velocity_lever_arm']]
    if len(r) != 3 or not all(math.isfinite(c) for c in r):
        raise ValueError(f'velocity_lever_arm must be 3 finite numbers (m), got {r}')
    if q == IDENTITY_MOUNTING and r == [0.0, 0.0, 0.0]:
        return None
    # R (IMU → velocity frame) transposed: rows are R's columns.
    m = quaternion_matrix(q)
    rt = (m[0], m[3], m[6], m[1], m[4], m[7], m[2], m[5], m[8])
    arm = tuple(rt[3 * i] * r[0] + rt[3 * i + 1] * r[1] + rt[3 * i + 2] * r[2]
                for i in range(3))
    return rt, arm


def _unit_quaternion(values, name):
    """``values[name]`` as a tuple of 4 floats, checked: finite, of norm 1 within the tolerance."""
    q = tuple(float(c) for c in values[name])
    if len(q) != 4 or not all(math.isfinite(c) for c in q) or abs(
            sum(c * c for c in q) - 1.0) > _UNIT_TOLERANCE:
        raise ValueError(f'{name} must be a unit quaternion w, x, y, z (norm 1 within '
                         f'{_UNIT_TOLERANCE:g}), got {list(q)}')
    return q


def mag_frame_rpy_text(values):
    """
    The warning for the deprecated ``mag_frame_rpy`` set (not zero), or None.

    Names the ``mag_mounting`` it is (tf2's ``setRPY`` quaternion), to copy
    into the params file.
    """
    rpy = [float(v) for v in values.get('mag_frame_rpy', (0.0, 0.0, 0.0))]
    if not any(v != 0.0 for v in rpy):
        return None
    q = list(quaternion_from_rpy(rpy))
    return (f'mag_frame_rpy is deprecated: give the magnetometer\'s mounting as mag_mounting, '
            f'a unit quaternion w, x, y, z; mag_frame_rpy {rpy} is mag_mounting {q} '
            '(used as given meanwhile)')


def covariance_estimated(values):
    """
    Whether ``imu/data`` carries the estimate's own covariance (else orientation_stddev's).

    ``orientation_covariance_mode`` ``'auto'`` is ``'fixed'`` when
    ``orientation_stddev`` is positive and differs from its default: a user
    who sets a number gets it. 0, the default of imu_filter_madgwick and of
    imu_complementary_filter (their own params files say ``0.0``), is "not
    given": a zero covariance would tell robot_localization that the
    orientation is exact.
    """
    mode = values['orientation_covariance_mode']
    if mode == 'auto':
        stddev = values['orientation_stddev']
        return not (stddev > 0.0 and stddev != ORIENTATION_STDDEV)
    return mode == 'estimate'


def covariance_text(values):
    """Say which ``orientation_covariance`` ``imu/data`` carries and why (the start-up log)."""
    mode, stddev = values['orientation_covariance_mode'], values['orientation_stddev']
    if not covariance_estimated(values):
        return (f'orientation_covariance of imu/data: orientation_stddev² on the diagonal '
                f'(orientation_stddev {stddev:g} rad, orientation_covariance_mode {mode})')
    if mode == 'auto' and stddev == 0.0:
        why = ('orientation_stddev 0.0 means not given (imu_tools\' default); a positive '
               'value selects a fixed one')
    else:
        why = f'orientation_covariance_mode {mode}'
    return f"orientation_covariance of imu/data: the estimate's own ({why})"


def unused_text(values, given):
    """
    Name the parameters of imu_tools' filters given and not used, with what replaces each.

    Parameters
    ----------
    values : dict
        Every parameter's value by name.
    given : set
        The names given at start-up with a value other than the default.

    Returns
    -------
    text : str or None
        The start-up warning; None when there is nothing to say.

    """
    names = [spec.name for spec in IMU_TOOLS_UNUSED if spec.name in given]
    if not names:
        return None
    return ("parameters of imu_tools' filters accepted but not used here: "
            + '; '.join(f'{name}={values[name]!r} (→ {REPLACED_BY[name]})' for name in names)
            + ' (docs/raw_imu.md)')
