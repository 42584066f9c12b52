"""
The observer's input rules without ROS: StepPairer and GuardedObserver.

Examples pin each rule; hypothesis drives both with arbitrary inputs (NaN,
infinities, subnormals, huge values, zero, negative and jumping stamps) and
checks the invariants: every input accounted for, bounded buffers, steps in
stamp order with valid values, and a finite estimate whatever comes in.
"""

from collections import Counter
import math

from hypothesis import example, given, settings, strategies as st
import pytest

from ext_observer.core import GAIN_MODES, SingleObserver, VARIANTS
from ext_observer.pipeline.guard import GUARD_REASONS, GuardedObserver
from ext_observer.pipeline.pairing import BACKWARD_JUMP, DROP_REASONS, KINDS, StepPairer

MS = 1_000_000
S = 1_000_000_000
Y = (1.0, 0.0, 0.0, 0.0)
THETA = (0.1, 0.2, 0.3)
THETA_SMALL = (0.01, -0.02, 0.005)  # a good increment (rad)
nan, inf = float('nan'), float('inf')
# Drops counted when a later input or a restart pushes an input out, not
# returned by the call that took it.
LATER_DROPS = ('unpaired_measurement', 'discarded_increment', 'discarded_measurement')


def make(**kwargs):
    options = dict(depth=4, timeout=100 * MS, backward_jump=1 * S, forward_gap=1 * S)
    options.update(kwargs)
    return StepPairer(**options)


def assert_accounted(pairer):
    for kind in KINDS:
        assert pairer.received[kind] == pairer.accounted(kind), kind


def apply(pairer, op, stamp, value, now):
    """
    One drawn operation on ``pairer``: ``(outcome, now)``.

    ``increment`` and ``imu`` (an angular velocity), ``measurement``, ``tick``
    (the clock moves on by ``stamp``) or ``restart``; the outcome is None, a
    backward jump (a restart) or a drop reason.
    """
    if op == 'increment':
        outcome = pairer.add_increment(stamp, value, now)
    elif op == 'imu':
        outcome = pairer.add_angular_velocity(stamp, value, now)
    elif op == 'measurement':
        outcome = pairer.add_measurement(stamp, value)
    elif op == 'tick':
        now += stamp
        outcome = None
    else:
        pairer.restart()
        outcome = BACKWARD_JUMP
    assert outcome is None or outcome == BACKWARD_JUMP or outcome in DROP_REASONS
    return outcome, now


def assert_valid_step(step, last):
    """A released step follows the one before (``last``), with a bounded increment."""
    assert step.previous == last
    assert all(map(math.isfinite, step.increment))
    assert math.hypot(*step.increment) <= 2.0
    if step.measurement is not None:
        assert math.hypot(*step.measurement) == pytest.approx(1.0)


# Examples, one rule each --------------------------------------------------------

def test_pairs_by_stamp_and_waits_for_the_measurement():
    pairer = make()
    assert pairer.add_increment(10 * MS, THETA, now=0) is None
    assert pairer.pop_ready(now=50 * MS) == []
    assert pairer.add_measurement(10 * MS, (2.0 ** -0.5, 0.0, 2.0 ** -0.5, 0.0)) is None
    [step] = pairer.pop_ready(now=60 * MS)
    assert (step.stamp, step.increment, step.previous, step.gap, step.early) == (
        10 * MS, THETA, None, False, False)
    assert step.measurement == pytest.approx((2.0 ** -0.5, 0.0, 2.0 ** -0.5, 0.0))
    assert pairer.processed == {'increment': 1, 'measurement': 1}
    assert_accounted(pairer)


def test_increment_propagates_after_the_timeout_or_a_newer_measurement():
    pairer = make()
    pairer.add_increment(10 * MS, THETA, now=0)
    assert pairer.pop_ready(now=99 * MS) == []
    [step] = pairer.pop_ready(now=100 * MS)
    assert step.measurement is None
    pairer.add_increment(20 * MS, THETA, now=100 * MS)
    pairer.add_measurement(30 * MS, Y)
    [step] = pairer.pop_ready(now=100 * MS)
    assert (step.stamp, step.measurement, step.previous) == (20 * MS, None, 10 * MS)
    assert_accounted(pairer)


def test_measurement_is_normalized_within_the_tolerance_and_dropped_beyond():
    pairer = make(norm_tolerance=0.1)
    pairer.add_measurement(10 * MS, (1.05, 0.0, 0.0, 0.0))
    pairer.add_increment(10 * MS, THETA, now=0)
    [step] = pairer.pop_ready(now=0)
    assert step.measurement == (1.0, 0.0, 0.0, 0.0)
    assert pairer.add_measurement(20 * MS, (1.2, 0.0, 0.0, 0.0)) == 'norm_out_of_tolerance'


@pytest.mark.parametrize('kind, value, reason', [
    ('increment', (nan, 0.0, 0.0), 'non_finite_increment'),
    ('increment', (0.0, -inf, 0.0), 'non_finite_increment'),
    ('increment', (12.0, 12.0, 12.0), 'increment_too_large'),
    ('increment', (1e200, 1e200, 0.0), 'increment_too_large'),
    ('measurement', (nan, 0.0, 0.0, 0.0), 'non_finite_measurement'),
    ('measurement', (0.0, 0.0, 0.0, 0.0), 'zero_quaternion'),
    ('measurement', (5e-324, 0.0, 0.0, 0.0), 'zero_quaternion'),
    ('measurement', (1e300, 1e300, 0.0, 0.0), 'norm_out_of_tolerance'),
])
def test_bad_values_are_dropped_by_reason(kind, value, reason):
    pairer = make(max_increment=20.0)
    if kind == 'increment':
        assert pairer.add_increment(10 * MS, value, now=0) == reason
    else:
        assert pairer.add_measurement(10 * MS, value) == reason
    assert pairer.drops[reason] == 1
    assert pairer.waiting(kind) == 0
    assert_accounted(pairer)


def test_zero_duplicate_and_stale_stamps_are_dropped():
    pairer = make()
    assert pairer.add_increment(0, THETA, now=0) == 'zero_stamp_increment'
    assert pairer.add_measurement(-5, Y) == 'zero_stamp_measurement'
    pairer.add_increment(10 * MS, THETA, now=0)
    assert pairer.add_increment(10 * MS, THETA, now=0) == 'duplicate_increment'
    pairer.add_measurement(10 * MS, Y)
    pairer.pop_ready(now=0)
    assert pairer.add_measurement(10 * MS, Y) == 'duplicate_measurement'
    assert pairer.add_increment(10 * MS, THETA, now=0) == 'duplicate_increment'
    assert pairer.add_increment(5 * MS, THETA, now=0) == 'stale_increment'
    assert pairer.add_measurement(5 * MS, Y) == 'stale_measurement'
    assert_accounted(pairer)


