"""
What the estimator's kernel must leave alone (no ROS): found by mutmut's sample of ahrs_kernel.py.

In 9D the IMU samples come without a field (fields have their own calls, at
their own rate): a sample without one must not touch the field's state (a
kernel that ran the field's step on the zeros of a missing field would take
them as the references). A reset forgets the last field's verdict with the
rest. Fast: part of ``make mutation``'s subset of the kernel
(docs/tests.md#mutmut).
"""

import numpy as np

from ext_observer.core.ahrs.ahrs_layout import S_HAS_REF, S_MAG_USED, S_REF
from ext_observer.core.ahrs.estimator import AhrsObserver, AhrsParams

DT = 0.01
TILTED = (1.2, -0.8, 9.7)
FIELD = (1.5e-5, 1.0e-5, -3.5e-5)


def field_state(est):
    s = est.flat_state
    return [s[S_HAS_REF], s[S_REF], s[S_REF + 1], s[S_MAG_USED]]


def test_in_9d_samples_without_a_field_leave_the_fields_state_and_the_heading():
    est = AhrsObserver(AhrsParams(), use_mag=True)
    # None yet: no references from a field that never came.
    for _ in range(50):
        est.update((0.0, 0.0, 0.0), TILTED, None, DT)
    assert field_state(est) == [0.0, 0.0, 0.0, 0.0]
    for _ in range(20):
        est.update((0.0, 0.0, 0.0), TILTED, FIELD, DT)
    before, q = field_state(est), np.array(est.q)
    assert before[0] == 1.0 and before[1] > 0.0
    for _ in range(50):
        est.update((0.0, 0.0, 0.0), TILTED, None, DT)
    assert field_state(est) == before
    assert np.allclose(est.q, q, atol=1e-9)


def test_a_reset_forgets_that_the_last_field_was_disturbed():
    est = AhrsObserver(AhrsParams(), use_mag=True)
    for _ in range(20):
        est.update((0.0, 0.0, 0.0), TILTED, FIELD, DT)
    est.update((0.0, 0.0, 0.0), TILTED, tuple(3.0 * v for v in FIELD), DT)
    assert est.mag_disturbed is True
    est.reset()
    assert est.mag_disturbed is False
