"""
How good the raw-IMU estimate is now: a variance for its inclination and one for its heading.

:class:`AttitudeUncertainty` runs beside
:class:`~ext_observer.core.ahrs.ahrs_observer.AhrsObserver` and is told, after
each step, what the estimator did (interval, rate, rest, an inclination held
on the gyro, the heading gain of a field); from that alone it propagates the
variance of the attitude error, as an error-state Kalman filter's covariance step does, with the
estimator's fixed gains. The model and its equations: docs/covariance.md
("The model"). :data:`~ext_observer.core.ahrs.ahrs_params.UNCERTAINTY_TABLE`
its parameters; the per-sample
arithmetic is :mod:`~ext_observer.core.ahrs.uncertainty_kernel`'s. Units
rad, s, rad/s, m/s²; every quantity a float, or an array ``(B,)`` for many
recordings at once.
"""

import math

import numpy as np

from . import uncertainty_kernel as _plain
from .ahrs_filters import rotate
from .ahrs_params import UncertaintyParams
from .compiled import entry_point
from .record import Group
from .uncertainty_kernel import (GYRO_MOTION_SIGMA, GYRO_SCALE_SIGMA, HEADING_UNKNOWN,
                                 INNOVATION_TIME, UNC)

__all__ = [
    'AttitudeUncertainty',
    'HEADING_UNKNOWN',
    'covariance_out',
]

_FLOAT64 = np.dtype(np.float64)
# UNC's sub-groups by name.
_GROUPS = {m.name: m for m in UNC.members if isinstance(m, Group)}


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


def _names(group):
    """The names of a group's fields (not its sub-groups')."""
    return [m[0] for m in group.members if not isinstance(m, Group)]