def test_backward_jump_restarts_the_time_line():
    pairer = make()
    pairer.add_increment(5 * S, THETA, now=0)
    pairer.add_measurement(5 * S, Y)
    pairer.pop_ready(now=0)
    pairer.add_measurement(6 * S, Y)
    # Within the threshold: stale. Beyond: a new time line.
    assert pairer.add_increment(4 * S + 1, THETA, now=0) == 'stale_increment'
    assert pairer.add_increment(1 * S, THETA, now=0) == BACKWARD_JUMP
    assert pairer.events['backward_jumps'] == 1
    assert pairer.drops['discarded_measurement'] == 1
    pairer.add_measurement(1 * S, Y)
    [step] = pairer.pop_ready(now=0)
    assert (step.stamp, step.previous) == (1 * S, None)
    assert_accounted(pairer)


def test_forward_gap_is_flagged():
    pairer = make()
    for stamp in (1 * S, 2 * S, 3 * S + 1):
        pairer.add_increment(stamp, THETA, now=0)
        pairer.add_measurement(stamp, Y)
    steps = pairer.pop_ready(now=0)
    assert [step.gap for step in steps] == [False, False, True]
    assert pairer.events['forward_gaps'] == 1


def test_buffers_are_bounded():
    pairer = make(depth=3, timeout=10 * S)
    # Measurements with no increment: the oldest goes, counted.
    for k in range(1, 6):
        pairer.add_measurement(k * S, Y)
    assert pairer.waiting('measurement') == 3
    assert pairer.drops['unpaired_measurement'] == 2
    # Increments that wait long: the oldest step goes on without waiting.
    pairer = make(depth=3, timeout=10 * S)
    for k in range(1, 6):
        pairer.add_increment(k * MS, THETA, now=0)
        pairer.pop_ready(now=0)
    assert pairer.waiting('increment') == 3
    assert pairer.events['early_releases'] == 2
    assert pairer.processed['increment'] == 2
    assert_accounted(pairer)


def test_configure_refuses_negative_bounds():
    with pytest.raises(ValueError, match='depth'):
        make(depth=0)
    with pytest.raises(ValueError, match='timeout'):
        make().configure(timeout=-1)


# Arbitrary input -------------------------------------------------------------------

any_float = st.floats(allow_nan=True, allow_infinity=True, allow_subnormal=True)
nice_float = st.floats(-1.5, 1.5)
plausible = st.integers(0, 40).map(lambda k: k * 50 * MS)          # a plausible stream
stamps = st.one_of(plausible, plausible,                             # (drawn twice as often)
                   st.sampled_from([0, -1, 2 ** 63, 10 ** 12]),      # zero, negative, far
                   st.integers(-2 ** 64, 2 ** 64))
small_float = st.floats(-1.0, 1.0)
increments = st.one_of(st.tuples(nice_float, nice_float, nice_float),
                       st.tuples(any_float, any_float, any_float),
                       st.tuples(small_float, small_float, small_float))  # valid
measurements = st.one_of(
    st.tuples(nice_float, nice_float, nice_float, nice_float),
    st.tuples(any_float, any_float, any_float, any_float),
    st.sampled_from([Y, (0.0, 0.0, 0.0, 0.0), (-0.5, 0.5, -0.5, 0.5)]),
    st.sampled_from([Y, (0.0, 1.0, 0.0, 0.0), (-0.5, 0.5, -0.5, 0.5)]))  # valid
operations = st.lists(st.one_of(
    st.tuples(st.just('increment'), stamps, increments),
    st.tuples(st.just('measurement'), stamps, measurements),
    st.tuples(st.just('tick'), st.integers(0, 300 * MS), st.none()),
    st.tuples(st.just('restart'), st.none(), st.none())), max_size=60)


# Every drop reason of increments and measurements at least once.
EVERY_DROP = [
    ('increment', 100 * MS, THETA), ('measurement', 100 * MS, Y), ('tick', 10 * MS, None),
    ('increment', 50 * MS, THETA),                                 # stale
    ('measurement', 50 * MS, Y),                                   # stale
    ('increment', 100 * MS, THETA), ('measurement', 100 * MS, Y),  # duplicates
    ('measurement', 150 * MS, Y), ('measurement', 200 * MS, Y),
    ('increment', 200 * MS, THETA),                                # 150 unpaired
    ('increment', 300 * MS, THETA), ('restart', None, None),       # discarded
    ('measurement', 500 * MS, Y), ('restart', None, None),         # discarded
    ('increment', 700 * MS, (nan, 0.0, 0.0)), ('increment', 700 * MS, (3.0, 0.0, 0.0)),
    ('measurement', 700 * MS, (0.0, 0.0, 0.0, 0.0)), ('measurement', 700 * MS, (2.0, 0, 0, 0)),
    ('measurement', 700 * MS, (nan, 0.0, 0.0, 0.0)),
    ('increment', 0, THETA), ('measurement', -1, Y),               # zero stamps
]


@settings(max_examples=400, deadline=None)
@given(operations, st.integers(1, 5))
@example(EVERY_DROP, 4)
def test_every_input_is_accounted_for_and_steps_are_valid(ops, depth):
    pairer = make(depth=depth, max_increment=2.0, norm_tolerance=0.1)
    now = 0
    last = None
    # The test's own counts: inputs sent, drops returned at once, steps released.
    sent = dict.fromkeys(KINDS, 0)
    returned = Counter()
    released = corrected = 0
    for op, stamp, value in ops:
        if op in sent:
            sent[op] += 1
        outcome, now = apply(pairer, op, stamp, value, now)
        if outcome in DROP_REASONS:
            returned[outcome] += 1
        if outcome == BACKWARD_JUMP:
            last = None
        for step in pairer.pop_ready(now):
            released += 1
            corrected += step.measurement is not None
            assert_valid_step(step, last)
            assert last is None or step.stamp > last
            assert step.stamp > 0
            last = step.stamp
        assert pairer.last_stamp == last
        assert pairer.waiting('increment') <= depth
        assert pairer.waiting('measurement') <= depth
        assert_accounted(pairer)
        # The pairer's counts against the test's: nothing received that was
        # not sent, every step counted once, and each drop it returned at
        # once counted under that reason (the others come later: unpaired
        # and discarded inputs).
        assert pairer.received == sent
        assert pairer.processed == {'increment': released, 'measurement': corrected}
        for reason in DROP_REASONS:
            if reason in LATER_DROPS:
                assert pairer.drops[reason] >= returned[reason], reason
            else:
                assert pairer.drops[reason] == returned[reason], reason


