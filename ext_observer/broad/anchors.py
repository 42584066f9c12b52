"""
The anchors, run on a BROAD recording for comparison only.

VQF and BasicVQF (``vqf``), Madgwick and Mahony (``ahrs``) and Fusion
(``imufusion``); the estimator never calls them. Each runs at the settings
its authors advise: VQF's and BasicVQF's defaults, BROAD's trial-agnostic
best for Madgwick and Mahony, Fusion's README's settings; Fusion also at its
package defaults (:data:`FUSION_DEFAULTS`: no rejection, no gyro range).

Each anchor gets the raw samples (rad/s, m/s², µT; Fusion °/s and g) and
its output is brought to scalar-first ``(w, x, y, z)``, sensor → ENU (the
convention of BROAD's ``opt_quat`` and of our estimator) by a fixed left
factor, checked on the data (see each runner). The packages are imported
only when an anchor runs (requirements-test.txt).
"""

import importlib.util
import math

import numpy as np

from ext_observer.broad.result_keys import ANCHORS, FUSION_DEFAULTS, OFFLINE_VQF
from ext_observer.core.constants import STANDARD_GRAVITY
from ext_observer.core.quaternion import conjugate, multiply

# Packages each anchor needs (PyPI names = import names).
ANCHOR_PACKAGES = {'VQF': 'vqf', 'BasicVQF': 'vqf', OFFLINE_VQF: 'vqf', 'Madgwick': 'ahrs',
                   'Mahony': 'ahrs', 'Fusion': 'imufusion', FUSION_DEFAULTS: 'imufusion'}
# BROAD's trial-agnostic best parameters for Madgwick and Mahony.
MADGWICK_BETA = 0.12
MAHONY_KP = 0.74
MAHONY_KI = 0.0012
# The gyro range of BROAD's sensor (myon aktos-t), rad/s: its files do not
# state it; the recordings reach 1352 °/s, beyond a 1000 °/s range, and
# ±2000 °/s is the widest usual one (and that of Fusion's own example).
BROAD_GYRO_RANGE = math.radians(2000.0)
# Fusion's README, "Algorithm settings": gain 0.5, acceleration and magnetic
# rejection 10°, rejection (recovery trigger) period 5 s (imufusion 1.3's
# rejection_timeout is in seconds); the gyro range is the data's. Its README
# also advises the gyro offset correction (imufusion.Bias) beside the AHRS.
FUSION_README = {'gain': 0.5, 'acceleration_rejection': 10.0, 'magnetic_rejection': 10.0,
                 'rejection_timeout': 5.0}

_H = math.sqrt(0.5)
# Left factors C with q_ENU = C ⊗ q_anchor, for sensor → world outputs.
# NWU (x north, y west, z up) to ENU is a rotation by +90° about the vertical.
NWU_TO_ENU = (_H, 0.0, 0.0, _H)
IDENTITY = (1.0, 0.0, 0.0, 0.0)


def attitude_from_acc_mag(acc, mag=None):
    """
    Return a first attitude, sensor → ENU, from one sample at rest.

    The accelerometer gives the vertical (it reads up at rest), the
    horizontal part of the field gives north. Without ``mag`` the heading is
    arbitrary (the sensor's y axis projected on the horizontal plane points
    north, or its x axis east when y is vertical).

    Parameters
    ----------
    acc : array_like, shape (3,)
    mag : array_like, shape (3,), optional

    Returns
    -------
    ndarray, shape (4,)
        Unit quaternion ``(w, x, y, z)``.

    """
    up = np.asarray(acc, dtype=float)
    up = up / np.linalg.norm(up)
    if mag is not None:
        east = np.cross(np.asarray(mag, dtype=float), up)
    else:
        east = np.cross((0.0, 1.0, 0.0), up)
        if np.linalg.norm(east) < 1e-6:
            east = np.array([1.0, 0.0, 0.0]) - up[0] * up
    east = east / np.linalg.norm(east)
    north = np.cross(up, east)
    # Rows: the world axes in sensor coordinates, so v_world = R v_sensor.
    return _quaternion_from_matrix(np.array([east, north, up]))


