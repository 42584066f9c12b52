"""
A generated IMU stream and a lower-rate attitude source, for the replay test.

The body turns with a smooth angular velocity ω(t) (rad/s, body frame); the
truth is integrated on a fine grid (0.1 ms) with exact rotations,
``q ← q ⊗ exp(ω(t + h/2) h / 2)``. The IMU samples ω at ``imu_rate`` with
white noise and a constant bias; the attitude source samples the truth at
``measurement_rate``, at stamps that fall between IMU samples
(``measurement_offset`` after one), with rotation-vector noise of
``measurement_noise`` rad, and flips the sign of each quaternion at random
(``flip_probability``): ``y`` and ``−y`` are the same rotation.
"""

import math

import numpy as np

from ext_observer.pipeline.guard import carried

SECOND = 1_000_000_000
FINE = 100_000  # ns, the truth's integration step


def omega_at(t):
    """The body's angular velocity at ``t`` s after the start, rad/s."""
    return (0.6 * math.sin(0.7 * t) + 0.2,
            0.4 * math.cos(0.5 * t),
            0.5 * math.sin(0.3 * t + 1.0))


def generate(seconds=6.0, imu_rate=200, measurement_rate=10, measurement_offset=0.0023,
             gyro_noise=0.002, gyro_bias=(0.002, -0.001, 0.001), measurement_noise=0.02,
             flip_probability=0.5, start=1000 * SECOND, seed=0):
    """
    Return the stream, ordered by stamp.

    Returns
    -------
    imu : list of (stamp ns, ω tuple)
    measurements : list of (stamp ns, y tuple (w, x, y, z), flipped bool)
    truth : dict stamp ns -> q tuple (w, x, y, z), at every IMU stamp and
        measurement stamp

    """
    rng = np.random.default_rng(seed)
    imu_step = SECOND // imu_rate
    measurement_step = SECOND // measurement_rate
    offset = round(measurement_offset * SECOND) // FINE * FINE
    q = tuple(float(v) for v in rng.normal(size=4))
    n = math.sqrt(sum(v * v for v in q))
    q = tuple(v / n for v in q)
    imu, measurements, truth = [], [], {}
    end = round(seconds * SECOND)
    h = FINE * 1e-9
    for elapsed in range(0, end + 1, FINE):
        stamp = start + elapsed
        if elapsed % imu_step == 0:
            w = omega_at(elapsed * 1e-9)
            noisy = tuple(w[i] + gyro_bias[i] + gyro_noise * rng.normal() for i in range(3))
            imu.append((stamp, noisy))
            truth[stamp] = q
        if elapsed % measurement_step == offset:
            nu = rng.normal(scale=measurement_noise, size=3)
            y = carried(q, tuple(float(v) for v in nu))
            flipped = bool(rng.random() < flip_probability)
            if flipped:
                y = tuple(-v for v in y)
            measurements.append((stamp, y, flipped))
            truth[stamp] = q
        w = omega_at((elapsed + FINE / 2) * 1e-9)
        q = carried(q, (w[0] * h, w[1] * h, w[2] * h))
    return imu, measurements, truth


def angle(p, q):
    """The rotation angle between unit quaternions ``p`` and ``q`` (sign-invariant), rad."""
    dot = abs(sum(a * b for a, b in zip(p, q)))
    return 2.0 * math.acos(min(1.0, dot))
