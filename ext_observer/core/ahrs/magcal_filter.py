"""
The magnetometer calibration's Kalman filter: its three steps, on the calibrator's record.

Part of the calibration's kernel (:mod:`~ext_observer.core.ahrs.magcal_kernel`,
whose docstring gives the model; the derivations: docs/calibration.md,
"The filter, in equations"): :func:`mc_predict` turns the field with the
gyro's rotation and lets it walk, :func:`mc_update` is one gated update
with a field, :func:`mc_start` starts the filter from a field (a prior, a
loaded calibration or nothing). Each takes the calibrator's record ``cal``
(:data:`~ext_observer.core.ahrs.magcal_layout.CAL`) and works on its fields
by name: the filter's state ``cal.x`` (its parts read through
:mod:`~ext_observer.core.ahrs.magcal_layout`'s ``offset_of``, ...), its
covariance ``cal.p`` (its blocks at the parts' rows, ``CAL_S``, ``CAL_Z``,
...) and the scratch of its matrices. Each line names its equation; the algebra is
:mod:`~ext_observer.core.ahrs.small_matrix`'s. The same subset of Python as
the kernel's, so numba compiles it (:mod:`~ext_observer.core.ahrs.compiled`).
"""

import math

from .magcal_layout import (GATE, CAL_D, CAL_DIFFUSE, CAL_LOADED_BIAS_STD,
                            CAL_LOADED_SOFT_SHARE, CAL_N, CAL_NIS_CAP, CAL_NIS_RATE, CAL_NY,
                            CAL_S, CAL_SCALE_FLOOR, CAL_SYMMETRIZE_EVERY, CAL_TAU, CAL_Z,
                            CAL_ZDT, field_with_offset_of, lag_of, offset_of,
                            set_field_with_offset, soft_iron_of)
from .small_matrix import (add3, add_diagonal, add_scaled3, col3_at, cols, column3_into,
                           combination12_into, copy_into, cross3, diagonal_into, dot12,
                           dot12_onto, dot3, fill, identity_minus, mat3_vec_at, mat3t_vec,
                           matmul_acc_into, neg3, quad3_at, rotation_of, rows, scale3, skew_into,
                           store3, sub3, sub_combination12, symmetrize, vec12_at, vec3_at,
                           vec_mat3_at)


# --- prediction ------------------------------------------------------------------

def mc_predict(cal, rw, rx, ry, rz, dt):
    """
    The field turns against the body and walks in the world.

    With ``s = m + z`` (= ``A y``, the field before the offset is removed):
    ``m ← Rᵀ m`` is ``s ← Rᵀ s + (I − Rᵀ) z``. At rest ``R = I`` and nothing
    ties ``s`` to ``z``, which keeps the covariance well conditioned while
    nothing can be learned.
    """
    r = rotation_of(rw, rx, ry, rz)
    e = identity_minus(r)
    x, p = cal.x, cal.p
    z = offset_of(x)
    m = sub3(field_with_offset_of(x), z)
    set_field_with_offset(x, add3(mat3t_vec(r, m), z))  # s ← Rᵀ m + z, m = s − z
    for j in range(CAL_N):  # P[s, :] ← Rᵀ P[s, :] + (I − R)ᵀ P[z, :]
        ps = col3_at(p, CAL_N * CAL_S + j, CAL_N)
        pz = col3_at(p, CAL_N * CAL_Z + j, CAL_N)
        column3_into(p, CAL_N * CAL_S + j, CAL_N, add3(mat3t_vec(r, ps), mat3t_vec(e, pz)))
    for i in range(CAL_N):  # P[:, s] ← P[:, s] R + P[:, z] (I − R)
        row = CAL_N * i
        ps = vec3_at(p, row + CAL_S)
        pz = vec3_at(p, row + CAL_Z)
        store3(p, row + CAL_S, add3(mat3t_vec(r, ps), mat3t_vec(e, pz)))
    walk = cal.field_rw * cal.field_scale
    add_diagonal(p, 0, CAL_N, CAL_S, 3, walk * walk * dt)  # P[s, s] += (rw |m|)² dt
    drift = cal.drift
    if drift != 0.0:
        # The offset drifts (temperature, a payload moved): never quite
        # frozen. s = m + z drifts with it.
        a = drift * cal.field_scale
        mc_drift(p, a * a * dt)


