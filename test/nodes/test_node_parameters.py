"""
The observer's, gyro's and monitor's parameters (``nodes/node_parameters.py``)
on real nodes: a params file honoured, the shipped one loading with the
defaults and listing every parameter with a comment, invalid values refused
with their reason at start-up and at runtime, a descriptor for each.
"""

import math

from numpy.testing import assert_allclose
import pytest
import rclpy
from rclpy.parameter import Parameter

from conftest import CONFIG
from ext_observer.nodes.gyro_node import GyroNode
from ext_observer.nodes.monitor_node import MonitorNode
from ext_observer.nodes.node_common import ParameterError
from ext_observer.nodes.node_parameters import (GYRO_PARAMETERS, MONITOR_PARAMETERS,
                                                OBSERVER_PARAMETERS)
from ext_observer.nodes.observer_node import ObserverNode
from ros_helpers import overrides


def write_params(path, text):
    path.write_text(text)
    return str(path)


def test_params_file_is_honoured(ros_domain_id, tmp_path):
    params = write_params(tmp_path / 'params.yaml', """
/**/observer:
  ros__parameters:
    variant: plain
    alpha: 0.05
    gain: [0.2, -0.1, -0.1, -0.1]
    initial_estimate: [0.0, 1.0, 0.0, 0.0]
    measurement_timeout: 0.5
gyro:
  ros__parameters:
    rate_hz: 40.0
    seed: 5
    initial_attitude: [0.0, 1.0, 0.0, 0.0]
monitor:
  ros__parameters:
    window: 7
    warn_distance: 0.2
    error_distance: 0.4
""")
    context = rclpy.context.Context()
    rclpy.init(args=['--ros-args', '--params-file', params], context=context,
               domain_id=ros_domain_id)
    nodes = []
    try:
        observer = ObserverNode(context=context, namespace='robot1')
        nodes.append(observer)
        assert observer.get_fully_qualified_name() == '/robot1/observer'
        assert observer.get_parameter('variant').value == 'plain'
        config = observer.observer.config
        assert (config.variant, config.alpha) == ('plain', 0.05)
        assert config.gain == (0.2, -0.1, -0.1, -0.1)
        assert observer.observer.state == (0.0, 1.0, 0.0, 0.0)
        assert observer.parameters.settings['measurement_timeout'] == 0.5
        gyro = GyroNode(context=context)
        nodes.append(gyro)
        assert gyro.get_parameter('rate_hz').value == 40.0
        assert gyro.get_parameter('seed').value == 5
        assert_allclose(gyro.gyro.attitude, [0.0, 1.0, 0.0, 0.0])
        monitor = MonitorNode(context=context)
        nodes.append(monitor)
        assert monitor.distances.maxlen == 7
        assert monitor.parameters.settings['error_distance'] == 0.4
    finally:
        for node in nodes:
            node.destroy_node()
        rclpy.try_shutdown(context=context)


def unset_scalar(spec):
    """A parameter without a default that YAML cannot list (e.g. align_sign)."""
    return (isinstance(spec.default, Parameter.Type)
            and not spec.default.name.endswith('_ARRAY'))


def test_shipped_params_file_loads_with_the_defaults(ros_domain_id):
    context = rclpy.context.Context()
    rclpy.init(args=['--ros-args', '--params-file', CONFIG], context=context,
               domain_id=ros_domain_id)
    nodes = []
    try:
        for node_class, specs in ((GyroNode, GYRO_PARAMETERS),
                                  (ObserverNode, OBSERVER_PARAMETERS),
                                  (MonitorNode, MONITOR_PARAMETERS)):
            node = node_class(context=context)
            nodes.append(node)
            # Every parameter comes from the file, none from the code's default
            # (but those unset by default: YAML has no "unset").
            assert set(node._parameter_overrides) == {
                spec.name for spec in specs if not unset_scalar(spec)}
            for spec in specs:
                value = node.parameters.values[spec.name]
                expected = None if isinstance(spec.default, Parameter.Type) else spec.default
                assert value == expected, spec.name
    finally:
        for node in nodes:
            node.destroy_node()
        rclpy.try_shutdown(context=context)


