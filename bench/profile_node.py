"""
Where the observer node's per-message time goes.

Two measurements, each in a child process with its own ROS domain:

``direct``
    The node's callbacks called directly with prepared messages (no
    executor, no DDS receive): the exact cost, in µs per step, of the work
    the node's own code does, next to its parts (the core step, the numpy
    normalization, building the messages, publishing, reading the clock)
    and to the bare relay's callbacks.
``loop``
    The node hosted on an executor, fed at 1 kHz by the driver process,
    under cProfile (wall clock; its overhead inflates the Python parts):
    the share of the main thread spent idle in the wait set, in the
    executor's own Python code, in taking and deserializing messages, and
    in the node's callbacks.

Run by ``python -m bench`` (see :func:`profile_direct`, :func:`profile_loop`).
The raw-IMU node's CPU split by thread (``python -m bench.profile_node imu``)
answered where its time goes (docs/nodes.md) and left; its code is this file at
commit 7319e4b.
"""

import argparse
import cProfile
import json
import os
import pstats
import sys
import tempfile
import threading
import time

from bench.numpy_use import numpy_use_per_step
from bench.procs import Child, children, reserved_domain_id, ros_env
from bench.rosutil import (EXECUTORS, make_executor, set_stamp,
                           spin_until_shutdown)
from bench.timing import best_pass, best_seconds, top_functions

DIRECT_STEPS = 5000
LOOP_RATE = 1000  # Hz
LOOP_SECONDS = 2.0


def _messages(steps, start, period_ns=1_000_000):
    """Paired messages of ``steps`` steps, stamped from ``start`` (ns) on."""
    from geometry_msgs.msg import QuaternionStamped, Vector3Stamped
    pairs = []
    for k in range(steps):
        inc = Vector3Stamped()
        inc.header.frame_id = 'imu'
        inc.vector.x, inc.vector.y, inc.vector.z = 0.001, -0.002, 0.003
        meas = QuaternionStamped()
        meas.header.frame_id = 'imu'
        meas.quaternion.w = 1.0
        set_stamp(inc.header.stamp, start + k * period_ns)
        set_stamp(meas.header.stamp, start + k * period_ns)
        pairs.append((inc, meas))
    return pairs


def _passes(count, steps, period_ns=1_000_000):
    """``count`` passes of messages on one continuous time line."""
    start = time.time_ns()
    return [_messages(steps, start + i * steps * period_ns, period_ns)
            for i in range(count)]


def _run_pairs(increment_callback, measurement_callback, pairs):
    start = time.perf_counter()
    for inc, meas in pairs:
        increment_callback(inc)
        measurement_callback(meas)
    return (time.perf_counter() - start) / len(pairs) * 1e6


# The parts of a step timed alone, and how to recognise their calls in a
# profile: (file name ending, function name).
PARTS = {
    'core_step': ('observer.py', 'step'),
    'numpy_normalize': ('quaternion.py', 'normalize'),
    'build_message': ('conversions.py', 'quaternion_stamped'),
    'publish': ('publisher.py', 'publish'),
    'clock_now': ('clock.py', 'now'),
}


def direct(steps=DIRECT_STEPS):
    """
    Time the node's and the relay's callbacks, and the parts of a step.

    The node's internals are not assumed: how often each part runs per step
    is counted by cProfile on the same callbacks.

    Returns
    -------
    result : dict
        µs per step (``observer_callbacks``, ``relay_callbacks``); µs per
        call of each part of :data:`PARTS` and ``calls_per_step``;
        ``numpy_use_per_step``, the functions that use numpy
        (:func:`bench.numpy_use.numpy_use_per_step`); ``top``, the functions with the most
        own time per step under cProfile.

    """
    import numpy as np
    import rclpy
    from rclpy.context import Context

    from bench.relay import RelayNode
    from ext_observer.nodes.conversions import quaternion_stamped
    from ext_observer.core import normalize, SingleObserver
    from ext_observer.nodes.observer_node import ObserverNode
    context = Context()
    rclpy.init(context=context)
    try:
        node = ObserverNode(context=context)
        relay = RelayNode(context)
        result = {}
        # Warm up, then the best of three passes; stamps go on across passes.
        profiled_steps = 1000
        *timed, profiled = _passes(5, steps)
        pairs = iter(timed)
        result['observer_callbacks'] = best_pass(lambda: _run_pairs(
            node.increment_callback, node.measurement_callback, next(pairs)), 4)
        pairs = iter(_passes(4, steps))
        result['relay_callbacks'] = best_pass(lambda: _run_pairs(
            relay.increment_callback, relay.measurement_callback, next(pairs)), 4)
        profile = cProfile.Profile()
        profile.runcall(_run_pairs, node.increment_callback,
                        node.measurement_callback, profiled[:profiled_steps])
        calls_per_step = dict.fromkeys(PARTS, 0.0)
        for (path, _, name), (_, calls, _, _, _) in pstats.Stats(profile).stats.items():
            for key, (ending, function) in PARTS.items():
                if name == function and path.endswith(ending):
                    calls_per_step[key] += calls / profiled_steps
        # Which functions use numpy, by what their calls do (not by module),
        # on the next steps of the same pass.
        result['numpy_use_per_step'] = numpy_use_per_step(
            profiled_steps, _run_pairs, node.increment_callback, node.measurement_callback,
            profiled[profiled_steps:2 * profiled_steps])
        result['numpy_use_steps'] = profiled_steps
        result['calls_per_step'] = calls_per_step
        result['top'] = top_functions(profile, profiled_steps, skip=(
            '_run_pairs', "<method 'disable' of '_lsprof.Profiler' objects>"))
        observer = SingleObserver()
        increment, measurement = (0.001, -0.002, 0.003), (1.0, 0.0, 0.0, 0.0)
        result['core_step'] = 1e6 * best_seconds(
            lambda: observer.step(increment, measurement), steps, 5)
        state = observer.state
        result['numpy_normalize'] = 1e6 * best_seconds(
            lambda: normalize(np.asarray(state)), steps, 5)
        msg = quaternion_stamped(state, time.time_ns(), 'world')
        result['build_message'] = 1e6 * best_seconds(
            lambda: quaternion_stamped(state, 1_000_000_000, 'world'), steps, 5)
        result['publish'] = 1e6 * best_seconds(
            lambda: node.estimate_publisher.publish(msg), steps, 5)
        clock = node.get_clock()
        result['clock_now'] = 1e6 * best_seconds(lambda: clock.now().nanoseconds,
                                                   steps, 5)
        node.destroy_node()
        relay.node.destroy_node()
    finally:
        rclpy.try_shutdown(context=context)
    return result


