"""
What :class:`~ext_observer.pipeline.pairing.StepPairer` deals in, apart from its rules.

The kinds of input, why one is dropped (the keys of its ``drops``), the
events it counts, the smallest vectors it accepts, and :data:`Step`, what it
releases. Every name is also importable from :mod:`ext_observer.pipeline.pairing`.
"""

from collections import namedtuple

__all__ = ['BACKWARD_JUMP', 'DROP_REASONS', 'EVENTS', 'INCREMENT_DROP_REASONS', 'KINDS',
           'MEASUREMENT_DROP_REASONS', 'MIN_ACCELERATION', 'MIN_FIELD', 'Step', 'VALUE_REASONS']

KINDS = ('increment', 'measurement')

# Why an input was dropped, by kind; the keys of StepPairer.drops.
INCREMENT_DROP_REASONS = (
    'non_finite_increment',     # a NaN or an infinity
    'increment_too_large',      # ‖θ‖ above max_increment
    'zero_stamp_increment',     # stamp zero or negative
    'stale_increment',          # older than the last step
    'duplicate_increment',      # the stamp of a step done or waiting
    'discarded_increment',      # waiting when the time line restarted
    'dt_too_large',             # IMU sample: the next one more than max_dt later
    'non_finite_acceleration',  # IMU sample for the raw-IMU estimator: a NaN or an infinity
    'zero_acceleration',        # ... or no specific force (norm below MIN_ACCELERATION)
)
MEASUREMENT_DROP_REASONS = (
    'non_finite_measurement',   # a NaN or an infinity
    'zero_quaternion',          # norm below validation.MIN_NORM
    'norm_out_of_tolerance',    # |‖y‖ − 1| above norm_tolerance
    'zero_stamp_measurement',
    'stale_measurement',        # older than the last step, or late for it
    'duplicate_measurement',
    'unpaired_measurement',     # no increment of its stamp came in time
    'discarded_measurement',
    'no_orientation',           # sensor_msgs/Imu without orientation (covariance[0] = −1)
    'zero_field',               # magnetic field with norm below MIN_FIELD
)
DROP_REASONS = INCREMENT_DROP_REASONS + MEASUREMENT_DROP_REASONS

# Smallest accepted specific force (m/s²) and magnetic field (T): below,
# the vector has no direction (a driver that leaves the field at zero).
MIN_ACCELERATION = 1e-6
MIN_FIELD = 1e-9

# Counted events that drop nothing.
EVENTS = ('backward_jumps', 'forward_gaps', 'early_releases')

# Returned by add_increment/add_measurement: accepted after a backward jump.
BACKWARD_JUMP = 'backward_jump'

VALUE_REASONS = {
    'increment': {'non_finite': 'non_finite_increment',
                  'increment_too_large': 'increment_too_large'},
    'measurement': {'non_finite': 'non_finite_measurement',
                    'zero_quaternion': 'zero_quaternion',
                    'norm_out_of_tolerance': 'norm_out_of_tolerance'},
}

Step = namedtuple('Step', 'stamp increment measurement previous gap early end',
                  defaults=(None,))
Step.__doc__ = """\
One step released by :class:`~ext_observer.pipeline.pairing.StepPairer`.

Attributes
----------
stamp : int
    ``t_k``, ns.
increment : tuple of 3 float
    ``θ_k``, rad, validated.
measurement : tuple of 4 float or None
    ``y_k`` (unit norm, scalar first), or None: propagate only.
previous : int or None
    Stamp of the step before (None for the first one of a time line).
gap : bool
    ``stamp − previous`` exceeds ``forward_gap``.
early : bool
    Released without waiting for its measurement because ``depth``
    increments were waiting behind it.
end : int or None
    ``t_{k+1}``, ns, for a step made from angular velocities (the stamp of
    the sample that closed its interval); None for a given increment.
"""
