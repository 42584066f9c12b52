"""
The load benchmark through DDS: a BROAD trial replayed into ``imu_filter_node``.

Each case starts the installed ``imu_filter_node`` (its defaults, but
``use_mag`` for the mode) and a recorder as processes of their own, in a
ROS domain of their own (``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``), and
replays one trial from this process at a multiple of real time: every
``sensor_msgs/Imu`` and ``MagneticField`` serialized before the replay
starts, then published as bytes with the trial's stamps, paced by the
monotonic clock (the replayer costs a ``publish`` a message, so it is not
the bottleneck). With ``busy``, one busy-loop process per core at normal
priority runs meanwhile; each ends by itself at a deadline and as soon as
this process is gone.

The recorder keeps ``imu/data`` as bytes and the node's ``/diagnostics``;
:func:`analyze` turns them into the figures of a case: the share of samples
answered, the samples lost by where they were lost (before the node: sent
but not counted by it; in the node: counted but not stepped; after it:
stepped but not recorded), the error over the answered samples against the
batch run of the same samples (:func:`~ext_observer.recordings.recording.attitude_from_imu`),
e²/σ² of the published covariance, the node's CPU per sample, and whether
``/diagnostics`` said WARN when more than 1 % was lost.

``python -m bench.load_dds record OUT`` is the recorder.
"""

import contextlib
import math
import os
import pickle
import struct
import subprocess
import sys
import tempfile
import threading
import time

import numpy as np

from bench.machine import load
from bench.procs import Child, cpu_seconds, installed_node, reserved_domain_id, ros_env
from bench.rosutil import on_compiled_kernels, watch_kernels

SPEEDS = (1.0, 2.0, 4.0)
# 'imu': a field after every IMU sample, with its stamp; a number: Hz.
FIELD_RATES = ('imu', 100.0)
LOADS = ('idle', 'busy')
MODES = ('9D', '6D')
# What the node should do with every core busy (the done-criteria of the
# load benchmark): answered over the movement samples, at these speeds...
ANSWERED_LIMIT = 0.99
ANSWERED_SPEEDS = (1.0, 2.0)
# ... its error over them against the batch run's, and e²/σ²'s range.
ERROR_RATIO_LIMIT = 1.5
ERROR_RATIO_GOAL = 1.2
Z2_RANGE = (0.3, 3.0)
# Above this share of samples lost, /diagnostics should say WARN.
WARN_SHARE = 0.01
# A case's output is over once no imu/data came for this long, s.
QUIET = 1.0
START_TIMEOUT = 60.0
# A cold numba cache: the node compiles its kernels in the background first.
SETTLE_TIMEOUT = 300.0
# Beyond the replay's own duration, for the busy loops' deadline, s.
BUSY_MARGIN = 120.0
FRAME_ID = 'imu_link'
TESLA_PER_MICROTESLA = 1e-6
# Keys of the node's status that speak of lost samples, read when present.
LOSS_WORDS = ('lost', 'hole', 'lag', 'behind')
# A WARN about losses says one of these (a WARN for the magnetometer's
# calibration, say, does not count).
LOSS_MESSAGE_WORDS = LOSS_WORDS + ('loss', 'drop')
STATUS_NAME = 'imu_filter'
_LEVELS = ('OK', 'WARN', 'ERROR', 'STALE')
_ORIENTATION = (struct.Struct('>13d'), struct.Struct('<13d'))

# The busy loop: arithmetic in slices of a few ms between checks of its
# deadline and of its parent (gone: the benchmark crashed or was killed).
BUSY_SOURCE = '''
import os, sys, time
end = time.monotonic() + float(sys.argv[1])
parent = int(sys.argv[2])
x = 0
while time.monotonic() < end and os.getppid() == parent:
    for _ in range(50000):
        x += 1
'''

# The node and the recorder are started through this: killed with the
# benchmark even when it is killed itself (PR_SET_PDEATHSIG survives exec).
GUARD_SOURCE = '''
import ctypes, os, signal, sys
try:
    ctypes.CDLL(None).prctl(1, signal.SIGKILL)
except (AttributeError, OSError):
    pass
if os.getppid() == int(sys.argv[1]):
    os.execv(sys.argv[2], sys.argv[2:])
'''


