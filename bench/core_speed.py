"""
The numerical core: batch speed, its ceilings, and accuracy beside the limit.

Everything here runs in the benchmark's own process (no ROS). Timings take
the best of a few repeats of loops long enough to dwarf the timer
(:func:`bench.timing.best_seconds`).
"""

import itertools
import os
import subprocess
import sys
import time

import numpy as np

from bench.timing import best_seconds
from ext_observer.core import (LuenbergerObserver, multiply,
                               quaternion_from_rotation_vector,
                               SimulatedGyro, SingleObserver, VARIANTS)

BATCH_SIZES = (1, 1000, 100_000)
PRODUCT_BATCH = 100_000


def _trajectory(batch, seed, steps):
    """A short simulated trajectory of the paper's setup, to cycle through."""
    shape = () if batch == 1 else (batch,)
    gyro = SimulatedGyro(increment_max=10.0, noise_std=0.1, seed=seed,
                         batch_shape=shape)
    return shape, gyro.simulate(steps)


def observer_rates(batch_sizes=BATCH_SIZES, variants=VARIANTS, seed=0):
    """
    Updates per second of :class:`LuenbergerObserver`, per variant and size.

    Batch size 1 is ``batch_shape=()``. The steps cycle through a short
    trajectory of the paper's setup (increments uniform in [0, 10) rad per
    axis, σ = 0.1, paper gain, constant mode), so the estimates stay where
    they would be in use. ``rotation_given`` passes ``E = exp(Ω/2)``
    precomputed, as the experiments do when observers share increments.

    Returns
    -------
    rows : list of dict
        ``variant``, ``batch``, ``us_per_step``, ``updates_per_s``, and the
        same with ``rotation_given``.

    """
    rows = []
    for batch in batch_sizes:
        cycle = 64 if batch <= 1000 else 8
        shape, traj = _trajectory(batch, seed, cycle)
        rotations = quaternion_from_rotation_vector(traj.increments)
        for variant in variants:
            obs = LuenbergerObserver(variant, batch_shape=shape)
            counter = itertools.count()

            def with_increment():
                k = next(counter) % cycle
                obs.step(traj.increments[k], traj.measurements[k])

            def with_rotation():
                k = next(counter) % cycle
                obs.step(traj.increments[k], traj.measurements[k],
                         rotation=rotations[k])
            increment_time = best_seconds(with_increment)
            obs.reset()
            rotation_time = best_seconds(with_rotation)
            rows.append({
                'variant': variant, 'batch': batch,
                'us_per_step': increment_time * 1e6,
                'updates_per_s': batch / increment_time,
                'us_per_step_rotation_given': rotation_time * 1e6,
                'updates_per_s_rotation_given': batch / rotation_time,
            })
    return rows


def single_observer_costs(variants=VARIANTS, seed=0, cycle=256):
    """µs per :meth:`SingleObserver.step` (plain floats), per variant."""
    _, traj = _trajectory(1, seed, cycle)
    inputs = [(tuple(map(float, theta)), tuple(map(float, y)))
              for theta, y in zip(traj.increments, traj.measurements)]
    costs = {}
    for variant in variants:
        obs = SingleObserver(variant)
        counter = itertools.count()

        def step():
            obs.step(*inputs[next(counter) % cycle])
        costs[variant] = best_seconds(step) * 1e6
    return costs


def product_costs(batch=PRODUCT_BATCH, seed=0):
    """
    Cost of one batched Hamilton product and of ``exp(Ω/2)`` (the ceilings).

    Returns
    -------
    result : dict
        ``multiply_us`` (:func:`quaternion.multiply`), ``exp_half_us``
        (:func:`quaternion_from_rotation_vector`), ``sincos_us`` (numpy's
        ``sin`` and ``cos`` of the half angles alone), and
        ``numpy_quaternion_us`` (its product; None when not installed), all
        for ``batch`` quaternions, with ``numpy_quaternion_version``.

    """
    rng = np.random.default_rng(seed)
    p = rng.standard_normal((batch, 4))
    q = rng.standard_normal((batch, 4))
    increments = rng.uniform(0.0, 10.0, (batch, 3))
    half_angles = 0.5 * np.linalg.norm(increments, axis=-1)
    result = {
        'batch': batch,
        'multiply_us': best_seconds(lambda: multiply(p, q)) * 1e6,
        'exp_half_us': best_seconds(
            lambda: quaternion_from_rotation_vector(increments)) * 1e6,
        'sincos_us': best_seconds(
            lambda: (np.sin(half_angles), np.cos(half_angles))) * 1e6,
        'numpy_quaternion_us': None,
        'numpy_quaternion_version': None,
    }
    try:
        import quaternion as npq
    except ImportError:
        return result
    a, b = npq.as_quat_array(p), npq.as_quat_array(q)
    product = a * b
    # Same convention (Hamilton, scalar first): the reference must agree.
    if not np.allclose(npq.as_float_array(product), multiply(p, q)):
        raise RuntimeError('numpy-quaternion disagrees with quaternion.multiply')
    result['numpy_quaternion_us'] = best_seconds(lambda: a * b) * 1e6
    from importlib import metadata
    try:
        result['numpy_quaternion_version'] = metadata.version('numpy-quaternion')
    except metadata.PackageNotFoundError:
        result['numpy_quaternion_version'] = getattr(npq, '__version__', '?')
    return result


