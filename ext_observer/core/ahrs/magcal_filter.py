"""
The magnetometer calibration's Kalman filter: its three steps, on the flat state.

Part of the calibration's kernel (:mod:`~ext_observer.core.ahrs.magcal_kernel`,
whose docstring gives the model): :func:`mc_predict` turns the field with
the gyro's rotation and lets it walk, :func:`mc_update` is one gated update
with a field, :func:`mc_start` starts the filter from a field (a prior, a
loaded calibration or nothing), with the written-out 3 × 3 inverse and the
symmetrization they use. The same subset of Python as the kernel's, so
numba compiles it (:mod:`~ext_observer.core.ahrs.compiled`).
"""

import math

from .magcal_layout import (GATE, MC_AH, MC_AI, MC_DELAY, MC_DRIFT, MC_FIELD_RW,
                            MC_FIELD_SCALE, MC_FRESH, MC_H, MC_HAS_PRIOR, MC_K, MC_LEARNED,
                            MC_NIS, MC_NOISE, MC_P, MC_PH, MC_PRIOR_COV, MC_PRIOR_P,
                            MC_PRIOR_SCALE, MC_PRIOR_X, MC_REFUSED_SHARE, MC_S, MC_SCALE,
                            MC_SI, MC_SOFT_IRON, MC_X, MC_YY, CAL_DIFFUSE, CAL_LOADED_BIAS_STD,
                            CAL_N)


def mc_predict(s, o, rw, rx, ry, rz, dt):
    """
    The field turns against the body and walks in the world.

    With ``s = m + z`` (= ``A y``, the field before the offset is removed):
    ``m ← Rᵀ m`` is ``s ← Rᵀ s + (I − Rᵀ) z``. At rest ``R = I`` and nothing
    ties ``s`` to ``z``, which keeps the covariance well conditioned while
    nothing can be learned.
    """
    q2 = 2.0 / (rw * rw + rx * rx + ry * ry + rz * rz)
    r00 = 1.0 - q2 * (ry * ry + rz * rz)
    r01 = q2 * (rx * ry - rw * rz)
    r02 = q2 * (rx * rz + rw * ry)
    r10 = q2 * (rx * ry + rw * rz)
    r11 = 1.0 - q2 * (rx * rx + rz * rz)
    r12 = q2 * (ry * rz - rw * rx)
    r20 = q2 * (rx * rz - rw * ry)
    r21 = q2 * (ry * rz + rw * rx)
    r22 = 1.0 - q2 * (rx * rx + ry * ry)
    # I − R
    e00 = 1.0 - r00
    e11 = 1.0 - r11
    e22 = 1.0 - r22
    x = o + MC_X
    z0 = s[x + 3]
    z1 = s[x + 4]
    z2 = s[x + 5]
    v0 = s[x] - z0
    v1 = s[x + 1] - z1
    v2 = s[x + 2] - z2
    s[x] = r00 * v0 + r10 * v1 + r20 * v2 + z0
    s[x + 1] = r01 * v0 + r11 * v1 + r21 * v2 + z1
    s[x + 2] = r02 * v0 + r12 * v1 + r22 * v2 + z2
    p = o + MC_P
    # P[s, :] ← Rᵀ P[s, :] + (I − Rᵀ) P[z, :]
    for c in range(CAL_N):
        a0 = s[p + c]
        a1 = s[p + CAL_N + c]
        a2 = s[p + 2 * CAL_N + c]
        b0 = s[p + 3 * CAL_N + c]
        b1 = s[p + 4 * CAL_N + c]
        b2 = s[p + 5 * CAL_N + c]
        s[p + c] = (r00 * a0 + r10 * a1 + r20 * a2) + (e00 * b0 - r10 * b1 - r20 * b2)
        s[p + CAL_N + c] = (r01 * a0 + r11 * a1 + r21 * a2) + (-r01 * b0 + e11 * b1 - r21 * b2)
        s[p + 2 * CAL_N + c] = (r02 * a0 + r12 * a1 + r22 * a2) + (-r02 * b0 - r12 * b1
                                                                + e22 * b2)
    # P[:, s] ← P[:, s] R + P[:, z] (I − R)
    for i in range(CAL_N):
        row = p + CAL_N * i
        a0 = s[row]
        a1 = s[row + 1]
        a2 = s[row + 2]
        b0 = s[row + 3]
        b1 = s[row + 4]
        b2 = s[row + 5]
        s[row] = (a0 * r00 + a1 * r10 + a2 * r20) + (b0 * e00 - b1 * r10 - b2 * r20)
        s[row + 1] = (a0 * r01 + a1 * r11 + a2 * r21) + (-b0 * r01 + b1 * e11 - b2 * r21)
        s[row + 2] = (a0 * r02 + a1 * r12 + a2 * r22) + (-b0 * r02 - b1 * r12 + b2 * e22)
    a = s[o + MC_FIELD_RW] * s[o + MC_FIELD_SCALE]
    q = a * a * dt
    for i in range(3):
        s[p + (CAL_N + 1) * i] += q
    drift = s[o + MC_DRIFT]
    if drift != 0.0:
        # The offset drifts (temperature, a payload moved): never quite
        # frozen. s = m + z drifts with it.
        a = drift * s[o + MC_FIELD_SCALE]
        q = a * a * dt
        for i in range(3):
            s[p + (CAL_N + 1) * i] += q
        for i in range(3):
            s[p + CAL_N * i + 3 + i] += q
        for i in range(3):
            s[p + CAL_N * (3 + i) + i] += q
        for i in range(3):
            s[p + (CAL_N + 1) * (3 + i)] += q