# The divergence guard on the pairer's steps -------------------------------------------

@settings(max_examples=300, deadline=None)
@given(st.sampled_from(VARIANTS), st.sampled_from(GAIN_MODES),
       st.tuples(st.floats(-2, 2), st.floats(-2, 2), st.floats(-2, 2),
                 st.floats(-2, 2)).filter(lambda q: 1e-3 < math.hypot(*q) <= 2.0),
       st.lists(st.tuples(increments, st.one_of(st.none(), measurements)), max_size=40))
def test_validated_and_guarded_steps_stay_finite(variant, gain_mode, initial, inputs):
    """Arbitrary floats through the pairer's checks and the guard: always a finite estimate."""
    pairer = make(max_increment=20.0)
    guarded = GuardedObserver(
        SingleObserver(variant, gain_mode=gain_mode, kappa=1.0, initial=initial,
                       gain=(1.5, -1.0, 1.0, -1.0)), max_residual=3.0, max_innovation=3.0)
    for k, (theta, y) in enumerate(inputs, start=1):
        pairer.add_increment(k * MS, theta, now=0)
        if y is not None:
            pairer.add_measurement(k * MS, y)
        for step in pairer.pop_ready(now=1 * S):
            state, reason = guarded.step(step.increment, step.measurement)
            assert all(map(math.isfinite, state))
            assert reason is None or reason in GUARD_REASONS
            # Checked, or reinitialized (a unit measurement or the initial estimate).
            assert abs(sum(v * v for v in state) - 1.0) <= 3.0 + 1e-12
            assert sum(v * v for v in state) >= 1e-12


# Angular velocities (an IMU) and measurements between the samples ------------------

def test_imu_samples_make_trapezoid_increments_the_first_only_initializes():
    pairer = make(timeout=0)
    assert pairer.add_angular_velocity(1 * S, (1.0, 0.0, -2.0), 0) is None
    assert pairer.pop_ready(0) == [] and pairer.waiting('increment') == 1
    pairer.add_angular_velocity(1 * S + 10 * MS, (3.0, 0.0, 2.0), 0)
    [step] = pairer.pop_ready(0)
    assert (step.stamp, step.end) == (1 * S, 1 * S + 10 * MS)
    assert step.increment == pytest.approx((0.02, 0.0, 0.0))
    # constant_dt replaces the stamps' interval in θ = ½ (ω_k + ω_{k+1}) Δt.
    pairer.configure(constant_dt=0.005)
    pairer.add_angular_velocity(1 * S + 30 * MS, (3.0, 0.0, 2.0), 0)
    [step] = pairer.pop_ready(0)
    assert step.increment == pytest.approx((0.015, 0.0, 0.01))
    assert pairer.received['increment'] == 3 and pairer.processed['increment'] == 2
    assert_accounted(pairer)


def test_imu_non_positive_and_too_large_intervals_are_dropped():
    pairer = make(timeout=0, max_dt=50 * MS)
    pairer.add_angular_velocity(2 * S, (0.1, 0.0, 0.0), 0)
    assert pairer.add_angular_velocity(2 * S, (0.1, 0.0, 0.0), 0) == 'duplicate_increment'
    assert pairer.add_angular_velocity(2 * S - MS, (0.1, 0.0, 0.0), 0) == 'stale_increment'
    assert pairer.add_angular_velocity(2 * S + MS, (nan, 0.0, 0.0), 0) == 'non_finite_increment'
    # A gap: the waiting sample is dropped; the new one starts over.
    assert pairer.add_angular_velocity(3 * S, (0.1, 0.0, 0.0), 0) == 'dt_too_large'
    assert pairer.pop_ready(0) == []
    pairer.add_angular_velocity(3 * S + 10 * MS, (0.1, 0.0, 0.0), 0)
    [step] = pairer.pop_ready(0)
    assert step.stamp == 3 * S
    # Far older: a new time line.
    assert pairer.add_angular_velocity(1 * S, (0.1, 0.0, 0.0), 0) == BACKWARD_JUMP
    assert pairer.drops['discarded_increment'] == 1
    assert_accounted(pairer)


def test_imu_sample_with_a_bad_acceleration_is_dropped_whole():
    pairer = make(timeout=0)
    g = (0.1, 0.0, 0.0)
    pairer.add_angular_velocity(2 * S, g, 0, (0.0, 0.0, 9.8))
    for acc, reason in (((nan, 0.0, 9.8), 'non_finite_acceleration'),
                        ((0.0, -inf, 9.8), 'non_finite_acceleration'),
                        ((0.0, 0.0, 0.0), 'zero_acceleration'),
                        ((1e-300, 0.0, 0.0), 'zero_acceleration')):
        # Checked before the stamp: a bad sample never becomes the waiting one.
        assert pairer.add_angular_velocity(2 * S + MS, g, 0, acc) == reason
        assert pairer.pending_stamp == 2 * S
    assert pairer.add_angular_velocity(2 * S + MS, g, 0, (5e-324, 0.0, 9.8)) is None
    assert pairer.pending_stamp == 2 * S + MS
    [step] = pairer.pop_ready(0)
    assert (step.stamp, step.end) == (2 * S, 2 * S + MS)
    assert_accounted(pairer)


def test_fields_are_checked_against_the_previous_field_only():
    pairer = make()
    field = (2e-5, 0.0, -4e-5)  # T
    assert pairer.field_stamp is None
    assert pairer.add_field(2 * S, field) is None
    for stamp, value, reason in ((3 * S, (nan, 0.0, 0.0), 'non_finite_measurement'),
                                 (3 * S, (0.0, 0.0, 0.0), 'zero_field'),
                                 (0, field, 'zero_stamp_measurement'),
                                 (2 * S, field, 'duplicate_measurement'),
                                 (2 * S - MS, field, 'stale_measurement')):
        assert pairer.add_field(stamp, value) == reason
        assert pairer.field_stamp == 2 * S
    # Fields are not paired with steps: an older IMU stamp does not matter.
    pairer.add_angular_velocity(5 * S, THETA, 0)
    assert pairer.add_field(3 * S, field) is None
    # Far older: the field's time line starts over.
    assert pairer.add_field(1 * S, field) is None
    assert pairer.field_stamp == 1 * S
    # A restart of the time line forgets the last field.
    pairer.restart()
    assert pairer.field_stamp is None
    assert pairer.processed['measurement'] == 3
    assert pairer.waiting('measurement') == 0
    assert_accounted(pairer)


