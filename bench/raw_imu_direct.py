"""
Where ``imu_filter_node``'s time per IMU sample goes, its callbacks called directly.

``python -m bench.raw_imu_direct [--samples 5000] [--json PATH]`` builds the
node (``ImuFilterNode``, its defaults) and :class:`bench.imu_filter_cpu.ImuRelay`
in one process and calls their callbacks with prepared messages: the BROAD
excerpt of the tests at 1 kHz, a field every tenth sample (no executor, no
DDS receive, warm caches). Publishing is replaced by a no-op in both, and
both publish as if each output had a subscriber, so both build their two
outputs per sample and send none: what is timed is each node's own Python
work. Beside them, each part timed alone: the node's ROS-free pipeline
(:class:`~ext_observer.pipeline.raw_imu.RawImuPipeline`: input checks, stamps, the
estimator), the core's float step
(:class:`~ext_observer.core.ahrs.ahrs_observer.AhrsObserver`), one real ``publish`` of
each output with no subscriber; the functions on the callbacks' path
that use numpy (:mod:`bench.numpy_use`); and the functions with the most own
time in the callbacks on bytes under cProfile. Each figure is the best of a
few passes (:mod:`bench.timing`), µs per IMU sample. Run in a child process
by ``python -m bench``.
"""

import argparse
import cProfile
import sys
import time

from bench.imu_filter_cpu import ImuRelay, load_samples, RawImuRelay
from bench.machine import save_json
from bench.numpy_use import numpy_use_per_step
from bench.rosutil import set_stamp
from bench.timing import best_pass, best_seconds, top_functions
from docgen.markdown import table

SAMPLES = 5000
RATE = 1000  # Hz
# The node starts on the plain kernels and goes on with the compiled ones once
# its background compile has them (31 s cold here): what it runs is timed after.
COMPILE_WAIT = 300  # s
MAG_EVERY = 10  # one field per this many IMU samples (100 Hz)
PASSES = 8  # the first warms up; the best of the others (shared cores)


class _NoPublish:
    """Stands in for ``Publisher.publish``: counts, sends nothing."""

    def __init__(self):
        self.count = 0

    def __call__(self, msg):
        self.count += 1