def mc_drift(p, q):
    """``P[(s, z), (s, z)] += q [[I, I], [I, I]]``: the offset's walk, ``s`` with it."""
    add_diagonal(p, 0, CAL_N, CAL_S, 3, q)
    add_diagonal(p, CAL_Z, CAL_N, CAL_S, 3, q)
    add_diagonal(p, CAL_N * CAL_Z, CAL_N, CAL_S, 3, q)
    add_diagonal(p, 0, CAL_N, CAL_Z, 3, q)


# --- update --------------------------------------------------------------------------

def mc_update(cal, y0, y1, y2, w0, w1, w2, live, norm):
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
        use = mc_correct(cal, (y0, y1, y2), (w0, w1, w2))
    learned = cal.learned + 1.0
    cal.learned = learned
    if learned % CAL_SYMMETRIZE_EVERY == 0.0:
        symmetrize(cal.p, 0, CAL_N)
    if use:
        mc_field_scale(cal, norm)
    return use


def mc_correct(cal, y, w):
    """The update proper: the innovation, its covariance and gate, then the gain; True if used."""
    x = cal.x
    sv = field_with_offset_of(x)
    tau = lag_of(x)
    c = cross3(w, sub3(sv, offset_of(x)))  # c = ω × m, m = s − z
    mc_inverse_a(cal)  # A⁻¹ = (I + D(d))⁻¹
    pred = mat3_vec_at(cal.ai, 0, add_scaled3(sv, tau, c))  # ŷ = A⁻¹ (s + τ c)
    nu = sub3(y, pred)  # ν = y − ŷ
    mc_jacobian(cal, scale3(tau, w), pred, c)
    g0, g1, g2 = mc_innovation_covariance(cal)
    nis = quad3_at(cal.si, 0, nu)  # NIS = νᵀ S⁻¹ ν
    capped = nis
    if CAL_NIS_CAP * GATE < nis:
        capped = CAL_NIS_CAP * GATE
    cal.nis = cal.nis + CAL_NIS_RATE * (capped - cal.nis)
    if nis < GATE:
        mc_gain_step(cal, nu, g0, g1, g2)
        return True
    return False


def mc_inverse_a(cal):
    """``A⁻¹ = (I + D(d))⁻¹`` into ``cal.ai``, ``d`` from ``cal.x``."""
    d0, d1, d2, d3, d4 = soft_iron_of(cal.x)
    mc_inv3(cal.ai, 1.0 + d0, d2, d3, d2, 1.0 + d1, d4, d3, d4, 1.0 - d0 - d1)


def mc_jacobian(cal, tw, pred, c):
    """
    ``H``, the Jacobian of ``A ŷ = s + τ ω × (s − z)``, then the measurement's, ``A⁻¹ H``.

    ``tw = τ ω``, ``pred = ŷ``, ``c = ω × (s − z)``.
    """
    h = cal.h
    skew_into(h, CAL_S, CAL_N, 1.0, tw)  # ∂/∂s = I + τ[ω]×
    skew_into(h, CAL_Z, CAL_N, 0.0, neg3(tw))  # ∂/∂z = −τ[ω]×
    mc_regressor_into(h, CAL_D, CAL_N, neg3(pred))  # ∂/∂d = −Y(ŷ)
    column3_into(h, CAL_TAU, CAL_N, c)  # ∂/∂τ = ω × m
    h0, h1, h2 = vec12_at(h, 0, 1), vec12_at(h, CAL_N, 1), vec12_at(h, 2 * CAL_N, 1)
    for r in range(3):  # (A⁻¹ H)ᵣ = (A⁻¹)ᵣ H
        combination12_into(cal.ah, CAL_N * r, vec3_at(cal.ai, 3 * r), h0, h1, h2)


