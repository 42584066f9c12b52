"""
The paper's Monte Carlo experiments (Section 3), on the core's building blocks.

- :func:`manifold_convergence`: Section 3.1 / Figure 1, the extended
  kinematics alone, started off the manifold.
- :func:`observer_runs`: Section 3.2 / Figure 2 and Table 1, observers
  started at 1 against a true attitude uniform on S³.
- :func:`error_table`: the statistics of Table 1.

Epoch ``k`` runs from 0 (initial state) to ``epochs`` (after the last
step), so histories have ``epochs + 1`` rows.
"""

import math

import numpy as np

from .. import quaternion as quat
from ..certificate import s3_certificate
from ..extension import sphere_extension
from .gyro_model import SimulatedGyro
from .observer import (component_major, DEFAULT_KAPPA, DEFAULT_KAPPA_MIN,
                       LuenbergerObserver, PAPER_ALPHA, PAPER_GAIN)

__all__ = [
    'ObserverSpec',
    'accuracy_limit',
    'error_table',
    'fit_contraction',
    'manifold_convergence',
    'observer_runs',
    'row_name',
]

# E[χ₃], the mean norm of a standard 3-D Gaussian vector.
MEAN_CHI3 = 2.0 * math.sqrt(2.0 / math.pi)


def accuracy_limit(noise_std, measurements):
    """
    Mean final error ``‖q − q̂‖`` of the best estimate from exact increments.

    Averaging ``K`` measurements ``y = q ⊗ exp(ν)`` transported to the same
    instant leaves ``‖q − q̂‖ ≈ ‖ν̄‖`` with ``ν̄ ~ N(0, σ²/K I₃)``, so the
    limit is ``σ E[χ₃] / √K`` (≈ 0.016 for σ = 0.1, K = 100).

    Parameters
    ----------
    noise_std : float
        ``σ`` of the measurement noise.
    measurements : int
        ``K``, the number of measurements.

    Returns
    -------
    limit : float

    """
    return noise_std * MEAN_CHI3 / math.sqrt(measurements)


def fit_contraction(values):
    """
    Fit ``values[k] ≈ C ρᵏ`` by least squares on the logarithm.

    Parameters
    ----------
    values : array_like, shape (epochs + 1,)
        Positive values per epoch.

    Returns
    -------
    rho : float
        The fitted per-epoch factor.

    """
    values = np.asarray(values, dtype=float)
    keep = values > 0.0
    k = np.arange(values.size)[keep]
    slope = np.polyfit(k, np.log(values[keep]), 1)[0]
    return float(np.exp(slope))


def manifold_convergence(runs=1000, epochs=100, epsilon=0.5, alpha=PAPER_ALPHA,
                         increment_max=0.5, delta=0.059, seed=0):
    """
    Section 3.1: the extended kinematics converge to S³ (Figure 1).

    Initial states ``[w, 0, 0, 0]`` with ``w`` uniform in
    ``[√(1 − √ε), √(1 + √ε)]`` (the whole of ``V⁻¹([0, ε])`` along 1),
    increments uniform per axis in ``[0, increment_max]``.

    Parameters
    ----------
    runs, epochs : int
    epsilon, delta, alpha : float
        As in Theorem 1 (paper: 0.5, 0.059, 0.01).
    increment_max : float
        rad per step (paper: 0.5).
    seed : int

    Returns
    -------
    result : dict
        ``residual`` ``(epochs + 1, runs)``: ``|q̄q − 1| = √V``;
        ``distance``: ``|‖q‖ − 1|``; ``fitted_factor``: the fitted per-epoch
        factor of the mean V; ``certified_factor``: ``1 − bc`` from
        :func:`s3_certificate`; ``fitted_residual_factor``: the same fit on
        the mean residual.

    """
    rng = np.random.default_rng(seed)
    root = math.sqrt(epsilon)
    w = rng.uniform(math.sqrt(1.0 - root), math.sqrt(1.0 + root), runs)
    x = np.zeros((runs, 4))
    x[:, 0] = w
    ext = sphere_extension()
    gyro = SimulatedGyro(increment_max=increment_max, noise_std=0.0,
                         seed=rng.integers(2**63), batch_shape=(runs,))

    def f(x, theta):
        return quat.multiply(x, quat.quaternion_from_rotation_vector(theta))

    states = [x]
    for _ in range(epochs):
        x = ext.step(f, x, alpha, gyro.step().increment)
        states.append(x)
    states = np.stack(states)
    residual = quat.constraint_residual(states)
    cert = s3_certificate(epsilon, delta, alpha)
    return {
        'residual': residual,
        'distance': quat.manifold_distance(states),
        'fitted_factor': fit_contraction((residual ** 2).mean(axis=1)),
        'fitted_residual_factor': fit_contraction(residual.mean(axis=1)),
        'certified_factor': cert.factor,
        'certificate': cert,
    }


