"""
A simulated road vehicle's IMU, with the truth an estimator is scored on.

World frame ENU (x east, y north, z up), gravity ``(0, 0, −g)``; body frame
x forward, y left, z up (the IMU's own frame: no mounting rotation, no
lever arm). The vehicle drives on a plane, level or tilted about the east
axis by ``slope_deg`` (a heading north climbs), so its attitude is
``R = R_slope · R_z(ψ)`` and its body angular velocity ``(0, 0, ψ̇)``.
Its body velocity is ``(v, 0, 0)`` (no side slip); the world acceleration
is ``d/dt (R v_b) = R (dv_b/dt + ω × v_b)`` and the accelerometer reads the
specific force ``f = R^T (a_world − g_world)``: about +g along up at rest,
as ``ext_observer.attitude_from_imu`` expects (docs/raw_imu.md).

Speed and yaw rate are piecewise linear in time (:class:`Segment`), so the
heading is integrated exactly and a noise-free gyro integrated by the
trapezoid rule gives back the true attitude. A rough road adds
band-limited vibration to the specific force only: the stored velocity is
the wheels' (odometry's), which does not see ±2 cm/s of shaking.

Units: s, m/s, m/s², rad/s, magnetic field in µT (ours takes tesla).
Quaternions scalar first ``(w, x, y, z)``, body → ENU.
"""

import math
from dataclasses import dataclass, field

import numpy as np

from ext_observer.core.quaternion import multiply, rotation_matrices

GRAVITY = 9.81  # m/s², the simulated world's
RATE = 100.0  # Hz, the IMU's
# Noise per sample (standard deviations) and the gyro's fixed bias.
GYRO_NOISE = 0.002  # rad/s
ACC_NOISE = 0.05  # m/s²
MAG_NOISE = 0.5  # µT
GYRO_BIAS_DEG = 0.5  # °/s, norm of the bias vector (direction from the seed)
# The Earth's field: a mid-latitude 50 µT, dipping 60° below north.
FIELD_UT = 50.0
FIELD_DIP_DEG = 60.0
# Rough road: band-limited vibration of the specific force, body axes x, y, z.
VIBRATION_BAND = (10.0, 30.0)  # Hz
VIBRATION_RMS = (1.0, 1.0, 2.0)  # m/s²; the vertical is what a road shakes most
# Below this speed the vibration fades (a vehicle at rest does not shake).
VIBRATION_FULL_SPEED = 5.0  # m/s


@dataclass(frozen=True)
class Segment:
    """
    A stretch of driving: over ``duration`` s, the speed changes at ``accel``
    (m/s²) and the yaw rate goes linearly to ``yaw_rate`` (rad/s).

    ``manoeuvre`` marks the samples the manoeuvre's metrics are taken over.
    """

    duration: float
    accel: float = 0.0
    yaw_rate: float = None  # None: the previous segment's, held
    manoeuvre: bool = False


@dataclass(frozen=True)
class Scenario:
    """A drive: its segments, its road, and how the IMU is disturbed."""

    name: str
    description: str
    segments: tuple
    slope_deg: float = 0.0
    heading0_deg: float = 90.0  # ψ of x forward from east, counter-clockwise: north
    speed0: float = 0.0  # m/s at t = 0
    yaw_rate0: float = 0.0  # rad/s at t = 0
    rough: bool = False
    gyro_bias_deg: float = GYRO_BIAS_DEG
    kind: str = 'other'  # 'turn' for the ratio the done-criteria read


@dataclass
class Simulation:
    """
    One simulated recording, ``N`` samples at :data:`RATE`.

    ``gyr``, ``acc``, ``mag`` are the sensors as measured (rad/s, m/s², µT);
    ``gyr_true``, ``acc_true`` the noise-free ones; ``quat`` the true
    attitude, body → ENU; ``velocity`` the body-frame velocity (m/s) at
    ``velocity_times`` (s; here the IMU's times); ``manoeuvre`` the samples
    the manoeuvre's metrics read.
    """

    scenario: Scenario
    times: np.ndarray
    gyr: np.ndarray
    acc: np.ndarray
    mag: np.ndarray
    gyr_true: np.ndarray
    acc_true: np.ndarray
    quat: np.ndarray
    velocity: np.ndarray
    velocity_times: np.ndarray
    manoeuvre: np.ndarray
    speed: np.ndarray
    yaw_rate: np.ndarray
    gyro_bias: np.ndarray = field(default_factory=lambda: np.zeros(3))

    @property
    def rate(self):
        """Hz."""
        return RATE


