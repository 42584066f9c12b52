"""
The parameters of ``imu_filter_node``: the raw-IMU estimator's, and imu_filter_madgwick's.

A params file or launch file written for ``imu_filter_madgwick_node`` starts
``imu_filter_node`` unchanged: every parameter of imu_filter_madgwick is
declared here. Those with the same meaning are honoured (``use_mag``,
``world_frame``, ``constant_dt``, ``mag_bias_*``, ``orientation_stddev``,
``declination``, ``yaw_offset``); those of Madgwick's filter or of features
this node does not have (:data:`MADGWICK_UNUSED`: ``gain``, ``zeta``,
``publish_tf``, ...) are accepted, and named in one start-up warning when
given. The estimator's own gains are the ``ahrs.*`` parameters and the
noise of the model behind the published covariance the ``covariance.*``
ones: each a row of the core's table
(:data:`~ext_observer.core.ahrs.ahrs_params.AHRS_TABLE`,
:data:`~ext_observer.core.ahrs.uncertainty.UNCERTAINTY_TABLE`), range and
all. Plain data, no ROS: :mod:`ext_observer.nodes.imu_filter_node` declares them.
"""

from ext_observer.core.ahrs.ahrs_params import AHRS_TABLE
from ext_observer.core.ahrs.estimator import WORLD_FRAMES
from ext_observer.core.ahrs.magcal import check_calibration
from ext_observer.core.ahrs.uncertainty import UNCERTAINTY_TABLE
from ext_observer.pipeline.parameter_specs import (COMMON_PARAMETERS, common_settings,
                                                   ParameterSpec, spec_from_tunable)
from ext_observer.pipeline.raw_imu import (AHRS_PREFIX, ahrs_params, COVARIANCE_PREFIX,
                                           uncertainty_params)

__all__ = ['COVARIANCE_MODES', 'IMU_FILTER_OWN', 'IMU_FILTER_PARAMETERS', 'MADGWICK_UNUSED',
           'covariance_estimated', 'covariance_text', 'imu_filter_settings']

# orientation_covariance of imu/data: the estimate's own, or orientation_stddev²;
# 'auto' is 'fixed' when orientation_stddev is set to a positive value other
# than ours (a user asks for that number), else 'estimate': imu_tools' own
# params files say 0.0, their default, which means "not given" here.
COVARIANCE_MODES = ('auto', 'estimate', 'fixed')
ORIENTATION_STDDEV = 0.05

# imu_filter_madgwick's parameters that this node accepts and does not use,
# with the value that says what this node does (or Madgwick's default).
MADGWICK_UNUSED = (
    ParameterSpec('gain', 0.1, "imu_filter_madgwick's filter gain β: not used (the "
                  'gains here are the ahrs.* time constants).'),
    ParameterSpec('zeta', 0.0, "imu_filter_madgwick's gyro drift gain: not used (the bias "
                  'is learned at rest, ahrs.tau_rest; in motion, ahrs.tau_bias).'),
    ParameterSpec('publish_tf', False, "imu_filter_madgwick's TF broadcast: not used (no "
                  'TF is published; orientation only, on imu/data).'),
    ParameterSpec('reverse_tf', False, "imu_filter_madgwick's TF direction: not used."),
    ParameterSpec('fixed_frame', 'odom', "imu_filter_madgwick's TF parent frame: not used."),
    ParameterSpec('publish_debug_topics', False,
                  "imu_filter_madgwick's roll/pitch/yaw debug topics: not used."),
    ParameterSpec('stateless', False, "imu_filter_madgwick's stateless mode: not used."),
    ParameterSpec('remove_gravity_vector', False,
                  "imu_filter_madgwick's gravity removal from imu/data: not used (the "
                  'acceleration goes out as measured).'),
)

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
    ParameterSpec('calibration_file', 'mag_calibration.yaml',
                  'Where ~/save_calibration writes the learned calibration (a params '
                  'file for this node: mag_bias_*, mag_soft_iron), relative to the '
                  "node's working directory."),
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
    ParameterSpec('max_dt', 0.1,
                  'Largest interval between two IMU samples, s; after a longer one the '
                  'estimator goes on from the new sample (dropped: dt_too_large).',
                  (0.0001, 10.0)),
    ParameterSpec('frame_id', 'world', 'frame_id of attitude_estimate (imu/data keeps the '
                  "sample's frame_id)."),
) + COMMON_PARAMETERS + (
    ParameterSpec('divergence_max_residual', 15.0,
                  'Divergence guard: reinitialize from the sample at hand when the '
                  'residual |q̂̄q̂ − 1| exceeds this after a step.', (0.01, 1000.0)),
    ParameterSpec('input_timeout', 2.0,
                  'WARN when no IMU sample has arrived for this long (after the first), s; '
                  'checked at each status, by the node clock; 0 = never.', (0.0, 3600.0)),
) + tuple(
    spec_from_tunable(row, AHRS_PREFIX, 'Estimator') for row in AHRS_TABLE) + tuple(
    spec_from_tunable(row, COVARIANCE_PREFIX, 'Covariance model (docs/covariance.md)')
    for row in UNCERTAINTY_TABLE)

IMU_FILTER_PARAMETERS = IMU_FILTER_OWN + MADGWICK_UNUSED


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
    if values['world_frame'] not in WORLD_FRAMES:
        raise ValueError(f'world_frame must be one of {tuple(WORLD_FRAMES)}, got '
                         f'{values["world_frame"]!r}')
    if values['orientation_covariance_mode'] not in COVARIANCE_MODES:
        raise ValueError(f'orientation_covariance_mode must be one of {COVARIANCE_MODES}, '
                         f'got {values["orientation_covariance_mode"]!r}')
    ahrs_params(values)
    uncertainty_params(values)
    settings = dict(values)
    settings['covariance_estimated'] = covariance_estimated(values)
    return settings


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
