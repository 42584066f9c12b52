"""
The demo: gyro → observer → monitor in one process, then a summary and a plot.

``python -m ext_observer demo`` composes the three nodes in one
``SingleThreadedExecutor`` with their own context, as ``composed.py`` in
ros2/examples does, plus a recorder node that keeps every estimate and every
ground truth. It runs the paper's observer setup (Section 3.2: increments
uniform in [0, 10] rad per axis, measurement noise σ = 0.1, gain
L = (0.11, −0.18, −0.18, −0.18), α = 0.01) for a bounded number of steps,
starting the estimate off the sphere at 1.3 (V = (1.3² − 1)² ≈ 0.48, inside
the certified set V ≤ 0.5), so that both the distance to S³ and the attitude
error start large and visibly fall. Progress comes from the monitor's
``/diagnostics``; the summary and the plot from the recorded topics, with
the core's ``manifold_distance`` and ``attitude_error``.
"""

import argparse
import os
import signal
import sys
import threading
import time

from ext_observer.core import VARIANTS

__all__ = ['main', 'run_demo']

DEFAULT_INITIAL_ESTIMATE = (1.3, 0.0, 0.0, 0.0)


def _quaternion_text(text):
    try:
        values = tuple(float(v) for v in text.split(','))
    except ValueError:
        raise argparse.ArgumentTypeError(f'expected w,x,y,z, got {text!r}') from None
    if len(values) != 4:
        raise argparse.ArgumentTypeError(f'expected 4 numbers w,x,y,z, got {text!r}')
    return values


def _positive(kind):
    def parse(text):
        value = kind(text)
        if not value > 0:
            raise argparse.ArgumentTypeError(f'must be positive, got {text}')
        return value
    return parse


def build_parser():
    """Return the argument parser of ``python -m ext_observer demo``."""
    parser = argparse.ArgumentParser(
        prog='python -m ext_observer demo',
        description='Run the simulated gyro, the observer and the monitor together '
                    'in one process; print a summary and write a plot.')
    parser.add_argument('--steps', type=_positive(int), default=150,
                        help='steps to simulate (default 150)')
    parser.add_argument('--rate', type=_positive(float), default=30.0,
                        help='steps per second, Hz (default 30)')
    parser.add_argument('--seed', type=int, default=7,
                        help='seed of the simulated gyro (default 7; -1 = random)')
    parser.add_argument('--variant', default='extended', choices=VARIANTS,
                        help='observer (default extended)')
    parser.add_argument('--increment-max', type=float, default=10.0,
                        help='bound of the increment per axis, rad (default 10, '
                             'the paper)')
    parser.add_argument('--noise', type=float, default=0.1,
                        help='measurement noise σ (default 0.1, the paper)')
    parser.add_argument('--initial-estimate', type=_quaternion_text,
                        default=DEFAULT_INITIAL_ESTIMATE,
                        help='initial estimate w,x,y,z (default 1.3,0,0,0)')
    parser.add_argument('--plot', default=os.path.join('out', 'demo.png'),
                        help='PNG to write (default out/demo.png; "" = none)')
    parser.add_argument('--quiet', action='store_true', help='no progress lines')
    return parser