# --- what is sent ------------------------------------------------------------

def field_rows(count, rate, field_rate):
    """
    Return the IMU samples after which a field is sent.

    Parameters
    ----------
    count : int
    rate : float
        The IMU's, Hz.
    field_rate : 'imu' or float
        ``'imu'``: every sample; a rate (Hz): the first sample of each
        ``1 / field_rate`` interval.

    """
    k = np.arange(count)
    if field_rate == 'imu':
        return k
    slot = np.floor(k * float(field_rate) / rate)
    return np.flatnonzero(np.diff(slot, prepend=-1.0) > 0)


def stamps_of(count, rate):
    """The stamps of the trial's samples, ns, as the batch run gives them."""
    from ext_observer.recordings.recording import SECOND, START
    return [START + round(k * SECOND / rate) for k in range(count)]


def serialized_messages(trial, mode, field_rate):
    """
    Return the replay: per IMU sample its ``Imu`` bytes and its field's bytes (or None).

    The field (T) has the stamp of the sample it follows; 6D sends none.
    """
    from rclpy.serialization import serialize_message
    from sensor_msgs.msg import Imu, MagneticField
    count = len(trial)
    stamps = stamps_of(count, trial.rate)
    imu, field = Imu(), MagneticField()
    imu.header.frame_id = field.header.frame_id = FRAME_ID
    imu.orientation_covariance[0] = -1.0  # a raw IMU: no orientation
    with_field = np.zeros(count, dtype=bool)
    if mode == '9D':
        with_field[field_rows(count, trial.rate, field_rate)] = True
    gyr, acc = trial.gyr.tolist(), trial.acc.tolist()
    mag = (trial.mag * TESLA_PER_MICROTESLA).tolist()
    out = []
    for k in range(count):
        sec, nanosec = divmod(stamps[k], 1_000_000_000)
        imu.header.stamp.sec = field.header.stamp.sec = sec
        imu.header.stamp.nanosec = field.header.stamp.nanosec = nanosec
        v, a = imu.angular_velocity, imu.linear_acceleration
        v.x, v.y, v.z = gyr[k]
        a.x, a.y, a.z = acc[k]
        raw_field = None
        if with_field[k]:
            m = field.magnetic_field
            m.x, m.y, m.z = mag[k]
            raw_field = serialize_message(field)
        out.append((serialize_message(imu), raw_field))
    return out


def batch_reference(trial, mode, field_rate):
    """The batch run of the trial with the fields the replay sends: a Recording."""
    from ext_observer.recordings.recording import attitude_from_imu
    mag = None
    if mode == '9D':
        mag = np.full(trial.mag.shape, np.nan)
        rows = field_rows(len(trial), trial.rate, field_rate)
        mag[rows] = trial.mag[rows] * TESLA_PER_MICROTESLA
    return attitude_from_imu(trial.gyr, trial.acc, mag, rate=trial.rate,
                             parameters={'use_mag': mode == '9D'})


# --- what comes back ---------------------------------------------------------

def decode_outputs(raws):
    """
    Stamps (ns), orientations ``(w, x, y, z)`` and covariances (9) of ``imu/data`` bytes.

    Returns
    -------
    stamps : ndarray of int64, shape (N,)
    quaternions : ndarray, shape (N, 4)
    covariances : ndarray, shape (N, 9)

    """
    from ext_observer.recordings.cdr import imu_layout
    stamps = np.zeros(len(raws), dtype=np.int64)
    quaternions, covariances = np.zeros((len(raws), 4)), np.zeros((len(raws), 9))
    for i, raw in enumerate(raws):
        order, body, stamp, _, _ = imu_layout(raw)
        values = _ORIENTATION[order].unpack_from(raw, body)
        stamps[i] = stamp
        x, y, z, w = values[:4]
        quaternions[i] = w, x, y, z
        covariances[i] = values[4:]
    return stamps, quaternions, covariances


def status_numbers(values):
    """A status's key-values as numbers where they are (counters, shares)."""
    out = {}
    for key, value in values.items():
        try:
            out[key] = float(value)
        except (TypeError, ValueError):
            continue
    return out