def _quaternion_from_matrix(r):
    """Unit quaternion ``(w, x, y, z)`` of a rotation matrix (largest pivot)."""
    trace = r[0, 0] + r[1, 1] + r[2, 2]
    diagonal = (trace, r[0, 0], r[1, 1], r[2, 2])
    pivot = int(np.argmax(diagonal))
    if pivot == 0:
        s = 2.0 * math.sqrt(1.0 + trace)
        q = (0.25 * s, (r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s,
             (r[1, 0] - r[0, 1]) / s)
    elif pivot == 1:
        s = 2.0 * math.sqrt(1.0 + r[0, 0] - r[1, 1] - r[2, 2])
        q = ((r[2, 1] - r[1, 2]) / s, 0.25 * s, (r[0, 1] + r[1, 0]) / s,
             (r[0, 2] + r[2, 0]) / s)
    elif pivot == 2:
        s = 2.0 * math.sqrt(1.0 - r[0, 0] + r[1, 1] - r[2, 2])
        q = ((r[0, 2] - r[2, 0]) / s, (r[0, 1] + r[1, 0]) / s, 0.25 * s,
             (r[1, 2] + r[2, 1]) / s)
    else:
        s = 2.0 * math.sqrt(1.0 - r[0, 0] - r[1, 1] + r[2, 2])
        q = ((r[1, 0] - r[0, 1]) / s, (r[0, 2] + r[2, 0]) / s,
             (r[1, 2] + r[2, 1]) / s, 0.25 * s)
    q = np.array(q)
    q = q / np.linalg.norm(q)
    return q if q[0] >= 0.0 else -q


def _to_enu(q, left):
    """``left ⊗ q``: an anchor's output in ENU, scalar first."""
    return multiply(np.asarray(left, dtype=float), np.asarray(q, dtype=float))


def _run_vqf(gyr, acc, mag, rate, use_mag, basic=False):
    import vqf
    cls = vqf.BasicVQF if basic else vqf.VQF
    out = cls(1.0 / rate).updateBatch(gyr, acc, mag if use_mag else None)
    # VQF: (w, x, y, z), sensor → ENU (its 9D output's x axis points east);
    # checked on BROAD: with left factors identity / NWU→ENU, the 9D total
    # RMSE on 01_undisturbed_slow_rotation_A is 2.0° / 88°, and the
    # conjugate or (x, y, z, w) readings give over 80° of inclination.
    return _to_enu(out['quat9D' if use_mag else 'quat6D'], IDENTITY)


def _run_offline_vqf(gyr, acc, mag, rate, use_mag):
    import vqf
    # offlineVQF: the same output convention as VQF's (above); it takes the
    # whole recording at once.
    out = vqf.offlineVQF(gyr, acc, mag if use_mag else None, 1.0 / rate)
    return _to_enu(out['quat9D' if use_mag else 'quat6D'], IDENTITY)


def _run_madgwick(gyr, acc, mag, rate, use_mag):
    from ahrs.filters import Madgwick
    # ahrs' Madgwick: (w, x, y, z), sensor → NWU (gravity reference +z, the
    # field's horizontal part along +x). Checked on BROAD: with the left
    # factor NWU→ENU the 9D total RMSE on 01_undisturbed_slow_rotation_A
    # is 3.5°, without it 93°. The field is normalized inside (units free).
    # Initialized like BROAD's example, from the first sample (gravity and,
    # in 9D, the field); the library's own 9D start ignores q0, so the loop
    # is run here, one library update per sample.
    f = Madgwick(frequency=rate, gain=MADGWICK_BETA)
    q0 = attitude_from_acc_mag(acc[0], mag[0] if use_mag else None)
    q = np.empty((len(gyr), 4))
    q[0] = multiply(conjugate(np.asarray(NWU_TO_ENU)), q0)
    _run_ahrs_filter(f, q, gyr, acc, mag, use_mag)
    return _to_enu(q, NWU_TO_ENU)


def _run_ahrs_filter(f, q, gyr, acc, mag, use_mag):
    """One ``ahrs`` update per sample from ``q[0]`` on (MARG in 9D, IMU in 6D)."""
    if use_mag:
        for k in range(1, len(gyr)):
            q[k] = f.updateMARG(q[k - 1], gyr[k], acc[k], mag[k])
    else:
        for k in range(1, len(gyr)):
            q[k] = f.updateIMU(q[k - 1], gyr[k], acc[k])


def _run_mahony(gyr, acc, mag, rate, use_mag):
    from ahrs.filters import Mahony
    # ahrs' Mahony: (w, x, y, z), sensor → ENU (gravity reference +z, the
    # field's horizontal part along +y). Checked on BROAD: identity left
    # factor gives 5.3° 9D total RMSE on the first 70 s of
    # 01_undisturbed_slow_rotation_A, NWU→ENU 95°. Field normalized inside.
    f = Mahony(frequency=rate, k_P=MAHONY_KP, k_I=MAHONY_KI)
    q = np.empty((len(gyr), 4))
    q[0] = attitude_from_acc_mag(acc[0], mag[0] if use_mag else None)
    _run_ahrs_filter(f, q, gyr, acc, mag, use_mag)
    return _to_enu(q, IDENTITY)


def fusion_settings(rate, gyro_range=BROAD_GYRO_RANGE, readme=True):
    """
    Return the keyword arguments of Fusion's ``AhrsSettings`` for a recording.

    Parameters
    ----------
    rate : float
        Hz.
    gyro_range : float
        The range of the gyro that recorded the data, rad/s (given to
        Fusion in °/s: beyond 98 % of it Fusion restarts, as after clipping).
    readme : bool
        The settings of Fusion's README (:data:`FUSION_README`), else the
        package defaults (no rejection, no gyro range), only the rate set.

    """
    if not readme:
        return {'sample_rate': rate}
    return dict(FUSION_README, sample_rate=rate, gyroscope_range=math.degrees(gyro_range))


def _run_fusion(gyr, acc, mag, rate, use_mag, gyro_range=BROAD_GYRO_RANGE, readme=True):
    import imufusion
    # Fusion: gyro in °/s, specific force in g, field in any unit; output
    # (w, x, y, z), sensor → NWU, its default convention (imufusion 1.3's
    # AhrsSettings ignores a convention given to its constructor, so the
    # default is kept and converted here). Checked on BROAD: with NWU→ENU
    # the 9D total RMSE on 01_undisturbed_slow_rotation_A is 3.3°, without
    # it 93°; the 6D inclination is 0.7°.
    f = imufusion.Ahrs()
    f.set_settings(imufusion.AhrsSettings(**fusion_settings(rate, gyro_range, readme)))
    f.set_sample_period(1.0 / rate)
    gyr_deg = np.degrees(gyr)
    if readme:  # the README's gyro offset correction, at its package settings
        bias = imufusion.Bias()
        bias.set_settings(imufusion.BiasSettings(sample_rate=rate))
        gyr_deg = np.array([bias.update(g) for g in gyr_deg]).reshape(gyr_deg.shape)
    acc_g = acc / STANDARD_GRAVITY  # Fusion takes the specific force in g
    q = np.empty((len(gyr), 4))
    if use_mag:
        for k in range(len(gyr)):
            f.update(gyr_deg[k], acc_g[k], mag[k])
            q[k] = f.get_quaternion()
    else:
        for k in range(len(gyr)):
            f.update_no_magnetometer(gyr_deg[k], acc_g[k])
            q[k] = f.get_quaternion()
    return _to_enu(q, NWU_TO_ENU)


# Runners of (gyr, acc, mag, rate, use_mag, gyro_range); only Fusion reads the range.
_RUNNERS = {
    'VQF': lambda *a: _run_vqf(*a[:5], basic=False),
    'BasicVQF': lambda *a: _run_vqf(*a[:5], basic=True),
    OFFLINE_VQF: lambda *a: _run_offline_vqf(*a[:5]),
    'Madgwick': lambda *a: _run_madgwick(*a[:5]),
    'Mahony': lambda *a: _run_mahony(*a[:5]),
    'Fusion': lambda *a: _run_fusion(*a, readme=True),
    FUSION_DEFAULTS: lambda *a: _run_fusion(*a, readme=False),
}


def anchor_estimates(anchor, gyr, acc, mag, rate, use_mag, gyro_range=BROAD_GYRO_RANGE):
    """
    Run one anchor on one recording; return its estimate, sensor → ENU.

    Parameters
    ----------
    anchor : str
        One of :data:`ANCHORS`.
    gyr, acc, mag : ndarray, shape (N, 3)
        rad/s, m/s², field (µT).
    rate : float
        Hz.
    use_mag : bool
        9D where true, 6D otherwise.
    gyro_range : float
        The range of the gyro that recorded the data, rad/s (default
        BROAD's sensor's, :data:`BROAD_GYRO_RANGE`); Fusion is told it.

    Returns
    -------
    ndarray, shape (N, 4)
        ``(w, x, y, z)``, sensor → ENU.

    """
    if anchor not in _RUNNERS:
        raise ValueError(f'anchor must be one of {ANCHORS}, got {anchor!r}')
    c = np.ascontiguousarray
    return _RUNNERS[anchor](c(gyr, dtype=float), c(acc, dtype=float),
                            c(mag, dtype=float), float(rate), bool(use_mag),
                            float(gyro_range))


def missing_anchor_packages():
    """Return the anchor packages that cannot be imported."""
    return sorted({p for p in ANCHOR_PACKAGES.values()
                   if importlib.util.find_spec(p) is None})
