"""
Acceleration rejection: a long-lasting specific force that tilts away from the gyro's vertical.

In a long turn the world-frame low-pass of the specific force (the
accelerometer step's target) stays tilted by the centripetal acceleration
for as long as the turn lasts, and the inclination follows it. Here the
estimator also carries a slow vertical ``u`` (world frame, ``rej.carried``):
the estimate's vertical as the gyro carries it, following the corrections
only with a time constant of ``_TAU_CARRIED``. Ordinary motion averages out
in the low-pass within seconds and ``u`` hardly moves; a low-passed force
more than ``acc_reject`` away from ``u`` is rejected, and the inclination is
pulled towards ``u`` instead, until the force comes back within half that
angle.

How long a rejection may last:

- **A force that turns with the body is not gravity.** Gravity is fixed in
  the world: while the body turns, it turns in the body frame at the
  body's rate (``ġ_body = −ω × g_body``). A force fixed in the body (a
  turn's centripetal force) turns in the world instead, unless it lies
  along the rotation axis. So the deviation ``d`` of the low-passed force
  from ``u`` is watched: while its rate follows ``ω × d`` (the gyro's
  prediction for a force fixed in the body), the time does not count
  towards ``acc_reject_time``; for as long as the turn lasts.
- **The rest counts**: rejected for longer than ``acc_reject_time``
  otherwise, the force is trusted again (``u`` taken from it): the maximum
  rejection time of Fusion's acceleration rejection (x-io Technologies,
  Madgwick's filter's successor), an idea learned there, not its code.
- **The bias's error carries ``u``** by ``path β`` (``path`` the integral
  of the rotation's tilting rows over the rejection); once its σ may
  have turned ``u`` by ``acc_reject``, the force is trusted again. A body
  that does not turn: the bias's σ times the time; one turning about the
  vertical carries a horizontal bias error round and back.

Written in the part of Python that numba compiles, as
:mod:`~ext_observer.core.ahrs.ahrs_kernel` (which calls it).
"""

import math

from .ahrs_filters import rotate, rotation_matrix
from .record import Group