def accuracy(runs=1000, epochs=100, seed=0):
    """
    Final mean ``‖q − q̂‖`` of every variant and gain mode on Table 1's setup.

    1000 runs × 100 epochs, ``SimulatedGyro(increment_max=10,
    noise_std=0.1)``, observers started at 1 against a uniform true attitude
    (:func:`ext_observer.core.paper.experiments.observer_runs`), next to the limit
    ``σ E[χ₃] / √K`` for exact increments.

    Returns
    -------
    result : dict
        ``rows`` (name → final mean and std of the error), ``limit``,
        ``seconds`` (wall time of the runs).

    """
    from ext_observer.core.paper.experiments import (accuracy_limit, ObserverSpec,
                                               observer_runs)
    from ext_observer.core.paper.observer import GAIN_MODES
    specs = [ObserverSpec(variant, mode) for mode in GAIN_MODES
             for variant in VARIANTS]
    start = time.perf_counter()
    histories = observer_runs(specs, runs=runs, epochs=epochs, seed=seed,
                              increment_max=10.0, noise_std=0.1)
    seconds = time.perf_counter() - start
    rows = {name: {'mean': float(h['error'][-1].mean()),
                   'std': float(h['error'][-1].std())}
            for name, h in histories.items()}
    return {'rows': rows, 'limit': accuracy_limit(0.1, epochs),
            'runs': runs, 'epochs': epochs, 'seconds': seconds,
            'observers': len(specs)}


def reproduce_time(seeds=5, no_plots=False, timeout=300.0):
    """
    Wall time of ``python -m ext_observer reproduce --seeds N`` (a child).

    The figures go to a temporary folder; ``no_plots`` adds ``--no-plots``
    (the Monte Carlo alone, in a fresh interpreter).

    Returns
    -------
    result : dict
        ``seconds`` and ``command``; ``note`` instead of ``seconds`` when
        the command is missing or fails.

    """
    repo = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    command = [sys.executable, '-m', 'ext_observer', 'reproduce',
               '--seeds', str(seeds)]
    if no_plots:
        command.append('--no-plots')
    shown = ' '.join(['python'] + command[1:])
    if not os.path.exists(os.path.join(repo, 'ext_observer', 'paper', 'reproduce.py')):
        return {'command': shown, 'note': 'not measured: reproduce is missing'}
    env = dict(os.environ)
    env['PYTHONPATH'] = repo + (os.pathsep + env['PYTHONPATH']
                                if env.get('PYTHONPATH') else '')
    env['MPLBACKEND'] = 'Agg'
    import tempfile
    with tempfile.TemporaryDirectory(prefix='bench-reproduce-') as tmp:
        start = time.perf_counter()
        try:
            done = subprocess.run(command + ['--out', tmp], cwd=tmp, env=env,
                                  stdout=subprocess.DEVNULL,
                                  stderr=subprocess.PIPE, text=True,
                                  timeout=timeout)
        except subprocess.TimeoutExpired:
            return {'command': shown, 'note': f'not measured: over {timeout} s'}
        seconds = time.perf_counter() - start
    if done.returncode != 0:
        tail = done.stderr.strip().splitlines()[-1:] or ['']
        return {'command': shown,
                'note': f'failed with exit code {done.returncode}: {tail[0]}'}
    return {'command': shown, 'seconds': seconds}


def lean_prototype_rate(batch=PRODUCT_BATCH, seed=0):
    """
    Updates per second of :class:`bench.lean.LeanExtendedStep` (E given).

    Returns
    -------
    result : dict
        ``us_per_step``, ``updates_per_s``, ``gap`` (largest difference from
        the core's step on a check batch).

    """
    from bench.lean import check_against_core, LeanExtendedStep
    gap = check_against_core(seed=seed)
    _, traj = _trajectory(batch, seed, 8)
    rotations = quaternion_from_rotation_vector(traj.increments)
    e = [np.ascontiguousarray(r.T) for r in rotations]
    y = [np.ascontiguousarray(m.T) for m in traj.measurements]
    step = LeanExtendedStep(batch)
    states = [np.ascontiguousarray(np.tile([[1.0], [0.0], [0.0], [0.0]],
                                           (1, batch))), np.empty((4, batch))]
    counter = itertools.count()

    def advance():
        k = next(counter)
        step(states[k % 2], e[k % 8], y[k % 8], states[(k + 1) % 2])
    seconds = best_seconds(advance)
    return {'us_per_step': seconds * 1e6, 'updates_per_s': batch / seconds,
            'gap': gap}
