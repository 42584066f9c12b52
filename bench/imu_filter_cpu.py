"""
Node CPU per IMU sample of ``imu_filter_node``, beside a bare relay, against its speed goal.

``python -m bench.imu_filter_cpu [--executor events] [--rate 1000] [--mag-rate 100]
[--seconds 10] [--rounds 3] [--json PATH]`` publishes ``sensor_msgs/Imu`` on
``imu/data_raw`` at ``--rate`` and ``sensor_msgs/MagneticField`` on
``imu/mag`` at ``--mag-rate`` (both best effort, as IMU drivers publish)
into each target in turn, and reads the target's CPU time (psutil)
over the publishing window, in ``--rounds`` interleaved runs of each:

- ``relay``: this module's :class:`ImuRelay`, the raw-IMU message path
  without the maths (per sample the node's two outputs, ``imu/data`` and
  ``attitude_estimate``, each, as the node does, only while it has a
  subscriber; the latest field kept), with the node's QoS
  (inputs best effort, outputs reliable, depth 100);
- ``imu_filter``: the shipped ``imu_filter_node`` (the console script next
  to this interpreter, else ``python -m ext_observer.nodes.imu_filter_node``) with
  its defaults (``use_mag`` true);

All spin on the same executor (``--executor``, default ``events``, the
node's default). The samples are the BROAD excerpt the tests replay
(``test/data``), looped. It prints one table, CPU µs per IMU sample (median
and every run), outputs received (the fewest of any run), and the ratio of
the medians against the goal, ``met`` or ``not met``: within
:data:`NODE_GOAL` × the relay's.

``python -m bench.imu_filter_cpu relay --executor events`` runs the relay alone
(SIGINT ends it). The ``step_only`` floor (``--floor``: the node cut down to the
estimate's arithmetic) answered what the node's own checks cost
(docs/compiled.md) and left; its code is this file at commit 7319e4b.
"""

import argparse
import glob
import os
import statistics
import sys
import threading
import time

import numpy as np

from bench.machine import load, load_range, log, save_json
from bench.procs import Child, cpu_seconds, installed_node, REPO, reserved_domain_id, ros_env
from bench.rosutil import (EXECUTORS, make_executor, on_compiled_kernels, spin_until_shutdown,
                           watch_kernels)

DATA = os.path.join(REPO, 'test', 'data')
# The raw-IMU node's speed goal: CPU per IMU sample (1 kHz IMU, 100 Hz field) within this
# factor of the bare relay's.
NODE_GOAL = 1.2
TARGETS = ('relay', 'imu_filter')
# With --serialized: the relay on bytes (RawImuRelay) and the node
# with serialized_io false, beside the two above.
RAW_RELAY, TYPED = 'raw_relay', 'imu_filter_typed'
# Below this share of the samples coming back as outputs, a target (or the
# driver) fell behind: a target that dropped samples did less work per
# sample published, and the ratio is no longer a clean measure.
COMPLETE = 0.99
# The relay's history depth: imu_filter_node's queue_depth default.
RELAY_DEPTH = 100


def verdict(ok):
    """The word every goal of the benchmark is judged with."""
    return 'met' if ok else 'not met'


