"""
Node throughput and latency: driver → node under test → probe, 3 processes.

For each target (the bare relay or the observer node, on one executor) the
node runs in its own process, a paced driver process publishes paired
increments and measurements at rising rates, and a probe process records
every ``attitude_estimate``. A rate is *sustained* when every step came
back (zero lost) and the median latency (measurement publish → estimate
arrival at the probe) is below 5 ms: a node that falls behind builds a
backlog of 100 ms and more, or drops steps from its queues.

Each target gets its own ROS_DOMAIN_ID, so no endpoint of a previous
target is ever seen. All processes are ended, also on error.
"""

import json
import os
import tempfile
import time

import numpy as np

from bench.procs import Child, children, cpu_seconds, reserved_domain_id, ros_env

RATES = (250, 500, 1000, 2000, 3000, 4000, 6000, 8000, 10000)  # Hz
SEGMENT_SECONDS = 2.0
LATENCY_RATE = 1000  # Hz, the rate of the latency section
LATENCY_SECONDS = 5.0
SUSTAINED_MEDIAN_MS = 5.0
# The observer runs with diagnostic_period 0.1 s; waiting this long after a
# run lets its input counters (propagated steps, drops) cover the whole run.
DIAGNOSTIC_WAIT = 0.25  # s
# Stop a target's sweep after this many consecutive unsustained rates.
STOP_AFTER_FAILURES = 2


class Target:
    """
    A node under test.

    Parameters
    ----------
    label : str
        Row label (``relay``, ``observer``...).
    executor : str
        Executor label shown in the tables.
    args : list of str
        Command line (``-m module ...`` runs with this interpreter).
    stamp_offset : int
        Steps between the stamp of the inputs and the stamp of the estimate
        (1: the estimate of step k is stamped ``t_{k+1}``).
    note : str

    """

    def __init__(self, label, executor, args, stamp_offset=0, note=''):
        self.label = label
        self.executor = executor
        self.args = list(args)
        self.stamp_offset = stamp_offset
        self.note = note

    @property
    def name(self):
        """Return ``label/executor``."""
        return f'{self.label}/{self.executor}'


POLL_PERIOD = 0.002  # s, of the polling relay
# Queue depth of the "deep" targets: 100 ms of messages at 1 kHz, against
# the 10 (10 ms) of the observer's default.
DEEP_QUEUE = 100


def relay_targets(executors=('single', 'multi', 'events'), polling=True,
                  deep=True):
    """
    Return the bare relay on each executor (it stamps ``t_k``).

    With ``deep``, also the relay on the EventsExecutor with queues of
    :data:`DEEP_QUEUE` instead of 10.

    With ``polling``, also :class:`bench.relay.PollingRelay` on the
    EventsExecutor: one timer takes every waiting message each
    :data:`POLL_PERIOD` (fewer wake-ups, messages taken in batches).
    """
    targets = [Target('relay', ex, ['-m', 'bench.relay', '--executor', ex])
               for ex in executors]
    if deep and 'events' in executors:
        targets.append(Target(
            'relay', f'events-depth{DEEP_QUEUE}',
            ['-m', 'bench.relay', '--executor', 'events', '--depth',
             str(DEEP_QUEUE)]))
    if polling:
        ms = f'{POLL_PERIOD * 1e3:g}'
        targets.append(Target(
            'relay', f'events-poll{ms}ms',
            ['-m', 'bench.relay', '--executor', 'events', '--poll',
             str(POLL_PERIOD)],
            note=f'PollingRelay: one timer every {ms} ms takes all waiting '
                 'messages; queue depth 100'))
    return targets


def analyze(stamps, published, est_stamps, arrived, stamp_offset, rate):
    """
    Match estimates to steps and measure loss and latency.

    Parameters
    ----------
    stamps : ndarray, shape (steps + 1,)
        Nominal stamps ``t_0 … t_steps`` of the driver, ns.
    published : ndarray, shape (steps,)
        Publish time of each step's measurement, ns.
    est_stamps, arrived : ndarray, shape (n,)
        Stamp and arrival time of each estimate at the probe, ns.
    stamp_offset : int
        Estimate of step k carries ``t_{k + stamp_offset}``.
    rate : float
        Hz (estimates within a quarter period of a nominal stamp match).

    Returns
    -------
    result : dict
        ``steps``, ``lost``, ``extra`` (estimates matching no step, or
        repeated), and latency ``p50``, ``p99``, ``max`` in ms (None if no
        estimate came back).

    """
    steps = len(published)
    j = np.clip(np.searchsorted(stamps, est_stamps), 1, len(stamps) - 1)
    nearer_left = (est_stamps - stamps[j - 1]) < (stamps[j] - est_stamps)
    j = np.where(nearer_left, j - 1, j)
    close = np.abs(est_stamps - stamps[j]) < 0.25e9 / rate
    k = j - stamp_offset
    valid = close & (k >= 0) & (k < steps)
    seen = np.unique(k[valid])
    result = {'steps': steps, 'lost': steps - seen.size,
              'extra': int(len(est_stamps) - seen.size)}
    if seen.size:
        latency = (arrived[valid] - published[k[valid]]) / 1e6
        result.update(p50=float(np.percentile(latency, 50)),
                      p99=float(np.percentile(latency, 99)),
                      max=float(latency.max()))
    else:
        result.update(p50=None, p99=None, max=None)
    result['sustained'] = bool(result['lost'] == 0 and result['p50'] is not None
                               and result['p50'] < SUSTAINED_MEDIAN_MS)
    return result


