"""
The covariance's step as functions on one flat state, and the raw-IMU sample in one call.

:class:`~ext_observer.core.ahrs.uncertainty.AttitudeUncertainty` keeps its
per-sample state in a flat container ``u`` (the slots below) and runs
:func:`uncertainty_step` on it: the same source plain (a Python ``list``,
whose items may also be numpy arrays ``(B,)`` for many recordings at once:
the arithmetic has no branch on them) or compiled by numba on a float64
array (:mod:`~ext_observer.core.ahrs.compiled` joins this file to the
estimator's kernels), as :mod:`~ext_observer.core.ahrs.ahrs_kernel` is. The
model is docs/covariance.md's ("The model").

:func:`sample_step` is what the node runs for the usual sample of an
estimate that exists: the estimator's step
(:func:`~ext_observer.core.ahrs.ahrs_kernel.ahrs_update`), the divergence guard
of :func:`~ext_observer.core.validation.check_state`, the covariance's step
and the published covariance, in one call instead of one per part: with
the compiled kernels, one crossing from Python per sample.
"""

import math

from .ahrs_filters import rotate
from .ahrs_kernel import ahrs_update
from .bias_kernel import bias_variance
from .layout import Layout

# Standard gravity, m/s²: turns the accelerometer's noise into a direction.
GRAVITY = 9.80665

# --- the layout ----------------------------------------------------------------

UNCERTAINTY = Layout()
# Constants (set once by the wrapper): the estimator's time constants (s),
# the noises of UncertaintyParams, and what is added on output (rad²; the
# stamp's per (rad/s)²).
U_TAU_ACC = UNCERTAINTY.field('tau_acc')
U_TAU_REST = UNCERTAINTY.field('tau_rest')
U_GYRO_NOISE = UNCERTAINTY.field('gyro_noise')
U_GYRO_RATE_NOISE = UNCERTAINTY.field('gyro_rate_noise')
U_BIAS_STD = UNCERTAINTY.field('bias_std')
U_BIAS_TIME = UNCERTAINTY.field('bias_time')
U_ACC_NOISE = UNCERTAINTY.field('acc_noise')
U_TILT_FLOOR = UNCERTAINTY.field('tilt_floor')
U_HEADING_FLOOR = UNCERTAINTY.field('heading_floor')
U_STAMP2 = UNCERTAINTY.field('stamp2')
# Coefficients of the interval U_DT (NaN: none yet).
U_DT = UNCERTAINTY.field('dt')
U_K_ACC = UNCERTAINTY.field('k_acc')
U_K_REST = UNCERTAINTY.field('k_rest')
U_R_ACC = UNCERTAINTY.field('r_acc')
U_R_GYRO = UNCERTAINTY.field('r_gyro')
U_Q_GYRO = UNCERTAINTY.field('q_gyro')
U_Q_RATE = UNCERTAINTY.field('q_rate')
U_PHI = UNCERTAINTY.field('phi')
U_Q_BIAS = UNCERTAINTY.field('q_bias')
# The state: per axis [[P, C], [C, B]] (tilt t, heading h, one B), the
# reference's variance, the calibration's, whether a field set the heading,
# the rate's squared world components (vertical, horizontal).
U_PT = UNCERTAINTY.field('pt')
U_CT = UNCERTAINTY.field('ct')
U_PH = UNCERTAINTY.field('ph')
U_CH = UNCERTAINTY.field('ch')
U_B = UNCERTAINTY.field('b')
U_UNKNOWN = UNCERTAINTY.field('unknown')
U_CALIBRATION = UNCERTAINTY.field('calibration')
U_HEADING_SET = UNCERTAINTY.field('heading_set')
U_WZ2 = UNCERTAINTY.field('wz2')
U_WH2 = UNCERTAINTY.field('wh2')
# The start (wherever the robot starts): s since it, samples and the mean of ((|f| − g)/g)² seen
# since, and the variance per horizontal axis the running mean of the
# specific force still owes to the motion (rad²).
U_START_T = UNCERTAINTY.field('start_t')
U_START_N = UNCERTAINTY.field('start_n')
U_START_M = UNCERTAINTY.field('start_m')
U_START_V = UNCERTAINTY.field('start_v')
U_START_F = UNCERTAINTY.field('start_f')  # the first sample's ((|f| − g)/g)²
# The heading's share of the start (9D): a field's heading is its horizontal
# part in the estimate's frame, which a tilt error ε turns by up to
# ε·|tan(dip)|. The weight the heading still gives the field it was taken
# from at the start, |tan(dip)| of the references, the share of the fields
# since (σ, rad) and the whole σ published (rad).
U_HS_W0 = UNCERTAINTY.field('hs_w0')
U_HS_TAN = UNCERTAINTY.field('hs_tan')
U_HS_REST = UNCERTAINTY.field('hs_rest')
U_HS = UNCERTAINTY.field('hs')
# A field lost: s since the last field (used or not), and the rotation about
# the world vertical (rad, signed) the gyro alone carried the heading through
# since it was lost; the fields back shrink it as they correct the heading.
U_FIELD_AGE = UNCERTAINTY.field('field_age')
U_YAW_HELD = UNCERTAINTY.field('yaw_held')
# The same, the whole rotation (rad, about any axis, unsigned).
U_ROTATION_HELD = UNCERTAINTY.field('rotation_held')
# The heading's lag behind the fields (rad, signed): the innovation of the
# fields that corrected the heading (their heading in the estimate's frame),
# low-passed over INNOVATION_TIME; a full correction (gain 1) clears it.
U_LAG = UNCERTAINTY.field('lag')
U_SIZE = UNCERTAINTY.size