class ImuRelay:
    """
    The raw-IMU message path without the maths.

    Parameters
    ----------
    context : rclpy.context.Context
    raw : bool
        Take the inputs as CDR bytes (:class:`RawImuRelay`).

    """

    def __init__(self, context, raw=False):
        from geometry_msgs.msg import QuaternionStamped
        from rclpy.event_handler import PublisherEventCallbacks
        from rclpy.node import Node
        from rclpy.qos import QoSProfile, ReliabilityPolicy
        from sensor_msgs.msg import Imu, MagneticField
        self.node = Node('imu_relay', context=context)
        self.field = None
        # The node's QoS at its defaults (queue_depth 100): reliable outputs,
        # best-effort inputs, so that neither side drops what the other takes.
        out = QoSProfile(depth=RELAY_DEPTH)
        # Each output published only while it has a subscriber, as the node
        # does (the benchmark reads imu/data only): the same work on each side.
        self.readers = {}
        self.publisher = self._publisher(Imu, 'imu/data', out, PublisherEventCallbacks)
        self.estimate_publisher = self._publisher(
            QuaternionStamped, 'attitude_estimate', out, PublisherEventCallbacks)
        self._estimate = QuaternionStamped()
        self._estimate.quaternion.w = 1.0
        inputs = QoSProfile(depth=RELAY_DEPTH, reliability=ReliabilityPolicy.BEST_EFFORT)
        self.node.create_subscription(Imu, 'imu/data_raw', self.imu_data_raw_callback, inputs,
                                      raw=raw)
        self.node.create_subscription(MagneticField, 'imu/mag', self.imu_mag_callback, inputs,
                                      raw=raw)
        self._out = Imu()
        self._out.orientation.w = 1.0

    def _publisher(self, kind, topic, qos, callbacks):
        """A publisher whose matched event keeps ``readers[topic]``: has it a subscriber now."""
        def matched(info):
            self.readers[topic] = info.current_count > 0
        return self.node.create_publisher(kind, topic, qos,
                                          event_callbacks=callbacks(matched=matched))

    def imu_mag_callback(self, msg):
        """Keep the latest field, as the estimator does."""
        field = msg.magnetic_field
        self.field = (field.x, field.y, field.z)

    def imu_data_raw_callback(self, msg):
        """Publish one output per sample with the input's rates passed through."""
        out = self._out
        out.header = msg.header
        out.angular_velocity = msg.angular_velocity
        out.linear_acceleration = msg.linear_acceleration
        readers = self.readers
        if readers.get('imu/data'):
            self.publisher.publish(out)
        if readers.get('attitude_estimate'):
            self._estimate.header.stamp = msg.header.stamp
            self.estimate_publisher.publish(self._estimate)


class RawImuRelay(ImuRelay):
    """
    The relay on bytes: what a serialized node cannot do with less.

    The inputs taken as CDR bytes; per sample the sample's bytes published as
    they came on ``imu/data``, and an ``attitude_estimate`` of fixed bytes
    with the sample's stamp: no message object on either side.
    """

    def __init__(self, context):
        from rclpy.serialization import serialize_message
        super().__init__(context, raw=True)
        template = serialize_message(self._estimate)
        self._head, self._tail = template[:4], template[12:]

    def imu_mag_callback(self, raw):
        """Keep the latest field's bytes."""
        self.field = raw

    def imu_data_raw_callback(self, raw):
        """Publish the sample's bytes and an estimate with its stamp."""
        readers = self.readers
        if readers.get('imu/data'):
            self.publisher.publish(raw)
        if readers.get('attitude_estimate'):
            self.estimate_publisher.publish(self._head + raw[4:12] + self._tail)


def _relay_main(argv):
    parser = argparse.ArgumentParser(prog='python -m bench.imu_filter_cpu relay')
    parser.add_argument('--executor', choices=EXECUTORS, default='events')
    parser.add_argument('--raw', action='store_true', help='RawImuRelay: on bytes')
    args = parser.parse_args(argv)
    import rclpy
    context = rclpy.Context()
    rclpy.init(context=context)
    relay = RawImuRelay(context) if args.raw else ImuRelay(context)
    executor = make_executor(args.executor, context)
    executor.add_node(relay.node)
    print('ready', flush=True)
    spin_until_shutdown(executor, context)
    relay.node.destroy_node()
    rclpy.try_shutdown(context=context)
    return 0


def target_args(label, executor):
    """The command line of a target (``relay`` or ``imu_filter``) on ``executor``."""
    if label == 'relay':
        return ['-m', 'bench.imu_filter_cpu', 'relay', '--executor', executor]
    if label == RAW_RELAY:
        return ['-m', 'bench.imu_filter_cpu', 'relay', '--executor', executor, '--raw']
    command = installed_node('imu_filter_node') + [
        '--executor', executor, '--ros-args', '-p', 'use_mag:=true']
    return command + (['-p', 'serialized_io:=false'] if label == TYPED else [])


