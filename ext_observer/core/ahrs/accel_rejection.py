"""
Acceleration rejection: a long-lasting specific force that tilts away from the gyro's vertical.

In a long turn the world-frame low-pass of the specific force (the
accelerometer step's target) stays tilted by the centripetal acceleration
for as long as the turn lasts, and the inclination follows it. Here the
estimator also carries a slow vertical ``u`` (world frame, ``S_ACC_CARRIED``):
the estimate's vertical as the gyro carries it, following the corrections
only with a time constant of ``_TAU_CARRIED``. Ordinary motion averages out
in the low-pass within seconds and ``u`` hardly moves; a low-passed force
more than ``acc_reject`` away from ``u`` is rejected, and the inclination is
pulled towards ``u`` instead, until the force comes back within half that
angle. Rejected for longer than ``acc_reject_time``, the force is trusted
again (``u`` taken from it): the maximum rejection time of Fusion's
acceleration rejection (x-io Technologies, Madgwick's filter's successor),
an idea learned there, not its code.

Written in the part of Python that numba compiles, as
:mod:`~ext_observer.core.ahrs.ahrs_kernel` (which calls it).
"""

import math

from .ahrs_filters import rotate
from .record import Group


REJ = Group('rej', 'Acceleration rejection', [
    ('carried', '1', 'u: the vertical the gyro carries, world frame', 3),
    ('time', 's', 'the force has been rejected (0: used)'),
    ('tilt', 'rad/s', 'the recent rate of tilting rotation'),
])

# s: how slowly the carried vertical follows the inclination's corrections
# (BROAD's motions average out in the low-pass within a few seconds).
_TAU_CARRIED = 10.0
# rad: and per this angle of tilting rotation.
_TILT_CARRIED = 1.0
# A rejection begins only if the bias's error, taken as this many σ (beyond 2σ
# is common at first), carries the vertical for _TAU_CARRIED.
_SIGMAS = 3.0
# The force is taken back below this share of the rejection angle.
_RELEASE = 0.5
_TINY = 1e-300


def _angle(ax, ay, az, bx, by, bz):
    """The angle (rad) between two vectors (not necessarily unit)."""
    cx, cy, cz = ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx
    return math.atan2(math.sqrt(cx * cx + cy * cy + cz * cz), ax * bx + ay * by + az * bz)


def acc_rejection_reset(s):
    """Forget the carried vertical, a rejection and the tilting rate (a reset)."""
    for i in range(3):
        s.rej.carried[i] = 0.0
    s.rej.time = 0.0
    s.rej.tilt = 0.0


def _tilting(s, dt):
    """
    The rate of tilting rotation (rad/s), low-passed over two ``tau_acc``.

    The gyro carries the vertical through a tilt with its scale and axis
    errors, and the low-passed force settles only after it: u forgets per
    radian tilted until then (a vehicle turns about the vertical).
    """
    w, x, y, z = s.est.q[0], s.est.q[1], s.est.q[2], s.est.q[3]
    rx = s.rest.gyr_lp[0] - s.bias.rate[0]
    ry = s.rest.gyr_lp[1] - s.bias.rate[1]
    rz = s.rest.gyr_lp[2] - s.bias.rate[2]
    wx, wy, wz = rotate(w, x, y, z, rx, ry, rz)
    k = dt / (2.0 * s.par.tau_acc + dt)
    s.rej.tilt += k * (math.sqrt(wx * wx + wy * wy) - s.rej.tilt)
    return s.rej.tilt


def _longest(s, th, sigmas):
    """
    The longest rejection (s): ``acc_reject_time``, and no longer than the
    bias's ``sigmas`` σ (the largest per axis) takes to turn the vertical by ``th``.
    """
    var = max(s.bias.p[0], max(s.bias.p[3], s.bias.p[5]))
    return min(s.par.acc_reject_time, th / (sigmas * math.sqrt(max(var, 0.0)) + _TINY))


def acc_rotation(s, fx, fy, fz, dt, starting):
    """
    δ = (w, x, y): the rotation taking the target to the vertical; the target is ``f`` or ``u``.

    Also moves ``u`` with the correction about to be applied (``C_K_ACC`` of δ)
    and towards the new vertical; ``S_ACC_REJ`` counts the seconds rejected
    (0: the force is used).
    """
    ux, uy, uz = s.rej.carried[0], s.rej.carried[1], s.rej.carried[2]
    th = s.par.acc_reject
    if starting or th <= 0.0 or uz <= 0.0:
        # From the start (or a clipped gyro), and when off: the force as it is.
        ux, uy, uz = 0.0, 0.0, 1.0
        s.rej.time = 0.0
    tx, ty, tz = fx, fy, fz
    if th > 0.0 and not starting:
        off = _angle(fx, fy, fz, ux, uy, uz)
        if s.rej.time > 0.0 and off < _RELEASE * th:
            s.rej.time = 0.0
        elif s.rej.time > 0.0 or (off > th and _longest(s, th, _SIGMAS) > _TAU_CARRIED):
            # (A bias too uncertain to carry the vertical for _TAU_CARRIED: no rejection.)
            s.rej.time += dt
            if s.rej.time > _longest(s, th, 1.0):
                # Rejected too long: the force is gravity after all.
                n = math.sqrt(fx * fx + fy * fy + fz * fz) + _TINY
                ux, uy, uz = fx / n, fy / n, fz / n
                s.rej.time = 0.0
            else:
                tx, ty, tz = ux, uy, uz
    n = math.sqrt(tx * tx + ty * ty + tz * tz) + _TINY
    dw, dx, dy = 1.0 + tz / n, ty / n, -tx / n
    dn = math.sqrt(dw * dw + dx * dx + dy * dy) + _TINY
    dw, dx, dy = dw / dn, dx / dn, dy / dn
    # u in the corrected world frame, then a step towards its vertical.
    kap = s.coef.k_acc
    ux, uy, uz = rotate(1.0 - kap + kap * dw, kap * dx, kap * dy, 0.0, ux, uy, uz)
    k = min(1.0, dt / _TAU_CARRIED + _tilting(s, dt) * dt / _TILT_CARRIED)
    ux, uy, uz = ux - k * ux, uy - k * uy, uz + k * (1.0 - uz)
    n = math.sqrt(ux * ux + uy * uy + uz * uz) + _TINY
    s.rej.carried[0] = ux / n
    s.rej.carried[1] = uy / n
    s.rej.carried[2] = uz / n
    return dw, dx, dy
