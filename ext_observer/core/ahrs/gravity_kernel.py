"""
The accelerometer's step of the raw-IMU estimator: the inclination from the specific force.

The specific force is rotated into the world frame with the estimate,
low-passed there (a running mean after a start, a clipped stretch or a
hole: :mod:`~ext_observer.core.ahrs.hole_kernel`), and the estimate turned
towards the direction that makes it vertical (docs/raw_imu.md, "The
estimator, step by step"). A hole's step stands for the usual steps it
missed: the low-pass and the correction advance by all of them. Plain
Python that numba compiles, as :mod:`~ext_observer.core.ahrs.ahrs_kernel`
(which calls it).
"""

from .accel_rejection import acc_rotation
from .ahrs_filters import first_order_step, rotate, steady
from .ahrs_layout import (C_BW, C_DT, C_K_ACC, C_K_REST, P_ACC_REJECT, P_MOTION_BIAS, P_REST_ACC,
                          P_TAU_ACC, S_ACC_REJ, S_ACC_STILL, S_INC_SIGMA, S_LP, S_Q, S_REST_ACC,
                          S_START, S_START_N, S_STEPS)
from .bias_kernel import learn_bias, rlp_steady
from .hole_kernel import RECOVERING, acc_deviation
from .velocity_kernel import velocity_removed


def ahrs_update_acc(s, ax, ay, az):
    """Correct the inclination from the world-frame filtered specific force."""
    # Rest detection needs the accelerometer's deviation from its mean.
    rx, ry, rz = first_order_step(s, S_REST_ACC, s[C_K_REST], ax, ay, az)
    ex, ey, ez = ax - rx, ay - ry, az - rz
    s[S_ACC_STILL] = 1.0 if (ex * ex + ey * ey + ez * ez) < s[P_REST_ACC] * s[P_REST_ACC] else 0.0
    # Gravity from the specific force less the body's own acceleration (rest sees it all).
    ax, ay, az = velocity_removed(s, ax, ay, az)

    w, x, y, z = s[S_Q], s[S_Q + 1], s[S_Q + 2], s[S_Q + 3]
    vx, vy, vz = rotate(w, x, y, z, ax, ay, az)
    dt = s[C_DT]
    acc_deviation(s, vx, vy, vz, dt)
    starting = s[S_START] < s[P_TAU_ACC]
    if starting:
        # The first tau_acc seconds (from the start, or after a clipped
        # gyro): the running mean of the world-frame specific force, which
        # a low-pass started on one sample of a moving body would only
        # approach at its own pace (VQF starts its low-pass so too).
        n = s[S_START_N] + 1.0
        s[S_START_N] = n
        fx = s[S_LP] + (vx - s[S_LP]) / n
        fy = s[S_LP + 1] + (vy - s[S_LP + 1]) / n
        fz = s[S_LP + 2] + (vz - s[S_LP + 2]) / n
        s1x, s1y, s1z = fx, fy, fz
        s2x, s2y, s2z = 0.0, 0.0, 0.0
        s[S_START] += dt
    else:
        b0, b1, b2, a1, a2 = s[C_BW], s[C_BW + 1], s[C_BW + 2], s[C_BW + 3], s[C_BW + 4]
        s1x, s1y, s1z = s[S_LP], s[S_LP + 1], s[S_LP + 2]
        s2x, s2y, s2z = s[S_LP + 3], s[S_LP + 4], s[S_LP + 5]
        # A hole's sample stands for the steps lost too (held across them).
        for _ in range(max(int(s[S_STEPS] + 0.5), 1)):
            fx, fy, fz = b0 * vx + s1x, b0 * vy + s1y, b0 * vz + s1z
            s1x, s1y, s1z = (b1 * vx - a1 * fx + s2x, b1 * vy - a1 * fy + s2y,
                             b1 * vz - a1 * fz + s2z)
            s2x, s2y, s2z = b2 * vx - a2 * fx, b2 * vy - a2 * fy, b2 * vz - a2 * fz

    # δ: the rotation taking f/|f| (or, f rejected, the gyro's vertical) to
    # the vertical, [1 + u_z, u_y, −u_x, 0] (|δ| = 0 only shrinks q̂).
    # (No rejection while holes or a clipped stretch leave the vertical unsure.)
    recovering = s[S_INC_SIGMA] > RECOVERING * s[P_ACC_REJECT]
    dw, dx, dy = acc_rotation(s, fx, fy, fz, dt, starting or recovering)
    # q̂ + κ (δ ⊗ q̂ − q̂) = r ⊗ q̂ with r = (1 − κ) + κ δ.
    kap = s[C_K_ACC]
    if s[S_STEPS] > 1.0:
        kap = 1.0 - (1.0 - kap) ** s[S_STEPS]
    rw, rx, ry = 1.0 - kap + kap * dw, kap * dx, kap * dy
    s[S_Q] = rw * w - rx * x - ry * y
    s[S_Q + 1] = rw * x + rx * w + ry * z
    s[S_Q + 2] = rw * y + ry * w - rx * z
    s[S_Q + 3] = rw * z + rx * y - ry * x
    # The filter's states follow the applied rotation (r need not be unit).
    s[S_LP], s[S_LP + 1], s[S_LP + 2] = rotate(rw, rx, ry, 0.0, s1x, s1y, s1z)
    s[S_LP + 3], s[S_LP + 4], s[S_LP + 5] = rotate(rw, rx, ry, 0.0, s2x, s2y, s2z)
    if starting:
        if s[S_START] >= s[P_TAU_ACC]:
            # The mean hands over to the low-pass, steady at it.
            steady(s, S_LP, s[S_LP], s[S_LP + 1], s[S_LP + 2])
            rlp_steady(s)
        else:
            rlp_steady(s)
        return
    # The corrections measure a bias once the low-pass has settled from
    # the start, one tau_acc after the running mean handed over.
    settled = s[S_START] >= 2.0 * s[P_TAU_ACC]
    if not settled:
        s[S_START] += dt
    if s[P_MOTION_BIAS] != 0.0 and s[S_ACC_REJ] == 0.0:
        learn_bias(s, rw, rx, ry, dt, settled)