def _categories(stats, steps):
    """Main-thread time per step by category, µs, from a pstats.Stats."""
    idle = take = callbacks = 0.0
    parts = dict.fromkeys(('core_step', 'numpy_normalize', 'build_message',
                           'publish', 'clock_now'), 0.0)
    total = 0.0
    for (path, _, name), (_, _, tottime, cumtime, _) in stats.stats.items():
        if name.startswith('<') and 'wait' in name and 'rclpy' in name:
            idle += tottime
        elif name == '_take_subscription':
            take += cumtime
        elif name in ('increment_callback', 'measurement_callback',
                      'timeout_callback', 'diagnostic_callback'):
            callbacks += cumtime
        elif name == 'step' and path.endswith('observer.py'):
            parts['core_step'] += cumtime
        elif name == 'normalize' and path.endswith('quaternion.py'):
            parts['numpy_normalize'] += cumtime
        elif name == 'quaternion_stamped':
            parts['build_message'] += cumtime
        elif name == 'publish' and path.endswith('publisher.py'):
            parts['publish'] += cumtime
        elif name == 'now' and path.endswith('clock.py'):
            parts['clock_now'] += cumtime
        if name == '_spin_for':
            total = cumtime
    per_step = 1e6 / max(steps, 1)
    return {
        'steps': steps,
        'total': total * per_step,
        'idle_wait': idle * per_step,
        'take_deserialize': take * per_step,
        'callbacks': callbacks * per_step,
        'executor_python': (total - idle - take - callbacks) * per_step,
        'callback_parts': {k: v * per_step for k, v in parts.items()},
    }


class _Timed:
    """A callback wrapper that adds up the wall and CPU time inside it."""

    def __init__(self, callback):
        self.callback = callback
        self.seconds = 0.0
        self.cpu_seconds = 0.0
        self.calls = 0

    def __call__(self, msg):
        start, cpu = time.perf_counter(), time.thread_time()
        self.callback(msg)
        self.cpu_seconds += time.thread_time() - cpu
        self.seconds += time.perf_counter() - start
        self.calls += 1


class _PublishCounter:
    """Counts the estimates a node publishes (one per step)."""

    def __init__(self, publisher):
        self.publish = publisher.publish
        self.count = 0
        publisher.publish = self

    def __call__(self, msg):
        self.count += 1
        self.publish(msg)


def _spin_for(executor, context, seconds):
    stop = threading.Event()
    timer = threading.Timer(seconds, stop.set)
    timer.start()
    spin_until_shutdown(executor, context, stop)
    timer.cancel()


