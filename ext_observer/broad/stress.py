"""
BROAD's trials made harder: the variants of the robustness benchmark.

Each BROAD trial (:class:`~ext_observer.broad.data.Trial`) is turned into the
recordings a robot's IMU gives more often than BROAD does:

- ``a`` as recorded;
- ``b`` cut at its first ``movement`` sample (no rest before the motion);
- ``c`` ``b`` plus a constant gyro bias of :data:`BIAS` (1 °/s) in a random
  direction, fixed per trial: the direction is a standard normal draw of
  ``numpy.random.default_rng(zlib.crc32(name))``, normalized
  (:func:`bias_of`);
- ``d`` ``c`` at :data:`LOW_RATE` (50 Hz): block ``k`` holds the samples of
  time ``[k, k + 1) / 50`` s from the start (5 or 6 of BROAD's 285.7 Hz
  samples), gyro, specific force and field are their means, and the
  reference quaternion and the ``movement`` flag are those of the block's
  last sample (after a block the estimator has integrated the gyro up to
  it, as after sample ``i`` of a recording it is scored against sample
  ``i``); an incomplete last block is dropped;
- ``e`` as recorded, the gyro clipped at ±:data:`GYRO_RANGE` (250 °/s) on
  each axis, as a gyro left at its default range (MPU-6050) does.

Pure numpy; the units are the trial's (rad/s, m/s², µT, Hz).
"""

import math
import zlib

import numpy as np

from ext_observer.broad.data import Trial

BIAS = math.radians(1.0)  # rad/s: the constant gyro bias of variant c
LOW_RATE = 50.0  # Hz: the rate of variant d
GYRO_RANGE = math.radians(250.0)  # rad/s (4.363): the gyro range of variant e
VARIANTS = ('a', 'b', 'c', 'd', 'e')
# One line per variant, for tables and pages.
DESCRIPTIONS = {
    'a': 'as recorded',
    'b': 'cut at its first movement sample (no rest before the motion)',
    'c': '(b) plus a constant gyro bias of 1 °/s in a random direction',
    'd': '(c) at 50 Hz (block averages)',
    'e': 'as recorded, gyro clipped at ±250 °/s per axis',
}
# The same, short, for table rows and figure labels.
LABELS = {
    'a': '(a) as recorded',
    'b': '(b) cut at first movement',
    'c': '(c) (b) + 1 °/s gyro bias',
    'd': '(d) (c) at 50 Hz',
    'e': '(e) gyro clipped ±250 °/s',
}
# The done-criterion on (b)–(e): ours at most this times VQF, in 6D
# inclination and 9D total RMSE (goal: 0.9).
RATIO_DONE = 1.0
RATIO_GOAL = 0.9


def _like(trial, gyr=None, acc=None, mag=None, quat=None, movement=None, rate=None,
          select=None):
    """A new Trial of the same name: the arrays given, or ``trial``'s (sliced)."""
    def pick(given, own):
        if given is not None:
            return given
        return own if select is None else own[select]
    return Trial(trial.name, pick(gyr, trial.gyr), pick(acc, trial.acc),
                 pick(mag, trial.mag), pick(quat, trial.quat),
                 pick(movement, trial.movement), trial.rate if rate is None else rate)


def first_movement(trial):
    """Return the index of the trial's first ``movement`` sample."""
    found = np.flatnonzero(trial.movement)
    if found.size == 0:
        raise ValueError(f'{trial.name}: no movement sample')
    return int(found[0])


def cut_at_movement(trial):
    """Return the trial from its first ``movement`` sample on (variant ``b``)."""
    return _like(trial, select=slice(first_movement(trial), None))


def bias_of(name, magnitude=BIAS):
    """
    Return the constant gyro bias of trial ``name`` (rad/s, shape (3,)).

    The direction is a standard normal draw of
    ``np.random.default_rng(zlib.crc32(name.encode()))``, normalized: the
    same for a trial on every run and machine, independent of the others.
    """
    rng = np.random.default_rng(zlib.crc32(name.encode('utf-8')))
    direction = rng.standard_normal(3)
    return magnitude * direction / np.linalg.norm(direction)


def with_bias(trial, bias=None):
    """Return the trial with a constant gyro bias added (default :func:`bias_of`)."""
    bias = bias_of(trial.name) if bias is None else np.asarray(bias, dtype=float)
    return _like(trial, gyr=trial.gyr + bias)


def blocks(n, rate, low_rate=LOW_RATE):
    """
    Return the block of each sample for resampling to ``low_rate``.

    Parameters
    ----------
    n : int
        Samples.
    rate, low_rate : float
        Hz; ``low_rate`` at most ``rate``.

    Returns
    -------
    block : ndarray of int, shape (n,)
        ``floor(i · low_rate / rate)``: sample ``i`` at time ``i / rate``
        falls in block ``k`` of time ``[k, k + 1) / low_rate``.
    count : int
        The complete blocks (the last one is complete when the next sample
        would open a new block).

    """
    if not 0.0 < low_rate <= rate:
        raise ValueError(f'low_rate must be in (0, {rate}], got {low_rate}')
    # A small tolerance: i · low_rate / rate lands on integers exactly when
    # the rates divide, and rounding must not move such a sample back.
    block = np.floor(np.arange(n) * (low_rate / rate) + 1e-9).astype(int)
    count = int(np.floor(n * (low_rate / rate) + 1e-9))
    return block, count


def downsample(trial, low_rate=LOW_RATE):
    """
    Return the trial at ``low_rate`` by block averages (variant ``d`` of ``c``).

    Gyro, specific force and field: the mean of each block's samples
    (:func:`blocks`); reference quaternion and ``movement``: those of the
    block's last sample. The rate of the result is ``low_rate`` exactly.
    """
    block, count = blocks(len(trial), trial.rate, low_rate)
    keep = block < count
    block = block[keep]
    sizes = np.bincount(block, minlength=count)
    if count == 0 or np.any(sizes == 0):
        raise ValueError(f'{trial.name}: too short or too slow for {low_rate} Hz blocks')
    last = np.cumsum(sizes) - 1

    def mean(x):
        sums = np.zeros((count, x.shape[1]))
        np.add.at(sums, block, x[keep])
        return sums / sizes[:, None]

    return Trial(trial.name, mean(trial.gyr), mean(trial.acc), mean(trial.mag),
                 trial.quat[last], trial.movement[last], low_rate)


def clip_gyro(trial, limit=GYRO_RANGE):
    """Return the trial with each gyro axis clipped to ``[-limit, limit]`` (rad/s)."""
    return _like(trial, gyr=np.clip(trial.gyr, -limit, limit))


def variant(trial, key):
    """
    Return variant ``key`` (one of :data:`VARIANTS`) of a trial.

    Parameters
    ----------
    trial : Trial
        As read by :func:`~ext_observer.broad.data.load_trial`.
    key : str
        ``'a'`` to ``'e'`` (see the module's docstring).

    Returns
    -------
    Trial
        A new trial of the same name; ``trial`` is not changed.

    """
    if key == 'a':
        return trial
    if key == 'b':
        return cut_at_movement(trial)
    if key == 'c':
        return with_bias(cut_at_movement(trial))
    if key == 'd':
        return downsample(with_bias(cut_at_movement(trial)))
    if key == 'e':
        return clip_gyro(trial)
    raise ValueError(f'variant must be one of {VARIANTS}, got {key!r}')


def variants(trial, keys=VARIANTS):
    """Return ``{key: variant(trial, key)}`` for the ``keys`` given."""
    return {key: variant(trial, key) for key in keys}
