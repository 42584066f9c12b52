"""
The magnetometer calibration's Kalman filter: its three steps, on the flat state.

Part of the calibration's kernel (:mod:`~ext_observer.core.ahrs.magcal_kernel`,
whose docstring gives the model; the derivations: docs/calibration.md,
"The filter, in equations"): :func:`mc_predict` turns the field with the
gyro's rotation and lets it walk, :func:`mc_update` is one gated update
with a field, :func:`mc_start` starts the filter from a field (a prior, a
loaded calibration or nothing). Each line names its equation; the algebra
is :mod:`~ext_observer.core.ahrs.small_matrix`'s. The same subset of Python
as the kernel's, so numba compiles it (:mod:`~ext_observer.core.ahrs.compiled`).
"""

import math

from .magcal_layout import (GATE, MC_AH, MC_AI, MC_DELAY, MC_DRIFT, MC_FIELD_RW,
                            MC_FIELD_SCALE, MC_FRESH, MC_H, MC_HAS_PRIOR, MC_K, MC_LEARNED,
                            MC_NIS, MC_NOISE, MC_P, MC_PH, MC_PRIOR_COV, MC_PRIOR_P,
                            MC_PRIOR_SCALE, MC_PRIOR_X, MC_REFUSED_SHARE, MC_S, MC_SCALE,
                            MC_SI, MC_SOFT_IRON, MC_X, MC_YY, CAL_D, CAL_DIFFUSE,
                            CAL_LOADED_BIAS_STD, CAL_LOADED_SOFT_SHARE, CAL_N, CAL_NIS_CAP,
                            CAL_NIS_RATE, CAL_NY, CAL_S, CAL_SCALE_FLOOR, CAL_SYMMETRIZE_EVERY,
                            CAL_TAU, CAL_Z)
from .small_matrix import (add3, add_diagonal, add_scaled3, col3_at, cols, column3_into,
                           combination12_into, copy_into, cross3, diagonal_into, dot12,
                           dot12_onto, dot3, fill, identity_minus, mat3_vec_at, mat3t_vec,
                           matmul_acc_into, neg3, quad3_at, rotation_of, rows, scale3, skew_into,
                           store3, sub3, sub_combination12, vec12_at, vec3_at, vec_mat3_at)


# --- prediction ------------------------------------------------------------------

def mc_predict(s, o, rw, rx, ry, rz, dt):
    """
    The field turns against the body and walks in the world.

    With ``s = m + z`` (= ``A y``, the field before the offset is removed):
    ``m ← Rᵀ m`` is ``s ← Rᵀ s + (I − Rᵀ) z``. At rest ``R = I`` and nothing
    ties ``s`` to ``z``, which keeps the covariance well conditioned while
    nothing can be learned.
    """
    r = rotation_of(rw, rx, ry, rz)
    e = identity_minus(r)
    x = o + MC_X
    z = vec3_at(s, x + CAL_Z)
    m = sub3(vec3_at(s, x + CAL_S), z)
    store3(s, x + CAL_S, add3(mat3t_vec(r, m), z))  # s ← Rᵀ m + z, m = s − z
    p = o + MC_P
    for c in range(CAL_N):  # P[s, :] ← Rᵀ P[s, :] + (I − R)ᵀ P[z, :]
        ps = col3_at(s, p + CAL_N * CAL_S + c, CAL_N)
        pz = col3_at(s, p + CAL_N * CAL_Z + c, CAL_N)
        column3_into(s, p + CAL_N * CAL_S + c, CAL_N, add3(mat3t_vec(r, ps), mat3t_vec(e, pz)))
    for i in range(CAL_N):  # P[:, s] ← P[:, s] R + P[:, z] (I − R)
        row = p + CAL_N * i
        ps = vec3_at(s, row + CAL_S)
        pz = vec3_at(s, row + CAL_Z)
        store3(s, row + CAL_S, add3(mat3t_vec(r, ps), mat3t_vec(e, pz)))
    walk = s[o + MC_FIELD_RW] * s[o + MC_FIELD_SCALE]
    add_diagonal(s, p, CAL_N, CAL_S, 3, walk * walk * dt)  # P[s, s] += (rw |m|)² dt
    drift = s[o + MC_DRIFT]
    if drift != 0.0:
        # The offset drifts (temperature, a payload moved): never quite
        # frozen. s = m + z drifts with it.
        a = drift * s[o + MC_FIELD_SCALE]
        mc_drift(s, p, a * a * dt)


