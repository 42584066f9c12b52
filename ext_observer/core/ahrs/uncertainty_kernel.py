"""
The covariance's state with names, its step as functions on it, and the raw-IMU sample in one call.

:class:`~ext_observer.core.ahrs.uncertainty.AttitudeUncertainty` keeps its
per-sample state in a record of :data:`UNC` (a
:class:`~ext_observer.core.ahrs.record.Group`: ``u.axes.pt``, ``u.start.var``,
...) and runs these functions on it: the same source plain (a plain
record, whose fields may also be numpy arrays ``(B,)`` for many
recordings at once: the arithmetic of :func:`covariance_step` and
:func:`covariance_variances` has no branch on them) or compiled by numba on
a structured record (:mod:`~ext_observer.core.ahrs.compiled` joins this file
to the estimator's kernels), as :mod:`~ext_observer.core.ahrs.ahrs_kernel`
is. The model is docs/covariance.md's ("The model").

The ``uncertainty_*`` functions take the record ``u``; what Python calls
(``covariance_*`` and :func:`sample_step`) takes a holder ``uh`` (a
one-element structured array compiled, ``[record]`` plain) and starts with
``u = uh[0]``. :func:`covariance_step` is the covariance's step of one
sample, its sub-steps in their one order, for the node's
:func:`sample_step` and the wrapper's steps alike.

:func:`sample_step` is what the node runs for the usual sample of an
estimate that exists: the estimator's step
(:func:`~ext_observer.core.ahrs.ahrs_kernel.ahrs_update`), the divergence guard
of :func:`~ext_observer.core.validation.check_state`, the covariance's step
and the published covariance, in one call instead of one per part: with
the compiled kernels, one crossing from Python per sample.
"""

import math

from ..constants import STANDARD_GRAVITY
from .ahrs_filters import UNIFORM_ANGLE_VARIANCE, gravity_deviation, rotate
from .ahrs_kernel import ahrs_update
from .bias_kernel import bias_variance
from .record import Group

# Variance of a heading known to be nothing better than uniform on (−π, π], rad².
HEADING_UNKNOWN = UNIFORM_ANGLE_VARIANCE

# --- the state -----------------------------------------------------------------

