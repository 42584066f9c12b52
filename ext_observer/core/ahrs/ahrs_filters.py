"""
The arithmetic the raw-IMU estimator's steps share, on floats and the state's arrays.

Rotating a vector by a quaternion, ``R(q̂)``'s rows, a first-order gain
from a time constant, a first attitude from gravity (and the field), and
the second-order Butterworth low-pass whose states are arrays of the state
(the accelerometer's ``inc.lp`` and ``R``'s ``bias.r_lp``), and the kernels'
one quaternion product and deviation from gravity. Plain Python that numba compiles, as
:mod:`~ext_observer.core.ahrs.ahrs_kernel`.
"""

import math

from ..constants import STANDARD_GRAVITY


# Below this |(1 + a_z, a_y, −a_x)| (about the angle, rad, from upside down) the
# half-way rotation is rounding: the first attitude turns half a turn about x instead.
ATTITUDE_FLIP_NORM = 1e-9
# rad²: the variance of an angle uniform on (−π, π] (σ 104°), one known to be nothing better.
UNIFORM_ANGLE_VARIANCE = math.pi * math.pi / 3.0


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


def quat_multiply(aw, ax, ay, az, bw, bx, by, bz):
    """The Hamilton product ``a ⊗ b`` of two quaternions ``(w, x, y, z)``: the kernels' one."""
    return (aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw)


def gravity_deviation(fx, fy, fz):
    """
    How far a world-frame specific force ``f`` (m/s²) is from gravity: a share of g².

    ``max(d_z², (d_x² + d_y²) / 2) / g²`` of its deviation ``d`` from
    ``(0, 0, g)``: one sample's variance per horizontal axis of the vertical
    it shows (a moving body's translational acceleration).
    """
    dz = fz - STANDARD_GRAVITY
    return max(dz * dz, 0.5 * (fx * fx + fy * fy)) / (STANDARD_GRAVITY * STANDARD_GRAVITY)


def clip(v, lo, hi):
    return lo if v < lo else hi if v > hi else v


def gain(tau, dt):
    """Per-sample gain of a first-order filter with time constant ``tau``."""
    return 1.0 - math.exp(-dt / tau)


def first_order_step(v, k, vx, vy, vz):
    """One step of the first-order low-pass (gain ``k``) of the 3-vector ``v`` (updated)."""
    lx, ly, lz = v[0], v[1], v[2]
    lx, ly, lz = lx + k * (vx - lx), ly + k * (vy - ly), lz + k * (vz - lz)
    v[0] = lx
    v[1] = ly
    v[2] = lz
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


def steady(bw, st, i, vx, vy, vz):
    """
    The Butterworth (coefficients ``bw``) steady for a constant ``v``.

    Its states are ``st[i:i+3]`` (s1) and ``st[i+3:i+6]`` (s2).
    """
    b1, b2, a1, a2 = bw[1], bw[2], bw[3], bw[4]
    # Steady state of the transposed direct form II for a constant input.
    st[i + 3] = (b2 - a2) * vx
    st[i + 4] = (b2 - a2) * vy
    st[i + 5] = (b2 - a2) * vz
    st[i] = (b1 - a1) * vx + st[i + 3]
    st[i + 1] = (b1 - a1) * vy + st[i + 4]
    st[i + 2] = (b1 - a1) * vz + st[i + 5]


def lowpass(bw, st, i, vx, vy, vz):
    """One step of the Butterworth (coefficients ``bw``, states ``st[i:i+6]``); its output."""
    b0, b1, b2, a1, a2 = bw[0], bw[1], bw[2], bw[3], bw[4]
    fx, fy, fz = b0 * vx + st[i], b0 * vy + st[i + 1], b0 * vz + st[i + 2]
    st[i] = b1 * vx - a1 * fx + st[i + 3]
    st[i + 1] = b1 * vy - a1 * fy + st[i + 4]
    st[i + 2] = b1 * vz - a1 * fz + st[i + 5]
    st[i + 3] = b2 * vx - a2 * fx
    st[i + 4] = b2 * vy - a2 * fy
    st[i + 5] = b2 * vz - a2 * fz
    return fx, fy, fz


def vertical_in_body(s):
    """The world's vertical in the body frame, ``R(q̂)ᵀ e_z`` (``R``'s third row), ``q̂`` of any nonzero norm."""
    w, x, y, z = s.est.q[0], s.est.q[1], s.est.q[2], s.est.q[3]
    n2 = w * w + x * x + y * y + z * z
    return (2.0 * (x * z - w * y) / n2, 2.0 * (y * z + w * x) / n2,
            (w * w - x * x - y * y + z * z) / n2)


def rotation_matrix(s):
    """The rows of ``R(q̂)`` (sensor → world), ``q̂`` of any nonzero norm."""
    w, x, y, z = s.est.q[0], s.est.q[1], s.est.q[2], s.est.q[3]
    n2 = w * w + x * x + y * y + z * z
    return ((w * w + x * x - y * y - z * z) / n2, 2.0 * (x * y - w * z) / n2,
            2.0 * (x * z + w * y) / n2,
            2.0 * (x * y + w * z) / n2, (w * w - x * x + y * y - z * z) / n2,
            2.0 * (y * z - w * x) / n2,
            2.0 * (x * z - w * y) / n2, 2.0 * (y * z + w * x) / n2,
            (w * w - x * x - y * y + z * z) / n2)

