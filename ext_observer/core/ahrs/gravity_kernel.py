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
from .bias_kernel import learn_bias, rlp_steady
from .hole_kernel import RECOVERING, acc_deviation
from .velocity_kernel import velocity_removed
from .record import Group

INC = Group('inc', "The inclination's filters: the world-frame specific force", [
    ('lp', 'm/s²', 'the Butterworth states s1 (3), s2 (3) of the world-frame force', 6),
    ('start', 's', 'since the start (or a clipped stretch)'),
    ('start_n', '', 'samples in the running mean of the start'),
    ('acc_dev', '(1/g)²', "the specific force's recent deviation from gravity"),
    ('sigma', 'rad', "the inclination's error σ that holes and clipped samples left beyond "
     "the usual, forgotten at the low-pass's pace (0: none)"),
])


def inc_reset(s):
    """The inclination's filters start again: the running mean first, nothing owed."""
    s.inc.start = 0.0
    s.inc.start_n = 0.0
    s.inc.acc_dev = 0.0
    s.inc.sigma = 0.0


def ahrs_update_acc(s, ax, ay, az):
    """Correct the inclination from the world-frame filtered specific force."""
    # Rest detection needs the accelerometer's deviation from its mean.
    rx, ry, rz = first_order_step(s.rest.acc_lp, s.coef.k_rest, ax, ay, az)
    ex, ey, ez = ax - rx, ay - ry, az - rz
    still = (ex * ex + ey * ey + ez * ez) < s.par.rest_acc * s.par.rest_acc
    s.rest.acc_still = 1.0 if still else 0.0
    # Gravity from the specific force less the body's own acceleration (rest sees it all).
    ax, ay, az = velocity_removed(s, ax, ay, az)

    w, x, y, z = s.est.q[0], s.est.q[1], s.est.q[2], s.est.q[3]
    vx, vy, vz = rotate(w, x, y, z, ax, ay, az)
    dt = s.coef.dt
    acc_deviation(s, vx, vy, vz, dt)
    starting = s.inc.start < s.par.tau_acc
    if starting:
        # The first tau_acc seconds (from the start, or after a clipped
        # gyro): the running mean of the world-frame specific force, which
        # a low-pass started on one sample of a moving body would only
        # approach at its own pace (VQF starts its low-pass so too).
        n = s.inc.start_n + 1.0
        s.inc.start_n = n
        fx = s.inc.lp[0] + (vx - s.inc.lp[0]) / n
        fy = s.inc.lp[1] + (vy - s.inc.lp[1]) / n
        fz = s.inc.lp[2] + (vz - s.inc.lp[2]) / n
        s1x, s1y, s1z = fx, fy, fz
        s2x, s2y, s2z = 0.0, 0.0, 0.0
        s.inc.start += dt
    else:
        b0, b1, b2, a1, a2 = s.coef.bw[0], s.coef.bw[1], s.coef.bw[2], s.coef.bw[3], s.coef.bw[4]
        s1x, s1y, s1z = s.inc.lp[0], s.inc.lp[1], s.inc.lp[2]
        s2x, s2y, s2z = s.inc.lp[3], s.inc.lp[4], s.inc.lp[5]
        # A hole's sample stands for the steps lost too (held across them).
        for _ in range(max(int(s.hole.steps + 0.5), 1)):
            fx, fy, fz = b0 * vx + s1x, b0 * vy + s1y, b0 * vz + s1z
            s1x, s1y, s1z = (b1 * vx - a1 * fx + s2x, b1 * vy - a1 * fy + s2y,
                             b1 * vz - a1 * fz + s2z)
            s2x, s2y, s2z = b2 * vx - a2 * fx, b2 * vy - a2 * fy, b2 * vz - a2 * fz

    # δ: the rotation taking f/|f| (or, f rejected, the gyro's vertical) to
    # the vertical, [1 + u_z, u_y, −u_x, 0] (|δ| = 0 only shrinks q̂).
    # (No rejection while holes or a clipped stretch leave the vertical unsure.)
    recovering = s.inc.sigma > RECOVERING * s.par.acc_reject
    dw, dx, dy = acc_rotation(s, fx, fy, fz, dt, starting or recovering)
    # q̂ + κ (δ ⊗ q̂ − q̂) = r ⊗ q̂ with r = (1 − κ) + κ δ.
    kap = s.coef.k_acc
    if s.hole.steps > 1.0:
        kap = 1.0 - (1.0 - kap) ** s.hole.steps
    rw, rx, ry = 1.0 - kap + kap * dw, kap * dx, kap * dy
    s.est.q[0] = rw * w - rx * x - ry * y
    s.est.q[1] = rw * x + rx * w + ry * z
    s.est.q[2] = rw * y + ry * w - rx * z
    s.est.q[3] = rw * z + rx * y - ry * x
    # The filter's states follow the applied rotation (r need not be unit).
    s.inc.lp[0], s.inc.lp[1], s.inc.lp[2] = rotate(rw, rx, ry, 0.0, s1x, s1y, s1z)
    s.inc.lp[3], s.inc.lp[4], s.inc.lp[5] = rotate(rw, rx, ry, 0.0, s2x, s2y, s2z)
    if starting:
        if s.inc.start >= s.par.tau_acc:
            # The mean hands over to the low-pass, steady at it.
            steady(s.coef.bw, s.inc.lp, 0, s.inc.lp[0], s.inc.lp[1], s.inc.lp[2])
            rlp_steady(s)
        else:
            rlp_steady(s)
        return
    # The corrections measure a bias once the low-pass has settled from
    # the start, one tau_acc after the running mean handed over.
    settled = s.inc.start >= 2.0 * s.par.tau_acc
    if not settled:
        s.inc.start += dt
    if s.par.motion_bias != 0.0 and s.rej.time == 0.0:
        learn_bias(s, rw, rx, ry, dt, settled)
