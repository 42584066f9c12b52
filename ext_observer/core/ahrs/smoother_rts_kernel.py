"""
The smoothed attitude's loops: an error-state Kalman filter forward, an RTS pass back.

:func:`rts_forward` runs the gyro strapdown at every sample (the nominal
attitude ``q``, the nominal world velocity ``v`` from the specific force)
and, every few samples, one step of a Kalman filter on the nominal's error
``δx = (δθ, δb, δv, δa, δs)``: ``δθ`` the attitude error in the world frame
(``q_true = exp(δθ) ⊗ q``), ``δb`` the gyro bias's (body frame, rad/s),
``δv`` the velocity's (world frame, m/s), ``δa`` the accelerometer bias's
(body frame, m/s²: a body that turns tells it from the tilt), ``δs`` the
gyro's scale factors' (relative, per axis: a body that turns tells them
from the field and the tilt). A tilt error turns gravity into a
growing horizontal velocity, and the velocity of a body that does not
travel far stays small: a weak pseudo-measurement ``v ≈ 0`` (exactly 0 at
rest) makes the accelerometer a measurement of the tilt. The field's
horizontal direction measures the heading. Each step stores what the
backward pass needs (its transition, the predicted and the updated
covariances, the correction it applied); :func:`rts_backward` runs the
Rauch–Tung–Striebel recursion on the error state and :func:`rts_output`
turns the smoothed errors into each sample's attitude and covariance.

The model follows J. Solà, "Quaternion kinematics for the error-state
Kalman filter" (2017, the error-state and its reset) and S. Särkkä,
"Bayesian Filtering and Smoothing" (2013, the RTS smoother); the lines are
ours. Arrays are numpy arrays (also plain); written in the part of Python
numba compiles (:mod:`~ext_observer.core.ahrs.compiled`). Quaternions
``(w, x, y, z)``, sensor → ENU; SI units.
"""

import math

from .ahrs_filters import quat_multiply, rotate

# The error state's size and where each part starts in it.
DIM = 15
# The sums a step keeps to make its transition again (transition()).
SUMS = 21
THETA = 0
BIAS = 3
VEL = 6
ACC_BIAS = 9
SCALE = 12


def theta(k):
    """Where the attitude error's axis ``k`` sits in the error state."""
    return THETA + k


def bias(k):
    """Where the gyro bias's axis ``k`` sits in the error state."""
    return BIAS + k


def vel(k):
    """Where the velocity's axis ``k`` sits in the error state."""
    return VEL + k


def acc_bias(k):
    """Where the accelerometer bias's axis ``k`` sits in the error state."""
    return ACC_BIAS + k


def scale(k):
    """Where the gyro scale factor's axis ``k`` sits in the error state."""
    return SCALE + k


def rotation_rows(w, x, y, z):
    """``R(q)`` of a unit quaternion, row-major, as a 9-tuple (``v_world = R v_body``)."""
    return (1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - w * z), 2.0 * (x * z + w * y),
            2.0 * (x * y + w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - w * x),
            2.0 * (x * z - w * y), 2.0 * (y * z + w * x), 1.0 - 2.0 * (x * x + y * y))


def rotation_quaternion(rx, ry, rz):
    """``exp(r / 2)``: the unit quaternion of the rotation vector ``r`` (rad)."""
    angle = math.sqrt(rx * rx + ry * ry + rz * rz)
    half = 0.5 * angle
    # sin(half) / angle, with its Taylor series near 0.
    k = 0.5 - angle * angle / 48.0 if angle < 1e-4 else math.sin(half) / angle
    return math.cos(half), k * rx, k * ry, k * rz


def unit(w, x, y, z):
    n = math.sqrt(w * w + x * x + y * y + z * z)
    return w / n, x / n, y / n, z / n


def scalar_update(p, dx, h, z, rho):
    """
    One scalar measurement ``z = h·δx + noise(rho)`` into ``(dx, p)`` (updated in place).

    ``h`` an array of DIM; ``p`` the covariance (DIM × DIM), ``dx`` the
    error estimate. Returns the normalized innovation squared.
    """
    ph = [0.0] * DIM
    s = rho
    r = z
    for i in range(DIM):
        acc = 0.0
        for j in range(DIM):
            acc += p[i, j] * h[j]
        ph[i] = acc
        s += h[i] * acc
        r -= h[i] * dx[i]
    for i in range(DIM):
        dx[i] += ph[i] * r / s
    for i in range(DIM):
        for j in range(DIM):
            p[i, j] -= ph[i] * ph[j] / s
    return r * r / s