def loop(executor_kind, out_path, seconds, node_kind='observer'):
    """
    Host the node and measure its main thread, after 'start' on stdin.

    ``node_kind`` is ``observer`` (the package's ObserverNode) or ``relay``.

    First ``seconds`` with the subscription callbacks wrapped in timers
    (no profiler): CPU time of the main thread and of the whole process per
    step, and the time inside the callbacks. Then ``seconds`` under
    cProfile, for the split (see :func:`_categories`).
    """
    import rclpy
    from rclpy.context import Context

    from bench.relay import RelayNode
    from ext_observer.nodes.observer_node import ObserverNode
    context = Context()
    rclpy.init(context=context)
    if node_kind == 'relay':
        node = RelayNode(context)
        ros_node = node.node
    else:
        node = ros_node = ObserverNode(context=context)
    executor = make_executor(executor_kind, context)
    executor.add_node(ros_node)
    started = threading.Event()

    def serve():
        for line in sys.stdin:
            if line.strip() == 'start':
                started.set()
                break
    threading.Thread(target=serve, daemon=True).start()
    print('ready', flush=True)
    try:
        while not started.is_set() and context.ok():
            executor.spin_once(timeout_sec=0.05)
        counter = _PublishCounter(node.estimate_publisher)
        timed = {}
        for name in ('increment_subscription', 'measurement_subscription'):
            subscription = getattr(node, name)
            timed[name] = _Timed(subscription.callback)
            subscription.callback = timed[name]
        steps0, thread0, process0 = (counter.count, time.thread_time(),
                                     time.process_time())
        _spin_for(executor, context, seconds)
        steps = max(counter.count - steps0, 1)
        result = {
            'executor': executor_kind,
            'node': node_kind,
            'timed_steps': steps,
            'main_thread_cpu': (time.thread_time() - thread0) / steps * 1e6,
            'process_cpu': (time.process_time() - process0) / steps * 1e6,
            'callbacks_wall': sum(t.seconds for t in timed.values())
            / steps * 1e6,
            'callbacks_cpu': sum(t.cpu_seconds for t in timed.values())
            / steps * 1e6,
        }
        for name, t in timed.items():
            getattr(node, name).callback = t.callback
        steps0 = counter.count
        profile = cProfile.Profile()
        profile.runcall(_spin_for, executor, context, seconds)
        result['cprofile'] = _categories(pstats.Stats(profile),
                                         counter.count - steps0)
        with open(out_path, 'w') as out:
            json.dump(result, out)
        print('profiled', flush=True)
        # Hold on until the parent ends this process.
        spin_until_shutdown(executor, context)
    finally:
        executor.shutdown()
        ros_node.destroy_node()
        rclpy.try_shutdown(context=context)


def profile_direct(index=0, log_dir=None):
    """Run :func:`direct` in a child process; return its result."""
    with tempfile.TemporaryDirectory(prefix='bench-') as tmp, \
            reserved_domain_id(index) as domain_id, children() as started:
        out = os.path.join(tmp, 'direct.json')
        child = Child('profile direct', ['-m', 'bench.profile_node', 'direct',
                                         '--out', out], ros_env(domain_id),
                      os.path.join(log_dir or tmp, 'profile-direct.log'))
        started.append(child)
        child.expect('profiled', 120)
        with open(out) as f:
            return json.load(f)


def profile_loop(executor='single', index=0, rate=LOOP_RATE,
                 seconds=LOOP_SECONDS, log_dir=None, node='observer'):
    """Measure ``node`` on ``executor`` fed at ``rate`` (see :func:`loop`)."""
    with tempfile.TemporaryDirectory(prefix='bench-') as tmp, \
            reserved_domain_id(index) as domain_id, children() as started:
        env = ros_env(domain_id)
        logs = log_dir or tmp
        out = os.path.join(tmp, 'loop.json')
        host = Child('profile loop', ['-m', 'bench.profile_node', 'loop',
                                      '--node', node, '--executor', executor,
                                      '--out', out, '--seconds', str(seconds)],
                     env, os.path.join(logs, f'profile-{node}-{executor}.log'))
        started.append(host)
        probe = Child('probe', ['-m', 'bench.probe'], env,
                      os.path.join(logs, 'profile-probe.log'))
        started.append(probe)
        driver = Child('driver', ['-m', 'bench.driver'], env,
                       os.path.join(logs, 'profile-driver.log'))
        started.append(driver)
        for child in (host, probe, driver):
            child.expect('ready', 30)
        driver.send('match 30')
        if driver.expect('', 40) != 'matched':
            raise RuntimeError('profile: the node did not subscribe'
                               + host.log_tail())
        probe.send('match 30')
        probe.expect('', 40)
        time.sleep(0.5)
        host.send('start')
        driver.send(f'run {rate} {2 * seconds + 1.0} '
                    f'{os.path.join(tmp, "d.npz")}')
        host.expect('profiled', 2 * seconds + 60)
        driver.expect('done', 2 * seconds + 60)
        with open(out) as f:
            result = json.load(f)
        result['rate'] = rate
        return result


def main(argv=None):
    """Child entry point: ``direct`` or ``loop``."""
    parser = argparse.ArgumentParser(prog='python -m bench.profile_node')
    parser.add_argument('mode', choices=('direct', 'loop'))
    parser.add_argument('--out', required=True)
    parser.add_argument('--executor', choices=EXECUTORS, default='single')
    parser.add_argument('--seconds', type=float, default=LOOP_SECONDS)
    parser.add_argument('--node', choices=('observer', 'relay'),
                        default='observer')
    args = parser.parse_args(argv)
    if args.mode == 'direct':
        result = direct()
        with open(args.out, 'w') as out:
            json.dump(result, out)
        print('profiled', flush=True)
    else:
        loop(args.executor, args.out, args.seconds, args.node)
    return 0


if __name__ == '__main__':
    sys.exit(main())
