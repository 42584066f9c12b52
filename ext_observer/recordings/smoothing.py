"""
The whole recording's attitude: a smoothed estimate (:func:`smoothed_attitude`).

The one place where ``attitude_from_imu(..., smooth=True)``, ``python -m
ext_observer csv --smooth`` and ``python -m ext_observer bag --smooth`` get
the estimate that uses the samples after each one too. They hand it the
inputs the online run had, as arrays, after that run (docs/own_data.md);
it returns each IMU sample's attitude and its σ. The smoother behind it may
change; what it is given and what it returns does not.

Conventions as :mod:`ext_observer.recordings.recording`'s: rad/s, m/s², T,
s; quaternions ``(w, x, y, z)``, sensor → ``world_frame``.
"""

import numpy as np

from ext_observer.core.ahrs.frames import world_from_enu
from ext_observer.core.ahrs.smoother import SmoothParams, smooth_attitude
from ext_observer.pipeline.batch import hold_finite
from ext_observer.pipeline.imu_filter_parameters import ahrs_params
from ext_observer.recordings.pipeline_run import run_arrays

__all__ = ['combined_std', 'field_per_sample', 'smoothed_attitude', 'time_reversed']


def smoothed_attitude(gyr, acc, mag, times, settings, *, mag_times=None, velocity=None,
                      velocity_times=None, online_std=None):
    """
    Return each IMU sample's attitude from the whole recording, and its σ.

    The attitude is :func:`~ext_observer.core.ahrs.smoother.smooth_attitude`'s
    (docs/offline.md: an online pass for the gyro bias and the field's
    calibration, a strapdown, zero-phase window averages for the
    inclination and the heading), with the node's ``ahrs.*`` parameters for
    its online pass, ``use_mag`` and the IMU's times (holes bridged from both
    sides), turned from ENU to ``world_frame``. It takes one field row per IMU
    sample: a field at the first sample at or after its time, NaN where none
    (:func:`field_per_sample`).

    The σ is the online covariance model's, from ``imu_filter_node``'s
    estimator run forward and on the time-reversed recording
    (:func:`time_reversed`): for the inclination and for the heading, the
    two runs' σ combined as of two independent estimates (:func:`combined_std`),
    as the smoothed estimate uses the samples on both sides. On BROAD's 22
    trials the smoothed estimate's mean e²/σ² is within 0.3–3 for both, on
    the tuning and on the held-out trials (docs/offline.md). The forward
    run is the caller's online run where it gives its σ (``online_std``);
    the backward one costs about as much; the smoother itself a fraction
    of that (docs/own_data.md).

    Parameters
    ----------
    gyr, acc : ndarray, shape (N, 3)
        Every IMU sample the online run took, in its order (a sample it
        dropped too): rad/s, m/s².
    mag : ndarray, shape (M, 3), or None
        T. With ``mag_times``, at its own times; without, row ``k`` belongs
        to IMU sample ``k`` (M = N; a row of NaN: no field there). None: 6D.
    times : ndarray, shape (N,)
        s, of each IMU sample (the online run's).
    settings : dict
        The node's settings (:func:`~ext_observer.recordings.recording.node_settings`):
        ``use_mag``, ``world_frame``, the estimator's parameters.
    mag_times : ndarray, shape (M,), optional
        s, on the IMU's clock.
    velocity, velocity_times : ndarray, optional
        The body's velocity, m/s, (V, 3), per IMU sample or at its own times
        (s), for the velocity aid, as
        :func:`~ext_observer.recordings.recording.attitude_from_imu` takes it:
        the σ's runs use it; the smoother does not (yet).
    online_std : tuple of ndarray, shape (N,), optional
        ``(inclination_std, heading_std)`` of the online run over these same
        inputs (:class:`~ext_observer.recordings.recording.Recording`'s), where
        the caller made one: the σ's forward run is then not run again.

    Returns
    -------
    quaternions : ndarray, shape (N, 4)
        Unit, sensor → ``world_frame``.
    inclination_std, heading_std : ndarray, shape (N,)
        rad, as :class:`~ext_observer.recordings.recording.Recording`'s
        (``imu/data``'s ``orientation_covariance`` is
        ``diag(σ_i² / 2, σ_i² / 2, σ_h²)``).

    """
    if mag is None:
        mag_times = None
    q = _smoothed(gyr, acc, mag, times, settings, mag_times)
    inputs = (gyr, acc, mag, mag_times, velocity, velocity_times)
    # Only the σ is kept of each run (memory: a long recording).
    if online_std is None:
        forward = _estimate(run_arrays(settings, None, times, *inputs))
    else:
        forward = (None, *online_std)
    reversed_times, reversed_inputs = time_reversed(times, *inputs)
    backward = _estimate(run_arrays(settings, None, reversed_times, *reversed_inputs))
    del reversed_times, reversed_inputs
    return (q, combined_std(forward[1], backward[1][::-1]),
            combined_std(forward[2], backward[2][::-1]))


