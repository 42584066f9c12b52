"""
Declaring the nodes' parameters with rclpy, validating them, applying changes.

The rows are plain data (:class:`~ext_observer.pipeline.parameter_specs.ParameterSpec`);
here each becomes a ``ParameterDescriptor`` (:func:`descriptor`: description,
range, read-only) and :class:`NodeParameters` declares them on a node.

Validation has one entry point per node, a function from the dict of all
parameter values to the node's settings that raises ``ValueError`` with the
reason. :class:`NodeParameters` calls it at start-up (an invalid value
raises :class:`ParameterError`, and ``main`` exits with code 2 and the reason
in the log) and for every runtime change (the change is refused, and the
reason is returned to the caller of ``set_parameters``). The numerical
checks themselves (finite gains, nonzero quaternions, ...) are the core's:
the nodes build the core objects from the candidate values and report the
core's ``ValueError``.
"""

from typing import Any, Callable, Optional, Sequence

from rcl_interfaces.msg import (FloatingPointRange, IntegerRange,
                                ParameterDescriptor, SetParametersResult)
from rclpy.exceptions import (InvalidParameterTypeException,
                              InvalidParameterValueException)
from rclpy.parameter import Parameter

from ext_observer.pipeline.parameter_specs import ParameterSpec

__all__ = ['NodeParameters', 'ParameterError', 'descriptor']


class ParameterError(ValueError):
    """A parameter value refused at start-up; the message is the reason."""


def descriptor(spec):
    """Return the ``ParameterDescriptor`` of a :class:`ParameterSpec`."""
    result = ParameterDescriptor(
        description=spec.description, read_only=spec.read_only,
        additional_constraints=spec.constraints, dynamic_typing=spec.dynamic)
    if spec.range is not None:
        low, high = spec.range
        if isinstance(spec.default, int):
            result.integer_range = [
                IntegerRange(from_value=int(low), to_value=int(high), step=1)]
        else:
            result.floating_point_range = [FloatingPointRange(
                from_value=float(low), to_value=float(high), step=0.0)]
    return result


def _python_value(parameter):
    value = parameter.value
    if parameter.type_ == Parameter.Type.NOT_SET:
        return None
    if parameter.type_ in (Parameter.Type.BOOL_ARRAY, Parameter.Type.INTEGER_ARRAY,
                           Parameter.Type.DOUBLE_ARRAY, Parameter.Type.STRING_ARRAY,
                           Parameter.Type.BYTE_ARRAY):
        return list(value)
    return value


class NodeParameters:
    """
    Declare a node's parameters, validate them, apply runtime changes.

    Parameters
    ----------
    node : rclpy.node.Node
    specs : sequence of ParameterSpec
        Declared in this order.
    validate : callable
        ``validate(values) -> settings``: ``values`` maps every name to its
        value; raises ``ValueError`` with the reason.
    apply : callable, optional
        ``apply(settings, changed_names)``, called after a runtime change was
        accepted and stored.

    Attributes
    ----------
    values : dict
        Current value of every parameter.
    given : set
        Parameters given at start-up with a value other than their default.
    settings : object
        What ``validate`` returned for ``values``.

    Raises
    ------
    ParameterError
        If the start-up values are refused.

    """

    def __init__(self, node, specs: Sequence[ParameterSpec],
                 validate: Callable[[dict], Any],
                 apply: Optional[Callable[[Any, set], None]] = None):
        self._node = node
        self._specs = tuple(specs)
        self._validate = validate
        self._apply = apply
        self._ready = False
        node.add_on_set_parameters_callback(self._on_set)
        node.add_post_set_parameters_callback(self._post_set)
        try:
            for spec in self._specs:
                node.declare_parameter(spec.name, spec.default, descriptor(spec))
        except (InvalidParameterValueException, InvalidParameterTypeException) as error:
            raise ParameterError(f'{node.get_name()}: {error}') from None
        self.values = {spec.name: _python_value(node.get_parameter_or(spec.name))
                       for spec in self._specs}
        # Given at start-up with a value other than the default (a params
        # file, -p, parameter_overrides): what a warning about unused
        # parameters names. A file that only repeats the defaults (a dump
        # loaded back) gives nothing.
        self.given = {spec.name for spec in self._specs
                      if self.values[spec.name] != spec.default}
        try:
            self.settings = validate(dict(self.values))
        except ValueError as error:
            raise ParameterError(f'{node.get_name()}: {error}') from None
        self._ready = True

    def _candidate(self, parameters):
        values = dict(self.values)
        values.update({p.name: _python_value(p) for p in parameters})
        return values

    def _own(self, parameters):
        # Parameters that rclpy declares itself (qos_overrides.*,
        # use_sim_time) are not ours to validate.
        return [p for p in parameters if p.name in self.values]

    def _on_set(self, parameters):
        if not self._ready or not self._own(parameters):
            # Start-up: rclpy has checked the type and the range; the values
            # are validated together once all are declared.
            return SetParametersResult(successful=True)
        try:
            self._validate(self._candidate(self._own(parameters)))
        except ValueError as error:
            reason = str(error)
            self._node.get_logger().warning(f'parameter change refused: {reason}')
            return SetParametersResult(successful=False, reason=reason)
        return SetParametersResult(successful=True)

    def _post_set(self, parameters):
        if not self._ready or not self._own(parameters):
            return
        parameters = self._own(parameters)
        values = self._candidate(parameters)
        self.settings = self._validate(dict(values))
        self.values = values
        if self._apply is not None:
            self._apply(self.settings, {p.name for p in parameters})
