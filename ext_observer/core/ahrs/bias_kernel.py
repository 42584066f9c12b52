"""
The gyro bias learned in motion: a Kalman filter on the inclination (and heading) corrections.

A bias error ``β = b − b̂`` turns the estimate by ``R β dt`` per sample; the
corrections take it back through the accelerometer's low-pass, so their
rate measures ``β`` through the low-passed ``R``. VQF's idea (Laidig &
Seel 2023); the formulation and code are ours (docs/raw_imu.md, "Wherever
the robot starts"). Called by :mod:`~ext_observer.core.ahrs.ahrs_kernel`.
"""

from .ahrs_filters import clip, lowpass, rotation_matrix, steady
from .record import Group


# The per-axis variances' places in bias.p (the upper triangle, packed by rows).
BIAS_P_XX = 0
BIAS_P_YY = 3
BIAS_P_ZZ = 5
BIAS_P_DIAGONAL = (BIAS_P_XX, BIAS_P_YY, BIAS_P_ZZ)
BIAS = Group('bias', 'The gyro bias and its Kalman filter in motion', [
    ('rate', 'rad/s', 'the gyro bias estimate, body frame', 3),
    ('p', '(rad/s)²', "the bias's covariance, upper triangle by rows: xx xy xz yy yz zz", 6),
    ('r_lp', '', "Butterworth states of R(q̂)'s rows x, y, z (s1 3, s2 3 each)", 18),
    ('rz_lp', '', "R(q̂)'s z row low-passed by the heading correction", 3),
])

# A correction rate further than 3 σ from what the bias predicts teaches nothing.
_GATE = 9.0


def bias_reset(s):
    """Forget the bias: zero, with its first covariance (a reset of the estimate)."""
    for i in range(3):
        s.bias.rate[i] = 0.0
    bias_forget(s)


def bias_forget(s):
    """Nothing known of the bias beyond its estimate: σ = bias_sigma_init per axis."""
    p0 = s.par.bias_sigma_init * s.par.bias_sigma_init
    s.bias.p[0] = p0
    s.bias.p[1] = 0.0
    s.bias.p[2] = 0.0
    s.bias.p[3] = p0
    s.bias.p[4] = 0.0
    s.bias.p[5] = p0


def rlp_steady(s):
    """The low-passed ``R(q̂)`` steady at the current one."""
    r = rotation_matrix(s)
    for j in range(3):
        steady(s.coef.bw, s.bias.r_lp, 6 * j, r[3 * j], r[3 * j + 1], r[3 * j + 2])


def bias_variance(s, i, j):
    """Element ``(i, j)`` of the bias estimate's covariance, (rad/s)²."""
    a, b = (i, j) if i <= j else (j, i)
    return s.bias.p[(a * (5 - a)) // 2 + b]


def _bias_grow(s):
    """The bias may have wandered: its variance grows, up to bias_sigma_init² per axis."""
    p0 = s.par.bias_sigma_init * s.par.bias_sigma_init
    q = s.coef.bias_q
    for d in BIAS_P_DIAGONAL:
        v = s.bias.p[d] + q
        s.bias.p[d] = v if v < p0 else max(s.bias.p[d], p0)


def bias_measure(s, hx, hy, hz, y, r):
    """
    One scalar measurement ``y = h · (b − b̂) + e``, ``var(e) = r``: the Kalman update.

    ``h`` in the body frame; the estimate is clipped to bias_max per axis;
    an innovation beyond 3 σ is not used.
    """
    p00, p01, p02 = s.bias.p[0], s.bias.p[1], s.bias.p[2]
    p11, p12, p22 = s.bias.p[3], s.bias.p[4], s.bias.p[5]
    ux = p00 * hx + p01 * hy + p02 * hz
    uy = p01 * hx + p11 * hy + p12 * hz
    uz = p02 * hx + p12 * hy + p22 * hz
    den = hx * ux + hy * uy + hz * uz + r
    if y * y > _GATE * den:
        # Not a bias: a correction of an error the model has no room for
        # (a start, a gyro that clipped, an estimate turned by hand).
        return
    kx, ky, kz = ux / den, uy / den, uz / den
    m = s.par.bias_max
    s.bias.rate[0] = clip(s.bias.rate[0] + kx * y, -m, m)
    s.bias.rate[1] = clip(s.bias.rate[1] + ky * y, -m, m)
    s.bias.rate[2] = clip(s.bias.rate[2] + kz * y, -m, m)
    s.bias.p[0] = p00 - kx * ux
    s.bias.p[1] = p01 - kx * uy
    s.bias.p[2] = p02 - kx * uz
    s.bias.p[3] = p11 - ky * uy
    s.bias.p[4] = p12 - ky * uz
    s.bias.p[5] = p22 - kz * uz


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
    hx, hy, hz = lowpass(s.coef.bw, s.bias.r_lp, 0, r[0], r[1], r[2])
    gx, gy, gz = lowpass(s.coef.bw, s.bias.r_lp, 6, r[3], r[4], r[5])
    lowpass(s.coef.bw, s.bias.r_lp, 12, r[6], r[7], r[8])
    _bias_grow(s)
    if s.rest.detected != 0.0 or not settled:
        return
    # Small-angle world rotation vector of r: (2 rx / rw, 2 ry / rw, 0).
    var = s.coef.bias_r / dt
    bias_measure(s, hx, hy, hz, -2.0 * rx / (rw * dt), var)
    bias_measure(s, gx, gy, gz, -2.0 * ry / (rw * dt), var)

