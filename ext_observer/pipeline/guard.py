"""
The divergence guard around the core's observer; no ROS.

:class:`GuardedObserver` runs a :class:`~ext_observer.core.SingleObserver`
step by step and checks every new estimate with
:func:`~ext_observer.core.validation.check_state` (the one divergence rule):
if ``|q̂̄q̂ − 1|`` exceeds ``max_residual``, the innovation ``‖y − q̂‖`` exceeds
``max_innovation``, the estimate is not finite or (nearly) zero, or the
step raised (the ``projected`` variant at a zero quaternion), the observer
is reinitialized from the latest valid measurement, carried forward by the
increments since it arrived (``y ⊗ exp(θ/2) ⊗ …``, so that it is an
attitude at the same time as the estimate), or from its initial estimate
when no measurement came yet. Whatever the inputs, the estimate it returns
is finite and nonzero.

The inputs are expected validated (:mod:`ext_observer.pipeline.pairing`): finite
increments with ``‖θ‖`` bounded, unit measurements.
"""

import math

from ext_observer.core.validation import check_state

__all__ = ['GUARD_REASONS', 'GuardedObserver', 'carried']

# Why the observer was reinitialized.
GUARD_REASONS = ('residual_too_large', 'innovation_too_large', 'state_non_finite',
                 'state_zero', 'step_failed')


def _rotation(theta):
    # exp(θ/2) as (w, x, y, z), the same formula as the core's float path.
    hx, hy, hz = 0.5 * theta[0], 0.5 * theta[1], 0.5 * theta[2]
    a = math.sqrt(hx * hx + hy * hy + hz * hz)
    s = 1.0 - a * a / 6.0 if a < 1e-4 else math.sin(a) / a
    return (math.cos(a), s * hx, s * hy, s * hz)


def carried(q, theta):
    """Return the unit quaternion ``q ⊗ exp(θ/2)`` (``q`` unit, ``θ`` rad)."""
    pw, px, py, pz = q
    qw, qx, qy, qz = _rotation(theta)
    rw = pw * qw - px * qx - py * qy - pz * qz
    rx = pw * qx + px * qw + py * qz - pz * qy
    ry = pw * qy - px * qz + py * qw + pz * qx
    rz = pw * qz + px * qy - py * qx + pz * qw
    n = math.sqrt(rw * rw + rx * rx + ry * ry + rz * rz)
    return (rw / n, rx / n, ry / n, rz / n)


class GuardedObserver:
    """
    A :class:`~ext_observer.core.SingleObserver` that never diverges silently.

    Parameters
    ----------
    observer : ext_observer.core.SingleObserver
    max_residual : float
        Largest accepted ``|q̂̄q̂ − 1|`` after a step.
    max_innovation : float
        Largest accepted ``‖y − q̂‖`` (``y`` after sign alignment, if the
        observer aligns).

    Attributes
    ----------
    observer : ext_observer.core.SingleObserver
    latest : tuple of 4 float or None
        The latest measurement, carried forward to the current step.

    """

    def __init__(self, observer, max_residual=15.0, max_innovation=5.0):
        self.observer = observer
        self.max_residual = max_residual
        self.max_innovation = max_innovation
        self.latest = None

    @property
    def state(self):
        """The current estimate ``q̂`` (tuple of 4 float)."""
        return self.observer.state

    def reset(self, initial=None):
        """Restart the observer (default: its initial estimate); forget ``latest``."""
        self.observer.reset(initial)
        self.latest = None

    def step(self, increment, measurement=None):
        """
        Advance by one step; reinitialize if the estimate diverged.

        Parameters
        ----------
        increment : sequence of 3 float
            ``θ_k``, rad, finite.
        measurement : sequence of 4 float, optional
            ``y_k``, unit norm.

        Returns
        -------
        state : tuple of 4 float
            ``q̂_{k+1}``, finite.
        reason : str or None
            Why the observer was reinitialized (:data:`GUARD_REASONS`).

        """
        observer = self.observer
        innovation = None
        if measurement is not None:
            # Plain expressions, not sum() over generators: this runs per step.
            q0, q1, q2, q3 = observer.state
            y0, y1, y2, y3 = measurement
            if observer.config.align_sign and y0 * q0 + y1 * q1 + y2 * q2 + y3 * q3 < 0.0:
                y0, y1, y2, y3 = -y0, -y1, -y2, -y3
            d0, d1, d2, d3 = y0 - q0, y1 - q1, y2 - q2, y3 - q3
            innovation = math.sqrt(d0 * d0 + d1 * d1 + d2 * d2 + d3 * d3)
            self.latest = (y0, y1, y2, y3)
        try:
            state = observer.step(increment, measurement)
        except (ValueError, OverflowError, ZeroDivisionError):
            reason = 'step_failed'
        else:
            reason = check_state(state, innovation, self.max_residual, self.max_innovation)
        if self.latest is not None:
            self.latest = carried(self.latest, increment)
        if reason is not None:
            self.observer.reset(self.latest)
            state = self.observer.state
        return state, reason
