"""
The velocity aid's input: a body velocity, checked and moved to the IMU's point and frame.

:meth:`RawImuPipeline.velocity <ext_observer.pipeline.raw_imu.RawImuPipeline.velocity>`
hands each velocity here; the core removes the acceleration it implies from
the specific force (:mod:`~ext_observer.core.ahrs.velocity_kernel`). A
velocity given in another frame (``velocity_mounting``, the IMU's orientation
in it) at another point (``velocity_lever_arm``, the IMU's position in it)
is the IMU's ``R^T (v + ω_v × r) = R^T v + ω × R^T r``, with ``ω`` the latest
IMU sample's rate less the bias: its derivative then carries the lever
arm's ``ω̇ × r`` and the rotation's ``ω × (ω × r)``.
"""

import math

from ext_observer.pipeline.imu_filter_parameters import velocity_frame

__all__ = ['VelocityInput', 'with_velocity']


class VelocityInput:
    """
    Velocities in (ns, m/s in the velocity's frame), the IMU's to the estimator.

    Parameters
    ----------
    estimator : ext_observer.pipeline.raw_imu.RawImuEstimator
    settings : dict
        ``velocity_timeout``, ``velocity_mounting``, ``velocity_lever_arm``
        (those missing: the defaults, the IMU's own frame).
    """

    def __init__(self, estimator, settings):
        self.estimator = estimator
        self.stamp = None
        self.configure(settings)

    def configure(self, settings):
        """Take the frame and the timeout."""
        self.frame = (velocity_frame(settings) if 'velocity_mounting' in settings else None)
        if 'velocity_timeout' in settings:
            self.estimator.core.velocity_timeout = float(settings['velocity_timeout'])

    def take(self, stamp, velocity):
        """One velocity; None if taken, else why dropped (``'not_finite'``, ``'out_of_order'``)."""
        v = tuple(float(c) for c in velocity)
        if len(v) != 3 or not all(math.isfinite(c) for c in v):
            return 'not_finite'
        if self.stamp is not None and stamp <= self.stamp:
            return 'out_of_order'
        dt = None if self.stamp is None else (stamp - self.stamp) * 1e-9
        self.stamp = stamp
        if self.frame is not None:
            v = self._at_imu(v)
        self.estimator.velocity(v, dt)
        return None

    def _at_imu(self, v):
        rt, (ax, ay, az) = self.frame
        core = self.estimator.core
        last, bias = core.field('gyro.last'), core.field('bias.rate')
        wx, wy, wz = (last[i] - bias[i] for i in range(3))
        return (rt[0] * v[0] + rt[1] * v[1] + rt[2] * v[2] + wy * az - wz * ay,
                rt[3] * v[0] + rt[4] * v[1] + rt[5] * v[2] + wz * ax - wx * az,
                rt[6] * v[0] + rt[7] * v[1] + rt[8] * v[2] + wx * ay - wy * ax)


def with_velocity(events, stamps, velocity_stamps):
    """
    Batch events ``(kind, index)`` with ``(2, j)`` for velocity ``j``.

    Each velocity comes before the first IMU sample at or after it.

    IMU samples are kind 0 at ``stamps[index]``; ``velocity_stamps`` ascending.
    """
    j, n = 0, len(velocity_stamps)
    for kind, i in events:
        if kind == 0:
            while j < n and velocity_stamps[j] <= stamps[i]:
                yield 2, j
                j += 1
        yield kind, i