def transition(phi, sums):
    """
    The transition ``Φ`` of one step (written into ``phi``) from its sums.

    ``sums`` (SUMS): the sum of ``R dt`` over the step (9, row-major), of
    ``R f dt`` (3) and of ``R diag(ω) dt`` (9, row-major).
    """
    for i in range(DIM):
        for j in range(DIM):
            phi[i, j] = 1.0 if i == j else 0.0
    # δθ' = −R (δb + diag(ω) δs); δv' = −[R f]× δθ − R δa (and so ½ [Σ R f dt]× Σ R dt
    # from the gyro bias).
    ax, ay, az = sums[9], sums[10], sums[11]
    cross = (0.0, -az, ay, az, 0.0, -ax, -ay, ax, 0.0)
    for i in range(3):
        for j in range(3):
            phi[theta(i), bias(j)] = -sums[3 * i + j]
            phi[theta(i), scale(j)] = -sums[12 + 3 * i + j]
            # The heading's error left out of the velocity: the velocity is
            # known too loosely to tell the heading, and would spoil it.
            phi[vel(i), theta(j)] = -cross[3 * i + j] if j < 2 else 0.0
            acc = 0.0
            for m in range(3):
                acc += cross[3 * i + m] * sums[3 * m + j]
            phi[vel(i), bias(j)] = 0.5 * acc
            phi[vel(i), acc_bias(j)] = -sums[3 * i + j]


def propagate(p, phi, dt_sum, q_gyr, q_head, q_bias, q_vel, q_acc_bias, out_pred):
    """
    The predicted covariance ``Φ P Φᵀ + Q`` of one step into ``out_pred``.

    ``q_*`` the noise densities (variance per second): ``q_gyr`` the
    tilt's, ``q_head`` the heading's.
    """
    tmp = [0.0] * (DIM * DIM)
    for i in range(DIM):
        for j in range(DIM):
            acc = 0.0
            for m in range(DIM):
                acc += phi[i, m] * p[m, j]
            tmp[DIM * i + j] = acc
    for i in range(DIM):
        for j in range(DIM):
            acc = 0.0
            for m in range(DIM):
                acc += tmp[DIM * i + m] * phi[j, m]
            out_pred[i, j] = acc
    out_pred[theta(2), theta(2)] += q_head * dt_sum
    for i in range(3):
        if i < 2:
            out_pred[theta(i), theta(i)] += q_gyr * dt_sum
        out_pred[bias(i), bias(i)] += q_bias * dt_sum
        out_pred[vel(i), vel(i)] += q_vel * dt_sum
        out_pred[acc_bias(i), acc_bias(i)] += q_acc_bias * dt_sum


def heading_update(p, dx, hx, hy, hz, rho, tilt):
    """
    The field's horizontal direction (world ``h``, nominal attitude) as a heading measurement.

    The true field points north: ``h_x`` of ``exp(δθ) h`` is 0, so
    ``atan2(h_x, h_y) = δθ_z − (h_z / h_y) δθ_y`` (the second term only with
    ``tilt``: the field's dip then also tells the tilt about north).
    """
    hh = math.sqrt(hx * hx + hy * hy)
    if hh <= 0.0:
        return 0.0
    h = [0.0] * DIM
    h[theta(2)] = 1.0
    if tilt:
        h[theta(1)] = -hz / hh
    return scalar_update(p, dx, h, math.atan2(hx, hy), rho)


