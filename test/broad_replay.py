"""
The BROAD excerpts of test/data/ and what the core makes of them offline.

:func:`load` reads an excerpt (``test/data/broad_<trial>.npz``, see
``test/data/README.md``). :func:`offline` runs the core's raw-IMU estimator
on floats exactly as ``imu_filter_node`` runs it on the replayed messages:
sample 0 only starts the time line, sample ``k ≥ 1`` is one ``update`` with ``dt = t_k − t_{k−1}`` (from the
integer nanosecond stamps, as the node computes it), and the field of every
``mag_every``-th sample (T) arrives after that sample, with the interval
since the previous field as its ``dt`` (before the first step it is kept
for the initialization). :func:`errors_deg` scores an estimate
against the optical reference as BROAD does (the total angle of
``q̂ ⊗ q_ref⁻¹``, over the ``movement`` samples with a finite reference).
"""

import math
import os

import numpy as np

from ext_observer.core.ahrs.ahrs_observer import AhrsObserver, AhrsParams, world_from_enu

DATA = os.path.join(os.path.dirname(os.path.abspath(__file__)), 'data')
TRIALS = ('01_undisturbed_slow_rotation_A', '28_disturbed_stationary_magnet_A')
SECOND = 1_000_000_000
START = 1000 * SECOND  # stamp of sample 0, ns
TESLA_PER_MICROTESLA = 1e-6


def load(trial):
    """Return the excerpt of ``trial`` as a dict of arrays (see make_excerpt.py)."""
    with np.load(os.path.join(DATA, f'broad_{trial}.npz')) as data:
        return {key: data[key] for key in data.files}


def stamps(count, rate):
    """Return the stamps of ``count`` samples at ``rate`` Hz from START, integer ns."""
    return [START + round(k * SECOND / rate) for k in range(count)]


def fields_tesla(data):
    """Return the excerpt's field in tesla, as a sensor_msgs/MagneticField carries it."""
    return data['mag'] * TESLA_PER_MICROTESLA


def offline(data, mag_every=3, use_mag=True, world_frame='enu', params=None):
    """
    Run the core on floats as the node does; return the ambient estimates.

    Parameters
    ----------
    data : dict
        An excerpt (:func:`load`).
    mag_every : int
        The field of sample ``k`` is used when ``k % mag_every == 0``.
    use_mag : bool
    world_frame : str
    params : AhrsParams, optional

    Returns
    -------
    estimates : ndarray, shape (N, 4)
        The estimate after sample ``k`` in ``world_frame`` (ambient, not
        normalized); NaN for sample 0.

    """
    gyr = [tuple(map(float, row)) for row in data['gyr']]
    acc = [tuple(map(float, row)) for row in data['acc']]
    mag = [tuple(map(float, row)) for row in fields_tesla(data)]
    times = stamps(len(gyr), float(data['rate']))
    core = AhrsObserver(params=params if params is not None else AhrsParams(),
                        use_mag=use_mag)
    latest = previous = None
    out = np.full((len(gyr), 4), np.nan)
    for k in range(len(gyr)):
        if k > 0:
            dt = (times[k] - times[k - 1]) * 1e-9
            out[k] = core.update(gyr[k], acc[k], latest if core.q is None else None, dt)
        if use_mag and k % mag_every == 0:
            latest = mag[k]
            if core.q is not None:
                # The interval since the previous field.
                core.update_mag(latest, None if previous is None
                                else (times[k] - previous) * 1e-9)
            previous = times[k]
    if world_frame != 'enu':
        out[1:] = world_from_enu(out[1:], world_frame)
    return out


def errors_deg(estimates, data):
    """
    Return the angles (deg) between the estimates and the optical reference.

    Parameters
    ----------
    estimates : ndarray, shape (N, 4)
        Sensor → ENU, any norm; NaN rows are skipped.
    data : dict
        The excerpt.

    Returns
    -------
    angles : ndarray
        One per scored sample: ``movement``, finite reference and estimate.

    """
    q = np.asarray(estimates, dtype=float)
    ref = np.asarray(data['opt_quat'], dtype=float)
    ok = data['movement'] & np.isfinite(ref).all(axis=1) & np.isfinite(q).all(axis=1)
    q = q[ok] / np.linalg.norm(q[ok], axis=1, keepdims=True)
    ref = ref[ok] / np.linalg.norm(ref[ok], axis=1, keepdims=True)
    # |w| of q ⊗ ref⁻¹ is |q · ref|.
    dot = np.clip(np.abs(np.sum(q * ref, axis=1)), 0.0, 1.0)
    return np.degrees(2.0 * np.arccos(dot))


def rmse(angles):
    """Return the root mean square of ``angles``."""
    return math.sqrt(float(np.mean(np.square(angles))))