def loss_keys(values):
    """The node's own keys about lost samples (when its version has them), as numbers."""
    return {key: value for key, value in status_numbers(values).items()
            if any(word in key for word in LOSS_WORDS)}


def _z2(error, sigma):
    keep = np.isfinite(error) & np.isfinite(sigma) & (sigma > 0.0)
    if not keep.any():
        return math.nan
    return float(np.mean((error[keep] / sigma[keep]) ** 2))


def diagnostics_summary(statuses, lost, sent):
    """
    What ``/diagnostics`` said during a case.

    Parameters
    ----------
    statuses : list of dict
        ``level`` (int), ``message``, ``values`` (dict of str), in order.
    lost, sent : int
        The samples not answered, and those sent.

    Returns
    -------
    dict
        ``statuses``, ``worst`` (level name), ``warn_messages`` (the distinct
        texts of the statuses above OK), ``loss_keys`` (the last status's),
        ``warned_of_loss``: None when at most :data:`WARN_SHARE` was lost,
        else whether some status at WARN or worse spoke of it
        (:data:`LOSS_MESSAGE_WORDS`).

    """
    worst = max((s['level'] for s in statuses), default=None)
    messages = []
    for s in statuses:
        if s['level'] >= 1 and s['message'] not in messages:
            messages.append(s['message'])
    last = statuses[-1]['values'] if statuses else {}
    warned = any(s['level'] >= 1 and any(w in s['message'].lower() for w in LOSS_MESSAGE_WORDS)
                 for s in statuses)
    return {'statuses': len(statuses),
            'worst': None if worst is None else _LEVELS[min(worst, 3)],
            'warn_messages': messages, 'loss_keys': loss_keys(last),
            'warned_of_loss': None if lost <= WARN_SHARE * sent else warned}


def loss_by_cause(sent, answered, last_values):
    """
    Samples lost before the node, in it and after it.

    From the node's last status: ``imu_samples`` (received) and ``steps``;
    ``None`` where the status lacks them. The first sample of a time line
    gives no step: it counts as dropped in the node.
    """
    numbers = status_numbers(last_values)
    received, steps = numbers.get('imu_samples'), numbers.get('steps')
    drops = {key[len('dropped_'):]: int(value) for key, value in numbers.items()
             if key.startswith('dropped_') and value}
    return {'received': None if received is None else int(received),
            'steps': None if steps is None else int(steps),
            'before_node': None if received is None else sent - int(received),
            'in_node': None if received is None or steps is None else int(received - steps),
            'after_node': None if steps is None else int(steps) - answered,
            'node_drops': drops}


def holes(answered, rate):
    """
    The runs of samples without an answer (sample 0 only starts the time line).

    Returns
    -------
    dict
        ``count``, ``longest_ms`` (the longest run, ms at the trial's rate),
        ``first_s`` (where the first one starts, s into the trial; None
        without any).

    """
    missing = ~np.asarray(answered, dtype=bool)
    missing[:1] = False
    edges = np.diff(np.concatenate([[0], missing.astype(np.int8), [0]]))
    starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    if not starts.size:
        return {'count': 0, 'longest_ms': 0.0, 'first_s': None}
    return {'count': int(starts.size), 'longest_ms': float(np.max(ends - starts)) * 1e3 / rate,
            'first_s': float(starts[0]) / rate}


