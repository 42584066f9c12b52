"""
Attitude from a raw IMU, gyro + accelerometer (+ magnetometer): :class:`AhrsObserver`.

The estimate ``q̂`` lives in R⁴ as in the paper's observer, held near S³ by
the extension term and never renormalized. Each sample runs three steps,
gyro, accelerometer (inclination) and magnetometer (heading only), written
once on a state with names in :mod:`~ext_observer.core.ahrs.ahrs_kernel` (plain or
compiled: the same estimates); this class wraps them for one estimate or a
batch of ``(B,)`` arrays. The steps, the credit to VQF and the conventions
(``(w, x, y, z)``, sensor → ENU, SI units) are docs/raw_imu.md's
("The estimator, step by step"); the calibration's phases docs/calibration.md's.
"""

import math
import operator

import numpy as np

from .frames import check_dt, initial_attitude, WORLD_FRAMES, world_from_enu
from .ahrs_params import AhrsParams
from .compiled import entry_point, kernels
from .magcal import MagCalibrator
from .ahrs_state import KERNEL_PARAMETERS, STATE
from .record import holder_of
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


# A reader per field name, for one estimate's view (AhrsObserver.field):
# the node reads several fields at every sample.
_READERS = {}


def _reader(name):
    """``view -> value`` of one state field: a float, a vector a tuple of floats."""
    path, size = STATE.path(name)
    get = operator.attrgetter('.'.join(path))
    if size == 1:
        return lambda view: float(get(view))
    return lambda view: tuple(float(v) for v in get(view))


