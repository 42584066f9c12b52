"""
Two hosts over DDS: the pipeline split across a link, through loss and a partition.

Marked ``hosts``: the default run deselects it; ``make test-hosts`` runs it
(root: network namespaces, veth, nftables; see ``netns.py``). Every test
makes its own test bed (two namespaces A and B joined by a veth pair on a
private /24) and removes it in a finalizer, with every process in it, also
when the test fails; leftovers of killed runs are removed first.

The processes inside the namespaces discover each other by multicast on the
link (``ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET``), with the test's own
``ROS_DOMAIN_ID``; pytest itself stays outside with localhost discovery and
starts no node: recorder processes (``hosts_recorder.py``), one beside the
observer and two beside the gyro and the monitor (a reliable and a
best-effort subscription to ``attitude_estimate``), write what they receive
to files that the test reads.

``test_faults``: gyro and monitor on one host, the observer on the other (and
the other way round), at 200 Hz, through 20 % random loss for 10 s, 50 % for
5 s, a partition of 3 s, and the observer's host restarted (its processes
killed and started again). ``test_qos_across_the_link``: the observer with
best-effort inputs through a sweep of loss rates, to compare reliable and
best-effort subscriptions. The figures go to ``out/hosts.json``;
``make hosts-report`` turns them into ``docs/across_machines.md`` and its
plots.
"""

import json
import math
import os
import re
import select
import subprocess
import sys
import time

import numpy as np
import pytest

from conftest import CONFIG, REPO
from ext_observer.core import attitude_error
import netns

pytestmark = pytest.mark.hosts

RATE_HZ = 200.0
STEP_PERIOD = 1.0 / RATE_HZ
SECOND = 1_000_000_000
# Rolling mean of the attitude error over this long (by publication time).
SMOOTHING_S = 0.25
# The no-fault band: this factor times the largest rolling mean of the
# fault-free baseline.
BAND_FACTOR = 1.25
BASELINE_S = 5.0
MONITOR_STALE_TIMEOUT = 1.0
# The observer's input_timeout: WARN "no increments on ..." after this.
OBSERVER_INPUT_TIMEOUT = 1.0
GYRO_DIAGNOSTIC_PERIOD = 0.5
# (name, kind, loss %, duration s, time given to recover s); the restart:
# the observer's host down for 2 s (every process killed), then started.
FAULTS = (
    ('loss 20 %', 'loss', 20, 10.0, 6.0),
    ('loss 50 %', 'loss', 50, 5.0, 6.0),
    ('partition 3 s', 'partition', 100, 3.0, 6.0),
    ('observer host restarted', 'restart', None, 2.0, 10.0),
)
# Bounds the test holds the pipeline to (s after the fault ends).
RECOVERY_BOUND_S = {'loss': 3.0, 'partition': 3.0, 'restart': 8.0}
MONITOR_OK_BOUND_S = 4.0
# The QoS sweep: loss rates, s each, s healed between.
QOS_LOSSES = (0, 10, 20, 35, 50)
QOS_SECONDS = 5.0
QOS_GAP_SECONDS = 2.0
OUT = os.path.join(REPO, 'out', 'hosts.json')
RECORDER = os.path.join(os.path.dirname(os.path.abspath(__file__)), 'hosts_recorder.py')
OBSERVER_STATUS = 'observer: inputs'
MONITOR_STATUS = 'monitor: attitude estimate'
GYRO_STATUS = 'gyro: outputs'
STALE, WARN, OK = 3, 1, 0


def installed(name):
    path = os.path.join(os.path.dirname(sys.executable), name)
    if not os.path.exists(path):
        pytest.fail(f'{name} is not installed next to {sys.executable}; run make test-hosts')
    return path


@pytest.fixture
def bed():
    """A fresh two-host test bed, removed at teardown whatever happened."""
    problem = netns.missing(install=False)
    if problem:
        pytest.fail(problem, pytrace=False)
    netns.cleanup_leftovers()
    test_bed = netns.TestBed()
    try:
        test_bed.create()
        yield test_bed
    finally:
        test_bed.destroy()
        assert not [n for n in netns.namespaces() if n.startswith(test_bed.a.namespace[:-2])]


