"""
Attitude from a raw IMU: gyro + accelerometer (+ magnetometer), ambient form.

The estimate ``q̂`` lives in R⁴ as in the paper's observer; nothing here
renormalizes it. Each sample runs three steps, each a short function:

``update_gyr``
    Propagation with the bias-corrected body-frame increment,
    ``p = q̂ ⊗ exp((ω − b̂) dt / 2)``, then the extension term of
    Corollary 1, ``p − α ∇V(p)`` with ``V(x) = (x̄x − 1)²``, which pulls the
    estimate back towards S³ (``|exp(·)| = 1``, so the gyro step preserves
    ``V`` and the theorem applies with the S³ certificate).
``update_acc``
    Inclination. The specific force is rotated into the world frame with the
    current estimate and low-pass filtered there (second-order Butterworth,
    time constant ``tau_acc``); the filter's states are rotated along with
    every correction, so they live in a frame that only the gyro moves and
    translational accelerations average out. The measurement is
    ``y = δ ⊗ q̂``, with ``δ`` the rotation that makes the filtered vector
    vertical, and the update is the paper's Luenberger form with a scalar
    gain, ``q̂ + κ_a (y − q̂)``.
``update_mag``
    Heading only. The field is rotated into the world frame and its
    horizontal direction gives the heading error ``ψ``; the measurement is
    ``y = R_z(ψ) ⊗ q̂`` (a rotation about the world vertical, so a disturbed
    magnetometer can never tilt the estimate), with gain ``κ_m`` from
    ``tau_mag``. A field whose norm or dip angle leaves its learned reference
    is rejected; a new field that stays consistent while the body moves is
    accepted after ``mag_new_time``.

The gyro bias is learned at rest (rest detected from the gyro and the
accelerometer) and, with ``tau_bias > 0`` (off by default), in motion from
the corrections: a constant bias makes the estimate drift, so the body-frame
correction averages ``−(b − b̂) dt``.

In 9D the magnetometer is calibrated online (``mag_cal``, on by default):
:class:`~ext_observer.core.magcal.MagCalibrator` learns the hard-iron
offset and the soft-iron matrix from the fields and the gyro's rotation
between them. Until its quality (the heading error its uncertainty would
cause) is below ``mag_cal_heading`` the heading does not follow the field:
it starts from the field as given (averaged until the body first moves, as
without calibration) and then follows the gyro alone (6D), while the
disturbance test watches the raw field. Once converged, a learned
calibration that turns the heading by more than ``mag_cal_deadband`` (RMS)
from the field as given, and by more than its uncertainty could, is
applied: the heading is set once from the calibrated field (as the
calibration tracks it, its noise averaged), the field references become the
calibrated field's, and 9D runs on calibrated fields, the heading following
them with a time constant of half the time since (at least 1 s) until that
reaches ``tau_mag``, as the calibration still improves. One that turns it
less (the sensor was calibrated already) is watched, and the field is used
as given. A field the norm/dip test rejects does not teach the
calibration. ``calibration_state`` says which phase runs;
:meth:`AhrsObserver.load_calibration` starts from a saved calibration.

Credit: several ideas here are VQF's (D. Laidig and T. Seel, "VQF: Highly
accurate IMU orientation estimation with bias estimation and magnetic
disturbance rejection", Information Fusion 90, 2023): the parameter set and
its first defaults (time constants in seconds, thresholds in physical
units), the accelerometer low-passed in a frame that only the gyro moves
(VQF's inertial frame), rest detection from the low-passed gyro and
accelerometer with the bias learned at rest, and the rejection of a field
whose norm or dip leaves its learned reference, with a candidate field that
is accepted after it has lasted while the body turns. The equations and the
code are ours (the extension term and the Luenberger form are the paper's).

Conventions: quaternions scalar first ``(w, x, y, z)``, sensor → world; the
world frame is ENU (x east, y north, z up, REP-103); at rest the
accelerometer reads about ``+9.81`` along the world vertical. Angular rate in
rad/s, acceleration in m/s², the magnetic field in any unit (only its
direction and its norm relative to the reference are used), time in s.

One code path serves one estimate and a batch: every quantity is a Python
float or a numpy array of shape ``(B,)``; :class:`AhrsObserver` picks the
operations (``math`` or ``numpy``, :mod:`~ext_observer.core.ahrs_math`) once.
The ROS node runs it on floats; :func:`estimate_batch`
(:mod:`~ext_observer.core.ahrs_batch`) runs many recordings at once. The
parameters: :class:`AhrsParams` (:mod:`~ext_observer.core.ahrs_params`).
"""

