"""
Attitude from a raw IMU, gyro + accelerometer (+ magnetometer): :class:`AhrsObserver`.

The estimate ``q̂`` lives in R⁴ as in the paper's observer, held near S³ by
the extension term and never renormalized. Each sample runs three steps,
gyro, accelerometer (inclination) and magnetometer (heading only), written
once on a flat state in :mod:`~ext_observer.core.ahrs.ahrs_kernel` (plain or
compiled: the same estimates); this class wraps them for one estimate or a
batch of ``(B,)`` arrays. The steps, the credit to VQF and the conventions
(``(w, x, y, z)``, sensor → ENU, SI units) are docs/raw_imu.md's
("The estimator, step by step"); the calibration's phases docs/calibration.md's.
"""

import math

import numpy as np

from .frames import check_dt, initial_attitude, WORLD_FRAMES, world_from_enu
from .ahrs_params import AhrsParams
from .compiled import kernels
from .magcal import MagCalibrator
from .ahrs_layout import P_VEL_TIMEOUT, S_VEL_USED
from .velocity_kernel import VELOCITY_TIMEOUT

__all__ = [
    'AhrsObserver',
    'AhrsParams',
    'MODES',
    'WORLD_FRAMES',
    'initial_attitude',
    'world_from_enu',
]

MODES = ('6D', '9D')