def mc_drift(s, p, q):
    """``P[(s, z), (s, z)] += q [[I, I], [I, I]]``: the offset's walk, ``s`` with it."""
    add_diagonal(s, p, CAL_N, CAL_S, 3, q)
    add_diagonal(s, p + CAL_Z, CAL_N, CAL_S, 3, q)
    add_diagonal(s, p + CAL_N * CAL_Z, CAL_N, CAL_S, 3, q)
    add_diagonal(s, p, CAL_N, CAL_Z, 3, q)


# --- update --------------------------------------------------------------------------

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
    if live:
        use = mc_correct(s, o, (y0, y1, y2), (w0, w1, w2))
    learned = s[o + MC_LEARNED] + 1.0
    s[o + MC_LEARNED] = learned
    if learned % CAL_SYMMETRIZE_EVERY == 0.0:
        mc_symmetrize(s, o + MC_P)
    if use:
        mc_field_scale(s, o, norm)
    return use


def mc_correct(s, o, y, w):
    """The update proper: the innovation, its covariance and gate, then the gain; True if used."""
    x = o + MC_X
    sv = vec3_at(s, x + CAL_S)
    tau = s[x + CAL_TAU]
    c = cross3(w, sub3(sv, vec3_at(s, x + CAL_Z)))  # c = ω × m, m = s − z
    ai = o + MC_AI
    mc_inverse_a(s, ai, x + CAL_D)  # A⁻¹ = (I + D(d))⁻¹
    pred = mat3_vec_at(s, ai, add_scaled3(sv, tau, c))  # ŷ = A⁻¹ (s + τ c)
    nu = sub3(y, pred)  # ν = y − ŷ
    mc_jacobian(s, o, scale3(tau, w), pred, c)
    g0, g1, g2 = mc_innovation_covariance(s, o)
    nis = quad3_at(s, o + MC_SI, nu)  # NIS = νᵀ S⁻¹ ν
    capped = nis
    if CAL_NIS_CAP * GATE < nis:
        capped = CAL_NIS_CAP * GATE
    s[o + MC_NIS] = s[o + MC_NIS] + CAL_NIS_RATE * (capped - s[o + MC_NIS])
    if nis < GATE:
        mc_gain_step(s, o, nu, g0, g1, g2)
        return True
    return False


def mc_inverse_a(s, out, d):
    """``A⁻¹ = (I + D(d))⁻¹`` into ``s[out:out + 9]``, ``d`` at ``s[d:d + 5]``."""
    d0, d1, d2, d3, d4 = s[d], s[d + 1], s[d + 2], s[d + 3], s[d + 4]
    mc_inv3(s, out, 1.0 + d0, d2, d3, d2, 1.0 + d1, d4, d3, d4, 1.0 - d0 - d1)


def mc_jacobian(s, o, tw, pred, c):
    """
    ``H``, the Jacobian of ``A ŷ = s + τ ω × (s − z)``, then the measurement's, ``A⁻¹ H``.

    ``tw = τ ω``, ``pred = ŷ``, ``c = ω × (s − z)``.
    """
    h = o + MC_H
    skew_into(s, h + CAL_S, CAL_N, 1.0, tw)  # ∂/∂s = I + τ[ω]×
    skew_into(s, h + CAL_Z, CAL_N, 0.0, neg3(tw))  # ∂/∂z = −τ[ω]×
    mc_regressor_into(s, h + CAL_D, CAL_N, neg3(pred))  # ∂/∂d = −Y(ŷ)
    column3_into(s, h + CAL_TAU, CAL_N, c)  # ∂/∂τ = ω × m
    h0, h1, h2 = vec12_at(s, h, 1), vec12_at(s, h + CAL_N, 1), vec12_at(s, h + 2 * CAL_N, 1)
    for r in range(3):  # (A⁻¹ H)ᵣ = (A⁻¹)ᵣ H
        combination12_into(s, o + MC_AH + CAL_N * r, vec3_at(s, o + MC_AI + 3 * r), h0, h1, h2)


