"""
The robustness benchmark's variants (``broad/stress.py``) on a synthetic
trial (no BROAD needed): the cut, the bias, the 50 Hz blocks, the clipping,
the halves. The runner: test_stress_run.py; the command ``broad --stress``
end to end: test_cli.py.
"""

import math

import numpy as np
import pytest

from ext_observer import broad
from ext_observer.broad import stress

RATE = 2000.0 / 7.0  # Hz, BROAD's 285.714...


def synthetic_trial(name='07_synthetic', n=1000, rest=137, seed=1):
    """Numbered columns that show where each output sample came from."""
    rng = np.random.default_rng(seed)
    gyr = 6.0 * rng.standard_normal((n, 3))  # rad/s: often beyond the 4.36 range
    acc = rng.standard_normal((n, 3)) + (0.0, 0.0, 9.81)
    mag = rng.standard_normal((n, 3)) + (20.0, 0.0, -40.0)
    quat = rng.standard_normal((n, 4))
    quat /= np.linalg.norm(quat, axis=1, keepdims=True)
    quat[300:310] = np.nan  # a gap of the optical reference
    movement = np.ones(n, dtype=bool)
    movement[:rest] = False
    movement[600:650] = False  # a pause later on
    return broad.Trial(name, gyr, acc, mag, quat, movement, RATE)


def test_as_recorded_is_the_trial():
    t = synthetic_trial()
    assert stress.variant(t, 'a') is t


def test_cut_starts_at_the_first_movement_sample():
    t = synthetic_trial(rest=137)
    b = stress.variant(t, 'b')
    assert len(b) == len(t) - 137
    assert b.movement[0]
    for name in ('gyr', 'acc', 'mag', 'quat', 'movement'):
        np.testing.assert_array_equal(getattr(b, name), getattr(t, name)[137:])
    assert b.rate == t.rate and b.name == t.name
    # The later pause stays: only the rest before the motion goes.
    assert not b.movement[600 - 137:650 - 137].any()


def test_bias_is_one_degree_per_second_constant_and_fixed_per_trial():
    t = synthetic_trial()
    b, c = stress.variant(t, 'b'), stress.variant(t, 'c')
    added = c.gyr - b.gyr
    np.testing.assert_allclose(added, np.tile(added[0], (len(added), 1)), atol=1e-12)
    assert math.degrees(np.linalg.norm(added[0])) == pytest.approx(1.0, abs=1e-9)
    np.testing.assert_allclose(added[0], stress.bias_of(t.name), atol=1e-12)
    for name in ('acc', 'mag', 'quat', 'movement'):
        np.testing.assert_array_equal(getattr(c, name), getattr(b, name))
    # The same on every call, another direction for another trial.
    np.testing.assert_array_equal(stress.bias_of(t.name), stress.bias_of(t.name))
    other = stress.bias_of('08_other')
    assert np.degrees(np.arccos(np.dot(other, added[0]) / stress.BIAS ** 2)) > 1.0
    # The trial given is not changed.
    np.testing.assert_array_equal(t.gyr, synthetic_trial().gyr)


def test_50_hz_blocks_are_averages_with_the_right_length_and_times():
    t = synthetic_trial()
    c, d = stress.variant(t, 'c'), stress.variant(t, 'd')
    assert d.rate == 50.0
    # Complete 20 ms blocks of (c): its duration × 50 Hz, rounded down.
    assert len(d) == math.floor(len(c) * 50.0 / RATE)
    start = 0
    for k in range(len(d)):
        # Block k: the samples at times i / RATE = 7 i / 2000 s in [k, k + 1) / 50 s,
        # that is 40 k <= 7 i < 40 (k + 1), in exact integers.
        stop = start
        while stop < len(c) and 7 * stop < 40 * (k + 1):
            stop += 1
        assert 40 * k <= 7 * start < 40 * (k + 1)
        assert stop - start in (5, 6)
        for name in ('gyr', 'acc', 'mag'):
            np.testing.assert_allclose(getattr(d, name)[k],
                                       getattr(c, name)[start:stop].mean(axis=0), rtol=1e-12)
        # Reference and movement flag of the block's last sample.
        np.testing.assert_array_equal(d.quat[k], c.quat[stop - 1])
        assert d.movement[k] == c.movement[stop - 1]
        start = stop
    # What is left over is an incomplete block.
    assert 7 * len(c) < 40 * (len(d) + 1)


def test_blocks_of_rates_that_divide():
    block, count = stress.blocks(10, 100.0, 50.0)
    np.testing.assert_array_equal(block, [0, 0, 1, 1, 2, 2, 3, 3, 4, 4])
    assert count == 5
    block, count = stress.blocks(9, 100.0, 50.0)
    assert count == 4
    with pytest.raises(ValueError, match='low_rate'):
        stress.blocks(10, 40.0, 50.0)


def test_clipping_clips_exactly_at_the_range_per_axis_and_leaves_the_rest():
    t = synthetic_trial()
    e = stress.variant(t, 'e')
    limit = math.radians(250.0)
    assert limit == pytest.approx(4.363, abs=5e-4)
    inside = np.abs(t.gyr) <= limit
    assert inside.any() and (~inside).any()
    np.testing.assert_array_equal(e.gyr[inside], t.gyr[inside])
    np.testing.assert_array_equal(e.gyr[~inside], np.sign(t.gyr[~inside]) * limit)
    for name in ('acc', 'mag', 'quat', 'movement'):
        np.testing.assert_array_equal(getattr(e, name), getattr(t, name))


def test_unknown_variant_and_trial_without_movement_are_errors():
    t = synthetic_trial()
    with pytest.raises(ValueError, match='variant must be one of'):
        stress.variant(t, 'f')
    still = broad.Trial('09_still', t.gyr, t.acc, t.mag, t.quat, np.zeros(len(t), bool), RATE)
    with pytest.raises(ValueError, match='no movement'):
        stress.variant(still, 'b')


# --- end to end ------------------------------------------------------------
