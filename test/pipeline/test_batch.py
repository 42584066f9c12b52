"""
Many recordings at once (``pipeline/batch.py``): a non-finite sample held at
the last finite one, inputs refused by what is wrong, each recording equal
to it run alone, what ``then`` returns. (The estimates in workers against this
process: ``core/ahrs/test_ahrs_observer.py``.)
"""

import math

import numpy as np
from numpy.testing import assert_array_equal
import pytest

from ext_observer.core.ahrs.ahrs_observer import AhrsObserver, AhrsParams
from ext_observer.pipeline.batch import estimate_batch, hold_finite

RATE = 100.0


def test_a_non_finite_sample_is_the_last_finite_one_and_the_first_the_first_finite():
    a = np.array([[math.nan, 0, 0], [1, 2, 3], [4, math.inf, 6], [7, 8, 9], [0, 0, math.nan]])
    assert_array_equal(hold_finite(a), [[1, 2, 3], [1, 2, 3], [1, 2, 3], [7, 8, 9], [7, 8, 9]])
    finite = np.ones((3, 3))
    assert hold_finite(finite) is finite
    with pytest.raises(ValueError, match='no finite sample'):
        hold_finite(np.full((2, 3), math.nan))


def test_inputs_are_refused_by_what_is_wrong():
    z = np.zeros((10, 3))
    with pytest.raises(ValueError, match='one entry per recording'):
        estimate_batch([z, z], [z], [z, z], [RATE, RATE], [True, True])
    with pytest.raises(ValueError, match=r'one sampling rate, got \[100.0, 200.0\]'):
        estimate_batch([z, z], [z, z], [z, z], [RATE, 200.0], [True, True])


def test_each_recording_equals_it_run_alone_with_its_bad_samples_held():
    rng = np.random.default_rng(4)
    gyr = [rng.normal(0.0, 0.3, (300, 3)) for _ in range(2)]
    acc = [rng.normal(0.0, 0.2, (300, 3)) + (0.0, 0.0, 9.81) for _ in range(2)]
    mag = [rng.normal(0.0, 0.5, (300, 3)) + (20.0, 0.0, -40.0) for _ in range(2)]
    gyr[1][50] = math.nan
    params = AhrsParams(tau_acc=1.0)
    out, after = estimate_batch(gyr, acc, mag, [RATE, RATE], [True, False], params=params,
                                then=lambda i, q: (i, len(q)))
    for i, use_mag in enumerate((True, False)):
        alone = AhrsObserver(params, use_mag=use_mag).run(
            hold_finite(gyr[i]), acc[i], mag[i] if use_mag else None, 1.0 / RATE)
        assert_array_equal(out[i], alone)
    assert np.all(np.isfinite(out[1]))
    assert after == [(0, 300), (1, 300)]
