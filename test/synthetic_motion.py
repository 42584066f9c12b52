"""
Synthetic motion with a known truth for the raw-IMU estimator's tests (no ROS).

:func:`synthetic` gives truth and IMU samples (a rest, then smooth rotation
about changing axes, with a bias, noise, translation and an optional
magnet); :func:`errors_deg` scores an estimate against the truth as BROAD
does. Shared by the estimator's, the calibration's and the covariance's tests.
"""

import math

import numpy as np

from ext_observer.core import quaternion as quat

G = 9.81
# A field of 50 µT pointing north and 60° down (ENU).
FIELD = 50.0 * np.array([0.0, math.cos(math.radians(60)), -math.sin(math.radians(60))])
RATE = 200.0


def rotate(q, v):
    """World coordinates of body vectors ``v`` for unit ``q`` (sensor → world)."""
    v4 = np.concatenate([np.zeros(np.shape(v)[:-1] + (1,)), v], axis=-1)
    return quat.multiply(quat.multiply(q, v4), quat.conjugate(q))[..., 1:]


def synthetic(seconds=60.0, rest=5.0, bias=(0.01, -0.015, 0.008), seed=0,
              accel=0.0, disturb=None):
    """
    Truth and IMU samples: rest, then smooth rotation about changing axes.

    Returns truth (N, 4) and gyr, acc, mag (N, 3); the gyro has a constant
    ``bias`` and small noise, ``accel`` m/s² of oscillating translation, and
    ``disturb = (t0, t1, degrees)`` turns the field by that angle about the
    east axis between t0 and t1 (norm and dip change: a nearby magnet).
    """
    rng = np.random.default_rng(seed)
    n = int(seconds * RATE)
    t = np.arange(n) / RATE
    moving = t >= rest
    omega = np.stack([0.8 * np.sin(0.7 * t), 0.6 * np.cos(0.45 * t + 1.0),
                      0.9 * np.sin(0.3 * t + 2.0)], axis=1) * moving[:, None]
    truth = np.empty((n, 4))
    truth[0] = quat.normalize(np.array([0.9, 0.1, -0.2, 0.3]))
    for k in range(1, n):
        truth[k] = quat.multiply(truth[k - 1], quat.exp(np.r_[0.0, omega[k] / (2 * RATE)]))
    conj = quat.conjugate(truth)
    lin = accel * np.stack([np.sin(6.9 * t), np.cos(5.3 * t), np.sin(8.2 * t)],
                           axis=1) * moving[:, None]
    acc = rotate(conj, np.array([0.0, 0.0, G]) + lin) + rng.normal(0, 0.02, (n, 3))
    field = np.broadcast_to(FIELD, (n, 3)).copy()
    if disturb is not None:
        t0, t1, degrees = disturb
        a = math.radians(degrees)
        rot = np.array([[1, 0, 0], [0, math.cos(a), -math.sin(a)], [0, math.sin(a), math.cos(a)]])
        inside = (t >= t0) & (t < t1)
        field[inside] = 1.5 * field[inside] @ rot.T
    mag = rotate(conj, field) + rng.normal(0, 0.2, (n, 3))
    gyr = omega + np.asarray(bias) + rng.normal(0, 0.002, (n, 3))
    return truth, gyr, acc, mag


def errors_deg(q, truth):
    """Total, heading and inclination error (degrees) as BROAD scores them."""
    d = quat.multiply(quat.normalize(q), quat.conjugate(truth))
    w, z = np.abs(d[..., 0]), d[..., 3]
    total = 2 * np.arccos(np.clip(w, 0, 1))
    heading = 2 * np.arctan(np.abs(z / d[..., 0]))
    incl = 2 * np.arccos(np.clip(np.sqrt(d[..., 0] ** 2 + z ** 2), 0, 1))
    return np.degrees(total), np.degrees(heading), np.degrees(incl)
