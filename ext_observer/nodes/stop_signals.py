"""
SIGINT (Ctrl-C) and SIGTERM ask a node's process to stop; they interrupt nothing.

:func:`install` replaces both signals' handlers by one that only records the
signal: no ``KeyboardInterrupt`` in the middle of an import, a callback or a
teardown, and no context shut down under a spinning executor. The node's
loop (:func:`~ext_observer.nodes.node_common.run_node`) asks :func:`received`
before it starts ROS, before it spins and between two spins, then stops the
executor, destroys the node and shuts rclpy down, in that order. A second
signal, while the node ends, ends the process at once (the signal's default
action). Imports ``os`` and ``signal`` only (not even ``threading``: each
millisecond before the handlers is one in which a signal meets Python's
defaults): the executables install them before they import rclpy, numpy or
numba (:mod:`~ext_observer.nodes.executables`).
"""

import os
import signal

__all__ = ['SIGNALS', 'install', 'received']

SIGNALS = (signal.SIGINT, signal.SIGTERM)

# The first stop signal received, or None.
_received = None


def _handler(signum, frame):
    global _received
    if _received is None:
        _received = signal.Signals(signum)
        return
    # Asked again while ending: the default action ends the process now.
    signal.signal(signum, signal.SIG_DFL)
    os.kill(os.getpid(), signum)


def install():
    """
    Handle SIGINT and SIGTERM by recording them; again, it changes nothing.

    Also where the process started with SIGINT ignored (a background job of
    a script: ``observer_node &``), so that Ctrl-C stops it as in a
    terminal. Only the main thread can set handlers: from another thread
    this does nothing.
    """
    for signum in SIGNALS:
        if signal.getsignal(signum) is not _handler:
            try:
                signal.signal(signum, _handler)
            except ValueError:  # not the main thread
                return


def received():
    """The stop signal received (``signal.Signals``), or None."""
    return _received