def analyze(trial, mode, outputs, statuses, reference):
    """
    The figures of one case.

    Parameters
    ----------
    trial : ext_observer.broad.data.Trial
        As replayed (every sample sent once).
    mode : {'9D', '6D'}
    outputs : tuple
        :func:`decode_outputs` of what the recorder got.
    statuses : list of dict
        The node's statuses (:func:`diagnostics_summary`).
    reference : Recording
        :func:`batch_reference`.

    Returns
    -------
    dict

    """
    from ext_observer.broad.scoring import error_angles, score
    stamps, quaternions, covariances = outputs
    count = len(trial)
    first = stamps_of(1, trial.rate)[0]
    index = np.rint((stamps - first) * trial.rate * 1e-9).astype(np.int64)
    valid = (index >= 0) & (index < count)
    index, quaternions, covariances = index[valid], quaternions[valid], covariances[valid]
    index, unique = np.unique(index, return_index=True)
    quaternions, covariances = quaternions[unique], covariances[unique]
    answered = np.zeros(count, dtype=bool)
    answered[index] = True
    movement = trial.movement
    scored = np.zeros(count, dtype=bool)
    scored[index] = movement[index]
    state = np.full((count, 4), np.nan)
    state[index] = quaternions
    dds = score(state, trial.quat, scored)
    batch = score(reference.quaternions, trial.quat, movement)
    _, heading, inclination = error_angles(quaternions, trial.quat[index])
    keep = movement[index]
    # How far the answered estimates are from the batch run's of the same samples.
    apart = error_angles(quaternions, reference.quaternions[index])[0]
    z2 = {'inclination': _z2(inclination[keep], np.sqrt(2.0 * covariances[keep, 0]))}
    if mode == '9D':
        z2['heading'] = _z2(heading[keep], np.sqrt(covariances[keep, 8]))
    share = len(index) / count
    key = 'total_rmse_deg' if mode == '9D' else 'inclination_rmse_deg'
    last = statuses[-1]['values'] if statuses else {}
    return {'sent': count, 'sent_movement': int(movement.sum()), 'answered': int(len(index)),
            'answered_movement': int(keep.sum()), 'share': share,
            'share_movement': float(keep.sum() / max(1, movement.sum())),
            'lost': loss_by_cause(count, int(len(index)), last),
            'holes': holes(answered, trial.rate),
            'error_key': key, 'dds': dds, 'batch': batch,
            'ratio': dds[key] / batch[key] if batch[key] else math.nan,
            'z2': z2, 'apart_max_deg': math.degrees(float(np.max(apart))) if apart.size
            else math.nan, 'diagnostics': diagnostics_summary(statuses, count - len(index), count)}


# --- the processes -----------------------------------------------------------

@contextlib.contextmanager
def busy_cores(seconds, cores=None):
    """
    One busy loop per core at normal priority for the context (at most ``seconds``).

    Each loop ends by itself after ``seconds`` and once this process is
    gone; the context ends each by its process id on exit.
    """
    procs = []
    try:
        for _ in range(cores or os.cpu_count() or 1):
            procs.append(subprocess.Popen(
                [sys.executable, '-c', BUSY_SOURCE, f'{seconds:.1f}', str(os.getpid())],
                stdin=subprocess.DEVNULL, start_new_session=True))
        yield [p.pid for p in procs]
    finally:
        for p in procs:
            with contextlib.suppress(OSError):
                p.kill()
        for p in procs:
            with contextlib.suppress(subprocess.TimeoutExpired):
                p.wait(5.0)


def node_command(mode):
    """The installed ``imu_filter_node`` (beside this interpreter), ``use_mag`` by ``mode``."""
    return installed_node('imu_filter_node') + [
        '--ros-args', '-p', f'use_mag:={"true" if mode == "9D" else "false"}']


def guarded(command):
    """``command`` (an executable's path first) that ends when this process does."""
    return [sys.executable, '-c', GUARD_SOURCE, str(os.getpid())] + list(command)


def _wait_for(ready, executor, children, timeout, what):
    # Spins the replayer's node meanwhile (its /diagnostics watch).
    deadline = time.monotonic() + timeout
    while not ready():
        for child in children:
            if child.proc.poll() is not None:
                raise RuntimeError(f'{child.name} ended during the {what}{child.log_tail()}')
        if time.monotonic() > deadline:
            raise RuntimeError(f'no {what} within {timeout:g} s'
                               + ''.join(c.log_tail() for c in children))
        executor.spin_once(timeout_sec=0.05)


