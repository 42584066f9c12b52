"""
``python -m bench.smooth_speed``: the smoother's time against the online run's, per stage.

A synthetic recording of ``--minutes`` at ``--rate`` Hz (:func:`recording`:
smooth rotation about changing axes, translation, a gyro bias, noise, a field
with every sample), through the online estimator
(:func:`~ext_observer.pipeline.batch.estimate_batch`) and through
:func:`~ext_observer.core.ahrs.smoother.smooth_attitude`, 6D and 9D. The
smoother's stages are timed apart: the online pass (its gyro bias), the
strapdown, the inclination, the heading and the rest (checks, bridges,
gaps). Thread CPU time (``time.thread_time``: the machine may be shared),
the best of ``--repeat`` runs for each figure; the numba kernels compiled
(or loaded from their cache) before the first run.
"""

import argparse
import contextlib
import sys
import time

import numpy as np

__all__ = ['main', 'measure', 'recording']

STAGES = ('online', 'strapdown', 'inclination', 'heading')
GRAVITY = 9.81  # m/s²
FIELD = (0.0, 25.0, -43.3)  # µT, ENU: 50 µT north, 60° down


def recording(minutes, rate, seed=0):
    """
    gyr (rad/s), acc (m/s²) and mag (µT), (N, 3) each: ``minutes`` at ``rate`` Hz.

    The body turns at rates of sines of a few tenths of a hertz about each
    axis and translates at 3 m/s²; the gyro reads a bias of about 0.01 rad/s.
    """
    from ext_observer.core.ahrs.smooth_strapdown import rotate_rows, strapdown
    rng = np.random.default_rng(seed)
    n = int(round(60.0 * minutes * rate))
    t = np.arange(n) / rate
    omega = np.stack((0.8 * np.sin(0.7 * t), 0.6 * np.cos(0.45 * t + 1.0),
                      0.9 * np.sin(0.3 * t + 2.0)), axis=1)
    inverse = strapdown(omega, 1.0 / rate, (0.9, 0.1, -0.2, 0.3)) * (1.0, -1.0, -1.0, -1.0)
    force = 3.0 * np.stack((np.sin(6.9 * t), np.cos(5.3 * t), np.sin(8.2 * t)), axis=1)
    force[:, 2] += GRAVITY
    gyr = omega + (0.01, -0.015, 0.008) + rng.normal(0.0, 0.002, (n, 3))
    acc = rotate_rows(inverse, force) + rng.normal(0.0, 0.02, (n, 3))
    mag = rotate_rows(inverse, np.broadcast_to(FIELD, (n, 3))) + rng.normal(0.0, 0.2, (n, 3))
    return gyr, acc, mag


@contextlib.contextmanager
def _timed(module, names, spent):
    """Each of ``module``'s functions ``names[stage]`` timed into ``spent[stage]`` (s)."""
    saved = {stage: getattr(module, name) for stage, name in names.items()}

    def wrap(stage, inner):
        def timed(*args, **kwargs):
            start = time.thread_time()
            try:
                return inner(*args, **kwargs)
            finally:
                spent[stage] += time.thread_time() - start
        return timed

    for stage, name in names.items():
        setattr(module, name, wrap(stage, saved[stage]))
    try:
        yield
    finally:
        for stage, name in names.items():
            setattr(module, name, saved[stage])


def measure(gyr, acc, mag, rate, repeat):
    """
    The best of ``repeat`` runs: ``{'online run': s, 'smoothed': s, stage: s, ...}``.

    ``mag`` None: 6D.
    """
    from ext_observer.core.ahrs import smoother
    from ext_observer.pipeline.batch import estimate_batch
    names = {'online': '_bias', 'strapdown': 'strapdown', 'inclination': 'inclination',
             'heading': 'heading'}
    best = {}
    for _ in range(repeat):
        start = time.thread_time()
        estimate_batch([gyr], [acc], [mag], [rate], [mag is not None])
        figures = {'online run': time.thread_time() - start}
        spent = dict.fromkeys(STAGES, 0.0)
        with _timed(smoother, names, spent):
            start = time.thread_time()
            smoother.smooth_attitude(gyr, acc, mag, rate)
            figures['smoothed'] = time.thread_time() - start
        figures.update(spent)
        figures['rest'] = figures['smoothed'] - sum(spent.values())
        for key, value in figures.items():
            best[key] = min(best.get(key, np.inf), value)
    return best


def main(argv=None):
    parser = argparse.ArgumentParser(prog='python -m bench.smooth_speed', description=__doc__)
    parser.add_argument('--minutes', type=float, default=10.0)
    parser.add_argument('--rate', type=float, default=1000.0, help='Hz (default 1000)')
    parser.add_argument('--repeat', type=int, default=3, help='runs; the best (default 3)')
    parser.add_argument('--modes', default='6D,9D', help='6D, 9D or both (default)')
    args = parser.parse_args(argv)
    if args.minutes <= 0.0 or args.repeat < 1:
        raise ValueError('--minutes must be positive and --repeat at least 1')
    from ext_observer.core.ahrs.smoother import smooth_attitude
    gyr, acc, field = recording(args.minutes, args.rate)
    warm = slice(0, int(args.rate))
    for mode in args.modes.split(','):
        if mode not in ('6D', '9D'):
            raise ValueError(f'--modes takes 6D and 9D, got {mode!r}')
        mag = field if mode == '9D' else None
        smooth_attitude(gyr[warm], acc[warm], None if mag is None else mag[warm], args.rate)
        best = measure(gyr, acc, mag, args.rate, args.repeat)
        ratio = best['smoothed'] / best['online run']
        stages = ', '.join(f'{stage} {best[stage]:.3f}' for stage in STAGES + ('rest',))
        print(f'{mode}, {len(gyr)} samples at {args.rate:g} Hz, best of {args.repeat} '
              f'(thread CPU s): online run {best["online run"]:.3f}, smoothed '
              f'{best["smoothed"]:.3f} ({ratio:.2f}x); {stages}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
