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

from ext_observer.core.quaternion import multiply, quaternion_from_rotation_vector
from ext_observer.pipeline.batch import hold_finite
from ext_observer.recordings.pipeline_run import run_arrays

__all__ = ['combined', 'smoothed_attitude', 'time_reversed']


def smoothed_attitude(gyr, acc, mag, times, settings, *, mag_times=None, velocity=None,
                      velocity_times=None):
    """
    Return each IMU sample's attitude from the whole recording, and its σ.

    The interim smoother: ``imu_filter_node``'s estimator run forward and on
    the time-reversed recording (:func:`time_reversed`), the two estimates
    combined per sample by their published σ (:func:`combined`): the
    inclination; the heading and its σ are the forward run's (each run's
    heading refers to what it met first, the field where it started in 9D,
    its own start in 6D, and the two differ by degrees). The two runs'
    errors are correlated (the same samples), which this combination
    ignores: its σ is somewhat optimistic (on BROAD the inclination's mean
    e²/σ² is 1.3). It is the seam's working body until the smoother of
    ``ext_observer.core.ahrs`` replaces it.

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
        :func:`~ext_observer.recordings.recording.attitude_from_imu` takes it.

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
    inputs = (gyr, acc, mag, mag_times, velocity, velocity_times)
    # Only what the combination reads is kept of each run (memory: a long recording).
    forward = _estimate(run_arrays(settings, None, times, *inputs))
    reversed_times, reversed_inputs = time_reversed(times, *inputs)
    backward = _estimate(run_arrays(settings, None, reversed_times, *reversed_inputs))
    del reversed_times, reversed_inputs
    return combined(forward, tuple(a[::-1] for a in backward), heading=False)


def _estimate(recording):
    return recording.quaternions, recording.inclination_std, recording.heading_std


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


def combined(first, second, heading=True):
    """
    Return two estimates of the same samples combined by their σ: ``(q, σ_i, σ_h)``.

    The second's inclination error (the body's vertical) is taken by the
    weight ``σ₁² / (σ₁² + σ₂²)`` of the first's inclination σ, about the
    axis between the two verticals; then, with ``heading``, the heading
    about the world's vertical likewise; the σ as of two independent
    estimates, ``(σ₁⁻² + σ₂⁻²)^(−1/2)``. A sample without a σ (NaN: no
    estimate of its own) takes the other's estimate; without ``heading``,
    the heading and its σ are the first's (a row without its σ: held as
    the quaternion is, from the nearest before, or the first).

    Parameters
    ----------
    first, second : tuple
        ``(quaternions (N, 4), inclination_std (N,), heading_std (N,))``,
        unit quaternions sensor → world, rad.
    heading : bool

    """
    q1, i1, h1 = first
    q2, i2, h2 = second
    weight, inclination_std = _weights(i1, i2)
    up1, up2 = _body_vertical(q1), _body_vertical(q2)
    axis = np.cross(up1, up2)
    sine = np.linalg.norm(axis, axis=1)
    angle = np.arctan2(sine, np.einsum('ij,ij->i', up1, up2))
    with np.errstate(invalid='ignore', divide='ignore'):
        unit = np.where(sine[:, None] > 0.0, axis / sine[:, None], 0.0)
    # R = R₁ C with Cᵀ turning the first's vertical towards the second's.
    q = multiply(q1, quaternion_from_rotation_vector(-(weight * angle)[:, None] * unit))
    if heading:
        weight, heading_std = _weights(h1, h2)
        turn = multiply(q2, q * [1.0, -1.0, -1.0, -1.0])
        yaw = 2.0 * np.arctan2(turn[:, 3], turn[:, 0])
        yaw = (yaw + np.pi) % (2.0 * np.pi) - np.pi
        zeros = np.zeros_like(yaw)
        q = multiply(quaternion_from_rotation_vector(
            np.column_stack([zeros, zeros, weight * yaw])), q)
    else:
        heading_std = np.asarray(h1, dtype=float)
        if np.isnan(heading_std).any() and not np.isnan(heading_std).all():
            heading_std = hold_finite(heading_std[:, None])[:, 0]
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    return q, inclination_std, heading_std


def _weights(std1, std2):
    """The second's weight and the combined σ, where either σ may be NaN (none)."""
    with np.errstate(divide='ignore', invalid='ignore'):
        info1, info2 = (np.nan_to_num(1.0 / np.maximum(np.asarray(s, dtype=float), 1e-12) ** 2)
                        for s in (std1, std2))
        total = info1 + info2
        weight = np.where(total > 0.0, info2 / total, 0.0)
        std = np.where(total > 0.0, 1.0 / np.sqrt(total), std1)
    return weight, std


def _body_vertical(q):
    """The world's z axis in the sensor frame, ``Rᵀ e_z``, shape (N, 3)."""
    w, x, y, z = q.T
    return np.column_stack([2.0 * (x * z - w * y), 2.0 * (y * z + w * x),
                            w * w - x * x - y * y + z * z])