def save(key, data):
    """Merge ``data`` under ``key`` into out/hosts.json."""
    os.makedirs(os.path.dirname(OUT), exist_ok=True)
    try:
        with open(OUT) as file:
            results = json.load(file)
    except (OSError, ValueError):
        results = {}
    results.setdefault('runs', {})[key] = data
    results['setup'] = dict(
        rate_hz=RATE_HZ, subnet=f'{netns.SUBNET}.0/{netns.PREFIX_LENGTH}',
        namespace_env=netns.NAMESPACE_ENV, smoothing_s=SMOOTHING_S, band_factor=BAND_FACTOR,
        baseline_s=BASELINE_S, monitor_stale_timeout_s=MONITOR_STALE_TIMEOUT,
        recovery_bound_s=RECOVERY_BOUND_S, monitor_ok_bound_s=MONITOR_OK_BOUND_S,
        faults=[dict(name=f[0], kind=f[1], loss_percent=f[2], seconds=f[3])
                for f in FAULTS],
        qos_losses=QOS_LOSSES, qos_seconds=QOS_SECONDS, cpus=os.cpu_count(),
        commit=subprocess.run(['git', 'rev-parse', '--short', 'HEAD'], cwd=REPO,
                              capture_output=True, text=True).stdout.strip() or None,
        date=time.strftime('%Y-%m-%d'))
    with open(OUT, 'w') as file:
        json.dump(results, file, indent=1)
        file.write('\n')


# Records --------------------------------------------------------------------------

class Record:
    """What one recorder process wrote so far (several files: one per incarnation)."""

    def __init__(self):
        self.paths = []
        self._offsets = {}
        self.estimates = {}     # stamp -> (source, received, now, q)
        self.truths = {}        # stamp -> q
        self.published = {}     # stamp -> when the gyro published the step, ns
        self.statuses = []      # (now, name, level, message, values)

    def add(self, path):
        self.paths.append(path)
        self._offsets[path] = 0

    def update(self):
        for path in self.paths:
            try:
                with open(path, 'rb') as file:
                    file.seek(self._offsets[path])
                    data = file.read()
            except FileNotFoundError:
                continue
            end = data.rfind(b'\n') + 1
            self._offsets[path] += end
            for line in data[:end].splitlines():
                item = json.loads(line)
                if item[0] == 'e':
                    self.estimates[item[1]] = (item[2], item[3], item[4], item[5:9])
                elif item[0] == 't':
                    self.truths[item[1]] = item[3:7]
                    self.published[item[1]] = item[2]
                else:
                    self.statuses.append(tuple(item[1:6]))
        return self

    def status_list(self, name):
        return [s for s in self.statuses if s[1] == name]

    def last_status(self, name):
        found = self.status_list(name)
        return found[-1] if found else None


def wait_until(predicate, timeout, message, check=lambda: None):
    deadline = time.monotonic() + timeout
    while not predicate():
        check()
        if time.monotonic() > deadline:
            pytest.fail(f'timed out after {timeout} s waiting for {message}')
        time.sleep(0.1)