def run_demo(steps=150, rate=30.0, seed=7, variant='extended', increment_max=10.0,
             noise=0.1, initial_estimate=DEFAULT_INITIAL_ESTIMATE, progress=None,
             domain_id=None):
    """
    Run the three nodes for ``steps`` steps and return what was recorded.

    Parameters
    ----------
    steps : int
    rate : float
        Hz.
    seed : int
        -1 for a random seed.
    variant : str
    increment_max, noise : float
        The gyro's ``increment_max`` (rad) and ``measurement_noise_std``.
    initial_estimate : sequence of 4 float
    progress : callable, optional
        Called with ``(elapsed_s, steps_done, status)`` for each status the
        monitor publishes.
    domain_id : int, optional
        ROS domain (default: ``ROS_DOMAIN_ID`` or 0).

    Returns
    -------
    result : dict
        ``stamps`` (ns), ``distance`` and ``attitude_error`` (rad) per step
        from 0 (the initial estimate) on, ``steps_done``, ``elapsed_s``,
        ``last_status``.

    Raises
    ------
    ext_observer.nodes.node_common.ParameterError
        If a node refuses a setting.

    """
    # Every process that starts a node keeps discovery on this machine.
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    import rclpy
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor

    context = Context()
    init_kwargs = {} if domain_id is None else {'domain_id': domain_id}
    rclpy.init(args=[], context=context, **init_kwargs)
    nodes = []
    executor = SingleThreadedExecutor(context=context)
    # Ctrl-C stops the loop between two spins. A KeyboardInterrupt raised
    # wherever the interpreter happens to be can cut an rclpy object in half
    # (Task.__del__ then prints a traceback at exit).
    interrupted = []
    previous_handler = None
    if threading.current_thread() is threading.main_thread():
        previous_handler = signal.signal(
            signal.SIGINT, lambda signum, frame: interrupted.append(signum))
    try:
        observer, recorder, gyro = _start_nodes(
            context, nodes, rate, dict(variant=variant, initial_estimate=initial_estimate),
            dict(steps=steps, seed=seed, increment_max=increment_max, noise=noise))
        for node in nodes:
            executor.add_node(node)
        elapsed = _spin_until_done(executor, observer, recorder, gyro, steps, rate,
                                   progress, interrupted)
        return _paired_result(recorder, initial_estimate, 1.0 / rate,
                              dict(steps_done=_steps_done(observer), elapsed_s=elapsed))
    finally:
        executor.shutdown()
        for node in nodes:
            node.destroy_node()
        rclpy.try_shutdown(context=context)
        if previous_handler is not None:
            signal.signal(signal.SIGINT, previous_handler)


def _start_nodes(context, nodes, rate, observer_settings, gyro_settings):
    """Create the observer, the monitor, the recorder and the gyro into ``nodes``."""
    from rclpy.parameter import Parameter

    from ext_observer.nodes.gyro_node import GyroNode
    from ext_observer.nodes.monitor_node import MonitorNode, STATUS_NAME
    from ext_observer.nodes.observer_node import ObserverNode

    observer = ObserverNode(context=context, parameter_overrides=[
        Parameter('variant', value=observer_settings['variant']),
        Parameter('initial_estimate',
                  value=[float(v) for v in observer_settings['initial_estimate']]),
        Parameter('step_period', value=1.0 / rate),
    ])
    nodes.append(observer)
    nodes.append(MonitorNode(context=context, parameter_overrides=[
        Parameter('diagnostic_period', value=0.5),
        Parameter('window', value=max(10, int(rate))),
    ]))
    recorder = _make_recorder(context, STATUS_NAME)
    nodes.append(recorder)
    gyro = GyroNode(context=context, parameter_overrides=[
        Parameter('rate_hz', value=float(rate)),
        Parameter('steps', value=int(gyro_settings['steps'])),
        Parameter('seed', value=int(gyro_settings['seed'])),
        Parameter('increment_max', value=float(gyro_settings['increment_max'])),
        Parameter('measurement_noise_std', value=float(gyro_settings['noise'])),
    ])
    nodes.append(gyro)
    return observer, recorder, gyro


def _steps_done(observer):
    return observer.counts['steps_corrected'] + observer.counts['steps_propagated']


def _spin_until_done(executor, observer, recorder, gyro, steps, rate, progress, interrupted):
    """Spin until the gyro has finished and every estimate is in (or a deadline); the time."""
    start = time.monotonic()
    deadline = start + steps / rate + 15.0
    reported = 0
    while time.monotonic() < deadline:
        if interrupted:
            raise KeyboardInterrupt
        executor.spin_once(timeout_sec=0.05)
        if progress is not None:
            while reported < len(recorder.statuses):
                progress(time.monotonic() - start, _steps_done(observer),
                         recorder.statuses[reported])
                reported += 1
        if gyro.finished and len(recorder.estimates) >= steps:
            break
    return time.monotonic() - start