UNC = Group('unc', "the attitude covariance's constants, its interval's coefficients and state", [
    Group('par', 'constants, set once by the wrapper', [
        ('tau_acc', 's', "the inclination correction's time constant (tau_acc + tau_acc_gain)"),
        ('tau_rest', 's', "the time constant of the bias learned at rest"),
        ('gyro_noise', 'rad/s/√Hz', "the gyro's white noise density"),
        ('gyro_rate_noise', '(rad/s per rad/s)/√Hz', "the gyro's noise proportional to the rate"),
        ('bias_std', 'rad/s', "σ of the bias's wander from the learned one"),
        ('bias_time', 's', 'the correlation time of that wander'),
        ('acc_noise', 'm/s²/√Hz', "the accelerometer's noise density"),
        ('tilt_floor', 'rad²', 'added on output to the tilt variance per horizontal axis'),
        ('heading_floor', 'rad²', 'added on output to the variance of a heading a field set'),
        ('stamp2', 's²', "the stamp's error squared: added on output per (rad/s)² of rate"),
    ]),
    Group('coef', 'the coefficients of the interval dt (NaN: none yet)', [
        ('dt', 's', 'the interval'),
        ('k_acc', '', "the inclination correction's gain"),
        ('k_rest', '', "the gain of the bias learned at rest"),
        ('r_acc', 'rad²', "one sample's inclination measurement variance: (acc_noise / g)² / dt"),
        ('r_gyro', '(rad/s)²', "one sample's rate variance: gyro_noise² / dt"),
        ('q_gyro', 'rad²', "the gyro's white noise over dt"),
        ('q_rate', 'rad² s²', "the noise proportional to the rate over dt, per (rad/s)²"),
        ('phi', '', "the bias error's decay over dt: exp(−dt / bias_time)"),
        ('q_bias', '(rad/s)²', "the bias's wander over dt"),
    ]),
    Group('axes', 'per axis [[P, C], [C, B]] of the angle and bias errors (tilt t, heading h)', [
        ('pt', 'rad²', "P of the tilt, per horizontal axis"),
        ('ct', 'rad²/s', "C of the tilt: its angle and bias errors' covariance"),
        ('ct_turned', 'rad²/s', "C of the tilt's part turned a quarter about the vertical: "
         'the bias error turned with the body while the inclination was held on the gyro'),
        ('ph', 'rad²', "P of the heading"),
        ('ch', 'rad²/s', "C of the heading"),
        ('b', '(rad/s)²', "B, the bias error's variance (one for every axis)"),
    ]),
    Group('rate', "the last sample's rate in the world frame, squared", [
        ('wz2', '(rad/s)²', 'its vertical component squared'),
        ('wh2', '(rad/s)²', 'its horizontal components squared'),
    ]),
    Group('head', 'what the heading rests on (9D)', [
        ('heading_set', '', 'whether a field has corrected the heading since the start (0 or 1)'),
        ('unknown', 'rad²', "the variance of the field the heading was taken from"),
        ('calibration', 'rad²', "the magnetometer calibration's heading variance"),
        ('lag', 'rad', "the heading's lag behind the fields (signed): the innovation of the "
         'fields that corrected the heading, low-passed over INNOVATION_TIME; a full '
         'correction clears it'),
    ]),
    Group('start', 'the start (wherever the robot starts): what its mean owes the motion', [
        ('time', 's', 'since the start (or since the inclination\'s mean restarted)'),
        ('count', '', 'samples seen since'),
        ('mean', '', 'the mean of ((|f| − g)/g)² seen since (uncertainty_start says how)'),
        ('first', '', "the first sample's ((|f| − g)/g)²"),
        ('var', 'rad²', 'the variance per horizontal axis the running mean still owes the motion'),
    ]),
    Group('head_start', "the heading's share of the start (9D): a field's heading is its "
          "horizontal part in the estimate's frame, which a tilt error ε turns by up to "
          'ε·|tan(dip)|', [
              ('weight', '', 'the weight the heading still gives the field it was taken from at '
               'the start'),
              ('tan_dip', '', '|tan(dip)| of the references (0: no field yet)'),
              ('since', 'rad', 'the share of the fields since (σ)'),
              ('sigma', 'rad', 'the whole share published (σ)'),
          ]),
    Group('held', 'a field lost: the rotation the gyro alone carried the heading through', [
        ('field_age', 's', 'since the last field (used or not)'),
        ('yaw', 'rad', 'about the world vertical since the field was lost (signed); the fields '
         'back shrink it as they correct the heading'),
        ('rotation', 'rad', 'the same, the whole rotation (about any axis, unsigned)'),
        ('ph', 'rad²', "the heading's P after the last field"),
    ]),
])

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
# by this share of the net rotation about the vertical (MEMS datasheets give
# 0.1 to 1 %; docs/broad_tuning.md#the-covariances-constants).
GYRO_SCALE_SIGMA = 0.003
# σ of the heading's drift per radian of rotation about any axis, without a
# field: the gyro's axis and cross-axis errors, which a body turning back and
# forth rectifies into a drift with no net turn
# (docs/broad_tuning.md#the-covariances-constants).
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
# a lag that builds up within seconds
# (docs/broad_tuning.md#the-covariances-constants).
INNOVATION_TIME = 5.0


def uncertainty_coefficients(u, dt):
    """The coefficients of the interval ``dt`` (s, positive and finite: checked by the caller)."""
    p, c = u.par, u.coef
    c.dt = dt
    c.k_acc = 1.0 - math.exp(-dt / p.tau_acc)
    c.k_rest = 1.0 - math.exp(-dt / p.tau_rest)
    a = p.acc_noise / STANDARD_GRAVITY  # the accelerometer's noise as a direction
    c.r_acc = a * a / dt
    g = p.gyro_noise
    c.r_gyro = g * g / dt
    c.q_gyro = g * g * dt
    r = p.gyro_rate_noise
    c.q_rate = r * r * dt
    phi = math.exp(-dt / p.bias_time)
    c.phi = phi
    b = p.bias_std
    c.q_bias = b * b * (1.0 - phi * phi)