class Pipeline:
    """gyro and monitor on one host, the observer on the other, and the recorders."""

    def __init__(self, bed, gyro_host, observer_host, domain_id, tmp_path,
                 input_reliability='reliable', queue_depth=100, seed=11):
        self.bed, self.gyro_host, self.observer_host = bed, gyro_host, observer_host
        self.tmp_path, self.input_reliability, self.seed = tmp_path, input_reliability, seed
        self.queue_depth = queue_depth
        self.env = {k: v for k, v in os.environ.items() if k not in netns.CLEARED_ENV}
        self.env.update(netns.NAMESPACE_ENV, ROS_DOMAIN_ID=str(domain_id),
                        PYTHONUNBUFFERED='1', RCUTILS_COLORIZED_OUTPUT='0')
        self.local = Record()       # beside the observer: everything it publishes
        self.remote = Record()      # beside gyro and monitor: reliable, truth, statuses
        self.remote_best_effort = Record()
        self.processes = {}
        self.gyro_outputs = []      # what each stopped gyro wrote (its final count)
        self.incarnations = 0

    def start(self, host, name, argv):
        log = self.tmp_path / f'{host.label}-{name}-{len(host.processes)}.log'
        process = host.start(argv, self.env, log)
        self.processes[name] = process
        return process

    def recorder(self, host, name, record, *options):
        path = self.tmp_path / f'{name}-{len(record.paths)}.jsonl'
        record.add(path)
        return self.start(host, name, [sys.executable, RECORDER, str(path)] + list(options))

    def start_observer_host(self):
        self.incarnations += 1
        self.recorder(self.observer_host, 'local_recorder', self.local,
                      '--estimates', 'reliable', '--diagnostics')
        self.start(self.observer_host, 'observer', [
            installed('observer_node'), '--ros-args', '--params-file', CONFIG,
            '-p', f'step_period:={STEP_PERIOD!r}', '-p', 'diagnostic_period:=0.25',
            '-p', f'input_timeout:={OBSERVER_INPUT_TIMEOUT}',
            '-p', f'input_reliability:={self.input_reliability}',
            '-p', f'queue_depth:={self.queue_depth}'])

    def start_all(self):
        self.start_observer_host()
        self.recorder(self.gyro_host, 'remote_recorder', self.remote,
                      '--estimates', 'reliable', '--truth', '--diagnostics')
        self.recorder(self.gyro_host, 'remote_best_effort', self.remote_best_effort,
                      '--estimates', 'best_effort')
        self.start(self.gyro_host, 'monitor', [
            installed('monitor_node'), '--ros-args', '--params-file', CONFIG,
            '-p', 'diagnostic_period:=0.2', '-p', f'stale_timeout:={MONITOR_STALE_TIMEOUT}',
            '-p', 'window:=50', '-p', f'queue_depth:={self.queue_depth}'])
        # The gyro starts publishing once the observer across the link subscribes.
        self.start(self.gyro_host, 'gyro', [
            installed('gyro_node'), '--ros-args', '--params-file', CONFIG,
            '-p', f'rate_hz:={RATE_HZ}', '-p', f'seed:={self.seed}',
            '-p', 'wait_for_subscribers:=1', '-p', f'diagnostic_period:={GYRO_DIAGNOSTIC_PERIOD}',
            '-p', f'queue_depth:={self.queue_depth}'])

    def check_alive(self):
        for name, process in self.processes.items():
            if not process.alive():
                pytest.fail(f'{name} on host {process.host.label} ended '
                            f'({process.process.returncode}):\n{process.output[-3000:]}')

    def update(self):
        for record in (self.local, self.remote, self.remote_best_effort):
            record.update()

    def wait_for_steady_state(self, timeout=60.0):
        def ready():
            self.update()
            status = self.remote.last_status(MONITOR_STATUS)
            return (status is not None and status[2] == OK and len(self.local.estimates) > 400
                    and len(self.remote_best_effort.estimates) > 100)
        wait_until(ready, timeout, 'the monitor OK and estimates on both hosts',
                   self.check_alive)

    def hold(self, seconds):
        """Let the pipeline run for ``seconds``, checking that every process lives."""
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            self.check_alive()
            time.sleep(min(0.1, max(0.0, deadline - time.monotonic())))

    def restart_observer_host(self, down_s):
        """
        Kill every process of the observer's host; after ``down_s``, start them again.

        Return the times of the kill and of the start, ns.
        """
        self.observer_host.kill_all()
        for name in ('observer', 'local_recorder'):
            self.processes.pop(name)
        killed = time.time_ns()
        self.hold(down_s)
        started = time.time_ns()
        self.start_observer_host()
        return killed, started

    def stop(self):
        """Stop the gyro, let the inputs drain, then read the last statuses; stop the rest."""
        gyro = self.processes.pop('gyro')
        gyro.interrupt(10.0)
        self.gyro_outputs.append(gyro.output)
        self.hold(1.0)
        self.update()
        for name, process in list(self.processes.items()):
            code = process.interrupt(10.0)
            assert code == 0, f'{name}: exit {code}\n{process.output[-3000:]}'
            assert 'Traceback' not in process.output, process.output
        self.processes.clear()
        self.update()


# Analysis --------------------------------------------------------------------------

def quantiles(values):
    if not len(values):
        return dict(p50=None, p99=None, max=None)
    values = np.asarray(values, dtype=float)
    return dict(p50=round(float(np.percentile(values, 50)), 2),
                p99=round(float(np.percentile(values, 99)), 2),
                max=round(float(values.max()), 2))


def error_series(pipeline):
    """Return (publication time ns, attitude error rad) of every published estimate."""
    stamps = sorted(t for t in pipeline.local.estimates if t in pipeline.remote.truths)
    published = np.array([pipeline.local.estimates[t][0] for t in stamps], dtype=np.int64)
    estimates = np.array([pipeline.local.estimates[t][3] for t in stamps], dtype=float)
    truths = np.array([pipeline.remote.truths[t] for t in stamps], dtype=float)
    errors = attitude_error(estimates, truths) if stamps else np.zeros(0)
    order = np.argsort(published, kind='stable')
    return published[order], np.asarray(errors)[order]


def rolling_mean(times, values, span_ns):
    """Mean of the values in (t − span, t] at each t (times sorted)."""
    sums = np.concatenate([[0.0], np.cumsum(values)])
    starts = np.searchsorted(times, times - span_ns, side='right')
    ends = np.arange(1, len(times) + 1)
    return (sums[ends] - sums[starts]) / (ends - starts)


def delivery(pipeline, record, start, end):
    """Delivered fraction and latency of the estimates published in [start, end)."""
    published = [(t, v[0]) for t, v in pipeline.local.estimates.items() if start <= v[0] < end]
    got = [(record.estimates[t], source) for t, source in published if t in record.estimates]
    return dict(
        published=len(published), delivered=len(got),
        delivered_fraction=round(len(got) / len(published), 4) if published else None,
        latency_ms=quantiles([(v[2] - source) / 1e6 for v, source in got]),
        reception_latency_ms=quantiles([(v[1] - source) / 1e6 for v, source in got]))