def rotate(q, theta):
    from ext_observer.pipeline.guard import carried
    return carried(q, theta)


def test_measurement_between_samples_corrects_its_interval_carried_back():
    pairer = make(timeout=100 * MS)
    omega = (2.0, -1.0, 0.5)
    q0 = (0.5, 0.5, -0.5, 0.5)
    t0, dt = 1 * S, 10 * MS
    pairer.add_angular_velocity(t0, omega, 0)
    pairer.add_angular_velocity(t0 + dt, omega, 0)
    # The attitude at t_m = t_0 + 0.4 Δt under the constant rate: q0 ⊗ exp(0.4 θ/2).
    theta = tuple(0.01 * w for w in omega)
    y = rotate(q0, tuple(0.4 * v for v in theta))
    pairer.add_measurement(t0 + 4 * MS, y)
    [step] = pairer.pop_ready(0)
    assert step.measurement == pytest.approx(q0, abs=1e-12)
    # The measurement of an interval already released is stale.
    assert pairer.add_measurement(t0 + 5 * MS, y) == 'stale_measurement'
    assert_accounted(pairer)


def test_lower_rate_measurements_steps_between_propagate():
    pairer = make(depth=50, timeout=20 * MS)
    t0, dt = 1 * S, 5 * MS
    corrected, now = [], 0
    for k in range(41):
        t = t0 + k * dt
        now = k * dt
        pairer.add_angular_velocity(t, (0.1, 0.2, 0.3), now)
        if k % 20 == 3:
            pairer.add_measurement(t + 2 * MS, Y)
        corrected += [s.stamp for s in pairer.pop_ready(now) if s.measurement is not None]
    corrected += [s.stamp for s in pairer.pop_ready(now + S) if s.measurement is not None]
    assert corrected == [t0 + 3 * dt, t0 + 23 * dt]
    assert pairer.processed['increment'] == 40
    assert not any(pairer.drops.values())
    assert_accounted(pairer)


imu_operations = st.lists(st.one_of(
    st.tuples(st.just('imu'), stamps, increments),
    st.tuples(st.just('measurement'), stamps, measurements),
    st.tuples(st.just('tick'), st.integers(0, 300 * MS), st.none()),
    st.tuples(st.just('restart'), st.none(), st.none())), max_size=60)


# A stream that releases steps, after any operations: good samples a usual
# interval apart from beyond every stamp drawn so far, each with or without
# a measurement inside its interval (drawn at random alone, the
# operations released no step in 400 examples, so the step checks never ran).
stream_intervals = st.lists(st.tuples(st.integers(1 * MS, 20 * MS), st.booleans()),
                            min_size=3, max_size=12)


def stream_start(ops):
    """A stamp after every positive stamp of ``ops``."""
    return max([stamp for _, stamp, _ in ops if stamp is not None and stamp > 0] + [0]) + S


