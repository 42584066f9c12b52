"""
The unit check (``pipeline/units.py``): samples only a wrong unit explains
are counted, by kind, with a finding that names the likely unit; plausible
samples and ones that are merely bad (not finite, zero) are not.
"""

import math

from ext_observer.pipeline.units import ACC_WINDOW, RATE_MAX, UnitCheck

G = 9.80665


def test_rates_beyond_the_range_count_as_deg_per_s_on_any_axis():
    check = UnitCheck()
    check.imu((RATE_MAX, -RATE_MAX, 0.0), (0.0, 0.0, G))
    assert check.counts['angular_velocity'] == 0
    for axis in range(3):
        gyr = [0.0, 0.0, 0.0]
        gyr[axis] = -1.01 * RATE_MAX
        check.imu(gyr, (0.0, 0.0, G))
    check.imu((math.inf, 0.0, 0.0), (0.0, 0.0, G))
    assert check.counts['angular_velocity'] == 3
    assert 'is it deg/s?' in check.findings['angular_velocity']


def test_a_specific_force_in_g_is_found_over_a_window():
    check = UnitCheck()
    for _ in range(ACC_WINDOW - 1):
        check.imu((0.0, 0.0, 0.0), (0.0, 0.0, 1.0))
    assert check.counts['acceleration'] == 0
    check.imu((0.0, 0.0, 0.0), (0.0, 0.0, 1.0))
    assert check.counts['acceleration'] == ACC_WINDOW
    assert check.findings['acceleration'].endswith('is it g?')
    for _ in range(ACC_WINDOW):
        check.imu((0.0, 0.0, 0.0), (0.0, 0.0, G))
        check.imu((0.0, 0.0, 0.0), (0.0, math.nan, G))  # not finite: not counted
    assert check.counts['acceleration'] == ACC_WINDOW


def test_a_field_in_microtesla_or_gauss_is_named_and_tesla_passes():
    check = UnitCheck()
    for field in ((2e-5, 0.0, -4e-5), (0.0, 0.0, 0.0), (math.nan, 0.0, 0.0)):
        check.field(field)
    assert check.counts['field'] == 0
    check.field((20.0, 0.0, -40.0))
    assert check.findings['field'].endswith('is it µT?')
    check.field((0.2, 0.0, -0.4))
    assert check.findings['field'].endswith('is it gauss?')
    check.field((1e-9, 0.0, 0.0))
    assert check.counts['field'] == 3 and 'is it' not in check.findings['field']
