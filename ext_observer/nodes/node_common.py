"""
What the nodes share beyond their parameters: diagnostics, QoS, ``main``.

The parameter rows (:class:`ParameterSpec`, plain data in
:mod:`ext_observer.pipeline.parameter_specs`) and their declaration
(:class:`NodeParameters`, :mod:`ext_observer.nodes.ros_parameters`) are
re-exported here; the input
machinery of the two estimator nodes (stamps, checks, silence, resets,
status) in :mod:`ext_observer.nodes.estimator_node_base`.
"""

import gc
import sys

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
import rclpy
from rclpy.event_handler import PublisherEventCallbacks, SubscriptionEventCallbacks
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.qos import (DurabilityPolicy, qos_check_compatible, qos_policy_name_from_kind,
                       QoSCompatibility, ReliabilityPolicy)
from rclpy.signals import SignalHandlerOptions
from rclpy.task import Future

from ext_observer.nodes import stop_signals
from ext_observer.nodes.ros_parameters import NodeParameters, ParameterError
from ext_observer.pipeline.parameter_specs import ParameterSpec

__all__ = [
    'EXECUTORS',
    'LEVEL_NAMES',
    'NO_TF2',
    'CounterDeltas',
    'ParameterError',
    'ParameterSpec',
    'NodeParameters',
    'QosWatch',
    'diagnostic_array',
    'executor_from_args',
    'key_values',
    'run_node',
    'transform_broadcaster',
]


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


# What the graph reports for an endpoint whose node discovery has not named yet.
UNNAMED = '_NODE_NAME_UNKNOWN_'


def _endpoint_name(info):
    if info.node_name == UNNAMED:
        return '(a node discovery has not named yet)'
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
        # The text last logged per topic: logged again once discovery names
        # a peer it could not name at the event.
        self._logged = {}

    def subscription(self, topic, qos, hint='', lost=None):
        """
        Return ``SubscriptionEventCallbacks`` for a subscription on ``topic``.

        ``lost(info)``, if given, is called at rmw's message-lost event
        (``info.total_count_change`` messages lost since the last one).
        """
        name = self._node.resolve_topic_name(topic)
        self._endpoints[name] = ('subscription', qos, hint)
        return SubscriptionEventCallbacks(
            incompatible_qos=lambda event: self._incompatible(name, event),
            message_lost=lost)

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
        self._logged[topic] = text
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
                continue
            self.problems[topic] = text
            if text != self._logged.get(topic) and 'not named yet' in self._logged.get(
                    topic, ''):
                self._logged[topic] = text
                self._node.get_logger().warning(f'incompatible QoS: {text}')

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
# Longest spin of the nodes' loop, s: how long a stop signal may wait to be
# seen when no callback runs. rclpy 7.1's EventsExecutor also busy-waits in
# spin() and never returns from it at shutdown; spun until a future with a
# finite timeout it sleeps, and returns.
SPIN_TIMEOUT = 0.1


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


def _executor(node, kind):
    """Return a new executor of ``kind`` with ``node`` added."""
    if kind == 'single':
        executor = SingleThreadedExecutor(context=node.context)
    else:
        from rclpy.experimental import EventsExecutor
        executor = EventsExecutor(context=node.context)
    executor.add_node(node)
    return executor


def _spin(executor, node, kind):
    """Spin until a stop signal or until the context is down."""
    context = node.context
    if kind == 'single':
        # Bounds each spin_once below: spin_once(timeout_sec) would make a
        # timer at every wait (4 % more CPU per message at 1 kHz here).
        node.create_timer(SPIN_TIMEOUT, lambda: None)
    # What start-up built lives as long as the process: out of the collector's
    # reach, a full collection does not walk it (200 ms here: a hole of 200
    # samples at 1 kHz).
    gc.freeze()
    while stop_signals.received() is None and context.ok():
        if kind == 'single':
            executor.spin_once()
        else:
            # Until a future that never completes: the executor's own loop
            # runs every callback of the timeout, where spin_once returned to
            # Python after each (a wake-up and the GIL twice per message).
            executor.spin_until_future_complete(Future(), timeout_sec=SPIN_TIMEOUT)


def run_node(node_class, args=None):
    """
    Run one node until a stop signal or shutdown; the body of each node's ``main``.

    As ``demo_nodes_py``'s talker, the node is always destroyed and rclpy
    shut down, and ``ExternalShutdownException`` is a normal end. SIGINT
    (Ctrl-C) and SIGTERM only ask the node to stop
    (:mod:`~ext_observer.nodes.stop_signals`; rclpy is initialized without
    its own signal handlers): whenever one comes, while the process imports,
    starts, spins or runs a callback, the loop ends at the next check, the
    executor is shut down, then the node is destroyed, and only then is
    the context shut down; the exit code is 0.

    The executor is chosen on the command line, before ``--ros-args``:
    ``--executor events`` (the default: ``rclpy.experimental.EventsExecutor``
    spun with ``spin_until_future_complete(future, timeout_sec=0.1)`` on a
    future that never completes, in a loop) or ``--executor single``
    (``SingleThreadedExecutor``, what ``rclpy.spin`` uses, spun with
    ``spin_once()`` in a loop, a timer of the node waking it every 0.1 s);
    the loop runs while no stop signal came and the context is up.

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
    # Here too for a main called otherwise than by its executable
    # (python -m, a script): the signals from now on.
    stop_signals.install()
    argv = sys.argv if args is None else args
    try:
        kind = executor_from_args(argv)
    except ValueError as error:
        rclpy.logging.get_logger(node_class.NODE_NAME).fatal(f'not starting: {error}')
        return 2
    if stop_signals.received() is not None:
        return 0
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    node = executor = None
    exit_code = 0
    try:
        if stop_signals.received() is None:
            node = node_class()
        if stop_signals.received() is None:
            executor = _executor(node, kind)
            _spin(executor, node, kind)
    except (KeyboardInterrupt, ExternalShutdownException):
        # KeyboardInterrupt: where the stop handlers could not be installed
        # (run_node outside the main thread).
        pass
    except ParameterError as error:
        rclpy.logging.get_logger(node_class.NODE_NAME).fatal(
            f'invalid parameters, not starting: {error}')
        exit_code = 2
    except Exception as error:
        # A shutdown of the context from a callback or another thread comes
        # under whatever spin was doing: a callback publishing fails with
        # RCLError, a message being taken with RuntimeError. That is the end
        # asked for; with the context still up, the error is real.
        if rclpy.ok():
            raise
        rclpy.logging.get_logger(node_class.NODE_NAME).debug(
            f'stopped under a callback: {error!r}')
    finally:
        if executor is not None:
            executor.shutdown()
            executor = None
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return exit_code


# What publish_tf needs and the pip wheels do not have (tf2 is not on PyPI).
NO_TF2 = ('publish_tf is true but tf2_ros does not import here ({error}): no TF is '
          'broadcast, the orientation is on imu/data. For the transform run the node in a '
          'ROS 2 installation (source /opt/ros/jazzy/setup.bash, colcon), or set publish_tf '
          'false to silence this')


def transform_broadcaster(node):
    """Return a tf2_ros TransformBroadcaster of ``node``, or the ImportError's text."""
    try:
        from tf2_ros import TransformBroadcaster
    except ImportError as error:
        return None, str(error)
    return TransformBroadcaster(node), None