def replay(messages, imu_pub, mag_pub, rate, speed):
    """
    Publish the messages at ``speed`` × real time; return its timing.

    Returns
    -------
    dict
        ``seconds`` (the replay took), ``nominal`` (it should have taken),
        ``late_max_ms`` (the most a message was published after its time).

    """
    period = 1.0 / (rate * speed)
    publish_imu, publish_mag = imu_pub.publish, mag_pub.publish
    late = 0.0
    start = time.monotonic()
    for k, (imu, field) in enumerate(messages):
        wait = start + k * period - time.monotonic()
        if wait > 0.0:
            time.sleep(wait)
        else:
            late = max(late, -wait)
        publish_imu(imu)
        if field is not None:
            publish_mag(field)
    return {'seconds': time.monotonic() - start, 'nominal': len(messages) * period,
            'late_max_ms': late * 1e3}


def run_case(messages, trial_rate, mode, speed, busy, log_dir, index=0, settle=True):
    """
    Replay ``messages`` into a fresh node once; return what came back and what it cost.

    Returns
    -------
    dict
        ``raws`` (``imu/data`` bytes), ``statuses`` (the node's), ``cpu_s``
        (the node's over the replay and until its output stopped),
        ``replay`` (:func:`replay`), ``load`` (1-minute load average before).

    """
    import rclpy
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import qos_profile_sensor_data
    from sensor_msgs.msg import Imu, MagneticField
    seconds = len(messages) / (trial_rate * speed)
    with contextlib.ExitStack() as stack:
        domain_id = stack.enter_context(reserved_domain_id(index))
        if busy:
            stack.enter_context(busy_cores(seconds + BUSY_MARGIN + SETTLE_TIMEOUT))
        tmp = stack.enter_context(tempfile.TemporaryDirectory(prefix='load-'))
        env = ros_env(domain_id)
        out = os.path.join(tmp, 'record.pickle')
        node = Child('imu_filter_node', guarded(node_command(mode)), env,
                     os.path.join(log_dir, f'load_node_{index}.log'))
        stack.callback(node.stop)
        recorder = Child('recorder', guarded([sys.executable, '-m', 'bench.load_dds', 'record',
                                              out]), env,
                         os.path.join(log_dir, f'load_recorder_{index}.log'))
        stack.callback(recorder.stop)
        os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
        context = rclpy.Context()
        rclpy.init(context=context, domain_id=domain_id)
        stack.callback(rclpy.try_shutdown, context=context)
        driver = rclpy.create_node('load_replayer', context=context)
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(driver)
        imu_pub = driver.create_publisher(Imu, 'imu/data_raw', qos_profile_sensor_data)
        mag_pub = driver.create_publisher(MagneticField, 'imu/mag', qos_profile_sensor_data)
        kernels = []
        watch = watch_kernels(driver, kernels)
        recorder.expect('ready', START_TIMEOUT)

        def connected():
            return (imu_pub.get_subscription_count() > 0
                    and (mode == '6D' or mag_pub.get_subscription_count() > 0)
                    and driver.count_publishers('imu/data') > 0
                    and driver.count_subscribers('imu/data') > 0)

        _wait_for(connected, executor, (node, recorder), START_TIMEOUT, 'connection')
        if settle:
            # Measured as it runs for good: once the compiled kernels are in.
            _wait_for(lambda: on_compiled_kernels(kernels), executor,
                      (node, recorder), SETTLE_TIMEOUT, 'compiled kernels')
        driver.destroy_subscription(watch)
        executor.spin_once(timeout_sec=0.5)  # the node sees the recorder's match
        load_before, cpu_before = load(), cpu_seconds(node.proc.pid)
        start = time.monotonic()
        timing = replay(messages, imu_pub, mag_pub, trial_rate, speed)
        recorder.send('drain')
        recorder.expect('saved', seconds + START_TIMEOUT)
        cpu = cpu_seconds(node.proc.pid) - cpu_before
        with open(out, 'rb') as f:
            recorded = pickle.load(f)
    # CLOCK_MONOTONIC is the machine's: the statuses since the replay began.
    statuses = [s for s in recorded['statuses'] if s['time'] >= start]
    return {'raws': recorded['imu'], 'statuses': statuses, 'cpu_s': cpu,
            'replay': timing, 'load': load_before}