import math

import numpy as np

from .ahrs_math import (_ArrayOps, _butterworth, _check_dt, _FloatOps, _gain, _rotate,
                        initial_attitude, WORLD_FRAMES, world_from_enu)
from .ahrs_params import AhrsParams
from .magcal import MagCalibrator

__all__ = [
    'AhrsObserver',
    'AhrsParams',
    'MODES',
    'WORLD_FRAMES',
    'estimate_batch',
    'initial_attitude',
    'world_from_enu',
]

MODES = ('6D', '9D')
_TINY = 1e-300
# After a calibration is applied, the heading's time constant is this share
# of the time since, and at least this (s), until it reaches tau_mag.
_REFINE_SHARE = 0.5
_REFINE_SHORTEST = 1.0


class AhrsObserver:
    """
    The raw-IMU estimator on floats (one estimate) or on ``(B,)`` arrays.

    Parameters
    ----------
    params : AhrsParams, optional
    use_mag : bool or ndarray of bool, shape (B,)
        9D (heading from the magnetometer) where true, 6D elsewhere.
    batch : int, optional
        ``None`` for one estimate on floats; ``B`` for arrays of shape (B,).
    variant : {'extended', 'plain'}
        ``plain`` drops the extension term (for comparison only).

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

    """

    def __init__(self, params=None, use_mag=True, batch=None, variant='extended'):
        if variant not in ('extended', 'plain'):
            raise ValueError(f"variant must be 'extended' or 'plain', got {variant!r}")
        self.params = params if params is not None else AhrsParams()
        self.batch = batch
        self.variant = variant
        if batch is None:
            self._o = _FloatOps
            self._proto = 0.0
            self.use_mag = bool(use_mag)
        else:
            self._o = _ArrayOps
            self._proto = np.zeros(int(batch))
            self.use_mag = np.broadcast_to(np.asarray(use_mag, dtype=bool),
                                           (int(batch),)).copy()
        self._any_mag = bool(np.any(self.use_mag))
        self._motion_bias = bool(np.any(np.asarray(self.params.tau_bias) > 0.0))
        self._dt = None
        self._mag_dt = None
        self.calibration = None
        p = self.params
        calibrate = np.asarray(p.mag_cal, dtype=bool) & self.use_mag
        if np.any(calibrate):
            self.calibration = MagCalibrator(
                batch, enabled=calibrate, noise=p.mag_cal_noise, field_rw=p.mag_cal_field_rw,
                soft_iron=p.mag_cal_soft_iron, delay=p.mag_cal_delay,
                heading=p.mag_cal_heading, deadband=p.mag_cal_deadband,
                drift=p.mag_cal_drift)
            # Slightly early, so that a field rate at mag_cal_rate learns from each.
            self._cal_period = 0.999 / float(np.max(p.mag_cal_rate))
        self.reset()

    # --- state -------------------------------------------------------------

    def reset(self):
        """Forget everything: the next accelerometer sample initializes."""
        z = self._o.zeros(self._proto)
        self.q = None
        self.bias = (z, z, z)
        self.rest = False if self.batch is None else np.zeros(self.batch, dtype=bool)
        self.rest_time = z
        self._rest_gyr = None
        self._rest_acc = None
        self._lp = None  # six Butterworth states: s1 (3) and s2 (3)
        self.mag_disturbed = self.rest
        self._mag_ref = None  # (norm, dip)
        self._mag_cand = None  # (norm, dip) of a new field
        self._mag_cand_time = z
        self._mag_used = z  # samples used since start (initial averaging)
        if self.calibration is not None:
            # The learned calibration stays; the field is followed afresh.
            self.calibration.restart()
            one = self._o.full(self._proto, 1.0)
            self._cal_turn = (one, z, z, z)  # body rotation since the previous field
            self._cal_rate = (z, z, z)  # the latest angular rate, bias removed
            self._cal_wait = math.inf  # time since the calibration last learned
            self._cal_moved = self.rest  # False: the body has not turned yet
            # Time since a calibration was applied (s).
            self._cal_since = self._o.full(self._proto, math.inf)
            self._cal_loaded = False

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
        self._cal_loaded = self._mag_ref is not None

    def _coefficients(self, dt):
        # Every sample when the stamps jitter: math on the float path.
        _check_dt(dt)
        p = self.params
        o = self._o
        dt = float(dt)  # a numpy scalar would make every later quantity one
        self._dt = dt
        self._bw = _butterworth(p.tau_acc, dt, o)
        self._k_acc = _gain(p.tau_acc_gain, dt, o)
        self._k_rest = _gain(p.tau_rest, dt, o)

    # --- the three steps ---------------------------------------------------

    def update(self, gyr, acc, mag=None, dt=None):
        """
        One IMU sample: gyro, then accelerometer, then magnetometer.

        Parameters
        ----------
        gyr, acc, mag : sequence of 3 floats or of 3 arrays (B,)
            rad/s, m/s², field (``mag`` ignored where ``use_mag`` is false).
        dt : float
            Time since the previous sample (s).

        """
        if dt != self._dt:
            self._coefficients(dt)
        if self.q is None:
            if mag is not None and self.calibration is not None:
                # Identity until the calibration is converged or loaded.
                mag = self.calibration.apply(mag)
            self.q = initial_attitude(acc, mag if self._any_mag else None,
                                      self._o, self.use_mag)
            self._init_filters(acc, gyr)
        else:
            self.update_gyr(gyr)
        self.update_acc(acc)
        if mag is not None and self._any_mag:
            self.update_mag(mag)
        return self.q

    def _init_filters(self, acc, gyr):
        ax, ay, az = _rotate(*self.q, *acc)
        b0, b1, b2, a1, a2 = self._bw
        # Steady state of the transposed direct form II for a constant input.
        s2 = tuple((b2 - a2) * v for v in (ax, ay, az))
        s1 = tuple((b1 - a1) * v + s for v, s in zip((ax, ay, az), s2))
        self._lp = s1 + s2
        self._rest_gyr = tuple(gyr)
        self._rest_acc = tuple(acc)

    def update_gyr(self, gyr):
        """Propagate with ``exp((ω − b̂) dt / 2)`` and apply the extension term."""
        o = self._o
        dt = self._dt
        bx, by, bz = self.bias
        ux = (gyr[0] - bx) * dt
        uy = (gyr[1] - by) * dt
        uz = (gyr[2] - bz) * dt
        # exp of the half increment: (cos(θ/2), sin(θ/2)/θ · u), θ = |u|; the
        # tiny term only keeps θ = 0 (then u = 0) from dividing by zero.
        t = o.sqrt(ux * ux + uy * uy + uz * uz)
        c = o.cos(0.5 * t)
        s = o.sin(0.5 * t) / (t + _TINY)
        ex, ey, ez = ux * s, uy * s, uz * s
        w, x, y, z = self.q
        pw = w * c - x * ex - y * ey - z * ez
        px = w * ex + x * c + y * ez - z * ey
        py = w * ey - x * ez + y * c + z * ex
        pz = w * ez + x * ey - y * ex + z * c
        if self.calibration is not None:
            tw, tx, ty, tz = self._cal_turn
            self._cal_turn = (tw * c - tx * ex - ty * ey - tz * ez,
                              tw * ex + tx * c + ty * ez - tz * ey,
                              tw * ey - tx * ez + ty * c + tz * ex,
                              tw * ez + tx * ey - ty * ex + tz * c)
            self._cal_rate = (gyr[0] - bx, gyr[1] - by, gyr[2] - bz)
            lx, ly, lz = self._rest_gyr
            lx, ly, lz = lx - bx, ly - by, lz - bz
            self._cal_moved = self._cal_moved | (lx * lx + ly * ly + lz * lz
                                                 >= self.params.rest_gyr ** 2)
        if self.variant == 'extended':
            # p − α ∇V(p), ∇V(p) = 4 p (p̄p − 1).
            f = 1.0 - 4.0 * self.params.alpha * (pw * pw + px * px + py * py + pz * pz - 1.0)
            pw, px, py, pz = pw * f, px * f, py * f, pz * f
        self.q = (pw, px, py, pz)
        self._detect_rest(gyr)

    def _detect_rest(self, gyr):
        p = self.params
        k = self._k_rest
        gx, gy, gz = self._rest_gyr
        gx, gy, gz = gx + k * (gyr[0] - gx), gy + k * (gyr[1] - gy), gz + k * (gyr[2] - gz)
        self._rest_gyr = (gx, gy, gz)
        bx, by, bz = self.bias
        ex, ey, ez = gyr[0] - gx, gyr[1] - gy, gyr[2] - gz
        dev = ex * ex + ey * ey + ez * ez
        mx, my, mz = gx - bx, gy - by, gz - bz
        mean = mx * mx + my * my + mz * mz
        th = p.rest_gyr * p.rest_gyr
        still = (dev < th) & (mean < th) & self._acc_still
        self.rest_time = (self.rest_time + self._dt) * still
        self.rest = self.rest_time >= p.rest_time
        # At rest the bias is the low-passed rate, within bias_max per axis
        # as in motion.
        kr = k * self.rest
        m = p.bias_max
        clip = self._o.clip
        self.bias = (clip(bx + kr * mx, -m, m), clip(by + kr * my, -m, m),
                     clip(bz + kr * mz, -m, m))

    _acc_still = True

    def update_acc(self, acc):
        """Correct the inclination from the world-frame filtered specific force."""
        o = self._o
        p = self.params
        ax, ay, az = acc
        # Rest detection needs the accelerometer's deviation from its mean.
        k = self._k_rest
        rx, ry, rz = self._rest_acc
        rx, ry, rz = rx + k * (ax - rx), ry + k * (ay - ry), rz + k * (az - rz)
        self._rest_acc = (rx, ry, rz)
        ex, ey, ez = ax - rx, ay - ry, az - rz
        self._acc_still = (ex * ex + ey * ey + ez * ez) < p.rest_acc * p.rest_acc

        w, x, y, z = self.q
        vx, vy, vz = _rotate(w, x, y, z, ax, ay, az)
        b0, b1, b2, a1, a2 = self._bw
        s1x, s1y, s1z, s2x, s2y, s2z = self._lp
        fx, fy, fz = b0 * vx + s1x, b0 * vy + s1y, b0 * vz + s1z
        s1x, s1y, s1z = (b1 * vx - a1 * fx + s2x, b1 * vy - a1 * fy + s2y,
                         b1 * vz - a1 * fz + s2z)
        s2x, s2y, s2z = b2 * vx - a2 * fx, b2 * vy - a2 * fy, b2 * vz - a2 * fz

        # δ: the rotation taking f/|f| to the vertical, [1 + u_z, u_y, −u_x, 0].
        # (A filtered vector pointing straight down, |δ| = 0, only shrinks the
        # estimate; the extension term restores it.)
        n = o.sqrt(fx * fx + fy * fy + fz * fz) + _TINY
        dw, dx, dy = 1.0 + fz / n, fy / n, -fx / n
        dn = o.sqrt(dw * dw + dx * dx + dy * dy) + _TINY
        dw, dx, dy = dw / dn, dx / dn, dy / dn
        # q̂ + κ (δ ⊗ q̂ − q̂) = r ⊗ q̂ with r = (1 − κ) + κ δ.
        kap = self._k_acc
        rw, rx, ry = 1.0 - kap + kap * dw, kap * dx, kap * dy
        self.q = (rw * w - rx * x - ry * y,
                  rw * x + rx * w + ry * z,
                  rw * y + ry * w - rx * z,
                  rw * z + rx * y - ry * x)
        # The filter's states follow the applied rotation (r need not be unit).
        self._lp = (_rotate(rw, rx, ry, 0.0, s1x, s1y, s1z)
                    + _rotate(rw, rx, ry, 0.0, s2x, s2y, s2z))
        if self._motion_bias:
            self._learn_bias(rw, rx, ry, 0.0)

    def _learn_bias(self, rw, rx, ry, rz):
        """In motion: the correction ``r`` (world) averages ``−(b − b̂) dt`` (body)."""
        o = self._o
        tb = self.params.tau_bias
        # Small-angle rotation vector of r, in the body frame.
        cx, cy, cz = 2.0 * rx / rw, 2.0 * ry / rw, 2.0 * rz / rw
        w, x, y, z = self.q
        cx, cy, cz = _rotate(w, -x, -y, -z, cx, cy, cz)
        k = o.where(self.rest | (tb <= 0.0), 0.0, 1.0 / o.where(tb > 0.0, tb, 1.0))
        m = self.params.bias_max
        bx, by, bz = self.bias
        self.bias = (o.clip(bx - k * cx, -m, m), o.clip(by - k * cy, -m, m),
                     o.clip(bz - k * cz, -m, m))

    def _mag_coefficients(self, dt):
        _check_dt(dt)
        p = self.params
        dt = float(dt)
        self._mag_dt = dt
        self._k_mag = _gain(p.tau_mag, dt, self._o)
        self._k_ref = _gain(p.tau_mag_ref, dt, self._o)

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
        dt = self._dt if dt is None else dt
        if dt != self._mag_dt:
            self._mag_coefficients(dt)
        if self.calibration is not None:
            mag = self._calibrate(mag, dt)
        o = self._o
        p = self.params
        w, x, y, z = self.q
        mx, my, mz = _rotate(w, x, y, z, *mag)
        h = o.sqrt(mx * mx + my * my)
        norm = o.sqrt(h * h + mz * mz)
        valid = (h > 0.0) & (norm > 0.0)
        dip = o.atan2(mz, h)
        psi = o.atan2(mx, my)

        if self._mag_ref is None:
            self._mag_ref = (norm, dip)
            self._mag_cand = (norm, dip)
        ref_n, ref_d = self._mag_ref
        th_n, th_d = p.mag_norm_th, p.mag_dip_th
        disturbed = (abs(norm - ref_n) > th_n * ref_n) | (abs(dip - ref_d) > th_d)
        # A new field: consistent with the candidate while the body turns.
        cand_n, cand_d = self._mag_cand
        consistent = (abs(norm - cand_n) < th_n * cand_n) & (abs(dip - cand_d) < th_d)
        gx, gy, gz = self._rest_gyr
        turning = gx * gx + gy * gy + gz * gz > p.mag_new_gyr ** 2
        self._mag_cand_time = (self._mag_cand_time + dt) * (disturbed & consistent & turning)
        kr = self._k_ref
        self._mag_cand = (o.where(consistent, cand_n + kr * (norm - cand_n), norm),
                          o.where(consistent, cand_d + kr * (dip - cand_d), dip))
        accept_new = disturbed & (self._mag_cand_time >= p.mag_new_time)
        ref_n = o.where(accept_new, self._mag_cand[0], ref_n)
        ref_d = o.where(accept_new, self._mag_cand[1], ref_d)
        disturbed = disturbed & o.logical_not(accept_new)
        use = valid & o.logical_not(disturbed) & self.use_mag
        self._mag_ref = (o.where(use, ref_n + kr * (norm - ref_n), ref_n),
                         o.where(use, ref_d + kr * (dip - ref_d), ref_d))
        self.mag_disturbed = disturbed
        if self.calibration is not None:
            # The heading waits for the calibration; before the body has
            # first moved it is the field's as given, averaged (the start).
            use = use & (self.calibration.ready | o.logical_not(self._cal_moved))

        # Heading measurement y = R_z(ψ) ⊗ q̂; gain κ_m, a running average at first.
        used = self._mag_used + use
        self._mag_used = used
        if self.calibration is None:
            kap = o.maximum(self._k_mag, 1.0 / o.maximum(used, 1.0)) * use
        else:
            # A calibration applied t ago improves still: the heading follows
            # it with the time constant t/2 (at least 1 s) until that reaches
            # tau_mag; the fields of older calibrations weigh less.
            since = self._cal_since + dt
            self._cal_since = since
            follow = 1.0 - o.exp(-dt / o.maximum(_REFINE_SHORTEST, _REFINE_SHARE * since))
            kap = o.maximum(o.maximum(self._k_mag, 1.0 / o.maximum(used, 1.0)), follow) * use
        half = 0.5 * psi
        rw, rz = 1.0 - kap + kap * o.cos(half), kap * o.sin(half)
        self._turn_heading(rw, rz)
        if self._motion_bias:
            # Only corrections of the steady phase teach the bias.
            self._learn_bias(rw, 0.0, 0.0, rz * (used * self._k_mag > 1.0))

    def _turn_heading(self, rw, rz):
        """``q̂ ← r ⊗ q̂`` for ``r = (rw, 0, 0, rz)`` (not unit), the filter's states with it."""
        w, x, y, z = self.q
        self.q = (rw * w - rz * z, rw * x - rz * y, rw * y + rz * x, rw * z + rz * w)
        # The filter's states turn with it about the vertical: (c, s) of 2θ.
        n2 = rw * rw + rz * rz
        c, s = (rw * rw - rz * rz) / n2, 2.0 * rw * rz / n2
        s1x, s1y, s1z, s2x, s2y, s2z = self._lp
        self._lp = (c * s1x - s * s1y, s * s1x + c * s1y, s1z,
                    c * s2x - s * s2y, s * s2x + c * s2y, s2z)

    def _norm_dip(self, mag):
        """Norm and dip angle of a body-frame field in the world frame."""
        o = self._o
        mx, my, mz = _rotate(*self.q, *mag)
        h = o.sqrt(mx * mx + my * my)
        return o.sqrt(h * h + mz * mz), o.atan2(mz, h)

    def _calibrate(self, mag, dt):
        """Teach the calibration this field; return the field the heading logic uses."""
        o = self._o
        cal = self.calibration
        rate = self._cal_rate
        self._cal_wait += dt
        if self._cal_wait < self._cal_period:
            return cal.apply(mag)  # learn at most at mag_cal_rate
        ready, applied = cal.ready, cal.applied
        allow = True
        if self._mag_ref is not None and np.any(ready):
            # A field the norm/dip test rejects does not teach.
            norm, dip = self._norm_dip(cal.apply(mag))
            ref_n, ref_d = self._mag_ref
            p = self.params
            disturbed = ((abs(norm - ref_n) > p.mag_norm_th * ref_n)
                         | (abs(dip - ref_d) > p.mag_dip_th))
            allow = o.logical_not(ready & disturbed)
        w, x, y, z = self.q
        n2 = w * w + x * x + y * y + z * z
        up = (2.0 * (x * z - w * y) / n2, 2.0 * (y * z + w * x) / n2,
              (w * w - x * x - y * y + z * z) / n2)
        cal.learn(mag, self._cal_turn, self._cal_wait, rate, up, allow)
        one, zero = o.full(self._proto, 1.0), o.zeros(self._proto)
        self._cal_turn = (one, zero, zero, zero)
        self._cal_wait = 0.0
        now_applied = cal.applied
        # A learned calibration applied: the heading is set once from the
        # calibrated field as the calibration tracks it (its noise averaged
        # over many fields); then it follows the calibrated fields.
        switched = now_applied & (o.logical_not(applied) | self._cal_loaded)
        self._cal_loaded = False
        align = switched
        if np.any(align) and self._mag_ref is not None:
            field = cal.field
            mx, my, mz = _rotate(*self.q, *(tuple(field.tolist()) if self.batch is None
                                            else tuple(field.T)))
            half = 0.5 * o.atan2(mx, my) * align
            self._turn_heading(o.cos(half), o.sin(half))
            # No initial averaging: the refinement's gain follows.
            self._mag_used = o.where(align, math.inf, self._mag_used)
            self._cal_since = o.where(align, 0.0, self._cal_since)
            if np.any(switched):
                # The references become the calibrated field's norm and dip.
                h = o.sqrt(mx * mx + my * my)
                norm, dip = o.sqrt(h * h + mz * mz), o.atan2(mz, h)
                ref_n, ref_d = self._mag_ref
                self._mag_ref = (o.where(switched, norm, ref_n), o.where(switched, dip, ref_d))
                cand_n, cand_d = self._mag_cand
                self._mag_cand = (o.where(switched, norm, cand_n),
                                  o.where(switched, dip, cand_d))
                self._mag_cand_time = o.where(switched, 0.0, self._mag_cand_time)
        return cal.apply(mag)



# The batch runs AhrsObserver, so it is imported once that is defined.
from .ahrs_batch import estimate_batch  # noqa: E402
