"""
The raw-IMU source of the observer node (``measurement_source: accel``).

With it, ``observer_node`` replaces ``imu_filter_madgwick_node``: the same
topics, ``use_mag`` and ``world_frame``; only the gains are its own
(``ahrs.*``, the parameters of :class:`~ext_observer.core.ahrs.AhrsParams`).

Inputs
    ``imu/data_raw`` (``sensor_msgs/Imu``): the angular velocity (rad/s)
    and the linear acceleration (m/s², the specific force: about +9.81 up at
    rest) of one sample; the orientation is ignored. ``imu/mag``
    (``sensor_msgs/MagneticField``, T), at its own rate, when ``use_mag``.
    Both go through :class:`~ext_observer.pairing.StepPairer` first (values
    and stamps checked, every input counted), as every other source.

Steps
    Sample ``k`` runs :meth:`AhrsObserver.update
    <ext_observer.core.ahrs.AhrsObserver.update>` with its own angular
    velocity and acceleration and ``dt = t_k − t_{k−1}`` (``constant_dt``
    when set); the first sample of a time line only sets ``t_0``, the second
    initializes the estimate from gravity (and the latest field). A field
    corrects the heading when it arrives
    (:meth:`~ext_observer.core.ahrs.AhrsObserver.update_mag`, the latest field
    only, with the hard-iron offset ``mag_bias_*`` removed and the interval
    since the previous field, from their stamps, as its ``dt``); before the
    first step it is kept for the initialization. Nothing normalizes the
    estimate on this path: the extension term of the core holds it near S³.

Outputs
    The core's estimate is sensor → ENU; it goes out in ``world_frame``
    (``q_frame = C ⊗ q_enu``, :data:`~ext_observer.core.ahrs.WORLD_FRAMES`),
    ambient on ``attitude_estimate`` and normalized on ``imu/data``, stamped
    with the sample's stamp.
"""

import math

from ext_observer.conversions import vector_from_msg
from ext_observer.core.ahrs import AhrsObserver, AhrsParams, WORLD_FRAMES
from ext_observer.core.quaternion import multiply_floats
from ext_observer.core.validation import check_state
from ext_observer.node_common import ParameterSpec

__all__ = ['AHRS_PREFIX', 'RAW_IMU_PARAMETERS', 'RawImuEstimator', 'ahrs_params',
           'imu_vectors', 'raw_imu_settings']

# The core's parameters are the node's parameters ahrs.<name>.
AHRS_PREFIX = 'ahrs.'

# What each AhrsParams field means, with its unit; (description, range).
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
}


def _ahrs_spec(name, default):
    description, bounds, constraints = _AHRS_DOCS.get(
        name, (f'AhrsParams.{name} (ext_observer/core/ahrs.py).', None, ''))
    return ParameterSpec(
        AHRS_PREFIX + name, float(default),
        f'measurement_source accel: {description} Default: the core\'s '
        '(AhrsParams.DEFAULTS).', bounds, read_only=True, constraints=constraints)


RAW_IMU_PARAMETERS = (
    ParameterSpec('use_mag', True,
                  'measurement_source accel: correct the heading from the magnetometer on '
                  'imu/mag (sensor_msgs/MagneticField, T), as imu_filter_madgwick; false: '
                  'gyro and accelerometer only (6D, heading free). With no field yet the '
                  'estimate runs 6D and /diagnostics warns.', read_only=True),
    ParameterSpec('world_frame', 'enu',
                  "measurement_source accel: world frame of the estimate: 'enu' (x east, "
                  "y north, z up; REP-103), 'nwu' or 'ned', as imu_filter_madgwick.",
                  read_only=True, constraints=f'One of {", ".join(WORLD_FRAMES)}.'),
    ParameterSpec('mag_bias_x', 0.0,
                  'measurement_source accel: hard-iron offset subtracted from the field, x, '
                  'T (as imu_filter_madgwick).', (-1.0, 1.0)),
    ParameterSpec('mag_bias_y', 0.0, 'The same, y, T.', (-1.0, 1.0)),
    ParameterSpec('mag_bias_z', 0.0, 'The same, z, T.', (-1.0, 1.0)),
) + tuple(_ahrs_spec(name, default) for name, default in AhrsParams.DEFAULTS.items())


def ahrs_params(values):
    """
    Return the core's parameters from the node's ``ahrs.*`` values.

    Parameters
    ----------
    values : dict
        Parameter values by name (the node's).

    Returns
    -------
    params : ext_observer.core.ahrs.AhrsParams

    Raises
    ------
    ValueError
        With the parameter's name and the core's reason.

    """
    given = {name[len(AHRS_PREFIX):]: value for name, value in values.items()
             if name.startswith(AHRS_PREFIX)}
    try:
        return AhrsParams(**given)
    except ValueError as error:
        raise ValueError(f'{AHRS_PREFIX}*: {error}') from None


