"""
Vector and small-matrix algebra for the kernels: 3-vectors as tuples, matrices in array fields.

A 3-vector is a tuple ``(x, y, z)``; a 3 × 3 matrix held in registers is a
9-tuple, row-major. A matrix stored in an array ``a`` (a field of a record,
such as a covariance ``c.p``; a list when plain) is read and written at a
local index ``at`` of it; a product or a copy names each matrix by its
array and a view ``(at, row stride, column stride)`` into it: :func:`rows`
for one stored row-major, :func:`cols` for the transpose of one. Each sum
runs left to right in the order its formula is written, so a kernel written
with these helpers gives the same bits as the products written out by hand.
The same subset of Python as the kernels
(:mod:`~ext_observer.core.ahrs.compiled` compiles them, and numba inlines
them into their callers).
"""

import math


def max_of(a, b):
    """``b`` where ``a < b``, else ``a`` (a NaN ``a`` kept, as the comparison written out)."""
    return b if a < b else a


def finite_or_zero(a):
    """``a``, or 0.0 where it is not finite."""
    return a if math.isfinite(a) else 0.0


def rows(at, width):
    """The view of a row-major matrix ``width`` wide stored from index ``at`` of its array."""
    return (at, width, 1)


def cols(at, width):
    """The transpose of the row-major matrix ``width`` wide stored from index ``at``."""
    return (at, 1, width)


def value_at(s, at):
    """``s[at]``: one entry, as the vectors' readers read theirs."""
    return s[at]


def vec3_at(s, at):
    """``s[at:at + 3]`` as a 3-vector."""
    return (s[at], s[at + 1], s[at + 2])


def vec5_at(s, at, step):
    """``s[at], s[at + step], …``: five of them, as a tuple."""
    return (s[at], s[at + step], s[at + 2 * step], s[at + 3 * step], s[at + 4 * step])


def vec12_at(s, at, step):
    """``s[at], s[at + step], …``: twelve of them, as a tuple (held in registers, compiled)."""
    return (s[at], s[at + step], s[at + 2 * step], s[at + 3 * step], s[at + 4 * step],
            s[at + 5 * step], s[at + 6 * step], s[at + 7 * step], s[at + 8 * step],
            s[at + 9 * step], s[at + 10 * step], s[at + 11 * step])


def dot12(a, b):
    """``a · b`` for 12-tuples, from the first product on."""
    return (a[0] * b[0] + a[1] * b[1] + a[2] * b[2] + a[3] * b[3] + a[4] * b[4] + a[5] * b[5]
            + a[6] * b[6] + a[7] * b[7] + a[8] * b[8] + a[9] * b[9] + a[10] * b[10]
            + a[11] * b[11])


def dot12_onto(acc, a, b):
    """``acc + a · b`` for 12-tuples, product by product onto ``acc``."""
    return (acc + a[0] * b[0] + a[1] * b[1] + a[2] * b[2] + a[3] * b[3] + a[4] * b[4]
            + a[5] * b[5] + a[6] * b[6] + a[7] * b[7] + a[8] * b[8] + a[9] * b[9]
            + a[10] * b[10] + a[11] * b[11])


def combination12_into(s, at, k, a, b, c):
    """``s[at:at + 12] = k₀ a + k₁ b + k₂ c`` (12-tuples), written out: held in registers."""
    s[at] = k[0] * a[0] + k[1] * b[0] + k[2] * c[0]
    s[at + 1] = k[0] * a[1] + k[1] * b[1] + k[2] * c[1]
    s[at + 2] = k[0] * a[2] + k[1] * b[2] + k[2] * c[2]
    s[at + 3] = k[0] * a[3] + k[1] * b[3] + k[2] * c[3]
    s[at + 4] = k[0] * a[4] + k[1] * b[4] + k[2] * c[4]
    s[at + 5] = k[0] * a[5] + k[1] * b[5] + k[2] * c[5]
    s[at + 6] = k[0] * a[6] + k[1] * b[6] + k[2] * c[6]
    s[at + 7] = k[0] * a[7] + k[1] * b[7] + k[2] * c[7]
    s[at + 8] = k[0] * a[8] + k[1] * b[8] + k[2] * c[8]
    s[at + 9] = k[0] * a[9] + k[1] * b[9] + k[2] * c[9]
    s[at + 10] = k[0] * a[10] + k[1] * b[10] + k[2] * c[10]
    s[at + 11] = k[0] * a[11] + k[1] * b[11] + k[2] * c[11]