def rts_forward(gyr, acc, mag, rest, count, dt, use_mag, q0, b0, a0, s0, p0, gravity, opts, qn,
                steps, sums, phi, preds, posts, corrs, nominal):
    """
    The forward filter over a whole recording; returns the number of steps.

    Parameters
    ----------
    gyr, acc, mag : arrays (count, 3)
        rad/s, m/s², the calibrated field (any unit; a NaN row: no field).
    rest : array (count,)
        1.0 where the body is at rest (its velocity is 0).
    count : int
    dt : float
        Sampling interval, s.
    use_mag : bool
    q0 : array (4,)
        First attitude, sensor → ENU.
    b0 : array (3,)
        First gyro bias, rad/s.
    a0 : array (3,)
        First accelerometer bias, m/s².
    s0 : array (3,)
        First gyro scale factors' errors (``ω = (1 − s) ω_gyro − b``).
    p0 : array (DIM, DIM)
        First covariance.
    gravity : float
        The specific force's norm at rest, m/s².
    opts : array
        ``(every, q_gyr, q_bias, q_vel, vel_var, vel_tau, rest_var, mag_var,
        mag_tau, norm_ref, dip_ref, norm_tol, dip_tol, mag_tilt, q_acc_bias,
        q_head)``:
        samples per step, the noise densities (rad²/s, rad²/s³, m²/s³; the
        last m²/s⁵), the
        velocity's pseudo-measurement (m²/s², s) and at rest (m²/s²), the
        heading's (rad², s), the field's references (its norm, its dip as
        ``h_z / |h|``) and tolerances, 1.0 to let the field tell the tilt,
        the accelerometer bias's walk and the heading's noise density (the
        gyro's about the vertical, rad²/s; ``q_gyr`` is the tilt's).
    qn : array (count, 4)
        Out: the nominal attitude after each sample.
    steps : int array (K,)
        Out: each step's sample.
    sums : array (K, SUMS)
        Out: each step's sums (:func:`transition`, from the step before).
    phi : array (DIM, DIM)
        Scratch.
    preds, posts : arrays (K, DIM, DIM)
        Out: each step's predicted and updated covariances.
    corrs : array (K, DIM)
        Out: each step's correction of the nominal.
    nominal : array (K, 9)
        Out: each step's nominal gyro bias, accelerometer bias and gyro
        scale factors' errors, after its correction.

    """
    every = int(opts[0])
    q_gyr, q_bias, q_vel = opts[1], opts[2], opts[3]
    vel_var, vel_tau, rest_var = opts[4], opts[5], opts[6]
    mag_var, mag_tau = opts[7], opts[8]
    norm_ref, dip_ref, norm_tol, dip_tol = opts[9], opts[10], opts[11], opts[12]
    tilt = opts[13] != 0.0
    q_acc_bias = opts[14]
    q_head = opts[15]
    w, x, y, z = q0[0], q0[1], q0[2], q0[3]
    bx, by, bz = b0[0], b0[1], b0[2]
    vx, vy, vz = 0.0, 0.0, 0.0
    ax, ay, az = a0[0], a0[1], a0[2]
    sx, sy, sz = s0[0], s0[1], s0[2]
    sw = [0.0] * 9
    p = posts[0]
    for i in range(DIM):
        for j in range(DIM):
            p[i, j] = p0[i, j]
    sr = [0.0] * 9
    sa = [0.0] * 3
    sh = [0.0] * 3
    h = [0.0] * DIM
    k = 0
    at_rest = True
    n_mag = 0
    s_norm = 0.0
    dt_sum = 0.0
    for n in range(count):
        if n > 0:
            # Strapdown: the gyro of sample n turns the body from n − 1 to n.
            dw, dx_, dy_, dz_ = rotation_quaternion(((1.0 - sx) * gyr[n, 0] - bx) * dt,
                                                    ((1.0 - sy) * gyr[n, 1] - by) * dt,
                                                    ((1.0 - sz) * gyr[n, 2] - bz) * dt)
            w, x, y, z = quat_multiply(w, x, y, z, dw, dx_, dy_, dz_)
            w, x, y, z = unit(w, x, y, z)
            r = rotation_rows(w, x, y, z)
            fx, fy, fz = rotate(w, x, y, z, acc[n, 0] - ax, acc[n, 1] - ay, acc[n, 2] - az)
            vx += fx * dt
            vy += fy * dt
            vz += (fz - gravity) * dt
            for m in range(9):
                sr[m] += r[m] * dt
                sw[m] += r[m] * gyr[n, m % 3] * dt
            sa[0] += fx * dt
            sa[1] += fy * dt
            sa[2] += fz * dt
            dt_sum += dt
        qn[n, 0], qn[n, 1], qn[n, 2], qn[n, 3] = w, x, y, z
        at_rest = at_rest and rest[n] != 0.0
        if use_mag and mag[n, 0] == mag[n, 0]:
            mx, my, mz = rotate(w, x, y, z, mag[n, 0], mag[n, 1], mag[n, 2])
            sh[0] += mx
            sh[1] += my
            sh[2] += mz
            s_norm += math.sqrt(mx * mx + my * my + mz * mz)
            n_mag += 1
        if n > 0 and n % every != 0 and n != count - 1:
            continue
        # One step of the filter at sample n.
        steps[k] = n
        if k > 0:
            for m in range(9):
                sums[k, m] = sr[m]
                sums[k, 12 + m] = sw[m]
            for m in range(3):
                sums[k, 9 + m] = sa[m]
            transition(phi, sums[k])
            propagate(posts[k - 1], phi, dt_sum, q_gyr, q_head, q_bias, q_vel, q_acc_bias,
                      preds[k])
            for i in range(DIM):
                for j in range(DIM):
                    posts[k, i, j] = preds[k, i, j]
        else:
            for i in range(DIM):
                for j in range(DIM):
                    preds[0, i, j] = p0[i, j]
        p = posts[k]
        dx = corrs[k]
        for i in range(DIM):
            dx[i] = 0.0
        span = dt_sum if dt_sum > 0.0 else dt
        # The velocity: 0 at rest, else small (one look per vel_tau).
        for c in range(3):
            for i in range(DIM):
                h[i] = 0.0
            h[vel(c)] = 1.0
            var = rest_var if at_rest else vel_var * vel_tau / span
            scalar_update(p, dx, h, -(vx, vy, vz)[c], var)
        if n_mag > 0:
            hn = math.sqrt(sh[0] * sh[0] + sh[1] * sh[1] + sh[2] * sh[2])
            norm = s_norm / n_mag
            off_norm = (norm / norm_ref - 1.0) / norm_tol
            off_dip = (sh[2] / hn - dip_ref) / dip_tol
            worse = 1.0 + off_norm * off_norm + off_dip * off_dip
            rho = mag_var * mag_tau / span * worse * worse
            heading_update(p, dx, sh[0], sh[1], sh[2], rho, tilt)
        # The reset: the correction moves into the nominal.
        cw, cx, cy, cz = rotation_quaternion(dx[theta(0)], dx[theta(1)], dx[theta(2)])
        w, x, y, z = quat_multiply(cw, cx, cy, cz, w, x, y, z)
        w, x, y, z = unit(w, x, y, z)
        bx += dx[bias(0)]
        by += dx[bias(1)]
        bz += dx[bias(2)]
        vx += dx[vel(0)]
        vy += dx[vel(1)]
        vz += dx[vel(2)]
        ax += dx[acc_bias(0)]
        ay += dx[acc_bias(1)]
        az += dx[acc_bias(2)]
        sx += dx[scale(0)]
        sy += dx[scale(1)]
        sz += dx[scale(2)]
        nominal[k, 0], nominal[k, 1], nominal[k, 2] = bx, by, bz
        nominal[k, 3], nominal[k, 4], nominal[k, 5] = ax, ay, az
        nominal[k, 6], nominal[k, 7], nominal[k, 8] = sx, sy, sz
        k += 1
        for m in range(9):
            sr[m] = 0.0
            sw[m] = 0.0
        sa[0], sa[1], sa[2] = 0.0, 0.0, 0.0
        sh[0], sh[1], sh[2] = 0.0, 0.0, 0.0
        s_norm = 0.0
        n_mag = 0
        dt_sum = 0.0
        at_rest = True
        qn[n, 0], qn[n, 1], qn[n, 2], qn[n, 3] = w, x, y, z
    return k