def mc_update(s, o, y0, y1, y2, w0, w1, w2, live, norm):
    """
    One (gated) Kalman update with ``y = A⁻¹ (s + τ ω × (s − z))``; 1.0 if used.

    Linear in ``s`` and ``z``, linearized in ``d`` and ``τ`` about the
    estimate: the measured ``y`` never enters the gain (written as
    ``A y = s + …`` with ``y`` in the regressor, its noise would pull ``A``
    towards 0 at rest, the errors-in-variables bias). Where not ``live``
    only the step is counted.
    """
    use = False
    x = o + MC_X
    p = o + MC_P
    if live:
        s0 = s[x]
        s1 = s[x + 1]
        s2 = s[x + 2]
        z0 = s[x + 3]
        z1 = s[x + 4]
        z2 = s[x + 5]
        d0 = s[x + 6]
        d1 = s[x + 7]
        d2 = s[x + 8]
        d3 = s[x + 9]
        d4 = s[x + 10]
        tau = s[x + 11]
        m0 = s0 - z0
        m1 = s1 - z1
        m2 = s2 - z2
        c0 = w1 * m2 - w2 * m1
        c1 = w2 * m0 - w0 * m2
        c2 = w0 * m1 - w1 * m0
        ai = o + MC_AI
        mc_inv3(s, ai, 1.0 + d0, d2, d3, d2, 1.0 + d1, d4, d3, d4, 1.0 - d0 - d1)
        v0 = s0 + tau * c0
        v1 = s1 + tau * c1
        v2 = s2 + tau * c2
        p0 = s[ai] * v0 + s[ai + 1] * v1 + s[ai + 2] * v2
        p1 = s[ai + 3] * v0 + s[ai + 4] * v1 + s[ai + 5] * v2
        p2 = s[ai + 6] * v0 + s[ai + 7] * v1 + s[ai + 8] * v2
        nu0 = y0 - p0
        nu1 = y1 - p1
        nu2 = y2 - p2
        tw0 = tau * w0
        tw1 = tau * w1
        tw2 = tau * w2
        # H: I + τ[ω]× for s, −τ[ω]× for z, −Y(pred) for d, ω × m for τ;
        # then A⁻¹ H.
        h = o + MC_H
        for k in range(36):
            s[h + k] = 0.0
        s[h] = 1.0
        s[h + 1] = -tw2
        s[h + 2] = tw1
        s[h + 4] = tw2
        s[h + 5] = -tw1
        s[h + 6] = -p0
        s[h + 8] = -p1
        s[h + 9] = -p2
        s[h + 11] = c0
        s[h + 12] = tw2
        s[h + 13] = 1.0
        s[h + 14] = -tw0
        s[h + 15] = -tw2
        s[h + 17] = tw0
        s[h + 19] = -p1
        s[h + 20] = -p0
        s[h + 22] = -p2
        s[h + 23] = c1
        s[h + 24] = -tw1
        s[h + 25] = tw0
        s[h + 26] = 1.0
        s[h + 27] = tw1
        s[h + 28] = -tw0
        s[h + 30] = p2
        s[h + 31] = p2
        s[h + 33] = -p0
        s[h + 34] = -p1
        s[h + 35] = c2
        ah = o + MC_AH
        for r in range(3):
            a0 = s[ai + 3 * r]
            a1 = s[ai + 3 * r + 1]
            a2 = s[ai + 3 * r + 2]
            for c in range(CAL_N):
                s[ah + CAL_N * r + c] = (a0 * s[h + c] + a1 * s[h + CAL_N + c]
                                         + a2 * s[h + 2 * CAL_N + c])
        # P Hᵀ, and S = H P Hᵀ + R summed along (the rows of P Hᵀ in order).
        # Written out, with the rows of A⁻¹ H held: the hot loop.
        a0, a1, a2, a3, a4, a5 = s[ah], s[ah + 1], s[ah + 2], s[ah + 3], s[ah + 4], s[ah + 5]
        a6, a7, a8, a9, a10, a11 = (s[ah + 6], s[ah + 7], s[ah + 8], s[ah + 9], s[ah + 10],
                                    s[ah + 11])
        b = ah + CAL_N
        b0, b1, b2, b3, b4, b5 = s[b], s[b + 1], s[b + 2], s[b + 3], s[b + 4], s[b + 5]
        b6, b7, b8, b9, b10, b11 = s[b + 6], s[b + 7], s[b + 8], s[b + 9], s[b + 10], s[b + 11]
        e = ah + 2 * CAL_N
        e0, e1, e2, e3, e4, e5 = s[e], s[e + 1], s[e + 2], s[e + 3], s[e + 4], s[e + 5]
        e6, e7, e8, e9, e10, e11 = s[e + 6], s[e + 7], s[e + 8], s[e + 9], s[e + 10], s[e + 11]
        ph = o + MC_PH
        s00 = s01 = s02 = s10 = s11 = s12 = s20 = s21 = s22 = 0.0
        for i in range(CAL_N):
            row = p + CAL_N * i
            q0, q1, q2, q3, q4, q5 = (s[row], s[row + 1], s[row + 2], s[row + 3], s[row + 4],
                                      s[row + 5])
            q6, q7, q8, q9, q10, q11 = (s[row + 6], s[row + 7], s[row + 8], s[row + 9],
                                        s[row + 10], s[row + 11])
            v0 = (q0 * a0 + q1 * a1 + q2 * a2 + q3 * a3 + q4 * a4 + q5 * a5 + q6 * a6 + q7 * a7
                  + q8 * a8 + q9 * a9 + q10 * a10 + q11 * a11)
            v1 = (q0 * b0 + q1 * b1 + q2 * b2 + q3 * b3 + q4 * b4 + q5 * b5 + q6 * b6 + q7 * b7
                  + q8 * b8 + q9 * b9 + q10 * b10 + q11 * b11)
            v2 = (q0 * e0 + q1 * e1 + q2 * e2 + q3 * e3 + q4 * e4 + q5 * e5 + q6 * e6 + q7 * e7
                  + q8 * e8 + q9 * e9 + q10 * e10 + q11 * e11)
            s[ph + 3 * i] = v0
            s[ph + 3 * i + 1] = v1
            s[ph + 3 * i + 2] = v2
            f0 = s[ah + i]
            f1 = s[b + i]
            f2 = s[e + i]
            s00 += f0 * v0
            s01 += f0 * v1
            s02 += f0 * v2
            s10 += f1 * v0
            s11 += f1 * v1
            s12 += f1 * v2
            s20 += f2 * v0
            s21 += f2 * v1
            s22 += f2 * v2
        a = s[o + MC_NOISE] * s[o + MC_FIELD_SCALE]
        a = a * a
        s00 += a
        s11 += a
        s22 += a
        sm = o + MC_S
        s[sm] = s00
        s[sm + 1] = s01
        s[sm + 2] = s02
        s[sm + 3] = s10
        s[sm + 4] = s11
        s[sm + 5] = s12
        s[sm + 6] = s20
        s[sm + 7] = s21
        s[sm + 8] = s22
        si = o + MC_SI
        mc_inv3(s, si, s00, s01, s02, s10, s11, s12, s20, s21, s22)
        i00, i01, i02, i10, i11, i12 = s[si], s[si + 1], s[si + 2], s[si + 3], s[si + 4], s[si + 5]
        i20, i21, i22 = s[si + 6], s[si + 7], s[si + 8]
        nis = (nu0 * i00 * nu0 + nu0 * i01 * nu1 + nu0 * i02 * nu2
               + nu1 * i10 * nu0 + nu1 * i11 * nu1 + nu1 * i12 * nu2
               + nu2 * i20 * nu0 + nu2 * i21 * nu1 + nu2 * i22 * nu2)
        use = nis < GATE
        capped = nis
        if 3.0 * GATE < nis:
            capped = 3.0 * GATE
        s[o + MC_NIS] = s[o + MC_NIS] + 0.02 * (capped - s[o + MC_NIS])
        if use:
            # K = P Hᵀ S⁻¹, x += K ν, P −= K (P Hᵀ)ᵀ, a row of K at a time.
            g0a, g0b, g0c = s[ph], s[ph + 1], s[ph + 2]
            g1a, g1b, g1c = s[ph + 3], s[ph + 4], s[ph + 5]
            g2a, g2b, g2c = s[ph + 6], s[ph + 7], s[ph + 8]
            g3a, g3b, g3c = s[ph + 9], s[ph + 10], s[ph + 11]
            g4a, g4b, g4c = s[ph + 12], s[ph + 13], s[ph + 14]
            g5a, g5b, g5c = s[ph + 15], s[ph + 16], s[ph + 17]
            g6a, g6b, g6c = s[ph + 18], s[ph + 19], s[ph + 20]
            g7a, g7b, g7c = s[ph + 21], s[ph + 22], s[ph + 23]
            g8a, g8b, g8c = s[ph + 24], s[ph + 25], s[ph + 26]
            g9a, g9b, g9c = s[ph + 27], s[ph + 28], s[ph + 29]
            g10a, g10b, g10c = s[ph + 30], s[ph + 31], s[ph + 32]
            g11a, g11b, g11c = s[ph + 33], s[ph + 34], s[ph + 35]
            kk = o + MC_K
            for i in range(CAL_N):
                f0 = s[ph + 3 * i]
                f1 = s[ph + 3 * i + 1]
                f2 = s[ph + 3 * i + 2]
                k0 = f0 * i00 + f1 * i10 + f2 * i20
                k1 = f0 * i01 + f1 * i11 + f2 * i21
                k2 = f0 * i02 + f1 * i12 + f2 * i22
                s[kk + 3 * i] = k0
                s[kk + 3 * i + 1] = k1
                s[kk + 3 * i + 2] = k2
                s[x + i] += k0 * nu0 + k1 * nu1 + k2 * nu2
                row = p + CAL_N * i
                s[row] -= k0 * g0a + k1 * g0b + k2 * g0c
                s[row + 1] -= k0 * g1a + k1 * g1b + k2 * g1c
                s[row + 2] -= k0 * g2a + k1 * g2b + k2 * g2c
                s[row + 3] -= k0 * g3a + k1 * g3b + k2 * g3c
                s[row + 4] -= k0 * g4a + k1 * g4b + k2 * g4c
                s[row + 5] -= k0 * g5a + k1 * g5b + k2 * g5c
                s[row + 6] -= k0 * g6a + k1 * g6b + k2 * g6c
                s[row + 7] -= k0 * g7a + k1 * g7b + k2 * g7c
                s[row + 8] -= k0 * g8a + k1 * g8b + k2 * g8c
                s[row + 9] -= k0 * g9a + k1 * g9b + k2 * g9c
                s[row + 10] -= k0 * g10a + k1 * g10b + k2 * g10c
                s[row + 11] -= k0 * g11a + k1 * g11b + k2 * g11c
    learned = s[o + MC_LEARNED] + 1.0
    s[o + MC_LEARNED] = learned
    if learned % 64.0 == 0.0:  # rounding makes P drift from symmetric, slowly
        mc_symmetrize(s, p)
    if use:
        m0 = s[x] - s[x + 3]
        m1 = s[x + 1] - s[x + 4]
        m2 = s[x + 2] - s[x + 5]
        scale = math.sqrt(m0 * m0 + m1 * m1 + m2 * m2)
        if 0.25 * norm > scale:
            scale = 0.25 * norm
        s[o + MC_FIELD_SCALE] = scale
    return use