def mc_innovation_covariance(s, o):
    """
    ``P Hᵀ``, ``S = H P Hᵀ + R`` and ``S⁻¹``, ``H`` the measurement's (``A⁻¹ H``).

    Returns the columns of ``P Hᵀ`` (12-tuples), for the gain.
    """
    ah, ph, sm = o + MC_AH, o + MC_PH, o + MC_S
    h0, h1, h2 = vec12_at(s, ah, 1), vec12_at(s, ah + CAL_N, 1), vec12_at(s, ah + 2 * CAL_N, 1)
    for i in range(CAL_N):  # (P Hᵀ)ᵢ = Pᵢ Hᵀ
        pi = vec12_at(s, o + MC_P + CAL_N * i, 1)
        store3(s, ph + 3 * i, (dot12(pi, h0), dot12(pi, h1), dot12(pi, h2)))
    g0, g1, g2 = vec12_at(s, ph, 3), vec12_at(s, ph + 1, 3), vec12_at(s, ph + 2, 3)
    noise = s[o + MC_NOISE] * s[o + MC_FIELD_SCALE]
    r = noise * noise  # R = (noise |m|)² I
    s[sm], s[sm + 1], s[sm + 2] = (dot12_onto(0.0, h0, g0) + r, dot12_onto(0.0, h0, g1),
                                   dot12_onto(0.0, h0, g2))  # S = H (P Hᵀ) + R
    s[sm + 3], s[sm + 4], s[sm + 5] = (dot12_onto(0.0, h1, g0), dot12_onto(0.0, h1, g1) + r,
                                       dot12_onto(0.0, h1, g2))
    s[sm + 6], s[sm + 7], s[sm + 8] = (dot12_onto(0.0, h2, g0), dot12_onto(0.0, h2, g1),
                                       dot12_onto(0.0, h2, g2) + r)
    mc_inv3(s, o + MC_SI, s[sm], s[sm + 1], s[sm + 2], s[sm + 3], s[sm + 4], s[sm + 5],
            s[sm + 6], s[sm + 7], s[sm + 8])
    return g0, g1, g2


def mc_gain_step(s, o, nu, g0, g1, g2):
    """
    ``K = P Hᵀ S⁻¹``, ``x += K ν``, ``P −= K (P Hᵀ)ᵀ``: a row of ``K`` at a time.

    ``g0, g1, g2``: the columns of ``P Hᵀ``.
    """
    x, ph, kk = o + MC_X, o + MC_PH, o + MC_K
    for i in range(CAL_N):
        k = vec_mat3_at(vec3_at(s, ph + 3 * i), s, o + MC_SI)  # Kᵢ = (P Hᵀ)ᵢ S⁻¹
        store3(s, kk + 3 * i, k)
        s[x + i] += dot3(k, nu)  # xᵢ += Kᵢ ν
        sub_combination12(s, o + MC_P + CAL_N * i, k, g0, g1, g2)  # Pᵢ −= Kᵢ (P Hᵀ)ᵀ


def mc_field_scale(s, o, norm):
    """The field's norm the noises scale with: ``|s − z|``, at least a share of ``norm``."""
    x = o + MC_X
    m = sub3(vec3_at(s, x + CAL_S), vec3_at(s, x + CAL_Z))
    scale = math.sqrt(dot3(m, m))
    if CAL_SCALE_FLOOR * norm > scale:
        scale = CAL_SCALE_FLOOR * norm
    s[o + MC_FIELD_SCALE] = scale


# --- start -----------------------------------------------------------------------------

def mc_start(s, o, y0, y1, y2, norm):
    """Initialize the filter from the field ``y`` (of norm ``norm``)."""
    fill(s, o + MC_X, CAL_N + CAL_N * CAL_N, 0.0)
    if s[o + MC_HAS_PRIOR] == 0.0:
        mc_prior_unknown(s, o, norm)
    elif s[o + MC_PRIOR_COV] != 0.0:
        mc_prior_kept(s, o)
    else:
        mc_prior_loaded(s, o, norm)
    mc_start_field(s, o, (y0, y1, y2), norm)
    mc_field_scale(s, o, norm)
    s[o + MC_REFUSED_SHARE] = 0.0
    s[o + MC_FRESH] = 0.0


