"""
A bare relay: the observer node's message path without the maths.

Subscribes to ``gyro/increment`` (geometry_msgs/Vector3Stamped) and
``attitude/measurement`` (geometry_msgs/QuaternionStamped), pairs them by
stamp, and publishes one ``attitude_estimate`` (QuaternionStamped, the
measurement's quaternion) per paired step. Its sustained rate is the
ceiling of a naive rclpy node on this machine; the observer's rate divided
by it is what the maths costs on top of rclpy.

Run as ``python -m bench.relay --executor single|multi|events``; SIGINT
ends it.
"""

import argparse
import sys

from bench.rosutil import EXECUTORS, make_executor, spin_until_shutdown

# Unpaired halves kept at most (a lost partner must not grow the dicts).
MAX_PENDING = 1000


class RelayNode:
    """
    The relay, built on a given rclpy context.

    Parameters
    ----------
    context : rclpy.context.Context
    depth : int
        Queue depth of the subscriptions and the publisher.

    """

    def __init__(self, context, depth=10):
        from geometry_msgs.msg import QuaternionStamped, Vector3Stamped
        from rclpy.node import Node
        self.node = Node('relay', context=context)
        self._out = QuaternionStamped
        self.increments = {}
        self.measurements = {}
        self.steps = 0
        self.estimate_publisher = self.node.create_publisher(
            QuaternionStamped, 'attitude_estimate', depth)
        inputs = self._inputs_node(context)
        self.increment_subscription = inputs.create_subscription(
            Vector3Stamped, 'gyro/increment', self.increment_callback, depth)
        self.measurement_subscription = inputs.create_subscription(
            QuaternionStamped, 'attitude/measurement', self.measurement_callback,
            depth)

    def _inputs_node(self, context):
        """The node the subscriptions belong to: the relay's own."""
        return self.node

    @staticmethod
    def _key(msg):
        stamp = msg.header.stamp
        return stamp.sec, stamp.nanosec

    def increment_callback(self, msg):
        """Keep the increment until its measurement comes, or pair it."""
        measurement = self._pair(msg, self.measurements, self.increments)
        if measurement is not None:
            self._publish(msg, measurement)

    def measurement_callback(self, msg):
        """Keep the measurement until its increment comes, or pair it."""
        increment = self._pair(msg, self.increments, self.measurements)
        if increment is not None:
            self._publish(increment, msg)

    def _pair(self, msg, partners, pending):
        """``msg``'s partner of the same stamp, taken from ``partners``; else keep ``msg``."""
        key = self._key(msg)
        partner = partners.pop(key, None)
        if partner is None:
            if len(pending) >= MAX_PENDING:
                del pending[next(iter(pending))]
            pending[key] = msg
        return partner

    def _publish(self, increment, measurement):
        out = self._out()
        out.header.frame_id = measurement.header.frame_id
        # The step's stamp t_k (the observer's t_{k+1} would need the period,
        # which costs nothing measurable).
        out.header.stamp = measurement.header.stamp
        out.quaternion = measurement.quaternion
        self.estimate_publisher.publish(out)
        self.steps += 1


class PollingRelay(RelayNode):
    """
    The relay with fewer wake-ups: a timer takes every waiting message.

    The subscriptions belong to a second node that no executor spins; a
    timer of ``period`` s on the relay node takes all the messages waiting
    in both (``take_message`` until empty) and pairs them as the relay
    does. One wake-up serves ``rate × period`` steps, at the price of up to
    ``period`` of added latency; the queues must hold ``rate × period``
    messages.

    Parameters
    ----------
    context : rclpy.context.Context
    depth : int
    period : float
        Poll period, s.

    """

    def __init__(self, context, depth=100, period=0.001):
        super().__init__(context, depth)
        self.poll_timer = self.node.create_timer(period, self.poll_callback)

    def _inputs_node(self, context):
        """A second node, which no executor spins: the timer takes its messages."""
        from rclpy.node import Node
        self.inputs = Node('relay_inputs', context=context)
        return self.inputs

    def poll_callback(self):
        """Take and pair every waiting increment and measurement."""
        for subscription in (self.increment_subscription,
                             self.measurement_subscription):
            with subscription.handle:
                take = subscription.handle.take_message
                while True:
                    taken = take(subscription.msg_type, False)
                    if taken is None:
                        break
                    subscription.callback(taken[0])


def main(argv=None):
    """Run the relay until SIGINT."""
    parser = argparse.ArgumentParser(prog='python -m bench.relay')
    parser.add_argument('--executor', choices=EXECUTORS, default='single')
    parser.add_argument('--depth', type=int, default=None,
                        help='queue depth (default 10; 100 with --poll)')
    parser.add_argument('--poll', type=float, default=None, metavar='PERIOD',
                        help='take messages in batches every PERIOD s '
                             '(PollingRelay) instead of one callback each')
    args = parser.parse_args(argv)
    import rclpy
    from rclpy.context import Context
    context = Context()
    rclpy.init(context=context)
    if args.poll:
        relay = PollingRelay(context, args.depth or 100, args.poll)
    else:
        relay = RelayNode(context, args.depth or 10)
    executor = make_executor(args.executor, context)
    executor.add_node(relay.node)
    print('ready', flush=True)
    try:
        spin_until_shutdown(executor, context)
    finally:
        executor.shutdown()
        if isinstance(relay, PollingRelay):
            relay.inputs.destroy_node()
        relay.node.destroy_node()
        rclpy.try_shutdown(context=context)
    return 0


if __name__ == '__main__':
    sys.exit(main())