class ObserverSpec:
    """
    One observer of an experiment: a variant and a gain mode.

    Parameters
    ----------
    variant : {'extended', 'plain', 'projected'}
    gain_mode : {'constant', 'rotating', 'scheduled'}
    alpha, kappa, kappa_min : float
        As in :class:`~ext_observer.core.paper.observer.ObserverConfig`.

    """

    def __init__(self, variant, gain_mode='constant', alpha=PAPER_ALPHA,
                 kappa=DEFAULT_KAPPA, kappa_min=DEFAULT_KAPPA_MIN):
        self.variant = variant
        self.gain_mode = gain_mode
        self.alpha = alpha
        self.kappa = kappa
        self.kappa_min = kappa_min

    @property
    def name(self):
        """Row name: the variant, then ``-<gain_mode>`` unless constant."""
        return row_name(self.variant, self.gain_mode)

    def build(self, batch_shape, gain=PAPER_GAIN):
        """Return a :class:`LuenbergerObserver` starting at 1."""
        return LuenbergerObserver(self.variant, alpha=self.alpha, gain=gain,
                                  batch_shape=batch_shape,
                                  gain_mode=self.gain_mode, kappa=self.kappa,
                                  kappa_min=self.kappa_min)


def row_name(variant, gain_mode='constant'):
    """Return the table row name of an observer (``extended-rotating``...)."""
    return variant if gain_mode == 'constant' else f'{variant}-{gain_mode}'


def observer_runs(specs, runs=1000, epochs=100, seed=0, increment_max=10.0,
                  noise_std=0.1, gain=PAPER_GAIN, gyro_noise_std=0.0,
                  gyro_bias=(0.0, 0.0, 0.0), bias_walk_std=0.0):
    """
    Section 3.2: observers against the simulated system (Figure 2, Table 1).

    The true initial attitude is uniform on S³, every observer starts at 1,
    and all observers see the same increments and measurements.

    Parameters
    ----------
    specs : sequence of ObserverSpec
    runs, epochs, seed : int
    increment_max, noise_std : float
        Increments uniform per axis in (0, increment_max) rad; measurement
        noise σ (paper: 10 and 0.1).
    gain : sequence of 4 float
        The constant gain L (paper: (0.11, −0.18, −0.18, −0.18)).
    gyro_noise_std, gyro_bias, bias_walk_std
        Gyro errors of :class:`SimulatedGyro` (default off, the paper's).

    Returns
    -------
    result : dict
        For each spec name: ``{'error': (epochs + 1, runs) ‖q − q̂‖,
        'residual': |q̂̄q̂ − 1|, 'distance': |‖q̂‖ − 1|,
        'angle': attitude error, rad}``.

    """
    gyro = SimulatedGyro(increment_max=increment_max, noise_std=noise_std,
                         seed=seed, batch_shape=(runs,),
                         gyro_noise_std=gyro_noise_std, gyro_bias=gyro_bias,
                         bias_walk_std=bias_walk_std)
    observers = {spec.name: spec.build((runs,), gain) for spec in specs}
    history = {name: [obs.state] for name, obs in observers.items()}
    truth = [gyro.attitude]
    for _ in range(epochs):
        sample = gyro.step()
        # Shared by every observer, laid out as they compute (no copies).
        E = component_major(quat.quaternion_from_rotation_vector(sample.increment))
        y = component_major(sample.measurement)
        for name, obs in observers.items():
            history[name].append(obs.step(sample.increment, y, rotation=E))
        truth.append(gyro.attitude)
    truth = np.stack(truth)
    result = {}
    for name, states in history.items():
        states = np.stack(states)
        result[name] = {
            'error': np.linalg.norm(truth - states, axis=-1),
            'residual': quat.constraint_residual(states),
            'distance': quat.manifold_distance(states),
            'angle': quat.attitude_error(truth, states),
        }
    return result


def error_table(histories, after=25):
    """
    The statistics of Table 1 for one observer.

    Parameters
    ----------
    histories : dict
        One entry of :func:`observer_runs`.
    after : int
        Max and Min are taken over the epochs ``k > after`` (paper: 25).

    Returns
    -------
    table : dict
        For ``error`` (‖q − q̂‖), ``distance`` (|q̂̄q̂ − 1|, the paper's
        column), ``euclidean_distance`` (|‖q̂‖ − 1|) and ``angle`` (rad):
        ``mean`` and ``std`` at the final epoch, ``max`` and ``min`` over
        all runs and epochs ``k > after``.

    """
    table = {}
    for key, source in (('error', 'error'), ('distance', 'residual'),
                        ('euclidean_distance', 'distance'),
                        ('angle', 'angle')):
        values = histories[source]
        late = values[after + 1:]
        table[key] = {
            'mean': float(values[-1].mean()),
            'std': float(values[-1].std()),
            'max': float(late.max()),
            'min': float(late.min()),
        }
    return table
