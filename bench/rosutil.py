"""
ROS helpers shared by the relay, the driver and the probe, and their line control.

Stamps are integer nanoseconds of the wall clock (``time.time_ns``), the
same clock in every process of the machine, so a latency is the difference
of two stamps taken in two processes.
"""

import struct
import sys
import time

EXECUTORS = ('single', 'multi', 'events')
# Spin timeout of the loops, s: finite, because rclpy 7.1's EventsExecutor
# busy-waits without one and hangs when shut down from another thread.
SPIN_TIMEOUT = 0.1
# Offset of builtin_interfaces/Time in a serialized *Stamped message: the
# 4-byte CDR encapsulation header, then header.stamp (int32 sec, uint32
# nanosec) first.
_STAMP = struct.Struct('<iI')
STAMP_OFFSET = 4


def make_executor(kind, context=None):
    """
    Return an rclpy executor by name.

    Parameters
    ----------
    kind : {'single', 'multi', 'events'}
        SingleThreadedExecutor, MultiThreadedExecutor (default threads) or
        rclpy.experimental.EventsExecutor.

    """
    from rclpy.executors import MultiThreadedExecutor, SingleThreadedExecutor
    if kind == 'single':
        return SingleThreadedExecutor(context=context)
    if kind == 'multi':
        return MultiThreadedExecutor(context=context)
    if kind == 'events':
        from rclpy.experimental import EventsExecutor
        return EventsExecutor(context=context)
    raise ValueError(f'executor must be one of {EXECUTORS}, got {kind!r}')


def spin_until_shutdown(executor, context, stop=None):
    """
    Spin with finite timeouts until the context shuts down or ``stop`` is set.

    Parameters
    ----------
    executor : rclpy executor
    context : rclpy.context.Context
    stop : threading.Event, optional

    """
    from rclpy.executors import ExternalShutdownException
    try:
        while context.ok() and not (stop is not None and stop.is_set()):
            executor.spin_once(timeout_sec=SPIN_TIMEOUT)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass


def set_stamp(stamp, ns):
    """Set a builtin_interfaces/Time from integer nanoseconds."""
    stamp.sec, stamp.nanosec = divmod(ns, 1_000_000_000)


def raw_stamp_ns(data):
    """Return the header stamp (ns) of a serialized *Stamped message."""
    sec, nanosec = _STAMP.unpack_from(data, STAMP_OFFSET)
    return sec * 1_000_000_000 + nanosec


def write_raw_stamp(buffer, ns):
    """Write the header stamp (ns) into a serialized *Stamped message."""
    _STAMP.pack_into(buffer, STAMP_OFFSET, *divmod(ns, 1_000_000_000))


def wait_until(condition, timeout):
    """Poll ``condition()`` until true or ``timeout`` s pass; return whether it came true."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if condition():
            return True
        time.sleep(0.02)
    return False


def serve_lines(commands, match):
    """
    Answer the command lines on stdin until ``quit`` or its end.

    ``match TIMEOUT`` answers ``matched`` or ``unmatched`` from
    ``match(timeout)``; any other first word is looked up in ``commands``
    (``{word: function(words)}``, which prints its own answer); an unknown
    one answers ``error unknown command``.
    """
    for line in sys.stdin:
        words = line.split()
        if not words:
            continue
        if words[0] == 'quit':
            break
        if words[0] == 'match':
            print('matched' if match(float(words[1])) else 'unmatched', flush=True)
        elif words[0] in commands:
            commands[words[0]](words)
        else:
            print(f'error unknown command {words[0]!r}', flush=True)


def kernels_of(msg):
    """The ``kernels`` value of a ``/diagnostics`` message, or None."""
    return next((kv.value for st in msg.status for kv in st.values if kv.key == 'kernels'), None)


def watch_kernels(node, kernels):
    """Append every ``kernels`` value ``/diagnostics`` says to ``kernels``; return the subscription."""
    from diagnostic_msgs.msg import DiagnosticArray

    def seen(msg):
        value = kernels_of(msg)
        if value is not None:
            kernels.append(value)
    return node.create_subscription(DiagnosticArray, '/diagnostics', seen, 10)


def on_compiled_kernels(kernels):
    """Whether the last ``kernels`` values seen say the node runs on the compiled ones for good."""
    return bool(kernels) and not kernels[-1].startswith('plain (')
