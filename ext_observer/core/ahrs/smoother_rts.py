"""
Each sample's attitude from the whole recording: :func:`smooth_attitude_rts`.

A fixed-interval smoother: an error-state Kalman filter runs forward over
the recording (the gyro strapdown at every sample, a filter step every
``update_interval`` s), then a Rauch–Tung–Striebel pass runs back
(:mod:`~ext_observer.core.ahrs.smoother_rts_kernel`: the model, the
equations, the sources). The accelerometer tells the tilt through the
velocity it integrates to (small for a body that does not travel far, zero
at rest); the magnetometer, calibrated with what a first online pass
learned (:class:`~ext_observer.core.ahrs.ahrs_observer.AhrsObserver`) and
applied from the first sample, tells the heading, less where its norm or
dip depart from the recording's. The smoothed covariance of the attitude
error is returned beside the attitude. Quaternions ``(w, x, y, z)``,
sensor → ENU, the first attitude's conventions as the online estimator's;
SI units (the field in any unit).
"""

import math

import numpy as np

from ext_observer.core.ahrs.ahrs_filters import first_attitude
from ext_observer.core.ahrs.compiled import kernels

__all__ = ['SMOOTHER_DEFAULTS', 'smooth_attitude_rts']

# The smoother's settings: name → (default, unit, meaning).
SMOOTHER_DEFAULTS = {
    'update_interval': (0.01, 's', 'time between two steps of the filter (the strapdown runs '
                        'at every sample)'),
    'gyro_noise': (0.01, 'rad/s/√Hz', "the tilt's noise density (the gyro's white noise and "
                   'what the model leaves out)'),
    'heading_noise': (0.003, 'rad/s/√Hz', "the heading's noise density (the gyro's about the "
                      'vertical)'),
    'bias_walk': (2e-5, 'rad/s/√s', "the gyro bias's random walk"),
    'acc_noise': (0.05, 'm/s²/√Hz', "the specific force's white noise density"),
    'velocity_sigma': (1.0, 'm/s', "the body's velocity, once per velocity_tau"),
    'velocity_tau': (2.0, 's', 'the time over which the velocity stays alike'),
    'rest_sigma': (0.01, 'm/s', 'the velocity at rest, per step'),
    'rest_window': (0.3, 's', 'the window whose gyro and accelerometer say rest'),
    'rest_gyro': (0.03, 'rad/s', "the gyro's standard deviation below which the body rests"),
    'rest_acc': (0.2, 'm/s²', "the accelerometer's standard deviation below which it rests"),
    'mag_sigma': (0.2, 'rad', "the field's heading, once per mag_tau"),
    'mag_tau': (1.0, 's', "the time over which the field's error stays alike"),
    'mag_norm_tol': (0.2, '1', "the field's norm's relative departure that doubles its σ"),
    'mag_dip_tol': (0.1, '1', "the field's dip's departure (its sine) that doubles its σ"),
    'mag_tilt': (0.0, '1', '1: the field also tells the tilt about north (its dip)'),
    'start_tilt': (0.1, 'rad', "the first attitude's tilt, σ"),
    'start_heading': (0.5, 'rad', "the first attitude's heading, σ"),
    'start_bias': (0.01, 'rad/s', "the first gyro bias's σ per axis"),
    'start_acc_bias': (0.0, 'm/s²', "the accelerometer bias's σ per axis (0: none)"),
    'acc_bias_walk': (1e-4, 'm/s²/√s', "the accelerometer bias's random walk"),
    'delay': (0.0, 's', "how late the IMU's samples come after the motion they measure "
              '(its filters, its clock): each sample gets the attitude this much after it'),
    'start_scale': (0.003, '1', "the gyro's scale factors' σ per axis (relative; 0: none)"),
}


def _settings(params):
    values = {name: row[0] for name, row in SMOOTHER_DEFAULTS.items()}
    unknown = set(params or {}) - set(values)
    if unknown:
        raise ValueError(f'unknown smoother settings {sorted(unknown)}; known: '
                         f'{sorted(values)}')
    values.update(params or {})
    for name, value in values.items():
        if not (math.isfinite(value) and value >= 0.0):
            raise ValueError(f'smoother setting {name} must be finite and >= 0, got {value}')
    for name in ('update_interval', 'velocity_sigma', 'velocity_tau', 'rest_sigma',
                 'mag_sigma', 'mag_tau', 'mag_norm_tol', 'mag_dip_tol', 'start_tilt',
                 'start_heading', 'start_bias'):
        if values[name] <= 0.0:
            raise ValueError(f'smoother setting {name} must be > 0, got {values[name]}')
    return values


def _vectors(a, name, count=None):
    a = np.ascontiguousarray(a, dtype=float)
    if a.ndim != 2 or a.shape[1] != 3 or (count is not None and len(a) != count):
        rows = 'N' if count is None else count
        raise ValueError(f'expected {name} of shape ({rows}, 3), got {a.shape}')
    return a


