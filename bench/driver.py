"""
A paced driver: paired increments and measurements at a given rate.

Publishes, for step k, ``gyro/increment`` (geometry_msgs/Vector3Stamped)
then ``attitude/measurement`` (geometry_msgs/QuaternionStamped) with the
same stamp ``t_k``: nominal, on the driver's own clock like an IMU's,
``1 / rate`` apart and continuing across runs (the first step of a run is
one new period after the last step of the previous run), so a node that
stamps its estimate ``t_k + (t_k − t_{k−1})`` stamps every step right.
Messages are serialized once (a cycle of simulated steps) and only their
stamp is patched, so the driver spends little CPU per step. Pacing sleeps
until the next deadline and then publishes every step that is due, so at
high rates steps go out in small bursts at the nominal mean rate.

Controlled by lines on stdin (``python -m bench.driver``):

``match TIMEOUT``
    wait until both topics have a subscriber; answers ``matched`` or
    ``unmatched``.
``run RATE DURATION PATH``
    publish ``RATE × DURATION`` steps; save ``stamps`` (``t_0 … t_N``, one
    more than the steps: the stamp an estimate of the last step carries),
    and ``published`` (wall-clock ns just before each measurement's
    publish) to ``PATH`` (``.npz``); answers ``done STEPS ACHIEVED_RATE``.
``quit``
"""

import sys
import time

import numpy as np

from bench.rosutil import serve_lines, wait_until, write_raw_stamp

TEMPLATES = 256


def _templates():
    """Serialized increment and measurement messages of simulated steps."""
    from geometry_msgs.msg import QuaternionStamped, Vector3Stamped
    from rclpy.serialization import serialize_message
    rng = np.random.default_rng(0)
    increments = rng.uniform(-0.01, 0.01, (TEMPLATES, 3))  # rad per step
    measurements = rng.normal(0.0, 0.01, (TEMPLATES, 4))
    measurements[:, 0] += 1.0
    measurements /= np.linalg.norm(measurements, axis=1, keepdims=True)
    pairs = []
    for theta, y in zip(increments, measurements):
        inc = Vector3Stamped()
        inc.header.frame_id = 'imu'
        inc.vector.x, inc.vector.y, inc.vector.z = (float(v) for v in theta)
        meas = QuaternionStamped()
        meas.header.frame_id = 'imu'
        q = meas.quaternion
        # ROS order (x, y, z, w); ours is scalar first.
        q.w, q.x, q.y, q.z = (float(v) for v in y)
        pairs.append((bytearray(serialize_message(inc)),
                      bytearray(serialize_message(meas))))
    return pairs


class Driver:
    """Publishers and the paced loop."""

    def __init__(self, context, depth=10):
        from geometry_msgs.msg import QuaternionStamped, Vector3Stamped
        from rclpy.node import Node
        self.node = Node('bench_driver', context=context)
        self.increment_publisher = self.node.create_publisher(
            Vector3Stamped, 'gyro/increment', depth)
        self.measurement_publisher = self.node.create_publisher(
            QuaternionStamped, 'attitude/measurement', depth)
        self.pairs = _templates()
        self.last_stamp = time.time_ns()

    def match(self, timeout):
        """Wait until both publishers have a subscriber; return success."""
        return wait_until(lambda: self.increment_publisher.get_subscription_count() > 0
                          and self.measurement_publisher.get_subscription_count() > 0, timeout)

    def run(self, rate, duration):
        """
        Publish ``rate × duration`` steps, paced; return the records.

        Returns
        -------
        stamps : ndarray of int64, shape (steps + 1,)
            Nominal stamps ``t_0 … t_steps``, ns.
        published : ndarray of int64, shape (steps,)
            Wall time just before each measurement's publish, ns.

        """
        steps = max(1, int(round(rate * duration)))
        stamps = np.empty(steps + 1, dtype=np.int64)
        published = np.empty(steps, dtype=np.int64)
        pub_increment = self.increment_publisher.publish
        pub_measurement = self.measurement_publisher.publish
        pairs = self.pairs
        base = self.last_stamp
        t0 = time.perf_counter_ns()
        period = 1e9 / rate
        k = 0
        while k < steps:
            now = time.perf_counter_ns() - t0
            due = min(steps, int(now / period) + 1)
            while k < due:
                stamp = base + int((k + 1) * period)
                increment, measurement = pairs[k % TEMPLATES]
                write_raw_stamp(increment, stamp)
                write_raw_stamp(measurement, stamp)
                pub_increment(bytes(increment))
                published[k] = time.time_ns()
                pub_measurement(bytes(measurement))
                stamps[k] = stamp
                k += 1
            if k < steps:
                wait = (k * period - (time.perf_counter_ns() - t0)) / 1e9
                if wait > 0:
                    time.sleep(wait)
        stamps[steps] = base + int((steps + 1) * period)
        self.last_stamp = int(stamps[steps - 1])
        return stamps, published


def main(argv=None):
    """Serve the commands of the module docstring on stdin."""
    import rclpy
    from rclpy.context import Context
    from rclpy.signals import SignalHandlerOptions
    context = Context()
    rclpy.init(context=context, signal_handler_options=SignalHandlerOptions.NO)
    driver = Driver(context)
    print('ready', flush=True)

    def run(words):
        rate, duration, path = float(words[1]), float(words[2]), words[3]
        stamps, published = driver.run(rate, duration)
        np.savez(path, stamps=stamps, published=published)
        span = (published[-1] - published[0]) / 1e9
        achieved = (len(published) - 1) / span if span > 0 else rate
        print(f'done {len(published)} {achieved:.1f}', flush=True)
    try:
        serve_lines({'run': run}, driver.match)
    except KeyboardInterrupt:
        pass
    finally:
        driver.node.destroy_node()
        rclpy.try_shutdown(context=context)
    return 0


if __name__ == '__main__':
    sys.exit(main())