def mc_prior_unknown(s, o, norm):
    """Nothing known: ``z`` diffuse, ``d`` and ``τ`` about 0 with their parameters' spread."""
    s[o + MC_SCALE] = 1.0
    mc_prior_spread(s, o, CAL_DIFFUSE * norm, s[o + MC_SOFT_IRON], s[o + MC_DELAY])


def mc_prior_kept(s, o):
    """A restart: ``(z, d, τ)`` and their covariance as learned before."""
    mc_prior_x(s, o)
    copy_into(s, rows(o + MC_P + (CAL_N + 1) * CAL_Z, CAL_N), s, rows(o + MC_PRIOR_P, 9), 9, 9)


def mc_prior_loaded(s, o, norm):
    """A loaded calibration: ``(z, d, τ)`` as loaded, a tighter prior about it."""
    mc_prior_x(s, o)
    soft = CAL_LOADED_SOFT_SHARE * s[o + MC_SOFT_IRON]
    mc_prior_spread(s, o, CAL_LOADED_BIAS_STD * norm / s[o + MC_SCALE], soft, s[o + MC_DELAY])


def mc_prior_spread(s, o, z_std, d_std, tau_std):
    """``P[z d τ, z d τ]`` diagonal, with these standard deviations."""
    p = o + MC_P
    diagonal_into(s, p, CAL_N, CAL_Z, 3, z_std * z_std)
    diagonal_into(s, p, CAL_N, CAL_D, CAL_NY, d_std * d_std)
    s[p + (CAL_N + 1) * CAL_TAU] = tau_std * tau_std


def mc_prior_x(s, o):
    """``x[3:]`` and the scale from the prior."""
    copy_into(s, rows(o + MC_X + CAL_Z, 1), s, rows(o + MC_PRIOR_X, 1), 9, 1)
    s[o + MC_SCALE] = s[o + MC_PRIOR_SCALE]


def mc_start_field(s, o, y, norm):
    """
    ``s = A y = y + Y(y) d``: as uncertain as ``d`` (and correlated with it), plus the noise.

    Independent of the offset.
    """
    x, p, yy, t = o + MC_X, o + MC_P, o + MC_YY, o + MC_K
    mc_regressor_into(s, yy, CAL_NY, y)
    matmul_acc_into(s, rows(x, 1), s, rows(yy, CAL_NY), s, rows(x + CAL_D, 1), 3, CAL_NY, 1)
    store3(s, x + CAL_S, add3(y, vec3_at(s, x + CAL_S)))  # s = y + Y d
    pd = rows(p + CAL_N * CAL_D + CAL_Z, CAL_N)  # P[d, 3:]
    matmul_acc_into(s, rows(p + CAL_Z, CAL_N), s, rows(yy, CAL_NY), s, pd, 3, CAL_NY,
                    CAL_N - CAL_Z)
    copy_into(s, cols(p + CAL_N * CAL_Z, CAL_N), s, rows(p + CAL_Z, CAL_N), 3, CAL_N - CAL_Z)
    # P[s, s] = Y P[d, d] Yᵀ + noise² I, Y P[d, d] in the scratch of K
    fill(s, t, 3 * CAL_NY, 0.0)
    pdd = rows(p + (CAL_N + 1) * CAL_D, CAL_N)
    matmul_acc_into(s, rows(t, CAL_NY), s, rows(yy, CAL_NY), s, pdd, 3, CAL_NY, CAL_NY)
    matmul_acc_into(s, rows(p, CAL_N), s, rows(t, CAL_NY), s, cols(yy, CAL_NY), 3, CAL_NY, 3)
    noise = s[o + MC_NOISE] * norm
    add_diagonal(s, p, CAL_N, CAL_S, 3, noise * noise)


# --- helpers ----------------------------------------------------------------------------

def mc_regressor_into(s, at, width, y):
    """``Y(y)`` (3 × 5, ``D(d) y = Y(y) d``) into ``s[at:]``, its rows ``width`` apart."""
    s[at], s[at + 1], s[at + 2], s[at + 3], s[at + 4] = y[0], 0.0, y[1], y[2], 0.0
    r = at + width
    s[r], s[r + 1], s[r + 2], s[r + 3], s[r + 4] = 0.0, y[1], y[0], 0.0, y[2]
    r = at + 2 * width
    s[r], s[r + 1], s[r + 2], s[r + 3], s[r + 4] = -y[2], -y[2], 0.0, y[0], y[1]


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
