"""
The gyro bias learned in motion: a Kalman filter on the inclination (and heading) corrections.

A bias error ``β = b − b̂`` turns the estimate by ``R β dt`` per sample; the
corrections take it back through the accelerometer's low-pass, so their
rate measures ``β`` through the low-passed ``R``. VQF's idea (Laidig &
Seel 2023); the formulation and code are ours (docs/raw_imu.md, "Wherever
the robot starts"). Called by :mod:`~ext_observer.core.ahrs.ahrs_kernel`.
"""

from .ahrs_filters import clip, lowpass, rotation_matrix, steady
from .ahrs_layout import (BIAS_P_DIAGONAL, C_BIAS_Q, C_BIAS_R, P_BIAS_MAX, P_BIAS_SIGMA_INIT,
                          S_BIAS, S_BIAS_P, S_REST, S_RLP)

# A correction rate further than 3 σ from what the bias predicts teaches nothing.
_GATE = 9.0


def bias_forget(s):
    """Nothing known of the bias beyond its estimate: σ = bias_sigma_init per axis."""
    p0 = s[P_BIAS_SIGMA_INIT] * s[P_BIAS_SIGMA_INIT]
    s[S_BIAS_P] = p0
    s[S_BIAS_P + 1] = 0.0
    s[S_BIAS_P + 2] = 0.0
    s[S_BIAS_P + 3] = p0
    s[S_BIAS_P + 4] = 0.0
    s[S_BIAS_P + 5] = p0


def rlp_steady(s):
    """The low-passed ``R(q̂)`` steady at the current one."""
    r = rotation_matrix(s)
    for j in range(3):
        steady(s, S_RLP + 6 * j, r[3 * j], r[3 * j + 1], r[3 * j + 2])


def bias_variance(s, i, j):
    """Element ``(i, j)`` of the bias estimate's covariance, (rad/s)²."""
    a, b = (i, j) if i <= j else (j, i)
    return s[S_BIAS_P + (a * (5 - a)) // 2 + b]


def _bias_grow(s):
    """The bias may have wandered: its variance grows, up to bias_sigma_init² per axis."""
    p0 = s[P_BIAS_SIGMA_INIT] * s[P_BIAS_SIGMA_INIT]
    q = s[C_BIAS_Q]
    for d in BIAS_P_DIAGONAL:
        v = s[S_BIAS_P + d] + q
        s[S_BIAS_P + d] = v if v < p0 else max(s[S_BIAS_P + d], p0)


def bias_measure(s, hx, hy, hz, y, r):
    """
    One scalar measurement ``y = h · (b − b̂) + e``, ``var(e) = r``: the Kalman update.

    ``h`` in the body frame; the estimate is clipped to bias_max per axis;
    an innovation beyond 3 σ is not used.
    """
    p00, p01, p02 = s[S_BIAS_P], s[S_BIAS_P + 1], s[S_BIAS_P + 2]
    p11, p12, p22 = s[S_BIAS_P + 3], s[S_BIAS_P + 4], s[S_BIAS_P + 5]
    ux = p00 * hx + p01 * hy + p02 * hz
    uy = p01 * hx + p11 * hy + p12 * hz
    uz = p02 * hx + p12 * hy + p22 * hz
    den = hx * ux + hy * uy + hz * uz + r
    if y * y > _GATE * den:
        # Not a bias: a correction of an error the model has no room for
        # (a start, a gyro that clipped, an estimate turned by hand).
        return
    kx, ky, kz = ux / den, uy / den, uz / den
    m = s[P_BIAS_MAX]
    s[S_BIAS] = clip(s[S_BIAS] + kx * y, -m, m)
    s[S_BIAS + 1] = clip(s[S_BIAS + 1] + ky * y, -m, m)
    s[S_BIAS + 2] = clip(s[S_BIAS + 2] + kz * y, -m, m)
    s[S_BIAS_P] = p00 - kx * ux
    s[S_BIAS_P + 1] = p01 - kx * uy
    s[S_BIAS_P + 2] = p02 - kx * uz
    s[S_BIAS_P + 3] = p11 - ky * uy
    s[S_BIAS_P + 4] = p12 - ky * uz
    s[S_BIAS_P + 5] = p22 - kz * uz


def learn_bias(s, rw, rx, ry, dt, settled):
    """
    In motion: the inclination correction ``r`` measures the bias error.

    A bias error ``β = b − b̂`` (body) turns the estimate by ``R β dt``
    (world) per sample; the corrections, which follow the low-passed
    specific force, take it back: their rate averages ``−LP(R) β``, with
    ``LP`` the accelerometer's low-pass. So ``−c/dt`` measures ``β``
    through the low-passed ``R`` (its horizontal rows), with the noise of
    a correction rate. A Kalman filter per sample on the bias, as VQF's
    (Laidig & Seel 2023); rest keeps its own, better measurement. Not
    before the low-pass has ``settled`` from a start.
    """
    r = rotation_matrix(s)
    hx, hy, hz = lowpass(s, S_RLP, r[0], r[1], r[2])
    gx, gy, gz = lowpass(s, S_RLP + 6, r[3], r[4], r[5])
    lowpass(s, S_RLP + 12, r[6], r[7], r[8])
    _bias_grow(s)
    if s[S_REST] != 0.0 or not settled:
        return
    # Small-angle world rotation vector of r: (2 rx / rw, 2 ry / rw, 0).
    var = s[C_BIAS_R] / dt
    bias_measure(s, hx, hy, hz, -2.0 * rx / (rw * dt), var)
    bias_measure(s, gx, gy, gz, -2.0 * ry / (rw * dt), var)

