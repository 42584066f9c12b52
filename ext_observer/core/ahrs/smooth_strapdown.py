"""
The smoother's strapdown and its arrays of rotations: :func:`strapdown`.

Helpers of :mod:`~ext_observer.core.ahrs.smoother` on whole arrays
(``(w, x, y, z)``, sensor → I): the gyro's integration (one compiled loop, or
a blocked scan in numpy), rotations of rows of vectors, products of rows of
quaternions, the windows' box sums. Where numba is wanted,
loops compiled from this file (:func:`_loops`); else numpy on whole arrays,
to the same floats.
"""

import math
import os
import types

import numpy as np

from ..quaternion import multiply, normalize, quaternion_from_rotation_vector
from .ahrs_filters import quat_multiply, rotate
from .compiled import compiled_name, wanted

__all__ = ['about_vertical', 'box3', 'field_parts', 'rotate_rows', 'slopes',
           'spread', 'strapdown', 'strapdown_blocked', 'tilted', 'turned',
           'turned_about_vertical']


def spread(s, count):
    """The mean squared deviation from their mean of vectors given by sums ``(Σx, Σ|x|²)``."""
    count = np.maximum(count, 1.0)
    mean = s[:, :-1] / count[:, None]
    return np.maximum(s[:, -1] / count - np.einsum('ij,ij->i', mean, mean), 0.0)


def slopes(gyr, t, span):
    """
    The rate's slope (rad/s²) ending at each sample and starting at it (N, 3) each.

    The difference to the sample about ``span`` s before (after); 0 where
    there is none.
    """
    index = np.arange(len(gyr))
    tk, wk = t, gyr
    back = np.searchsorted(tk, tk - span, side='right') - 1
    ahead = np.searchsorted(tk, tk + span, side='left')
    back = np.where(back >= np.arange(len(tk)), np.arange(len(tk)) - 1, back)
    ahead = np.where(ahead <= np.arange(len(tk)), np.arange(len(tk)) + 1, ahead)
    out_back, out_ahead = np.zeros_like(gyr), np.zeros_like(gyr)
    ok = back >= 0
    out_back[index[ok]] = (wk[ok] - wk[back[ok]]) / (tk[ok] - tk[back[ok]])[:, None]
    ok = ahead < len(tk)
    out_ahead[index[ok]] = (wk[ahead[ok]] - wk[ok]) / (tk[ahead[ok]] - tk[ok])[:, None]
    return out_back, out_ahead


def strapdown(rate, dt, first):
    """
    ``q_k = q_{k−1} ⊗ exp(ω_k dt_k / 2)`` from ``q_0 = first``, each normalized.

    ``dt``: s, one for all steps or each step's (N,).

    One compiled loop where numba is wanted (:func:`_integrate`); else
    :func:`strapdown_blocked`, numpy on whole arrays. The two agree to
    rounding.
    """
    loops = _loops()
    if loops is None:
        return strapdown_blocked(rate, dt, first)
    out = np.empty((len(rate), 4))
    first = normalize(np.asarray(first, dtype=float))
    dt = np.ascontiguousarray(np.broadcast_to(np.asarray(dt, dtype=float), (len(rate),)))
    loops.integrate(np.ascontiguousarray(rate, dtype=float), dt, first[0], first[1], first[2],
                    first[3], out)
    return out


