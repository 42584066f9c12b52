"""
A whole recording's unit check (``recordings/input_units.py``): judged on
typical samples (the median force and field, the rate at the 99th
percentile), refused with every finding, a few fast samples taken as motion.
"""

import math

import numpy as np
import pytest

from ext_observer.recordings.input_units import check_units

N = 1000


def recording():
    rng = np.random.default_rng(2)
    gyr = rng.normal(0.0, 0.5, (N, 3))
    acc = rng.normal(0.0, 0.1, (N, 3)) + (0.0, 0.0, 9.81)
    mag = rng.normal(0.0, 1e-7, (N, 3)) + (2e-5, 0.0, -4e-5)
    return gyr, acc, mag


def test_si_units_pass_and_a_few_fast_or_bad_samples_are_motion():
    gyr, acc, mag = recording()
    gyr[:5] = 100.0  # under 1 % of the samples beyond the range
    acc[7] = math.nan
    mag[9] = (20.0, 0.0, -40.0)
    check_units(gyr, acc, mag)
    check_units(gyr, acc, None)


def test_every_wrong_unit_is_named_in_one_error():
    gyr, acc, mag = recording()
    with pytest.raises(ValueError, match=r'gyr: .*deg/s\?; acc: .*is it g\?; mag: .*is it µT\?'
                                         r' \(check_units=False runs it as it is\)'):
        check_units(np.degrees(gyr) * 100, acc / 9.81, mag * 1e6)


def test_a_rate_beyond_the_range_on_most_samples_is_a_unit():
    gyr, acc, mag = recording()
    gyr[: N // 50] = 100.0  # 2 % of the samples: the 99th percentile sees them
    with pytest.raises(ValueError, match='gyr: angular velocity 100'):
        check_units(gyr, acc, mag)