def _smoothed(gyr, acc, mag, times, settings, mag_times):
    """:func:`~ext_observer.core.ahrs.smoother.smooth_attitude`'s estimate, in ``world_frame``."""
    times = np.asarray(times, dtype=float)
    # The samples the online run stepped on: each later than every one before
    # (a repeated or out-of-order stamp is dropped, as the node drops it); a
    # dropped row shows the estimate of the sample before it.
    kept = _increasing(times)
    if kept.sum() < 2:
        raise ValueError('the IMU times must increase somewhere to give a rate')
    use_mag = bool(settings['use_mag']) and mag is not None
    field = None
    if use_mag:  # fields placed among the kept samples' times (increasing)
        field = (np.asarray(mag, dtype=float)[kept] if mag_times is None
                 else field_per_sample(mag, mag_times, times[kept]))
    if field is not None and np.isnan(field).all():
        field = None  # no field at all: 6D
    params = SmoothParams(online=ahrs_params(settings))
    q, _ = smooth_attitude(hold_finite(np.asarray(gyr, dtype=float)[kept]),
                           hold_finite(np.asarray(acc, dtype=float)[kept]), field,
                           params=params, times=times[kept])
    rows = np.maximum.accumulate(np.where(kept, np.arange(len(times)), 0))
    q = q[np.cumsum(kept)[rows] - 1]
    return world_from_enu(q, settings['world_frame'])


def _increasing(times):
    """Where a time is later than every time before it (the first always), bool (N,)."""
    latest = np.maximum.accumulate(np.where(np.isfinite(times), times, -np.inf))
    kept = np.ones(len(times), dtype=bool)
    kept[1:] = times[1:] > latest[:-1]
    return kept


def field_per_sample(mag, mag_times, times):
    """
    One field row per IMU sample: a field at the first sample at or after its time.

    A row with no field there is NaN (a slower magnetometer, a field lost for
    a while: the smoother bridges those from the fields on both sides);
    several fields before one sample: the last of them.

    Parameters
    ----------
    mag : ndarray, shape (M, 3)
    mag_times : ndarray, shape (M,), or None
        s; None: ``mag`` has a row per IMU sample already (returned as it is).
    times : ndarray, shape (N,)
        s, the IMU samples', increasing.

    Returns
    -------
    ndarray, shape (N, 3)

    """
    mag = np.asarray(mag, dtype=float)
    if mag_times is None:
        return mag
    mag_times = np.asarray(mag_times, dtype=float)
    order = np.argsort(mag_times, kind='stable')
    at = np.searchsorted(np.asarray(times, dtype=float), mag_times[order], side='left')
    inside = at < len(times)
    at, fields = at[inside], mag[order][inside]
    # The last field for each sample: the last occurrence of each index.
    last = len(at) - 1 - np.unique(at[::-1], return_index=True)[1]
    out = np.full((len(times), 3), np.nan)
    out[at[last]] = fields[last]
    return out


def _estimate(recording):
    return None, recording.inclination_std, recording.heading_std


def time_reversed(times, gyr, acc, mag=None, mag_times=None, velocity=None,
                  velocity_times=None):
    """
    Return the recording played backwards: ``(times, (gyr, acc, mag, mag_times, ...))``.

    Times mirrored (``t₀ + t_last − t``, so the intervals are kept), rows in
    reverse. The rate turns its sign; sample ``k``'s rate covers the
    interval before it, which backwards is the one after it: the reversed
    sample at ``t_k`` carries ``−gyr[k + 1]`` (the last, ``−gyr[N − 1]``:
    the first sample only sets ``t₀``). The specific force and the field do
    not change; the velocity turns its sign.
    """
    times = np.asarray(times, dtype=float)
    mirror = times[0] + times[-1]
    back_gyr = -np.concatenate([gyr[1:], gyr[-1:]])[::-1]

    def timed(values, at, sign=1.0):
        if values is None:
            return None, None
        values = sign * np.asarray(values, dtype=float)[::-1]
        return values, None if at is None else mirror - np.asarray(at, dtype=float)[::-1]

    return mirror - times[::-1], (back_gyr, np.asarray(acc)[::-1], *timed(mag, mag_times),
                                  *timed(velocity, velocity_times, -1.0))


def combined_std(std1, std2):
    """
    Two independent estimates' σ combined, ``(σ₁⁻² + σ₂⁻²)^(−1/2)`` (N,).

    Where one has no σ (NaN: no estimate of its own), the other's; where
    neither has, the nearest before's (or the first's); an infinite σ1 with
    nothing to combine stays.
    """
    with np.errstate(divide='ignore', invalid='ignore'):
        total = sum(np.nan_to_num(1.0 / np.maximum(np.asarray(s, dtype=float), 1e-12) ** 2)
                    for s in (std1, std2))
        std = np.where(total > 0.0, 1.0 / np.sqrt(total), np.asarray(std1, dtype=float))
    if np.isnan(std).any() and not np.isnan(std).all():
        return hold_finite(std[:, None])[:, 0]
    return std