def load_samples():
    """IMU samples (gyr rad/s, acc m/s², mag T) of the tests' BROAD excerpts."""
    gyr, acc, mag = [], [], []
    for path in sorted(glob.glob(os.path.join(DATA, '*.npz'))):
        with np.load(path) as data:
            gyr.append(data['gyr'])
            acc.append(data['acc'])
            mag.append(data['mag'] * 1e-6)  # µT → T
    if not gyr:
        raise SystemExit(f'no excerpt under {DATA}')
    return np.concatenate(gyr), np.concatenate(acc), np.concatenate(mag)


def measure(target, domain_id, samples, rate, mag_rate, seconds, log_path, settle=False):
    """
    Publish into one target and return its CPU and output figures.

    With ``settle``, the window starts once the target's ``/diagnostics``
    says its kernels are no longer ``plain (...)``: a node that starts on the
    plain kernels is measured as it runs for good.

    Returns
    -------
    dict
        ``cpu_us_per_sample``, ``samples``, ``fields``, ``outputs``,
        ``achieved_rate_hz``, ``load`` (the 1-minute load average before and
        after).

    """
    import rclpy
    from rclpy.qos import qos_profile_sensor_data
    from sensor_msgs.msg import Imu, MagneticField
    env = ros_env(domain_id)
    child = Child('target', target, env, log_path)
    os.environ['ROS_DOMAIN_ID'] = str(domain_id)
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=domain_id)
    try:
        node = rclpy.create_node('raw_imu_driver', context=context)
        imu_pub = node.create_publisher(Imu, 'imu/data_raw', qos_profile_sensor_data)
        mag_pub = node.create_publisher(MagneticField, 'imu/mag', qos_profile_sensor_data)
        outputs = [0]
        node.create_subscription(Imu, 'imu/data', lambda msg: outputs.__setitem__(
            0, outputs[0] + 1), 100)
        # The node starts on the plain kernels and goes on with the compiled
        # ones once loaded (compiled first where the cache is cold): measured
        # from then on, as it runs for good.
        kernels = []
        watch_kernels(node, kernels)
        executor = make_executor('single', context)
        executor.add_node(node)
        stop = threading.Event()
        spinner = threading.Thread(target=spin_until_shutdown,
                                   args=(executor, context, stop), daemon=True)
        spinner.start()
        deadline = time.monotonic() + 20.0
        while (imu_pub.get_subscription_count() == 0
               or node.count_publishers('imu/data') == 0):
            if time.monotonic() > deadline or child.proc.poll() is not None:
                raise RuntimeError(f'target did not come up: {child.log_tail()}')
            time.sleep(0.05)
        if settle:
            deadline = time.monotonic() + 300.0
            while not on_compiled_kernels(kernels):
                if time.monotonic() > deadline or child.proc.poll() is not None:
                    raise RuntimeError(f'the kernels did not settle: {child.log_tail()}')
                time.sleep(0.05)
        time.sleep(1.0)
        gyr, acc, mag = samples
        every = max(1, round(rate / mag_rate))
        imu, field = Imu(), MagneticField()
        imu.header.frame_id = field.header.frame_id = 'imu_link'
        period = 1.0 / rate
        count = int(seconds * rate)
        load_before, start_cpu = load(), cpu_seconds(child.proc.pid)
        start = time.monotonic()
        stamp0 = time.time_ns()
        fields = 0
        for k in range(count):
            i = k % len(gyr)
            ns = stamp0 + round(k * period * 1e9)
            imu.header.stamp.sec, imu.header.stamp.nanosec = divmod(ns, 1_000_000_000)
            v = imu.angular_velocity
            v.x, v.y, v.z = float(gyr[i, 0]), float(gyr[i, 1]), float(gyr[i, 2])
            a = imu.linear_acceleration
            a.x, a.y, a.z = float(acc[i, 0]), float(acc[i, 1]), float(acc[i, 2])
            imu_pub.publish(imu)
            if k % every == 0:
                field.header.stamp = imu.header.stamp
                m = field.magnetic_field
                m.x, m.y, m.z = float(mag[i, 0]), float(mag[i, 1]), float(mag[i, 2])
                mag_pub.publish(field)
                fields += 1
            wait = start + (k + 1) * period - time.monotonic()
            if wait > 0:
                time.sleep(wait)
        elapsed = time.monotonic() - start
        time.sleep(0.5)
        cpu = cpu_seconds(child.proc.pid) - start_cpu
        stop.set()
        spinner.join(timeout=2.0)
        return dict(cpu_us_per_sample=cpu / count * 1e6, samples=count, fields=fields,
                    outputs=outputs[0], achieved_rate_hz=count / elapsed,
                    load=(load_before, load()))
    finally:
        child.stop()
        rclpy.try_shutdown(context=context)


