"""
The parameters of ``imu_filter_node``: the raw-IMU estimator's, and imu_filter_madgwick's.

A params file or launch file written for ``imu_filter_madgwick_node`` starts
``imu_filter_node`` unchanged: every parameter of imu_filter_madgwick is
declared here. Those with the same meaning are honoured (``use_mag``,
``world_frame``, ``constant_dt``, ``mag_bias_*``, ``orientation_stddev``,
``declination``, ``yaw_offset``); those of Madgwick's filter or of features
this node does not have (:data:`MADGWICK_UNUSED`: ``gain``, ``zeta``,
``publish_tf``, ...) are accepted, and named in one start-up warning when
given. The estimator's own gains are the ``ahrs.*`` parameters, the fields
of :class:`~ext_observer.core.ahrs.estimator.AhrsParams` in physical units; the
noise of the model behind the published covariance are the
``covariance.*`` parameters (:class:`~ext_observer.core.ahrs.uncertainty.UncertaintyParams`).
"""

import math

from ext_observer.core.ahrs.estimator import AhrsParams, WORLD_FRAMES
from ext_observer.core.ahrs.magcal import check_calibration
from ext_observer.core.ahrs.uncertainty import UncertaintyParams
from ext_observer.nodes.estimator_node import COMMON_PARAMETERS, common_settings
from ext_observer.nodes.parameters import ParameterSpec
from ext_observer.pipeline.raw_imu import AHRS_PREFIX, ahrs_params, COVARIANCE_PREFIX, uncertainty_params

__all__ = ['COVARIANCE_MODES', 'IMU_FILTER_OWN', 'IMU_FILTER_PARAMETERS', 'MADGWICK_UNUSED',
           'covariance_estimated', 'covariance_text', 'imu_filter_settings']

# orientation_covariance of imu/data: the estimate's own, or orientation_stddev²;
# 'auto' is 'fixed' when orientation_stddev is set to a positive value other
# than ours (a user asks for that number), else 'estimate': imu_tools' own
# params files say 0.0, their default, which means "not given" here.
COVARIANCE_MODES = ('auto', 'estimate', 'fixed')
ORIENTATION_STDDEV = 0.05

# What each AhrsParams field means, with its unit; (description, range,
# constraints).
_AHRS_DOCS = {
    'alpha': ('gain α of the extension term that holds the estimate near S³.',
              (0.0, 1.0), 'Must lie in (0, 0.0762), the range certified by Theorem 1.'),
    'tau_acc': ('time constant of the world-frame low-pass of the accelerometer, s.',
                (0.0, 1e4), 'Positive.'),
    'tau_acc_gain': ('time constant of the inclination correction (the gain κ_a), s.',
                     (0.0, 1e4), 'Positive.'),
    'tau_mag': ('time constant of the heading correction from the magnetometer (κ_m), s '
                '(the gain of each field follows from the interval since the previous '
                'field).', (0.0, 1e4), 'Positive.'),
    'tau_bias': ('time constant of the gyro bias estimate in motion, s; 0 turns it off.',
                 (0.0, 1e6), 'At least 0.'),
    'bias_max': ('largest gyro bias estimate per axis, rad/s.', (0.0, 10.0), 'Positive.'),
    'rest_gyr': ('rest detection: threshold on the angular rate, rad/s.', (0.0, 10.0),
                 'Positive.'),
    'rest_acc': ('rest detection: threshold on the deviation of the specific force, '
                 'm/s².', (0.0, 100.0), 'Positive.'),
    'rest_time': ('rest detection: time below both thresholds before rest, s.',
                  (0.0, 1e4), 'Positive.'),
    'tau_rest': ('time constant of the rest-detection filters and of the bias estimate '
                 'at rest, s.', (0.0, 1e4), 'Positive.'),
    'mag_norm_th': ('magnetic disturbance: relative deviation of the field norm from its '
                    'reference.', (0.0, 100.0), 'Positive.'),
    'mag_dip_th': ('magnetic disturbance: deviation of the dip angle from its reference, '
                   'rad.', (0.0, math.pi), 'Positive.'),
    'mag_new_time': ('time a new, consistent field must last (while the body turns) '
                     'before it is accepted, s.', (0.0, 1e4), 'Positive.'),
    'mag_new_gyr': ('angular rate the body must turn at for that time to count, rad/s.',
                    (0.0, 100.0), 'Positive.'),
    'tau_mag_ref': ('time constant of the learned field norm and dip references, s.',
                    (0.0, 1e6), 'Positive.'),
    'mag_cal': ('calibrate the magnetometer online in 9D (hard-iron offset and soft-iron '
                'matrix, learned while the body turns; docs/calibration.md); false: the '
                'fields are used as given.', None, ''),
    'mag_cal_noise': ("the field's noise per sample and axis, relative to its norm.",
                      (0.0, 1.0), 'Positive.'),
    'mag_cal_field_rw': ('how fast the world field may change where the body goes, '
                         'relative to its norm, per √s.', (0.0, 10.0), 'Positive.'),
    'mag_cal_soft_iron': ('prior standard deviation of each element of the soft-iron '
                          'matrix S − I.', (0.0, 10.0), 'Positive.'),
    'mag_cal_delay': ("prior standard deviation of the field's lag behind the gyro, s "
                      '(learned); 0: no lag.', (0.0, 10.0), 'At least 0.'),
    'mag_cal_heading': ('the calibration is converged, and the heading follows the '
                        'field, when the heading error its uncertainty would cause is '
                        'below this, rad (1σ).', (0.0, 3.1416), 'Positive.'),
    'mag_cal_deadband': ('a learned calibration replaces the field as given only when it '
                         'turns the heading by more than this, rad (RMS).', (0.0, 3.1416),
                         'At least 0.'),
    'mag_cal_drift': ('random walk of the hard-iron offset, relative to the field norm, '
                      'per √s; 0: constant.', (0.0, 10.0), 'At least 0.'),
    'mag_cal_rate': ('most fields per second the calibration learns from, Hz (every field '
                     'is calibrated).', (0.0, 1e5), 'Positive.')
}


