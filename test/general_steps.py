"""
The one-call sample's parts one call each: what the tests compare ``sample_step`` with.

The pipeline runs a usual sample in one call
(:func:`~ext_observer.core.ahrs.uncertainty_kernel.sample_step`); here the
core's step, the guard and the covariance's step run one after the other
through the wrappers, as an independent form of the same sample.
"""

from ext_observer.core.quaternion import multiply_floats
from ext_observer.core.validation import check_state


def general_step(estimator, gyr, acc, dt):
    """One sample of a :class:`~ext_observer.pipeline.raw_imu.RawImuEstimator`, a call per part."""
    core = estimator.core
    if not core.initialized:
        return estimator._initialize(gyr, acc, dt)
    q = core.update(gyr, acc, None, dt)
    reason = check_state(q, None, estimator.max_residual)
    if reason is not None:
        return estimator._initialize(gyr, acc, dt, reason)
    hole, step_dt = core.hole_variance, core.step_interval
    estimator.uncertainty.step(step_dt, gyr, q, core.rest, core.bias_variance,
                               core.clip_variance, acc,
                               (dt - step_dt, hole, core.hole_restart) if hole != 0.0 else None)
    return (q if estimator.frame is None else multiply_floats(estimator.frame, q)), None
