"""
A simulated rate-integrating gyro and attitude sensor (Section 3).

At step k the model yields

- the increment ``θ_k`` (rad, body frame, the rotation over
  ``[t_k, t_{k+1})``), drawn uniformly per axis in
  ``[increment_min, increment_max]``, so that ``Ω_k = (0, θ_k)`` and the
  truth moves by ``q_{k+1} = q_k ⊗ exp(Ω_k / 2)``;
- the true attitude ``q_k``;
- the measurement ``y_k = q_k ⊗ exp(ν_k)`` with ``ν_k ~ N(0, σ² I₃)`` a
  vector quaternion (so the measured rotation is off by ``2‖ν_k‖``).

Optional gyro errors (off by default, so the paper's setup is exact): the
*reported* increment is ``θ_k + β_k + η_k`` with ``η_k ~ N(0, σ_g² I₃)``
(per-step angle noise, rad) and a bias ``β_k`` (rad per step) that starts at
``gyro_bias`` and follows a random walk of step ``σ_β``. The truth always
moves by the exact ``θ_k``.

Draws happen in a fixed order per step (increment, measurement noise, gyro
noise, bias walk), so the same seed gives the same stream.
"""

from collections import namedtuple

import numpy as np

from .. import quaternion as quat

__all__ = ['GyroSample', 'SimulatedGyro', 'Trajectory']

GyroSample = namedtuple('GyroSample', 'increment attitude measurement')
GyroSample.__doc__ = """\
One step of the gyro model.

Attributes
----------
increment : ndarray, shape (*batch_shape, 3)
    Reported ``θ_k``, rad (with the gyro errors, if any).
attitude : ndarray, shape (*batch_shape, 4)
    True ``q_k``.
measurement : ndarray, shape (*batch_shape, 4)
    ``y_k = q_k ⊗ exp(ν_k)``.
"""

Trajectory = namedtuple('Trajectory', 'increments attitudes measurements')
Trajectory.__doc__ = """\
Stacked samples: arrays of shape (steps, *batch_shape, 3 or 4).
"""


class SimulatedGyro:
    """
    Increments, true attitudes and noisy attitude measurements.

    Parameters
    ----------
    increment_max : float
        Upper bound of the uniform increment per axis, rad (paper: 0.5 for
        Figure 1, 10 for the observer).
    noise_std : float
        ``σ`` of the measurement noise ``ν_k`` (paper: 0.1).
    seed : int or None
        Seed of ``numpy.random.default_rng``.
    initial_attitude : array_like, shape (4,) or (*batch_shape, 4), optional
        ``q_0``; default uniform on S³ (per run).
    batch_shape : tuple of int
        Independent runs simulated together.
    increment_min : float
        Lower bound of the uniform increment per axis, rad.
    gyro_noise_std : float
        ``σ_g``, per-step angle noise on the reported increment, rad.
    gyro_bias : array_like, shape (3,)
        Initial bias of the reported increment, rad per step.
    bias_walk_std : float
        Random-walk step of the bias, rad per step per step.

    Raises
    ------
    ValueError
        For negative or non-finite parameters, or ``increment_min >
        increment_max``.

    """

    def __init__(self, increment_max=10.0, noise_std=0.1, seed=None,
                 initial_attitude=None, batch_shape=(), increment_min=0.0,
                 gyro_noise_std=0.0, gyro_bias=(0.0, 0.0, 0.0),
                 bias_walk_std=0.0):
        for name, value in (('increment_max', increment_max),
                            ('increment_min', increment_min),
                            ('noise_std', noise_std),
                            ('gyro_noise_std', gyro_noise_std),
                            ('bias_walk_std', bias_walk_std)):
            if not (np.isfinite(value) and value >= 0.0):
                raise ValueError(
                    f'{name} must be finite and non-negative, got {value}')
        if increment_min > increment_max:
            raise ValueError(f'increment_min ({increment_min}) must not exceed '
                             f'increment_max ({increment_max})')
        self.increment_min = float(increment_min)
        self.increment_max = float(increment_max)
        self.noise_std = float(noise_std)
        self.gyro_noise_std = float(gyro_noise_std)
        self.bias_walk_std = float(bias_walk_std)
        self.batch_shape = tuple(batch_shape)
        self.rng = np.random.default_rng(seed)
        bias = quat.check_vectors(gyro_bias, 'gyro_bias')
        if not np.all(np.isfinite(bias)):
            raise ValueError(f'gyro_bias must be finite, got {bias}')
        self.bias = np.broadcast_to(bias, self.batch_shape + (3,)).copy()
        if initial_attitude is None:
            q0 = quat.random_unit_quaternions(self.rng, self.batch_shape)
        else:
            q0 = quat.normalize(initial_attitude)
        self.attitude = np.broadcast_to(q0, self.batch_shape + (4,)).copy()
        self.steps = 0

    def step(self):
        """
        Draw step k and advance the truth to ``q_{k+1}``.

        Returns
        -------
        sample : GyroSample
            ``(θ_k reported, q_k, y_k)``.

        """
        shape = self.batch_shape + (3,)
        theta = self.rng.uniform(self.increment_min, self.increment_max, shape)
        nu = self.rng.normal(0.0, 1.0, shape) * self.noise_std
        y = quat.multiply(self.attitude, quat.exp(
            np.concatenate((np.zeros(self.batch_shape + (1,)), nu), axis=-1)))
        reported = theta
        if self.gyro_noise_std > 0.0 or np.any(self.bias != 0.0):
            reported = theta + self.bias
            if self.gyro_noise_std > 0.0:
                reported = reported + self.rng.normal(0.0, self.gyro_noise_std,
                                                      shape)
        if self.bias_walk_std > 0.0:
            self.bias = self.bias + self.rng.normal(0.0, self.bias_walk_std,
                                                    shape)
        sample = GyroSample(reported, self.attitude, y)
        # Renormalized so that rounding never drifts the truth off S³.
        self.attitude = quat.normalize(quat.multiply(
            self.attitude, quat.quaternion_from_rotation_vector(theta)))
        self.steps += 1
        return sample

    def simulate(self, steps):
        """
        Draw ``steps`` samples.

        Parameters
        ----------
        steps : int

        Returns
        -------
        trajectory : Trajectory
            ``increments (steps, *batch_shape, 3)``, ``attitudes`` and
            ``measurements`` ``(steps, *batch_shape, 4)``.

        """
        samples = [self.step() for _ in range(int(steps))]
        return Trajectory(*(np.stack(arrays) for arrays in zip(*samples)))