def uncertainty_propagate(u, dt, gx, gy, gz, w, x, y, z, rest, held):
    """
    One IMU sample: the gyro's propagation, the bias at rest, the inclination correction.

    ``dt`` the interval (s; its coefficients recomputed when it changed),
    ``g`` the measured rate (rad/s, body frame), ``(w, x, y, z)`` the
    estimate after the step (any nonzero norm), ``rest`` 1.0 (or True)
    where the estimator detected rest and learned the bias, else 0.0;
    ``held`` 1.0 where it held the inclination on the gyro (the specific
    force rejected: no correction from it), else 0.0.

    While held, the tilt's covariance with the bias error turns with the body
    about the vertical (a bias error fixed in the body tilts the world along a
    direction that turns with it): ``C = ct + i ct_turned`` in the body's
    turning frame, ``dC/dt = B − i ω_z C``, and the tilt grows by ``2 Re(C)``:
    a body turning at ``ω_z`` is carried round and back, one that does not
    turn by ``B t²``. (Where the force corrects the tilt, its correction
    outweighs the turn: ``C`` keeps its axes, as before.)
    """
    if dt != u.coef.dt:
        uncertainty_coefficients(u, dt)
    c, e = u.coef, u.axes
    w2 = gx * gx + gy * gy + gz * gz
    q_theta = c.q_gyro + c.q_rate * w2
    # The rate about the world vertical: the third row of R(q), over |q|².
    n2 = w * w + x * x + y * y + z * z
    wz = (2.0 * (x * z - w * y) * gx + 2.0 * (y * z + w * x) * gy
          + (w * w - x * x - y * y + z * z) * gz) / n2
    b = e.b
    phi = c.phi
    # [θ, β] ← F [θ, β] with F = [[1, dt], [0, φ]]: F P Fᵀ + Q, per axis.
    bdt = b * dt
    pt = e.pt + (2.0 * e.ct + bdt) * dt + q_theta
    ph = e.ph + (2.0 * e.ch + bdt) * dt + q_theta
    # C turned by −ω_z dt while held, as the rotation (1 − i a)/(1 + i a), a = ω_z dt / 2
    # (arithmetic only, for arrays too; exactly C where nothing turns).
    a = 0.5 * held * wz * dt
    d = 1.0 + a * a
    cs, sn = (1.0 - a * a) / d, 2.0 * a / d
    c1 = e.ct + bdt
    ct = phi * (c1 * cs + e.ct_turned * sn)
    ct2 = phi * (e.ct_turned * cs - c1 * sn)
    ch = phi * (e.ch + bdt)
    b = phi * phi * b + c.q_bias
    # At rest the bias is the low-passed rate: β ← (1 − k_r) β + k_r n.
    kr = c.k_rest * rest
    a = 1.0 - kr
    b = a * a * b + kr * kr * c.r_gyro
    ct = a * ct
    ct2 = a * ct2
    ch = a * ch
    # The inclination correction of every sample not held: P ← (1 − k)² P + k² R.
    k = c.k_acc * (1.0 - held)
    a = 1.0 - k
    e.pt = a * a * pt + k * k * c.r_acc
    e.ct = a * ct
    e.ct_turned = a * ct2
    e.ph = ph
    e.ch = ch
    e.b = b
    wz2 = wz * wz
    u.rate.wz2 = wz2
    held = u.held
    age = held.field_age + dt
    held.field_age = age
    # (A product, not a branch: the fields may be arrays.)
    lost = (age > FIELD_SILENT) * dt
    held.yaw = held.yaw + lost * wz
    held.rotation = held.rotation + lost * w2 ** 0.5
    u.rate.wh2 = w2 - wz2


def uncertainty_bias(u, var):
    """
    The estimator's own bias variance (rad²/s², its Kalman filter's, per axis): at least that.

    The model's ``B`` never claims a bias better known than the estimator's
    learning in motion does (a start, a gyro that clipped). ``var`` 0: no
    change (``B`` is not negative).
    """
    b = u.axes.b
    # The larger, exactly, also on arrays (no branch).
    u.axes.b = var * (var > b) + b * (var <= b)


