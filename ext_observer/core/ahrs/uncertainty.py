"""
How good the raw-IMU estimate is now: a variance for its inclination and one for its heading.

:class:`AttitudeUncertainty` runs beside
:class:`~ext_observer.core.ahrs.ahrs_observer.AhrsObserver` and is told, after
each step, what the estimator did (interval, rate, rest, the heading gain
of a field); from that alone it propagates the variance of the attitude
error, as an error-state Kalman filter's covariance step does, with the
estimator's fixed gains. The model and its equations: docs/covariance.md
("The model"). :data:`~ext_observer.core.ahrs.ahrs_params.UNCERTAINTY_TABLE` its parameters; the per-sample
arithmetic is :mod:`~ext_observer.core.ahrs.uncertainty_kernel`'s. Units
rad, s, rad/s, m/s²; every quantity a float, or an array ``(B,)`` for many
recordings at once.
"""

import math

import numpy as np

from . import uncertainty_kernel as _plain
from .ahrs_filters import rotate
from .ahrs_params import UncertaintyParams
from .uncertainty_kernel import (
    GRAVITY, U_ACC_NOISE, U_B, U_BIAS_STD, U_BIAS_TIME, U_CALIBRATION, U_CH, U_CT, U_DT,
    U_GYRO_NOISE, U_GYRO_RATE_NOISE, U_HEADING_FLOOR, U_HEADING_SET, U_HS, U_HS_REST, U_HS_TAN,
    U_HS_W0, U_K_ACC, U_K_REST, U_LAG, U_PH,
    U_PHI, U_PT, U_Q_BIAS, U_Q_GYRO, U_Q_RATE, U_R_ACC, U_R_GYRO, U_SIZE, U_STAMP2,
    U_START_F, U_START_M, U_START_N, U_START_T, U_START_V, U_TAU_ACC,
    U_TAU_REST, U_TILT_FLOOR, U_UNKNOWN, U_WH2, U_WZ2, U_FIELD_AGE, U_YAW_HELD,
    U_ROTATION_HELD, INNOVATION_TIME)

__all__ = [
    'AttitudeUncertainty',
    'GRAVITY',
    'HEADING_UNKNOWN',
    'covariance_out',
]

# Variance of a heading known to be nothing better than uniform on (−π, π], rad².
HEADING_UNKNOWN = math.pi * math.pi / 3.0
_FLOAT64 = np.dtype(np.float64)
# The slots uncertainty_start writes.
_START_SLOTS = (U_START_T, U_START_N, U_START_M, U_START_F, U_START_V)
# The slots of the heading's share of the start.
_HS_SLOTS = (U_HS_W0, U_HS_TAN, U_HS_REST, U_HS)


def covariance_out(array):
    """
    Return ``array`` if the kernels may write a covariance into it, else raise ValueError.

    A writable C-contiguous float64 array of 9 (a ``sensor_msgs/Imu``
    message's ``orientation_covariance`` is one): the compiled kernels write
    into its memory as that, unchecked.
    """
    if not (array.__class__ is np.ndarray and array.flags.c_contiguous
            and array.dtype is _FLOAT64 and array.shape == (9,) and array.flags.writeable):
        raise ValueError('a covariance is written into a writable C-contiguous float64 '
                         f'array of 9, got {array!r}')
    return array


class _Slot:
    """An attribute kept in the tracker's flat state ``_u``: a float, or an array ``(B,)``."""

    def __init__(self, index, flag=False):
        self.index = index
        self.flag = flag

    def __get__(self, obj, owner=None):
        if obj is None:
            return self
        value = obj._u[self.index]
        if obj._compiled:  # a float64 array: a Python float (or bool) out
            return float(value) != 0.0 if self.flag else float(value)
        return value

    def __set__(self, obj, value):
        obj._u[self.index] = value