def sub_combination12(s, at, k, a, b, c):
    """``s[at:at + 12] −= k₀ a + k₁ b + k₂ c`` (12-tuples), written out: held in registers."""
    s[at] -= k[0] * a[0] + k[1] * b[0] + k[2] * c[0]
    s[at + 1] -= k[0] * a[1] + k[1] * b[1] + k[2] * c[1]
    s[at + 2] -= k[0] * a[2] + k[1] * b[2] + k[2] * c[2]
    s[at + 3] -= k[0] * a[3] + k[1] * b[3] + k[2] * c[3]
    s[at + 4] -= k[0] * a[4] + k[1] * b[4] + k[2] * c[4]
    s[at + 5] -= k[0] * a[5] + k[1] * b[5] + k[2] * c[5]
    s[at + 6] -= k[0] * a[6] + k[1] * b[6] + k[2] * c[6]
    s[at + 7] -= k[0] * a[7] + k[1] * b[7] + k[2] * c[7]
    s[at + 8] -= k[0] * a[8] + k[1] * b[8] + k[2] * c[8]
    s[at + 9] -= k[0] * a[9] + k[1] * b[9] + k[2] * c[9]
    s[at + 10] -= k[0] * a[10] + k[1] * b[10] + k[2] * c[10]
    s[at + 11] -= k[0] * a[11] + k[1] * b[11] + k[2] * c[11]


def store3(s, at, v):
    """``s[at:at + 3] = v``."""
    s[at] = v[0]
    s[at + 1] = v[1]
    s[at + 2] = v[2]


def col3_at(s, at, width):
    """The column at ``s[at:]`` of a matrix ``width`` wide, as a 3-vector."""
    return (s[at], s[at + width], s[at + 2 * width])


def add3(a, b):
    """``a + b``."""
    return (a[0] + b[0], a[1] + b[1], a[2] + b[2])


def sub3(a, b):
    """``a − b``."""
    return (a[0] - b[0], a[1] - b[1], a[2] - b[2])


def neg3(a):
    """``−a``."""
    return (-a[0], -a[1], -a[2])


def scale3(k, a):
    """``k a``."""
    return (k * a[0], k * a[1], k * a[2])


def add_scaled3(a, k, b):
    """``a + k b``."""
    return (a[0] + k * b[0], a[1] + k * b[1], a[2] + k * b[2])


def dot3(a, b):
    """``a · b``."""
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def cross3(a, b):
    """``a × b``."""
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def mat3t_vec(m, v):
    """``Mᵀ v`` for a 9-tuple ``M`` (equally ``vᵀ M``, a row times ``M``)."""
    return (m[0] * v[0] + m[3] * v[1] + m[6] * v[2],
            m[1] * v[0] + m[4] * v[1] + m[7] * v[2],
            m[2] * v[0] + m[5] * v[1] + m[8] * v[2])


def mat3_vec_at(s, at, v):
    """``M v`` for the row-major 3 × 3 matrix ``M`` at ``s[at:]``."""
    return (s[at] * v[0] + s[at + 1] * v[1] + s[at + 2] * v[2],
            s[at + 3] * v[0] + s[at + 4] * v[1] + s[at + 5] * v[2],
            s[at + 6] * v[0] + s[at + 7] * v[1] + s[at + 8] * v[2])


def vec_mat3_at(v, s, at):
    """``vᵀ M`` for the row-major 3 × 3 matrix ``M`` at ``s[at:]``."""
    return (v[0] * s[at] + v[1] * s[at + 3] + v[2] * s[at + 6],
            v[0] * s[at + 1] + v[1] * s[at + 4] + v[2] * s[at + 7],
            v[0] * s[at + 2] + v[1] * s[at + 5] + v[2] * s[at + 8])


