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

Angular velocities (an IMU)
    :meth:`StepPairer.add_angular_velocity` takes the samples ``ω_j``
    (rad/s) of an IMU instead of increments. A sample waits for the next one
    (it is counted as a waiting increment); sample ``k + 1`` closes the
    interval ``[t_k, t_{k+1})`` and makes the increment of step ``k``,

        θ_k = ½ (ω_k + ω_{k+1}) Δt,

    the trapezoid rule, with ``Δt = t_{k+1} − t_k`` or ``constant_dt`` when
    that is set (the stamps still order the samples and are checked). A
    sample not newer than the one waiting is dropped (``Δt ≤ 0``: ``stale``
    or ``duplicate``, or a backward jump as above); when ``Δt`` exceeds
    ``max_dt`` (ns) the waiting sample is dropped (``dt_too_large``) and the
    new one starts over: the first sample of a time line only initializes.
    Given the sample's specific force too (the raw-IMU estimator uses it), a
    sample whose acceleration is not finite or zero is dropped as a whole
    (``non_finite_acceleration``, ``zero_acceleration``) before its stamp is
    looked at.

    With ``arrival_order`` (and ``constant_dt > 0``; for a caller whose
    steps wait for nothing: its steps are ready at once, whatever ``timeout``
    says, since repeated stamps cannot wait side by side) the samples are taken in the order
    they arrive and every one closes the interval of the one before with
    ``Δt = constant_dt``, as imu_filter_madgwick's ``constant_dt`` does:
    repeated, older and zero stamps are integrated, not dropped (drivers
    that stamp in bursts, imu_tools #3), and ``max_dt`` is not applied.
    Only non-finite values (and a zero acceleration) are dropped, and a
    stamp older than the waiting one by more than ``backward_jump`` still
    restarts the time line. A step's ``end`` is then the closing sample's
    stamp, whatever its order.

Magnetic fields (a magnetometer at its own rate)
    :meth:`StepPairer.add_field` checks a field (finite, nonzero:
    ``non_finite_measurement``, ``zero_field``) and its stamp against the
    previous field's only (zero, ``duplicate``, ``stale``; a jump back by
    more than ``backward_jump`` starts the field's time line over); the
    caller uses an accepted field at once, so it never waits and is never
    paired. Fields count as measurements.

Measurements of a step with an interval (bracketing)
    A step made from angular velocities knows its interval ``[t_k, t_{k+1})``.
    The measurement stamped ``t_m`` with ``t_k ≤ t_m < t_{k+1}`` is that
    step's (the one nearest ``t_k`` if several are; the others are dropped as
    ``unpaired``), carried back from ``t_m`` to ``t_k`` along the step's own
    rotation, ``y ⊗ exp(−f θ_k / 2)`` with ``f = (t_m − t_k) / Δt`` (a
    constant rate over the interval), so that it is an attitude at ``t_k``
    as the observer expects; at ``t_m = t_k`` it is used as it is. Rule 3
    applies with "newer" meaning ``t_m ≥ t_{k+1}``, and a measurement older
    than the end of the last step released is ``stale``. So a measurement at
    a lower rate corrects the step it falls in if it arrives before that
    step is released (within ``timeout`` of the increment's arrival, or
    before a later measurement); the steps in between propagate.