def strapdown_blocked(rate, dt, first):
    """
    :func:`strapdown` on whole arrays: a blocked scan.

    The running products within blocks of about √N samples (one product per
    column, over all blocks at once), then the blocks' running products, then
    each block's products from its start's.
    """
    n = len(rate)
    dt = np.broadcast_to(np.asarray(dt, dtype=float), (n,))
    step = quaternion_from_rotation_vector(rate * dt[:, None])
    step[0] = normalize(np.asarray(first, dtype=float))
    size = max(1, int(math.ceil(math.sqrt(n))))
    blocks = -(-n // size)
    padded = np.zeros((blocks * size, 4))
    padded[:, 0] = 1.0
    padded[:n] = step
    # Column j holds the j-th sample of every block, contiguous.
    within = np.ascontiguousarray(padded.reshape(blocks, size, 4).transpose(1, 0, 2))
    for j in range(1, size):
        within[j] = multiply(within[j - 1], within[j])
    before = np.empty((blocks, 4))
    before[0] = (1.0, 0.0, 0.0, 0.0)
    for i in range(1, blocks):
        before[i] = multiply(before[i - 1], within[-1, i - 1])
    q = multiply(before[None, :, :], within).transpose(1, 0, 2).reshape(-1, 4)[:n]
    return normalize(q)


def _integrate(rate, dt, w, x, y, z, out):
    """
    The strapdown loop over samples: ``q_k`` into ``out`` (N, 4) from ``q_0 = (w, x, y, z)``.

    ``dt`` (N,): each step's interval, s.
    """
    out[0, 0], out[0, 1], out[0, 2], out[0, 3] = w, x, y, z
    for k in range(1, rate.shape[0]):
        vx, vy, vz = rate[k, 0] * dt[k], rate[k, 1] * dt[k], rate[k, 2] * dt[k]
        angle = math.sqrt(vx * vx + vy * vy + vz * vz)
        # sin(a / 2) / a, its limit 1/2 below a rounding error's angle.
        s = math.sin(0.5 * angle) / angle if angle > 1e-8 else 0.5
        w, x, y, z = _product(w, x, y, z, math.cos(0.5 * angle), s * vx, s * vy, s * vz)
        scale = 1.0 / math.sqrt(w * w + x * x + y * y + z * z)
        w, x, y, z = w * scale, x * scale, y * scale, z * scale
        out[k, 0], out[k, 1], out[k, 2], out[k, 3] = w, x, y, z


def _rotate_each(q, v, out):
    """Each row of ``v`` (N, 3) rotated by its row of ``q`` (N, 4), into ``out`` (N, 3)."""
    for k in range(v.shape[0]):
        out[k, 0], out[k, 1], out[k, 2] = _rotate(q[k, 0], q[k, 1], q[k, 2], q[k, 3],
                                                  v[k, 0], v[k, 1], v[k, 2])


def _box_pass(i, v, total, ring, p, s, n, h):
    """
    One box pass at its sample ``i`` (input ``v``): its running sum, its box sum at ``i − h``.

    The running sum goes into ``ring[p, s]``; the slot after ``s`` holds
    the one at ``i − 2 h − 1`` (written ``2 h + 1`` steps before). Past the
    last sample the running sum holds the total; before the first, 0.
    """
    if i < n:
        total = v if i == 0 else total + v
    ring[p, s] = total
    lo = ring[p, s + 1 if s + 1 < ring.shape[1] else 0]
    return total, total - (lo if i >= 2 * h + 1 else 0.0)


def _box3_each(x, h, out):
    """
    :func:`box3` of ``x`` (N, m) into ``out``, one column at a time in one sweep.

    The three passes run together, each ``h`` samples behind the one
    before (its input, the box sum at ``i − h``, is then known), each
    keeping its last ``2 h + 2`` running sums in a ring: numpy's floats
    (the same sums in the same order) with a small working set.
    """
    n, m = x.shape
    # Beyond the recording's length, a wider box sums the same samples.
    h = min(h, n)
    size = 2 * h + 2
    ring = np.empty((3, size))
    for j in range(m):
        s = 0
        t0 = t1 = t2 = 0.0
        for t in range(n + 3 * h):
            v = x[t, j] if t < n else 0.0
            t0, v = _step(t, v, t0, ring, 0, s, n, h)
            if t >= h:
                t1, v = _step(t - h, v, t1, ring, 1, s, n, h)
                if t >= 2 * h:
                    t2, v = _step(t - 2 * h, v, t2, ring, 2, s, n, h)
                    if t >= 3 * h:
                        out[t - 3 * h, j] = v
            s = s + 1 if s + 1 < size else 0


def _size4(w, x, y, z):
    """
    ``|q|`` as :func:`~ext_observer.core.quaternion.normalize` sums it.

    numpy's ``einsum`` over four contiguous floats adds them in two lanes
    (x86-64): ``(w² + y²) + (x² + z²)``.
    """
    return math.sqrt((w * w + y * y) + (x * x + z * z))


def _turn_one(rw, rx, ry, rz, q, k, out):
    """``out[k] = r ⊗ q[k]`` normalized; False where it is 0 or not finite."""
    w, x, y, z = _product(rw, rx, ry, rz, q[k, 0], q[k, 1], q[k, 2], q[k, 3])
    size = _size(w, x, y, z)
    out[k, 0], out[k, 1], out[k, 2], out[k, 3] = w / size, x / size, y / size, z / size
    return math.isfinite(size) and size != 0.0


def _turn_each(r, q, first, out):
    """
    ``r_k ⊗ q_k`` normalized (N, 4) into ``out``; ``first``: ``r_k`` normalized first.

    Returns False where a quaternion to normalize is 0 or not finite
    (``out`` then partly written).
    """
    for k in range(q.shape[0]):
        rw, rx, ry, rz = r[k, 0], r[k, 1], r[k, 2], r[k, 3]
        if first:
            size = _size(rw, rx, ry, rz)
            if not (math.isfinite(size) and size != 0.0):
                return False
            rw, rx, ry, rz = rw / size, rx / size, ry / size, rz / size
        if not _turn_row(rw, rx, ry, rz, q, k, out):
            return False
    return True


def _vertical_each(cos, sin, q, out):
    """:func:`turned_about_vertical` into ``out`` (N, 4), from the half angles' cos and sin."""
    for k in range(q.shape[0]):
        if not _turn_row(cos[k], 0.0, 0.0, sin[k], q, k, out):
            return False
    return True


def _tilt_each(f, q, out):
    """:func:`tilted` into ``out`` (N, 4); False as :func:`_turn_each`."""
    for k in range(q.shape[0]):
        fx, fy, fz = f[k, 0], f[k, 1], f[k, 2]
        size = math.sqrt((fx * fx + fy * fy) + fz * fz)
        cw, cx, cy = 1.0 + fz / size, fy / size, -(fx / size)
        size = _size(cw, cx, cy, 0.0)
        if not (math.isfinite(size) and size != 0.0):
            return False
        if not _turn_row(cw / size, cx / size, cy / size, 0.0 / size, q, k, out):
            return False
    return True


def _field_each(q, mag, norm, horizontal, vertical, unit):
    """:func:`field_parts` into ``norm``, ``horizontal``, ``vertical`` (N,), ``unit`` (N, 2)."""
    for k in range(q.shape[0]):
        vx, vy, vz = mag[k, 0], mag[k, 1], mag[k, 2]
        if math.isnan(vx):
            vx, vy, vz = 0.0, 0.0, 0.0
        mx, my, mz = _rotate(q[k, 0], q[k, 1], q[k, 2], q[k, 3], vx, vy, vz)
        norm[k] = math.sqrt((mx * mx + my * my) + mz * mz)
        h = math.hypot(mx, my)
        horizontal[k], vertical[k] = h, mz
        d = _TINY if h < _TINY else h
        unit[k, 0], unit[k, 1] = mx / d, my / d


# The helpers the loops call, by these names: _loops binds them to their compiled twins
# (a compiled loop calls only compiled functions).
_product = quat_multiply
_rotate = rotate
_size = _size4
_turn_row = _turn_one
_step = _box_pass
_TINY = float(np.finfo(float).tiny)
_LOOPS = []


def _loops():
    """
    The loops of this file compiled by numba, or None where numba is not wanted.

    A namespace of :func:`_integrate` (``integrate``), :func:`_rotate_each`
    (``rotate``), :func:`_turn_each` (``turn``), :func:`_tilt_each`
    (``tilt``), :func:`_vertical_each` (``vertical``), :func:`_field_each`
    (``field``) and :func:`_box3_each` (``box3``). None: the callers run
    numpy on whole arrays, to the same floats (the strapdown: to rounding).
    Cached on disk beside the kernels' compiled code, in a folder of its own
    (the kernels' twins of ``quat_multiply`` and ``rotate`` have the same
    files and names) for this version of the kernel files
    (:func:`~ext_observer.core.ahrs.compiled.compiled_name`).
    """
    global _product, _rotate, _size, _turn_row, _step
    if not _LOOPS:
        loops = None
        if wanted(None)[0]:
            import numba
            name, folder = compiled_name()
            saved = numba.config.CACHE_DIR
            numba.config.CACHE_DIR = os.path.join(folder, f'{name}_smoother')
            try:
                _product = numba.njit(cache=True)(quat_multiply)
                _rotate = numba.njit(cache=True, error_model='numpy')(rotate)
                _size = numba.njit(cache=True)(_size4)
                _turn_row = numba.njit(cache=True, error_model='numpy')(_turn_one)
                _step = numba.njit(cache=True)(_box_pass)
                loops = types.SimpleNamespace(
                    integrate=numba.njit(cache=True)(_integrate),
                    rotate=numba.njit(cache=True, error_model='numpy')(_rotate_each),
                    turn=numba.njit(cache=True, error_model='numpy')(_turn_each),
                    tilt=numba.njit(cache=True, error_model='numpy')(_tilt_each),
                    vertical=numba.njit(cache=True, error_model='numpy')(_vertical_each),
                    field=numba.njit(cache=True, error_model='numpy')(_field_each),
                    box3=numba.njit(cache=True)(_box3_each))
            finally:
                numba.config.CACHE_DIR = saved
        _LOOPS.append(loops)
    return _LOOPS[0]


def turned(r, q, first=False):
    """
    ``r ⊗ q`` normalized (N, 4), for rows of quaternions ``r``, ``q`` (N, 4).

    ``first``: ``r`` normalized first. A compiled loop, or
    :func:`~ext_observer.core.quaternion.normalize` and
    :func:`~ext_observer.core.quaternion.multiply` on whole arrays: the same
    floats (:func:`_size4`).

    Raises
    ------
    ValueError
        Where a quaternion to normalize is 0 or not finite.
    """
    loops = _loops()
    if loops is None:
        return normalize(multiply(normalize(r) if first else r, q))
    out = np.empty((len(q), 4))
    if not loops.turn(np.ascontiguousarray(r, dtype=float), np.ascontiguousarray(q, dtype=float),
                      bool(first), out):
        raise ValueError('Cannot normalize a quaternion that is zero or not finite')
    return out


def turned_about_vertical(angle, q):
    """
    ``r ⊗ q`` normalized (N, 4): ``r``, the rotations by ``angle`` (N,) rad about the world's z.

    :func:`turned` of :func:`about_vertical`'s, without their array.
    """
    loops = _loops()
    if loops is None:
        return turned(about_vertical(angle), q)
    out = np.empty((len(q), 4))
    if not loops.vertical(np.cos(0.5 * angle), np.sin(0.5 * angle),
                          np.ascontiguousarray(q, dtype=float), out):
        raise ValueError('Cannot normalize a quaternion that is zero or not finite')
    return out


def tilted(f, q):
    """
    ``c ⊗ q`` (N, 4): ``c``, the smallest rotation turning each row of ``f`` (N, 3) up (+z).

    A compiled loop, or numpy on whole arrays: the same floats
    (:func:`_size4`).

    Raises
    ------
    ValueError
        Where ``f`` points straight down, is 0 or is not finite.
    """
    loops = _loops()
    if loops is None:
        up = f / np.linalg.norm(f, axis=1, keepdims=True)
        # (1 + up·z, up × z) normalized: the rotation by the angle between up and z about
        # up × z.
        c = np.stack((1.0 + up[:, 2], up[:, 1], -up[:, 0], np.zeros(len(up))), axis=1)
        return normalize(multiply(normalize(c), q))
    out = np.empty((len(q), 4))
    if not loops.tilt(np.ascontiguousarray(f, dtype=float), np.ascontiguousarray(q, dtype=float),
                      out):
        raise ValueError('Cannot normalize a quaternion that is zero or not finite')
    return out


def field_parts(q, mag):
    """
    The field ``mag`` (N, 3) rotated by ``q`` (N, 4), in parts; a NaN row reads as 0.

    Returns its norm, its horizontal norm and its vertical component (N,)
    each, and its horizontal direction (N, 2) (0 where it has none). A
    compiled loop, or numpy on whole arrays: the same floats.
    """
    loops = _loops()
    if loops is None:
        m = rotate_rows(q, np.where(np.isnan(mag[:, :1]), 0.0, mag))
        horizontal = np.hypot(m[:, 0], m[:, 1])
        return (np.linalg.norm(m, axis=1), horizontal, m[:, 2],
                m[:, :2] / np.maximum(horizontal, np.finfo(float).tiny)[:, None])
    n = len(q)
    norm, horizontal, vertical, unit = np.empty(n), np.empty(n), np.empty(n), np.empty((n, 2))
    loops.field(np.ascontiguousarray(q, dtype=float), np.ascontiguousarray(mag, dtype=float),
                norm, horizontal, vertical, unit)
    return norm, horizontal, vertical, unit


def box3(x, h, out=None):
    """
    ``x`` (N, ...) through three box sums in a row along axis 0 (a Gaussian-like window).

    Each box sums its input over ``[k − h, k + h]`` at each sample ``k``,
    truncated at the ends: the differences of the running sum. A compiled
    loop, or numpy's ``cumsum`` on a padded array: the same floats. ``out``:
    a C-contiguous array of ``x``'s shape for the result, ``x`` itself
    allowed.
    """
    loops = _loops()
    n = len(x)
    out = np.empty(np.shape(x)) if out is None else out
    if loops is not None:
        # Each sample's sums are written after its input is read: out may be x.
        loops.box3(np.ascontiguousarray(x, dtype=float).reshape(n, -1), int(h),
                   out.reshape(n, -1))
        return out
    for _ in range(3):
        c = np.empty((n + 2 * h + 1,) + x.shape[1:])
        c[:h + 1] = 0.0
        np.cumsum(x, axis=0, out=c[h + 1:n + h + 1])
        c[n + h + 1:] = c[n + h]
        # c[h + 1 + k] is the sum up to sample k; before the first, 0; past the last, all.
        x = c[2 * h + 1:] - c[:n]
    out[...] = x
    return out


def rotate_rows(q, v):
    """
    The vectors ``v`` (N, 3) rotated by the quaternions ``q`` (N, 4): ``q ⊗ v ⊗ q̄ / |q|²``.

    The kernels' rotation (:func:`~ext_observer.core.ahrs.ahrs_filters.rotate`)
    in a compiled loop, or on columns: the same floats.
    """
    out = np.empty((len(v), 3))
    loops = _loops()
    if loops is None:
        out[:, 0], out[:, 1], out[:, 2] = rotate(q[:, 0], q[:, 1], q[:, 2], q[:, 3],
                                                 v[:, 0], v[:, 1], v[:, 2])
    else:
        loops.rotate(np.ascontiguousarray(q, dtype=float), np.ascontiguousarray(v, dtype=float),
                     out)
    return out


def about_vertical(angle):
    """Unit quaternions (N, 4) of rotations by ``angle`` (N,) rad about the world's z axis."""
    r = np.zeros((len(angle), 4))
    r[:, 0] = np.cos(0.5 * angle)
    r[:, 3] = np.sin(0.5 * angle)
    return r