# sample_step's outcomes: 0 the step ran; else the estimator stepped but the
# estimate failed the guard (the caller reinitializes), or nothing ran: the
# interval was not one to step with, or there is no estimate yet.
SAMPLE_OK = 0
SAMPLE_NON_FINITE = 1
SAMPLE_RESIDUAL = 2
SAMPLE_BAD_DT = 3
SAMPLE_NOT_STARTED = 4

# s: how long a moving body's translational acceleration keeps its direction
# (a hand, a robot's base: a fraction of a second to a second); the running
# mean of t seconds owes ``c / (c + t)`` of one sample's deviation.
START_CORRELATION = 1.0
# rad²: a start's share below this is forgotten (a millionth of a degree).
_START_FORGOTTEN = 1e-16
# σ of the gyro's scale error (relative): without a field, the heading drifts
# by this share of the net rotation about the vertical (BROAD's dev trial 08
# turns ten times one way without one and drifts 0.33 % of it; MEMS
# datasheets give 0.1 to 1 %).
GYRO_SCALE_SIGMA = 0.003
# σ of the heading's drift per radian of rotation about any axis, without a
# field: the gyro's axis and cross-axis errors, which a body turning back and
# forth rectifies into a drift with no net turn (BROAD's dev trial 34 drifts
# 9° steadily in 70 s, 0.085 % of the 10650° it turns: 0.03 % puts all of it
# within 2σ with the other terms, 0.02 % 97 %; 0.05 % leaves a margin).
GYRO_MOTION_SIGMA = 0.0005
# The model's one bias variance per axis is the mean of the bias filter's three
# (its covariance's trace over the axes it sums).
BIAS_TRACE_AXES = 3.0
# s: no field for this long is a field lost (mag_timeout's default), not the
# interval of a slower magnetometer.
FIELD_SILENT = 1.0
# s: the fields' innovation is averaged over this long before its square is
# counted in the heading's variance: long enough to average the fields' noise
# and their calibration's orientation-dependent error, short enough to follow
# a lag that builds up within seconds (dev trial 08's fast turns: 8° in 30 s
# while the model claimed 2°). Chosen on the even trials among 3 to 8 s.
INNOVATION_TIME = 5.0