def cholesky_solve(a, b, out, low):
    """``out = a⁻¹ b`` for a symmetric positive definite ``a`` (DIM × DIM), ``b`` DIM × DIM."""
    for i in range(DIM):
        for j in range(i + 1):
            acc = a[i, j]
            for m in range(j):
                acc -= low[i, m] * low[j, m]
            if i == j:
                low[i, i] = math.sqrt(acc if acc > 0.0 else 1e-300)
            else:
                low[i, j] = acc / low[j, j]
    for c in range(DIM):
        for i in range(DIM):
            acc = b[i, c]
            for m in range(i):
                acc -= low[i, m] * out[m, c]
            out[i, c] = acc / low[i, i]
        for i in range(DIM - 1, -1, -1):
            acc = out[i, c]
            for m in range(i + 1, DIM):
                acc -= low[m, i] * out[m, c]
            out[i, c] = acc / low[i, i]


def rts_backward(k_count, sums, preds, posts, corrs, smooth, phi, m_tmp, x_tmp, low, d_tmp):
    """
    The Rauch–Tung–Striebel recursion on the error state, from the last step back.

    ``smooth[k]`` (out) the smoothed error at step ``k`` from its updated
    nominal; ``posts[k]`` is overwritten with the smoothed covariance. The
    gain ``G = P⁺_k Φᵀ (P⁻_{k+1})⁻¹`` is ``Xᵀ`` with ``P⁻ X = Φ P⁺``.
    """
    last = k_count - 1
    for i in range(DIM):
        smooth[last, i] = 0.0
    e = [0.0] * DIM
    for k in range(last - 1, -1, -1):
        transition(phi, sums[k + 1])
        pred = preds[k + 1]
        post = posts[k]
        for i in range(DIM):
            e[i] = smooth[k + 1, i] + corrs[k + 1, i]
            for j in range(DIM):
                acc = 0.0
                for m in range(DIM):
                    acc += phi[i, m] * post[m, j]
                m_tmp[i, j] = acc
        cholesky_solve(pred, m_tmp, x_tmp, low)
        # x_tmp = Gᵀ: the smoothed error and D = P^s_{k+1} − P⁻_{k+1}.
        for i in range(DIM):
            acc = 0.0
            for m in range(DIM):
                acc += x_tmp[m, i] * e[m]
            smooth[k, i] = acc
            for j in range(DIM):
                d_tmp[i, j] = posts[k + 1, i, j] - pred[i, j]
        # P^s_k = P⁺_k + Gᵀ' D G, with G = x_tmpᵀ.
        for i in range(DIM):
            for j in range(DIM):
                acc = 0.0
                for m in range(DIM):
                    acc += d_tmp[i, m] * x_tmp[m, j]
                m_tmp[i, j] = acc
        for i in range(DIM):
            for j in range(DIM):
                acc = 0.0
                for m in range(DIM):
                    acc += x_tmp[m, i] * m_tmp[m, j]
                post[i, j] += acc


