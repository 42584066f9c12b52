"""The one place where ROS's (x, y, z, w) meets the core's (w, x, y, z)."""

import math
import struct

from builtin_interfaces.msg import Time
from geometry_msgs.msg import Quaternion, Vector3
from hypothesis import given, settings, strategies as st
import numpy as np
from numpy.testing import assert_allclose
import pytest

from ext_observer.nodes.conversions import (
    msg_from_quaternion, msg_from_vector, nanoseconds_from_stamp, quaternion_from_msg,
    quaternion_stamped, stamp_from_nanoseconds, STAMP_MAX, vector_from_msg, vector_stamped)
from ext_observer.core import quaternion_from_rotation_vector

finite = st.floats(allow_nan=False, allow_infinity=False, width=64)
# NaN (any payload), infinities, subnormals, ±0 and the largest doubles.
any_float = st.floats(allow_nan=True, allow_infinity=True, allow_subnormal=True, width=64)


def bits(values):
    """The IEEE 754 bits of each float: equal even for NaN, distinct for ±0."""
    return [struct.pack('<d', v) for v in values]


def test_field_order_is_scalar_first():
    msg = msg_from_quaternion((1.0, 2.0, 3.0, 4.0))
    assert (msg.w, msg.x, msg.y, msg.z) == (1.0, 2.0, 3.0, 4.0)
    assert quaternion_from_msg(msg) == (1.0, 2.0, 3.0, 4.0)


def test_rotation_about_z_keeps_its_meaning():
    # A quarter turn about z: (w, x, y, z) = (cos π/4, 0, 0, sin π/4).
    q = quaternion_from_rotation_vector(np.array([0.0, 0.0, math.pi / 2]))
    msg = msg_from_quaternion(q)
    assert msg.z == pytest.approx(math.sqrt(0.5))
    assert msg.w == pytest.approx(math.sqrt(0.5))
    assert msg.x == msg.y == 0.0


@settings(deadline=None)
@given(st.tuples(finite, finite, finite, finite))
def test_quaternion_round_trip(q):
    assert quaternion_from_msg(msg_from_quaternion(q)) == q


@settings(deadline=None)
@given(st.tuples(finite, finite, finite))
def test_vector_round_trip(v):
    assert vector_from_msg(msg_from_vector(v)) == v


def test_numpy_input():
    q = np.array([0.5, -0.5, 0.5, -0.5])
    assert_allclose(quaternion_from_msg(msg_from_quaternion(q)), q)
    assert vector_from_msg(msg_from_vector(np.arange(3.0))) == (0.0, 1.0, 2.0)


@pytest.mark.parametrize('values', [(1.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0, 0.0)])
def test_quaternion_needs_four(values):
    with pytest.raises(ValueError, match='needs 4 elements, got'):
        msg_from_quaternion(values)


def test_vector_needs_three():
    with pytest.raises(ValueError, match='needs 3 elements, got 4'):
        msg_from_vector((1.0, 2.0, 3.0, 4.0))


@settings(deadline=None)
@given(st.tuples(any_float, any_float, any_float, any_float))
def test_any_float_survives_both_ways(q):
    # What arrives on a topic is copied bit for bit and never raises; the
    # checks are the observer's (test_pairing.py).
    msg = Quaternion(x=q[1], y=q[2], z=q[3], w=q[0])
    assert bits(quaternion_from_msg(msg)) == bits(q)
    assert bits(quaternion_from_msg(msg_from_quaternion(q))) == bits(q)
    assert bits(vector_from_msg(Vector3(x=q[0], y=q[1], z=q[2]))) == bits(q[:3])
    assert bits(vector_from_msg(msg_from_vector(q[1:]))) == bits(q[1:])


@settings(deadline=None)
@given(st.integers(min_value=0, max_value=STAMP_MAX))
def test_stamp_round_trip(nanoseconds):
    stamp = stamp_from_nanoseconds(nanoseconds)
    assert 0 <= stamp.nanosec < 10 ** 9
    assert nanoseconds_from_stamp(stamp) == nanoseconds


@settings(deadline=None)
@given(st.integers(-2 ** 31, 2 ** 31 - 1), st.integers(0, 2 ** 32 - 1))
def test_any_stamp_converts(sec, nanosec):
    # Negative seconds and nanosec beyond a second exist on the wire: the
    # conversion never raises; a time at or before 0 is dropped by the
    # observer with the zero stamps.
    assert nanoseconds_from_stamp(Time(sec=sec, nanosec=nanosec)) == sec * 10 ** 9 + nanosec


@pytest.mark.parametrize('nanoseconds', [-1, STAMP_MAX + 1, 2 ** 80])
def test_out_of_range_stamp_is_refused(nanoseconds):
    with pytest.raises(ValueError, match='a stamp must lie in'):
        stamp_from_nanoseconds(nanoseconds)


def test_stamped_messages():
    msg = quaternion_stamped((1.0, 0.0, 0.0, 0.0), 3_000_000_007, 'world')
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (3, 7)
    assert msg.header.frame_id == 'world'
    assert msg.quaternion.w == 1.0
    vector = vector_stamped((0.1, 0.2, 0.3), 5, 'base_link')
    assert nanoseconds_from_stamp(vector.header.stamp) == 5
    assert vector_from_msg(vector.vector) == (0.1, 0.2, 0.3)