class AhrsObserver:
    """
    The raw-IMU estimator on floats (one estimate) or on ``(B,)`` arrays.

    The steps are the functions of :mod:`~ext_observer.core.ahrs.ahrs_kernel` on
    one flat state per estimate: compiled by numba when it is installed
    (:mod:`~ext_observer.core.ahrs.compiled`), plain Python otherwise, one source
    and the same results to rounding. With ``batch``, the estimates step one
    after the other.

    Parameters
    ----------
    params : AhrsParams, optional
        With ``batch``, a value may be an array of shape ``(B,)``: one per
        estimate (``mag_cal_rate``: the largest counts for all).
    use_mag : bool or ndarray of bool, shape (B,)
        9D (heading from the magnetometer) where true, 6D elsewhere.
    batch : int, optional
        ``None`` for one estimate on floats; ``B`` for arrays of shape (B,).
    variant : {'extended', 'plain'}
        ``plain`` drops the extension term (for comparison only).
    compiled : bool, optional
        Run the compiled steps (an error if numba is not installed), or the
        plain ones; default: compiled where numba is installed, unless the
        environment sets ``EXT_OBSERVER_COMPILED=0``.

    Attributes
    ----------
    q : tuple of 4
        The ambient estimate ``(w, x, y, z)``, sensor → ENU; ``None`` until
        the first accelerometer sample initializes it.
    bias : tuple of 3
        The gyro bias estimate (rad/s), body frame.
    rest : bool or ndarray
        Whether rest is detected.
    mag_disturbed : bool or ndarray
        Whether the last magnetometer sample was rejected.
    calibration : MagCalibrator or None
        The online magnetometer calibration (``None`` when ``mag_cal`` is
        false or no element runs 9D): ``bias``, ``soft_iron``, ``quality``,
        ``counts``.
    compiled : bool
        Whether the compiled steps run.

    """

    def __init__(self, params=None, use_mag=True, batch=None, variant='extended', compiled=None):
        if variant not in ('extended', 'plain'):
            raise ValueError(f"variant must be 'extended' or 'plain', got {variant!r}")
        self.params = params if params is not None else AhrsParams()
        self.batch = batch
        self.variant = variant
        n = 1 if batch is None else int(batch)
        self._n = n
        if batch is None:
            self.use_mag = bool(use_mag)
            uses = [self.use_mag]
        else:
            self.use_mag = np.broadcast_to(np.asarray(use_mag, dtype=bool), (n,)).copy()
            uses = [bool(u) for u in self.use_mag]
        self._kernels = kernels(compiled)
        self.compiled = self._kernels.compiled
        k = self._kernels.ahrs
        p = self.params
        values = p.as_dict()

        def each(name, i):
            value = values[name]
            return float(value[i]) if np.ndim(value) else float(value)

        calibrate = [bool(np.asarray(p.mag_cal)[i] if np.ndim(p.mag_cal) else p.mag_cal)
                     and uses[i] for i in range(n)]
        size = k.A_SIZE + (self._kernels.magcal.MC_SIZE if any(calibrate) else 0)
        self._states = []
        for i in range(n):
            s = self._kernels.container(size)
            for name in k.PARAMETERS:
                s[k.AHRS.offset(name)] = each(name, i)
            s[k.P_USE_MAG] = 1.0 if uses[i] else 0.0
            s[k.P_EXTENDED] = 1.0 if variant == 'extended' else 0.0
            s[k.P_HAS_CAL] = 1.0 if calibrate[i] else 0.0
            s[k.P_MOTION_BIAS] = 1.0 if each('tau_bias', i) > 0.0 else 0.0
            s[k.C_DT] = s[k.C_MAG_DT] = math.nan
            s[k.S_ACC_STILL] = 1.0
            s[P_VEL_TIMEOUT] = VELOCITY_TIMEOUT
            self._states.append(s)
        self._dt = None
        self._mag_dt = None
        self.calibration = None
        if any(calibrate):
            self.calibration = MagCalibrator(
                batch, enabled=calibrate, noise=p.mag_cal_noise, field_rw=p.mag_cal_field_rw,
                soft_iron=p.mag_cal_soft_iron, delay=p.mag_cal_delay,
                heading=p.mag_cal_heading, deadband=p.mag_cal_deadband,
                drift=p.mag_cal_drift, kernel=self._kernels.magcal,
                blocks=[(s, k.MC0) for s in self._states])
            # Slightly early, so that a field rate at mag_cal_rate learns from each.
            period = 0.999 / float(np.max(p.mag_cal_rate))
            for s in self._states:
                s[k.P_CAL_PERIOD] = period
        self.reset()

    def __getstate__(self):
        # The kernels hold modules: a copy or a pickle asks for them again.
        state = self.__dict__.copy()
        del state['_kernels']
        return state

    def __setstate__(self, state):
        self.__dict__.update(state)
        self._kernels = kernels(self.compiled)

    def use_kernels(self, kernels):
        """
        Go on with other kernels (plain or compiled) from the same state.

        The state is copied into the new kernels' container; the estimates
        go on as they would have (compiled and plain agree to the bit). A
        node that started on the plain kernels while the compiled ones were
        being compiled switches with this between two samples.

        Parameters
        ----------
        kernels : ext_observer.core.ahrs.compiled.Kernels

        """
        if kernels is self._kernels:
            return
        states = []
        for s in self._states:
            c = kernels.container(len(s))
            for i in range(len(s)):
                c[i] = float(s[i])
            states.append(c)
        self._states = states
        self._kernels = kernels
        self.compiled = kernels.compiled
        if self.calibration is not None:
            self.calibration.use_kernel(kernels.magcal,
                                        [(s, kernels.ahrs.MC0) for s in states])

    @property
    def kernels(self):
        """The kernels it runs (:class:`~ext_observer.core.ahrs.compiled.Kernels`)."""
        return self._kernels

    @property
    def flat_state(self):
        """
        The flat state of a single estimate (ahrs_kernel's layout), for a caller that steps it.

        :func:`~ext_observer.core.ahrs.uncertainty_kernel.sample_step` runs the
        estimator's step on it together with the covariance's. A new
        container after :meth:`use_kernels`: ask again rather than keep it.
        """
        if self.batch is not None:
            raise ValueError('flat_state is that of a single estimate, not of a batch')
        return self._states[0]

    # --- state -------------------------------------------------------------

    def reset(self):
        """Forget everything: the next accelerometer sample initializes."""
        for s in self._states:
            self._kernels.ahrs.ahrs_reset(s)

    def _slots(self, start, count):
        """Slots of the state(s): floats, or arrays (B,) with ``batch``."""
        if self.batch is None:
            s = self._states[0]
            return tuple(float(s[start + i]) for i in range(count))
        return tuple(np.array([float(s[start + i]) for s in self._states])
                     for i in range(count))

    def _flag(self, slot):
        if self.batch is None:
            return bool(self._states[0][slot] != 0.0)
        return np.array([s[slot] != 0.0 for s in self._states])

    @property
    def initialized(self):
        """Whether the first accelerometer sample has initialized the estimate (``q`` not None)."""
        k = self._kernels.ahrs
        if self.batch is None:
            return self._states[0][k.S_INIT] != 0.0
        return any(s[k.S_INIT] != 0.0 for s in self._states)

    @property
    def q(self):
        """The ambient estimate ``(w, x, y, z)``; None before the first sample."""
        k = self._kernels.ahrs
        if self.batch is None:  # the node's path, read every sample: no generator
            s = self._states[0]
            if s[k.S_INIT] == 0.0:
                return None
            i = k.S_Q
            return float(s[i]), float(s[i + 1]), float(s[i + 2]), float(s[i + 3])
        if not any(s[k.S_INIT] != 0.0 for s in self._states):
            return None
        return self._slots(k.S_Q, 4)

    @q.setter
    def q(self, value):
        k = self._kernels.ahrs
        for i, s in enumerate(self._states):
            if value is None:
                s[k.S_INIT] = 0.0
                continue
            for j in range(4):
                s[k.S_Q + j] = float(value[j] if self.batch is None else value[j][i])
            s[k.S_INIT] = 1.0

    def field(self, name):
        """
        A field of the flat state by its name in ahrs_kernel's layout (``AHRS``).

        A float (a vector: a tuple of floats); with ``batch``, arrays
        ``(B,)``. E.g. ``'bias'``, ``'lp'`` (the Butterworth states),
        ``'k_acc'``, ``'mag_used'``, ``'ref'``.
        """
        offset, size = self._kernels.ahrs.AHRS.fields[name]
        values = self._slots(offset, size)
        return values[0] if size == 1 else values

    def set_field(self, name, value):
        """Set a one-slot field of every estimate (a float, or an array ``(B,)``)."""
        offset, size = self._kernels.ahrs.AHRS.fields[name]
        if size != 1:
            raise ValueError(f'{name} has {size} slots; set_field sets one-slot fields')
        values = np.broadcast_to(np.asarray(value, dtype=float), (self._n,))
        for i, s in enumerate(self._states):
            s[offset] = float(values[i])

    @property
    def bias(self):
        """The gyro bias estimate (rad/s), body frame; settable (a saved or known bias)."""
        return self.field('bias')

    @bias.setter
    def bias(self, value):
        # VQF's setBiasEstimate: the estimate goes on from this bias (each
        # value a float, or with batch an array (B,)).
        offset, size = self._kernels.ahrs.AHRS.fields['bias']
        for i, s in enumerate(self._states):
            for j in range(size):
                s[offset + j] = float(value[j] if self.batch is None else value[j][i])

    @property
    def bias_std(self):
        """σ of the gyro bias estimate per body axis (rad/s): its Kalman filter's."""
        k = self._kernels.ahrs
        if self.batch is None:
            s = self._states[0]
            return tuple(math.sqrt(max(float(k.bias_variance(s, i, i)), 0.0)) for i in range(3))
        return tuple(np.array([math.sqrt(max(float(k.bias_variance(s, i, i)), 0.0))
                               for s in self._states]) for i in range(3))

    @property
    def bias_variance(self):
        """
        The mean variance of the bias estimate over the body axes, (rad/s)²; None when off.

        None where the bias is not learned in motion (``tau_bias`` 0): the
        covariance then keeps its own model of it.
        """
        if not self.params.tau_bias > 0.0 if self.batch is None else not np.all(
                np.asarray(self.params.tau_bias) > 0.0):
            return None
        x, y, z = self.bias_std
        return (x * x + y * y + z * z) / 3.0

    def _count(self, slot):
        if self.batch is None:
            return int(self._states[0][slot])
        return np.array([int(s[slot]) for s in self._states])

    @property
    def clipped(self):
        """Samples found at the gyro's range so far (``gyro_range``, or stuck at its peak)."""
        return self._count(self._kernels.ahrs.S_CLIPS)

    @property
    def clip_variance(self):
        """What the last sample, at the gyro's range, adds to the variances (rad²; 0: none)."""
        return self._slots(self._kernels.ahrs.S_CLIPPED, 1)[0]

    @property
    def holes(self):
        """Holes in the stream bridged so far (``hole_kernel``: intervals much longer than usual)."""
        return self._count(self._kernels.ahrs.S_HOLES)

    @property
    def hole_variance(self):
        """What the last sample's hole adds to the variances (rad² per axis; 0: none)."""
        return self._slots(self._kernels.ahrs.S_HOLE_VAR, 1)[0]

    @property
    def hole_restart(self):
        """After a hole: the seconds the inclination's restarted mean weighs the old as (−1: kept)."""
        return self._slots(self._kernels.ahrs.S_HOLE_T0, 1)[0]

    @property
    def step_interval(self):
        """The interval the last step's coefficients are for, s (a hole's keeps the usual one)."""
        return self._slots(self._kernels.ahrs.C_DT, 1)[0]

    @property
    def rest(self):
        """Whether rest is detected."""
        return self._flag(self._kernels.ahrs.S_REST)

    @property
    def mag_disturbed(self):
        """Whether the last magnetometer sample was rejected."""
        return self._flag(self._kernels.ahrs.S_MAG_DIST)

    @property
    def velocity_used(self):
        """Whether the last step removed the body's acceleration (a fresh velocity given)."""
        return self._flag(S_VEL_USED)

    @property
    def velocity_timeout(self):
        """s: an older velocity is not used (``VELOCITY_TIMEOUT`` unless set)."""
        return float(self._states[0][P_VEL_TIMEOUT])

    @velocity_timeout.setter
    def velocity_timeout(self, value):
        check_dt(value)
        for s in self._states:
            s[P_VEL_TIMEOUT] = float(value)

    def velocity(self, v, dt=None):
        """
        Take the body's velocity (m/s, IMU frame), ``dt`` s after the previous one.

        The steps that follow, until it is older than ``VELOCITY_TIMEOUT``,
        remove ``dv/dt + ω × v`` from the specific force (the velocity aid,
        :mod:`~ext_observer.core.ahrs.velocity_kernel`); ``dt`` None: the first.
        """
        self._each(self._kernels.ahrs.velocity_sample, v, -1.0 if dt is None else float(dt))

    @property
    def calibration_state(self):
        """``'off'``, ``'learning'``, ``'converged'`` or ``'loaded'`` (a list with ``batch``)."""
        if self.calibration is None:
            return 'off' if self.batch is None else ['off'] * self.batch
        return self.calibration.state

    def load_calibration(self, bias, soft_iron):
        """
        Start from a saved magnetometer calibration, refined online.

        Parameters
        ----------
        bias : sequence of 3 floats
            Hard-iron offset ``b`` in the field's unit.
        soft_iron : sequence of 9 floats or array_like, shape (3, 3)
            Soft-iron matrix ``S`` (row-major) of ``m_raw = S m + b``.

        Raises
        ------
        ValueError
            When the calibration is off (``mag_cal`` false, or 6D), or for a
            non-finite, asymmetric, singular or indefinite value.

        """
        if self.calibration is None:
            raise ValueError('the magnetometer calibration is off (mag_cal false or 6D); '
                             'subtract a fixed offset before the estimator instead')
        self.calibration.load(bias, soft_iron)
        # Loaded while running: the heading and the references are taken
        # from the calibrated field at the next field (before the first
        # field, the start does that).
        k = self._kernels.ahrs
        for s in self._states:
            s[k.S_CAL_LOADED] = s[k.S_HAS_REF]

    # --- the three steps ---------------------------------------------------

    def _interval(self, dt):
        if dt != self._dt:
            check_dt(dt)
            self._dt = float(dt)  # a numpy scalar would make every later quantity one
        return self._dt

    def update(self, gyr, acc, mag=None, dt=None):
        """
        One IMU sample: gyro, then accelerometer, then magnetometer.

        Parameters
        ----------
        gyr, acc, mag : sequence of 3 floats or of 3 arrays (B,)
            rad/s, m/s², field (``mag`` ignored where ``use_mag`` is false).
        dt : float
            Time since the previous sample (s).

        Returns
        -------
        tuple of 4
            The estimate ``q``.

        """
        dt = self._interval(dt)
        step = self._kernels.ahrs.ahrs_update
        if self.batch is None:
            s = self._states[0]
            if mag is None:
                return step(s, gyr[0], gyr[1], gyr[2], acc[0], acc[1], acc[2], False,
                            0.0, 0.0, 0.0, dt)
            return step(s, gyr[0], gyr[1], gyr[2], acc[0], acc[1], acc[2], True,
                        mag[0], mag[1], mag[2], dt)
        g = np.asarray(gyr, dtype=float).reshape(3, self._n)
        a = np.asarray(acc, dtype=float).reshape(3, self._n)
        m = None if mag is None else np.asarray(mag, dtype=float).reshape(3, self._n)
        out = np.empty((self._n, 4))
        for i, s in enumerate(self._states):
            if m is None:
                out[i] = step(s, g[0, i], g[1, i], g[2, i], a[0, i], a[1, i], a[2, i], False,
                              0.0, 0.0, 0.0, dt)
            else:
                out[i] = step(s, g[0, i], g[1, i], g[2, i], a[0, i], a[1, i], a[2, i], True,
                              m[0, i], m[1, i], m[2, i], dt)
        return tuple(out.T.copy())

    def run(self, gyr, acc, mag=None, dt=None, out=None):
        """
        A whole recording at one interval, from where the estimate is.

        One call of the kernel's loop (compiled: the whole recording in
        numba; plain: the same loop in Python), as :meth:`update` per sample.

        Parameters
        ----------
        gyr, acc : array_like, shape (N, 3)
        mag : array_like, shape (N, 3), optional
        dt : float
        out : ndarray, shape (N, 4), optional
            Where to write the estimates (C-contiguous float64), e.g. memory
            shared with the process that asked for them; default: a new array.

        Returns
        -------
        ndarray, shape (N, 4)
            The estimate after each sample (``out`` where given).

        """
        if self.batch is not None:
            raise ValueError('run is for one estimate (batch=None); use estimate_batch')
        dt = self._interval(dt)
        g = np.ascontiguousarray(gyr, dtype=float).reshape(-1, 3)
        a = np.ascontiguousarray(acc, dtype=float).reshape(-1, 3)
        if len(a) != len(g) or (mag is not None and len(mag) != len(g)):
            raise ValueError('gyr, acc and mag must have one row per sample')
        m = g if mag is None else np.ascontiguousarray(mag, dtype=float).reshape(-1, 3)
        count = len(g)
        if out is not None and not (isinstance(out, np.ndarray) and out.shape == (count, 4)
                                    and out.dtype == np.float64 and out.flags.c_contiguous
                                    and out.flags.writeable):
            raise ValueError(f'out must be a writable C-contiguous float64 array of shape '
                             f'({count}, 4)')
        run = self._kernels.ahrs.ahrs_run
        s = self._states[0]
        if self.compiled:
            if out is None:
                out = np.empty((count, 4))
            run(s, g, a, m, count, mag is not None, dt, out)
            return out
        rows = [[0.0] * 4 for _ in range(count)]
        run(s, g.tolist(), a.tolist(), m.tolist(), count, mag is not None, dt, rows)
        if out is None:
            return np.array(rows).reshape(count, 4)
        out[...] = np.array(rows).reshape(count, 4)
        return out

    def unbridged(self, gyr, dt):
        """
        A hole of ``dt`` s too long to bridge, closed by a sample of rate ``gyr`` (rad/s).

        The estimate holds; the doubt the hole leaves restarts the means
        (:func:`~ext_observer.core.ahrs.ahrs_kernel.ahrs_unbridged`). One
        estimate only. Returns the variance per axis (rad²) and the weight
        (s) the inclination's mean restarted with (−1.0: kept).
        """
        if self.batch is not None:
            raise ValueError('unbridged takes one estimate, not a batch')
        return self._kernels.ahrs.ahrs_unbridged(self._states[0], float(gyr[0]), float(gyr[1]),
                                                 float(gyr[2]), float(dt))

    def _each(self, func, vector, *extra):
        if self.batch is None:
            func(self._states[0], *vector, *extra)
            return
        v = np.asarray(vector, dtype=float).reshape(len(vector), self._n)
        for i, s in enumerate(self._states):
            func(s, *(float(c) for c in v[:, i]), *extra)

    def update_acc(self, acc):
        """Correct the inclination from the world-frame filtered specific force."""
        self._each(self._kernels.ahrs.ahrs_update_acc, acc)

    def update_mag(self, mag, dt=None):
        """
        Correct the heading from the magnetometer, rejecting disturbed fields.

        Parameters
        ----------
        mag : sequence of 3 floats or of 3 arrays (B,)
            The field, body frame, any unit.
        dt : float, optional
            Time since the previous field (s); default: the IMU's ``dt``
            (a field with every sample). The gains of a field that arrives
            at its own rate follow from its own interval.

        """
        if dt is None:
            # The last sample's interval, as the kernels hold it (a caller
            # may step them directly: RawImuEstimator's sample_step).
            dt = float(self._states[0][self._kernels.ahrs.C_DT])
            check_dt(dt)
        elif dt != self._mag_dt:
            check_dt(dt)
            self._mag_dt = dt
        self._each(self._kernels.ahrs.ahrs_update_mag, mag, float(dt))