def quad3_at(s, at, v):
    """``vᵀ M v`` for the row-major 3 × 3 matrix ``M`` at ``s[at:]``, term by term."""
    return (v[0] * s[at] * v[0] + v[0] * s[at + 1] * v[1] + v[0] * s[at + 2] * v[2]
            + v[1] * s[at + 3] * v[0] + v[1] * s[at + 4] * v[1] + v[1] * s[at + 5] * v[2]
            + v[2] * s[at + 6] * v[0] + v[2] * s[at + 7] * v[1] + v[2] * s[at + 8] * v[2])


def rotation_of(w, x, y, z):
    """The rotation matrix (9-tuple) of the quaternion ``(w, x, y, z)``, any nonzero norm."""
    q2 = 2.0 / (w * w + x * x + y * y + z * z)
    return (1.0 - q2 * (y * y + z * z), q2 * (x * y - w * z), q2 * (x * z + w * y),
            q2 * (x * y + w * z), 1.0 - q2 * (x * x + z * z), q2 * (y * z - w * x),
            q2 * (x * z - w * y), q2 * (y * z + w * x), 1.0 - q2 * (x * x + y * y))


def identity_minus(m):
    """``I − M`` for a 9-tuple ``M``."""
    return (1.0 - m[0], -m[1], -m[2], -m[3], 1.0 - m[4], -m[5], -m[6], -m[7], 1.0 - m[8])


def skew_into(s, at, width, diagonal, v):
    """``diagonal · I + [v]×`` into the 3 × 3 block at ``s[at:]`` of a matrix ``width`` wide."""
    s[at] = diagonal
    s[at + 1] = -v[2]
    s[at + 2] = v[1]
    s[at + width] = v[2]
    s[at + width + 1] = diagonal
    s[at + width + 2] = -v[0]
    s[at + 2 * width] = -v[1]
    s[at + 2 * width + 1] = v[0]
    s[at + 2 * width + 2] = diagonal


def column3_into(s, at, width, v):
    """``v`` into the column at ``s[at:]`` of a matrix ``width`` wide."""
    s[at] = v[0]
    s[at + width] = v[1]
    s[at + 2 * width] = v[2]


def matmul_acc_into(out, out_view, a, a_view, b, b_view, n, k, m):
    """
    ``OUT += A B`` (``n × k`` times ``k × m``), product by product onto each entry.

    Each matrix is an array and a view into it (:func:`rows`, :func:`cols`);
    the arrays may be one and the same.
    """
    for i in range(n):
        for j in range(m):
            ai = a_view[0] + a_view[1] * i
            bj = b_view[0] + b_view[2] * j
            o = out_view[0] + out_view[1] * i + out_view[2] * j
            acc = out[o]
            for t in range(k):
                acc += a[ai + a_view[2] * t] * b[bj + b_view[1] * t]
            out[o] = acc


def fill(s, at, count, value):
    """``s[at:at + count] = value``."""
    for k in range(count):
        s[at + k] = value


def copy_into(out, out_view, a, a_view, n, m):
    """``OUT = A`` (``n × m``; arrays and views, :func:`cols` for a transpose)."""
    for i in range(n):
        for j in range(m):
            out[out_view[0] + out_view[1] * i + out_view[2] * j] = \
                a[a_view[0] + a_view[1] * i + a_view[2] * j]


def symmetrize(s, at, n):
    """``S ← (S + Sᵀ) / 2`` for the ``n × n`` matrix at ``s[at:]`` (row-major)."""
    for i in range(n):
        for j in range(i + 1, n):
            v = 0.5 * (s[at + n * i + j] + s[at + n * j + i])
            s[at + n * i + j] = v
            s[at + n * j + i] = v


def diagonal_into(s, at, width, first, count, value):
    """``value`` into ``count`` diagonal entries from the ``first`` (a matrix ``width`` wide)."""
    for i in range(first, first + count):
        s[at + (width + 1) * i] = value


def add_diagonal(s, at, width, first, count, value):
    """``value`` added to ``count`` diagonal entries from the ``first`` (matrix ``width`` wide)."""
    for i in range(first, first + count):
        s[at + (width + 1) * i] += value
