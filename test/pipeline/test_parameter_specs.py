"""
The parameter rows as plain data (``pipeline/parameter_specs.py``): ROS type
names, defaults as written, a row from a core table's, the common checks.
"""

import pytest

from ext_observer.core.ahrs.parameter_rows import Tunable
from ext_observer.pipeline.parameter_specs import (COMMON_PARAMETERS, common_settings,
                                                   ParameterSpec, ros_type_name,
                                                   spec_from_tunable)


@pytest.mark.parametrize('value, name', [
    (True, 'bool'), (3, 'integer'), (0.5, 'double'), ('auto', 'string'),
    ([1.0, 2.0], 'double_array'), ([1, 2], 'integer_array'), ([False], 'bool_array'),
    (['a'], 'string_array'), ([], 'byte_array')])
def test_the_ros_type_of_a_python_value_is_rclpys(value, name):
    assert ros_type_name(value) == name


def test_a_value_without_a_ros_type_is_refused():
    with pytest.raises(TypeError, match='no ROS parameter type'):
        ros_type_name([1.0, 'a'])
    with pytest.raises(TypeError, match='every parameter needs a default'):
        ParameterSpec('x', None, 'x.')
    with pytest.raises(TypeError, match='a range needs an int or float default'):
        ParameterSpec('x', True, 'x.', (0, 1))


def test_defaults_are_written_as_yaml_and_types_named_for_the_docs():
    assert ParameterSpec('a', [True, 0.5, 'x'], 'a.').default_text == "[true, 0.5, 'x']"
    assert ParameterSpec('b', False, 'b.').default_text == 'false'
    assert ParameterSpec('c', 'auto', 'c.', dynamic=True).type_name == 'string or bool'
    assert ParameterSpec('d', 2, 'd.', (1, 3)).type_name == 'integer'


def test_a_core_row_becomes_a_read_only_prefixed_parameter_with_its_rule():
    row = Tunable('tau', 3.0, 's', 0.0, 100.0, 'time constant', high_open=True)
    spec = spec_from_tunable(row, 'ahrs.', 'Estimator')
    assert (spec.name, spec.default, spec.range) == ('ahrs.tau', 3.0, (0.0, 100.0))
    assert spec.description == 'Estimator: time constant, s.'
    assert spec.read_only and spec.constraints == 'Must be > 0 and < 100.'
    flag = spec_from_tunable(Tunable('on', True, '', None, None, 'on'), 'ahrs.', 'E')
    assert flag.range is None and flag.constraints == ''


def test_the_common_checks_refuse_an_unknown_forward_gap_action():
    values = {spec.name: spec.default for spec in COMMON_PARAMETERS}
    common_settings(values)
    with pytest.raises(ValueError, match="forward_gap_action must be one of .* got 'stop'"):
        common_settings(dict(values, forward_gap_action='stop'))
