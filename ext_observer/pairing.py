"""
Increments and measurements into observer steps, in stamp order; no ROS.

Step k needs the increment ``θ_k`` (rad, the body rotation over
``[t_k, t_{k+1})``) and, when it comes, the measurement ``y_k``; both carry
the stamp ``t_k`` as integer nanoseconds. :class:`StepPairer` takes the
inputs as they arrive, in any order and of any quality, and releases the
steps in stamp order. The node calls it and runs the observer; the rules
live here so that they can be tested without ROS (``test/test_pairing.py``,
with hypothesis).

Rules, in the order they are applied to an input:

1. Values: an increment goes through
   :func:`~ext_observer.core.validation.check_increment` (``‖θ‖`` at most
   ``max_increment``), a measurement through
   :func:`~ext_observer.core.validation.check_measurement` (within
   ``norm_tolerance`` of unit norm it is normalized, else rejected).
2. Stamps: zero or negative stamps are dropped. An input whose stamp is not
   newer than the last step released is ``duplicate`` if that step already
   used one like it, ``stale`` otherwise; so is a second input with the stamp
   of one still waiting. An input older than the last step by more than
   ``backward_jump`` (ns) is not stale but a *backward jump* (a bag that
   restarts, a simulation reset): the waiting inputs are discarded, the time
   line starts over, and :data:`BACKWARD_JUMP` tells the caller to reset the
   observer.
3. Pairing: an increment waits for the measurement of its stamp until its
   deadline (``now + timeout`` at arrival), or until a newer measurement
   shows that its own is not coming (a publisher sends in stamp order); then
   its step goes on without a measurement. A measurement waits until a step
   as new as it is released (then it is dropped as ``unpaired``).
4. Bounds: at most ``depth`` increments and ``depth`` measurements wait. One
   more measurement drops the oldest (``unpaired``); one more increment
   releases the oldest step at once, without its measurement, rather than
   losing a rotation of the body (counted in :attr:`StepPairer.events` as
   ``early_releases``).
5. A released step whose stamp is more than ``forward_gap`` (ns) after the
   previous one has ``gap`` set (counted as ``forward_gaps``); the caller
   decides whether that resets the observer.

Accounting: for each kind (``increment``, ``measurement``), ``received =
processed + dropped + waiting`` at all times (:meth:`StepPairer.accounted`),
with the drops by reason in :attr:`StepPairer.drops` (:data:`DROP_REASONS`).

Other sources of increments (issue 8: an IMU whose angular rates are
integrated into ``θ`` between samples) plug in by calling
:meth:`StepPairer.add_increment` with ``θ`` over ``[t_k, t_{k+1})`` stamped
``t_k``; measurements at a lower rate than the increments are handled by
rule 3 (each step without one propagates). Matching a measurement to a step
is :meth:`StepPairer._take_measurement` (equal stamps); a source whose
measurement stamps fall between step stamps replaces that one method.
"""

from collections import namedtuple

from ext_observer.core.validation import check_increment, check_measurement

__all__ = ['BACKWARD_JUMP', 'DROP_REASONS', 'KINDS', 'Step', 'StepPairer']

KINDS = ('increment', 'measurement')

# Why an input was dropped, by kind; the keys of StepPairer.drops.
INCREMENT_DROP_REASONS = (
    'non_finite_increment',     # a NaN or an infinity
    'increment_too_large',      # ‖θ‖ above max_increment
    'zero_stamp_increment',     # stamp zero or negative
    'stale_increment',          # older than the last step
    'duplicate_increment',      # the stamp of a step done or waiting
    'discarded_increment',      # waiting when the time line restarted
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
)
DROP_REASONS = INCREMENT_DROP_REASONS + MEASUREMENT_DROP_REASONS

# Counted events that drop nothing.
EVENTS = ('backward_jumps', 'forward_gaps', 'early_releases')

# Returned by add_increment/add_measurement: accepted after a backward jump.
BACKWARD_JUMP = 'backward_jump'

