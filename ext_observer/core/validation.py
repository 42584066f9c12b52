"""
Input validation for the observers: reject bad input before it touches the state.

Each check returns a *reason* (a short snake_case string, used as a counter
key in diagnostics) or ``None`` when the input is valid. They work on plain
Python floats, as the ROS node receives them, and cost about a microsecond.

Reasons
-------
non_finite
    A NaN or an infinity in the input.
zero_quaternion
    A measurement whose norm is below ``MIN_NORM`` (no direction).
norm_out_of_tolerance
    A measurement with ``|‖y‖ − 1|`` above the tolerance (an absurd norm).
increment_too_large
    An increment whose angle ``‖θ‖`` exceeds the bound (rad).
zero_vector
    A direction (specific force, magnetic field) whose norm is below the
    bound: no direction.
state_non_finite, residual_too_large, innovation_too_large, state_zero
    The divergence guard on the estimate (see :func:`check_state`).
"""

import math

__all__ = [
    'MIN_NORM',
    'check_increment',
    'check_measurement',
    'check_state',
    'check_vector',
]

MIN_NORM = 1e-6


def check_increment(increment, max_increment):
    """
    Check a rotation increment ``θ`` (rad).

    Parameters
    ----------
    increment : sequence of 3 float
    max_increment : float
        Largest accepted ``‖θ‖``, rad.

    Returns
    -------
    reason : str or None

    """
    x, y, z = increment
    n2 = x * x + y * y + z * z
    if not math.isfinite(n2):
        # Also catches overflow of finite but huge components.
        return 'non_finite' if not all(map(math.isfinite, increment)) \
            else 'increment_too_large'
    if n2 > max_increment * max_increment:
        return 'increment_too_large'
    return None


def check_measurement(measurement, norm_tolerance):
    """
    Check a measured attitude and normalize it.

    Parameters
    ----------
    measurement : sequence of 4 float
        ``(w, x, y, z)``.
    norm_tolerance : float
        Largest accepted ``|‖y‖ − 1|``; within it, ``y`` is normalized.

    Returns
    -------
    unit : tuple of 4 float or None
        The normalized measurement, or None when rejected.
    reason : str or None

    """
    w, x, y, z = measurement
    n2 = w * w + x * x + y * y + z * z
    if not math.isfinite(n2):
        if not (math.isfinite(w) and math.isfinite(x) and math.isfinite(y)
                and math.isfinite(z)):
            return None, 'non_finite'
        # Finite but huge components: their norm is surely out of tolerance.
        return None, 'norm_out_of_tolerance'
    n = math.sqrt(n2)
    if n < MIN_NORM:
        return None, 'zero_quaternion'
    if abs(n - 1.0) > norm_tolerance:
        return None, 'norm_out_of_tolerance'
    return (w / n, x / n, y / n, z / n), None


def check_vector(vector, min_norm):
    """
    Check a measured direction: a specific force or a magnetic field.

    Parameters
    ----------
    vector : sequence of 3 float
        In its own unit (m/s², T, ...).
    min_norm : float
        Smallest accepted norm, in the same unit.

    Returns
    -------
    reason : str or None
        ``non_finite``, ``zero_vector`` or None.

    """
    x, y, z = vector
    if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(z)):
        return 'non_finite'
    # hypot neither underflows nor overflows on finite components.
    if math.hypot(x, y, z) < min_norm:
        return 'zero_vector'
    return None


def check_state(state, innovation_norm=None, max_residual=math.inf,
                max_innovation=math.inf):
    """
    Divergence guard on an estimate ``q̂``: the one rule of every guard.

    :class:`~ext_observer.pipeline.guard.GuardedObserver` and the raw-IMU
    pipeline call it; the compiled sample step
    (:func:`~ext_observer.core.ahrs.uncertainty_kernel.sample_step`) checks
    its first two reasons in numba, as integer outcomes mapped to these names.

    Parameters
    ----------
    state : sequence of 4 float
    innovation_norm : float, optional
        ``‖y − q̂‖`` of the last update.
    max_residual : float
        Largest accepted ``|q̂̄q̂ − 1|``.
    max_innovation : float
        Largest accepted innovation norm.

    Returns
    -------
    reason : str or None
        ``state_non_finite``, ``residual_too_large``,
        ``innovation_too_large``, ``state_zero`` (``‖q̂‖`` below
        :data:`MIN_NORM`) or None.

    """
    w, x, y, z = state
    n2 = w * w + x * x + y * y + z * z
    if not math.isfinite(n2):
        return 'state_non_finite'
    if abs(n2 - 1.0) > max_residual:
        return 'residual_too_large'
    if innovation_norm is not None and innovation_norm > max_innovation:
        return 'innovation_too_large'
    # 0 is a fixed point of every observer variant without measurements, and
    # has no attitude: as bad as a divergence.
    if n2 < MIN_NORM * MIN_NORM:
        return 'state_zero'
    return None