class AhrsObserver:
    """
    The raw-IMU estimator on floats (one estimate) or on ``(B,)`` arrays.

    The steps are the functions of :mod:`~ext_observer.core.ahrs.ahrs_kernel` on
    one state per estimate (:data:`~ext_observer.core.ahrs.ahrs_state.STATE`):
    compiled by numba when it is installed (:mod:`~ext_observer.core.ahrs.compiled`),
    plain Python otherwise, one source and the same results to the bit. With
    ``batch``, the estimates step one after the other.

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
    held : bool or ndarray
        Whether the last step held the inclination on the gyro (the specific
        force rejected: ``accel_rejection``).
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
        p = self.params
        values = p.as_dict()

        def each(name, i):
            value = values[name]
            return float(value[i]) if np.ndim(value) else float(value)

        calibrate = [bool(np.asarray(p.mag_cal)[i] if np.ndim(p.mag_cal) else p.mag_cal)
                     and uses[i] for i in range(n)]
        # One holder per estimate (record.py): its record is what the kernels step.
        self._states = []
        for i in range(n):
            h = STATE.holder(self.compiled)
            s = h[0]
            for name in KERNEL_PARAMETERS:
                STATE.set(s, f'par.{name}', each(name, i))
            STATE.set(s, 'par.use_mag', 1.0 if uses[i] else 0.0)
            STATE.set(s, 'par.extended', 1.0 if variant == 'extended' else 0.0)
            STATE.set(s, 'par.has_cal', 1.0 if calibrate[i] else 0.0)
            STATE.set(s, 'par.motion_bias', 1.0 if each('tau_bias', i) > 0.0 else 0.0)
            STATE.set(s, 'coef.dt', math.nan)
            STATE.set(s, 'coef.mag_dt', math.nan)
            STATE.set(s, 'rest.acc_still', 1.0)
            STATE.set(s, 'par.velocity_timeout', VELOCITY_TIMEOUT)
            self._states.append(h)
        self._dt = None
        self._mag_dt = None
        self.calibration = None
        if any(calibrate):
            self.calibration = MagCalibrator(
                batch, enabled=calibrate, noise=p.mag_cal_noise, field_rw=p.mag_cal_field_rw,
                soft_iron=p.mag_cal_soft_iron, delay=p.mag_cal_delay,
                heading=p.mag_cal_heading, deadband=p.mag_cal_deadband,
                drift=p.mag_cal_drift, kernel=self._kernels.magcal,
                blocks=[holder_of(h, 'cal') for h in self._states])
            # Slightly early, so that a field rate at mag_cal_rate learns from each.
            period = 0.999 / float(np.max(p.mag_cal_rate))
            for h in self._states:
                STATE.set(h[0], 'par.cal_period', period)
        self.reset()

    def __getstate__(self):
        # The kernels hold modules: a copy or a pickle asks for them again.
        state = self.__dict__.copy()
        del state['_kernels']
        state.pop('_record_view', None)
        state.pop('_update_entry', None)
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
        for h in self._states:
            c = STATE.holder(kernels.compiled)
            STATE.copy(h[0], c[0])
            states.append(c)
        self._states = states
        self._kernels = kernels
        self.compiled = kernels.compiled
        if self.calibration is not None:
            self.calibration.use_kernel(
                kernels.magcal, [holder_of(h, 'cal') for h in states])

    @property
    def kernels(self):
        """The kernels it runs (:class:`~ext_observer.core.ahrs.compiled.Kernels`)."""
        return self._kernels

    @property
    def state(self):
        """
        The holder of a single estimate's state (``STATE``), for a caller that steps it.

        :func:`~ext_observer.core.ahrs.uncertainty_kernel.sample_step` runs the
        estimator's step on it together with the covariance's. A new
        holder after :meth:`use_kernels`: ask again rather than keep it.
        """
        if self.batch is not None:
            raise ValueError('state is that of a single estimate, not of a batch')
        return self._states[0]

    # --- state -------------------------------------------------------------

    def reset(self):
        """Forget everything: the next accelerometer sample initializes."""
        for h in self._states:
            self._kernels.ahrs.ahrs_reset_in(h)

    def field(self, name):
        """
        A field of the state by its path (``'rest.time'``) or its name where unique (``'k_acc'``).

        A float (a vector: a tuple of floats); with ``batch``, arrays
        ``(B,)``. E.g. ``'bias.rate'``, ``'inc.lp'`` (the Butterworth
        states), ``'k_acc'``, ``'mag_used'``, ``'ref'``; every field:
        :mod:`~ext_observer.core.ahrs.ahrs_state` (docs/layout.md).
        """
        if self.batch is None:
            read = _READERS.get(name)
            if read is None:
                read = _READERS[name] = _reader(name)
            return read(self._view(self._states[0]))
        values = [STATE.get(h[0], name) for h in self._states]
        if isinstance(values[0], tuple):
            return tuple(np.array(v) for v in zip(*values))
        return np.array(values)

    def set_field(self, name, value):
        """Set a field of every estimate (a float, or an array ``(B,)``; a vector: a sequence)."""
        path, size = STATE.path(name)
        if size != 1:
            if np.ndim(value) == 0 or len(value) != size:
                raise ValueError(f'{name} has {size} values, got {value!r}')
            for i, h in enumerate(self._states):
                STATE.set(h[0], name, [float(value[j] if self.batch is None else value[j][i])
                                       for j in range(size)])
            return
        values = np.broadcast_to(np.asarray(value, dtype=float), (self._n,))
        for i, h in enumerate(self._states):
            STATE.set(h[0], name, float(values[i]))

    def _view(self, holder):
        """The holder's record by attribute (``STATE.view``), kept while the holder is."""
        cached = self.__dict__.get('_record_view')
        if cached is None or cached[0] is not holder:
            cached = self._record_view = (holder, STATE.view(holder))
        return cached[1]

    def _flag(self, name):
        if self.batch is None:
            return bool(self.field(name) != 0.0)
        return np.array([STATE.get(h[0], name) != 0.0 for h in self._states])

    @property
    def initialized(self):
        """Whether the first accelerometer sample has initialized the estimate (``q`` not None)."""
        if self.batch is None:
            return self.field('est.init') != 0.0
        return any(STATE.get(h[0], 'est.init') != 0.0 for h in self._states)

    @property
    def q(self):
        """The ambient estimate ``(w, x, y, z)``; None before the first sample."""
        if self.batch is None:  # the node's path: read at every field
            est = self._view(self._states[0]).est
            if est.init == 0.0:
                return None
            q = est.q
            return float(q[0]), float(q[1]), float(q[2]), float(q[3])
        if not self.initialized:
            return None
        return self.field('est.q')

    @q.setter
    def q(self, value):
        for i, h in enumerate(self._states):
            if value is None:
                STATE.set(h[0], 'est.init', 0.0)
                continue
            STATE.set(h[0], 'est.q', [float(value[j] if self.batch is None else value[j][i])
                                      for j in range(4)])
            STATE.set(h[0], 'est.init', 1.0)

    @property
    def bias(self):
        """The gyro bias estimate (rad/s), body frame; settable (a saved or known bias)."""
        return self.field('bias.rate')

    @bias.setter
    def bias(self, value):
        # VQF's setBiasEstimate: the estimate goes on from this bias (each
        # value a float, or with batch an array (B,)).
        self.set_field('bias.rate', value)

    @property
    def bias_std(self):
        """σ of the gyro bias estimate per body axis (rad/s): its Kalman filter's."""
        variance = self._kernels.ahrs.bias_variance_in
        if self.batch is None:
            h = self._states[0]
            return tuple(math.sqrt(max(float(variance(h, i, i)), 0.0)) for i in range(3))
        return tuple(np.array([math.sqrt(max(float(variance(h, i, i)), 0.0))
                               for h in self._states]) for i in range(3))

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

    def _count(self, name):
        if self.batch is None:
            return int(self.field(name))
        return np.array([int(STATE.get(h[0], name)) for h in self._states])

    # The state's fields that tell what the last steps did, read-only.
    clipped = property(lambda self: self._count('gyro.clips'), doc=(
        "Samples found at the gyro's range so far (``gyro_range``, or stuck at its peak)."))
    clip_variance = property(lambda self: self.field('gyro.clipped'), doc=(
        "What the last sample, at the gyro's range, adds to the variances (rad²; 0: none)."))
    holes = property(lambda self: self._count('hole.count'), doc=(
        "Holes in the stream bridged so far (``hole_kernel``: intervals much over the usual)."))
    hole_variance = property(lambda self: self.field('hole.var'), doc=(
        "What the last sample's hole adds to the variances (rad² per axis; 0: none)."))
    hole_restart = property(lambda self: self.field('hole.t0'), doc=(
        "After a hole: the seconds the inclination's restarted mean weighs the old as "
        "(−1: the mean kept)."))
    step_interval = property(lambda self: self.field('coef.dt'), doc=(
        "The interval the last step's coefficients are for, s (a hole's keeps the usual one)."))
    rest = property(lambda self: self._flag('rest.detected'), doc="Whether rest is detected.")
    held = property(lambda self: self._flag('rej.time'), doc=(
        "Whether the last step held the inclination on the gyro (the specific force "
        "rejected)."))
    mag_disturbed = property(lambda self: self._flag('field.mag_dist'), doc=(
        "Whether the last magnetometer sample was rejected."))
    velocity_used = property(lambda self: self._flag('vel.used'), doc=(
        "Whether the last step removed the body's acceleration (a fresh velocity given)."))

    @property
    def velocity_timeout(self):
        """s: an older velocity is not used (``VELOCITY_TIMEOUT`` unless set)."""
        return STATE.get(self._states[0][0], 'par.velocity_timeout')

    @velocity_timeout.setter
    def velocity_timeout(self, value):
        check_dt(value)
        self.set_field('par.velocity_timeout', float(value))

    def velocity(self, v, dt=None):
        """
        Take the body's velocity (m/s, IMU frame), ``dt`` s after the previous one.

        The steps that follow, until it is older than ``VELOCITY_TIMEOUT``,
        remove ``dv/dt + ω × v`` from the specific force (the velocity aid,
        :mod:`~ext_observer.core.ahrs.velocity_kernel`); ``dt`` None: the first.
        """
        self._each(self._kernels.ahrs.velocity_sample_in, v, -1.0 if dt is None else float(dt))

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
        for h in self._states:
            STATE.set(h[0], 'cal_feed.loaded', STATE.get(h[0], 'field.has_ref'))

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
        step = self._update_step()
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

    def _update_step(self):
        """
        The kernels' ``ahrs_update_in``; compiled, once compiled, its machine code called directly.

        Past numba's look at every argument's type (a third of a call's
        cost for the state's nested record), as the node's ``sample_step``
        (:func:`~ext_observer.core.ahrs.compiled.entry_point`).
        """
        cached = self.__dict__.get('_update_entry')
        if cached is not None and cached[0] is self._kernels:
            return cached[1]
        step = self._kernels.ahrs.ahrs_update_in
        if self.compiled and len(getattr(step, 'signatures', ())) == 1:
            self._update_entry = (self._kernels, entry_point(step))
        return step

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
        run = self._kernels.ahrs.ahrs_run_in
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
        return self._kernels.ahrs.ahrs_unbridged_in(self._states[0], float(gyr[0]), float(gyr[1]),
                                                 float(gyr[2]), float(dt))

    def field_back(self, var):
        """
        A field back after a loss, the heading having gained ``var`` rad² on the gyro alone.

        :func:`~ext_observer.core.ahrs.field_kernel.field_back`: the next
        fields correct the heading with the gain of that doubt, judged
        against the references and the calibration learned before. One
        estimate only.
        """
        if self.batch is not None:
            raise ValueError('field_back takes one estimate, not a batch')
        self._kernels.ahrs.field_back_in(self._states[0], float(var))

    def _each(self, func, vector, *extra):
        if self.batch is None:
            func(self._states[0], *vector, *extra)
            return
        v = np.asarray(vector, dtype=float).reshape(len(vector), self._n)
        for i, h in enumerate(self._states):
            func(h, *(float(c) for c in v[:, i]), *extra)

    def update_acc(self, acc):
        """Correct the inclination from the world-frame filtered specific force."""
        self._each(self._kernels.ahrs.ahrs_update_acc_in, acc)

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
            dt = self.field('coef.dt')
            check_dt(dt)
        elif dt != self._mag_dt:
            check_dt(dt)
            self._mag_dt = dt
        self._each(self._kernels.ahrs.ahrs_update_mag_in, mag, float(dt))

