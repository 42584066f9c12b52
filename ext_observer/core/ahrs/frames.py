"""
The raw-IMU estimator's world frames and first attitude, for callers.

The estimator's arithmetic itself is :mod:`~ext_observer.core.ahrs.ahrs_kernel`
(one source for the plain and the compiled steps); :func:`initial_attitude`
is its first attitude, on floats. Quaternions scalar first,
``(w, x, y, z)``, sensor → world.
"""

import math

import numpy as np

from .ahrs_filters import first_attitude

__all__ = ['WORLD_FRAMES', 'check_dt', 'initial_attitude', 'world_from_enu']

_H = math.sqrt(0.5)
# Left factor C with q_frame = C ⊗ q_enu (C maps ENU coordinates to the frame's).
WORLD_FRAMES = {
    'enu': (1.0, 0.0, 0.0, 0.0),
    'nwu': (_H, 0.0, 0.0, -_H),
    'ned': (0.0, _H, _H, 0.0),
}


def check_dt(dt):
    if not (math.isfinite(dt) and dt > 0.0):
        raise ValueError(f'dt must be positive and finite, got {dt}')


def initial_attitude(acc, mag=None, use_mag=True):
    """
    A first attitude from gravity (and the field's heading), ENU.

    Parameters
    ----------
    acc : sequence of 3 floats
        Specific force, body frame (points up at rest).
    mag : sequence of 3 floats, optional
        Magnetic field, body frame; without it the heading is that of the
        smallest rotation taking the accelerometer's axis to the vertical.
    use_mag : bool
        False: the field is ignored.

    Returns
    -------
    tuple of 4 floats
        Unit quaternion ``(w, x, y, z)``, sensor → ENU.

    """
    ax, ay, az = (float(v) for v in acc)
    mx, my, mz = (0.0, 0.0, 0.0) if mag is None else (float(v) for v in mag)
    return first_attitude(ax, ay, az, mag is not None, mx, my, mz, bool(use_mag))


def world_from_enu(q, frame):
    """
    Express an ENU attitude in another world frame.

    Parameters
    ----------
    q : array_like, shape (..., 4)
    frame : {'enu', 'nwu', 'ned'}

    Returns
    -------
    ndarray, shape (..., 4)

    """
    if frame not in WORLD_FRAMES:
        raise ValueError(f'frame must be one of {tuple(WORLD_FRAMES)}, got {frame!r}')
    from ..quaternion import multiply
    return multiply(np.asarray(WORLD_FRAMES[frame], dtype=float), np.asarray(q, dtype=float))