def _inputs(samples, start, count):
    """``count`` IMU samples from ``start`` (ns) on: (stamp, gyr, acc, field or None)."""
    gyr, acc, mag = samples
    out = []
    for k in range(count):
        i = k % len(gyr)
        out.append((start + k * (1_000_000_000 // RATE), tuple(map(float, gyr[i])),
                    tuple(map(float, acc[i])),
                    tuple(map(float, mag[i])) if k % MAG_EVERY == 0 else None))
    return out


def _messages(inputs):
    """The inputs as (Imu, MagneticField or None) messages."""
    from sensor_msgs.msg import Imu, MagneticField
    out = []
    for stamp, gyr, acc, field in inputs:
        imu = Imu()
        imu.header.frame_id = 'imu_link'
        set_stamp(imu.header.stamp, stamp)
        v, a = imu.angular_velocity, imu.linear_acceleration
        v.x, v.y, v.z = gyr
        a.x, a.y, a.z = acc
        mag = None
        if field is not None:
            mag = MagneticField()
            mag.header = imu.header
            m = mag.magnetic_field
            m.x, m.y, m.z = field
        out.append((imu, mag))
    return out


def _serialized(messages):
    """The messages as CDR bytes, as a subscription with ``raw=True`` hands them."""
    from rclpy.serialization import serialize_message
    return [(serialize_message(imu), None if mag is None else serialize_message(mag))
            for imu, mag in messages]


def _compiled(node):
    """Run the node's compile timer until it goes on with the compiled kernels (or gives up)."""
    deadline = time.monotonic() + COMPILE_WAIT
    while node.compiler is not None and time.monotonic() < deadline:
        node.compile_timer_callback()
        time.sleep(0.1)
    return node.compiler is None


def _feed(imu_callback, mag_callback, messages):
    start = time.perf_counter()
    for imu, mag in messages:
        if mag is not None:
            mag_callback(mag)
        imu_callback(imu)
    return (time.perf_counter() - start) / len(messages) * 1e6


def _feed_pipeline(pipeline, inputs):
    start = time.perf_counter()
    for stamp, gyr, acc, field in inputs:
        if field is not None:
            pipeline.field(stamp, field)
        pipeline.imu(stamp, gyr, acc)
    return (time.perf_counter() - start) / len(inputs) * 1e6


def _feed_core(core, inputs):
    dt, mag_dt = 1.0 / RATE, MAG_EVERY / RATE
    start = time.perf_counter()
    for _, gyr, acc, field in inputs:
        if field is not None and core.q is not None:
            core.update_mag(field, mag_dt)
        core.update(gyr, acc, None, dt)
    return (time.perf_counter() - start) / len(inputs) * 1e6


class _Timeline:
    """Passes of inputs on one continuous time line (a jump back resets the node)."""

    def __init__(self, samples, count):
        self.samples, self.count = samples, count
        self.next = time.time_ns()

    def inputs(self):
        out = _inputs(self.samples, self.next, self.count)
        self.next += self.count * (1_000_000_000 // RATE)
        return out


def direct(count=SAMPLES):
    """
    Time the node's and the relay's callbacks and the parts of the node's work.

    Returns
    -------
    dict
        µs per IMU sample: ``imu_filter_callbacks``, ``relay_callbacks``
        (typed messages), ``imu_filter_serialized_callbacks``,
        ``raw_relay_callbacks`` (CDR bytes), ``pipeline``, ``core``; µs per
        call: ``publish_imu``,
        ``publish_estimate``; ``outputs_per_sample`` of each node (2 when
        both outputs were built); ``numpy_use_per_sample``
        (:func:`bench.numpy_use.numpy_use_per_step`); ``top``, the functions
        with the most own time per sample in the callbacks on bytes under
        cProfile; ``samples``; ``compiled`` (the node went on with the
        compiled kernels before the timing).

    """
    import rclpy
    from rclpy.context import Context

    from ext_observer.core.ahrs.ahrs_observer import AhrsObserver
    from ext_observer.nodes.imu_filter_node import ImuFilterNode
    from ext_observer.pipeline.raw_imu import RawImuPipeline
    samples = load_samples()
    context = Context()
    rclpy.init(context=context)
    try:
        node = ImuFilterNode(context=context)
        relay, raw_relay = ImuRelay(context), RawImuRelay(context)
        real_imu, real_estimate = node.imu_publisher.publish, node.estimate_publisher.publish
        silent = {}
        for name, publisher in (('imu_filter', node.imu_publisher),
                                ('imu_filter', node.estimate_publisher),
                                ('relay', relay.publisher), ('relay', relay.estimate_publisher),
                                ('raw_relay', raw_relay.publisher),
                                ('raw_relay', raw_relay.estimate_publisher)):
            publisher.publish = silent.setdefault(name, _NoPublish())
        silent['imu_filter_serialized'] = silent['imu_filter']
        # As with a subscriber on each output: all build their two outputs.
        node._publish_imu = node._publish_estimate = True
        for r in (relay, raw_relay):
            r.readers.update({'imu/data': True, 'attitude_estimate': True})
        result = {'samples': count, 'compiled': _compiled(node)}
        # One time line per consumer: the node must see no gap between passes.
        lines = {label: _Timeline(samples, count) for label in (
            'imu_filter', 'relay', 'raw_relay', 'parts')}
        # The node's two paths go on from each other's last sample.
        lines['imu_filter_serialized'] = lines['imu_filter']
        for label, imu_callback, mag_callback, bytes_in in (
                ('imu_filter', node.imu_data_raw_callback, node.imu_mag_callback, False),
                ('imu_filter_serialized', node.imu_data_raw_serialized_callback,
                 node.imu_mag_serialized_callback, True),
                ('relay', relay.imu_data_raw_callback, relay.imu_mag_callback, False),
                ('raw_relay', raw_relay.imu_data_raw_callback, raw_relay.imu_mag_callback,
                 True)):
            before = silent[label].count
            convert = _serialized if bytes_in else list
            result[f'{label}_callbacks'] = best_pass(lambda: _feed(
                imu_callback, mag_callback, convert(_messages(lines[label].inputs()))), PASSES)
            result.setdefault('outputs_per_sample', {})[label] = (
                (silent[label].count - before) / (PASSES * count))
        profile = cProfile.Profile()
        profile.runcall(_feed, node.imu_data_raw_serialized_callback,
                        node.imu_mag_serialized_callback,
                        _serialized(_messages(lines['imu_filter'].inputs())))
        result['top'] = top_functions(profile, count, skip=('_feed', '<listcomp>'))
        result['numpy_use_per_sample'] = numpy_use_per_step(
            count, _feed, node.imu_data_raw_callback, node.imu_mag_callback,
            _messages(lines['imu_filter'].inputs()))
        settings = node.parameters.settings
        pipeline = RawImuPipeline(settings, depth=settings['queue_depth'])
        result['pipeline'] = best_pass(
            lambda: _feed_pipeline(pipeline, lines['parts'].inputs()), PASSES)
        core = AhrsObserver(node.observer.params, use_mag=True)
        result['core'] = best_pass(lambda: _feed_core(core, lines['parts'].inputs()), PASSES)
        imu, _ = _messages(lines['parts'].inputs()[:1])[0]
        estimate = node._estimate_msg
        result['publish_imu'] = 1e6 * best_seconds(lambda: real_imu(imu), count, PASSES)
        result['publish_estimate'] = 1e6 * best_seconds(lambda: real_estimate(estimate), count,
                                                        PASSES)
        node.destroy_node()
        relay.node.destroy_node()
        raw_relay.node.destroy_node()
    finally:
        rclpy.try_shutdown(context=context)
    return result


def main(argv=None):
    """Print the figures (and write them with ``--json``); return 0."""
    parser = argparse.ArgumentParser(prog='python -m bench.raw_imu_direct')
    parser.add_argument('--samples', type=int, default=SAMPLES, help='IMU samples per pass')
    parser.add_argument('--json', metavar='PATH', help='also write the results there')
    args = parser.parse_args(argv)
    result = direct(args.samples)
    print(f'compiled kernels: {result["compiled"]}')
    for key in ('imu_filter_callbacks', 'relay_callbacks', 'imu_filter_serialized_callbacks',
                'raw_relay_callbacks', 'pipeline', 'core', 'publish_imu', 'publish_estimate'):
        print(f'{key}: {result[key]:.1f} µs')
    print(f'numpy on the callbacks\' path: {result["numpy_use_per_sample"] or "none"}')
    print('own time under cProfile, callbacks on bytes:')
    print(table(['function', 'own µs per sample', 'calls per sample'],
                [[f'`{row["function"]}`', f'{row["own_us"]:.2f}', f'{row["calls"]:.2f}']
                 for row in result['top']]))
    save_json(args.json, result)
    return 0


if __name__ == '__main__':
    sys.exit(main())
