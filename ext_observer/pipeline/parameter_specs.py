"""
The nodes' parameters as plain data: :class:`ParameterSpec` rows, and the docs made of them.

A node lists its parameters once, as rows; :mod:`ext_observer.nodes.ros_parameters`
declares them with rclpy (a ``ParameterDescriptor`` per row), and in a clone
``python -m ext_observer docs`` (``docgen/parameter_tables.py``) writes
docs/parameters.md and config/*.yaml from the same rows. No ROS here: the
offline tools read the same tables.

Every parameter has a value: rclpy's ``get_parameters`` (what ``ros2 param
dump`` calls) answers nothing for a whole request that names a parameter
declared with a type and no value, so "not set" is spelled as a value
(``'auto'``, all zeros) that the node's validation reads.
"""

import dataclasses
from typing import Any, Optional, Tuple

__all__ = ['COMMON_PARAMETERS', 'FORWARD_GAP_ACTIONS', 'ParameterSpec', 'common_settings',
           'ros_type_name', 'spec_from_tunable']


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
        if self.default is None:
            raise TypeError(f'{self.name}: every parameter needs a default value')
        if self.range is not None and (isinstance(self.default, bool)
                                       or not isinstance(self.default, (int, float))):
            raise TypeError(f'{self.name}: a range needs an int or float default')

    @property
    def type_name(self):
        """Return the ROS type name of the parameter (for the docs)."""
        name = ros_type_name(self.default)
        return f'{name} or bool' if self.dynamic else name

    @property
    def default_text(self):
        """Return the default as written in docs/parameters.md and the YAML."""
        return _yaml_value(self.default)


def ros_type_name(value):
    """The ROS parameter type of a Python value, as rclpy's ``Parameter.Type`` (lower case)."""
    scalar = ((bool, 'bool'), (int, 'integer'), (float, 'double'), (str, 'string'))
    for kind, name in scalar:
        if isinstance(value, kind):
            return name
    if isinstance(value, (list, tuple)):
        # rclpy's order: an empty list is a byte array.
        for kind, name in ((bytes, 'byte'),) + scalar:
            if all(isinstance(v, kind) for v in value):
                return f'{name}_array'
    raise TypeError(f'no ROS parameter type for {value!r}')


def spec_from_tunable(row, prefix, what):
    """
    The node's parameter ``prefix + row.name`` from a core table's row (start-up only).

    Its description is ``what: <the row's line>``, its range the row's,
    closed (rclpy's ranges include their ends), and the row's rule (an open
    end) in the constraints: the node's validation builds the core's
    parameters, which enforce it.
    """
    bounds = None if row.flag else (row.low, row.high)
    return ParameterSpec(prefix + row.name, row.default, f'{what}: {row.description}',
                         bounds, read_only=True, constraints=row.rule)


def _yaml_value(value):
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, str):
        return f"'{value}'"
    if isinstance(value, (list, tuple)):
        return '[' + ', '.join(_yaml_value(v) for v in value) + ']'
    return repr(value)


# At a forward gap of the inputs (the estimator nodes).
FORWARD_GAP_ACTIONS = ('propagate', 'reset')

# The parameters both estimator nodes have, with the same meaning.
COMMON_PARAMETERS = (
    ParameterSpec('backward_jump_threshold', 1.0,
                  'An input stamp older than the last step by more than this, or a '
                  'backward jump of the node clock by more than this, restarts the '
                  'time line and resets the estimator, s; smaller: stale, dropped.',
                  (0.001, 3600.0)),
    ParameterSpec('forward_gap_threshold', 1.0,
                  'A step more than this after the previous one is a forward gap, s.',
                  (0.001, 3600.0)),
    ParameterSpec('forward_gap_action', 'propagate',
                  "At a forward gap: 'propagate' (go on from the current estimate) or "
                  "'reset' (start over).",
                  constraints=f'One of {", ".join(FORWARD_GAP_ACTIONS)}.'),
    ParameterSpec('queue_depth', 100,
                  'History depth of every subscription and publisher (keep last), and '
                  'the most inputs of each kind waiting for their pair.', (1, 10000),
                  read_only=True),
    ParameterSpec('diagnostic_period', 1.0, 'Period of /diagnostics, s.', (0.01, 3600.0),
                  read_only=True),
)


def common_settings(values):
    """
    Check the values of :data:`COMMON_PARAMETERS` that rclpy's ranges do not.

    Raises
    ------
    ValueError
        With the reason.

    """
    if values['forward_gap_action'] not in FORWARD_GAP_ACTIONS:
        raise ValueError(f'forward_gap_action must be one of {FORWARD_GAP_ACTIONS}, got '
                         f'{values["forward_gap_action"]!r}')
