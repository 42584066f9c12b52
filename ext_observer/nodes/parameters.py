"""
Declared parameters of the nodes: specs, validation, the generated docs.

Each node lists its parameters once, as :class:`ParameterSpec` rows; from
them come the ``ParameterDescriptor`` (description, range, read-only), the
tables of ``docs/parameters.md`` (:func:`markdown_table`, written by
``python -m ext_observer docs``) and the YAML in ``config/``.

Every parameter has a value: rclpy's ``get_parameters`` (what ``ros2 param
dump`` calls) answers nothing for a whole request that names a parameter
declared with a type and no value, so "not set" is spelled as a value
(``'auto'``, all zeros) that the node's validation reads.

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

import dataclasses
import textwrap
from typing import Any, Callable, Optional, Sequence, Tuple

from rcl_interfaces.msg import (FloatingPointRange, IntegerRange,
                                ParameterDescriptor, SetParametersResult)
from rclpy.exceptions import (InvalidParameterTypeException,
                              InvalidParameterValueException)
from rclpy.parameter import Parameter

__all__ = ['ParameterError', 'ParameterSpec', 'NodeParameters', 'markdown_table',
           'yaml_section']


class ParameterError(ValueError):
    """A parameter value refused at start-up; the message is the reason."""


@dataclasses.dataclass(frozen=True)
class ParameterSpec:
    """
    One declared parameter.

    Attributes
    ----------
    name : str
    default : bool, int, float, str or list
        The default value; its Python type is the parameter's type (every
        parameter has one: see the module docstring).
    description : str
        Shown by ``ros2 param describe`` and in ``docs/parameters.md``; states the unit.
    range : tuple of 2 numbers, optional
        Inclusive ``(from, to)`` for an int or float parameter.
    read_only : bool
        Structural: set at start-up only.
    constraints : str
        Further rules, in words (``ParameterDescriptor.additional_constraints``).
    dynamic : bool
        Declared with ``dynamic_typing``: the default is a string (``'auto'``)
        and a value of another type (a bool) is accepted too; the node's
        validation checks it.

    """

    name: str
    default: Any
    description: str
    range: Optional[Tuple[float, float]] = None
    read_only: bool = False
    constraints: str = ''
    dynamic: bool = False

    def __post_init__(self):
        if self.default is None or isinstance(self.default, Parameter.Type):
            raise TypeError(f'{self.name}: every parameter needs a default value')

    def descriptor(self):
        """Return the ``ParameterDescriptor`` of this parameter."""
        descriptor = ParameterDescriptor(
            description=self.description, read_only=self.read_only,
            additional_constraints=self.constraints, dynamic_typing=self.dynamic)
        if self.range is not None:
            low, high = self.range
            if isinstance(self.default, bool) or not isinstance(
                    self.default, (int, float)):
                raise TypeError(f'{self.name}: a range needs an int or float default')
            if isinstance(self.default, int):
                descriptor.integer_range = [
                    IntegerRange(from_value=int(low), to_value=int(high), step=1)]
            else:
                descriptor.floating_point_range = [FloatingPointRange(
                    from_value=float(low), to_value=float(high), step=0.0)]
        return descriptor

    @property
    def type_name(self):
        """Return the ROS type name of the parameter (for the docs)."""
        name = Parameter.Type.from_parameter_value(self.default).name.lower()
        return f'{name} or bool' if self.dynamic else name

    @property
    def default_text(self):
        """Return the default as written in docs/parameters.md and the YAML."""
        return _yaml_value(self.default)


def _yaml_value(value):
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, str):
        return f"'{value}'"
    if isinstance(value, (list, tuple)):
        return '[' + ', '.join(_yaml_value(v) for v in value) + ']'
    return repr(value)


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
                node.declare_parameter(spec.name, spec.default, spec.descriptor())
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


def markdown_table(specs):
    """
    Return the table of a node's parameters in ``docs/parameters.md``.

    Parameters
    ----------
    specs : sequence of ParameterSpec

    Returns
    -------
    table : str
        Markdown, one row per parameter, ending with a newline.

    """
    rows = ['| parameter | type | default | range | runtime | description |',
            '| --- | --- | --- | --- | --- | --- |']
    for spec in specs:
        bounds = '' if spec.range is None else f'[{spec.range[0]}, {spec.range[1]}]'
        runtime = 'no' if spec.read_only else 'yes'
        description = spec.description
        if spec.constraints:
            description += f' {spec.constraints}'
        description = description.replace('|', '\\|')
        rows.append(f'| `{spec.name}` | {spec.type_name} | `{spec.default_text}` | '
                    f'{bounds} | {runtime} | {description} |')
    return '\n'.join(rows) + '\n'


def yaml_section(node_name, specs):
    """
    Return a node's section of ``config/ext_observer.yaml``.

    Every parameter with its default, under a comment made of its description,
    constraints, range and whether it is start-up only, wrapped at 78
    columns.

    Parameters
    ----------
    node_name : str
        The section is ``/**/<node_name>``.
    specs : sequence of ParameterSpec

    Returns
    -------
    section : str
        YAML, ending with a newline.

    """
    lines = [f'/**/{node_name}:', '  ros__parameters:']
    for spec in specs:
        text = spec.description
        if spec.constraints:
            text += f' {spec.constraints}'
        if spec.range is not None:
            text += f' Range [{spec.range[0]}, {spec.range[1]}].'
        if spec.read_only:
            text += ' Start-up only.'
        lines += textwrap.wrap(text, width=78, initial_indent='    # ',
                               subsequent_indent='    # ', break_on_hyphens=False)
        lines.append(f'    {spec.name}: {spec.default_text}')
    return '\n'.join(lines) + '\n'