def mc_innovation_covariance(cal):
    """
    ``P Hᵀ``, ``S = H P Hᵀ + R`` and ``S⁻¹``, ``H`` the measurement's (``A⁻¹ H``).

    Returns the columns of ``P Hᵀ`` (12-tuples), for the gain.
    """
    ah, ph, sm, p = cal.ah, cal.ph, cal.s, cal.p
    h0, h1, h2 = vec12_at(ah, 0, 1), vec12_at(ah, CAL_N, 1), vec12_at(ah, 2 * CAL_N, 1)
    for i in range(CAL_N):  # (P Hᵀ)ᵢ = Pᵢ Hᵀ
        pi = vec12_at(p, CAL_N * i, 1)
        store3(ph, 3 * i, (dot12(pi, h0), dot12(pi, h1), dot12(pi, h2)))
    g0, g1, g2 = vec12_at(ph, 0, 3), vec12_at(ph, 1, 3), vec12_at(ph, 2, 3)
    noise = cal.noise * cal.field_scale
    r = noise * noise  # R = (noise |m|)² I
    sm[0], sm[1], sm[2] = (dot12_onto(0.0, h0, g0) + r, dot12_onto(0.0, h0, g1),
                           dot12_onto(0.0, h0, g2))  # S = H (P Hᵀ) + R
    sm[3], sm[4], sm[5] = (dot12_onto(0.0, h1, g0), dot12_onto(0.0, h1, g1) + r,
                           dot12_onto(0.0, h1, g2))
    sm[6], sm[7], sm[8] = (dot12_onto(0.0, h2, g0), dot12_onto(0.0, h2, g1),
                           dot12_onto(0.0, h2, g2) + r)
    mc_inv3(cal.si, sm[0], sm[1], sm[2], sm[3], sm[4], sm[5], sm[6], sm[7], sm[8])
    return g0, g1, g2


def mc_gain_step(cal, nu, g0, g1, g2):
    """
    ``K = P Hᵀ S⁻¹``, ``x += K ν``, ``P −= K (P Hᵀ)ᵀ``: a row of ``K`` at a time.

    ``g0, g1, g2``: the columns of ``P Hᵀ``.
    """
    x, p, ph, kk, si = cal.x, cal.p, cal.ph, cal.k, cal.si
    for i in range(CAL_N):
        k = vec_mat3_at(vec3_at(ph, 3 * i), si, 0)  # Kᵢ = (P Hᵀ)ᵢ S⁻¹
        store3(kk, 3 * i, k)
        x[i] += dot3(k, nu)  # xᵢ += Kᵢ ν
        sub_combination12(p, CAL_N * i, k, g0, g1, g2)  # Pᵢ −= Kᵢ (P Hᵀ)ᵀ


def mc_field_scale(cal, norm):
    """The field's norm the noises scale with: ``|s − z|``, at least a share of ``norm``."""
    x = cal.x
    m = sub3(field_with_offset_of(x), offset_of(x))
    scale = math.sqrt(dot3(m, m))
    if CAL_SCALE_FLOOR * norm > scale:
        scale = CAL_SCALE_FLOOR * norm
    cal.field_scale = scale


# --- start -----------------------------------------------------------------------------

def mc_start(cal, y0, y1, y2, norm):
    """Initialize the filter from the field ``y`` (of norm ``norm``)."""
    fill(cal.x, 0, CAL_N, 0.0)
    fill(cal.p, 0, CAL_N * CAL_N, 0.0)
    if cal.has_prior == 0.0:
        mc_prior_unknown(cal, norm)
    elif cal.prior_cov != 0.0:
        mc_prior_kept(cal)
    else:
        mc_prior_loaded(cal, norm)
    mc_start_field(cal, (y0, y1, y2), norm)
    mc_field_scale(cal, norm)
    cal.fresh = 0.0


def mc_prior_unknown(cal, norm):
    """Nothing known: ``z`` diffuse, ``d`` and ``τ`` about 0 with their parameters' spread."""
    cal.scale = 1.0
    mc_prior_spread(cal, CAL_DIFFUSE * norm, cal.soft_iron, cal.delay)


def mc_prior_kept(cal):
    """A restart: ``(z, d, τ)`` and their covariance as learned before."""
    mc_prior_x(cal)
    copy_into(cal.p, rows((CAL_N + 1) * CAL_Z, CAL_N), cal.prior_p, rows(0, CAL_ZDT),
              CAL_ZDT, CAL_ZDT)


