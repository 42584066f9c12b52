"""
The arithmetic the raw-IMU estimator's steps share, on floats and its flat state.

Rotating a vector by a quaternion, ``R(q̂)``'s rows, a first-order gain
from a time constant, a first attitude from gravity (and the field), and
the second-order Butterworth low-pass whose states live in the flat state
(the accelerometer's and ``R``'s). Plain Python that numba compiles, as
:mod:`~ext_observer.core.ahrs.ahrs_kernel`.
"""

import math

from .ahrs_layout import C_BW, S_Q

# Below this |(1 + a_z, a_y, −a_x)| (about the angle, rad, from upside down) the
# half-way rotation is rounding: the first attitude turns half a turn about x instead.
ATTITUDE_FLIP_NORM = 1e-9


def rotate(w, x, y, z, vx, vy, vz):
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


def clip(v, lo, hi):
    return lo if v < lo else hi if v > hi else v


def gain(tau, dt):
    """Per-sample gain of a first-order filter with time constant ``tau``."""
    return 1.0 - math.exp(-dt / tau)


def first_order_step(s, i, k, vx, vy, vz):
    """One step of the first-order low-pass (gain ``k``) of a 3-vector kept at ``s[i:i+3]``."""
    lx, ly, lz = s[i], s[i + 1], s[i + 2]
    lx, ly, lz = lx + k * (vx - lx), ly + k * (vy - ly), lz + k * (vz - lz)
    s[i] = lx
    s[i + 1] = ly
    s[i + 2] = lz
    return lx, ly, lz


def first_attitude(ax, ay, az, has_mag, mx, my, mz, use_mag):
    """
    A first attitude from gravity (and the field's heading), ENU: a unit quaternion.

    Without a field (``has_mag`` 0) the heading is that of the smallest
    rotation taking the accelerometer's axis to the vertical.
    """
    n = math.sqrt(ax * ax + ay * ay + az * az)
    n = n if n > 0.0 else 1.0
    ax, ay, az = ax / n, ay / n, az / n
    w, x, y = 1.0 + az, ay, -ax
    d = math.sqrt(w * w + x * x + y * y)
    flip = d < ATTITUDE_FLIP_NORM
    d = 1.0 if flip else d
    w, x, y = (0.0, 1.0, 0.0) if flip else (w / d, x / d, y / d)
    z = 0.0 * w
    if not has_mag:
        return w, x, y, z
    hx, hy, _ = rotate(w, x, y, z, mx, my, mz)
    psi = math.atan2(hx, hy) if use_mag else 0.0
    c, s = math.cos(0.5 * psi), math.sin(0.5 * psi)
    return c * w - s * z, c * x - s * y, c * y + s * x, c * z + s * w


def steady(s, i, vx, vy, vz):
    """The Butterworth states at ``s[i:i+3]``, ``s[i+3:i+6]`` steady for a constant ``v``."""
    b1, b2, a1, a2 = s[C_BW + 1], s[C_BW + 2], s[C_BW + 3], s[C_BW + 4]
    # Steady state of the transposed direct form II for a constant input.
    s[i + 3] = (b2 - a2) * vx
    s[i + 4] = (b2 - a2) * vy
    s[i + 5] = (b2 - a2) * vz
    s[i] = (b1 - a1) * vx + s[i + 3]
    s[i + 1] = (b1 - a1) * vy + s[i + 4]
    s[i + 2] = (b1 - a1) * vz + s[i + 5]


def lowpass(s, i, vx, vy, vz):
    """One step of the Butterworth whose states are at ``s[i:i+6]``; its output."""
    b0, b1, b2, a1, a2 = s[C_BW], s[C_BW + 1], s[C_BW + 2], s[C_BW + 3], s[C_BW + 4]
    fx, fy, fz = b0 * vx + s[i], b0 * vy + s[i + 1], b0 * vz + s[i + 2]
    s[i] = b1 * vx - a1 * fx + s[i + 3]
    s[i + 1] = b1 * vy - a1 * fy + s[i + 4]
    s[i + 2] = b1 * vz - a1 * fz + s[i + 5]
    s[i + 3] = b2 * vx - a2 * fx
    s[i + 4] = b2 * vy - a2 * fy
    s[i + 5] = b2 * vz - a2 * fz
    return fx, fy, fz


def rotation_matrix(s):
    """The rows of ``R(q̂)`` (sensor → world), ``q̂`` of any nonzero norm."""
    w, x, y, z = s[S_Q], s[S_Q + 1], s[S_Q + 2], s[S_Q + 3]
    n2 = w * w + x * x + y * y + z * z
    return ((w * w + x * x - y * y - z * z) / n2, 2.0 * (x * y - w * z) / n2,
            2.0 * (x * z + w * y) / n2,
            2.0 * (x * y + w * z) / n2, (w * w - x * x + y * y - z * z) / n2,
            2.0 * (y * z - w * x) / n2,
            2.0 * (x * z - w * y) / n2, 2.0 * (y * z + w * x) / n2,
            (w * w - x * x - y * y + z * z) / n2)

