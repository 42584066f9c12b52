"""
The field's references: its norm and dip, followed, and a disturbed field told apart.

Kernel functions of the field step (:mod:`~ext_observer.core.ahrs.field_kernel`,
whose ``FIELD`` group they read and write): the field in the estimate's world
frame (:func:`field_angles`), judged by its norm and dip against references
that follow it, with a candidate for a new field and a rejection that ends
(VQF's magnetic disturbance rejection, Laidig & Seel 2023). In the part of
Python numba compiles.
"""

import math

from .ahrs_filters import rotate
from .hole_kernel import forget_wait

# s: a field rejected as disturbed for longer than this is the field (VQF's
# maximum rejection time, Laidig & Seel 2023): the references follow it.
_MAX_REJECTION = 60.0
# A short undisturbed stretch takes back this many times its length of the
# rejection time (VQF's magnetic rejection factor); a field off a young
# candidate takes back as much of the candidate's time.
MAG_REJECTION_FACTOR = 2.0
# σ: a field whose heading is further from the estimate than this many of
# the doubt's and its own does not correct it (a disturbance).
FIELD_GATE = 3.0


def field_angles(s, mx, my, mz):
    """The body field in the estimate's world frame: ``(norm, dip, heading ψ, valid)``."""
    mx, my, mz = rotate(s.est.q[0], s.est.q[1], s.est.q[2], s.est.q[3], mx, my, mz)
    h = math.sqrt(mx * mx + my * my)
    norm = math.sqrt(h * h + mz * mz)
    return norm, math.atan2(mz, h), math.atan2(mx, my), (h > 0.0) and (norm > 0.0)


def first_references(s, norm, dip):
    """The first field: the references and the candidate are its norm and dip."""
    s.field.ref[0] = norm
    s.field.ref[1] = dip
    s.field.cand[0] = norm
    s.field.cand[1] = dip
    s.field.has_ref = 1.0
    s.field.ref_age = 0.0
    s.field.ref_rest = 0.0


def off_references(s, norm, dip, tilt):
    """
    Whether a field's norm or dip is off the references (disturbed).

    The dip is the field's in the estimate's world frame: a tilt error of σ
    ``tilt`` (rad) turns it by as much, so the dip's threshold widens to
    ``√(mag_dip_th² + (FIELD_GATE tilt)²)`` (the norm does not depend on
    the attitude).
    """
    ref_n = s.field.ref[0]
    dd = dip - s.field.ref[1]
    th_d = s.par.mag_dip_th
    return (abs(norm - ref_n) > s.par.mag_norm_th * ref_n) or (
        dd * dd > th_d * th_d + FIELD_GATE * FIELD_GATE * tilt * tilt)


def follow_candidate(s, norm, dip, dt):
    """
    A new field: its candidate norm and dip, and for how long the body has turned with it.

    VQF's candidate (Laidig & Seel 2023): its time counts whether or not the
    references reject the field. A field off it starts it over; while the
    references are young (fewer than ``mag_new_time`` s of fields, none at
    rest) it only takes back :data:`MAG_REJECTION_FACTOR` times its length,
    so that a moving body's spread does not keep one sample's references.
    """
    cand_n, cand_d = s.field.cand[0], s.field.cand[1]
    th_n, th_d = s.par.mag_norm_th, s.par.mag_dip_th
    consistent = (abs(norm - cand_n) < th_n * cand_n) and (abs(dip - cand_d) < th_d)
    gx, gy, gz = s.rest.gyr_lp[0], s.rest.gyr_lp[1], s.rest.gyr_lp[2]
    turning = gx * gx + gy * gy + gz * gz > s.par.mag_new_gyr ** 2
    if consistent:
        if turning:
            s.field.cand_time += dt
    elif s.field.ref_rest == 0.0 and s.field.ref_age < s.par.mag_new_time:
        s.field.cand_time = max(s.field.cand_time - MAG_REJECTION_FACTOR * dt, 0.0)
    else:
        s.field.cand_time = 0.0
    kr = s.coef.k_ref
    if consistent:
        # c ← c + k_ref (m − c), norm and dip
        s.field.cand[0] = cand_n + kr * (norm - cand_n)
        s.field.cand[1] = cand_d + kr * (dip - cand_d)
    elif s.field.cand_time == 0.0:
        s.field.cand[0] = norm
        s.field.cand[1] = dip


def reject_or_accept(s, disturbed, dt):
    """
    Count a disturbed field's rejection; accept the candidate as the field: still disturbed?

    A new field is accepted once it has lasted ``mag_new_time``, or longer than
    fields have confirmed the references (those of a body that starts beside
    a magnet are not trusted longer than the true field has been seen), or
    after :data:`_MAX_REJECTION` s of rejection.
    """
    rejected = s.field.rejected + dt if disturbed else max(s.field.rejected
                                                        - MAG_REJECTION_FACTOR * dt, 0.0)
    s.field.rejected = rejected
    accept = disturbed and (s.field.cand_time >= min(s.par.mag_new_time, s.field.ref_age)
                            or rejected >= _MAX_REJECTION)
    if not accept:
        return disturbed
    s.field.rejected = 0.0
    s.field.ref[0] = s.field.cand[0]
    s.field.ref[1] = s.field.cand[1]
    if s.field.ref_age < s.par.mag_new_time:
        # The heading followed disturbed fields: its running mean starts again.
        s.field.mag_used = 0.0
        forget_wait(s)
    s.field.ref_age = s.field.cand_time
    s.field.ref_rest = 0.0
    return False


def follow_references(s, norm, dip, use, dt):
    """A field the heading may ``use`` confirms the references, and they follow it."""
    if use:
        s.field.ref_age += dt
        if s.rest.detected != 0.0:
            s.field.ref_rest = 1.0
        kr = s.coef.k_ref
        ref_n, ref_d = s.field.ref[0], s.field.ref[1]
        # r ← r + k_ref (m − r), norm and dip
        s.field.ref[0] = ref_n + kr * (norm - ref_n)
        s.field.ref[1] = ref_d + kr * (dip - ref_d)
