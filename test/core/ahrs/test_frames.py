"""
The estimator's world frames and first attitude (``frames.py``), no ROS.

:func:`initial_attitude` from gravity and the field (the heading from the
field, or the smallest rotation without one), :func:`world_from_enu` and
its frames as REP 103 names them, :func:`check_dt`'s refusals.
"""

import math

import numpy as np
from numpy.testing import assert_allclose
import pytest

from ext_observer.core import quaternion as quat
from ext_observer.core.ahrs.frames import (check_dt, initial_attitude, WORLD_FRAMES,
                                              world_from_enu)
from synthetic_motion import errors_deg, FIELD, rotate, synthetic


@pytest.fixture(scope='module')
def motion():
    return synthetic()


def test_initial_attitude_from_gravity_and_field(motion):
    truth, gyr, acc, mag = motion
    q = np.asarray(initial_attitude(tuple(acc[0]), tuple(mag[0])))
    total, _, _ = errors_deg(q, truth[0])
    assert total < 1.0
    q6 = np.asarray(initial_attitude(tuple(acc[0])))
    _, _, incl = errors_deg(q6, truth[0])
    assert incl < 1.0


@pytest.mark.parametrize('frame, east', [('enu', (1, 0, 0)), ('nwu', (0, -1, 0)),
                                         ('ned', (0, 1, 0))])
def test_world_frames_name_east_as_rep_103_does(frame, east):
    q = world_from_enu(np.array([1.0, 0.0, 0.0, 0.0]), frame)
    assert_allclose(rotate(q, np.array([1.0, 0.0, 0.0])), east, atol=1e-15)
    up = {'enu': (0, 0, 1), 'nwu': (0, 0, 1), 'ned': (0, 0, -1)}[frame]
    assert_allclose(rotate(q, np.array([0.0, 0.0, 1.0])), up, atol=1e-15)


def _same_rotation(a, b):
    return min(np.abs(np.asarray(a) - np.asarray(b)).max(),
               np.abs(np.asarray(a) + np.asarray(b)).max())


@pytest.mark.parametrize('seed', range(5))
def test_the_first_attitude_of_noise_free_samples_is_the_truth(seed):
    rng = np.random.default_rng(seed)
    truth = quat.normalize(rng.normal(size=4))
    acc = rotate(quat.conjugate(truth), np.array([0.0, 0.0, 9.81]))
    mag = rotate(quat.conjugate(truth), FIELD)
    assert _same_rotation(initial_attitude(tuple(acc), tuple(mag)), truth) < 1e-12
    # Without the field (or told not to use it): the inclination only.
    for q in (initial_attitude(tuple(acc)), initial_attitude(tuple(acc), tuple(mag), False)):
        _, _, incl = errors_deg(np.asarray(q), truth)
        assert incl < 1e-5  # degrees: arccos near 1 resolves no finer


def test_without_a_field_the_first_attitude_is_the_smallest_rotation_to_the_vertical():
    # The accelerometer's axis tilted about x only: the rotation is about x.
    a = math.radians(30.0)
    q = initial_attitude((0.0, 9.81 * math.sin(a), 9.81 * math.cos(a)))
    assert_allclose(q, (math.cos(a / 2), math.sin(a / 2), 0.0, 0.0), atol=1e-12)
    assert initial_attitude((0.0, 0.0, 9.81), (1.0, 2.0, 3.0), use_mag=False) == (
        initial_attitude((0.0, 0.0, 9.81)))


def test_the_world_frames_are_unit_quaternions_and_apply_to_any_shape():
    for c in WORLD_FRAMES.values():
        assert sum(v * v for v in c) == pytest.approx(1.0, abs=1e-15)
    q = quat.normalize(np.random.default_rng(2).normal(size=(3, 5, 4)))
    for frame in WORLD_FRAMES:
        out = world_from_enu(q, frame)
        assert out.shape == q.shape
        assert_allclose(out[1, 2], world_from_enu(q[1, 2], frame), atol=0.0)
    assert_allclose(world_from_enu(q, 'enu'), q, atol=0.0)


def test_an_unknown_world_frame_is_refused_by_name():
    with pytest.raises(ValueError, match="frame must be one of .*got 'end'"):
        world_from_enu((1.0, 0.0, 0.0, 0.0), 'end')


@pytest.mark.parametrize('dt', [0.0, -0.01, math.inf, math.nan])
def test_an_interval_not_positive_and_finite_is_refused(dt):
    with pytest.raises(ValueError, match='dt must be positive and finite'):
        check_dt(dt)


def test_a_positive_finite_interval_passes():
    assert check_dt(1e-9) is None and check_dt(0.01) is None
