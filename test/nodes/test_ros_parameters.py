"""
The parameter rows declared with rclpy (``nodes/ros_parameters.py``): each
row's ``ParameterDescriptor`` (range by type, read-only, constraints,
dynamic typing). (On real nodes, every row: ``nodes/test_node_parameters.py``.)
"""

from ext_observer.nodes.ros_parameters import descriptor
from ext_observer.pipeline.parameter_specs import ParameterSpec


def test_a_float_row_has_a_floating_point_range_and_its_words():
    d = descriptor(ParameterSpec('alpha', 0.01, 'Gain.', (0.0, 1.0), read_only=True,
                                 constraints='Must be certified.'))
    assert d.description == 'Gain.' and d.read_only
    assert d.additional_constraints == 'Must be certified.'
    [r] = d.floating_point_range
    assert (r.from_value, r.to_value, r.step) == (0.0, 1.0, 0.0)
    assert len(d.integer_range) == 0 and not d.dynamic_typing


def test_an_integer_row_has_an_integer_range_and_others_none():
    [r] = descriptor(ParameterSpec('depth', 100, 'Depth.', (1, 10000))).integer_range
    assert (r.from_value, r.to_value, r.step) == (1, 10000, 1)
    d = descriptor(ParameterSpec('mode', 'auto', 'Mode.', dynamic=True))
    assert d.dynamic_typing and not d.read_only
    assert len(d.integer_range) == 0 and len(d.floating_point_range) == 0