def uncertainty_coefficients(u, dt):
    """The coefficients of the interval ``dt`` (s, positive and finite: checked by the caller)."""
    u[U_DT] = dt
    u[U_K_ACC] = 1.0 - math.exp(-dt / u[U_TAU_ACC])
    u[U_K_REST] = 1.0 - math.exp(-dt / u[U_TAU_REST])
    a = u[U_ACC_NOISE] / GRAVITY
    u[U_R_ACC] = a * a / dt
    g = u[U_GYRO_NOISE]
    u[U_R_GYRO] = g * g / dt  # one sample's rate variance
    u[U_Q_GYRO] = g * g * dt
    r = u[U_GYRO_RATE_NOISE]
    u[U_Q_RATE] = r * r * dt
    phi = math.exp(-dt / u[U_BIAS_TIME])
    u[U_PHI] = phi
    b = u[U_BIAS_STD]
    u[U_Q_BIAS] = b * b * (1.0 - phi * phi)


def uncertainty_step(u, dt, gx, gy, gz, w, x, y, z, rest):
    """
    One IMU sample: the gyro's propagation, the bias at rest, the inclination correction.

    ``dt`` the interval (s; its coefficients recomputed when it changed),
    ``g`` the measured rate (rad/s, body frame), ``(w, x, y, z)`` the
    estimate after the step (any nonzero norm), ``rest`` 1.0 (or True)
    where the estimator detected rest and learned the bias, else 0.0.
    """
    if dt != u[U_DT]:
        uncertainty_coefficients(u, dt)
    w2 = gx * gx + gy * gy + gz * gz
    q_theta = u[U_Q_GYRO] + u[U_Q_RATE] * w2
    b = u[U_B]
    phi = u[U_PHI]
    # [θ, β] ← F [θ, β] with F = [[1, dt], [0, φ]]: F P Fᵀ + Q, per axis.
    bdt = b * dt
    pt = u[U_PT] + (2.0 * u[U_CT] + bdt) * dt + q_theta
    ph = u[U_PH] + (2.0 * u[U_CH] + bdt) * dt + q_theta
    ct = phi * (u[U_CT] + bdt)
    ch = phi * (u[U_CH] + bdt)
    b = phi * phi * b + u[U_Q_BIAS]
    # At rest the bias is the low-passed rate: β ← (1 − k_r) β + k_r n.
    kr = u[U_K_REST] * rest
    a = 1.0 - kr
    b = a * a * b + kr * kr * u[U_R_GYRO]
    ct = a * ct
    ch = a * ch
    # The inclination correction of every sample.
    k = u[U_K_ACC]
    a = 1.0 - k
    u[U_PT] = a * a * pt + k * k * u[U_R_ACC]
    u[U_CT] = a * ct
    u[U_PH] = ph
    u[U_CH] = ch
    u[U_B] = b
    # The rate about the world vertical: the third row of R(q), over |q|².
    n2 = w * w + x * x + y * y + z * z
    wz = (2.0 * (x * z - w * y) * gx + 2.0 * (y * z + w * x) * gy
          + (w * w - x * x - y * y + z * z) * gz) / n2
    wz2 = wz * wz
    u[U_WZ2] = wz2
    age = u[U_FIELD_AGE] + dt
    u[U_FIELD_AGE] = age
    # (A product, not a branch: the state's slots may be arrays.)
    lost = (age > FIELD_SILENT) * dt
    u[U_YAW_HELD] = u[U_YAW_HELD] + lost * wz
    u[U_ROTATION_HELD] = u[U_ROTATION_HELD] + lost * w2 ** 0.5
    u[U_WH2] = w2 - wz2


def uncertainty_bias(u, var):
    """
    The estimator's own bias variance (rad²/s², its Kalman filter's, per axis): at least that.

    The model's ``B`` never claims a bias better known than the estimator's
    learning in motion does (a start, a gyro that clipped).
    """
    b = u[U_B]
    # The larger, exactly, also on arrays (no branch).
    u[U_B] = var * (var > b) + b * (var <= b)


def uncertainty_clipped(u, var):
    """
    A sample at the gyro's range: the angle's variances grow by ``var`` (rad²).

    The estimator's ``(range dt)²`` per clipped axis: the rate beyond the
    range is unknown (0 for a sample that did not clip: nothing changes).
    """
    u[U_PT] = u[U_PT] + var
    u[U_PH] = u[U_PH] + var


