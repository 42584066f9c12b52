"""
The unit check of a whole recording: refuse magnitudes that only a wrong unit explains.

:func:`~ext_observer.recordings.recording.attitude_from_imu` runs it before
the estimator, on typical samples, with the node's own check.
"""

import numpy as np

from ext_observer.pipeline.units import ACC_WINDOW, UnitCheck

__all__ = ['GYRO_PERCENTILE', 'check_units']

# Percentile of the per-sample largest |angular rate| that the unit check
# looks at: a few fast samples are motion, most of them a unit.
GYRO_PERCENTILE = 99.0


def _typical(rows, norms, quantile):
    finite = np.isfinite(norms)
    if not finite.any():
        return None
    order = np.argsort(np.where(finite, norms, np.inf))[:int(finite.sum())]
    return tuple(rows[order[int(quantile * (len(order) - 1))]])


def check_units(gyr, acc, mag):
    """
    Refuse the units the node would warn of, judged on typical samples.

    The node's own check (:class:`~ext_observer.pipeline.units.UnitCheck`) sees the
    median specific force (as a window of samples), the sample whose largest
    rate is at :data:`GYRO_PERCENTILE`, and the median field.
    """
    check = UnitCheck()
    acc_row = _typical(acc, np.linalg.norm(acc, axis=1), 0.5)
    gyr_row = _typical(gyr, np.abs(gyr).max(axis=1), GYRO_PERCENTILE / 100.0)
    if acc_row is not None and gyr_row is not None:
        for _ in range(ACC_WINDOW):
            check.imu(gyr_row, acc_row)
    if mag is not None:
        mag_row = _typical(mag, np.linalg.norm(mag, axis=1), 0.5)
        if mag_row is not None:
            check.field(mag_row)
    names = {'angular_velocity': 'gyr', 'acceleration': 'acc', 'field': 'mag'}
    found = [f'{names[kind]}: {text}' for kind, text in check.findings.items()]
    if found:
        raise ValueError('; '.join(found) + ' (check_units=False runs it as it is)')
