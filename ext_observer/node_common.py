"""
What the three nodes share: declared parameters, validation, ``main``.

Each node lists its parameters once, as :class:`ParameterSpec` rows; from
them come the ``ParameterDescriptor`` (description, range, read-only), the
tables of ``docs/parameters.md`` (:func:`markdown_table`, written by
``python -m ext_observer docs``) and the YAML in ``config/``.

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
import sys
import textwrap
from typing import Any, Callable, Optional, Sequence, Tuple

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import (FloatingPointRange, IntegerRange,
                                ParameterDescriptor, SetParametersResult)
import rclpy
from rclpy.event_handler import PublisherEventCallbacks, SubscriptionEventCallbacks
from rclpy.exceptions import (InvalidParameterTypeException,
                              InvalidParameterValueException)
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.parameter import Parameter
from rclpy.qos import (DurabilityPolicy, qos_check_compatible, qos_policy_name_from_kind,
                       QoSCompatibility, ReliabilityPolicy)

__all__ = [
    'EXECUTORS',
    'LEVEL_NAMES',
    'CounterDeltas',
    'ParameterError',
    'ParameterSpec',
    'NodeParameters',
    'QosWatch',
    'diagnostic_array',
    'executor_from_args',
    'key_values',
    'markdown_table',
    'run_node',
    'yaml_section',
]


class ParameterError(ValueError):
    """A parameter value refused at start-up; the message is the reason."""


@dataclasses.dataclass(frozen=True)
class ParameterSpec:
    """
    One declared parameter.

    Attributes
    ----------
    name : str
    default : bool, int, float, str, list or rclpy.parameter.Parameter.Type
        The default value; its Python type is the parameter's type. A
        ``Parameter.Type`` declares a parameter with no default (unset).
    description : str
        Shown by ``ros2 param describe`` and in ``docs/parameters.md``; states the unit.
    range : tuple of 2 numbers, optional
        Inclusive ``(from, to)`` for an int or float parameter.
    read_only : bool
        Structural: set at start-up only.
    constraints : str
        Further rules, in words (``ParameterDescriptor.additional_constraints``).
    example : bool, int, float, str or list, optional
        For a parameter unset by default: the value the params file shows,
        commented out.

    """

    name: str
    default: Any
    description: str
    range: Optional[Tuple[float, float]] = None
    read_only: bool = False
    constraints: str = ''
    example: Any = None

    def descriptor(self):
        """Return the ``ParameterDescriptor`` of this parameter."""
        descriptor = ParameterDescriptor(
            description=self.description, read_only=self.read_only,
            additional_constraints=self.constraints)
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
        if isinstance(self.default, Parameter.Type):
            return self.default.name.lower()
        return Parameter.Type.from_parameter_value(self.default).name.lower()

    @property
    def default_text(self):
        """Return the default as written in docs/parameters.md and the YAML."""
        if isinstance(self.default, Parameter.Type):
            return '[]' if self.default.name.endswith('_ARRAY') else 'unset'
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
        value (``None`` when unset); raises ``ValueError`` with the reason.
    apply : callable, optional
        ``apply(settings, changed_names)``, called after a runtime change was
        accepted and stored.

    Attributes
    ----------
    values : dict
        Current value of every parameter.
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

    Every parameter with its default (one unset by default commented out,
    with its ``example``), under a comment made of its description,
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
        unset = (isinstance(spec.default, Parameter.Type)
                 and not spec.default.name.endswith('_ARRAY'))
        if unset:
            text += ' Unset here: uncomment the next line to set it.'
        lines += textwrap.wrap(text, width=78, initial_indent='    # ',
                               subsequent_indent='    # ', break_on_hyphens=False)
        if unset:
            lines.append(f'    # {spec.name}: {_yaml_value(spec.example)}')
        else:
            lines.append(f'    {spec.name}: {spec.default_text}')
    return '\n'.join(lines) + '\n'


def key_values(pairs):
    """
    Return diagnostic key values; floats are written with 6 significant digits.

    Parameters
    ----------
    pairs : iterable of (str, object)

    Returns
    -------
    values : list of diagnostic_msgs.msg.KeyValue

    """
    result = []
    for key, value in pairs:
        if isinstance(value, float):
            text = f'{value:.6g}'
        elif isinstance(value, bool):
            text = 'true' if value else 'false'
        else:
            text = str(value)
        result.append(KeyValue(key=key, value=text))
    return result


def diagnostic_array(stamp, statuses):
    """
    Return a ``DiagnosticArray`` stamped ``stamp``.

    Parameters
    ----------
    stamp : builtin_interfaces.msg.Time
    statuses : sequence of diagnostic_msgs.msg.DiagnosticStatus

    """
    array = DiagnosticArray()
    array.header.stamp = stamp
    array.status = list(statuses)
    return array


class CounterDeltas:
    """
    What rose since the last diagnostic period.

    ``deltas(counters)`` returns ``{name: increase}`` for the counters that
    rose since the previous call (all of them count from 0 at the first call).
    """

    def __init__(self):
        self._reported = {}

    def deltas(self, counters):
        """Return the counters of ``counters`` that rose, with their increase."""
        rose = {name: value - self._reported.get(name, 0)
                for name, value in counters.items()
                if value != self._reported.get(name, 0)}
        self._reported = dict(counters)
        return rose


def _endpoint_name(info):
    namespace = info.node_namespace.rstrip('/')
    return f'{namespace}/{info.node_name}'


def _policy_fix(role, ours, theirs, hint):
    """Return ``(problem, fix)`` in words for two incompatible profiles."""
    publisher, subscription = (ours, theirs) if role == 'publisher' else (theirs, ours)
    peer = 'subscription' if role == 'publisher' else 'publisher'
    if (publisher.reliability == ReliabilityPolicy.BEST_EFFORT
            and subscription.reliability == ReliabilityPolicy.RELIABLE):
        problem = 'publisher is BEST_EFFORT, subscription is RELIABLE'
        fix = ('publish with RELIABLE reliability' if role == 'subscription'
               else 'subscribe with BEST_EFFORT reliability')
    elif (publisher.durability == DurabilityPolicy.VOLATILE
          and subscription.durability == DurabilityPolicy.TRANSIENT_LOCAL):
        problem = 'publisher is VOLATILE, subscription is TRANSIENT_LOCAL'
        fix = ('publish with TRANSIENT_LOCAL durability' if role == 'subscription'
               else 'subscribe with VOLATILE durability')
    else:
        _, reason = qos_check_compatible(publisher, subscription)
        problem = reason.strip().rstrip(';') or 'incompatible QoS'
        fix = f'make the {peer}\'s QoS match this {role}\'s'
    if hint:
        fix += f', or {hint}'
    return problem, fix


class QosWatch:
    """
    Incompatible QoS on a node's endpoints, from the rclpy QoS event callbacks.

    Pass :meth:`subscription` / :meth:`publisher` as ``event_callbacks`` when
    creating each endpoint. An ``incompatible_qos`` event (a peer that will
    never be matched) is logged with the fix named, counted, and kept in
    :attr:`problems` for the diagnostics; :meth:`refresh` (each diagnostic
    period) looks at the graph again and forgets a problem once no
    incompatible peer remains on that topic.

    Parameters
    ----------
    node : rclpy.node.Node

    Attributes
    ----------
    events : int
        Incompatible peers reported so far.
    problems : dict
        ``topic -> text`` (who, what, the fix) for every topic that has an
        incompatible peer now.

    """

    def __init__(self, node):
        self._node = node
        self._endpoints = {}
        self.events = 0
        self.problems = {}

    def subscription(self, topic, qos, hint=''):
        """Return ``SubscriptionEventCallbacks`` for a subscription on ``topic``."""
        name = self._node.resolve_topic_name(topic)
        self._endpoints[name] = ('subscription', qos, hint)
        return SubscriptionEventCallbacks(
            incompatible_qos=lambda event: self._incompatible(name, event))

    def publisher(self, topic, qos, hint='', matched=None):
        """
        Return ``PublisherEventCallbacks`` for a publisher on ``topic``.

        ``matched(info)``, if given, is called when a subscription is matched
        or unmatched (``info.current_count`` subscriptions now).
        """
        name = self._node.resolve_topic_name(topic)
        self._endpoints[name] = ('publisher', qos, hint)
        return PublisherEventCallbacks(
            incompatible_qos=lambda event: self._incompatible(name, event),
            matched=matched)

    def _incompatible(self, topic, event):
        self.events += max(1, event.total_count_change)
        text = self._describe(topic)
        if text is None:
            role = self._endpoints[topic][0]
            peer = 'subscription' if role == 'publisher' else 'publisher'
            policy = qos_policy_name_from_kind(event.last_policy_kind)
            text = (f'a {peer} on {topic} has an incompatible {policy} policy; '
                    f'match the QoS of this {role}')
        self.problems[topic] = text
        self._node.get_logger().warning(f'incompatible QoS: {text}')

    def _describe(self, topic):
        role, ours, hint = self._endpoints[topic]
        if role == 'subscription':
            peers = self._node.get_publishers_info_by_topic(topic)
            mine = self._node.get_subscriptions_info_by_topic(topic)
        else:
            peers = self._node.get_subscriptions_info_by_topic(topic)
            mine = self._node.get_publishers_info_by_topic(topic)
        # Compare profiles as the graph reports them (an unset deadline in a
        # QoSProfile is "infinite" in the graph).
        name = (self._node.get_name(), self._node.get_namespace())
        for info in mine:
            if (info.node_name, info.node_namespace) == name:
                ours = info.qos_profile
                break
        texts = []
        for info in peers:
            theirs = info.qos_profile
            compatibility, _ = (qos_check_compatible(theirs, ours) if role == 'subscription'
                                else qos_check_compatible(ours, theirs))
            if compatibility != QoSCompatibility.ERROR:
                continue
            problem, fix = _policy_fix(role, ours, theirs, hint)
            peer = 'subscription' if role == 'publisher' else 'publisher'
            texts.append(f'{peer} {_endpoint_name(info)} on {topic}: {problem}: {fix}')
        return '; '.join(texts) if texts else None

    def refresh(self):
        """Check the topics with problems again; keep only the current ones."""
        for topic in list(self.problems):
            text = self._describe(topic)
            if text is None:
                del self.problems[topic]
            else:
                self.problems[topic] = text

    def key_values(self):
        """Return the diagnostic pairs: the event count and one per problem topic."""
        return ([('qos_incompatible_events', self.events)]
                + [(f'qos_incompatible:{topic}', text)
                   for topic, text in sorted(self.problems.items())])


LEVEL_NAMES = {
    DiagnosticStatus.OK: 'OK',
    DiagnosticStatus.WARN: 'WARN',
    DiagnosticStatus.ERROR: 'ERROR',
    DiagnosticStatus.STALE: 'STALE',
}


# Executors of the nodes' main (``--executor``); the first is the default.
EXECUTORS = ('events', 'single')
# Spin timeout of the EventsExecutor loop, s. rclpy 7.1's EventsExecutor
# busy-waits when spun without a timeout; with a finite one it sleeps.
EVENTS_SPIN_TIMEOUT = 0.1


def executor_from_args(args):
    """
    Return the executor named by ``--executor`` among the non-ROS arguments.

    Parameters
    ----------
    args : list of str
        The command line (``sys.argv`` or what ``main`` was given), ROS
        arguments included; ``--executor NAME`` or ``--executor=NAME`` is
        looked for outside ``--ros-args ... --``.

    Returns
    -------
    executor : str
        One of :data:`EXECUTORS`; the first when the option is absent.

    Raises
    ------
    ValueError
        For an unknown executor or a missing value.

    """
    from rclpy.utilities import remove_ros_args
    words = remove_ros_args(list(args))
    kind = EXECUTORS[0]
    for index, word in enumerate(words):
        if word == '--executor':
            if index + 1 >= len(words):
                raise ValueError(f'--executor needs a value, one of {EXECUTORS}')
            kind = words[index + 1]
        elif word.startswith('--executor='):
            kind = word.split('=', 1)[1]
    if kind not in EXECUTORS:
        raise ValueError(f'--executor must be one of {EXECUTORS}, got {kind!r}')
    return kind


def _spin(node, kind):
    context = node.context
    if kind == 'single':
        executor = SingleThreadedExecutor(context=context)
    else:
        from rclpy.experimental import EventsExecutor
        executor = EventsExecutor(context=context)
    executor.add_node(node)
    try:
        if kind == 'single':
            executor.spin()
        else:
            while context.ok():
                executor.spin_once(timeout_sec=EVENTS_SPIN_TIMEOUT)
    finally:
        executor.shutdown()


def run_node(node_class, args=None):
    """
    Run one node until Ctrl-C or shutdown; the body of each node's ``main``.

    As ``demo_nodes_py``'s talker: spin inside ``try``, treat
    ``KeyboardInterrupt`` and ``ExternalShutdownException`` as a normal end
    (and any error raised once the context is down: Ctrl-C shuts it down
    under whatever spin was doing, publishing or taking a message), and
    always destroy the node and shut rclpy down.

    The executor is chosen on the command line, before ``--ros-args``:
    ``--executor events`` (the default: ``rclpy.experimental.EventsExecutor``
    spun with ``spin_once(timeout_sec=0.1)`` in a loop while the context is
    up) or ``--executor single`` (``SingleThreadedExecutor``, what
    ``rclpy.spin`` uses).

    Parameters
    ----------
    node_class : type
        A node class constructible with no arguments.
    args : list of str, optional
        Command line arguments for ``rclpy.init`` (default ``sys.argv``).

    Returns
    -------
    exit_code : int
        0 on a normal end, 2 when the parameters or the executor were
        refused at start-up.

    """
    argv = sys.argv if args is None else args
    try:
        kind = executor_from_args(argv)
    except ValueError as error:
        rclpy.logging.get_logger(node_class.NODE_NAME).fatal(f'not starting: {error}')
        return 2
    rclpy.init(args=args)
    node = None
    exit_code = 0
    try:
        node = node_class()
        _spin(node, kind)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except ParameterError as error:
        rclpy.logging.get_logger(node_class.NODE_NAME).fatal(
            f'invalid parameters, not starting: {error}')
        exit_code = 2
    except Exception as error:
        # Ctrl-C shuts the context down at once, under whatever spin was
        # doing: a callback publishing fails with RCLError, a message being
        # taken with RuntimeError. That is the end we asked for; with the
        # context still up, the error is real.
        if rclpy.ok():
            raise
        rclpy.logging.get_logger(node_class.NODE_NAME).debug(
            f'stopped under a callback: {error!r}')
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return exit_code