def steps_made(pipeline, start, end):
    """
    What became of the gyro's steps stamped in [start, end).

    Each estimate stamped t_k + Δ is the step of the increment stamped t_k: a
    step without one is an increment that never reached the observer (or
    came too late and was dropped). ``delay_ms``: when the observer published
    the step's estimate, after the gyro made the step (a reliable input
    stalled behind a repair delays every step after the lost one);
    ``error``: the attitude error of those estimates.
    """
    period = round(STEP_PERIOD * SECOND)
    steps = sorted(t for t in pipeline.remote.truths if start <= t < end)
    done = [t for t in steps if t + period in pipeline.local.estimates
            and t + period in pipeline.remote.truths]
    if not steps:
        return dict(steps=0, estimated_fraction=None, delay_ms=quantiles([]),
                    error_mean=None, error_p90=None)
    errors = attitude_error(
        np.array([pipeline.local.estimates[t + period][3] for t in done], dtype=float),
        np.array([pipeline.remote.truths[t + period] for t in done], dtype=float)
    ) if done else np.zeros(0)
    return dict(
        steps=len(steps), estimated_fraction=round(len(done) / len(steps), 4),
        delay_ms=quantiles([(pipeline.local.estimates[t + period][0]
                             - pipeline.remote.published[t]) / 1e6 for t in done]),
        error_mean=round(float(np.mean(errors)), 4) if len(errors) else None,
        error_p90=round(float(np.percentile(errors, 90)), 4) if len(errors) else None)


def longest_pause(times, start, end):
    """The longest time in [start, end) without a published estimate, s."""
    if end <= start:
        return None
    inside = times[(times >= start) & (times < end)]
    edges = np.concatenate([[start], inside, [end]]).astype(np.int64)
    return round(float(np.diff(edges).max()) / SECOND, 3)


def counter_at(statuses, key, when):
    """The value of ``key`` in the last status at or before ``when`` (0 before any)."""
    value = 0
    for status in statuses:
        if status[0] > when:
            break
        value = int(status[4].get(key, 0))
    return value


def counter_delta(statuses, key, start, end):
    return counter_at(statuses, key, end) - counter_at(statuses, key, start)


def steps_published(pipeline):
    """
    At most how many steps the gyro made, by counts that are not the observer's.

    The gyro's own final count, the line it logs when it stops (``stopping:
    N steps published``), plus one: Ctrl-C may end it between a step's
    measurement and its increment. Its last status is no bound: a diagnostic
    timer delayed on a loaded machine made one 120 steps older than the end
    (0.6 s at 200 Hz, its period being 0.5 s).
    """
    counts = [int(n) for output in pipeline.gyro_outputs
              for n in re.findall(r'stopping: (\d+) steps published', output)]
    assert counts, f'no final count in the gyro\'s output:\n{pipeline.gyro_outputs}'
    return max(counts) + 1


def check_accounting(statuses, published):
    """
    received = processed + dropped (the sum of dropped_<reason>) + waiting, every status.

    And against the test's count: no observer (each incarnation counts from
    zero) received more increments, or more measurements, than the gyro
    published.
    """
    assert statuses, 'no status of the observer'
    for now, _, level, message, values in statuses:
        received, processed = int(values['inputs_received']), int(values['inputs_processed'])
        dropped, waiting = int(values['inputs_dropped']), int(values['inputs_waiting'])
        by_reason = sum(int(v) for k, v in values.items() if k.startswith('dropped_'))
        assert received == processed + dropped + waiting, values
        assert dropped == by_reason, values
        assert int(values['increments']) <= published, (published, values)
        assert int(values['measurements']) <= published, (published, values)


def check_monitor_accounting(statuses):
    """The monitor's estimates and ground truths: every one accounted for, every status."""
    assert statuses, 'no status of the monitor'
    for status in statuses:
        values = {k: int(v) for k, v in status[4].items() if k in COUNTERS}
        assert values['estimates_received'] == (
            values['estimates_processed'] + values['dropped_non_finite_estimate']), values
        assert values['ground_truth_received'] == (
            values['ground_truth_paired'] + values['dropped_non_finite_ground_truth']
            + values['dropped_unpaired_ground_truth'] + values['waiting_ground_truth']), values
        assert values['dropped_non_finite_estimate'] == 0, values


COUNTERS = ('estimates_received', 'estimates_processed', 'dropped_non_finite_estimate',
            'ground_truth_received', 'ground_truth_paired', 'dropped_non_finite_ground_truth',
            'dropped_unpaired_ground_truth', 'waiting_ground_truth')


def all_finite(record):
    return all(math.isfinite(v) for entry in record.estimates.values() for v in entry[3])


# Tests -----------------------------------------------------------------------------

