"""
A fitted motion model for a hole: the lost gyro rates, a linear map of the rates beside it.

One map per hole length (samples lost) and shape: from the ``before`` rates
up to the last kept sample and the ``after`` rates from the first kept one
(the same weights for each axis) to the lost rates, by ridge least squares
over every :data:`STRIDE`-th window of that length in the training trials'
recorded gyro (any stretch of a recording is an example of a hole). Two
shapes: **causal** (``after`` = 1: what the estimator holds when the first
sample after the hole comes) and **two-sided** (``after`` = ``before``: known
``after − 1`` samples later). ``K`` and the ridge are chosen by a two-fold
split of the training trials, on the rotation the lost rates integrate to.
Rates in rad/s; the sample rate is the trials' one.
"""

import math

import numpy as np

KS = (3, 10, 30, 100)  # samples on each side tried
RIDGES = (1e-8, 1e-5, 1e-3, 1e-1)  # × the inputs' mean power
STRIDE = 10  # samples between training windows (a 60 s trial at 286 Hz gives 1,700)
SHAPES = ('causal', 'two-sided')


def trial_number(name):
    """The leading number of a BROAD trial's name (``'09_undisturbed_…'`` → 9)."""
    digits = ''.join(c for c in name.split('_')[0] if c.isdigit())
    return int(digits) if digits else 0


def split_even_odd(trials):
    """The even-numbered trials (to fit on) and the odd ones (to score on)."""
    even = [t for t in trials if trial_number(t.name) % 2 == 0]
    return even, [t for t in trials if trial_number(t.name) % 2 == 1]


def _after(shape, k):
    return 1 if shape == 'causal' else k


def windows(gyr, lost, before, after, stride=STRIDE):
    """
    Inputs ``(n, before + after)`` and targets ``(n, lost)`` of every ``stride``-th window.

    A row per window and axis: the window's first ``before`` and last
    ``after`` rates, and the ``lost`` rates between them (windows with a
    missing rate left out).
    """
    total = before + lost + after
    starts = np.arange(0, len(gyr) - total + 1, stride)
    w = gyr[starts[:, None] + np.arange(total)]  # (windows, total, 3)
    w = w[np.isfinite(w).all(axis=(1, 2))].transpose(0, 2, 1).reshape(-1, total)
    inputs = np.concatenate([w[:, :before], w[:, before + lost:]], axis=1)
    return inputs, w[:, before:before + lost]


_SUMS = {}  # (trials' names, lost, before, after) → _sums: the shapes and Ks share them


def _sums(trials, lost, before, after):
    """The normal equations' sums ``XᵀX``, ``XᵀY`` and ``1ᵀYᵀY1`` over the trials' windows."""
    key = (tuple(t.name for t in trials), lost, before, after)
    if key not in _SUMS:
        _SUMS[key] = _window_sums(trials, lost, before, after)
    return _SUMS[key]


def _window_sums(trials, lost, before, after):
    p = before + after
    xx, xy, yy, n = np.zeros((p, p)), np.zeros((p, lost)), 0.0, 0
    for t in trials:
        x, y = windows(t.gyr, lost, before, after)
        xx += x.T @ x
        xy += x.T @ y
        yy += float(np.sum(y.sum(axis=1) ** 2))
        n += len(x)
    return xx, xy, yy, n


def _solve(xx, xy, ridge):
    scale = ridge * np.trace(xx) / len(xx)
    return np.linalg.solve(xx + scale * np.eye(len(xx)), xy)


def _turn_mse(weights, sums):
    """The mean square error of the lost rates' sum (one axis) under ``weights``, from ``sums``."""
    xx, xy, yy, n = sums
    s = weights.sum(axis=1)
    return float((s @ xx @ s - 2.0 * s @ xy.sum(axis=1) + yy) / max(n, 1))


class MotionModel:
    """
    The fitted maps of one shape per hole length, ``K`` and ridge chosen on the training trials.

    ``MotionModel(train, shape)``; ``predict(gyr, i0, i1)`` gives the rates
    lost between the kept samples ``i0`` and ``i1`` (``(i1 − i0 − 1, 3)``);
    ``chosen[lost]`` the ``(K, ridge, validation RMS)`` of each length (the
    error of the lost rates' sum, rad/s, per axis) and
    ``ks`` restricts the ``K`` tried (one ``K``: that ``K``'s best ridge).
    """

    def __init__(self, train, shape, ks=KS, ridges=RIDGES):
        self.train, self.shape, self.ks, self.ridges = list(train), shape, tuple(ks), ridges
        self.fits, self.chosen = {}, {}

    def _fit(self, lost):
        folds = (self.train[0::2], self.train[1::2])
        best = None
        for k in self.ks:
            before, after = k, _after(self.shape, k)
            sums = [_sums(f, lost, before, after) for f in folds]
            for ridge in self.ridges:
                mse = sum(_turn_mse(_solve(a[0], a[1], ridge), b) * b[3]
                          for a, b in ((sums[0], sums[1]), (sums[1], sums[0])))
                mse /= max(sums[0][3] + sums[1][3], 1)
                if best is None or mse < best[2]:
                    whole = [a + b for a, b in zip(sums[0][:2], sums[1][:2])]
                    best = (k, ridge, mse, _solve(whole[0], whole[1], ridge))
        k, ridge, mse, weights = best
        self.chosen[lost] = (k, ridge, math.sqrt(max(mse, 0.0)))  # (rounding: from sums)
        self.fits[lost] = (k, _after(self.shape, k), weights)

    def reach(self, lost):
        """How many samples from the first after the hole the map of ``lost`` reads (1: causal)."""
        if lost not in self.fits:
            self._fit(lost)
        return self.fits[lost][1]

    def predict(self, gyr, i0, i1):
        """The rates (rad/s, ``(i1 − i0 − 1, 3)``) lost between the samples ``i0`` and ``i1``."""
        lost = int(i1 - i0 - 1)
        if lost not in self.fits:
            self._fit(lost)
        before, after, weights = self.fits[lost]
        # (Indices held inside the recording: a hole at its very start or end repeats the edge.)
        rows = np.clip(np.r_[i0 - before + 1:i0 + 1, i1:i1 + after], 0, len(gyr) - 1)
        return (gyr[rows].T @ weights).T
