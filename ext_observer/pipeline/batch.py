"""
Many recordings through the raw-IMU estimator (:func:`estimate_batch`).

Each recording runs whole through one
:class:`~ext_observer.core.ahrs.estimator.AhrsObserver` (:meth:`~ext_observer.core.ahrs.estimator.AhrsObserver.run`:
compiled by numba where it is installed, plain Python otherwise), in this
process or shared among forked workers: the same estimator, the same results.
"""

import multiprocessing

import numpy as np

from ext_observer.core.ahrs.ahrs_params import AhrsParams
from ext_observer.core.ahrs.compiled import kernels
from ext_observer.core.ahrs.estimator import AhrsObserver

__all__ = ['estimate_batch', 'hold_finite']


def estimate_batch(gyr, acc, mag, rate_hz, use_mag, params=None, variant='extended',
                   workers=1):
    """
    Run many recordings (one estimator each, same parameters).

    Each recording runs whole, on floats (:meth:`AhrsObserver.run
    <ext_observer.core.ahrs.estimator.AhrsObserver.run>`); ``workers > 1`` shares them
    among forked processes, longest first, which takes the total work over
    ``workers``. The results do not depend on ``workers``.

    Parameters
    ----------
    gyr, acc, mag : list of ndarray, shape (N_i, 3)
        rad/s, m/s², field (any unit). ``mag`` entries may be ``None`` where
        ``use_mag`` is false. A sample with a non-finite value is replaced
        by the last finite one of its sensor (held), as a node would drop it.
    rate_hz : list of float
        Sampling rate of each recording (all must be equal).
    use_mag : list of bool
        9D where true, 6D elsewhere.
    params : AhrsParams, optional
        Values may be arrays of shape ``(B,)``: one per recording.
    variant : {'extended', 'plain'}
    workers : int
        Processes (forked; Linux and macOS); 1 runs in this process.

    Returns
    -------
    list of ndarray, shape (N_i, 4)
        The ambient estimates ``q̂_k`` (not normalized), sensor → ENU.

    """
    global _JOB
    count = len(gyr)
    if not (len(acc) == len(mag) == len(rate_hz) == len(use_mag) == count):
        raise ValueError('gyr, acc, mag, rate_hz and use_mag must have one entry per recording')
    rates = {float(r) for r in rate_hz}
    if len(rates) != 1:
        raise ValueError(f'all recordings must share one sampling rate, got {sorted(rates)}')
    dt = 1.0 / rates.pop()
    use_mag = np.asarray(use_mag, dtype=bool)
    lengths = [len(g) for g in gyr]
    workers = max(1, min(int(workers), count))
    _JOB = (gyr, acc, mag, use_mag, dt, params, variant)
    out = [None] * count
    if workers > 1 and kernels().compiled:
        # The loop compiled (or loaded from numba's cache) once, before the workers fork.
        AhrsObserver(use_mag=False).run(np.zeros((1, 3)), np.array([[0.0, 0.0, 9.8]]), None, dt)
    try:
        if workers == 1:
            for i in range(count):
                out[i] = _run_one(i)[1]
            return out
        order = sorted(range(count), key=lambda i: -lengths[i])
        # Forked workers read the inputs from this module (no copies).
        with multiprocessing.get_context('fork').Pool(workers) as pool:
            for i, q in pool.imap_unordered(_run_one, order):
                out[i] = q
        return out
    finally:
        _JOB = None


_JOB = None


def _run_one(i):
    """Recording ``i`` of ``_JOB``: ``(i, estimates)``."""
    gyr, acc, mag, use_mag, dt, params, variant = _JOB
    if params is not None and any(np.ndim(v) for v in params.as_dict().values()):
        params = AhrsParams(**{name: value[i] if np.ndim(value) else value
                               for name, value in params.as_dict().items()})
    est = AhrsObserver(params, use_mag=bool(use_mag[i]), variant=variant)
    g = hold_finite(np.asarray(gyr[i], dtype=float))
    a = hold_finite(np.asarray(acc[i], dtype=float))
    m = hold_finite(np.asarray(mag[i], dtype=float)) if use_mag[i] else None
    return i, est.run(g, a, m, dt)


def hold_finite(a):
    """A recording with every non-finite sample replaced by the last finite one."""
    bad = ~np.isfinite(a).all(axis=1)
    if not bad.any():
        return a
    if bad.all():
        raise ValueError('a recording has no finite sample')
    index = np.where(bad, 0, np.arange(len(a)))
    np.maximum.accumulate(index, out=index)
    first = np.argmax(~bad)
    index[:first] = first  # before the first finite sample: that sample
    return a[index]