def test_test_bed_is_two_hosts_on_a_private_link(bed, tmp_path):
    # Each namespace has lo and its end of the veth, no other interface and no
    # route but the /24 (no default route: nothing can leave).
    links = bed.describe()
    assert {label: sorted(name for name, _ in found) for label, found in links.items()} == {
        'A': ['lo', netns.VETH], 'B': ['lo', netns.VETH]}
    for host in bed.hosts:
        main = [r['dst'] for r in bed.routes(host) if r.get('table', 'main') == 'main']
        assert main == [f'{netns.SUBNET}.0/{netns.PREFIX_LENGTH}'], main
    # nftables drops what it is told to: 1000 datagrams A -> B at 20 % loss.
    # The receiver says when it listens, keeps every datagram that crosses
    # (a socket buffer for all 1000, whatever the scheduling), and counts
    # them once told the sender is done: none still on the way when two
    # reads 0.5 s apart find the socket empty.
    receiver = ('import socket, sys, time\n'
                's = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)\n'
                's.setsockopt(socket.SOL_SOCKET, 33, 8 << 20)\n'  # SO_RCVBUFFORCE, root
                f's.bind(("{bed.b.address}", 47000)); s.setblocking(False)\n'
                'print("ready", flush=True)\n'
                'sys.stdin.readline()\n'
                'n, quiet = 0, 0\n'
                'while quiet < 2:\n'
                '    got = 0\n'
                '    while True:\n'
                '        try: s.recv(100)\n'
                '        except BlockingIOError: break\n'
                '        got += 1\n'
                '    n += got; quiet = 0 if got else quiet + 1\n'
                '    time.sleep(0.5)\n'
                'print(n)\n')
    sender = ('import socket, time\n'
              's = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)\n'
              'for i in range(1000):\n'
              f'    s.sendto(b"x", ("{bed.b.address}", 47000)); time.sleep(0.0005)\n')
    bed.set_loss(20)
    listener = subprocess.Popen(['ip', 'netns', 'exec', bed.b.namespace, sys.executable, '-c',
                                 receiver], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                text=True, start_new_session=True)
    try:
        ready, _, _ = select.select([listener.stdout], [], [], 20.0)
        assert ready and listener.stdout.readline() == 'ready\n', 'the receiver did not start'
        bed.a.exec(sys.executable, '-c', sender)
        received = int(listener.communicate('done\n', timeout=20)[0])
    finally:
        listener.kill()
        listener.wait()
    assert 700 <= received <= 880, received
    total, dropped = bed.link_counters()
    assert total >= 1000 and dropped == 1000 - received
    # Nothing for an address outside the /24 was even tried.
    try:
        bed.a.exec(sys.executable, '-c', 'import socket; socket.socket(socket.AF_INET, '
                   'socket.SOCK_DGRAM).sendto(b"x", ("192.0.2.1", 9))')
    except RuntimeError as error:
        assert 'Network is unreachable' in str(error)
    assert bed.escaped_packets() == 0


def run_faults(pipeline, bed):
    """Baseline, then each fault of FAULTS; return the timeline (wall ns)."""
    pipeline.start_all()
    pipeline.wait_for_steady_state()
    timeline = [dict(name='baseline', kind='none', start=time.time_ns())]
    pipeline.hold(BASELINE_S)
    timeline[-1]['end'] = time.time_ns()
    for name, kind, loss, seconds, recovery in FAULTS:
        phase = dict(name=name, kind=kind, loss_percent=loss, seconds=seconds)
        if kind == 'restart':
            phase['start'], phase['end'] = pipeline.restart_observer_host(seconds)
        else:
            if kind == 'loss':
                bed.set_loss(loss)
            else:
                bed.partition()
            phase['start'] = time.time_ns()
            pipeline.hold(seconds)
            total, dropped = bed.link_counters()
            bed.heal()
            phase['end'] = time.time_ns()
            phase['packets'] = total
            phase['packet_loss_measured'] = round(dropped / total, 4) if total else None
        pipeline.hold(recovery)
        phase['next'] = time.time_ns()
        timeline.append(phase)
    pipeline.stop()
    return timeline


