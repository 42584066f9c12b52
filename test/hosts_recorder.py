"""
A recorder node for the two-host test bed (``test_hosts.py``).

Runs as its own process inside one of the namespaces (``ip netns exec``):
pytest stays outside them, with localhost discovery, and reads what this
process writes. Each line of the output file is a JSON array:

- ``["e", stamp, source, received, now, w, x, y, z]``: an ``attitude_estimate``;
  ``stamp`` its header stamp, ``source`` the writer's source timestamp,
  ``received`` the reader's reception timestamp (both from the middleware's
  message info), ``now`` this process's clock in the callback; all ns since
  the epoch (the namespaces share the machine's clock);
- ``["t", stamp, source, w, x, y, z]``: an ``attitude/ground_truth`` (``source``:
  when the gyro published step k, with its increment and measurement);
- ``["d", now, name, level, message, {key: value}]``: a ``/diagnostics`` status.

Usage: ``hosts_recorder.py OUT [--estimates reliable|best_effort|none]
[--truth] [--diagnostics]``. SIGINT or SIGTERM end it (exit 0).
"""

import argparse
import json
import signal
import sys
import time

import rclpy
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import QuaternionStamped


def nanoseconds(stamp):
    return stamp.sec * 1_000_000_000 + stamp.nanosec


class Recorder(Node):

    def __init__(self, out, estimates, truth, diagnostics):
        super().__init__('hosts_recorder')
        self.out = out
        self.lines = []
        if estimates != 'none':
            reliability = {'reliable': ReliabilityPolicy.RELIABLE,
                           'best_effort': ReliabilityPolicy.BEST_EFFORT}[estimates]
            # Keep all: after a stall the observer publishes a burst of
            # estimates faster than this process reads them, and a kept-last
            # history would drop the oldest unread in this reader (with depth
            # 1000, 37 % of a burst of 1180 once), which is not what the
            # link did.
            self.create_subscription(QuaternionStamped, 'attitude_estimate',
                                     self.estimate_callback,
                                     QoSProfile(history=HistoryPolicy.KEEP_ALL,
                                                reliability=reliability))
        if truth:
            self.create_subscription(QuaternionStamped, 'attitude/ground_truth',
                                     self.truth_callback,
                                     QoSProfile(history=HistoryPolicy.KEEP_ALL))
        if diagnostics:
            self.create_subscription(DiagnosticArray, '/diagnostics',
                                     self.diagnostics_callback, QoSProfile(depth=100))
        self.create_timer(0.1, self.flush)

    def estimate_callback(self, msg, info):
        q = msg.quaternion
        self.lines.append(['e', nanoseconds(msg.header.stamp), info['source_timestamp'],
                           info['received_timestamp'], time.time_ns(), q.w, q.x, q.y, q.z])

    def truth_callback(self, msg, info):
        q = msg.quaternion
        self.lines.append(['t', nanoseconds(msg.header.stamp), info['source_timestamp'],
                           q.w, q.x, q.y, q.z])

    def diagnostics_callback(self, msg):
        now = time.time_ns()
        for status in msg.status:
            level = status.level
            level = level[0] if isinstance(level, (bytes, bytearray)) else int(level)
            self.lines.append(['d', now, status.name, level, status.message,
                               {kv.key: kv.value for kv in status.values}])

    def flush(self):
        if self.lines:
            self.out.write(''.join(json.dumps(line) + '\n' for line in self.lines))
            self.out.flush()
            self.lines = []


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('out')
    parser.add_argument('--estimates', choices=('reliable', 'best_effort', 'none'),
                        default='reliable')
    parser.add_argument('--truth', action='store_true')
    parser.add_argument('--diagnostics', action='store_true')
    args = parser.parse_args(argv)
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    stop = []
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, lambda *_: stop.append(True))
    with open(args.out, 'a') as out:
        node = Recorder(out, args.estimates, args.truth, args.diagnostics)
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        try:
            while not stop:
                executor.spin_once(timeout_sec=0.05)
        except ExternalShutdownException:
            pass
        finally:
            node.flush()
            executor.shutdown()
            node.destroy_node()
            rclpy.try_shutdown()
    return 0


if __name__ == '__main__':
    sys.exit(main())