def rts_output(count, k_count, steps, qn, smooth, corrs, posts, q_out, cov_out):
    """
    Each sample's smoothed attitude and its error's covariance (world frame, 3 × 3).

    Between two steps the nominal is the gyro's alone; its error goes from
    the smoothed one after step ``k`` to the one before step ``k + 1``
    (smoothed plus that step's correction), linearly in time, and so does
    the covariance.
    """
    k = 0
    for n in range(count):
        while k < k_count - 1 and steps[k] < n:
            k += 1
        # n in (steps[k − 1], steps[k]]: at a step, the smoothed error of its update.
        if steps[k] == n or k == 0:
            ex = smooth[k, theta(0)]
            ey = smooth[k, theta(1)]
            ez = smooth[k, theta(2)]
            for i in range(3):
                for j in range(3):
                    cov_out[n, i, j] = posts[k, theta(i), theta(j)]
        else:
            a = (n - steps[k - 1]) / (steps[k] - steps[k - 1])
            e0 = smooth[k - 1, theta(0)]
            e1 = smooth[k - 1, theta(1)]
            e2 = smooth[k - 1, theta(2)]
            ex = e0 + a * (smooth[k, theta(0)] + corrs[k, theta(0)] - e0)
            ey = e1 + a * (smooth[k, theta(1)] + corrs[k, theta(1)] - e1)
            ez = e2 + a * (smooth[k, theta(2)] + corrs[k, theta(2)] - e2)
            for i in range(3):
                for j in range(3):
                    c0 = posts[k - 1, theta(i), theta(j)]
                    cov_out[n, i, j] = c0 + a * (posts[k, theta(i), theta(j)] - c0)
        cw, cx, cy, cz = rotation_quaternion(ex, ey, ez)
        w, x, y, z = quat_multiply(cw, cx, cy, cz, qn[n, 0], qn[n, 1], qn[n, 2], qn[n, 3])
        q_out[n, 0], q_out[n, 1], q_out[n, 2], q_out[n, 3] = w, x, y, z