def analyse_faults(pipeline, timeline):
    """Recovery, monitor levels, accounting and QoS figures of each phase."""
    times, errors = error_series(pipeline)
    assert len(times) > 1000, 'too few estimates paired with the ground truth'
    rolling = rolling_mean(times, errors, int(SMOOTHING_S * SECOND))
    baseline = timeline[0]
    in_baseline = (times >= baseline['start']) & (times < baseline['end'])
    assert in_baseline.sum() > 0.8 * RATE_HZ * BASELINE_S, in_baseline.sum()
    band = BAND_FACTOR * float(rolling[in_baseline].max())
    monitor = pipeline.remote.status_list(MONITOR_STATUS)
    observer = pipeline.local.status_list(OBSERVER_STATUS)
    gyro = pipeline.remote.status_list(GYRO_STATUS)
    phases = []
    for phase in timeline:
        start, end, after = phase['start'], phase['end'], phase.get('next', phase['end'])
        row = dict(phase)
        row['steps_during'] = steps_made(pipeline, start, end)
        if phase['kind'] != 'none':
            late = (times >= end) & (times < after)
            out = times[late & (rolling > band)]
            recovered_in_time = bool(late.any()) and not (
                rolling[late][times[late] > after - 2 * SECOND] > band).any()
            row['recovered'] = recovered_in_time
            row['recovery_s'] = round((int(out[-1]) - end) / SECOND + STEP_PERIOD, 3) if len(
                out) else 0.0
            row['peak_error_rolling'] = round(float(rolling[(times >= start) & (
                times < after)].max()), 3) if ((times >= start) & (times < after)).any() else None
            first = times[times >= end]
            row['first_estimate_after_s'] = round((int(first[0]) - end) / SECOND, 3) if len(
                first) else None
            # STALE during the fault (or, after a restart, before the new
            # observer's first estimates), then OK again.
            stale_until = end + (MONITOR_STALE_TIMEOUT + 0.5) * SECOND
            stale = [s for s in monitor if start <= s[0] <= stale_until and s[2] == STALE]
            row['monitor_stale'] = bool(stale)
            row['monitor_stale_after_s'] = round((stale[0][0] - start) / SECOND, 2) if stale \
                else None
            oks = [s for s in monitor if s[0] >= max(end, stale[-1][0] if stale else 0)
                   and s[2] == OK]
            row['monitor_ok_after_s'] = round((oks[0][0] - end) / SECOND, 2) if oks else None
            # The observer's own status (its host): a silent input during
            # the fault, and when its statuses stop saying so.
            silent = [s for s in observer if start <= s[0] <= stale_until and s[2] == WARN
                      and 'no increments on ' in s[3]]
            row['observer_silent'] = bool(silent)
            row['observer_silent_after_s'] = round((silent[0][0] - start) / SECOND, 2) \
                if silent else None
            back = [s for s in observer if s[0] >= max(end, silent[-1][0] if silent else 0)
                    and 'no increments on ' not in s[3]]
            row['observer_back_after_s'] = round((back[0][0] - end) / SECOND, 2) \
                if back else None
        # Estimates published per second through the fault (the observer keeps going).
        during = times[(times >= start) & (times < end)]
        row['estimates_per_s_during'] = (round(len(during) / ((end - start) / SECOND), 1)
                                         if end > start else None)
        row['longest_gap_during_s'] = longest_pause(times, start, end)
        if phase['kind'] in ('none', 'loss'):
            row['reliable'] = delivery(pipeline, pipeline.remote, start, end)
            row['best_effort'] = delivery(pipeline, pipeline.remote_best_effort, start, end)
            for key in ('steps', 'steps_corrected', 'steps_propagated', 'increments',
                        'measurements', 'inputs_dropped', 'forward_gaps', 'early_releases',
                        'dropped_stale_measurement', 'dropped_unpaired_measurement',
                        'dropped_stale_increment'):
                # Over the phase and the time after it: what a loss did may
                # be counted only once the repairs arrive.
                row[f'observer_{key}'] = counter_delta(observer, key, start, after)
            row['gyro_steps_published'] = counter_delta(gyro, 'steps_published', start, end)
            steps = row['steps_during']['steps']
            row['propagated_fraction'] = round(
                row['observer_steps_propagated'] / steps, 4) if steps else None
        phases.append(row)
    series = dict(t=[round((int(t) - baseline['start']) / SECOND, 3) for t in times[::10]],
                  rolling_error=[round(float(v), 4) for v in rolling[::10]])
    return dict(band_rad=round(band, 4),
                baseline_error_mean=round(float(errors[in_baseline].mean()), 4),
                phases=phases, series=series,
                timeline_s=[dict(name=p['name'], start=(p['start'] - baseline['start']) / SECOND,
                                 end=(p['end'] - baseline['start']) / SECOND)
                            for p in timeline])