def mc_start(s, o, y0, y1, y2, norm):
    """Initialize the filter from the field ``y`` (of norm ``norm``)."""
    x = o + MC_X
    p = o + MC_P
    for k in range(CAL_N + CAL_N * CAL_N):
        s[x + k] = 0.0
    soft = s[o + MC_SOFT_IRON]
    delay = s[o + MC_DELAY]
    if s[o + MC_HAS_PRIOR] == 0.0:
        s[o + MC_SCALE] = 1.0
        big = CAL_DIFFUSE * norm
        big = big * big
        for i in range(3, 6):
            s[p + (CAL_N + 1) * i] = big
        for i in range(6, 11):
            s[p + (CAL_N + 1) * i] = soft * soft
        s[p + (CAL_N + 1) * 11] = delay * delay
    else:
        for k in range(9):
            s[x + 3 + k] = s[o + MC_PRIOR_X + k]
        s[o + MC_SCALE] = s[o + MC_PRIOR_SCALE]
        if s[o + MC_PRIOR_COV] != 0.0:
            for i in range(9):
                for j in range(9):
                    s[p + CAL_N * (3 + i) + 3 + j] = s[o + MC_PRIOR_P + 9 * i + j]
        else:  # loaded: a tighter prior about it
            std = CAL_LOADED_BIAS_STD * norm / s[o + MC_SCALE]
            for i in range(3, 6):
                s[p + (CAL_N + 1) * i] = std * std
            a = 0.2 * soft
            for i in range(6, 11):
                s[p + (CAL_N + 1) * i] = a * a
            s[p + (CAL_N + 1) * 11] = delay * delay
    # s = A y = y + Y(y) d: as uncertain as d (and correlated with it),
    # plus the noise; independent of the offset.
    yy = o + MC_YY
    for k in range(15):
        s[yy + k] = 0.0
    s[yy] = y0
    s[yy + 2] = y1
    s[yy + 3] = y2
    s[yy + 6] = y1
    s[yy + 7] = y0
    s[yy + 9] = y2
    s[yy + 10] = -y2
    s[yy + 11] = -y2
    s[yy + 13] = y0
    s[yy + 14] = y1
    for r in range(3):
        acc = 0.0
        for k in range(5):
            acc += s[yy + 5 * r + k] * s[x + 6 + k]
        s[x + r] = (y0 if r == 0 else y1 if r == 1 else y2) + acc
    # P[s, 3:] = Y P[d, 3:], and its transpose
    for r in range(3):
        for c in range(3, CAL_N):
            acc = 0.0
            for k in range(5):
                acc += s[yy + 5 * r + k] * s[p + CAL_N * (6 + k) + c]
            s[p + CAL_N * r + c] = acc
    for r in range(3):
        for c in range(3, CAL_N):
            s[p + CAL_N * c + r] = s[p + CAL_N * r + c]
    # P[s, s] = Y P[d, d] Yᵀ + noise² I; Y P[d, d] into the scratch of K
    t = o + MC_K
    for r in range(3):
        for c in range(5):
            acc = 0.0
            for k in range(5):
                acc += s[yy + 5 * r + k] * s[p + CAL_N * (6 + k) + 6 + c]
            s[t + 5 * r + c] = acc
    noise = s[o + MC_NOISE] * norm
    for r in range(3):
        for c in range(3):
            acc = 0.0
            for k in range(5):
                acc += s[t + 5 * r + k] * s[yy + 5 * c + k]
            if r == c:
                acc += noise * noise
            s[p + CAL_N * r + c] = acc
    m0 = s[x] - s[x + 3]
    m1 = s[x + 1] - s[x + 4]
    m2 = s[x + 2] - s[x + 5]
    scale = math.sqrt(m0 * m0 + m1 * m1 + m2 * m2)
    if 0.25 * norm > scale:
        scale = 0.25 * norm
    s[o + MC_FIELD_SCALE] = scale
    s[o + MC_REFUSED_SHARE] = 0.0
    s[o + MC_FRESH] = 0.0


def mc_inv3(s, out, a, b, c, d, e, f, g, h, i):
    """The inverse of ``[[a, b, c], [d, e, f], [g, h, i]]`` (cofactors) into ``s[out:out + 9]``."""
    c00 = e * i - f * h
    c01 = f * g - d * i
    c02 = d * h - e * g
    det = a * c00 + b * c01 + c * c02
    s[out] = c00 / det
    s[out + 1] = (c * h - b * i) / det
    s[out + 2] = (b * f - c * e) / det
    s[out + 3] = c01 / det
    s[out + 4] = (a * i - c * g) / det
    s[out + 5] = (c * d - a * f) / det
    s[out + 6] = c02 / det
    s[out + 7] = (b * g - a * h) / det
    s[out + 8] = (a * e - b * d) / det


def mc_symmetrize(s, p):
    """``P ← (P + Pᵀ) / 2`` for the 12 × 12 matrix at ``s[p:]``."""
    for i in range(CAL_N):
        for j in range(i + 1, CAL_N):
            v = 0.5 * (s[p + CAL_N * i + j] + s[p + CAL_N * j + i])
            s[p + CAL_N * i + j] = v
            s[p + CAL_N * j + i] = v