@settings(max_examples=400, deadline=None)
@given(imu_operations, st.integers(1, 5), st.sampled_from([0.0, 0.01]), stream_intervals)
def test_every_imu_sample_is_accounted_for_and_steps_are_valid(ops, depth, constant_dt,
                                                               stream):
    pairer = make(depth=depth, max_increment=2.0, norm_tolerance=0.1,
                  max_dt=200 * MS, constant_dt=constant_dt)
    now = 0
    last = last_end = None
    released = 0
    stamp = stream_start(ops)
    ops = ops + [('imu', stamp, THETA_SMALL)]
    for interval, measured in stream:
        if measured:
            ops.append(('measurement', stamp + interval // 2, Y))
        stamp += interval
        ops += [('imu', stamp, THETA_SMALL), ('tick', interval, None)]
    ops.append(('tick', S, None))  # then nothing waits for a measurement
    for op, stamp, value in ops:
        outcome, now = apply(pairer, op, stamp, value, now)
        if outcome == BACKWARD_JUMP:
            last = last_end = None
        for step in pairer.pop_ready(now):
            assert_valid_step(step, last)
            assert last_end is None or step.stamp >= last_end
            assert 0 < step.stamp < step.end <= step.stamp + 200 * MS
            last, last_end = step.stamp, step.end
            released += 1
        assert pairer.waiting('increment') <= depth + 1
        assert pairer.waiting('measurement') <= depth
        assert_accounted(pairer)
    # Every interval of the stream was released (the checks above ran).
    assert released >= len(stream)


raw_imu_operations = st.lists(st.one_of(
    st.tuples(st.just('imu'), stamps, st.tuples(increments, increments)),
    st.tuples(st.just('field'), stamps, increments),
    st.tuples(st.just('restart'), st.none(), st.none())), max_size=60)


@settings(max_examples=400, deadline=None)
@given(raw_imu_operations, st.integers(1, 5), stream_intervals)
def test_raw_imu_samples_and_fields_are_accounted_for(ops, depth, stream):
    # The raw IMU: samples with their acceleration, fields used at once,
    # nothing waits for a measurement (timeout 0); then a stream of good
    # samples with fields between them.
    pairer = make(depth=depth, timeout=0, max_increment=2.0, max_dt=200 * MS)
    released = 0
    stamp = stream_start(ops)
    sample = (THETA_SMALL, (0.1, -0.2, 9.8))
    ops = ops + [('imu', stamp, sample)]
    for interval, field in stream:
        if field:
            ops.append(('field', stamp + interval // 2, (2e-5, 0.0, -4e-5)))
        stamp += interval
        ops.append(('imu', stamp, sample))
    for op, stamp, value in ops:
        if op == 'imu':
            omega, acceleration = value
            outcome = pairer.add_angular_velocity(stamp, omega, 0, acceleration)
            if pairer.pending_stamp == stamp and outcome in (None, BACKWARD_JUMP):
                # Taken: finite, with a direction.
                assert all(map(math.isfinite, omega + acceleration))
                assert math.hypot(*acceleration) > 0.0
        elif op == 'field':
            before = pairer.field_stamp
            outcome = pairer.add_field(stamp, value)
            if outcome is None:
                assert all(map(math.isfinite, value)) and math.hypot(*value) > 0.0
                assert pairer.field_stamp == stamp > 0
                assert before is None or stamp > before or before - stamp > S
            else:
                assert pairer.field_stamp == before
        else:
            pairer.restart()
            outcome = None
        assert outcome is None or outcome == BACKWARD_JUMP or outcome in DROP_REASONS
        for step in pairer.pop_ready(0):
            assert step.measurement is None
            assert 0 < step.stamp < step.end <= step.stamp + 200 * MS
            released += 1
        # Steps wait for nothing; fields never wait.
        assert pairer.waiting('increment') <= 1
        assert pairer.waiting('measurement') == 0
        assert_accounted(pairer)
    assert released >= len(stream)


# The raw IMU's samples: a 5 ms stream, its steps drawn as differences
# (mostly the usual one; duplicates, stale, jumps back, gaps and far stamps
# among them), rates and accelerations good, bad and at the edges.
sample_stamps = st.one_of(st.just(5 * MS), st.just(5 * MS), st.just(5 * MS),
                          st.integers(1, 60 * MS),
                          st.sampled_from([0, -MS, -3 * S, 600 * MS, 2 * S]),
                          st.integers(-2 ** 40, 2 ** 40))
rates = st.one_of(st.tuples(small_float, small_float, small_float),
                  st.tuples(any_float, any_float, any_float),
                  st.sampled_from([(1e3, 0.0, 0.0), (0.0, 0.0, 400.0)]))
specific_forces = st.one_of(st.tuples(st.floats(-20, 20), st.floats(-20, 20), st.just(9.8)),
                            st.tuples(any_float, any_float, any_float),
                            st.sampled_from([(0.0, 0.0, 0.0), (1e-300, 0.0, 0.0),
                                             (4e-6, 0.0, 0.0), (1e200, 1e200, 0.0),
                                             (math.inf, 0.0, 9.8)]))
usual_sample = st.tuples(st.just('sample'), st.just(5 * MS),
                         st.tuples(small_float, small_float, small_float),
                         st.tuples(st.floats(-20, 20), st.floats(-20, 20), st.just(9.8)))
sample_operations = st.lists(st.one_of(
    usual_sample, usual_sample, usual_sample, usual_sample,
    st.tuples(st.just('sample'), sample_stamps, rates, specific_forces),
    st.tuples(st.just('sample'), sample_stamps, rates, specific_forces),
    st.tuples(st.just('field'), sample_stamps, st.just((2e-5, 0.0, -4e-5)), st.none()),
    # A measurement (none comes with the raw IMU; a caller that pairs them
    # would send them): the one-call path must step aside.
    st.tuples(st.just('measurement'), st.none(), st.just((1.0, 0.0, 0.0, 0.0)),
              st.integers(-10 * MS, 10 * MS)),
    st.tuples(st.just('restart'), st.none(), st.none(), st.none())), max_size=60)


def assert_one_call_is_the_general_calls(options, ops):
    """
    ``ops`` through the one-call path and through the general calls alike; its outcomes.

    One pairer takes each sample with ``add_sample``, another (the same
    ``options``) with ``add_angular_velocity`` then ``pop_ready``: every
    outcome, step, state and counter is the same. Returns the one-call
    path's outcomes of the samples.
    """
    fast, general = StepPairer(**options), StepPairer(**options)
    stamp = 2 * S
    outcomes = []
    for kind, delta, value, acc in ops:
        if delta is not None:
            stamp += delta
        if kind == 'sample':
            outcome, steps = fast.add_sample(stamp, value, acc)
            assert outcome == general.add_angular_velocity(stamp, value, 0, acc)
            assert list(steps) == general.pop_ready(0)
            outcomes.append(outcome)
        elif kind == 'field':
            assert fast.add_field(stamp, value) == general.add_field(stamp, value)
        elif kind == 'measurement':
            at = stamp + acc   # around the last sample's stamp
            assert fast.add_measurement(at, value) == general.add_measurement(at, value)
        else:
            assert fast.restart() == general.restart()
        assert _pairer_state(fast) == _pairer_state(general)
    assert_accounted(fast)
    return outcomes


def _pairer_state(pairer):
    return (dict(pairer.received), dict(pairer.processed), dict(pairer.drops),
            dict(pairer.events), pairer.pending_stamp, pairer.last_stamp, pairer.field_stamp,
            pairer.waiting('increment'), pairer.waiting('measurement'))


@settings(max_examples=400, deadline=None)
@given(sample_operations, st.sampled_from([0.0, 0.004]),
       st.sampled_from([40 * MS, 300 * MS]), st.booleans(), st.sampled_from([0, 0, 20 * MS]),
       st.sampled_from([3.0, 3.0, 0.004]))
def test_add_sample_is_add_angular_velocity_then_pop_ready(ops, constant_dt, max_dt, arrival,
                                                           timeout, max_increment):
    # The raw IMU's one-call path decides the usual sample itself: every
    # outcome, step and counter is that of the two general calls, in any
    # configuration (arrival order, a timeout, a small max_increment).
    settings_ = dict(timeout=timeout, depth=4, backward_jump=1 * S, forward_gap=500 * MS,
                     max_dt=max_dt, constant_dt=constant_dt, max_increment=max_increment,
                     arrival_order=arrival)
    assert_one_call_is_the_general_calls(settings_, ops)


def test_arrival_order_steps_with_a_repeated_stamp_are_all_accounted():
    # Arrival order integrates a repeated stamp; with a timeout its steps
    # still wait for nothing, so none overwrites another that waits.
    pairer = StepPairer(timeout=20 * MS, depth=4, backward_jump=1 * S, forward_gap=500 * MS,
                        max_dt=40 * MS, constant_dt=0.004, max_increment=3.0,
                        arrival_order=True)
    released = []
    for stamp, rate in ((2 * S + 5 * MS, 0.0), (2 * S + 10 * MS, 0.0),
                        (2 * S + 10 * MS, 1000.0), (2 * S + 15 * MS, 0.0)):
        pairer.add_angular_velocity(stamp, (rate, 0.0, 0.0), 0, (0.0, 0.0, 9.8))
        released += pairer.pop_ready(0)
    assert pairer.received['increment'] == 4
    assert_accounted(pairer)
    assert len(released) == 3


def test_arrival_order_add_sample_is_add_angular_velocity_then_pop_ready():
    # The one-call path and the general one agree in arrival order too, on
    # the arbitrary streams above (duplicates, stale, jumps, gaps).
    @settings(max_examples=300, deadline=None)
    @given(sample_operations)
    def check(ops):
        options = dict(timeout=0, depth=4, backward_jump=S,
                       forward_gap=S // 2, max_dt=S // 25, constant_dt=0.004,
                       max_increment=3.0, arrival_order=True)
        for outcome in assert_one_call_is_the_general_calls(options, ops):
            assert outcome in (None, 'backward_jump', 'non_finite_increment',
                               'non_finite_acceleration', 'zero_acceleration',
                               'increment_too_large'), outcome

    check()


# A step's interval bound and the step a measurement at a step's end belongs to -----------

def test_an_interval_of_max_dt_is_a_step_and_one_nanosecond_more_is_dropped():
    pairer = StepPairer(timeout=0, max_dt=50 * MS)
    pairer.add_angular_velocity(2 * S, (0.1, 0.0, 0.0), 0)
    assert pairer.add_angular_velocity(2 * S + 50 * MS, (0.1, 0.0, 0.0), 0) is None
    [step] = pairer.pop_ready(0)
    assert (step.stamp, step.end) == (2 * S, 2 * S + 50 * MS)
    assert pairer.add_angular_velocity(2 * S + 100 * MS + 1, (0.1, 0.0, 0.0), 0) == 'dt_too_large'
    assert pairer.add_angular_velocity(2 * S + 130 * MS, (0.1, 0.0, 0.0), 0) is None
    [step] = pairer.pop_ready(0)
    assert (step.stamp, step.end) == (2 * S + 100 * MS + 1, 2 * S + 130 * MS)


def test_a_measurement_at_a_steps_end_corrects_the_next_step():
    # Samples at 0, 10 and 20 ms; a measurement stamped 10 ms is the
    # attitude at the start of the second interval, not the end of the first.
    pairer = StepPairer(depth=4, timeout=100 * MS)
    t0 = 1 * S
    pairer.add_angular_velocity(t0, (0.1, 0.2, 0.3), 0)
    pairer.add_angular_velocity(t0 + 10 * MS, (0.1, 0.2, 0.3), 0)
    pairer.add_measurement(t0 + 10 * MS, Y)
    pairer.add_angular_velocity(t0 + 20 * MS, (0.1, 0.2, 0.3), 0)
    pairer.add_angular_velocity(t0 + 30 * MS, (0.1, 0.2, 0.3), 0)
    steps = pairer.pop_ready(1 * S)
    assert [(s.stamp, s.measurement) for s in steps] == [
        (t0, None), (t0 + 10 * MS, Y), (t0 + 20 * MS, None)]


# The pairing rules at their edges -------------------------------------------------------

def test_a_sample_the_caller_rejects_is_received_and_dropped_with_its_reason():
    pairer = StepPairer()
    for count in (1, 2):
        assert pairer.reject('increment', 'non_finite_increment') == 'non_finite_increment'
        assert pairer.received['increment'] == count
        assert pairer.drops['non_finite_increment'] == count
    assert pairer.received['measurement'] == 0
    assert pairer.accounted('increment') == 2


def test_a_sample_backward_by_backward_jump_is_stale_and_one_nanosecond_more_a_jump():
    pairer = StepPairer(timeout=0, backward_jump=1 * S)
    t = 10 * S
    pairer.add_angular_velocity(t, (0.1, 0.0, 0.0), 0)
    assert pairer.add_angular_velocity(t - 1 * S, (0.1, 0.0, 0.0), 0) == 'stale_increment'
    assert pairer.events['backward_jumps'] == 0
    for count in (1, 2):
        t -= 1 * S + 1
        assert pairer.add_angular_velocity(t, (0.1, 0.0, 0.0), 0) == BACKWARD_JUMP
        assert pairer.events['backward_jumps'] == count


def test_a_field_at_stamp_1_is_taken_and_one_backward_by_backward_jump_is_stale():
    pairer = StepPairer(timeout=0, backward_jump=1 * S)
    assert pairer.add_field(1, (2e-5, 0.0, -4e-5)) is None
    assert pairer.add_field(3 * S, (2e-5, 0.0, -4e-5)) is None
    assert pairer.add_field(2 * S, (2e-5, 0.0, -4e-5)) == 'stale_measurement'
    assert pairer.add_field(2 * S - 1, (2e-5, 0.0, -4e-5)) is None  # a jump back: taken
    assert pairer.field_stamp == 2 * S - 1


@pytest.mark.parametrize('constant_dt', [0.0, 0.005])
def test_arrival_order_takes_a_repeated_stamp_only_with_a_constant_dt(constant_dt):
    # imu_tools' constant_dt: with arrival_order and a constant_dt > 0
    # every sample is taken in the order it comes; without a constant_dt the
    # stamps rule (a repeated one is a duplicate).
    pairer = StepPairer(timeout=0, constant_dt=constant_dt, arrival_order=True)
    pairer.add_angular_velocity(2 * S, (0.1, 0.0, 0.0), 0)
    outcome = pairer.add_angular_velocity(2 * S, (0.1, 0.0, 0.0), 0)
    assert outcome == (None if constant_dt > 0.0 else 'duplicate_increment')


# The pairing rules' edges that mutmut's run of pairing.py (docs/tests.md#mutmut)
# found untested: each is a documented rule, checked at its bound.

@pytest.mark.parametrize('axis', [0, 1, 2])
def test_a_rate_with_one_non_finite_component_is_dropped(axis):
    pairer = StepPairer(timeout=0)
    for value in (math.nan, math.inf):
        rate = [0.1, 0.2, 0.3]
        rate[axis] = value
        assert pairer.add_angular_velocity(2 * S, tuple(rate), 0) == 'non_finite_increment'
    assert pairer.drops['non_finite_increment'] == 2
    assert pairer.waiting('increment') == 0


def test_an_increment_beyond_max_increment_is_dropped_on_the_general_path():
    pairer = StepPairer(timeout=0, max_increment=0.01)
    pairer.add_angular_velocity(2 * S, (1.0, 0.0, 0.0), 0)
    # 10 ms at 1 rad/s: 0.01 rad, at the bound (kept); at 1.1 rad/s beyond it.
    assert pairer.add_angular_velocity(2 * S + 10 * MS, (1.0, 0.0, 0.0), 0) is None
    assert pairer.add_angular_velocity(2 * S + 20 * MS, (1.2, 0.0, 0.0), 0) == (
        'increment_too_large')
    assert [s.stamp for s in pairer.pop_ready(0)] == [2 * S]
    assert pairer.drops['increment_too_large'] == 1


def test_a_step_waits_for_its_measurement_until_now_reaches_timeout():
    pairer = StepPairer(timeout=10 * MS)
    pairer.add_angular_velocity(2 * S, (0.1, 0.0, 0.0), 0)
    pairer.add_angular_velocity(2 * S + 5 * MS, (0.1, 0.0, 0.0), 0)
    assert pairer.pop_ready(0) == []
    assert pairer.pop_ready(10 * MS - 1) == []
    [step] = pairer.pop_ready(10 * MS)
    assert (step.stamp, step.measurement) == (2 * S, None)


def test_a_sample_at_stamp_1_after_a_later_one_is_a_backward_jump():
    # Stamp 1 ns is a stamp (only 0 and below are refused), here 10 s back.
    pairer = StepPairer(timeout=0)
    pairer.add_angular_velocity(10 * S, (0.1, 0.0, 0.0), 0)
    assert pairer.add_angular_velocity(0, (0.1, 0.0, 0.0), 0) == 'zero_stamp_increment'
    assert pairer.add_angular_velocity(1, (0.1, 0.0, 0.0), 0) == BACKWARD_JUMP
    assert pairer.pending_stamp == 1
    fresh = StepPairer(timeout=0)
    assert fresh.add_angular_velocity(1, (0.1, 0.0, 0.0), 0) is None
    assert fresh.add_increment(2, (0.0, 0.0, 0.0), 0) is None
    assert fresh.add_measurement(0, Y) == 'zero_stamp_measurement'


def test_in_arrival_order_stamps_only_mark_jumps_back():
    # imu_tools' constant_dt: samples are taken as they come, the first one
    # whatever its stamp; a jump back beyond backward_jump starts over
    # (counted each time) from that sample; exactly backward_jump back is a
    # step like any other.
    pairer = StepPairer(timeout=0, constant_dt=0.005, arrival_order=True, backward_jump=1 * S)
    assert pairer.add_angular_velocity(0, (0.1, 0.0, 0.0), 0) is None
    assert pairer.add_angular_velocity(10 * S, (0.1, 0.0, 0.0), 0) is None
    assert pairer.add_angular_velocity(9 * S, (0.1, 0.0, 0.0), 0) is None
    assert [s.stamp for s in pairer.pop_ready(0)] == [0, 10 * S]
    t = 9 * S
    for count in (1, 2):
        t -= 1 * S + 1
        assert pairer.add_angular_velocity(t, (0.1, 0.0, 0.0), 0) == BACKWARD_JUMP
        assert pairer.events['backward_jumps'] == count
        assert pairer.pending_stamp == t
    assert pairer.add_angular_velocity(t + 1, (0.2, 0.0, 0.0), 0) is None
    [step] = pairer.pop_ready(0)
    assert step.stamp == t and step.increment[0] == pytest.approx(0.15 * 0.005)


def test_add_sample_in_arrival_order_restarts_at_a_jump_back():
    pairer = StepPairer(timeout=0, constant_dt=0.005, arrival_order=True, backward_jump=1 * S)
    acc = (0.0, 0.0, 9.8)
    pairer.add_sample(10 * S, (0.1, 0.0, 0.0), acc)
    assert pairer.add_sample(5 * S, (0.1, 0.0, 0.0), acc) == (BACKWARD_JUMP, ())
    assert pairer.events['backward_jumps'] == 1
    # Without a constant interval, arrival order does not apply: a repeated
    # stamp is a duplicate on the one-call path too.
    plain = StepPairer(timeout=0, arrival_order=True)
    plain.add_sample(2 * S, (0.1, 0.0, 0.0), acc)
    assert plain.add_sample(2 * S, (0.1, 0.0, 0.0), acc) == ('duplicate_increment', ())


def test_add_sample_refuses_an_infinite_acceleration_and_an_increment_too_large():
    pairer = StepPairer(timeout=0, max_increment=0.01)
    acc = (0.0, 0.0, 9.8)
    pairer.add_sample(2 * S, (0.1, 0.0, 0.0), acc)
    assert pairer.add_sample(2 * S + 5 * MS, (0.1, 0.0, 0.0), (math.inf, 0.0, 9.8)) == (
        'non_finite_acceleration', ())
    # Trapezoid over 5 ms: 0.3 rad/s on average, 0.0015 rad, kept; 2.75 rad/s
    # on average, 0.01375 rad, beyond 0.01.
    outcome, steps = pairer.add_sample(2 * S + 5 * MS, (0.5, 0.0, 0.0), acc)
    assert outcome is None and len(steps) == 1
    assert pairer.add_sample(2 * S + 10 * MS, (5.0, 0.0, 0.0), acc) == ('increment_too_large', ())


def test_add_sample_with_a_timeout_waits_as_the_general_path_does():
    # The one-call path is for steps that wait for nothing; with a timeout
    # a step waits for its measurement (or the deadline) as it would.
    pairer = StepPairer(timeout=50 * MS)
    acc = (0.0, 0.0, 9.8)
    assert pairer.add_sample(2 * S, (0.1, 0.0, 0.0), acc) == (None, ())
    assert pairer.add_sample(2 * S + 5 * MS, (0.1, 0.0, 0.0), acc) == (None, ())
    assert pairer.waiting('increment') == 2
    [step] = pairer.pop_ready(50 * MS)
    assert step.stamp == 2 * S


def test_after_a_one_call_step_a_measurement_inside_it_is_stale_and_at_its_end_taken():
    acc = (0.0, 0.0, 9.8)
    for at, outcome in ((2 * S + 5 * MS - 1, 'stale_measurement'), (2 * S + 5 * MS, None)):
        pairer = StepPairer(timeout=0)
        pairer.add_sample(2 * S, (0.1, 0.0, 0.0), acc)
        [step] = pairer.add_sample(2 * S + 5 * MS, (0.1, 0.0, 0.0), acc)[1]
        assert (step.stamp, step.end) == (2 * S, 2 * S + 5 * MS)
        assert pairer.add_measurement(at, Y) == outcome
        # The uncorrected last step's start is stale too (not a duplicate).
        assert pairer.add_measurement(2 * S, Y) == 'stale_measurement'


def test_a_measurement_jump_back_is_counted_each_time_and_its_edge_is_stale():
    pairer = StepPairer(timeout=0, backward_jump=1 * S)
    pairer.add_increment(10 * S, (0.0, 0.0, 0.0), 0)
    pairer.pop_ready(0)
    assert pairer.add_measurement(9 * S, Y) == 'stale_measurement'
    assert pairer.add_measurement(9 * S - 1, Y) == BACKWARD_JUMP
    assert pairer.add_increment(20 * S, (0.0, 0.0, 0.0), 0) is None
    pairer.pop_ready(1)
    assert pairer.add_measurement(19 * S - 1, Y) == BACKWARD_JUMP
    assert pairer.events['backward_jumps'] == 2


def test_restart_returns_everything_it_discards():
    pairer = StepPairer(timeout=1 * S)
    pairer.add_angular_velocity(2 * S, (0.1, 0.0, 0.0), 0)
    pairer.add_angular_velocity(2 * S + 5 * MS, (0.1, 0.0, 0.0), 0)
    pairer.add_measurement(3 * S, Y)
    pairer.add_measurement(4 * S, Y)
    assert pairer.restart() == 4   # one step and one sample waiting, two measurements
    assert pairer.drops['discarded_increment'] == 2
    assert pairer.drops['discarded_measurement'] == 2


def test_a_later_measurement_releases_a_step_at_once_from_its_edge_on():
    # A publisher sends in stamp order: a measurement at or after a step's
    # limit (its end, or its stamp + 1 for a given increment) shows the
    # step's own is not coming.
    pairer = StepPairer(timeout=1 * S)
    pairer.add_angular_velocity(2 * S, (0.1, 0.0, 0.0), 0)
    pairer.add_angular_velocity(2 * S + 5 * MS, (0.1, 0.0, 0.0), 0)
    pairer.add_measurement(2 * S + 5 * MS, Y)
    [step] = pairer.pop_ready(0)
    assert (step.stamp, step.measurement) == (2 * S, None)
    given = StepPairer(timeout=1 * S)
    given.add_increment(2 * S, (0.0, 0.0, 0.0), 0)
    given.add_measurement(2 * S - 1, Y)   # older: no sign
    assert given.pop_ready(0) == []
    given.add_measurement(2 * S + 1, Y)
    [step] = given.pop_ready(0)
    assert (step.stamp, step.measurement) == (2 * S, None)


def test_a_step_released_for_depth_is_marked_early():
    pairer = StepPairer(depth=1, timeout=1 * S)
    pairer.add_increment(2 * S, (0.0, 0.0, 0.0), 0)
    pairer.add_increment(3 * S, (0.0, 0.0, 0.0), 0)
    [step] = pairer.pop_ready(0)
    assert step.stamp == 2 * S and step.early is True
    assert pairer.events['early_releases'] == 1


def test_forward_gaps_are_counted_each_time():
    pairer = StepPairer(timeout=0, forward_gap=1 * S)
    for k, stamp in enumerate((2 * S, 4 * S, 6 * S)):
        pairer.add_increment(stamp, (0.0, 0.0, 0.0), 0)
        [step] = pairer.pop_ready(0)
        assert step.gap == (k > 0)
    assert pairer.events['forward_gaps'] == 2


def test_the_measurements_of_a_step_after_its_first_are_dropped_at_its_release():
    # Three inside one 10 ms interval: the first corrects it, the others
    # (the last at end - 1 ns) are unpaired; one at its end waits.
    pairer = StepPairer(timeout=1 * S)
    t0 = 2 * S
    pairer.add_angular_velocity(t0, (0.0, 0.0, 0.0), 0)
    pairer.add_angular_velocity(t0 + 10 * MS, (0.0, 0.0, 0.0), 0)
    for stamp in (t0, t0 + 3 * MS, t0 + 10 * MS - 1, t0 + 10 * MS):
        pairer.add_measurement(stamp, Y)
    [step] = pairer.pop_ready(0)
    assert step.measurement == Y
    assert pairer.drops['unpaired_measurement'] == 2
    assert pairer.waiting('measurement') == 1


@pytest.mark.parametrize('constant_dt', [0.0, 0.004])
def test_the_one_call_step_is_the_trapezoid_of_the_two_rates(constant_dt):
    # Slow rates, so that an increment off by any factor still passes the
    # bound and shows; over the stamps' 5 ms, or constant_dt when given.
    pairer = StepPairer(timeout=0, constant_dt=constant_dt)
    acc = (0.0, 0.0, 9.8)
    pairer.add_sample(2 * S, (0.001, -0.002, 0.0), acc)
    outcome, [step] = pairer.add_sample(2 * S + 5 * MS, (0.003, 0.0, 0.001), acc)
    dt = constant_dt or 0.005
    assert outcome is None
    assert step.increment == pytest.approx((0.002 * dt, -0.001 * dt, 0.0005 * dt), rel=1e-12)


def test_a_measurement_for_a_given_increment_already_released_is_stale():
    # The step of 2 s went on without one: its measurement, late, is stale
    # (not taken, not a duplicate); one for the next stamp is taken.
    pairer = StepPairer(timeout=0)
    pairer.add_increment(2 * S, (0.0, 0.0, 0.0), 0)
    [step] = pairer.pop_ready(0)
    assert step.measurement is None
    assert pairer.add_measurement(2 * S, Y) == 'stale_measurement'
    # The increment again, corrected or not, is a duplicate.
    assert pairer.add_increment(2 * S, (0.0, 0.0, 0.0), 0) == 'duplicate_increment'
    assert pairer.add_measurement(3 * S, Y) is None
    assert pairer.add_increment(3 * S, (0.0, 0.0, 0.0), 0) is None
    [step] = pairer.pop_ready(0)
    assert step.measurement == Y
    # Corrected, its stamp again is a duplicate.
    assert pairer.add_measurement(3 * S, Y) == 'duplicate_measurement'


def test_an_unknown_setting_is_refused_by_name():
    with pytest.raises(TypeError, match="unknown setting 'max_gap'"):
        StepPairer().configure(max_gap=1)


def test_a_default_pairer_refuses_a_measurement_off_unit_norm_by_more_than_10_percent():
    pairer = StepPairer()
    assert pairer.add_measurement(2 * S, (1.09, 0.0, 0.0, 0.0)) is None
    assert pairer.add_measurement(3 * S, (1.12, 0.0, 0.0, 0.0)) == 'norm_out_of_tolerance'