def mc_prior_loaded(cal, norm):
    """A loaded calibration: ``(z, d, τ)`` as loaded, a tighter prior about it."""
    mc_prior_x(cal)
    soft = CAL_LOADED_SOFT_SHARE * cal.soft_iron
    mc_prior_spread(cal, CAL_LOADED_BIAS_STD * norm / cal.scale, soft, cal.delay)


def mc_prior_spread(cal, z_std, d_std, tau_std):
    """``P[z d τ, z d τ]`` diagonal, with these standard deviations."""
    p = cal.p
    diagonal_into(p, 0, CAL_N, CAL_Z, 3, z_std * z_std)
    diagonal_into(p, 0, CAL_N, CAL_D, CAL_NY, d_std * d_std)
    diagonal_into(p, 0, CAL_N, CAL_TAU, 1, tau_std * tau_std)


def mc_prior_x(cal):
    """``x[3:]`` and the scale from the prior."""
    copy_into(cal.x, rows(CAL_Z, 1), cal.prior_x, rows(0, 1), CAL_ZDT, 1)
    cal.scale = cal.prior_scale


def mc_start_field(cal, y, norm):
    """
    ``s = A y = y + Y(y) d``: as uncertain as ``d`` (and correlated with it), plus the noise.

    Independent of the offset.
    """
    x, p, yy, t = cal.x, cal.p, cal.yy, cal.k
    mc_regressor_into(yy, 0, CAL_NY, y)
    matmul_acc_into(x, rows(CAL_S, 1), yy, rows(0, CAL_NY), x, rows(CAL_D, 1), 3, CAL_NY, 1)
    set_field_with_offset(x, add3(y, field_with_offset_of(x)))  # s = y + Y d
    pd = rows(CAL_N * CAL_D + CAL_Z, CAL_N)  # P[d, 3:]
    matmul_acc_into(p, rows(CAL_Z, CAL_N), yy, rows(0, CAL_NY), p, pd, 3, CAL_NY, CAL_ZDT)
    copy_into(p, cols(CAL_N * CAL_Z, CAL_N), p, rows(CAL_Z, CAL_N), 3, CAL_ZDT)
    # P[s, s] = Y P[d, d] Yᵀ + noise² I, Y P[d, d] in the scratch of K
    fill(t, 0, 3 * CAL_NY, 0.0)
    pdd = rows((CAL_N + 1) * CAL_D, CAL_N)
    matmul_acc_into(t, rows(0, CAL_NY), yy, rows(0, CAL_NY), p, pdd, 3, CAL_NY, CAL_NY)
    matmul_acc_into(p, rows(0, CAL_N), t, rows(0, CAL_NY), yy, cols(0, CAL_NY), 3, CAL_NY, 3)
    noise = cal.noise * norm
    add_diagonal(p, 0, CAL_N, CAL_S, 3, noise * noise)


# --- helpers ----------------------------------------------------------------------------

def mc_regressor_into(a, at, width, y):
    """``Y(y)`` (3 × 5, ``D(d) y = Y(y) d``) into ``a[at:]``, its rows ``width`` apart."""
    a[at], a[at + 1], a[at + 2], a[at + 3], a[at + 4] = y[0], 0.0, y[1], y[2], 0.0
    r = at + width
    a[r], a[r + 1], a[r + 2], a[r + 3], a[r + 4] = 0.0, y[1], y[0], 0.0, y[2]
    r = at + 2 * width
    a[r], a[r + 1], a[r + 2], a[r + 3], a[r + 4] = -y[2], -y[2], 0.0, y[0], y[1]


def mc_inv3(out, a, b, c, d, e, f, g, h, i):
    """The inverse of ``[[a, b, c], [d, e, f], [g, h, i]]`` (cofactors) into ``out[0:9]``."""
    c00 = e * i - f * h
    c01 = f * g - d * i
    c02 = d * h - e * g
    det = a * c00 + b * c01 + c * c02
    out[0] = c00 / det
    out[1] = (c * h - b * i) / det
    out[2] = (b * f - c * e) / det
    out[3] = c01 / det
    out[4] = (a * i - c * g) / det
    out[5] = (c * d - a * f) / det
    out[6] = c02 / det
    out[7] = (b * g - a * h) / det
    out[8] = (a * e - b * d) / det
