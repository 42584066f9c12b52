"""
The raw-IMU estimator's arithmetic on Python floats or ``(B,)`` arrays.

:class:`~ext_observer.core.ahrs.AhrsObserver` picks the operations once
(``_FloatOps``: ``math``; ``_ArrayOps``: numpy) and every step is written
once with them. Here too: rotating a vector by a quaternion, the
Butterworth and first-order gains, the first attitude from gravity and the
field, and the world frames (ENU, NWU, NED). Quaternions scalar first,
``(w, x, y, z)``, sensor → world.
"""

import math

import numpy as np

__all__ = ['WORLD_FRAMES', 'initial_attitude', 'world_from_enu']

_H = math.sqrt(0.5)
# Left factor C with q_frame = C ⊗ q_enu (C maps ENU coordinates to the frame's).
WORLD_FRAMES = {
    'enu': (1.0, 0.0, 0.0, 0.0),
    'nwu': (_H, 0.0, 0.0, -_H),
    'ned': (0.0, _H, _H, 0.0),
}


class _FloatOps:
    sqrt = staticmethod(math.sqrt)
    tan = staticmethod(math.tan)
    exp = staticmethod(math.exp)
    atan2 = staticmethod(math.atan2)
    cos = staticmethod(math.cos)
    sin = staticmethod(math.sin)

    @staticmethod
    def where(cond, a, b):
        return a if cond else b

    @staticmethod
    def clip(v, lo, hi):
        return lo if v < lo else hi if v > hi else v

    @staticmethod
    def logical_not(v):
        return not v

    maximum = staticmethod(max)

    @staticmethod
    def zeros(like):
        return 0.0

    @staticmethod
    def full(like, value):
        return float(value)


class _ArrayOps:
    sqrt = staticmethod(np.sqrt)
    tan = staticmethod(np.tan)
    exp = staticmethod(np.exp)
    atan2 = staticmethod(np.arctan2)
    cos = staticmethod(np.cos)
    sin = staticmethod(np.sin)
    where = staticmethod(np.where)
    clip = staticmethod(np.clip)
    logical_not = staticmethod(np.logical_not)
    maximum = staticmethod(np.maximum)

    @staticmethod
    def zeros(like):
        return np.zeros_like(like, dtype=float)

    @staticmethod
    def full(like, value):
        return np.full(np.shape(like), value, dtype=float)


def _rotate(w, x, y, z, vx, vy, vz):
    """``q v q̄ / |q|²``: vector ``v`` rotated by the rotation of ``q ≠ 0``."""
    # v(w² − |u|²) + 2(u·v)u + 2w(u × v), over |q|².
    n2 = w * w + x * x + y * y + z * z
    s = (w * w - x * x - y * y - z * z)
    d = 2.0 * (x * vx + y * vy + z * vz)
    w2 = 2.0 * w
    cx = y * vz - z * vy
    cy = z * vx - x * vz
    cz = x * vy - y * vx
    return ((s * vx + d * x + w2 * cx) / n2,
            (s * vy + d * y + w2 * cy) / n2,
            (s * vz + d * z + w2 * cz) / n2)


def _butterworth(tau, dt, o):
    """Second-order Butterworth low-pass (bilinear, prewarped), cutoff 1/(2π τ)."""
    wc = o.tan(0.5 * dt / tau)
    k = math.sqrt(2.0) * wc
    a0 = 1.0 + k + wc * wc
    b0 = wc * wc / a0
    return (b0, 2.0 * b0, b0, 2.0 * (wc * wc - 1.0) / a0, (1.0 - k + wc * wc) / a0)


def _check_dt(dt):
    if not (math.isfinite(dt) and dt > 0.0):
        raise ValueError(f'dt must be positive and finite, got {dt}')


def _gain(tau, dt, o):
    """Per-sample gain of a first-order filter with time constant ``tau``."""
    return 1.0 - o.exp(-dt / tau)


def initial_attitude(acc, mag=None, ops=_FloatOps, use_mag=True):
    """
    A first attitude from gravity (and the field's heading), ENU.

    Parameters
    ----------
    acc : sequence of 3
        Specific force, body frame (points up at rest).
    mag : sequence of 3, optional
        Magnetic field, body frame; without it the heading is that of the
        smallest rotation taking the accelerometer's axis to the vertical.
    ops : operations (floats or arrays)
    use_mag : bool or ndarray

    Returns
    -------
    tuple of 4
        Unit quaternion ``(w, x, y, z)``, sensor → ENU.

    """
    o = ops
    ax, ay, az = acc
    n = o.sqrt(ax * ax + ay * ay + az * az)
    n = o.where(n > 0.0, n, 1.0)
    ax, ay, az = ax / n, ay / n, az / n
    w, x, y = 1.0 + az, ay, -ax
    d = o.sqrt(w * w + x * x + y * y)
    flip = d < 1e-9
    d = o.where(flip, 1.0, d)
    w, x, y = o.where(flip, 0.0, w / d), o.where(flip, 1.0, x / d), o.where(flip, 0.0, y / d)
    z = 0.0 * w
    if mag is None:
        return (w, x, y, z)
    mx, my, _ = _rotate(w, x, y, z, *mag)
    psi = o.where(use_mag, o.atan2(mx, my), 0.0)
    c, s = o.cos(0.5 * psi), o.sin(0.5 * psi)
    return (c * w - s * z, c * x - s * y, c * y + s * x, c * z + s * w)


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
    from .quaternion import multiply
    return multiply(np.asarray(WORLD_FRAMES[frame], dtype=float), np.asarray(q, dtype=float))

