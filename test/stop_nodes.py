"""
Small nodes that test_processes.py runs as processes, to see how ``run_node`` stops them.

``python test/stop_nodes.py NAME [ARGS]`` runs one through
:func:`ext_observer.nodes.node_common.run_node`:

- ``background``: says whether it handles SIGINT (a background job starts
  with SIGINT ignored);
- ``ordered [--executor single]``: publishes at 1 kHz and says when its
  context goes down and whether it was still up when the node was destroyed;
- ``busy callback|thread [--executor single]``: the context shut down from a
  callback, or from another thread while the main thread spins.
"""

import signal
import sys
import threading
import time

import rclpy
from rclpy.node import Node
from std_msgs.msg import Float64

from ext_observer.nodes.node_common import run_node


class BackgroundNode(Node):
    """Says whether SIGINT is handled, then idles."""

    NODE_NAME = 'background'

    def __init__(self):
        super().__init__(self.NODE_NAME)
        handled = signal.getsignal(signal.SIGINT) not in (signal.SIG_IGN, signal.SIG_DFL)
        print(f'the node handles SIGINT: {handled}', flush=True)
        self.create_timer(0.01, lambda: None)


class OrderedNode(Node):
    """Publishes at 1 kHz; says when it spins, when it is destroyed and when its context ends."""

    NODE_NAME = 'ordered'

    def __init__(self):
        super().__init__(self.NODE_NAME)
        self.publisher = self.create_publisher(Float64, 'x', 10)
        self.create_timer(0.001, self.timer_callback)
        self.context.on_shutdown(lambda: print('context shut down', flush=True))
        self.steps = 0

    def timer_callback(self):
        self.publisher.publish(Float64(data=1.0))
        self.steps += 1
        if self.steps == 100:
            print('spinning', flush=True)

    def destroy_node(self):
        print(f'destroy_node, context up: {self.context.ok()}', flush=True)
        super().destroy_node()


class BusyNode(Node):
    """Publishes every 10 ms; with ``HOW`` 'callback', shuts the context down in a callback."""

    NODE_NAME = 'busy'
    HOW = 'callback'

    def __init__(self):
        super().__init__(self.NODE_NAME)
        self.publisher = self.create_publisher(Float64, 'x', 10)
        self.create_timer(0.01, self.timer_callback)

    def timer_callback(self):
        if self.HOW == 'thread':
            self.publisher.publish(Float64(data=1.0))
            return
        # The context goes down while a callback runs.
        rclpy.shutdown()
        self.publisher.publish(Float64(data=1.0))


def main(argv):
    """Run the node ``argv[1]`` names (see the module); its exit code."""
    name, rest = argv[1], argv[2:]
    if name == 'background':
        return run_node(BackgroundNode, ['background'])
    if name == 'ordered':
        return run_node(OrderedNode, ['ordered'] + rest)
    if name != 'busy':
        raise ValueError(f'no node {name!r}: background, ordered or busy')
    BusyNode.HOW, rest = rest[0], rest[1:]
    if BusyNode.HOW == 'thread':
        # Shut down from another thread, while the main thread spins.
        threading.Thread(target=lambda: (time.sleep(1.0), rclpy.shutdown()),
                         daemon=True).start()
    return run_node(BusyNode, ['busy'] + rest)


if __name__ == '__main__':
    sys.exit(main(sys.argv))