def profile(scenario, rate=RATE):
    """
    Return times, speed, acceleration, yaw rate, heading and manoeuvre mask.

    Each is sampled at ``k / rate``; the heading (rad) is the exact integral
    of the piecewise-linear yaw rate.
    """
    count = int(round(sum(s.duration for s in scenario.segments) * rate)) + 1
    times = np.arange(count) / rate
    speed, accel, yaw_rate, heading = (np.empty(count) for _ in range(4))
    manoeuvre = np.zeros(count, dtype=bool)
    t0, v0, r0 = 0.0, scenario.speed0, scenario.yaw_rate0
    psi0 = math.radians(scenario.heading0_deg)
    for index, segment in enumerate(scenario.segments):
        r1 = r0 if segment.yaw_rate is None else segment.yaw_rate
        slope = (r1 - r0) / segment.duration
        last = index == len(scenario.segments) - 1
        inside = (times >= t0 - 1e-9) & ((times < t0 + segment.duration - 1e-9) | last)
        tau = times[inside] - t0
        speed[inside] = v0 + segment.accel * tau
        accel[inside] = segment.accel
        yaw_rate[inside] = r0 + slope * tau
        heading[inside] = psi0 + r0 * tau + 0.5 * slope * tau * tau
        manoeuvre[inside] = segment.manoeuvre
        psi0 += r0 * segment.duration + 0.5 * slope * segment.duration ** 2
        v0 += segment.accel * segment.duration
        r0, t0 = r1, t0 + segment.duration
    if np.any(speed < -1e-9):
        raise ValueError(f'{scenario.name}: the speed goes negative (a vehicle that reverses?)')
    return times, np.maximum(speed, 0.0), accel, yaw_rate, heading, manoeuvre


def attitude(heading, slope_deg):
    """Return ``q = q_slope ⊗ q_z(ψ)``, body → ENU, shape (N, 4)."""
    half = 0.5 * np.asarray(heading, dtype=float)
    q_z = np.stack([np.cos(half), 0.0 * half, 0.0 * half, np.sin(half)], axis=-1)
    a = 0.5 * math.radians(slope_deg)
    return multiply(np.array([math.cos(a), math.sin(a), 0.0, 0.0]), q_z)


def body_kinematic_acceleration(speed, accel, yaw_rate):
    """``dv_b/dt + ω × v_b`` for ``v_b = (v, 0, 0)``, ``ω = (0, 0, r)``: ``(v̇, r v, 0)``."""
    return np.stack([accel, yaw_rate * speed, 0.0 * speed], axis=-1)


def earth_field():
    """The field in ENU, µT: north and down by :data:`FIELD_DIP_DEG`."""
    dip = math.radians(FIELD_DIP_DEG)
    return FIELD_UT * np.array([0.0, math.cos(dip), -math.sin(dip)])


def band_limited(rng, count, rate, band, rms):
    """White noise kept to ``band`` (Hz) by its spectrum, scaled to ``rms``."""
    spectrum = np.fft.rfft(rng.standard_normal(count))
    frequencies = np.fft.rfftfreq(count, 1.0 / rate)
    spectrum[(frequencies < band[0]) | (frequencies > band[1])] = 0.0
    signal = np.fft.irfft(spectrum, count)
    return signal * (rms / np.sqrt(np.mean(signal * signal)))