"""

import math

from ext_observer.core.validation import check_increment, check_measurement, check_vector
from ext_observer.pipeline.guard import carried
# The vocabulary lives in pairing_terms.py; its names are importable from here too.
from ext_observer.pipeline.pairing_terms import (  # noqa: F401
    VALUE_REASONS, BACKWARD_JUMP, DROP_REASONS, EVENTS, INCREMENT_DROP_REASONS, KINDS,
    MEASUREMENT_DROP_REASONS, MIN_ACCELERATION, MIN_FIELD, Step)

__all__ = ['BACKWARD_JUMP', 'DROP_REASONS', 'KINDS', 'MIN_ACCELERATION', 'MIN_FIELD', 'Step',
           'StepPairer']

# add_sample decides a sample at once only with |a|² above this (well clear
# of MIN_ACCELERATION, where check_vector's hypot decides).
_FAST_ACC2 = (4.0 * MIN_ACCELERATION) ** 2


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
    max_dt : int
        Largest interval between two IMU samples, ns.
    constant_dt : float
        ``Δt`` of every IMU interval, s; 0: from the stamps.
    arrival_order : bool
        IMU samples in arrival order, each closing an interval of
        ``constant_dt`` (see the module docstring); only with ``constant_dt``.

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
                 forward_gap=1_000_000_000, max_dt=100_000_000, constant_dt=0.0,
                 arrival_order=False):
        self.configure(depth=depth, timeout=timeout, max_increment=max_increment,
                       norm_tolerance=norm_tolerance, backward_jump=backward_jump,
                       forward_gap=forward_gap, max_dt=max_dt, constant_dt=constant_dt,
                       arrival_order=arrival_order)
        self.received = dict.fromkeys(KINDS, 0)
        self.processed = dict.fromkeys(KINDS, 0)
        self.drops = dict.fromkeys(DROP_REASONS, 0)
        self.events = dict.fromkeys(EVENTS, 0)
        # stamp -> (increment, deadline, end of the interval or None);
        # stamp -> measurement; the IMU sample waiting for the next one.
        self._increments = {}
        self._measurements = {}
        self._pending = None
        self._last_stamp = None
        self._last_end = None
        self._last_corrected = False
        self._last_field = None

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
                            'backward_jump', 'forward_gap', 'max_dt', 'constant_dt',
                            'arrival_order'):
                raise TypeError(f'unknown setting {name!r}')
            if name == 'arrival_order':
                value = bool(value)
            elif not value >= (1 if name == 'depth' else 0):
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
            return self._drop(VALUE_REASONS['increment'][reason])
        outcome = self._check_stamp(stamp, self._increments, 'increment')
        if outcome is not None and outcome != BACKWARD_JUMP:
            return self._drop(outcome)
        self._increments[stamp] = (tuple(increment), now + self.timeout, None)
        return outcome

    def add_angular_velocity(self, stamp, omega, now, acceleration=None):
        """
        Take an IMU sample ``ω`` (rad/s) stamped ``t``; see the module docstring.

        Parameters
        ----------
        stamp : int
            ``t``, ns.
        omega : sequence of 3 float
            Angular velocity of the body, rad/s, body frame.
        now : int
            The caller's clock, ns: the increment this sample completes gets
            the deadline ``now + timeout``.
        acceleration : sequence of 3 float, optional
            The sample's specific force, m/s², when the caller uses it (the
            raw-IMU estimator): a sample whose acceleration is not finite or
            is zero (:data:`MIN_ACCELERATION`) is dropped as a whole.

        Returns
        -------
        outcome : str or None
            As :meth:`add_increment`; also the reason when the *waiting*
            sample was dropped (``dt_too_large``, or a value reason of the
            increment it made).

        """
        self.received['increment'] += 1
        w0, w1, w2 = omega
        if not (math.isfinite(w0) and math.isfinite(w1) and math.isfinite(w2)):
            return self._drop('non_finite_increment')
        if acceleration is not None:
            reason = check_vector(acceleration, MIN_ACCELERATION)
            if reason is not None:
                return self._drop('non_finite_acceleration' if reason == 'non_finite'
                                  else 'zero_acceleration')
        pending = self._pending
        arrival = self.arrival_order and self.constant_dt > 0.0
        if pending is None:
            outcome = None if arrival else self._check_stamp(stamp, self._increments,
                                                             'increment')
            if outcome is not None and outcome != BACKWARD_JUMP:
                return self._drop(outcome)
            self._pending = (stamp, omega)
            return outcome
        start, (v0, v1, v2) = pending
        if arrival:
            if start - stamp > self.backward_jump:
                self.restart()
                self.events['backward_jumps'] += 1
                self._pending = (stamp, omega)
                return BACKWARD_JUMP
        elif stamp <= start:
            if stamp <= 0:
                return self._drop('zero_stamp_increment')
            if stamp == start:
                return self._drop('duplicate_increment')
            if start - stamp > self.backward_jump:
                self.restart()
                self.events['backward_jumps'] += 1
                self._pending = (stamp, omega)
                return BACKWARD_JUMP
            return self._drop('stale_increment')
        self._pending = (stamp, omega)
        span = stamp - start
        if span > self.max_dt and not arrival:
            return self._drop('dt_too_large')
        dt = self.constant_dt if self.constant_dt > 0.0 else span * 1e-9
        half = 0.5 * dt
        theta = ((v0 + w0) * half, (v1 + w1) * half, (v2 + w2) * half)
        reason = check_increment(theta, self.max_increment)
        if reason is not None:
            return self._drop(VALUE_REASONS['increment'][reason])
        # In arrival order stamps may repeat, so no step waits (its deadline is
        # now): two waiting with one start stamp would be one key.
        self._increments[start] = (theta, now if arrival else now + self.timeout, stamp)
        return None

    def add_sample(self, stamp, omega, acceleration):
        """
        The raw IMU's path: take a sample and release the step it closes, in one call.

        The same as :meth:`add_angular_velocity` (``now`` 0) followed by
        :meth:`pop_ready` (0), for a caller whose steps wait for nothing
        (``timeout`` 0) and pair nothing (the raw IMU, whose fields go through
        :meth:`add_field`). The usual sample (finite, after the one that
        waits, within ``max_dt``, no forward gap) is decided here at once;
        any other goes the general way, so the outcome, the step and every
        counter are those of the two calls (``test_pairing.py`` checks that on
        arbitrary samples).

        Returns
        -------
        outcome : str or None
            As :meth:`add_angular_velocity`.
        steps : tuple of Step
            What :meth:`pop_ready` releases: the step this sample closed, if any.

        """
        pending = self._pending
        if (pending is not None and self.timeout == 0 and not self._increments
                and not self._measurements):
            start, (v0, v1, v2) = pending
            span = stamp - start
            w0, w1, w2 = omega
            a0, a1, a2 = acceleration
            a2n = a0 * a0 + a1 * a1 + a2 * a2
            previous = self._last_stamp
            # Well clear of the zero-acceleration threshold (hypot there);
            # a non-finite value fails the comparisons.
            if ((0 < span <= self.max_dt if not (self.arrival_order and self.constant_dt > 0.0)
                 else -span <= self.backward_jump) and _FAST_ACC2 < a2n < math.inf
                    and math.isfinite(w0) and math.isfinite(w1) and math.isfinite(w2)
                    and (previous is None or start - previous <= self.forward_gap)):
                dt = self.constant_dt if self.constant_dt > 0.0 else span * 1e-9
                half = 0.5 * dt
                t0, t1, t2 = (v0 + w0) * half, (v1 + w1) * half, (v2 + w2) * half
                if t0 * t0 + t1 * t1 + t2 * t2 <= self.max_increment * self.max_increment:
                    self.received['increment'] += 1
                    self.processed['increment'] += 1
                    self._pending = (stamp, omega)
                    self._last_stamp = start
                    self._last_end = stamp
                    self._last_corrected = False
                    return None, (Step(start, (t0, t1, t2), None, previous, False, False,
                                       stamp),)
        outcome = self.add_angular_velocity(stamp, omega, 0, acceleration)
        return outcome, tuple(self.pop_ready(0))

    def add_field(self, stamp, field):
        """
        Take a magnetometer sample, used at once by the caller (never paired).

        The field is validated (finite, norm at least :data:`MIN_FIELD`) and
        its stamp checked against the previous field's: zero or negative,
        equal (``duplicate``) or older (``stale``) stamps are dropped, except
        one older by more than ``backward_jump`` (the field's time line
        restarted; accepted). An accepted field counts as a processed
        measurement.

        Parameters
        ----------
        stamp : int
            ns.
        field : sequence of 3 float
            Magnetic field, T (any unit: only its direction and relative norm
            matter; :data:`MIN_FIELD` assumes tesla).

        Returns
        -------
        outcome : str or None
            None when accepted, else the drop reason.

        """
        self.received['measurement'] += 1
        reason = check_vector(field, MIN_FIELD)
        if reason is not None:
            return self._drop('non_finite_measurement' if reason == 'non_finite'
                              else 'zero_field')
        if stamp <= 0:
            return self._drop('zero_stamp_measurement')
        last = self._last_field
        if last is not None and stamp <= last:
            if stamp == last:
                return self._drop('duplicate_measurement')
            if last - stamp <= self.backward_jump:
                return self._drop('stale_measurement')
        self._last_field = stamp
        self.processed['measurement'] += 1
        return None

    def reject(self, kind, reason):
        """Count an input of ``kind`` that the caller dropped for ``reason``."""
        self.received[kind] += 1
        return self._drop(reason)

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
            return self._drop(VALUE_REASONS['measurement'][reason])
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
        if kind == 'measurement' and self._last_end is not None and stamp < self._last_end:
            # Within the interval of a step already released.
            return 'stale_measurement'
        return None

    def restart(self):
        """
        Start a new time line: discard what waits, forget the last step.

        Returns
        -------
        discarded : int
            Inputs discarded (counted as ``discarded_*``).

        """
        pending = self._pending is not None
        discarded = len(self._increments) + pending + len(self._measurements)
        self.drops['discarded_increment'] += len(self._increments) + pending
        self.drops['discarded_measurement'] += len(self._measurements)
        self._increments.clear()
        self._measurements.clear()
        self._pending = None
        self._last_stamp = None
        self._last_end = None
        self._last_corrected = False
        self._last_field = None
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
            increment, deadline, end = self._increments[stamp]
            measurement = self._take_measurement(stamp, increment, end)
            early = False
            if measurement is None:
                # A measurement at or after this one's limit shows that this
                # step's is not coming (a publisher sends in stamp order).
                limit = stamp + 1 if end is None else end
                if len(self._increments) > self.depth:
                    early = True
                    self.events['early_releases'] += 1
                elif now < deadline and not (self._measurements
                                             and max(self._measurements) >= limit):
                    break
            del self._increments[stamp]
            steps.append(self._release(stamp, increment, measurement, early, end))
        return steps

    def _take_measurement(self, stamp, increment, end):
        """Return the measurement of the step (removed; carried to ``stamp``), or None."""
        if not self._measurements:
            return None
        if end is None:
            return self._measurements.pop(stamp, None)
        inside = [t for t in self._measurements if stamp <= t < end]
        if not inside:
            return None
        first = min(inside)
        y = self._measurements.pop(first)
        if first == stamp:
            return y
        f = -(first - stamp) / (end - stamp)
        return carried(y, (f * increment[0], f * increment[1], f * increment[2]))

    def _release(self, stamp, increment, measurement, early, end=None):
        previous = self._last_stamp
        gap = previous is not None and stamp - previous > self.forward_gap
        if gap:
            self.events['forward_gaps'] += 1
        self._last_stamp = stamp
        self._last_end = end
        self._last_corrected = measurement is not None
        self.processed['increment'] += 1
        if measurement is not None:
            self.processed['measurement'] += 1
        if self._measurements:
            limit = stamp if end is None else end - 1
            for old in [t for t in self._measurements if t <= limit]:
                del self._measurements[old]
                self.drops['unpaired_measurement'] += 1
        return Step(stamp, increment, measurement, previous, gap, early, end)

    # Accounting -------------------------------------------------------------

    @property
    def field_stamp(self):
        """Stamp of the last field accepted (None at the start of its time line)."""
        return self._last_field

    @property
    def pending_stamp(self):
        """Stamp of the IMU sample waiting for the next one (None if none waits)."""
        return None if self._pending is None else self._pending[0]

    @property
    def last_stamp(self):
        """Stamp of the last step released (None at the start of a time line)."""
        return self._last_stamp

    def waiting(self, kind):
        """Return how many inputs of ``kind`` wait (for their pair, or the next sample)."""
        if kind == 'increment':
            return len(self._increments) + (self._pending is not None)
        return len(self._measurements)

    def dropped(self, kind):
        """Return how many inputs of ``kind`` were dropped, all reasons."""
        reasons = INCREMENT_DROP_REASONS if kind == 'increment' else MEASUREMENT_DROP_REASONS
        return sum(self.drops[reason] for reason in reasons)

    def accounted(self, kind):
        """Return ``processed + dropped + waiting`` of ``kind`` (= ``received``)."""
        return self.processed[kind] + self.dropped(kind) + self.waiting(kind)