def _check_dt(dt):
    if not (math.isfinite(dt) and dt > 0.0):
        raise ValueError(f'dt must be positive and finite, got {dt}')


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
        self._variances = _plain.covariance_variances
        # The per-sample state and its constants: a record of UNC in a
        # holder (what the kernels take); self._u reads and writes it.
        self._holder = UNC.holder(False)
        self._u = UNC.view(self._holder)
        par = self._u.par
        par.tau_acc, par.tau_rest = self._tau[0], self._tau[2]
        par.gyro_noise, par.gyro_rate_noise = p.gyro_noise, p.gyro_rate_noise
        par.bias_std, par.bias_time, par.acc_noise = p.bias_std, p.bias_time, p.acc_noise
        par.tilt_floor = 0.5 * p.inclination_floor ** 2
        par.heading_floor = p.heading_floor ** 2
        par.stamp2 = p.stamp_error ** 2
        self._u.coef.dt = math.nan  # no coefficients yet
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
        copied into the new kernels' holder; the variances go on as they
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
        if kernels.compiled and (np.ndim(self.use_mag) or any(
                np.ndim(UNC.get(self._holder[0], '.'.join(path)))
                for path, _, _, _ in UNC.fields())):
            raise ValueError('the compiled kernels take one estimate, not arrays')
        holder = UNC.holder(kernels.compiled)
        UNC.copy(self._holder[0], holder[0])
        self._holder, self._u = holder, UNC.view(holder)
        self._kernel, self._compiled = kernels.uncertainty, kernels.compiled
        self._variances = (self._first_variances if kernels.compiled
                           else kernels.uncertainty.covariance_variances)

    def _first_variances(self, holder):
        """The compiled variances; from now on their code called past numba's dispatch."""
        out = self._kernel.covariance_variances(holder)
        self._variances = entry_point(self._kernel.covariance_variances)
        return out

    @property
    def state(self):
        """
        The holder of the state: what the kernels take.

        A record of :data:`~ext_observer.core.ahrs.uncertainty_kernel.UNC`
        in a one-element structured array with the compiled kernels,
        ``[record]`` with the plain ones: what
        :func:`~ext_observer.core.ahrs.uncertainty_kernel.sample_step` steps.
        """
        return self._holder

    @property
    def heading_set(self):
        """Whether a field has corrected the heading since the start (bool, or an array)."""
        value = self._u.head.heading_set
        return float(value) != 0.0 if self._compiled else value

    @heading_set.setter
    def heading_set(self, value):
        self._u.head.heading_set = value

    @property
    def _dt(self):
        """The interval of the coefficients, s (NaN: none yet)."""
        return float(self._u.coef.dt)

    # --- state -------------------------------------------------------------

    def reset(self):
        """Forget everything: nothing is known until :meth:`start`."""
        self.started = False
        self.heading_set = False
        self.last_field = None
        u = self._u
        e = u.axes
        e.pt = e.ct = e.ph = e.ch = e.b = 0.0
        u.head.unknown = 0.0
        u.head.calibration = 0.0
        u.rate.wh2 = u.rate.wz2 = 0.0
        self._clear_start()

    def _clear_start(self):
        u = self._u
        zero = 0.0 * u.axes.pt
        for name in ('start', 'held', 'head_start'):
            record = getattr(u, name)
            for field in _names(_GROUPS[name]):
                setattr(record, field, zero)
        u.head.lag = zero

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
        u = self._u
        e = u.axes
        self.started = True
        self.heading_set = self.use_mag & False
        e.pt = u.coef.r_acc
        e.ct = e.ch = 0.0 * e.pt
        e.b = p.bias_init * p.bias_init + 0.0 * e.pt
        # 9D: only the reference is unknown, the drift starts now; 6D: the
        # heading is the start's, one sample's drift.
        e.ph = (1 - self.use_mag) * u.coef.q_gyro
        u.head.unknown = self.use_mag * HEADING_UNKNOWN
        u.head.calibration = 0.0
        u.rate.wh2 = u.rate.wz2 = 0.0
        self._clear_start()
        if acc is not None:
            # The estimate was taken from this sample: only its norm shows.
            ax, ay, az = acc
            self._start_sample(dt, (0.0 * ax, 0.0 * ax, (ax * ax + ay * ay + az * az) ** 0.5))

    def _start_sample(self, dt, f):
        """The start's share for a world-frame specific force ``f`` (floats, or arrays (B,))."""
        kernel = self._kernel
        fx, fy, fz = f
        if self._compiled or not np.ndim(fx):
            kernel.covariance_start(self._holder, float(dt), float(fx), float(fy), float(fz))
            return
        # Many recordings: the same kernel on each one's floats.
        u = self._u
        names = _names(_GROUPS['start'])
        columns = {n: np.array(np.broadcast_to(getattr(u.start, n), np.shape(fx)), dtype=float)
                   for n in names}
        if not (columns['var'].any() or (columns['time'] < u.par.tau_acc).any()):
            return
        holder = UNC.holder(False)
        one = holder[0]
        for group in ('par', 'coef'):  # the constants and coefficients: floats
            for n in _names(_GROUPS[group]):
                setattr(getattr(one, group), n, getattr(getattr(u, group), n))
        for b in range(len(fx)):
            for n in names:
                setattr(one.start, n, float(columns[n][b]))
            kernel.covariance_start(holder, float(dt), float(fx[b]), float(fy[b]), float(fz[b]))
            for n in names:
                columns[n][b] = getattr(one.start, n)
        for n in names:
            setattr(u.start, n, columns[n])

    def _coefficients(self, dt):
        _check_dt(dt)
        self._kernel.covariance_coefficients(self._holder, float(dt))

    # --- the steps ---------------------------------------------------------

    def step(self, dt, gyr, q, rest, bias_var=None, clip_var=None, acc=None, hole=None,
             held=None):
        """
        One IMU sample: the gyro's propagation, the bias at rest, the inclination correction.

        And what the estimator said of the sample: its bias variance, a
        clipped rate, a hole bridged, the start's share
        (:func:`~ext_observer.core.ahrs.uncertainty_kernel.covariance_step`).

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
            The specific force, m/s², body: how unsure the start still is.
            None: nothing of the start is counted (as at rest).
        hole : tuple of 3 float, optional
            A hole the estimator bridged: ``(extra, var, t0)``, the seconds
            beyond ``dt`` (the usual interval, whose coefficients the step
            kept), the bridge's variance per axis, rad²
            (:func:`~ext_observer.core.ahrs.uncertainty_kernel.uncertainty_hole`),
            and the seconds the restarted inclination mean weighs the old as
            (negative: not restarted; :func:`~ext_observer.core.ahrs.uncertainty_kernel.
            uncertainty_restart`).
        held : bool or ndarray, optional
            Whether the estimator held the inclination on the gyro, the
            specific force rejected (:attr:`AhrsObserver.held
            <ext_observer.core.ahrs.ahrs_observer.AhrsObserver.held>`): no
            correction from it. None: not held.

        """
        if dt != self._u.coef.dt:
            _check_dt(dt)
        gx, gy, gz = gyr
        w, x, y, z = q
        extra, hole_var, hole_t0 = ((float(hole[0]), float(hole[1]), float(hole[2]))
                                    if hole is not None else (0.0, 0.0, -1.0))
        ax, ay, az = acc if acc is not None else (0.0, 0.0, 0.0)
        if self._compiled:
            self._kernel.covariance_step(
                self._holder, float(dt), float(gx), float(gy), float(gz), float(w), float(x),
                float(y), float(z), 1.0 if rest else 0.0, 1.0 if held else 0.0,
                0.0 if bias_var is None else float(bias_var),
                0.0 if clip_var is None else float(clip_var), extra, hole_var, hole_t0,
                float(ax), float(ay), float(az), acc is not None)
            return
        # Many recordings count the start one by one, after the step (the
        # kernel's order: the start's share last).
        many = acc is not None and any(np.ndim(v) for v in (w, x, y, z, ax, ay, az))
        self._kernel.covariance_step(
            self._holder, dt, gx, gy, gz, w, x, y, z, rest, 0.0 if held is None else held,
            0.0 if bias_var is None else bias_var, 0.0 if clip_var is None else clip_var,
            extra, hole_var, hole_t0, ax, ay, az, acc is not None and not many)
        if many:
            self._start_sample(dt, rotate(w, x, y, z, ax, ay, az))

    def unbridged(self, dt, var, t0):
        """
        A hole of ``dt`` s the estimator did not bridge (over ``max_dt``): what it leaves.

        ``var`` the rotation it may have hidden (rad² per axis) and ``t0``
        the weight the inclination's mean restarted with (negative: kept),
        :meth:`AhrsObserver.unbridged
        <ext_observer.core.ahrs.ahrs_observer.AhrsObserver.unbridged>`'s
        (:func:`~ext_observer.core.ahrs.uncertainty_kernel.covariance_unbridged`).
        One estimate (floats).
        """
        self._kernel.covariance_unbridged(self._holder, float(dt), float(var), float(t0))

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
        u = self._u
        e, head, held = u.axes, u.head, u.held
        unknown = head.unknown
        # A correction pulls the whole heading error, the reference's part
        # included, to the field's; without one both stay.
        e.ph = a * a * (e.ph + used * unknown) + gain * gain * self._r_mag
        e.ch = a * e.ch
        held.yaw = a * held.yaw
        held.rotation = a * held.rotation
        held.field_age = 0.0 * held.field_age
        held.ph = e.ph
        unknown = (1 - used) * unknown
        self.heading_set = self.heading_set | used
        c2 = calibration * calibration
        ref = reference + u.par.heading_floor
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
        head.unknown = unknown
        head.calibration = used * c2 + (1 - used) * head.calibration
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
        head, k = self._u.head, self._k_lag
        lag = (a > 0.0) * head.lag
        # l ← (1 − k) l + k ψ, where a used field gave ψ
        if isinstance(lag, float) and not np.ndim(innovation):
            if used and innovation == innovation:
                lag = lag + k * (innovation - lag)
        else:
            given = np.asarray(used) & np.isfinite(innovation)
            lag = np.where(given, lag + k * (np.nan_to_num(innovation) - lag), lag)
        head.lag = float(lag) if self._compiled else lag

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
        hs, start = self._u.head_start, self._u.start
        w0, tan, rest = hs.weight, hs.tan_dip, hs.since
        if not (np.ndim(dip) or np.ndim(gain) or np.ndim(w0)):
            # One estimate (the node's path): floats.
            if dip != dip:
                return
            t = abs(math.tan(dip))
            one = math.atan(math.sqrt(max(start.mean, start.first)))
            if tan == 0.0:  # the first field: the heading was taken from it
                w0, rest = 1.0, 0.0
            else:
                w0 = w0 * (1.0 - gain)
                rest = (1.0 - gain) * rest + gain * t * math.sqrt(start.var)
            hs.weight, hs.tan_dip, hs.since = w0, t, rest
            hs.sigma = w0 * t * one + rest
            return
        one = np.arctan(np.sqrt(np.maximum(start.mean, start.first)))
        now = np.sqrt(start.var)
        with np.errstate(invalid='ignore'):
            t = np.abs(np.tan(dip))
        seen = np.isfinite(t)
        t = np.where(seen, t, 0.0)
        first = seen & (tan == 0.0)
        k = np.where(first, 0.0, gain)
        w0 = np.where(first, 1.0, w0 * (1.0 - k))
        rest = np.where(first, 0.0, np.where(seen, (1.0 - k) * rest + k * t * now, rest))
        tan = np.where(seen, t, tan)
        sigma = w0 * tan * one + rest
        for name, v in (('weight', w0), ('tan_dip', tan), ('since', rest), ('sigma', sigma)):
            setattr(hs, name, float(v) if self._compiled or not np.ndim(v) else v)

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
    def held_variance(self):
        """
        The heading variance the gyro alone added since the last field, rad².

        What the propagation added to ``P`` since (the gyro's noise, its
        bias) and the held term of a field lost (the gyro's scale and axes
        errors over the rotation since): what a field back has to correct.
        """
        u = self._u
        scale = GYRO_SCALE_SIGMA * u.held.yaw
        axes = GYRO_MOTION_SIGMA * u.held.rotation
        grown = u.axes.ph - u.held.ph
        return grown * (grown > 0.0) + scale * scale + axes * axes

    @property
    def tilt_variance(self):
        """Variance of the tilt about each horizontal world axis, rad²."""
        return self._variances(self._holder)[0]

    @property
    def heading_variance(self):
        """Variance of the heading (about the world vertical), rad²."""
        return self._variances(self._holder)[1]

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
        t, h = self._variances(self._holder)
        z = 0.0 * t
        return (t, z, z, z, t, z, z, z, h)
