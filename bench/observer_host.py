"""
Run the package's ``ObserverNode`` on an executor of the benchmark's choice.

The shipped ``observer_node`` entry point spins with ``rclpy.spin`` (the
default SingleThreadedExecutor) and has no executor option, so the
benchmark hosts the same, unmodified node class to compare executors:
``python -m bench.observer_host --executor events --ros-args -p ...``.
SIGINT ends it.
"""

import argparse
import sys

from bench.rosutil import EXECUTORS, make_executor, spin_until_shutdown


def main(argv=None):
    """Spin one ObserverNode until SIGINT."""
    argv = sys.argv[1:] if argv is None else list(argv)
    parser = argparse.ArgumentParser(prog='python -m bench.observer_host')
    parser.add_argument('--executor', choices=EXECUTORS, default='single')
    args, ros_args = parser.parse_known_args(argv)
    import rclpy
    from rclpy.context import Context

    from ext_observer.nodes.observer_node import ObserverNode
    context = Context()
    rclpy.init(args=['observer_host'] + ros_args, context=context)
    node = ObserverNode(context=context)
    executor = make_executor(args.executor, context)
    executor.add_node(node)
    print('ready', flush=True)
    try:
        spin_until_shutdown(executor, context)
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=context)
    return 0


if __name__ == '__main__':
    sys.exit(main())