REJ = Group('rej', 'Acceleration rejection', [
    ('carried', '1', 'u: the vertical the gyro carries, world frame', 3),
    ('time', 's', 'the force has been rejected (0: used)'),
    ('tilt', 'rad/s', 'the recent rate of tilting rotation'),
    ('dev', '1', "d: the low-passed force's direction less u, world frame (after the last "
     'correction)', 3),
    ('follow', '(rad/s)²', "d's rate · ω × d (the rate of a d fixed in the body), low-passed "
     'over tau_acc'),
    ('predicted', '(rad/s)²', 'the square of ω × d, low-passed over tau_acc'),
    ('turned', 's', 'of the rejection, the time d turned with the body (a sustained turn)'),
    ('path', 's', "∫ R(q̂)'s x and y rows dt over the rejection: a constant bias error β "
     'carries u by path β', 6),
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
# d turns with the body when its rate follows ω × d by more than this share:
# half-way between a force fixed in the world (0: gravity) and one fixed in
# the body (1: a turn's centripetal force), the midpoint of the two.
_FOLLOW = 0.5
_TINY = 1e-300


def _angle(ax, ay, az, bx, by, bz):
    """The angle (rad) between two vectors (not necessarily unit)."""
    cx, cy, cz = ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx
    return math.atan2(math.sqrt(cx * cx + cy * cy + cz * cz), ax * bx + ay * by + az * bz)


def acc_rejection_reset(s):
    """Forget the carried vertical, a rejection, the tilting rate and the turn's test (a reset)."""
    for i in range(3):
        s.rej.carried[i] = 0.0
        s.rej.dev[i] = 0.0
    s.rej.time = 0.0
    s.rej.tilt = 0.0
    s.rej.follow = 0.0
    s.rej.predicted = 0.0
    _rejection_starts(s)


def _rejection_starts(s):
    """Nothing of a rejection counted yet: no time held by a turn, no path."""
    s.rej.turned = 0.0
    for i in range(6):
        s.rej.path[i] = 0.0


def _world_rate(s):
    """The low-passed rate less the bias, in the world frame (rad/s)."""
    w, x, y, z = s.est.q[0], s.est.q[1], s.est.q[2], s.est.q[3]
    rx = s.rest.gyr_lp[0] - s.bias.rate[0]
    ry = s.rest.gyr_lp[1] - s.bias.rate[1]
    rz = s.rest.gyr_lp[2] - s.bias.rate[2]
    return rotate(w, x, y, z, rx, ry, rz)


def _tilting(s, wx, wy, dt):
    """
    The rate of tilting rotation (rad/s), low-passed over two ``tau_acc``.

    The gyro carries the vertical through a tilt with its scale and axis
    errors, and the low-passed force settles only after it: u forgets per
    radian tilted until then (a vehicle turns about the vertical).
    ``(wx, wy)``: the world rate's horizontal part.
    """
    k = dt / (2.0 * s.par.tau_acc + dt)
    s.rej.tilt += k * (math.sqrt(wx * wx + wy * wy) - s.rej.tilt)
    return s.rej.tilt


def _bias_var(s):
    """The bias's largest variance per axis, (rad/s)²."""
    return max(max(s.bias.p[0], max(s.bias.p[3], s.bias.p[5])), 0.0)


def _bias_carries(s, th):
    """
    How long (s) the bias's :data:`_SIGMAS` σ (the largest per axis) takes to
    turn a vertical the body does not turn by ``th``.
    """
    return th / (_SIGMAS * math.sqrt(_bias_var(s)) + _TINY)


def _turns_with_body(s, hx, hy, hz, wx, wy, wz, dt):
    """
    Whether d, the low-passed force's deviation from u, turns with the body.

    Gravity is fixed in the world frame: the gyro carries the body through
    it, and a tilt of the estimate leaves d fixed in the world too. A
    force fixed in the body (a turn's centripetal force) turns in the world
    with the body, at ``ω × d``, unless it lies along the rotation axis
    (the low-pass passes the turning force at the body's rate, lagging and
    smaller, after a transient). So the rate of ``d = h`` is compared with
    the gyro's ``ω × d`` over ``tau_acc``: it follows it by more than
    :data:`_FOLLOW`, and ``ω × d`` is faster than the bias's σ (the rate
    at which an error of the bias could turn u): a turn.
    """
    px, py, pz = wy * hz - wz * hy, wz * hx - wx * hz, wx * hy - wy * hx
    rx = (hx - s.rej.dev[0]) / dt
    ry = (hy - s.rej.dev[1]) / dt
    rz = (hz - s.rej.dev[2]) / dt
    k = dt / (s.par.tau_acc + dt)
    s.rej.follow += k * (rx * px + ry * py + rz * pz - s.rej.follow)
    s.rej.predicted += k * (px * px + py * py + pz * pz - s.rej.predicted)
    return (s.rej.predicted > _bias_var(s)
            and s.rej.follow > _FOLLOW * s.rej.predicted)


def _path_step(s, dt):
    """Add the rows of R(q̂) that tilt (its x and y rows) over ``dt`` to the path."""
    r = rotation_matrix(s)
    for i in range(6):
        s.rej.path[i] += r[i] * dt


def _carried_off(s):
    """
    The σ (rad) by which the bias's error may have carried u over the rejection.

    A constant bias error ``β`` (body frame) tilts u by ``path β``; its σ in the
    worst horizontal direction, with the bias's largest variance per axis on
    each: the largest singular value of ``path``. A body that does not turn
    has ``path = t R``: the bias's σ times the time, as without a path; a body
    turning about the vertical carries a horizontal β round and back.
    """
    p = s.rej.path
    a = p[0] * p[0] + p[1] * p[1] + p[2] * p[2]
    b = p[3] * p[3] + p[4] * p[4] + p[5] * p[5]
    c = p[0] * p[3] + p[1] * p[4] + p[2] * p[5]
    h = 0.5 * (a - b)
    lam = 0.5 * (a + b) + math.sqrt(h * h + c * c)
    return math.sqrt(_bias_var(s) * lam)


def acc_rotation(s, fx, fy, fz, dt, starting):
    """
    δ = (w, x, y): the rotation taking the target to the vertical; the target is ``f`` or ``u``.

    Also moves ``u`` with the correction about to be applied (``k_acc`` of δ)
    and towards the new vertical; ``rej.time`` counts the seconds rejected
    (0: the force is used). A rejection ends when the force comes back near
    ``u``, or after ``acc_reject_time`` not counting the time the deviation
    turned with the body (:func:`_turns_with_body`), or once the bias's σ may
    have carried ``u`` by ``acc_reject`` (:func:`_carried_off`).
    """
    ux, uy, uz = s.rej.carried[0], s.rej.carried[1], s.rej.carried[2]
    th = s.par.acc_reject
    if starting or th <= 0.0 or uz <= 0.0:
        # From the start (or a clipped gyro), and when off: the force as it is.
        ux, uy, uz = 0.0, 0.0, 1.0
        s.rej.time = 0.0
    wx, wy, wz = _world_rate(s)
    nf = math.sqrt(fx * fx + fy * fy + fz * fz) + _TINY
    hx, hy, hz = fx / nf - ux, fy / nf - uy, fz / nf - uz
    turning = False
    if not starting:
        turning = _turns_with_body(s, hx, hy, hz, wx, wy, wz, dt)
    tx, ty, tz = fx, fy, fz
    if th > 0.0 and not starting:
        off = _angle(fx, fy, fz, ux, uy, uz)
        if s.rej.time > 0.0 and off < _RELEASE * th:
            s.rej.time = 0.0
        elif s.rej.time > 0.0 or (off > th and _bias_carries(s, th) > _TAU_CARRIED):
            # (A bias too uncertain to carry the vertical for _TAU_CARRIED: no rejection.)
            if s.rej.time == 0.0:
                _rejection_starts(s)
            s.rej.time += dt
            if turning:
                s.rej.turned += dt
            _path_step(s, dt)
            if (s.rej.time - s.rej.turned > s.par.acc_reject_time
                    or _carried_off(s) > th):
                # Rejected too long: the force is gravity after all.
                ux, uy, uz = fx / nf, fy / nf, fz / nf
                s.rej.time = 0.0
            else:
                tx, ty, tz = ux, uy, uz
    n = math.sqrt(tx * tx + ty * ty + tz * tz) + _TINY
    dw, dx, dy = 1.0 + tz / n, ty / n, -tx / n
    dn = math.sqrt(dw * dw + dx * dx + dy * dy) + _TINY
    dw, dx, dy = dw / dn, dx / dn, dy / dn
    # u and d in the corrected world frame, then u a step towards its vertical.
    kap = s.coef.k_acc
    rw, rx, ry = 1.0 - kap + kap * dw, kap * dx, kap * dy
    ux, uy, uz = rotate(rw, rx, ry, 0.0, ux, uy, uz)
    k = min(1.0, dt / _TAU_CARRIED + _tilting(s, wx, wy, dt) * dt / _TILT_CARRIED)
    ux, uy, uz = ux - k * ux, uy - k * uy, uz + k * (1.0 - uz)
    n = math.sqrt(ux * ux + uy * uy + uz * uz) + _TINY
    s.rej.carried[0] = ux / n
    s.rej.carried[1] = uy / n
    s.rej.carried[2] = uz / n
    fx, fy, fz = rotate(rw, rx, ry, 0.0, fx / nf, fy / nf, fz / nf)
    s.rej.dev[0] = fx - s.rej.carried[0]
    s.rej.dev[1] = fy - s.rej.carried[1]
    s.rej.dev[2] = fz - s.rej.carried[2]
    return dw, dx, dy