def uncertainty_clipped(u, var):
    """
    A sample at the gyro's range: the angle's variances grow by ``var`` (rad²).

    The estimator's ``(range dt)²`` per clipped axis: the rate beyond the
    range is unknown (0 for a sample that did not clip: nothing changes).
    """
    u.axes.pt = u.axes.pt + var
    u.axes.ph = u.axes.ph + var


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
    e = u.axes
    a = (1.0 - u.coef.k_acc) ** (extra / u.coef.dt)
    e.pt = a * a * e.pt
    e.ct = a * e.ct
    g = u.par.gyro_noise
    grow = g * g * extra + e.b * extra * extra + var
    if tilt:
        e.pt = e.pt + grow
    e.ph = e.ph + grow


def uncertainty_restart(u, t0):
    """
    The estimator restarted the inclination's mean after a hole, the old weighed as ``t0`` s.

    Its inclination is a running mean again, as at a start that has run
    for ``t0`` s: the start's share follows from the samples from now on
    (:func:`uncertainty_start`), and the propagated variance is the
    accelerometer's own.
    """
    u.start.time = t0
    u.start.count = 0.0
    u.start.mean = 0.0
    u.axes.pt = u.coef.r_acc
    u.axes.ct = 0.0


def uncertainty_starting(u):
    """Whether the start still counts: its running mean still owes something, or still runs."""
    return u.start.var != 0.0 or u.start.time < u.par.tau_acc


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
    st = u.start
    t = st.time
    if t < u.par.tau_acc:
        n = st.count + 1.0
        e = gravity_deviation(fx, fy, fz)
        m = st.mean + (e - st.mean) / n
        if n == 1.0:
            st.first = e
        st.count = n
        st.mean = m
        a = math.atan(math.sqrt(max(m, st.first)))
        st.var = a * a * START_CORRELATION / (START_CORRELATION + t)
    else:
        k = u.coef.k_acc
        v = (1.0 - k) * (1.0 - k) * st.var
        st.var = v if v > _START_FORGOTTEN else 0.0
    st.time = t + dt


def uncertainty_variances(u):
    """The published variances: ``(V_t, V_h)``, rad² (tilt per horizontal axis, heading)."""
    p, e, hd = u.par, u.axes, u.head
    t = e.pt + u.start.var + p.tilt_floor + 0.5 * p.stamp2 * u.rate.wh2
    scale = GYRO_SCALE_SIGMA * u.held.yaw
    axes = GYRO_MOTION_SIGMA * u.held.rotation
    held = hd.heading_set * (scale * scale + axes * axes) ** 0.5
    field = hd.heading_set * (p.heading_floor + hd.calibration)
    hs = u.head_start.sigma
    h = (e.ph + hd.unknown + field + p.stamp2 * u.rate.wz2 + hs * hs)
    # The fields' lag beyond their own error (the floor, the calibration's σ)
    # is the heading's: where it says more, the lost field's drift is the same
    # turn's (a scale error), added as σ (products, not branches: arrays).
    lag = hd.lag * hd.lag - field
    more = lag > h
    lag = more * lag
    return t, h + held * held + more * ((lag ** 0.5 + held) ** 2 - h - held * held)


# --- what Python calls: a holder ------------------------------------------------

def covariance_coefficients(uh, dt):
    """:func:`uncertainty_coefficients` of the holder's record."""
    uncertainty_coefficients(uh[0], dt)


def covariance_start(uh, dt, fx, fy, fz):
    """:func:`uncertainty_start` of the holder's record while the start counts (one estimate)."""
    u = uh[0]
    if uncertainty_starting(u):
        uncertainty_start(u, dt, fx, fy, fz)


def covariance_variances(uh):
    """:func:`uncertainty_variances` of the holder's record: ``(V_t, V_h)``, rad²."""
    return uncertainty_variances(uh[0])


