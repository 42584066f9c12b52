"""
Many recordings through the raw-IMU estimator (:func:`estimate_batch`).

Each recording runs whole through one
:class:`~ext_observer.core.ahrs.ahrs_observer.AhrsObserver`
(:meth:`~ext_observer.core.ahrs.ahrs_observer.AhrsObserver.run`:
compiled by numba where it is installed, plain Python otherwise), in this
process or shared among forked workers: the same estimator, the same results.
"""

import mmap
import multiprocessing

import numpy as np

from ext_observer.core.ahrs.ahrs_params import AhrsParams
from ext_observer.core.ahrs.compiled import kernels
from ext_observer.core.ahrs.ahrs_observer import AhrsObserver

__all__ = ['estimate_batch', 'hold_finite', 'shared_arrays']


def estimate_batch(gyr, acc, mag, rate_hz, use_mag, params=None, variant='extended',
                   workers=1, then=None):
    """
    Run many recordings (one estimator each, same parameters).

    Each recording runs whole, on floats (:meth:`AhrsObserver.run
    <ext_observer.core.ahrs.ahrs_observer.AhrsObserver.run>`); ``workers > 1`` shares them
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
    then : callable, optional
        ``then(i, q)`` on recording ``i``'s estimates as soon as they are
        made, where they are made (a worker); what it returns must pickle
        (small: a score, not an array). For work on each recording that
        can share the workers too.

    Returns
    -------
    list of ndarray, shape (N_i, 4)
        The ambient estimates ``q̂_k`` (not normalized), sensor → ENU.
    list
        Only with ``then``: what it returned for each recording.

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
    _JOB = (gyr, acc, mag, use_mag, dt, params, variant, then, None)
    out, after = [None] * count, [None] * count
    if workers > 1 and kernels().compiled:
        # The loop compiled (or loaded from numba's cache) once, before the workers fork.
        AhrsObserver(use_mag=False).run(np.zeros((1, 3)), np.array([[0.0, 0.0, 9.8]]), None, dt)
    try:
        if workers == 1:
            for i in range(count):
                _, out[i], after[i] = _run_one(i)
        else:
            order = sorted(range(count), key=lambda i: -lengths[i])
            # Forked workers read the inputs from this module and write the
            # estimates into memory shared with this process: nothing is
            # copied either way (pickling ~100 MB back cost more than the
            # work it shared).
            out = shared_arrays([(n, 4) for n in lengths])
            _JOB = _JOB[:-1] + (out,)
            with multiprocessing.get_context('fork').Pool(workers) as pool:
                for i, _, result in pool.imap_unordered(_run_one, order):
                    after[i] = result
    finally:
        _JOB = None
    return out if then is None else (out, after)


_JOB = None


def shared_arrays(shapes, dtype=float):
    """
    Zeroed arrays in one anonymous shared mapping, which forked children write and this reads.

    Parameters
    ----------
    shapes : list of tuple of int, or of (tuple of int, dtype)
        Each array's shape, with its own dtype where given as a pair.
    dtype : numpy dtype
        Of the arrays given by shape alone.

    Returns
    -------
    list of ndarray
        C-contiguous, writable, one per shape; the mapping lives as long as
        any of them.

    """
    specs = [(tuple(s[0]), np.dtype(s[1])) if len(s) == 2 and not np.isscalar(s[0])
             else (tuple(s), np.dtype(dtype)) for s in shapes]
    sizes = [int(np.prod(s, dtype=np.int64)) * d.itemsize for s, d in specs]
    # Each array starts on a 64-byte boundary.
    starts = np.concatenate([[0], np.cumsum([-(-n // 64) * 64 for n in sizes])])
    buffer = mmap.mmap(-1, max(int(starts[-1]), 1))
    return [np.frombuffer(buffer, dtype=d, count=n // d.itemsize, offset=int(start)).reshape(s)
            for (s, d), n, start in zip(specs, sizes, starts)]


def _run_one(i):
    """
    Recording ``i`` of ``_JOB``: ``(i, estimates, then's result)``.

    In a worker the estimates are written to the shared output and not
    sent back (``None`` in their place).
    """
    gyr, acc, mag, use_mag, dt, params, variant, then, shared = _JOB
    if params is not None and any(np.ndim(v) for v in params.as_dict().values()):
        params = AhrsParams(**{name: value[i] if np.ndim(value) else value
                               for name, value in params.as_dict().items()})
    est = AhrsObserver(params, use_mag=bool(use_mag[i]), variant=variant)
    g = hold_finite(np.asarray(gyr[i], dtype=float))
    a = hold_finite(np.asarray(acc[i], dtype=float))
    m = hold_finite(np.asarray(mag[i], dtype=float)) if use_mag[i] else None
    q = est.run(g, a, m, dt, out=None if shared is None else shared[i])
    result = None if then is None else then(i, q)
    return i, (q if shared is None else None), result


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