def _paired_result(recorder, initial_estimate, period, result):
    """Pair the recorded estimates with the truths; ``result`` with the distances and errors."""
    import numpy as np

    from ext_observer.core import attitude_error, manifold_distance

    estimates = dict(recorder.estimates)
    truths = dict(recorder.truths)
    if truths:
        # Step 0: the initial estimate against the first truth q_0.
        estimates[min(truths)] = tuple(float(v) for v in initial_estimate)
    paired = _pair_by_stamp(estimates, truths, round(0.25e9 * period))
    if paired:
        est = np.array([estimates[e] for _, e in paired])
        tru = np.array([truths[t] for t, _ in paired])
        distance = manifold_distance(est)
        error = attitude_error(est, tru)
    else:
        distance = error = np.zeros(0)
    return dict(result, stamps=[t for t, _ in paired], distance=np.asarray(distance),
                attitude_error=np.asarray(error),
                last_status=recorder.statuses[-1] if recorder.statuses else None)


def _pair_by_stamp(estimates, truths, tolerance):
    """
    Pair each ground truth with the estimate of the nearest stamp.

    The observer stamps ``t_k + Δ`` with ``Δ`` rounded to whole nanoseconds,
    so the two clocks may differ by a nanosecond; ``tolerance`` (ns) absorbs it.

    Returns
    -------
    pairs : list of (truth stamp, estimate stamp), in stamp order

    """
    import bisect
    keys = sorted(estimates)
    pairs = []
    for stamp in sorted(truths):
        i = bisect.bisect_left(keys, stamp)
        near = [k for k in keys[max(i - 1, 0):i + 1] if abs(k - stamp) <= tolerance]
        if near:
            pairs.append((stamp, min(near, key=lambda k: abs(k - stamp))))
    return pairs


def _make_recorder(context, status_name):
    from diagnostic_msgs.msg import DiagnosticArray
    from geometry_msgs.msg import QuaternionStamped
    from rclpy.node import Node

    from ext_observer.nodes.conversions import nanoseconds_from_stamp, quaternion_from_msg

    class Recorder(Node):
        """Keep every estimate, ground truth and monitor status."""

        def __init__(self):
            super().__init__('demo_recorder', context=context)
            self.estimates = {}
            self.truths = {}
            self.statuses = []
            self.create_subscription(QuaternionStamped, 'attitude_estimate',
                                     self.estimate_callback, 100)
            self.create_subscription(QuaternionStamped, 'attitude/ground_truth',
                                     self.truth_callback, 100)
            self.create_subscription(DiagnosticArray, '/diagnostics',
                                     self.diagnostics_callback, 10)

        def estimate_callback(self, msg):
            self.estimates[nanoseconds_from_stamp(msg.header.stamp)] = \
                quaternion_from_msg(msg.quaternion)

        def truth_callback(self, msg):
            self.truths[nanoseconds_from_stamp(msg.header.stamp)] = \
                quaternion_from_msg(msg.quaternion)

        def diagnostics_callback(self, msg):
            self.statuses.extend(s for s in msg.status if s.name == status_name)

    return Recorder()


def _print_progress(total):
    from ext_observer.nodes.node_common import LEVEL_NAMES

    def show(elapsed, done, status):
        print(f'[{elapsed:5.1f} s] step {done:4d}/{total}  monitor '
              f'{LEVEL_NAMES.get(status.level, "?"):5s} {status.message}', flush=True)
    return show