def cases(speeds=SPEEDS, field_rates=FIELD_RATES, loads=LOADS, modes=MODES):
    """The cases in the order they run: ``(load, speed, mode, field_rate)`` (6D: no field)."""
    kinds = [(mode, rate) for mode in modes for rate in (field_rates if mode == '9D' else (None,))]
    return [(load_, speed, mode, rate) for load_ in loads for speed in speeds
            for mode, rate in kinds]


def dds_rows(trial, case_list, log_dir, progress=None, settle=True):
    """
    Run every case of ``case_list`` (:func:`cases`) on ``trial``; return a row each.

    A case that fails is a row with ``error`` (the first line of why); the
    others run on.
    """
    os.makedirs(log_dir, exist_ok=True)
    messages, references, rows = {}, {}, []
    for index, (load_, speed, mode, field_rate) in enumerate(case_list):
        row = {'load': load_, 'speed': speed, 'mode': mode, 'field_rate': field_rate,
               'rate': trial.rate, 'seconds': len(trial) / trial.rate}
        if progress:
            progress(f'DDS case {index + 1}/{len(case_list)}: {load_}, {speed:g}x, {mode}'
                     + (f', field {field_rate}' if field_rate is not None else '') + ' ...')
        kind = (mode, field_rate)
        if kind not in messages:
            messages[kind] = serialized_messages(trial, mode, field_rate)
            references[kind] = batch_reference(trial, mode, field_rate)
        try:
            run = run_case(messages[kind], trial.rate, mode, speed, load_ == 'busy', log_dir,
                           index=index, settle=settle)
        except (RuntimeError, OSError, EOFError) as error:
            row['error'] = (str(error).splitlines() or [type(error).__name__])[0]
            rows.append(row)
            continue
        row.update(analyze(trial, mode, decode_outputs(run['raws']), run['statuses'],
                           references[kind]))
        row['cpu_us_per_sample'] = (run['cpu_s'] / row['answered'] * 1e6 if row['answered']
                                    else math.nan)
        row['replay'], row['load_average'] = run['replay'], run['load']
        rows.append(row)
    return rows


# --- the recorder (a process of its own) -------------------------------------

def _record_main(out):
    """Keep ``imu/data`` (bytes) and the node's statuses until told ``drain``; save them."""
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import QoSProfile
    from sensor_msgs.msg import Imu
    context = rclpy.Context()
    rclpy.init(context=context)
    node = rclpy.create_node('load_recorder', context=context)
    raws, statuses, last = [], [], [time.monotonic()]

    def output(raw):
        raws.append(raw)
        last[0] = time.monotonic()

    def diagnostics(msg):
        for status in msg.status:
            if status.name.split(':')[0].strip().endswith(STATUS_NAME):
                level = status.level  # a byte in rclpy's Python messages
                statuses.append({'time': time.monotonic(), 'message': status.message,
                                 'level': ord(level) if isinstance(level, bytes) else int(level),
                                 'values': {kv.key: kv.value for kv in status.values}})

    node.create_subscription(Imu, 'imu/data', output, QoSProfile(depth=1000), raw=True)
    node.create_subscription(DiagnosticArray, '/diagnostics', diagnostics, 100)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    drain = threading.Event()
    threading.Thread(target=lambda: [drain.set() for line in sys.stdin if
                                     line.strip() == 'drain'], daemon=True).start()
    print('ready', flush=True)
    try:
        while context.ok() and not drain.is_set():
            executor.spin_once(timeout_sec=0.1)
        # Done once the output is quiet and a status came after it (the final counters).
        while context.ok():
            executor.spin_once(timeout_sec=0.05)
            quiet = time.monotonic() - last[0] > QUIET
            if quiet and statuses and statuses[-1]['time'] > last[0] + QUIET:
                break
        with open(out, 'wb') as f:
            pickle.dump({'imu': raws, 'statuses': statuses}, f)
        print('saved', flush=True)
    except KeyboardInterrupt:
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown(context=context)
    return 0


if __name__ == '__main__':
    if sys.argv[1:2] == ['record'] and len(sys.argv) == 3:
        sys.exit(_record_main(sys.argv[2]))
    sys.exit('usage: python -m bench.load_dds record OUT (the recorder of bench/load.py)')