def raw_imu_settings(values):
    """
    Validate the raw-IMU parameters.

    Parameters
    ----------
    values : dict
        Every parameter of :data:`RAW_IMU_PARAMETERS` by name (and others).

    Raises
    ------
    ValueError
        With the reason.

    """
    if values['world_frame'] not in WORLD_FRAMES:
        raise ValueError(f'world_frame must be one of {tuple(WORLD_FRAMES)}, got '
                         f'{values["world_frame"]!r}')
    ahrs_params(values)


def imu_vectors(msg):
    """
    Return the angular velocity (rad/s) and the specific force (m/s²) of an IMU sample.

    Parameters
    ----------
    msg : sensor_msgs.msg.Imu

    Returns
    -------
    gyr, acc : tuple of 3 float

    """
    return vector_from_msg(msg.angular_velocity), vector_from_msg(msg.linear_acceleration)


class RawImuEstimator:
    """
    The core's raw-IMU estimator as the node runs it: one call per sample or field.

    Parameters
    ----------
    settings : dict
        The node's settings (``ahrs.*``, ``use_mag``, ``world_frame``,
        ``mag_bias_*``, ``divergence_max_residual``).

    Attributes
    ----------
    core : ext_observer.core.ahrs.AhrsObserver
    latest_field : tuple of 3 float or None
        The latest field (T, hard-iron offset removed).

    """

    def __init__(self, settings):
        self.core = AhrsObserver(params=ahrs_params(settings), use_mag=settings['use_mag'])
        self.world_frame = settings['world_frame']
        # The left factor into world_frame; None for ENU, the core's own.
        self._frame = None if self.world_frame == 'enu' else WORLD_FRAMES[self.world_frame]
        self.latest_field = None
        self.configure(settings)

    def configure(self, settings):
        """Take the settings that may change at runtime."""
        self.max_residual = settings['divergence_max_residual']
        self._mag_bias = (settings['mag_bias_x'], settings['mag_bias_y'],
                          settings['mag_bias_z'])

    def field_from_msg(self, msg):
        """Return the field of a ``sensor_msgs/MagneticField``, T, as measured."""
        return vector_from_msg(msg.magnetic_field)

    def field(self, field, dt=None):
        """
        Correct the heading with a field; before the first step, only keep it.

        Parameters
        ----------
        field : sequence of 3 float
            T, as measured (validated by the caller); the hard-iron offset is
            removed here.
        dt : float, optional
            Time since the previous field, s; None (the first field of a time
            line): the IMU's interval.

        """
        bx, by, bz = self._mag_bias
        field = (field[0] - bx, field[1] - by, field[2] - bz)
        self.latest_field = field
        if self.core.q is not None:
            self.core.update_mag(field, dt)

    def step(self, gyr, acc, dt):
        """
        Run one IMU sample.

        Parameters
        ----------
        gyr, acc : sequence of 3 float
            Angular velocity (rad/s) and specific force (m/s²) of the sample
            (:func:`imu_vectors`), validated by the caller (finite, nonzero
            acceleration).
        dt : float
            Time since the previous sample, s.

        Returns
        -------
        state : tuple of 4 float
            The ambient estimate in ``world_frame``, finite.
        reason : str or None
            Why the estimator was reinitialized from this sample
            (:data:`~ext_observer.guard.GUARD_REASONS`), else None.

        """
        core = self.core
        try:
            q = core.update(gyr, acc, self.latest_field if core.q is None else None, dt)
        except (ValueError, OverflowError, ZeroDivisionError):
            reason = 'step_failed'
        else:
            reason = check_state(q, None, self.max_residual)
        if reason is not None:
            core.reset()
            core.update(gyr, acc, self.latest_field, dt)
        return self.state, reason

    @property
    def state(self):
        """The estimate in ``world_frame`` (ambient), or None before the first step."""
        q = self.core.q
        if q is None or self._frame is None:
            return q
        return multiply_floats(self._frame, q)

    def reset(self):
        """Forget the estimate: the next step initializes it again."""
        self.core.reset()

    def key_values(self):
        """
        Return the diagnostic pairs of the estimator.

        ``world_frame``, ``use_mag``, ``initialized``, ``bias_x``, ``bias_y``,
        ``bias_z`` (rad/s), ``rest``, ``mag_disturbed`` and ``residual``
        (``|q̂̄q̂ − 1|``; NaN before the first step).
        """
        core = self.core
        q = core.q
        residual = math.nan if q is None else abs(
            q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3] - 1.0)
        bx, by, bz = core.bias
        return [('world_frame', self.world_frame), ('use_mag', bool(core.use_mag)),
                ('initialized', q is not None), ('bias_x', float(bx)),
                ('bias_y', float(by)), ('bias_z', float(bz)), ('rest', bool(core.rest)),
                ('mag_disturbed', bool(core.mag_disturbed)), ('residual', residual)]