# What each UncertaintyParams field means, with its unit; (description, range).
_COVARIANCE_DOCS = {
    'gyro_noise': ('white noise density of the gyro, rad/s/√Hz.', (1e-9, 1.0)),
    'gyro_rate_noise': ('noise density of the gyro error proportional to the rate (scale '
                        'factor, misalignment, vibration), (rad/s per rad/s)/√Hz.', (0.0, 1.0)),
    'bias_std': ('how far the gyro bias wanders from the learned one, rad/s (σ).',
                 (0.0, 1.0)),
    'bias_time': ('correlation time of that wander, s.', (1e-3, 1e6)),
    'bias_init': ('gyro bias uncertainty per axis before the first rest, rad/s.',
                  (0.0, 1.0)),
    'acc_noise': ('accelerometer noise density, m/s²/√Hz.', (1e-9, 10.0)),
    'mag_noise': ("noise density of the field's horizontal direction, rad·√s.",
                  (1e-9, 10.0)),
    'inclination_floor': ('smallest inclination σ (translational acceleration, '
                          'accelerometer calibration, mounting), rad.', (0.0, 1.0)),
    'heading_floor': ('smallest heading σ once a field has set the heading (a bent but '
                      'accepted field), rad.', (0.0, 1.0)),
    'stamp_error': ("timing error of a sample's stamp, s: the orientation is off by "
                    '|ω| times it.', (0.0, 1.0)),
}


def _covariance_spec(name, default):
    description, bounds = _COVARIANCE_DOCS[name]
    positive = name in UncertaintyParams.POSITIVE
    return ParameterSpec(
        COVARIANCE_PREFIX + name, float(default),
        f'Covariance model: {description} Default: UncertaintyParams.DEFAULTS '
        '(docs/covariance.md).', bounds, read_only=True,
        constraints='Positive.' if positive else 'At least 0 (0: off).')


def _ahrs_spec(name, default):
    description, bounds, constraints = _AHRS_DOCS.get(
        name, (f'AhrsParams.{name} (ext_observer/core/ahrs/estimator.py).', None, ''))
    return ParameterSpec(
        AHRS_PREFIX + name, default if isinstance(default, bool) else float(default),
        f'Estimator: {description} Default: the core\'s (AhrsParams.DEFAULTS).', bounds,
        read_only=True, constraints=constraints)


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
) + tuple(_ahrs_spec(name, default) for name, default in AhrsParams.DEFAULTS.items()) + tuple(
    _covariance_spec(name, default) for name, default in UncertaintyParams.DEFAULTS.items())

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