_VALUE_REASONS = {
    'increment': {'non_finite': 'non_finite_increment',
                  'increment_too_large': 'increment_too_large'},
    'measurement': {'non_finite': 'non_finite_measurement',
                    'zero_quaternion': 'zero_quaternion',
                    'norm_out_of_tolerance': 'norm_out_of_tolerance'},
}

Step = namedtuple('Step', 'stamp increment measurement previous gap early')
Step.__doc__ = """\
One step released by :class:`StepPairer`.

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
"""


class StepPairer:
    """
    Validate, order and pair the inputs of the observer; count every one.

    Parameters
    ----------
    depth : int
        Most increments, and most measurements, waiting at once (>= 1).
    timeout : int
        Longest wait of an increment for its measurement, ns (>= 0).
    max_increment : float
        Largest accepted ``‖θ‖``, rad.
    norm_tolerance : float
        Largest accepted ``|‖y‖ − 1|``.
    backward_jump : int
        An input older than the last step by more than this (ns) restarts
        the time line instead of being dropped as stale.
    forward_gap : int
        A step more than this (ns) after the previous one is flagged ``gap``.

    Attributes
    ----------
    received, processed : dict
        Inputs by kind (:data:`KINDS`); an increment is processed when its
        step is released, a measurement when it is used by one.
    drops : dict
        Inputs dropped, by reason (:data:`DROP_REASONS`).
    events : dict
        ``backward_jumps``, ``forward_gaps``, ``early_releases``.

    """

    def __init__(self, depth=10, timeout=100_000_000, max_increment=20.0,
                 norm_tolerance=0.1, backward_jump=1_000_000_000,
                 forward_gap=1_000_000_000):
        self.configure(depth=depth, timeout=timeout, max_increment=max_increment,
                       norm_tolerance=norm_tolerance, backward_jump=backward_jump,
                       forward_gap=forward_gap)
        self.received = dict.fromkeys(KINDS, 0)
        self.processed = dict.fromkeys(KINDS, 0)
        self.drops = dict.fromkeys(DROP_REASONS, 0)
        self.events = dict.fromkeys(EVENTS, 0)
        # stamp -> (increment, deadline); stamp -> measurement
        self._increments = {}
        self._measurements = {}
        self._last_stamp = None
        self._last_corrected = False

    def configure(self, **settings):
        """
        Change settings (the constructor's keywords); waiting inputs stay.

        Raises
        ------
        ValueError
            For a negative bound or a depth below 1.
        """
        for name, value in settings.items():
            if name not in ('depth', 'timeout', 'max_increment', 'norm_tolerance',
                            'backward_jump', 'forward_gap'):
                raise TypeError(f'unknown setting {name!r}')
            if not value >= (1 if name == 'depth' else 0):
                raise ValueError(f'{name} must not be negative (depth: >= 1), got {value}')
            setattr(self, name, value)

    # Inputs -----------------------------------------------------------------

    def add_increment(self, stamp, increment, now):
        """
        Take ``θ_k`` stamped ``t_k``.

        Parameters
        ----------
        stamp : int
            ``t_k``, ns.
        increment : sequence of 3 float
            ``θ_k``, rad.
        now : int
            The caller's clock, ns: the deadline is ``now + timeout``.

        Returns
        -------
        outcome : str or None
            None when accepted; the drop reason when dropped;
            :data:`BACKWARD_JUMP` when accepted as the first input of a new
            time line (the observer should be reset).

        """
        self.received['increment'] += 1
        reason = check_increment(increment, self.max_increment)
        if reason is not None:
            return self._drop(_VALUE_REASONS['increment'][reason])
        outcome = self._check_stamp(stamp, self._increments, 'increment')
        if outcome is not None and outcome != BACKWARD_JUMP:
            return self._drop(outcome)
        self._increments[stamp] = (tuple(increment), now + self.timeout)
        return outcome

    def add_measurement(self, stamp, measurement):
        """
        Take ``y_k`` stamped ``t_k``; see :meth:`add_increment`.

        Parameters
        ----------
        stamp : int
        measurement : sequence of 4 float
            ``(w, x, y, z)``; normalized when accepted.

        Returns
        -------
        outcome : str or None

        """
        self.received['measurement'] += 1
        unit, reason = check_measurement(measurement, self.norm_tolerance)
        if reason is not None:
            return self._drop(_VALUE_REASONS['measurement'][reason])
        outcome = self._check_stamp(stamp, self._measurements, 'measurement')
        if outcome is not None and outcome != BACKWARD_JUMP:
            return self._drop(outcome)
        self._measurements[stamp] = unit
        while len(self._measurements) > self.depth:
            del self._measurements[min(self._measurements)]
            self.drops['unpaired_measurement'] += 1
        return outcome

    def _drop(self, reason):
        self.drops[reason] += 1
        return reason

    def _check_stamp(self, stamp, waiting, kind):
        if stamp <= 0:
            return f'zero_stamp_{kind}'
        last = self._last_stamp
        # A measurement for the last step, which went on without one, came
        # too late: stale, not a duplicate.
        used = kind == 'increment' or self._last_corrected
        if stamp in waiting or (stamp == last and used):
            return f'duplicate_{kind}'
        if last is not None and stamp <= last:
            if last - stamp > self.backward_jump:
                self.restart()
                self.events['backward_jumps'] += 1
                return BACKWARD_JUMP
            return f'stale_{kind}'
        return None

    def restart(self):
        """
        Start a new time line: discard what waits, forget the last step.

        Returns
        -------
        discarded : int
            Inputs discarded (counted as ``discarded_*``).

        """
        discarded = len(self._increments) + len(self._measurements)
        self.drops['discarded_increment'] += len(self._increments)
        self.drops['discarded_measurement'] += len(self._measurements)
        self._increments.clear()
        self._measurements.clear()
        self._last_stamp = None
        self._last_corrected = False
        return discarded

    # Steps ------------------------------------------------------------------

    def pop_ready(self, now):
        """
        Release every step that is ready, in stamp order.

        Parameters
        ----------
        now : int
            The caller's clock, ns (compared with the deadlines).

        Returns
        -------
        steps : list of Step

        """
        steps = []
        while self._increments:
            stamp = min(self._increments)
            increment, deadline = self._increments[stamp]
            measurement = self._take_measurement(stamp)
            early = False
            if measurement is None:
                if len(self._increments) > self.depth:
                    early = True
                    self.events['early_releases'] += 1
                elif now < deadline and not (self._measurements
                                             and max(self._measurements) > stamp):
                    break
            del self._increments[stamp]
            steps.append(self._release(stamp, increment, measurement, early))
        return steps

    def _take_measurement(self, stamp):
        """Return the measurement of the step stamped ``stamp`` (removed), or None."""
        return self._measurements.pop(stamp, None)

    def _release(self, stamp, increment, measurement, early):
        previous = self._last_stamp
        gap = previous is not None and stamp - previous > self.forward_gap
        if gap:
            self.events['forward_gaps'] += 1
        self._last_stamp = stamp
        self._last_corrected = measurement is not None
        self.processed['increment'] += 1
        if measurement is not None:
            self.processed['measurement'] += 1
        if self._measurements:
            for old in [t for t in self._measurements if t <= stamp]:
                del self._measurements[old]
                self.drops['unpaired_measurement'] += 1
        return Step(stamp, increment, measurement, previous, gap, early)

    # Accounting -------------------------------------------------------------

    @property
    def last_stamp(self):
        """Stamp of the last step released (None at the start of a time line)."""
        return self._last_stamp

    def waiting(self, kind):
        """Return how many inputs of ``kind`` wait for their pair."""
        return len(self._increments if kind == 'increment' else self._measurements)

    def dropped(self, kind):
        """Return how many inputs of ``kind`` were dropped, all reasons."""
        reasons = INCREMENT_DROP_REASONS if kind == 'increment' else MEASUREMENT_DROP_REASONS
        return sum(self.drops[reason] for reason in reasons)

    def accounted(self, kind):
        """Return ``processed + dropped + waiting`` of ``kind`` (= ``received``)."""
        return self.processed[kind] + self.dropped(kind) + self.waiting(kind)