@pytest.mark.parametrize('layout', ['gyro_monitor_on_a', 'gyro_monitor_on_b'])
def test_faults(bed, ros_domain_id, tmp_path, layout):
    gyro_host, observer_host = (bed.a, bed.b) if layout == 'gyro_monitor_on_a' else (
        bed.b, bed.a)
    pipeline = Pipeline(bed, gyro_host, observer_host, ros_domain_id, tmp_path)
    try:
        timeline = run_faults(pipeline, bed)
    finally:
        for process in pipeline.processes.values():
            process.kill()
    result = analyse_faults(pipeline, timeline)
    result.update(layout=dict(gyro_monitor=gyro_host.label, observer=observer_host.label),
                  input_reliability='reliable',
                  escaped_packets=bed.escaped_packets())
    final = pipeline.local.last_status(OBSERVER_STATUS)[4]
    result['observer_final'] = {k: v for k, v in final.items() if k.startswith(
        ('inputs_', 'dropped_', 'steps', 'forward_gaps', 'early_releases', 'resets_',
         'reinitialized_')) and v != '0'}
    result['observer_statuses_checked'] = len(pipeline.local.status_list(OBSERVER_STATUS))
    result['monitor_statuses_checked'] = len(pipeline.remote.status_list(MONITOR_STATUS))
    save(layout, result)
    summary = json.dumps({p['name']: {k: p.get(k) for k in (
        'recovery_s', 'monitor_stale', 'monitor_ok_after_s', 'estimates_per_s_during',
        'packet_loss_measured')} for p in result['phases']}, indent=1)
    print(f'\n{layout}: band {result["band_rad"]} rad\n{summary}', file=sys.stderr)

    # Nothing left the two namespaces.
    assert result['escaped_packets'] == 0
    # Never a non-finite estimate, on either host.
    for record in (pipeline.local, pipeline.remote, pipeline.remote_best_effort):
        assert all_finite(record)
    check_monitor_accounting(pipeline.remote.status_list(MONITOR_STATUS))
    # Every input accounted for in every status of every incarnation; nothing
    # waits once the gyro stopped.
    check_accounting(pipeline.local.status_list(OBSERVER_STATUS), steps_published(pipeline))
    # Nothing waits once the gyro stopped, but the measurement of a step whose
    # increment never came (the gyro publishes the measurement first and was
    # stopped before its last increment got out): a measurement waits for a step
    # as new as it, where an increment is released at its deadline.
    assert int(final['inputs_waiting']) <= 1, final
    if final['inputs_waiting'] != '0':
        assert int(final['steps']) == int(final['increments']), final
    phases = {p['name']: p for p in result['phases']}
    for name, kind, loss, seconds, _ in FAULTS:
        phase = phases[name]
        # Back in the no-fault band, within the bound, and staying there.
        assert phase['recovered'], phase
        assert phase['recovery_s'] <= RECOVERY_BOUND_S[kind], phase
        if kind == 'loss':
            # The observer keeps publishing through the loss.
            assert phase['estimates_per_s_during'] >= 0.5 * RATE_HZ, phase
            assert phase['longest_gap_during_s'] < 1.0, phase
            assert abs(phase['packet_loss_measured'] - loss / 100) < 0.05, phase
        if kind in ('partition', 'restart'):
            # The monitor on the other host goes STALE, then OK again.
            assert phase['monitor_stale'], phase
            assert phase['monitor_ok_after_s'] is not None, phase
            assert phase['monitor_ok_after_s'] <= MONITOR_OK_BOUND_S + (
                RECOVERY_BOUND_S['restart'] if kind == 'restart' else 0), phase
        if kind == 'partition':
            # The observer's own host sees its increments stop, then come back.
            assert phase['observer_silent'], phase
            # (Not before input_timeout: the last increment came at the
            # partition's start at the latest, give or take a step.)
            assert phase['observer_silent_after_s'] >= 0.9 * OBSERVER_INPUT_TIMEOUT, phase
            assert phase['observer_back_after_s'] is not None, phase
            assert phase['observer_back_after_s'] <= MONITOR_OK_BOUND_S, phase


# QoS across the link ----------------------------------------------------------------

# The observer's inputs: best effort (a lost increment is lost), or reliable
# with a history of 5 s at 200 Hz (room for the retransmissions); the fault
# runs above have the default, reliable with a history of 100 (0.5 s).
QOS_CASES = {
    'best_effort_inputs': dict(input_reliability='best_effort', queue_depth=100,
                               losses=QOS_LOSSES),
    'reliable_inputs_depth_1000': dict(input_reliability='reliable', queue_depth=1000,
                                       losses=(0, 20, 50)),
}


def healed_gap_s(config):
    """
    The healed time after a loss phase, s.

    A reliable input stalls behind its repairs for up to its history (depth
    over rate): the phase's estimates go out in a burst up to that long after
    the link healed. The next phase must not begin before, or that burst
    crosses the next phase's lossier link and its history overwrites them.
    """
    if config['input_reliability'] != 'reliable':
        return QOS_GAP_SECONDS
    return max(QOS_GAP_SECONDS, config['queue_depth'] / RATE_HZ + 1.0)