def summarize(runs, goal=NODE_GOAL):
    """
    The medians, their ratio and the verdict, from the runs of each target.

    Parameters
    ----------
    runs : dict
        ``{'relay': [run, ...], 'imu_filter': [run, ...]}``, the runs of
        :func:`measure` in round order (round ``k`` of each ran one after the
        other).
    goal : float
        Most ``imu_filter`` / ``relay`` allowed.

    Returns
    -------
    dict
        ``medians`` (µs per sample), ``ratio`` (of the medians; None
        without both), ``round_ratios`` (round by round), ``goal``, ``met``,
        and ``short``: the fewest outputs received of each target that, in
        some run, got fewer than :data:`COMPLETE` of the samples back.

    """
    cpu = {label: [r['cpu_us_per_sample'] for r in rows] for label, rows in runs.items()}
    medians = {label: statistics.median(values) for label, values in cpu.items() if values}
    ratio = (medians['imu_filter'] / medians['relay']
             if 'imu_filter' in medians and medians.get('relay') else None)
    round_ratios = [f / r for f, r in zip(cpu.get('imu_filter', []), cpu.get('relay', []))]
    return {'medians': medians, 'ratio': ratio, 'round_ratios': round_ratios,
            'goal': goal, 'met': ratio is not None and ratio <= goal,
            'short': short_outputs(runs)}


def goal_line(result):
    """The sentence that states the goal and whether it is met."""
    s = result
    if s['ratio'] is None:
        return f'goal (raw-IMU node): imu_filter ≤ {s["goal"]:g}× the relay: not measured'
    spread = ''
    if s['round_ratios']:
        low, high = min(s['round_ratios']), max(s['round_ratios'])
        spread = f', rounds {low:.2f}–{high:.2f}'
        if low <= s['goal'] < high:
            spread += ' (on both sides of the goal)'
    runs = [run for rows in s['runs'].values() for run in rows]
    text = (f'goal (raw-IMU node): imu_filter ≤ {s["goal"]:g}× the relay\'s CPU per IMU sample '
            f'({s["executor"]}): {s["ratio"]:.2f}× (medians of {s["rounds"]}{spread}; load '
            f'average {load_range(runs)} on {os.cpu_count()} cores): {verdict(s["met"])}')
    if short_text(s):
        text += f' ({short_text(s)})'
    return text


# CPU per IMU sample of the node on bytes against the typed relay's, same run:
# at most SERIALIZED_GOAL, SERIALIZED_AIM the aim.
SERIALIZED_GOAL, SERIALIZED_AIM = 0.6, 0.4


def ratios_lines(result):
    """Each target's CPU per sample against the typed relay's: medians and round by round."""
    cpu = {label: [r['cpu_us_per_sample'] for r in rows]
           for label, rows in result['runs'].items()}
    relay = cpu.get('relay')
    if not relay:
        return []
    lines = []
    for label, values in cpu.items():
        if label == 'relay' or not values:
            continue
        rounds = [v / r for v, r in zip(values, relay)]
        lines.append(f'{label} / relay: {statistics.median(values) / statistics.median(relay):.2f}'
                     f'× (medians; rounds {", ".join(f"{x:.2f}" for x in rounds)})')
    if RAW_RELAY in cpu:
        ratio = statistics.median(cpu['imu_filter']) / statistics.median(relay)
        lines.append(f'goal: imu_filter (serialized_io) ≤ {SERIALIZED_GOAL:g}× the typed '
                     f'relay: {ratio:.2f}×: {verdict(ratio <= SERIALIZED_GOAL)}')
    return lines


def short_outputs(runs):
    """The fewest outputs of each target that got fewer than :data:`COMPLETE` back in a run."""
    return {label: min(r['outputs'] for r in rows) for label, rows in runs.items()
            if rows and any(r['outputs'] < COMPLETE * r['samples'] for r in rows)}


