"""
``ros2 param dump`` on every node: list, get all, write the file, load it back.

rclpy's ``get_parameters`` answers nothing for a whole request that names a
parameter declared with a type and no value; ``ros2 param dump`` then prints
``ros__parameters: {}`` without an error. Each node is asked here as
ros2cli asks it, through its parameter services over DDS: the answer must
hold a set value for every name listed, and the file written from it must
start the node again with the same values.
"""

import pytest
from rcl_interfaces.msg import ParameterType
from rcl_interfaces.srv import GetParameters, ListParameters
import rclpy
from rclpy.context import Context
from rclpy.node import Node

from ext_observer.nodes.gyro_node import GyroNode
from ext_observer.nodes.imu_filter_node import ImuFilterNode
from ext_observer.nodes.monitor_node import MonitorNode
from ext_observer.nodes.observer_node import ObserverNode

NODES = (GyroNode, ObserverNode, MonitorNode, ImuFilterNode)

_FIELDS = {
    ParameterType.PARAMETER_BOOL: 'bool_value',
    ParameterType.PARAMETER_INTEGER: 'integer_value',
    ParameterType.PARAMETER_DOUBLE: 'double_value',
    ParameterType.PARAMETER_STRING: 'string_value',
    ParameterType.PARAMETER_BOOL_ARRAY: 'bool_array_value',
    ParameterType.PARAMETER_INTEGER_ARRAY: 'integer_array_value',
    ParameterType.PARAMETER_DOUBLE_ARRAY: 'double_array_value',
    ParameterType.PARAMETER_STRING_ARRAY: 'string_array_value',
}


def _call(spinner, client, request):
    spinner.spin_until(lambda: client.service_is_ready(), 10.0, client.srv_name)
    future = client.call_async(request)
    spinner.spin_until(future.done, 10.0, f'the answer of {client.srv_name}')
    return future.result()


def dump(spinner, asker, node_name):
    """Return ``{name: value}`` of ``node_name`` as ``ros2 param dump`` gets it."""
    names = _call(spinner, asker.create_client(ListParameters, f'/{node_name}/list_parameters'),
                  ListParameters.Request()).result.names
    answer = _call(spinner, asker.create_client(GetParameters, f'/{node_name}/get_parameters'),
                   GetParameters.Request(names=list(names)))
    assert len(answer.values) == len(names), (
        f'/{node_name}/get_parameters answered {len(answer.values)} values for '
        f'{len(names)} names (a parameter without a value?)')
    values = {}
    for name, value in zip(names, answer.values):
        assert value.type in _FIELDS, f'{name} has no value (type {value.type})'
        field = getattr(value, _FIELDS[value.type])
        values[name] = list(field) if value.type >= ParameterType.PARAMETER_BYTE_ARRAY \
            else field
    return values


def _yaml(value):
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, str):
        return "'" + value.replace("'", "''") + "'"
    if isinstance(value, list):
        return '[' + ', '.join(_yaml(v) for v in value) + ']'
    return repr(value)


def write_params_file(path, node_name, values):
    """Write ``values`` as ros2 param dump does: nested by the dots in the names."""
    tree = {}
    for name, value in sorted(values.items()):
        *parents, leaf = name.split('.')
        branch = tree
        for parent in parents:
            branch = branch.setdefault(parent, {})
        branch[leaf] = value

    def lines(branch, indent):
        for key, value in branch.items():
            if isinstance(value, dict):
                yield f'{" " * indent}{key}:'
                yield from lines(value, indent + 2)
            else:
                yield f'{" " * indent}{key}: {_yaml(value)}'

    text = '\n'.join([f'/{node_name}:', '  ros__parameters:', *lines(tree, 4)]) + '\n'
    path.write_text(text)


@pytest.mark.parametrize('node_class', NODES, ids=lambda c: c.NODE_NAME)
def test_param_dump_answers_every_parameter_and_loads_back(
        ros_context, ros_domain_id, spinner, tmp_path, node_class):
    node = spinner.add(node_class(context=ros_context))
    asker = spinner.add(Node('param_dump', context=ros_context))
    values = dump(spinner, asker, node.get_name())
    declared = {spec.name for spec in node.parameters._specs}
    assert declared <= set(values), declared - set(values)
    # ros2 param get on the parameters that had no value before.
    for name in declared & {'align_sign', 'increment_source', 'initial_attitude'}:
        assert values[name] not in (None, [], ''), name

    # The dumped file starts the node again with the same values.
    path = tmp_path / f'{node_class.NODE_NAME}.yaml'
    write_params_file(path, node.get_name(), values)
    context = Context()
    rclpy.init(args=['--ros-args', '--params-file', str(path)], context=context,
               domain_id=ros_domain_id)
    try:
        again = node_class(context=context)
        try:
            for name in declared:
                assert again.get_parameter(name).value == pytest.approx(values[name]) \
                    if isinstance(values[name], float) else \
                    list(again.get_parameter(name).value) == values[name] \
                    if isinstance(values[name], list) else \
                    again.get_parameter(name).value == values[name], name
            assert not (node_class is ImuFilterNode and again.parameters.given & {
                'gain', 'zeta', 'publish_tf'}), 'a dump reloaded must not warn'
        finally:
            again.destroy_node()
    finally:
        rclpy.try_shutdown(context=context)