def _drain(probe, expected, limit=3.0, quiet=0.3):
    """Wait until the probe has ``expected`` records or they stop coming."""
    deadline = time.monotonic() + limit
    last, since = -1, time.monotonic()
    while time.monotonic() < deadline:
        probe.send('count')
        count = int(probe.expect('count', 5))
        if count >= expected:
            return
        if count != last:
            last, since = count, time.monotonic()
        elif time.monotonic() - since > quiet:
            return
        time.sleep(0.05)


def _counters(path):
    """The observer's input counters in a probe dump ({} for the relay)."""
    with np.load(path) as p:
        return json.loads(str(p['counters']))


def _degraded(before, after):
    """Steps propagated without their measurement, and inputs dropped."""
    if not after or not before:
        return None, None

    def delta(key):
        return int(float(after.get(key, 0))) - int(float(before.get(key, 0)))
    dropped = sum(delta(key) for key in after if key.startswith('dropped_'))
    return delta('steps_propagated'), dropped


def _segment(target, node, driver, probe, rate, seconds, tmp):
    dpath = os.path.join(tmp, 'driver.npz')
    ppath = os.path.join(tmp, 'probe.npz')
    probe.send(f'dump {ppath}')  # forget anything from before
    probe.expect('dumped', 10)
    before = _counters(ppath)
    pids = {'node': node.proc.pid, 'driver': driver.proc.pid,
            'probe': probe.proc.pid}
    cpu0 = {name: cpu_seconds(pid) for name, pid in pids.items()}
    driver.send(f'run {rate} {seconds} {dpath}')
    words = driver.expect('done', 3 * seconds + 20).split()
    steps, achieved = int(words[0]), float(words[1])
    _drain(probe, steps)
    cpu1 = {name: cpu_seconds(pid) for name, pid in pids.items()}
    cpu = {name: None if cpu0[name] is None or cpu1[name] is None
           else 1e6 * (cpu1[name] - cpu0[name]) / steps for name in pids}
    time.sleep(DIAGNOSTIC_WAIT)
    probe.send(f'dump {ppath}')
    probe.expect('dumped', 10)
    with np.load(dpath) as d, np.load(ppath) as p:
        result = analyze(d['stamps'], d['published'], p['stamps'],
                         p['arrived'], target.stamp_offset, rate)
    result['propagated'], result['dropped'] = _degraded(before,
                                                        _counters(ppath))
    if result['propagated'] or result['dropped']:
        # A step without its measurement is lost as well, if not silently.
        result['sustained'] = False
    result.update(target=target.name, label=target.label,
                  executor=target.executor, rate=rate, seconds=seconds,
                  achieved=achieved, cpu_us_per_step=cpu['node'],
                  driver_cpu_us_per_step=cpu['driver'],
                  probe_cpu_us_per_step=cpu['probe'])
    return result