@pytest.mark.parametrize('node_class, values, reason', [
    (ObserverNode, dict(alpha=0.5), 'outside the range certified by Theorem 1'),
    (ObserverNode, dict(alpha=0.0), 'outside the range certified'),
    (ObserverNode, dict(alpha=0.0, allow_uncertified_alpha=True), 'alpha must be positive'),
    (ObserverNode, dict(alpha=2.0, allow_uncertified_alpha=True), 'out of range'),
    (ObserverNode, dict(variant='kalman'), "variant must be one of"),
    (ObserverNode, dict(gain_mode='adaptive'), 'gain_mode must be one of'),
    (ObserverNode, dict(gain=[0.1, 0.2, 0.3]), 'gain must have 4 elements'),
    (ObserverNode, dict(gain=[0.1, 0.2, 0.3, math.nan]), 'gain must be finite'),
    (ObserverNode, dict(initial_estimate=[0.0, 0.0, 0.0, 0.0]), 'nonzero'),
    (ObserverNode, dict(kappa=0.0), r'kappa must be in \(0, 1\]'),
    (ObserverNode, dict(kappa_min=0.0), r'kappa_min must be in \(0, 1\]'),
    (ObserverNode, dict(forward_gap_action='stop'), 'forward_gap_action must be one of'),
    (ObserverNode, dict(input_reliability='sometimes'), 'input_reliability must be one of'),
    (ObserverNode, dict(max_increment=0.0), 'max_increment must be positive'),
    (ObserverNode, dict(initial_estimate=[3.0, 0.0, 0.0, 0.0], divergence_max_residual=5.0),
     r'initial_estimate has \|q̂̄q̂ − 1\| = 8, above divergence_max_residual \(5\)'),
    (ObserverNode, dict(backward_jump_threshold=0.0), 'out of range'),
    (ObserverNode, dict(alpha=1), "expecting type 'DOUBLE'"),
    (GyroNode, dict(rate_hz=0.0), 'out of range'),
    (GyroNode, dict(gyro_noise_std=-0.1), 'out of range'),
    (GyroNode, dict(gyro_bias=[0.1, 0.0]), 'gyro_bias must have 3 elements'),
    (GyroNode, dict(gyro_bias=[0.1, math.inf, 0.0]), 'gyro_bias must be finite'),
    (GyroNode, dict(initial_attitude=[1.0, 0.0, 0.0]), 'initial_attitude must have 4 '
                                                       'elements'),
    (MonitorNode, dict(warn_distance=0.5, error_distance=0.4),
     r'error_distance \(0.4\) must not be below warn_distance \(0.5\)'),
])
def test_invalid_start_up_parameter_is_refused_with_its_reason(
        ros_context, node_class, values, reason):
    with pytest.raises(ParameterError, match=reason):
        node_class(context=ros_context, parameter_overrides=overrides(**values))


def test_gyro_and_monitor_refuse_runtime_changes_with_reasons(ros_context, spinner):
    gyro = spinner.add(GyroNode(context=ros_context))
    monitor = spinner.add(MonitorNode(context=ros_context))
    [result] = gyro.set_parameters([Parameter('seed', value=3)])
    assert not result.successful and 'read-only' in result.reason
    [result] = gyro.set_parameters([Parameter('rate_hz', value=200.0)])
    assert result.successful
    [result] = monitor.set_parameters([Parameter('warn_distance', value=0.9)])
    assert not result.successful and 'must not be below warn_distance' in result.reason
    [result] = monitor.set_parameters([Parameter('error_distance', value=0.9)])
    assert result.successful
    assert monitor.parameters.settings['error_distance'] == 0.9


def test_every_parameter_has_a_descriptor(ros_context):
    for node_class in (GyroNode, ObserverNode, MonitorNode):
        node = node_class(context=ros_context)
        try:
            for spec in node.parameters._specs:
                descriptor = node.describe_parameter(spec.name)
                assert descriptor.description == spec.description
                assert descriptor.read_only == spec.read_only
                if spec.range is not None:
                    ranges = list(descriptor.floating_point_range) + list(
                        descriptor.integer_range)
                    assert [(r.from_value, r.to_value) for r in ranges] == [spec.range]
        finally:
            node.destroy_node()


ALL_SPECS = (('gyro', GYRO_PARAMETERS), ('observer', OBSERVER_PARAMETERS),
             ('monitor', MONITOR_PARAMETERS))


def test_params_file_has_every_parameter_with_a_comment():
    import yaml

    from docgen.parameter_tables import render_config
    with open(CONFIG, encoding='utf-8') as config:
        text = config.read()
        lines = text.splitlines()
        config.seek(0)
        sections = yaml.safe_load(config)
    assert render_config(text) == text, (
        'config/ext_observer.yaml differs from the parameter specs: run  make docs')
    for name, specs in ALL_SPECS:
        values = sections[f'/**/{name}']['ros__parameters']
        # Every parameter has a value YAML can list (align_sign once had
        # none and was a comment line; the loop that checked such comments
        # never ran since, as the mutation tests found). A new one without: list it here.
        assert not any(map(unset_scalar, specs)), [s.name for s in specs if unset_scalar(s)]
        assert list(values) == [spec.name for spec in specs]
        for spec in specs:
            expected = [] if isinstance(spec.default, Parameter.Type) else spec.default
            assert values[spec.name] == expected, spec.name
    for index, line in enumerate(lines):
        if line.startswith('    ') and not line.lstrip().startswith('#'):
            assert lines[index - 1].lstrip().startswith('#'), f'no comment above {line!r}'