@pytest.mark.parametrize('case', list(QOS_CASES))
def test_qos_across_the_link(bed, ros_domain_id, tmp_path, case):
    config = QOS_CASES[case]
    pipeline = Pipeline(bed, bed.a, bed.b, ros_domain_id, tmp_path,
                        input_reliability=config['input_reliability'],
                        queue_depth=config['queue_depth'])
    timeline = []
    try:
        pipeline.start_all()
        pipeline.wait_for_steady_state()
        for loss in config['losses']:
            bed.set_loss(loss)
            start = time.time_ns()
            pipeline.hold(QOS_SECONDS)
            total, dropped = bed.link_counters()
            bed.heal()
            timeline.append(dict(loss_percent=loss, start=start, end=time.time_ns(),
                                 packet_loss_measured=round(dropped / total, 4)
                                 if total else None))
            pipeline.hold(healed_gap_s(config))
        pipeline.stop()
    finally:
        for process in pipeline.processes.values():
            process.kill()
    times, _ = error_series(pipeline)
    observer = pipeline.local.status_list(OBSERVER_STATUS)
    rows = []
    for phase in timeline:
        start, end = phase['start'], phase['end']
        after = end + healed_gap_s(config) * SECOND
        row = dict(phase)
        row.update(
            reliable=delivery(pipeline, pipeline.remote, start, end),
            best_effort=delivery(pipeline, pipeline.remote_best_effort, start, end),
            steps_during=steps_made(pipeline, start, end))
        # Counters over the phase and the healed time after it (a stalled
        # reliable input is processed only once its repair arrives).
        # The steps of the healed time after have their measurements: what
        # propagated over [start, after) are the loss's steps.
        steps = row['steps_during']['steps']
        row['propagated_fraction'] = round(counter_delta(
            observer, 'steps_propagated', start, after) / steps, 4) if steps else None
        row['observer_drops'] = {key: counter_delta(observer, key, start, after)
                                 for key in observer[-1][4] if key.startswith('dropped_')
                                 and counter_delta(observer, key, start, after)}
        row['longest_gap_s'] = longest_pause(times, start, end)
        rows.append(row)
    result = dict(case=case, input_reliability=config['input_reliability'],
                  queue_depth=config['queue_depth'], seconds=QOS_SECONDS, phases=rows,
                  escaped_packets=bed.escaped_packets())
    save(f'qos_{case}', result)
    summary = json.dumps([{k: (r[k] if k not in ('reliable', 'best_effort') else {
        x: r[k][x] for x in ('delivered_fraction', 'latency_ms')}) for k in (
        'loss_percent', 'steps_during', 'propagated_fraction', 'longest_gap_s',
        'reliable', 'best_effort')} for r in rows], indent=1)
    print(f'\nqos {case}:\n{summary}', file=sys.stderr)

    assert result['escaped_packets'] == 0
    for record in (pipeline.local, pipeline.remote, pipeline.remote_best_effort):
        assert all_finite(record)
    check_accounting(observer, steps_published(pipeline))
    check_monitor_accounting(pipeline.remote.status_list(MONITOR_STATUS))
    by_loss = {row['loss_percent']: row for row in rows}
    # No loss: everything arrives, either way.
    assert by_loss[0]['best_effort']['delivered_fraction'] >= 0.99, by_loss[0]
    assert by_loss[0]['reliable']['delivered_fraction'] >= 0.99, by_loss[0]
    # 20 %: reliable gets (nearly) every estimate.
    lossy = by_loss[20]
    assert lossy['reliable']['delivered_fraction'] >= 0.98, lossy
    if config['input_reliability'] == 'best_effort':
        # Estimates go out steadily, one per step: reliable waits for its
        # repairs, best effort does not and loses about a fifth of them.
        # (With reliable inputs they go out in bursts after each repair,
        # several to a datagram, and on 2 shared cores the subscriber's
        # queue then sets both latencies: best effort's p50 was 219 ms
        # against reliable's 153 ms once; it delivered 67 % once, when the
        # recorders kept the last 1000, and 78 to 83 % since they keep all.
        # Neither is asserted there.)
        # Compared on the middleware's own stamps (source to reception, not
        # when a subscriber's callback got to run on a loaded machine), and
        # what best effort delivers against the loss the link counted.
        assert (lossy['reliable']['reception_latency_ms']['p50']
                > lossy['best_effort']['reception_latency_ms']['p50']), lossy
        expected = 1.0 - lossy['packet_loss_measured']
        assert abs(lossy['best_effort']['delivered_fraction'] - expected) <= 0.1, lossy
        # A lost increment is a step without an estimate; the others at once.
        assert 0.7 <= lossy['steps_during']['estimated_fraction'] <= 0.9, lossy
        assert lossy['steps_during']['delay_ms']['p50'] < 100, lossy
    else:
        # A history of 5 s keeps every increment until its repair: every
        # step gets its estimate, late.
        assert lossy['steps_during']['estimated_fraction'] >= 0.99, lossy