def sweep(target, index, rates=RATES, seconds=SEGMENT_SECONDS,
          latency_seconds=LATENCY_SECONDS, log_dir=None, progress=print):
    """
    Run one target through the rising rates.

    Parameters
    ----------
    target : Target
    index : int
        Picks a fresh domain id per target.
    rates : sequence of float
    seconds, latency_seconds : float
        Length of a segment; of the segment at :data:`LATENCY_RATE`.
    log_dir : str, optional
        Where the children's stderr goes (default: a temporary folder).
    progress : callable

    Returns
    -------
    results : list of dict
        One per rate run (see :func:`analyze`), or one dict with ``error``.

    """
    results = []
    with tempfile.TemporaryDirectory(prefix='bench-') as tmp, \
            reserved_domain_id(index) as domain_id, children() as started:
        logs = log_dir or tmp
        env = ros_env(domain_id)
        tag = target.name.replace('/', '-')
        try:
            node = Child(target.name, target.args, env,
                         os.path.join(logs, f'{tag}.log'))
            started.append(node)
            probe = Child('probe', ['-m', 'bench.probe'], env,
                          os.path.join(logs, f'{tag}-probe.log'))
            started.append(probe)
            driver = Child('driver', ['-m', 'bench.driver'], env,
                           os.path.join(logs, f'{tag}-driver.log'))
            started.append(driver)
            probe.expect('ready', 30)
            driver.expect('ready', 30)
            driver.send('match 30')
            if driver.expect('', 40) != 'matched':
                raise RuntimeError(f'{target.name}: no subscriber on the '
                                   f'input topics{node.log_tail()}')
            probe.send('match 30')
            if probe.expect('', 40) != 'matched':
                raise RuntimeError(f'{target.name}: no attitude_estimate '
                                   f'publisher{node.log_tail()}')
            time.sleep(0.5)  # let both ends of every match settle
            _segment(target, node, driver, probe, 200, 0.5, tmp)  # warm-up
            failures = 0
            for rate in rates:
                length = latency_seconds if rate == LATENCY_RATE else seconds
                result = _segment(target, node, driver, probe, rate, length, tmp)
                results.append(result)
                progress(_progress_line(result))
                if node.proc.poll() is not None:
                    raise RuntimeError(f'{target.name} exited with '
                                       f'{node.proc.returncode}{node.log_tail()}')
                failures = 0 if result['sustained'] else failures + 1
                if failures >= STOP_AFTER_FAILURES:
                    break
            driver.send('quit')
            probe.send('quit')
        except (RuntimeError, OSError, ValueError) as error:
            progress(f'  {target.name}: {error}')
            results.append({'target': target.name, 'label': target.label,
                            'executor': target.executor, 'error': str(error)})
    return results


def _progress_line(r):
    lat = ('no estimate' if r['p50'] is None else
           f"p50 {r['p50']:.2f} p99 {r['p99']:.1f} max {r['max']:.1f} ms")
    cpu = ('' if r['cpu_us_per_step'] is None
           else f", node CPU {r['cpu_us_per_step']:.0f} µs/step")
    mark = 'sustained' if r['sustained'] else 'NOT sustained'
    return (f"  {r['target']:<18} {r['rate']:>6.0f} Hz (driver "
            f"{r['achieved']:.0f}): lost {r['lost']}/{r['steps']}, {lat}"
            f"{cpu}: {mark}")


def sustained_rate(results):
    """
    Highest rate that was sustained (zero lost, median < 5 ms), or None.

    A sweep goes on after one unsustained rate, so a single hiccup (another
    process taking the cores for a few ms) does not end it; the tables show
    every rate.
    """
    rates = [r['rate'] for r in results if 'error' not in r and r['sustained']]
    return max(rates, default=None)


# The observer runs with its defaults (extended variant, paper gain) but the
# queue depth of the relay (10), so that observer and relay compare on equal
# queues, and diagnostics at 10 Hz for the input counters. The target
# SHIPPED runs it exactly as shipped (EventsExecutor, queue_depth 100).
OBSERVER_ROS_ARGS = ('--ros-args', '-p', 'diagnostic_period:=0.1')
EQUAL_DEPTH = ('-p', 'queue_depth:=10')
SHIPPED = f'observer/events-depth{DEEP_QUEUE}'


def observer_targets(executors=('single', 'multi', 'events'), deep=True):
    """
    Return the observer node on each executor, and as shipped.

    The shipped entry point (``python -m ext_observer.nodes.observer_node``) runs
    ``--executor single`` and ``--executor events``; the MultiThreadedExecutor,
    which the node does not offer, hosts the same node class in
    :mod:`bench.observer_host`. With ``deep``, the entry point with its
    defaults (:data:`SHIPPED`: EventsExecutor, ``queue_depth`` 100).
    """
    targets = []
    for ex in executors:
        if ex in ('single', 'events'):
            args = ['-m', 'ext_observer.nodes.observer_node', '--executor', ex]
            note = f'shipped entry point, --executor {ex}'
        else:
            args = ['-m', 'bench.observer_host', '--executor', ex]
            note = 'ObserverNode hosted by bench.observer_host'
        targets.append(Target('observer', ex,
                              args + list(OBSERVER_ROS_ARGS) + list(EQUAL_DEPTH),
                              stamp_offset=1, note=note))
    if deep and 'events' in executors:
        targets.append(Target(
            'observer', f'events-depth{DEEP_QUEUE}',
            ['-m', 'ext_observer.nodes.observer_node'] + list(OBSERVER_ROS_ARGS),
            stamp_offset=1, note='shipped entry point, its defaults'))
    return targets
