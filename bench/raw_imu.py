"""
Node CPU per IMU sample of the raw-IMU estimator, beside a bare relay.

``python -m bench.raw_imu [--rate 1000] [--mag-rate 100] [--seconds 10]
[--rounds 3]`` publishes ``sensor_msgs/Imu`` on ``imu/data_raw`` at ``--rate`` and
``sensor_msgs/MagneticField`` on ``imu/mag`` at ``--mag-rate`` (both best
effort, as IMU drivers publish) into each target in turn, and reads the
target's CPU time from ``/proc`` over the publishing window, in
``--rounds`` interleaved runs of each:

- ``relay``: this module's :class:`ImuRelay`, the raw-IMU message path
  without the maths (per sample the node's two outputs, ``imu/data`` and
  ``attitude_estimate``; the latest field kept);
- ``observer``: the shipped ``observer_node`` with
  ``measurement_source:=accel`` (``use_mag`` true).

Both spin on the same executor (``--executor``, default ``events``, the
node's default). The samples are the BROAD excerpt the tests replay
(``test/data``), looped. It prints one table: CPU µs per IMU sample
(median and every run), outputs received (the fewest of any run), and the
ratio of the medians. Figures, never pass/fail.

``python -m bench.raw_imu relay --executor events`` runs the relay alone
(SIGINT ends it).
"""

import argparse
import glob
import os
import statistics
import sys
import threading
import time

import numpy as np

from bench.procs import Child, REPO, reserved_domain_id, ros_env
from bench.rosutil import EXECUTORS, make_executor, spin_until_shutdown

DATA = os.path.join(REPO, 'test', 'data')


class ImuRelay:
    """
    The raw-IMU message path without the maths.

    Parameters
    ----------
    context : rclpy.context.Context

    """

    def __init__(self, context):
        from geometry_msgs.msg import QuaternionStamped
        from rclpy.node import Node
        from rclpy.qos import qos_profile_sensor_data
        from sensor_msgs.msg import Imu, MagneticField
        self.node = Node('imu_relay', context=context)
        self.field = None
        self.publisher = self.node.create_publisher(Imu, 'imu/data', 10)
        self.estimate_publisher = self.node.create_publisher(
            QuaternionStamped, 'attitude_estimate', 10)
        self._estimate = QuaternionStamped()
        self._estimate.quaternion.w = 1.0
        self.node.create_subscription(Imu, 'imu/data_raw', self.imu_data_raw_callback,
                                      qos_profile_sensor_data)
        self.node.create_subscription(MagneticField, 'imu/mag', self.imu_mag_callback,
                                      qos_profile_sensor_data)
        self._out = Imu()
        self._out.orientation.w = 1.0

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
        self.publisher.publish(out)
        self._estimate.header.stamp = msg.header.stamp
        self.estimate_publisher.publish(self._estimate)


def _relay_main(argv):
    parser = argparse.ArgumentParser(prog='python -m bench.raw_imu relay')
    parser.add_argument('--executor', choices=EXECUTORS, default='events')
    args = parser.parse_args(argv)
    import rclpy
    context = rclpy.Context()
    rclpy.init(context=context)
    relay = ImuRelay(context)
    executor = make_executor(args.executor, context)
    executor.add_node(relay.node)
    print('ready', flush=True)
    spin_until_shutdown(executor, context)
    relay.node.destroy_node()
    rclpy.try_shutdown(context=context)
    return 0


def _cpu_seconds(pid):
    with open(f'/proc/{pid}/stat') as f:
        fields = f.read().rsplit(')', 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')


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


def measure(target_args, domain_id, samples, rate, mag_rate, seconds, log_path):
    """
    Publish into one target and return its CPU and output figures.

    Returns
    -------
    dict
        ``cpu_us_per_sample``, ``samples``, ``fields``, ``outputs``,
        ``achieved_rate_hz``.

    """
    import rclpy
    from rclpy.qos import qos_profile_sensor_data
    from sensor_msgs.msg import Imu, MagneticField
    env = ros_env(domain_id)
    child = Child('target', target_args, env, log_path)
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
        time.sleep(1.0)
        gyr, acc, mag = samples
        every = max(1, round(rate / mag_rate))
        imu, field = Imu(), MagneticField()
        imu.header.frame_id = field.header.frame_id = 'imu_link'
        period = 1.0 / rate
        count = int(seconds * rate)
        start_cpu = _cpu_seconds(child.proc.pid)
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
        cpu = _cpu_seconds(child.proc.pid) - start_cpu
        stop.set()
        spinner.join(timeout=2.0)
        return dict(cpu_us_per_sample=cpu / count * 1e6, samples=count, fields=fields,
                    outputs=outputs[0], achieved_rate_hz=count / elapsed)
    finally:
        child.stop()
        rclpy.try_shutdown(context=context)


def main(argv=None):
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ['relay']:
        return _relay_main(argv[1:])
    parser = argparse.ArgumentParser(prog='python -m bench.raw_imu')
    parser.add_argument('--rate', type=float, default=1000.0, help='IMU rate, Hz')
    parser.add_argument('--mag-rate', type=float, default=100.0, help='field rate, Hz')
    parser.add_argument('--seconds', type=float, default=10.0, help='per run')
    parser.add_argument('--rounds', type=int, default=3,
                        help='runs of each target, interleaved (relay, observer, relay, ...)')
    parser.add_argument('--executor', choices=EXECUTORS, default='events')
    parser.add_argument('--log-dir', default=os.path.join(REPO, 'out', 'bench'))
    args = parser.parse_args(argv)
    if args.rounds < 1:
        parser.error('--rounds must be at least 1')
    os.makedirs(args.log_dir, exist_ok=True)
    samples = load_samples()
    targets = [
        ('relay', ['-m', 'bench.raw_imu', 'relay', '--executor', args.executor]),
        ('observer', ['-m', 'ext_observer.observer_node', '--executor', args.executor,
                      '--ros-args', '-p', 'measurement_source:=accel',
                      '-p', 'use_mag:=true']),
    ]
    # One run of one target varies by about ±10 % (the machine's other
    # work); interleaved rounds and medians keep the ratio steady.
    runs = {label: [] for label, _ in targets}
    for round_ in range(args.rounds):
        for index, (label, target) in enumerate(targets):
            print(f'round {round_ + 1}/{args.rounds}, {label}: {args.rate:g} Hz IMU, '
                  f'{args.mag_rate:g} Hz field, {args.seconds:g} s ...', file=sys.stderr,
                  flush=True)
            with reserved_domain_id(index) as domain_id:
                runs[label].append(measure(
                    target, domain_id, samples, args.rate, args.mag_rate, args.seconds,
                    os.path.join(args.log_dir, f'raw_imu_{label}.log')))
    print(f'| target ({args.executor}) | CPU µs per IMU sample, median (runs) | samples | '
          'fields | outputs received | achieved rate (Hz) |')
    print('|---|---|---|---|---|---|')
    medians = {}
    for label, rows in runs.items():
        cpu = [r['cpu_us_per_sample'] for r in rows]
        medians[label] = statistics.median(cpu)
        last = rows[-1]
        print(f'| {label} | {medians[label]:.1f} ({", ".join(f"{c:.0f}" for c in cpu)}) | '
              f'{last["samples"]} | {last["fields"]} | {min(r["outputs"] for r in rows)} | '
              f'{min(r["achieved_rate_hz"] for r in rows):.0f} |')
    print(f'\nobserver / relay CPU per sample (medians of {args.rounds} runs): '
          f'{medians["observer"] / medians["relay"]:.2f}×')
    return 0


if __name__ == '__main__':
    sys.exit(main())
