"""
The probe: records the arrival of every ``attitude_estimate``.

Takes the messages serialized (``raw=True``) and only notes the wall-clock
arrival time and the bytes; stamps are read out of the bytes when the
records are dumped, so the probe's per-message cost stays small and it is
not the bottleneck of the chain. Controlled by lines on stdin
(``python -m bench.probe [--executor events]``):

``match TIMEOUT``
    wait for a publisher on the topic; answers ``matched`` or ``unmatched``.
``count``
    answers ``count N`` (records since the last dump).
``dump PATH``
    save ``stamps`` and ``arrived`` (ns) to ``PATH`` (``.npz``), forget
    them, and answer ``dumped N``. The file also holds ``counters``: the
    JSON of the key values of the last ``/diagnostics`` status whose name
    ends with ``: inputs`` (the observer's input counters), ``{}`` if none.
``quit``
"""

import argparse
import json
import sys
import threading
import time

import numpy as np

from bench.rosutil import (EXECUTORS, make_executor, raw_stamp_ns, serve_lines,
                           spin_until_shutdown, wait_until)


class Probe:
    """A raw subscription and its records."""

    def __init__(self, context, topic='attitude_estimate', depth=1000):
        from geometry_msgs.msg import QuaternionStamped
        from rclpy.node import Node
        self.node = Node('bench_probe', context=context)
        self.topic = topic
        self.lock = threading.Lock()
        self.arrived = []
        self.data = []
        self.counters = {}
        self.node.create_subscription(QuaternionStamped, topic,
                                      self.estimate_callback, depth, raw=True)
        from diagnostic_msgs.msg import DiagnosticArray
        self.node.create_subscription(DiagnosticArray, '/diagnostics',
                                      self.diagnostics_callback, 10)

    def estimate_callback(self, data):
        """Note the arrival time and keep the bytes."""
        now = time.time_ns()
        with self.lock:
            self.arrived.append(now)
            self.data.append(data)

    def diagnostics_callback(self, msg):
        """Keep the key values of the last ``...: inputs`` status."""
        for status in msg.status:
            if status.name.endswith(': inputs'):
                self.counters = {kv.key: kv.value for kv in status.values}

    def take(self):
        """Return and forget the records: ``(stamps, arrived)`` in ns."""
        with self.lock:
            arrived, self.arrived = self.arrived, []
            data, self.data = self.data, []
        stamps = np.fromiter((raw_stamp_ns(d) for d in data), dtype=np.int64,
                             count=len(data))
        return stamps, np.asarray(arrived, dtype=np.int64)

    def match(self, timeout):
        """Wait for a publisher of the topic; return success."""
        return wait_until(lambda: self.node.count_publishers(self.topic) > 0, timeout)


def _serve(probe, stop):
    def count(words):
        with probe.lock:
            print(f'count {len(probe.arrived)}', flush=True)

    def dump(words):
        stamps, arrived = probe.take()
        np.savez(words[1], stamps=stamps, arrived=arrived, counters=json.dumps(probe.counters))
        print(f'dumped {len(stamps)}', flush=True)
    try:
        serve_lines({'count': count, 'dump': dump}, probe.match)
    finally:
        stop.set()


def main(argv=None):
    """Record until ``quit`` or SIGINT."""
    parser = argparse.ArgumentParser(prog='python -m bench.probe')
    parser.add_argument('--executor', choices=EXECUTORS, default='events')
    parser.add_argument('--topic', default='attitude_estimate')
    args = parser.parse_args(argv)
    import rclpy
    from rclpy.context import Context
    context = Context()
    rclpy.init(context=context)
    probe = Probe(context, args.topic)
    executor = make_executor(args.executor, context)
    executor.add_node(probe.node)
    stop = threading.Event()
    threading.Thread(target=_serve, args=(probe, stop), daemon=True).start()
    print('ready', flush=True)
    try:
        spin_until_shutdown(executor, context, stop)
    finally:
        executor.shutdown()
        probe.node.destroy_node()
        rclpy.try_shutdown(context=context)
    return 0


if __name__ == '__main__':
    sys.exit(main())