def write_plot(result, path, title):
    """
    Write the distance to S³ and the attitude error per step as a PNG.

    Parameters
    ----------
    result : dict
        As returned by :func:`run_demo`.
    path : str
    title : str

    """
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    import numpy as np

    steps = np.arange(len(result['distance']))
    figure, (top, bottom) = plt.subplots(2, 1, sharex=True, figsize=(7, 5.5))
    for axes, values, color in ((top, result['distance'], 'tab:blue'),
                                (bottom, result['attitude_error'], 'tab:red')):
        axes.plot(steps, values, color=color, alpha=0.35, linewidth=1, label='per step')
        width = min(10, len(values))
        if width > 1:
            smooth = np.convolve(values, np.ones(width) / width, mode='valid')
            axes.plot(steps[width - 1:], smooth, color=color, linewidth=2,
                      label=f'mean of the last {width} steps')
        axes.set_ylim(bottom=0.0)
        axes.grid(True, alpha=0.3)
    top.legend(loc='upper right', fontsize=8)
    top.set_ylabel('distance to S³  |‖q̂‖ − 1|')
    bottom.set_ylabel('attitude error (rad)')
    bottom.set_xlabel('step k')
    bottom.grid(True, alpha=0.3)
    top.set_title(title, fontsize=10)
    figure.tight_layout()
    directory = os.path.dirname(path)
    if directory:
        os.makedirs(directory, exist_ok=True)
    figure.savefig(path, dpi=100)
    plt.close(figure)


def main(argv=None):
    """
    Run the demo; return the exit code.

    Parameters
    ----------
    argv : list of str, optional
        Options (default ``sys.argv[1:]``); see ``--help``.

    Returns
    -------
    exit_code : int
        0 when the estimate converged (attitude error and distance at the end
        below their start values), 1 otherwise, 2 for invalid settings.

    """
    args = build_parser().parse_args(sys.argv[1:] if argv is None else argv)
    from ext_observer.nodes.node_common import ParameterError
    from rclpy.executors import ExternalShutdownException

    print(f'ext_observer demo: {args.variant} observer, {args.steps} steps at '
          f'{args.rate:g} Hz, increments up to {args.increment_max:g} rad per axis, '
          f'measurement noise {args.noise:g}, initial estimate '
          f'{tuple(args.initial_estimate)}', flush=True)
    try:
        result = run_demo(
            steps=args.steps, rate=args.rate, seed=args.seed, variant=args.variant,
            increment_max=args.increment_max, noise=args.noise,
            initial_estimate=args.initial_estimate,
            progress=None if args.quiet else _print_progress(args.steps))
    except (ParameterError, ValueError) as error:
        print(f'error: {error}', file=sys.stderr)
        return 2
    except (KeyboardInterrupt, ExternalShutdownException):
        print('interrupted', file=sys.stderr)
        return 130

    distance, error = result['distance'], result['attitude_error']
    if len(distance) < 2:
        print('error: no estimate was paired with the ground truth', file=sys.stderr)
        return 1
    tail = max(1, len(distance) // 5)
    start = (float(distance[0]), float(error[0]))
    end = (float(distance[-tail:].mean()), float(error[-tail:].mean()))
    print()
    print(f'Summary: {result["steps_done"]} steps in {result["elapsed_s"]:.1f} s, '
          f'{len(distance)} estimates paired with the ground truth')
    print(f'  {"":24s} {"start (k = 0)":>15s} {f"end (last {tail} steps)":>20s}')
    print(f'  {"distance to S³":24s} {start[0]:15.4f} {end[0]:20.4f}')
    print(f'  {"attitude error (rad)":24s} {start[1]:15.4f} {end[1]:20.4f}')
    if args.plot:
        write_plot(result, args.plot,
                   f'{args.variant} observer, increments ≤ {args.increment_max:g} rad, '
                   f'noise {args.noise:g}, seed {args.seed}')
        print(f'  plot: {args.plot}')
    converged = end[0] < start[0] and end[1] < start[1]
    print('  converged' if converged else '  did NOT converge')
    return 0 if converged else 1


if __name__ == '__main__':
    sys.exit(main())