def _moving_std(a, width):
    """Each sample's standard deviation (largest axis) over a window centred on it."""
    count = len(a)
    half = width // 2
    c1 = np.vstack([np.zeros((1, 3)), np.cumsum(a, axis=0)])
    c2 = np.vstack([np.zeros((1, 3)), np.cumsum(a * a, axis=0)])
    lo = np.clip(np.arange(count) - half, 0, count)
    hi = np.clip(np.arange(count) + half + 1, 0, count)
    n = (hi - lo)[:, None]
    mean = (c1[hi] - c1[lo]) / n
    var = (c2[hi] - c2[lo]) / n - mean * mean
    return np.sqrt(np.max(np.maximum(var, 0.0), axis=1))


def rest_flags(gyr, acc, rate, settings):
    """1.0 where the gyro and the accelerometer are still over ``rest_window``, else 0.0."""
    width = max(1, int(round(settings['rest_window'] * rate)))
    still = ((_moving_std(gyr, width) < settings['rest_gyro'])
             & (_moving_std(acc, width) < settings['rest_acc']))
    return still.astype(float)


def online_calibration(gyr, acc, mag, rate):
    """
    The magnetometer calibration a first online pass learns over the whole recording.

    Returns
    -------
    bias : ndarray (3,) or None
        Hard-iron offset ``b`` of ``y = S m + b`` (None: the online pass did
        not apply one).
    soft_iron : ndarray (3, 3) or None
    gyro_bias : ndarray (3,)
        The online estimate's gyro bias at the end, rad/s.
    lag : float
        The field's lag behind the gyro the calibration learned, s (0 if it
        did not converge).

    """
    from ext_observer.core.ahrs.ahrs_observer import AhrsObserver
    observer = AhrsObserver(use_mag=True)
    observer.run(gyr, acc, mag, 1.0 / rate)
    gyro_bias = np.asarray(observer.bias, dtype=float)
    cal = observer.calibration
    lag = float(cal.delay) if cal is not None and cal.state in ('converged', 'loaded') else 0.0
    # What the online estimator itself would apply: a learned calibration
    # that turns the heading by less than its deadband is left out.
    if cal is None or not cal.applied:
        return None, None, gyro_bias, lag
    return (np.asarray(cal.bias, dtype=float), np.asarray(cal.soft_iron, dtype=float), gyro_bias,
            lag)


def calibrated_field(mag, bias, soft_iron):
    """``S⁻¹ (y − b)``: the field in the sensor's frame, the calibration undone."""
    if bias is None:
        return mag
    return np.linalg.solve(soft_iron, (mag - bias).T).T


def _field_on_time(mag, samples):
    """The field ``samples`` (a float) after each sample, linearly between two."""
    count = len(mag)
    at = np.clip(np.arange(count) + samples, 0.0, count - 1.0)
    return np.stack([np.interp(at, np.arange(count), mag[:, i]) for i in range(3)], axis=1)


def _later(q, samples):
    """The attitude ``samples`` (a float) after each one, between two samples linearly."""
    count = len(q)
    at = np.minimum(np.arange(count) + samples, count - 1)
    lo = np.minimum(at.astype(np.int64), count - 2)
    f = (at - lo)[:, None]
    later = (1.0 - f) * q[lo] + f * q[lo + 1]
    return later / np.linalg.norm(later, axis=1, keepdims=True)


