"""
Drive an ``imu_filter_node`` through DDS in a test: samples, a lockstep replay, a whole run.

:func:`samples` and :func:`turning` make (stamp ns, gyr, acc, field)
samples at 100 Hz; :func:`replay` publishes them so that each sample and
its field reach every node before the next; :func:`run_node` starts a node
with a driver (``test_raw_imu.Driver``) and replays them into it.
"""

import math
import time

import numpy as np

from broad_replay import START
from ext_observer.nodes.imu_filter_node import ImuFilterNode
from imu_driver import connect, Driver
from ros_helpers import overrides, SECOND


def samples(count, gyr=(0.0, 0.0, 0.2), acc=(0.5, -0.3, 9.7), field=(2e-5, 1e-5, -4e-5)):
    """A turning body at 100 Hz: (stamp ns, gyr, acc, field) per sample."""
    return [(START + k * SECOND // 100, gyr, acc, field) for k in range(count)]


def replay(spinner, driver, nodes, data):
    """Publish in lockstep: each sample and its field reach every node first."""
    deadline = time.monotonic() + 60.0
    fields0 = [n.pairer.received['measurement'] for n in nodes]
    samples0 = [n.pairer.received['increment'] for n in nodes]
    for k, (stamp, gyr, acc, field) in enumerate(data):
        driver.send_field(stamp, field)
        while any(n.pairer.received['measurement'] < f0 + k + 1
                  for n, f0 in zip(nodes, fields0)):
            spinner.executor.spin_once(timeout_sec=0.01)
            assert time.monotonic() < deadline, f'field {k} never arrived'
        driver.send_imu(stamp, gyr, acc)
        while any(n.pairer.received['increment'] < s0 + k + 1
                  for n, s0 in zip(nodes, samples0)):
            spinner.executor.spin_once(timeout_sec=0.01)
            assert time.monotonic() < deadline, f'sample {k} never arrived'


def turning(count, seed=0):
    """Samples of a body turning about a changing axis, with noise (seeded)."""
    rng = np.random.default_rng(seed)
    out = []
    for k, (stamp, _, _, _) in enumerate(samples(count)):
        gyr = tuple(float(v) for v in (0.3 * math.sin(0.02 * k), 0.2, 0.4 * math.cos(0.03 * k))
                    + rng.normal(0.0, 0.01, 3))
        acc = tuple(float(v) for v in (0.4, -0.2, 9.7) + rng.normal(0.0, 0.05, 3))
        field = tuple(float(v) for v in (2e-5, 1e-5, -4e-5) + rng.normal(0.0, 5e-7, 3))
        out.append((stamp, gyr, acc, field))
    return out


def run_node(spinner, ros_context, data, name, **parameters):
    node = spinner.add(ImuFilterNode(node_name=name, context=ros_context,
                                     parameter_overrides=overrides(**parameters)))
    driver = spinner.add(Driver(ros_context))
    connect(spinner, driver, node)
    replay(spinner, driver, [node], data)
    spinner.spin_until(lambda: len(driver.estimates) >= len(data) - 1, 10.0,
                       'the estimates')
    return node, driver