def uncertainty_hole(u, extra, var, tilt):
    """
    A hole bridged: the angle's variances grow by what the usual step did not count.

    The estimator bridged ``extra`` s more than the usual interval (the
    step counted that one): the gyro's noise and the bias over that time,
    and ``var`` (rad² per axis), the bridge's own error
    (:func:`~ext_observer.core.ahrs.hole_kernel.hole_variance`); the
    inclination's only where its mean was not restarted (``tilt``). The
    estimator's inclination correction stood for the steps the hole missed
    too (``1 + extra / dt`` of them): what was there before it is corrected
    as by as many.
    """
    a = (1.0 - u[U_K_ACC]) ** (extra / u[U_DT])
    u[U_PT] = a * a * u[U_PT]
    u[U_CT] = a * u[U_CT]
    g = u[U_GYRO_NOISE]
    grow = g * g * extra + u[U_B] * extra * extra + var
    if tilt:
        u[U_PT] = u[U_PT] + grow
    u[U_PH] = u[U_PH] + grow


def uncertainty_restart(u, t0):
    """
    The estimator restarted the inclination's mean after a hole, the old weighed as ``t0`` s.

    Its inclination is a running mean again, as at a start that has run
    for ``t0`` s: the start's share follows from the samples from now on
    (:func:`uncertainty_start`), and the propagated variance is the
    accelerometer's own.
    """
    u[U_START_T] = t0
    u[U_START_N] = 0.0
    u[U_START_M] = 0.0
    u[U_PT] = u[U_R_ACC]
    u[U_CT] = 0.0


def uncertainty_start(u, dt, fx, fy, fz):
    """
    A sample's specific force in the world frame (m/s²): how unsure the start still is.

    For its first ``tau_acc`` seconds the estimator's inclination is the
    running mean of the world-frame specific force; a moving body's sample
    is off gravity's direction by its translational acceleration ``d``, up
    to ``atan(|d| / g)``. What each sample shows of ``d``: its deviation
    from the vertical ``g`` of the estimate, ``(fx, fy, fz − g)`` (the
    first sample, from which the estimate was taken, only ``|f| − g``).
    The mean of ``max(d_z², (d_x² + d_y²) / 2) / g²`` since the start is one
    sample's variance per horizontal axis (a motion with no preferred
    direction shows on each axis alike), and the running mean of ``t``
    seconds owes ``c / (c + t)`` of it (``c`` :data:`START_CORRELATION`).
    Then the low-pass forgets it as any error (``(1 − k)²`` per sample).
    A body at rest keeps the accelerometer's own deviation (its noise and
    scale error): a small σ. Floats only (one estimate).
    """
    t = u[U_START_T]
    if t < u[U_TAU_ACC]:
        n = u[U_START_N] + 1.0
        dz = fz - GRAVITY
        e = max(dz * dz, 0.5 * (fx * fx + fy * fy)) / (GRAVITY * GRAVITY)
        m = u[U_START_M] + (e - u[U_START_M]) / n
        if n == 1.0:
            u[U_START_F] = e
        u[U_START_N] = n
        u[U_START_M] = m
        a = math.atan(math.sqrt(max(m, u[U_START_F])))
        u[U_START_V] = a * a * START_CORRELATION / (START_CORRELATION + t)
    else:
        k = u[U_K_ACC]
        v = (1.0 - k) * (1.0 - k) * u[U_START_V]
        u[U_START_V] = v if v > _START_FORGOTTEN else 0.0
    u[U_START_T] = t + dt