def smooth_attitude_rts(gyr, acc, mag, rate, params=None, calibration=None, compiled=None,
                        details=False):
    """
    Each sample's attitude and its covariance from the whole recording.

    Parameters
    ----------
    gyr : array_like, shape (N, 3)
        Angular velocity, rad/s, sensor frame.
    acc : array_like, shape (N, 3)
        Specific force, m/s² (up at rest).
    mag : array_like, shape (N, 3) or None
        Magnetic field, any unit (None: 6D, the heading from the gyro
        alone); a row of NaN: no field at that sample.
    rate : float
        Sampling rate, Hz.
    params : dict, optional
        Settings of :data:`SMOOTHER_DEFAULTS` to change.
    calibration : tuple, optional
        ``(b, S)`` of ``y = S m + b`` for the field, or ``(b, S, lag)`` with
        the field's lag behind the gyro (s), taken out; default: the
        calibration a first online pass over the recording learns, applied
        from the first sample where the online estimator applied it (its
        lag is not taken out: docs/broad_tuning.md, "The
        Rauch–Tung–Striebel smoother").
    compiled : bool, optional
        As :func:`~ext_observer.core.ahrs.compiled.kernels` (the same
        results either way).
    details : bool
        Also return what else the smoother estimated.

    Returns
    -------
    q : ndarray, shape (N, 4)
        Unit quaternions ``(w, x, y, z)``, sensor → ENU.
    cov : ndarray, shape (N, 3, 3)
        Covariance of the attitude error (rad², world frame ENU:
        ``q_true = exp(δθ) ⊗ q``): ``cov[:, 2, 2]`` the heading's, the
        upper-left block the tilt's.
    details : dict
        Only with ``details``: at each filter step (``steps``, the sample
        indices), the smoothed ``gyro_bias`` (rad/s), ``acc_bias`` (m/s²)
        and ``gyro_scale`` (relative errors: ``ω = (1 − s) ω_gyro − b``),
        each of shape (K, 3).

    """
    settings = _settings(params)
    gyr = _vectors(gyr, 'gyr')
    count = len(gyr)
    acc = _vectors(acc, 'acc', count)
    if count < 2:
        raise ValueError(f'at least 2 samples are needed, got {count}')
    if not (math.isfinite(rate) and rate > 0.0):
        raise ValueError(f'rate must be positive, got {rate}')
    if not (np.all(np.isfinite(gyr)) and np.all(np.isfinite(acc))):
        raise ValueError('gyr and acc must be finite (a hole: drop its rows and give times)')
    dt = 1.0 / rate
    use_mag = mag is not None
    rest = rest_flags(gyr, acc, rate, settings)
    gyro_bias = np.mean(gyr[rest != 0.0], axis=0) if np.any(rest) else np.zeros(3)
    if use_mag:
        mag = _vectors(mag, 'mag', count)
        if calibration is None:
            b, s, _, _ = online_calibration(gyr, acc, mag, rate)
            lag = 0.0
        else:
            b, s = (np.asarray(c, dtype=float) for c in calibration[:2])
            lag = float(calibration[2]) if len(calibration) > 2 else 0.0
        field = calibrated_field(mag, b, s)
        if lag != 0.0:
            field = _field_on_time(field, lag * rate)
        field = np.ascontiguousarray(field)
    else:
        field = np.zeros((count, 3))
    norms = np.linalg.norm(field, axis=1)
    have = np.isfinite(norms) & (norms > 0.0)
    if use_mag and not np.any(have):
        raise ValueError('no finite, nonzero field in mag')
    norm_ref, dip_ref = 1.0, 0.0
    if use_mag:
        norm_ref = float(np.median(norms[have]))
        up = acc[have] / np.linalg.norm(acc[have], axis=1)[:, None]
        dip_ref = float(np.median(np.sum(field[have] * up, axis=1) / norms[have]))
    gravity = float(np.median(np.linalg.norm(acc, axis=1)))
    first = int(np.argmax(have)) if use_mag else 0
    q0 = np.array(first_attitude(acc[0, 0], acc[0, 1], acc[0, 2], use_mag, field[first, 0],
                                 field[first, 1], field[first, 2], use_mag))
    p0 = np.diag([settings['start_tilt'] ** 2] * 2 + [settings['start_heading'] ** 2]
                 + [settings['start_bias'] ** 2] * 3 + [settings['velocity_sigma'] ** 2] * 3
                 # A tiny σ for none keeps the covariance positive definite.
                 + [max(settings['start_acc_bias'], 1e-9) ** 2] * 3
                 + [max(settings['start_scale'], 1e-9) ** 2] * 3)
    every = max(1, int(round(settings['update_interval'] * rate)))
    opts = np.array([every, settings['gyro_noise'] ** 2, settings['bias_walk'] ** 2,
                     settings['acc_noise'] ** 2, settings['velocity_sigma'] ** 2,
                     settings['velocity_tau'], settings['rest_sigma'] ** 2,
                     settings['mag_sigma'] ** 2, settings['mag_tau'], norm_ref, dip_ref,
                     settings['mag_norm_tol'], settings['mag_dip_tol'], settings['mag_tilt'],
                     settings['acc_bias_walk'] ** 2, settings['heading_noise'] ** 2])
    k = kernels(compiled).smoother_rts
    dim = k.DIM
    steps_max = (count - 1) // every + 2
    qn = np.empty((count, 4))
    steps = np.zeros(steps_max, dtype=np.int64)
    sums = np.zeros((steps_max, k.SUMS))
    phi = np.empty((dim, dim))
    preds = np.empty((steps_max, dim, dim))
    posts = np.empty((steps_max, dim, dim))
    corrs = np.empty((steps_max, dim))
    nominal = np.empty((steps_max, 9))
    used = k.rts_forward(gyr, acc, field, rest, count, dt, use_mag, q0, gyro_bias, np.zeros(3),
                         np.zeros(3), p0, gravity, opts, qn, steps, sums, phi, preds, posts,
                         corrs, nominal)
    del field
    smooth = np.empty((used, dim))
    k.rts_backward(used, sums, preds, posts, corrs, smooth, phi, np.empty((dim, dim)),
                   np.empty((dim, dim)), np.zeros((dim, dim)), np.empty((dim, dim)))
    del sums, preds
    q = np.empty((count, 4))
    cov = np.empty((count, 3, 3))
    k.rts_output(count, used, steps, qn, smooth, corrs, posts, q, cov)
    if settings['delay'] > 0.0:
        q = _later(q, settings['delay'] * rate)
    if not details:
        return q, cov
    parts = {name: nominal[:used, 3 * i:3 * i + 3] + smooth[:, at:at + 3]
             for i, (name, at) in enumerate((('gyro_bias', k.BIAS), ('acc_bias', k.ACC_BIAS),
                                             ('gyro_scale', k.SCALE)))}
    return q, cov, {'steps': steps[:used].copy(), **parts}