def covariance_step(uh, dt, gx, gy, gz, w, x, y, z, rest, held, bias_var, clip_var, extra,
                    hole_var, hole_t0, ax, ay, az, with_acc):
    """
    The covariance's step of one IMU sample: its sub-steps in their one order.

    The propagation over ``dt`` (the usual interval, s) with the rate
    ``g`` (rad/s, body) to the estimate ``(w, x, y, z)`` after the step
    (any nonzero norm), the bias at ``rest`` (1.0 or True; else 0.0), the
    inclination ``held`` on the gyro (1.0; else 0.0) (:func:`uncertainty_propagate`);
    a hole's restart of the inclination's mean (``hole_t0`` s, where
    ``hole_t0 ≥ 0``; :func:`uncertainty_restart`);
    the estimator's bias variance ``bias_var`` ((rad/s)², 0: none;
    :func:`uncertainty_bias`); a clipped sample's ``clip_var`` (rad², 0:
    none; :func:`uncertainty_clipped`); a hole bridged, ``extra`` s beyond
    ``dt`` with the bridge's variance ``hole_var`` (rad², 0: no hole;
    :func:`uncertainty_hole`); and, with ``with_acc`` true, the start's
    share of the specific force ``a`` (m/s², body; :func:`uncertainty_start`).

    The start's share reads and writes only ``u.start`` (and constants); the
    others only ``u.axes``: its place in the order changes no bit. The rate,
    the estimate, ``rest``, ``held``, ``bias_var`` and ``clip_var`` may be arrays
    ``(B,)`` (plain); the hole's arguments and ``with_acc`` are floats, and
    with arrays ``with_acc`` is false (the wrapper counts the start
    recording by recording).
    """
    u = uh[0]
    uncertainty_propagate(u, dt, gx, gy, gz, w, x, y, z, rest, held)
    if hole_var != 0.0 and hole_t0 >= 0.0:
        uncertainty_restart(u, hole_t0)
    uncertainty_bias(u, bias_var)
    uncertainty_clipped(u, clip_var)
    if hole_var != 0.0:
        uncertainty_hole(u, extra, hole_var, hole_t0 < 0.0)
    if with_acc and uncertainty_starting(u):
        fx, fy, fz = rotate(w, x, y, z, ax, ay, az)
        uncertainty_start(u, dt, fx, fy, fz)


def covariance_unbridged(uh, dt, var, t0):
    """
    A hole of ``dt`` s the estimator did not bridge (over ``max_dt``): what it leaves.

    ``var`` the rotation it may have hidden (rad² per axis) and ``t0`` the
    weight the inclination's mean restarted with (negative: kept),
    :func:`~ext_observer.core.ahrs.ahrs_kernel.ahrs_unbridged`'s. The angles'
    variances grow by it and by the gyro's noise and bias over the hole, the
    inclination's only where its mean was kept (else it restarts as after a
    bridged hole); the heading's up to :data:`HEADING_UNKNOWN`. The hole
    counts as time without a field. One estimate (floats).
    """
    u = uh[0]
    if t0 >= 0.0:
        uncertainty_restart(u, t0)
    e = u.axes
    g = u.par.gyro_noise
    grow = g * g * dt + e.b * dt * dt + var
    if t0 < 0.0:
        e.pt = e.pt + grow
    e.ph = min(e.ph + grow, HEADING_UNKNOWN)
    u.held.field_age = u.held.field_age + dt


def sample_step(state, uh, cov, gx, gy, gz, ax, ay, az, dt, max_residual):
    """
    The usual raw-IMU sample of an estimate that exists, in one call.

    The estimator's step without a field (``state``: the estimate's holder,
    :mod:`~ext_observer.core.ahrs.record`), the guard (the estimate
    finite, ``|q̂̄q̂ − 1| ≤ max_residual``), and where it passes the
    covariance's step (:func:`covariance_step` on the holder ``uh``) and
    the 3×3 covariance written into ``cov`` (9 slots, row-major:
    ``diag(V_t, V_t, V_h)``).

    Returns
    -------
    outcome : int
        ``SAMPLE_OK``; ``SAMPLE_NON_FINITE`` or ``SAMPLE_RESIDUAL`` (the
        estimator stepped; ``uh`` and ``cov`` are untouched); nothing ran:
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
    bias_var = 0.0
    if s.par.motion_bias != 0.0:
        bias_var = (bias_variance(s, 0, 0) + bias_variance(s, 1, 1)
                    + bias_variance(s, 2, 2)) / BIAS_TRACE_AXES
    covariance_step(uh, step_dt, gx, gy, gz, w, x, y, z, 1.0 if s.rest.detected != 0.0 else 0.0,
                    1.0 if s.rej.time > 0.0 else 0.0, bias_var, s.gyro.clipped,
                    dt - step_dt, s.hole.var, s.hole.t0, ax, ay, az, True)
    t, h = uncertainty_variances(uh[0])
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