def short_text(result):
    """Which targets got fewer outputs back than samples sent, or ''."""
    short = short_outputs(result['runs'])
    if not short:
        return ''
    samples = max(r['samples'] for rows in result['runs'].values() for r in rows)
    return ('outputs short of the samples, fewest: '
            + ', '.join(f'{label} {count} of {samples}' for label, count in short.items())
            + '; a target that dropped samples did less work per sample')


def compare(executor='events', rate=1000.0, mag_rate=100.0, seconds=10.0, rounds=3,
            log_dir=None, progress=None, serialized=False):
    """
    Run the relay and the node in interleaved rounds; return the runs and the verdict.

    Returns
    -------
    dict
        The settings, ``runs`` (per target), and :func:`summarize`'s keys.

    """
    log_dir = log_dir or os.path.join(REPO, 'out', 'bench')
    os.makedirs(log_dir, exist_ok=True)
    samples = load_samples()
    # One run of one target varies by about ±10 % (the machine's other
    # work); interleaved rounds and medians keep the ratio steady.
    targets = (TARGETS[0], RAW_RELAY, TYPED, TARGETS[1]) if serialized else TARGETS
    runs = {label: [] for label in targets}
    for round_ in range(rounds):
        for index, label in enumerate(targets):
            if progress:
                progress(f'round {round_ + 1}/{rounds}, {label} ({executor}): {rate:g} Hz '
                         f'IMU, {mag_rate:g} Hz field, {seconds:g} s ...')
            with reserved_domain_id(index) as domain_id:
                runs[label].append(measure(
                    target_args(label, executor), domain_id, samples, rate, mag_rate,
                    seconds, os.path.join(log_dir, f'raw_imu_{label}_{executor}.log'),
                    settle=label not in ('relay', RAW_RELAY)))
    result = {'executor': executor, 'rate': rate, 'mag_rate': mag_rate, 'seconds': seconds,
              'rounds': rounds, 'runs': runs}
    result.update(summarize(runs))
    return result


def table(result):
    """The printed table of one :func:`compare`."""
    from docgen.markdown import table as markdown_table
    rows = []
    for label, runs in result['runs'].items():
        cpu = ', '.join(f'{r["cpu_us_per_sample"]:.0f}' for r in runs)
        rows.append([label, f'{result["medians"][label]:.1f} ({cpu})', runs[-1]['samples'],
                     runs[-1]['fields'], min(r['outputs'] for r in runs),
                     f'{min(r["achieved_rate_hz"] for r in runs):.0f}'])
    return markdown_table([f'target ({result["executor"]})',
                           'CPU µs per IMU sample, median (runs)', 'samples', 'fields',
                           'outputs received', 'achieved rate (Hz)'], rows)


def main(argv=None):
    """Compare the node with the relay; print the table and the verdict; return 0."""
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ['relay']:
        return _relay_main(argv[1:])
    parser = argparse.ArgumentParser(prog='python -m bench.imu_filter_cpu')
    parser.add_argument('--rate', type=float, default=1000.0, help='IMU rate, Hz')
    parser.add_argument('--mag-rate', type=float, default=100.0, help='field rate, Hz')
    parser.add_argument('--seconds', type=float, default=10.0, help='per run')
    parser.add_argument('--rounds', type=int, default=3,
                        help='runs of each target, interleaved (relay, imu_filter, relay, ...)')
    parser.add_argument('--executor', choices=EXECUTORS, default='events')
    parser.add_argument('--serialized', action='store_true',
                        help=f'also {RAW_RELAY} (the relay on bytes) and {TYPED} (the node '
                             'with serialized_io false)')
    parser.add_argument('--log-dir', default=os.path.join(REPO, 'out', 'bench'))
    parser.add_argument('--json', metavar='PATH', help='also write the results there')
    args = parser.parse_args(argv)
    if args.rounds < 1:
        parser.error('--rounds must be at least 1')
    result = compare(args.executor, args.rate, args.mag_rate, args.seconds, args.rounds,
                     args.log_dir, log, serialized=args.serialized)
    print(table(result))
    print()
    print(goal_line(result))
    for line in ratios_lines(result):
        print(line)
    save_json(args.json, result)
    return 0


if __name__ == '__main__':
    sys.exit(main())
