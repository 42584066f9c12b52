"""
Many recordings through the raw-IMU estimator at once (:func:`estimate_batch`).

Vectorized in this process (one :class:`~ext_observer.core.ahrs.AhrsObserver`
on ``(B,)`` arrays) or shared among forked workers, each on Python floats:
the same estimator, the same results to rounding.
"""

import multiprocessing

import numpy as np

from .ahrs_params import AhrsParams

__all__ = ['estimate_batch']


def estimate_batch(gyr, acc, mag, rate_hz, use_mag, params=None, variant='extended',
                   workers=1):
    """
    Run many recordings at once (one estimator each, same parameters).

    Two ways, one estimator, the same results (to rounding, about 1e-12;
    the magnetometer calibration's Kalman filter, multiplied in a stack
    when vectorized, magnifies rounding to about 1e-11):

    - ``workers=1``: in this process, vectorized across the recordings (one
      :class:`AhrsObserver` on arrays of shape ``(B,)``). A step costs about
      the same whatever ``B``, so the time is that of the longest recording.
    - ``workers>1``: the recordings shared among forked processes, each run
      on Python floats, longest first. The time is the total work over
      ``workers``: faster than the vectorized way from two processes on.

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
    if workers > 1:
        global _JOB
        _JOB = (gyr, acc, mag, use_mag, dt, params, variant)
        order = sorted(range(count), key=lambda i: -lengths[i])
        out = [None] * count
        try:
            # Forked workers read the inputs from this module (no copies).
            with multiprocessing.get_context('fork').Pool(workers) as pool:
                for i, q in pool.imap_unordered(_run_one, order):
                    out[i] = q
        finally:
            _JOB = None
        return out

    n_max = max(lengths)

    def stack(arrays):
        out = np.empty((n_max, 3, count))
        for i, a in enumerate(arrays):
            a = np.zeros((lengths[i], 3)) if a is None else np.asarray(a, dtype=float)
            out[:len(a), :, i] = _hold_finite(a)
            out[len(a):, :, i] = out[len(a) - 1, :, i]  # hold the last sample past the end
        return out

    g_all, a_all, m_all = stack(gyr), stack(acc), stack(mag)
    from .ahrs import AhrsObserver  # ahrs imports this module
    est = AhrsObserver(params, use_mag=use_mag, batch=count, variant=variant)
    out = np.empty((n_max, 4, count))
    update = est.update
    for k in range(n_max):
        out[k, 0], out[k, 1], out[k, 2], out[k, 3] = update(g_all[k], a_all[k], m_all[k], dt)
    return [np.ascontiguousarray(out[:n, :, i]) for i, n in enumerate(lengths)]


_JOB = None


def _run_one(i):
    """Recording ``i`` of ``_JOB`` on Python floats: ``(i, estimates)``."""
    gyr, acc, mag, use_mag, dt, params, variant = _JOB
    if params is not None and any(np.ndim(v) for v in params.as_dict().values()):
        params = AhrsParams(**{name: value[i] if np.ndim(value) else value
                               for name, value in params.as_dict().items()})
    from .ahrs import AhrsObserver  # ahrs imports this module
    est = AhrsObserver(params, use_mag=bool(use_mag[i]), variant=variant)
    g = _hold_finite(np.asarray(gyr[i], dtype=float)).tolist()
    a = _hold_finite(np.asarray(acc[i], dtype=float)).tolist()
    m = (_hold_finite(np.asarray(mag[i], dtype=float)).tolist() if use_mag[i]
         else [None] * len(g))
    update = est.update
    return i, np.array([update(g[k], a[k], m[k], dt) for k in range(len(g))])


def _hold_finite(a):
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