def simulate(scenario, seed=0, rate=RATE, noise=True):
    """
    Simulate ``scenario``; return a :class:`Simulation`.

    ``seed`` fixes the noise, the gyro bias's direction and the vibration;
    ``noise=False`` gives the exact sensors (no noise, bias nor vibration).
    """
    times, speed, accel, yaw_rate, heading, manoeuvre = profile(scenario, rate)
    count = len(times)
    quat = attitude(heading, scenario.slope_deg)
    r = rotation_matrices(quat)
    up = np.array([0.0, 0.0, GRAVITY])
    kinematic = body_kinematic_acceleration(speed, accel, yaw_rate)
    # f = R^T (a_world − g_world), a_world = R · kinematic.
    acc_true = kinematic + np.einsum('nji,j->ni', r, up)
    gyr_true = np.stack([0.0 * yaw_rate, 0.0 * yaw_rate, yaw_rate], axis=-1)
    mag_true = np.einsum('nji,j->ni', r, earth_field())
    velocity = np.stack([speed, 0.0 * speed, 0.0 * speed], axis=-1)
    rng = np.random.default_rng(seed)
    bias = np.zeros(3)
    gyr, acc, mag = gyr_true.copy(), acc_true.copy(), mag_true.copy()
    if noise:
        direction = rng.standard_normal(3)
        bias = math.radians(scenario.gyro_bias_deg) * direction / np.linalg.norm(direction)
        gyr += bias + GYRO_NOISE * rng.standard_normal((count, 3))
        acc += ACC_NOISE * rng.standard_normal((count, 3))
        mag += MAG_NOISE * rng.standard_normal((count, 3))
        if scenario.rough:
            fade = np.minimum(speed / VIBRATION_FULL_SPEED, 1.0)
            for axis, rms in enumerate(VIBRATION_RMS):
                acc[:, axis] += fade * band_limited(rng, count, rate, VIBRATION_BAND, rms)
    return Simulation(scenario=scenario, times=times, gyr=gyr, acc=acc, mag=mag,
                      gyr_true=gyr_true, acc_true=acc_true, quat=quat,
                      velocity=velocity, velocity_times=times.copy(), manoeuvre=manoeuvre,
                      speed=speed, yaw_rate=yaw_rate, gyro_bias=bias)


# The drives of the benchmark. Speeds and yaw rates: a_c = v · ω.
CRUISE_SPEED = 15.0  # m/s (54 km/h) for the turns and the rough road
START_ACCEL = 1.5  # m/s², a gentle start to cruise speed (10 s)
REST = 10.0  # s at rest first: every estimator learns its gyro bias there
TURN_SECONDS = 30.0
TURN_RAMP = 2.0  # s of steering into and out of a turn
TURN_G = (0.1, 0.25, 0.5)  # centripetal, in g
BRAKE_G = 0.3
SLOPE_DEG = 5.0
STANDARD_G = 9.81


def _turn(centripetal_g, slope_deg):
    omega = centripetal_g * STANDARD_G / CRUISE_SPEED
    name = f'turn {centripetal_g:g} g' + (f', {slope_deg:g}° slope' if slope_deg else ', level')
    segments = (Segment(REST), Segment(CRUISE_SPEED / START_ACCEL, accel=START_ACCEL),
                Segment(10.0),
                Segment(TURN_RAMP, yaw_rate=omega, manoeuvre=True),
                Segment(TURN_SECONDS, manoeuvre=True),
                Segment(TURN_RAMP, yaw_rate=0.0, manoeuvre=True),
                Segment(20.0))
    return Scenario(name=name, segments=segments, slope_deg=slope_deg, kind='turn',
                    description=f'{CRUISE_SPEED:g} m/s, yaw rate {omega:.3f} rad/s for '
                                f'{TURN_SECONDS:g} s ({TURN_RAMP:g} s ramps)')


def _accel_brake(slope_deg):
    a = BRAKE_G * STANDARD_G
    seconds = 6.0
    cycle = (Segment(seconds, accel=a, manoeuvre=True), Segment(5.0, manoeuvre=True),
             Segment(seconds, accel=-a, manoeuvre=True), Segment(5.0, manoeuvre=True))
    name = 'accelerate/brake ±0.3 g' + (f', {slope_deg:g}° uphill' if slope_deg else ', level')
    return Scenario(name=name, segments=(Segment(REST),) + cycle * 3, slope_deg=slope_deg,
                    kind='straight',
                    description=f'3 × (±{BRAKE_G:g} g for {seconds:g} s to '
                                f'{a * seconds:.1f} m/s, 5 s cruise, 5 s stop)')


def _rough():
    return Scenario(name='rough road, level', rough=True, kind='straight',
                    segments=(Segment(REST), Segment(CRUISE_SPEED / START_ACCEL,
                                                     accel=START_ACCEL),
                              Segment(40.0, manoeuvre=True)),
                    description=f'{CRUISE_SPEED:g} m/s straight, vibration '
                                f'{VIBRATION_BAND[0]:g}–{VIBRATION_BAND[1]:g} Hz, RMS '
                                f'{VIBRATION_RMS} m/s² (x, y, z)')


def scenarios():
    """The benchmark's drives, in the table's order."""
    return ([_turn(g, 0.0) for g in TURN_G] + [_turn(g, SLOPE_DEG) for g in TURN_G]
            + [_accel_brake(0.0), _accel_brake(SLOPE_DEG), _rough()])