def uncertainty_variances(u):
    """The published variances: ``(V_t, V_h)``, rad² (tilt per horizontal axis, heading)."""
    t = u[U_PT] + u[U_START_V] + u[U_TILT_FLOOR] + 0.5 * u[U_STAMP2] * u[U_WH2]
    scale = GYRO_SCALE_SIGMA * u[U_YAW_HELD]
    axes = GYRO_MOTION_SIGMA * u[U_ROTATION_HELD]
    held = u[U_HEADING_SET] * (scale * scale + axes * axes) ** 0.5
    field = u[U_HEADING_SET] * (u[U_HEADING_FLOOR] + u[U_CALIBRATION])
    h = (u[U_PH] + u[U_UNKNOWN] + field + u[U_STAMP2] * u[U_WZ2] + u[U_HS] * u[U_HS])
    # The fields' lag beyond their own error (the floor, the calibration's σ)
    # is the heading's: where it says more, the lost field's drift is the same
    # turn's (a scale error), added as σ (products, not branches: arrays).
    lag = u[U_LAG] * u[U_LAG] - field
    more = lag > h
    lag = more * lag
    return t, h + held * held + more * ((lag ** 0.5 + held) ** 2 - h - held * held)


def sample_step(state, u, cov, gx, gy, gz, ax, ay, az, dt, max_residual):
    """
    The usual raw-IMU sample of an estimate that exists, in one call.

    The estimator's step without a field (``state``: the estimate's holder,
    :mod:`~ext_observer.core.ahrs.record`), the guard (the estimate
    finite, ``|q̂̄q̂ − 1| ≤ max_residual``), and where it passes the
    covariance's step (``u``) and the 3×3 covariance written into ``cov``
    (9 slots, row-major: ``diag(V_t, V_t, V_h)``).

    Returns
    -------
    outcome : int
        ``SAMPLE_OK``; ``SAMPLE_NON_FINITE`` or ``SAMPLE_RESIDUAL`` (the
        estimator stepped; ``u`` and ``cov`` are untouched); nothing ran:
        ``SAMPLE_BAD_DT`` (``dt`` not positive and finite) or
        ``SAMPLE_NOT_STARTED`` (no estimate yet: the first step initializes).
    w, x, y, z : float
        The estimate after the step (ambient, sensor → ENU).

    """
    s = state[0]
    if s.est.init == 0.0:
        return SAMPLE_NOT_STARTED, 0.0, 0.0, 0.0, 0.0
    if not (dt > 0.0 and dt < math.inf):
        return SAMPLE_BAD_DT, 0.0, 0.0, 0.0, 0.0
    w, x, y, z = ahrs_update(s, gx, gy, gz, ax, ay, az, False, 0.0, 0.0, 0.0, dt)
    n2 = w * w + x * x + y * y + z * z
    if not math.isfinite(n2):
        return SAMPLE_NON_FINITE, w, x, y, z
    if abs(n2 - 1.0) > max_residual:
        return SAMPLE_RESIDUAL, w, x, y, z
    # The usual interval: dt itself, or the one a hole's step kept.
    step_dt = s.coef.dt
    uncertainty_step(u, step_dt, gx, gy, gz, w, x, y, z, 1.0 if s.rest.detected != 0.0 else 0.0)
    hole = s.hole.var
    if hole != 0.0 and s.hole.t0 >= 0.0:
        uncertainty_restart(u, s.hole.t0)
    if u[U_START_V] != 0.0 or u[U_START_T] < u[U_TAU_ACC]:
        fx, fy, fz = rotate(w, x, y, z, ax, ay, az)
        uncertainty_start(u, step_dt, fx, fy, fz)
    if s.par.motion_bias != 0.0:
        uncertainty_bias(u, (bias_variance(s, 0, 0) + bias_variance(s, 1, 1)
                             + bias_variance(s, 2, 2)) / BIAS_TRACE_AXES)
    if s.gyro.clipped != 0.0:
        uncertainty_clipped(u, s.gyro.clipped)
    if hole != 0.0:
        uncertainty_hole(u, dt - step_dt, hole, s.hole.t0 < 0.0)
    t, h = uncertainty_variances(u)
    zero = 0.0 * t
    cov[0] = t
    cov[1] = zero
    cov[2] = zero
    cov[3] = zero
    cov[4] = t
    cov[5] = zero
    cov[6] = zero
    cov[7] = zero
    cov[8] = h
    return SAMPLE_OK, w, x, y, z