class AttitudeUncertainty:
    """
    The variance of the raw-IMU estimate's inclination and heading, step by step.

    Parameters
    ----------
    params : UncertaintyParams, optional
    tau_acc, tau_mag, tau_rest : float
        The estimator's time constants (s): the inclination correction
        (``tau_acc + tau_acc_gain`` of :class:`~ext_observer.core.ahrs.ahrs_observer.AhrsParams`),
        the heading correction and the bias learned at rest.
    use_mag : bool or ndarray of bool
        9D (the heading is unknown until a field sets it) or 6D (the heading
        is the estimator's own start, known exactly then, and drifts).

    Attributes
    ----------
    started : bool
        Whether :meth:`start` has run since the last :meth:`reset`.
    heading_set : bool or ndarray
        Whether a field has corrected the heading since the start.
    last_field : tuple or None
        The latest :meth:`field`'s interval, gain, calibration σ, reference
        variance and dip, as given (a run can be replayed from them).

    """

    # The per-sample state and its constants live in the flat container
    # ``_u`` (uncertainty_kernel's layout); these names read and write it.
    _tilt_floor = _Slot(U_TILT_FLOOR)
    _heading_floor = _Slot(U_HEADING_FLOOR)
    _stamp2 = _Slot(U_STAMP2)
    _dt = _Slot(U_DT)
    _r_acc = _Slot(U_R_ACC)
    _q_gyro = _Slot(U_Q_GYRO)
    _pt = _Slot(U_PT)
    _ct = _Slot(U_CT)
    _ph = _Slot(U_PH)
    _ch = _Slot(U_CH)
    _b = _Slot(U_B)
    _unknown = _Slot(U_UNKNOWN)
    _calibration = _Slot(U_CALIBRATION)
    heading_set = _Slot(U_HEADING_SET, flag=True)
    _wz2 = _Slot(U_WZ2)
    _wh2 = _Slot(U_WH2)

    def __init__(self, params=None, tau_acc=2.05, tau_mag=15.0, tau_rest=0.5, use_mag=True):
        self.params = params if params is not None else UncertaintyParams()
        for name, tau in (('tau_acc', tau_acc), ('tau_mag', tau_mag), ('tau_rest', tau_rest)):
            if not (math.isfinite(tau) and tau > 0.0):
                raise ValueError(f'{name} must be positive and finite, got {tau}')
        self._tau = (float(tau_acc), float(tau_mag), float(tau_rest))
        self.use_mag = use_mag
        p = self.params
        self._kernel = _plain
        self._compiled = False
        self._u = [0.0] * U_SIZE
        u = self._u
        u[U_TAU_ACC], u[U_TAU_REST] = self._tau[0], self._tau[2]
        u[U_GYRO_NOISE], u[U_GYRO_RATE_NOISE] = p.gyro_noise, p.gyro_rate_noise
        u[U_BIAS_STD], u[U_BIAS_TIME], u[U_ACC_NOISE] = p.bias_std, p.bias_time, p.acc_noise
        # What is added on output, rad² (the stamp's per (rad/s)²).
        self._tilt_floor = 0.5 * p.inclination_floor ** 2
        self._heading_floor = p.heading_floor ** 2
        self._stamp2 = p.stamp_error ** 2
        self._dt = math.nan  # no coefficients yet
        self._field_dt = None
        self._gain_dt = None
        self.reset()

    @classmethod
    def for_estimator(cls, ahrs_params, params=None, use_mag=True):
        """Return the tracker for an estimator with these :class:`AhrsParams`."""
        return cls(params, tau_acc=ahrs_params.tau_acc + ahrs_params.tau_acc_gain,
                   tau_mag=ahrs_params.tau_mag, tau_rest=ahrs_params.tau_rest,
                   use_mag=use_mag)

    def use_kernels(self, kernels):
        """
        Go on with other kernels (plain or compiled) from the same state.

        As :meth:`AhrsObserver.use_kernels
        <ext_observer.core.ahrs.ahrs_observer.AhrsObserver.use_kernels>`: the state is
        copied into the new kernels' container; the variances go on as they
        would have. The compiled kernels take one estimate (floats), not
        arrays ``(B,)``.

        Parameters
        ----------
        kernels : ext_observer.core.ahrs.compiled.Kernels

        Raises
        ------
        ValueError
            For compiled kernels and a tracker of many recordings.

        """
        if kernels.uncertainty is self._kernel:
            return
        if kernels.compiled and any(np.ndim(v) for v in list(self._u) + [self.use_mag]):
            raise ValueError('the compiled kernels take one estimate, not arrays')
        u = kernels.container(U_SIZE)
        for i, value in enumerate(self._u):
            u[i] = value if not kernels.compiled else float(value)
        self._u, self._kernel, self._compiled = u, kernels.uncertainty, kernels.compiled

    @property
    def state(self):
        """The flat state (uncertainty_kernel's layout): what :func:`sample_step` steps."""
        return self._u

    # --- state -------------------------------------------------------------

    def reset(self):
        """Forget everything: nothing is known until :meth:`start`."""
        self.started = False
        self.heading_set = False
        self.last_field = None
        self._pt = self._ct = self._ph = self._ch = self._b = 0.0
        self._unknown = 0.0
        self._calibration = 0.0
        self._wh2 = self._wz2 = 0.0
        self._clear_start()

    def _clear_start(self):
        u = self._u
        u[U_START_T] = u[U_START_N] = u[U_START_M] = u[U_START_F] = u[U_START_V] = 0.0 * u[U_PT]
        u[U_YAW_HELD] = u[U_ROTATION_HELD] = u[U_FIELD_AGE] = u[U_LAG] = 0.0 * u[U_PT]
        for i in _HS_SLOTS:
            u[i] = 0.0 * u[U_PT]

    def start(self, dt, acc=None):
        """
        The estimator has just initialized from one accelerometer sample.

        The inclination is that sample's direction (``acc``, m/s², body: how
        far a moving body's may be off, see
        :func:`~ext_observer.core.ahrs.uncertainty_kernel.uncertainty_start`;
        None: counted as at rest); in 9D the heading is
        unknown until a field corrects it (:meth:`field`, gain 1 for the
        first); in 6D the heading is the estimator's own start, and only
        its drift from there is counted. The bias is unknown
        (``bias_init``).
        """
        self._coefficients(dt)
        p = self.params
        self.started = True
        self.heading_set = self.use_mag & False
        self._pt = self._r_acc
        self._ct = self._ch = 0.0 * self._pt
        self._b = p.bias_init * p.bias_init + 0.0 * self._pt
        # 9D: only the reference is unknown, the drift starts now; 6D: the
        # heading is the start's, one sample's drift.
        self._ph = (1 - self.use_mag) * self._q_gyro
        self._unknown = self.use_mag * HEADING_UNKNOWN
        self._calibration = 0.0
        self._wh2 = self._wz2 = 0.0
        self._clear_start()
        if acc is not None:
            # The estimate was taken from this sample: only its norm shows.
            ax, ay, az = acc
            self._start_sample(dt, (0.0 * ax, 0.0 * ax, (ax * ax + ay * ay + az * az) ** 0.5))

    def _start_sample(self, dt, f):
        """The start's share for a world-frame specific force ``f`` (floats, or arrays ``(B,)``)."""
        u, kernel = self._u, self._kernel
        fx, fy, fz = f
        if self._compiled or not np.ndim(fx):
            if u[U_START_V] != 0.0 or u[U_START_T] < u[U_TAU_ACC]:
                kernel.uncertainty_start(u, float(dt), float(fx), float(fy), float(fz))
            return
        # Many recordings: the same kernel on each one's floats.
        columns = {i: np.array(np.broadcast_to(u[i], np.shape(fx)), dtype=float)
                   for i in _START_SLOTS}
        if not (columns[U_START_V].any() or (columns[U_START_T] < u[U_TAU_ACC]).any()):
            return
        one = list(u)
        for b in range(len(fx)):
            for i in _START_SLOTS:
                one[i] = float(columns[i][b])
            if one[U_START_V] != 0.0 or one[U_START_T] < one[U_TAU_ACC]:
                kernel.uncertainty_start(one, float(dt), float(fx[b]), float(fy[b]),
                                         float(fz[b]))
            for i in _START_SLOTS:
                columns[i][b] = one[i]
        for i in _START_SLOTS:
            u[i] = columns[i]

    def _coefficients(self, dt):
        if not (math.isfinite(dt) and dt > 0.0):
            raise ValueError(f'dt must be positive and finite, got {dt}')
        self._kernel.uncertainty_coefficients(self._u, float(dt))

    # --- the steps ---------------------------------------------------------

    def step(self, dt, gyr, q, rest, bias_var=None, clip_var=None, acc=None, hole=None):
        """
        One IMU sample: the gyro's propagation, the bias at rest, the inclination correction.

        (:func:`~ext_observer.core.ahrs.uncertainty_kernel.uncertainty_step`.)

        Parameters
        ----------
        dt : float
            Interval, s (as given to the estimator).
        gyr : sequence of 3
            The measured rate, rad/s, body frame.
        q : sequence of 4
            The estimate after the step, ``(w, x, y, z)``, sensor → world,
            any nonzero norm (for the rate's world components).
        rest : bool or ndarray
            Whether the estimator detected rest (and learned the bias).
        bias_var : float or ndarray, optional
            The estimator's own bias variance, (rad/s)² per axis (its
            Kalman filter's, :attr:`AhrsObserver.bias_std
            <ext_observer.core.ahrs.ahrs_observer.AhrsObserver.bias_std>`): the
            model's is at least that. None: the model's alone.
        clip_var : float or ndarray, optional
            What a sample at the gyro's range adds to the angle's variances,
            rad² (:attr:`AhrsObserver.clip_variance
            <ext_observer.core.ahrs.ahrs_observer.AhrsObserver.clip_variance>`).
        acc : sequence of 3, optional
            The specific force, m/s², body: how unsure the start still is
            (one estimate, floats). None: nothing of the start is counted
            (as at rest).
        hole : tuple of 3 float, optional
            A hole the estimator bridged: ``(extra, var, t0)``, the seconds
            beyond ``dt`` (the usual interval, whose coefficients the step
            kept), the bridge's variance per axis, rad²
            (:func:`~ext_observer.core.ahrs.uncertainty_kernel.uncertainty_hole`),
            and the seconds the restarted inclination mean weighs the old as
            (negative: not restarted; :func:`~ext_observer.core.ahrs.uncertainty_kernel.
            uncertainty_restart`).

        """
        if dt != self._u[U_DT]:
            self._coefficients(dt)
        gx, gy, gz = gyr
        w, x, y, z = q
        if self._compiled:
            self._kernel.uncertainty_step(self._u, float(dt), float(gx), float(gy), float(gz),
                                          float(w), float(x), float(y), float(z),
                                          1.0 if rest else 0.0)
        else:
            self._kernel.uncertainty_step(self._u, dt, gx, gy, gz, w, x, y, z, rest)
        if hole is not None and hole[2] >= 0.0:
            self._kernel.uncertainty_restart(self._u, float(hole[2]))
        if bias_var is not None:
            self._kernel.uncertainty_bias(
                self._u, float(bias_var) if self._compiled else bias_var)
        if clip_var is not None and np.any(clip_var):
            self._kernel.uncertainty_clipped(
                self._u, float(clip_var) if self._compiled else clip_var)
        if hole is not None:
            self._kernel.uncertainty_hole(self._u, float(hole[0]), float(hole[1]),
                                          hole[2] < 0.0)
        if acc is not None:
            self._start_sample(dt, rotate(w, x, y, z, *acc))

    def unbridged(self, dt, var, t0):
        """
        A hole of ``dt`` s the estimator did not bridge (over ``max_dt``): what it leaves.

        ``var`` the rotation it may have hidden (rad² per axis) and ``t0``
        the weight the inclination's mean restarted with (negative: kept),
        :meth:`AhrsObserver.unbridged
        <ext_observer.core.ahrs.ahrs_observer.AhrsObserver.unbridged>`'s. The
        angles' variances grow by it and by the gyro's noise and bias over
        the hole, the inclination's only where its mean was kept (else it
        restarts as after a bridged hole); the heading's up to that of an
        unknown heading. The hole counts as time without a field. One
        estimate (floats).
        """
        st = self._u
        if t0 >= 0.0:
            self._kernel.uncertainty_restart(st, float(t0))
        g = st[U_GYRO_NOISE]
        grow = g * g * dt + st[U_B] * dt * dt + var
        if t0 < 0.0:
            st[U_PT] = st[U_PT] + grow
        st[U_PH] = min(st[U_PH] + grow, HEADING_UNKNOWN)
        st[U_FIELD_AGE] = st[U_FIELD_AGE] + dt

    def field(self, dt, gain, calibration=0.0, reference=math.nan, dip=math.nan,
              innovation=math.nan):
        """
        A field, and the gain with which it corrected the heading.

        Parameters
        ----------
        dt : float or None
            Interval since the previous field, s; None: the IMU's.
        gain : float or ndarray
            The estimator's heading gain for this field, in [0, 1]; 0 when
            it was rejected (or the magnetometer is not calibrated yet).
        calibration : float or ndarray
            The magnetometer calibration's heading σ now, rad (0 without
            one; at most that of an unknown heading is counted, also for
            an infinite or NaN σ); counted while the heading follows the
            field.
        reference : float or ndarray
            Where the field did not correct the heading (gain 0) and the
            heading still rests on a field whose calibration is being
            learned: ``turn² + quality²`` of that calibration for this field,
            rad² (see the module's docstring; at most that of an unknown
            heading is counted, also for inf). NaN: nothing new (the
            default).
        dip : float or ndarray
            The dip of the estimator's field references, rad (NaN: none,
            the default): how far the start's inclination error turns the
            heading taken from a field (:meth:`_heading_start`).
        innovation : float or ndarray
            Where the field corrected the heading: its heading in the
            corrected estimate's frame, rad (what is left of the correction;
            NaN: not given, the default). Its mean over the last
            :data:`~ext_observer.core.ahrs.uncertainty_kernel.INNOVATION_TIME`
            is the heading's lag behind the fields, whatever its cause (a
            gyro's scale error in fast turns, a bias not yet learned), and
            its square is published (:meth:`_lag`). Not part of
            :attr:`last_field`.

        """
        dt = self._dt if dt is None else dt
        self.last_field = (dt, gain, calibration, reference, dip)
        if dt != self._field_dt:
            if not (math.isfinite(dt) and dt > 0.0):
                raise ValueError(f'dt must be positive and finite, got {dt}')
            self._field_dt = dt
            self._r_mag = self.params.mag_noise ** 2 / dt
            self._k_lag = 1.0 - math.exp(-dt / INNOVATION_TIME)
        used = gain > 0.0
        a = 1.0 - gain
        # Each slot read and written once (a compiled state is an array).
        st = self._u
        unknown = st[U_UNKNOWN]
        # A correction pulls the whole heading error, the reference's part
        # included, to the field's; without one both stay.
        st[U_PH] = a * a * (st[U_PH] + used * unknown) + gain * gain * self._r_mag
        st[U_CH] = a * st[U_CH]
        st[U_YAW_HELD] = a * st[U_YAW_HELD]
        st[U_ROTATION_HELD] = a * st[U_ROTATION_HELD]
        st[U_FIELD_AGE] = 0.0 * st[U_FIELD_AGE]
        unknown = (1 - used) * unknown
        self.heading_set = self.heading_set | used
        c2 = calibration * calibration
        ref = reference + st[U_HEADING_FLOOR]
        if isinstance(c2, float):
            c2 = c2 if c2 <= HEADING_UNKNOWN else HEADING_UNKNOWN
        else:
            c2 = np.where(c2 <= HEADING_UNKNOWN, c2, HEADING_UNKNOWN)
        if isinstance(ref, float):
            if ref == ref and not used:
                unknown = ref if ref <= HEADING_UNKNOWN else HEADING_UNKNOWN
        else:
            given = (ref == ref) & ~np.asarray(used)
            unknown = np.where(given, np.minimum(ref, HEADING_UNKNOWN), unknown)
        st[U_UNKNOWN] = unknown
        st[U_CALIBRATION] = used * c2 + (1 - used) * st[U_CALIBRATION]
        self._lag(a, used, innovation)
        self._heading_start(gain, dip)

    def _lag(self, a, used, innovation):
        """
        The heading's lag behind the fields, for a field that kept ``a = 1 − κ`` of the error.

        A field's innovation is the heading error it shows plus its own
        noise; averaged over seconds the noise goes and a lag stays: an
        error the propagation does not explain (a drift of ``r`` rad/s
        stands at about ``r tau_mag`` under the correction, which the
        innovations after each correction still show). A full correction
        (the heading taken from a field) clears it; a field not used, or
        one whose innovation is not given, teaches nothing. The lag is held
        while no field comes: the heading keeps the error it had.
        """
        st, k = self._u, self._k_lag
        lag = (a > 0.0) * st[U_LAG]
        # l ← (1 − k) l + k ψ, where a used field gave ψ
        if isinstance(lag, float) and not np.ndim(innovation):
            if used and innovation == innovation:
                lag = lag + k * (innovation - lag)
        else:
            given = np.asarray(used) & np.isfinite(innovation)
            lag = np.where(given, lag + k * (np.nan_to_num(innovation) - lag), lag)
        st[U_LAG] = float(lag) if self._compiled else lag

    def _heading_start(self, gain, dip):
        """
        The heading's share of the start (9D), for a field with this gain and dip.

        The estimator takes its first heading from the first field's
        horizontal part, seen with the first sample's inclination: a moving
        body's is off by its acceleration, ε per horizontal axis with one
        sample's variance ``atan²(√max(m, f))`` (``m`` the mean of what the
        samples since show of the motion, ``f`` the first one's;
        :func:`~ext_observer.core.ahrs.uncertainty_kernel.uncertainty_start`),
        and a tilt error about the axis across the field turns the field's
        horizontal part by ε·|tan(dip)|. That error stays in the heading,
        gyro-held, as long as the heading keeps that first field: its
        weight ``w0`` shrinks by ``(1 − κ)`` with each field that corrects
        the heading with gain κ. Each such field brings the inclination
        error of its own time (the start's variance still owed, ``V``),
        ``r ← (1 − κ) r + κ |tan(dip)| √V``; the two are the same motion's
        error, added as σ: ``σ = w0 |tan(dip)| atan(√max(m, f)) + r``.
        Before any field, and in 6D, nothing (the heading is unknown, or
        the start's own).
        """
        st = self._u
        w0, tan, rest = st[U_HS_W0], st[U_HS_TAN], st[U_HS_REST]
        if not (np.ndim(dip) or np.ndim(gain) or np.ndim(w0)):
            # One estimate (the node's path): floats.
            if dip != dip:
                return
            t = abs(math.tan(dip))
            one = math.atan(math.sqrt(max(st[U_START_M], st[U_START_F])))
            if tan == 0.0:  # the first field: the heading was taken from it
                w0, rest = 1.0, 0.0
            else:
                w0 = w0 * (1.0 - gain)
                rest = (1.0 - gain) * rest + gain * t * math.sqrt(st[U_START_V])
            st[U_HS_W0], st[U_HS_TAN], st[U_HS_REST] = w0, t, rest
            st[U_HS] = w0 * t * one + rest
            return
        one = np.arctan(np.sqrt(np.maximum(st[U_START_M], st[U_START_F])))
        now = np.sqrt(st[U_START_V])
        with np.errstate(invalid='ignore'):
            t = np.abs(np.tan(dip))
        seen = np.isfinite(t)
        t = np.where(seen, t, 0.0)
        first = seen & (tan == 0.0)
        k = np.where(first, 0.0, gain)
        w0 = np.where(first, 1.0, w0 * (1.0 - k))
        rest = np.where(first, 0.0, np.where(seen, (1.0 - k) * rest + k * t * now, rest))
        tan = np.where(seen, t, tan)
        hs = w0 * tan * one + rest
        for i, v in ((U_HS_W0, w0), (U_HS_TAN, tan), (U_HS_REST, rest), (U_HS, hs)):
            st[i] = float(v) if self._compiled or not np.ndim(v) else v

    def heading_gain(self, count, dt=None):
        """
        The estimator's heading gain for the ``count``-th field used since the start.

        ``max(1 − exp(−dt / tau_mag), 1 / count)``: a running mean of the
        first fields, then the first-order correction (as
        :class:`~ext_observer.core.ahrs.ahrs_observer.AhrsObserver` does).
        """
        dt = self._dt if dt is None else dt
        if dt != self._gain_dt:
            self._gain_dt = dt
            self._k_mag = 1.0 - math.exp(-dt / self._tau[1])
        k = self._k_mag
        return (k if k * count > 1.0 else 1.0 / count) if count >= 1 else 0.0

    # --- outputs -----------------------------------------------------------

    @property
    def tilt_variance(self):
        """Variance of the tilt about each horizontal world axis, rad²."""
        return self._kernel.uncertainty_variances(self._u)[0]

    @property
    def heading_variance(self):
        """Variance of the heading (about the world vertical), rad²."""
        return self._kernel.uncertainty_variances(self._u)[1]

    @property
    def inclination_std(self):
        """σ of the inclination angle, rad: ``√(2 V_t)``."""
        return (2.0 * self.tilt_variance) ** 0.5

    @property
    def heading_std(self):
        """σ of the heading, rad."""
        return self.heading_variance ** 0.5

    @property
    def covariance(self):
        """
        The 3×3 covariance about the world frame's x, y, z axes, row-major.

        Returns
        -------
        tuple of 9
            ``(V_t, 0, 0, 0, V_t, 0, 0, 0, V_h)``, rad².

        """
        t, h = self._kernel.uncertainty_variances(self._u)
        z = 0.0 * t
        return (t, z, z, z, t, z, z, z, h)
