"""
Cross-process tests: the installed executables as separate processes.

The executables are the console scripts pip installed next to this Python
(``make test`` installs the package). A probe node in the test process checks
the pipeline end to end, calls the observer's parameter services, and every
process is ended by the test (SIGINT, checked), or by the fixture on failure.
"""

import os
import re
import signal
import sys
import time

from diagnostic_msgs.msg import DiagnosticStatus
import numpy as np
import pytest
from rcl_interfaces.msg import Parameter as ParameterMsg
from rcl_interfaces.msg import ParameterType, ParameterValue
from rcl_interfaces.srv import GetParameters, SetParameters

from conftest import CONFIG
from ext_observer.core import attitude_error, manifold_distance
from ext_observer.nodes.monitor_node import DIAGNOSTIC_KEYS, ERROR_KEYS, STATUS_NAME
from ext_observer.nodes.node_common import LEVEL_NAMES
from ros_helpers import cpu_seconds, installed, Probe, values_of

# Small nodes run as processes, to see how run_node stops them.
STOP_NODES = os.path.join(os.path.dirname(os.path.abspath(__file__)), 'stop_nodes.py')


def assert_clean_exit(process, code=0):
    output = process.output
    assert process.process.returncode == code, output
    assert 'Traceback' not in output, output


def call(spinner, client, request, timeout=10.0):
    spinner.spin_until(lambda: client.service_is_ready(), timeout,
                       f'the service {client.srv_name}')
    future = client.call_async(request)
    spinner.spin_until(future.done, timeout, f'the answer of {client.srv_name}')
    return future.result()


def wait_for_nodes(spinner, probe, names, timeout=20.0):
    spinner.spin_until(lambda: set(names) <= set(probe.get_node_names()), timeout,
                       f'the nodes {names}')


def test_installed_nodes_end_to_end(ros_processes, ros_context, spinner):
    probe = spinner.add(Probe(ros_context))
    gyro = ros_processes([installed('gyro_node'), '--ros-args', '-p', 'rate_hz:=50.0',
                          '-p', 'seed:=5'])
    observer = ros_processes([
        installed('observer_node'), '--ros-args', '--params-file', CONFIG,
        '-p', 'initial_estimate:=[1.3, 0.0, 0.0, 0.0]', '-p', 'step_period:=0.02',
        '-p', 'diagnostic_period:=0.25'])
    monitor = ros_processes([
        installed('monitor_node'), '--ros-args', '--params-file', CONFIG,
        '-p', 'diagnostic_period:=0.25', '-p', 'window:=20'])
    wait_for_nodes(spinner, probe, ['gyro', 'observer', 'monitor'])
    # Discovery between processes takes its time (up to a few seconds): judge
    # only what arrives once the probe sees the publishers.
    spinner.spin_until(lambda: probe.count_publishers('attitude/ground_truth') > 0
                       and probe.count_publishers('attitude_estimate') > 0, 20.0,
                       'the publishers of gyro and observer')

    def paired():
        return sorted(t for t in probe.estimates if t in probe.truths)

    spinner.spin_until(lambda: len(paired()) >= 120, 40.0,
                       '120 estimates paired with the ground truth')
    spinner.spin_until(
        lambda: ERROR_KEYS[0] in values_of(probe.last_status(STATUS_NAME) or
                                           DiagnosticStatus()), 10.0,
        'a monitor status with the attitude error')

    # Converged: the estimates of the last 30 steps, against the truth.
    late = paired()[-30:]
    estimates = np.array([probe.estimates[t] for t in late])
    truths = np.array([probe.truths[t] for t in late])
    assert np.mean(attitude_error(estimates, truths)) < 0.6
    assert np.mean(manifold_distance(estimates)) < 0.15
    status = probe.last_status(STATUS_NAME)
    assert status.level == DiagnosticStatus.OK, status.message
    assert set(DIAGNOSTIC_KEYS + ERROR_KEYS) <= set(values_of(status))
    assert float(values_of(status)['attitude_error_mean']) < 1.0

    # The parameter services of another process: the file's value, and a refusal.
    getter = probe.create_client(GetParameters, '/observer/get_parameters')
    answer = call(spinner, getter, GetParameters.Request(names=['variant', 'alpha']))
    assert [v.string_value for v in answer.values[:1]] == ['extended']
    assert answer.values[1].double_value == 0.01
    setter = probe.create_client(SetParameters, '/observer/set_parameters')
    request = SetParameters.Request(parameters=[ParameterMsg(
        name='alpha', value=ParameterValue(type=ParameterType.PARAMETER_DOUBLE,
                                           double_value=0.5))])
    [result] = call(spinner, setter, request).results
    assert not result.successful
    assert 'outside the range certified by Theorem 1' in result.reason

    # Ctrl-C: every node exits 0 without a traceback.
    for process in (gyro, observer, monitor):
        process.interrupt(timeout=10.0)
        assert_clean_exit(process)
    # The monitor said at start-up what it watches.
    assert 'watching /attitude_estimate (distance to S³' in monitor.output
    # The gyro's last word is its count, at least every truth the probe got.
    [count] = re.findall(r'stopping: (\d+) steps published', gyro.output)
    assert int(count) >= len(probe.truths)


@pytest.mark.parametrize('name, executor', [
    ('gyro_node', []), ('observer_node', []), ('monitor_node', []),
    ('observer_node', ['--executor', 'single']), ('gyro_node', ['--executor=single'])])
def test_ctrl_c_on_an_idle_node_exits_cleanly(ros_processes, ros_context, spinner, name,
                                              executor):
    probe = spinner.add(Probe(ros_context))
    process = ros_processes([installed(name)] + executor)
    wait_for_nodes(spinner, probe, [name[:-len('_node')]])
    spinner.spin_for(0.3)
    process.interrupt(timeout=10.0)
    assert_clean_exit(process)


def main_thread_schedule(pid):
    """Return the main thread's time running and time runnable but waiting, s."""
    with open(f'/proc/{pid}/task/{pid}/schedstat') as stat:
        running, waiting, _ = map(int, stat.read().split())
    return running * 1e-9, waiting * 1e-9


def test_idle_node_on_the_events_executor_sleeps(ros_processes, ros_context, spinner):
    # rclpy 7.1's EventsExecutor burns a core when spun without a timeout;
    # run_node spins it with spin_once(timeout_sec=0.1). Measured here: about
    # 0.01 core for an idle observer (its 40 Hz timeout timer and 2 Hz
    # subscriber check), 0.03 on the SingleThreadedExecutor.
    probe = spinner.add(Probe(ros_context))
    process = ros_processes([installed('observer_node')])
    wait_for_nodes(spinner, probe, ['observer'])
    # Started: its first status is out (the start-up's work is done).
    spinner.spin_until(lambda: probe.last_status('observer: inputs') is not None, 20.0,
                       "the observer's first status")
    pid = process.process.pid
    # Windows of 2 s until one shows the node idle, for at most 30 s: on a
    # loaded machine a window may still hold the tail of the start-up. A
    # spinning executor never passes: it uses a core, or, starved by other
    # processes, its main thread is still running or waiting for a CPU most
    # of the time (0.6 of each window with spin_once(timeout_sec=0) here, at
    # a load of 7 on 2 cores; an idle observer 0.01).
    deadline = time.monotonic() + 30.0
    windows = []
    while True:
        cpu, schedule, start = cpu_seconds(pid), main_thread_schedule(pid), time.monotonic()
        time.sleep(2.0)
        wall = time.monotonic() - start
        cores = (cpu_seconds(pid) - cpu) / wall
        busy = sum(after - before for after, before in zip(main_thread_schedule(pid),
                                                            schedule)) / wall
        windows.append((round(cores, 3), round(busy, 3)))
        if cores < 0.15 and busy < 0.3:
            break
        assert time.monotonic() < deadline, (
            f'an idle observer used (cores, main thread running or runnable) {windows}')
    process.interrupt(timeout=10.0)
    assert_clean_exit(process)


def test_unknown_executor_is_refused(ros_processes):
    process = ros_processes([installed('observer_node'), '--executor', 'multi'])
    process.wait(timeout=20.0)
    assert_clean_exit(process, code=2)
    assert "--executor must be one of ('events', 'single')" in process.output


def as_background_job(argv):
    """Return ``argv`` run as ``argv &`` in a shell script runs it: SIGINT ignored."""
    return [sys.executable, '-c', 'import os, signal, sys; '
            'signal.signal(signal.SIGINT, signal.SIG_IGN); os.execv(sys.argv[1], sys.argv[1:])',
            *argv]


def test_ctrl_c_on_busy_nodes_exits_cleanly(ros_processes, ros_context, spinner):
    # At 2 kHz a callback is publishing most of the time when Ctrl-C comes:
    # the node stops between two callbacks, its context still up (the gyro
    # runs as a background job, started with SIGINT ignored: run_node
    # handles it).
    probe = spinner.add(Probe(ros_context))
    observer = ros_processes([installed('observer_node'), '--ros-args',
                              '-p', 'queue_depth:=100'])
    wait_for_nodes(spinner, probe, ['observer'])
    gyro = ros_processes(as_background_job([
        installed('gyro_node'), '--ros-args', '-p', 'rate_hz:=2000.0',
        '-p', 'queue_depth:=100', '-p', 'wait_for_subscribers:=1']))
    spinner.spin_until(lambda: len(probe.estimates) > 500, 20.0, 'a busy pipeline')
    for process in (gyro, observer):
        process.interrupt(timeout=10.0)
        assert_clean_exit(process)


def test_a_background_jobs_node_ends_on_ctrl_c(ros_processes):
    # Started with SIGINT ignored, a node had only rclpy's signal thread to
    # end it; run_node handles SIGINT itself, so that Ctrl-C ends it as in a
    # terminal.
    process = ros_processes(as_background_job([sys.executable, STOP_NODES, 'background']))
    wait_for_output(process, 'the node handles SIGINT:', 30.0)
    assert 'the node handles SIGINT: True' in process.output
    process.interrupt(timeout=10.0)
    assert_clean_exit(process)


def numpy_loaded(pid):
    """Whether numpy's compiled core is mapped in process ``pid`` (it imports)."""
    with open(f'/proc/{pid}/maps') as maps:
        return '_multiarray_umath' in maps.read()


@pytest.mark.parametrize('signum', [signal.SIGINT, signal.SIGTERM])
def test_a_stop_signal_while_the_node_imports_ends_it_cleanly(ros_processes, signum):
    # The executable sets its stop handlers before it imports its node: a
    # signal among the imports (numpy loaded, rclpy and the node's modules
    # still to come) stops it before it starts, with exit code 0. Python's
    # own handling raised KeyboardInterrupt there (a traceback), and
    # SIGTERM killed the process.
    process = ros_processes([installed('imu_filter_node')])
    pid = process.process.pid
    deadline = time.monotonic() + 30.0
    while not numpy_loaded(pid):
        assert process.process.poll() is None, process.output
        assert time.monotonic() < deadline, f'numpy not loaded within 30 s:\n{process.output}'
        time.sleep(0.002)
    process.process.send_signal(signum)
    process.wait(timeout=20.0)
    assert_clean_exit(process)
    assert '[imu_filter]' not in process.output, 'the node had started'


@pytest.mark.parametrize('executor', [[], ['--executor', 'single']])
@pytest.mark.parametrize('signum', [signal.SIGINT, signal.SIGTERM])
def test_a_stop_signal_shuts_the_context_down_last(ros_processes, executor, signum):
    # A node publishing at 1 kHz: the signal stops the executor, the node is
    # destroyed with the context still up, and only then does the context go
    # down. With rclpy's own handlers it went down first, under the spinning
    # executor and the callback publishing.
    process = ros_processes([sys.executable, STOP_NODES, 'ordered'] + executor)
    wait_for_output(process, 'spinning', 30.0)
    process.process.send_signal(signum)
    process.wait(timeout=20.0)
    assert_clean_exit(process)
    output = process.output
    assert 'destroy_node, context up: True' in output, output
    assert output.index('destroy_node') < output.index('context shut down'), output


@pytest.mark.parametrize('executor', [[], ['--executor', 'single']])
def test_sigterm_on_a_running_node_exits_cleanly(ros_processes, ros_context, spinner,
                                                 executor):
    probe = spinner.add(Probe(ros_context))
    process = ros_processes([installed('imu_filter_node')] + executor)
    wait_for_nodes(spinner, probe, ['imu_filter'])
    spinner.spin_for(0.3)
    process.process.send_signal(signal.SIGTERM)
    process.wait(timeout=20.0)
    assert_clean_exit(process)


@pytest.mark.parametrize('executor', [[], ['--executor', 'single']])
@pytest.mark.parametrize('how', ['callback', 'thread'])
def test_run_node_ends_cleanly_when_the_context_goes_down(ros_processes, how, executor):
    # A shutdown from a callback: publishing after it raises RCLError inside
    # spin, which run_node takes as the end it is. And a shutdown from
    # another thread (rclpy 7.1's EventsExecutor hangs when shut down from
    # another thread unless spun with a finite timeout).
    process = ros_processes([sys.executable, STOP_NODES, 'busy', how] + executor)
    process.wait(timeout=20.0)
    assert_clean_exit(process)


def test_invalid_start_up_parameter_exits_with_the_reason(ros_processes):
    process = ros_processes([installed('observer_node'), '--ros-args', '-p', 'alpha:=0.5'])
    process.wait(timeout=20.0)
    assert_clean_exit(process, code=2)
    assert 'outside the range certified by Theorem 1' in process.output
    assert 'allow_uncertified_alpha' in process.output


def wait_for_output(process, text, timeout):
    deadline = time.monotonic() + timeout
    while text not in process.output:
        assert process.process.poll() is None, process.output
        if time.monotonic() > deadline:
            pytest.fail(f'no {text!r} within {timeout} s:\n{process.output}')
        time.sleep(0.1)


def test_demo_converges_and_writes_the_plot(ros_processes, tmp_path):
    plot = tmp_path / 'demo.png'
    process = ros_processes([sys.executable, '-m', 'ext_observer', 'demo', '--steps', '60',
                             '--rate', '60', '--plot', str(plot)])
    process.wait(timeout=60.0)
    assert_clean_exit(process)
    output = process.output
    assert 'monitor OK' in output or 'monitor WARN' in output
    assert 'Summary: 60 steps' in output
    assert 'distance to S³' in output and 'attitude error (rad)' in output
    assert output.rstrip().endswith('converged')
    with open(plot, 'rb') as png:
        assert png.read(8) == b'\x89PNG\r\n\x1a\n'


def test_ctrl_c_on_the_demo_exits_cleanly(ros_processes):
    process = ros_processes([sys.executable, '-m', 'ext_observer', 'demo', '--steps',
                             '10000', '--plot', ''])
    wait_for_output(process, 'monitor', 30.0)
    assert process.interrupt(timeout=15.0) == 130
    assert 'interrupted' in process.output
    assert 'Traceback' not in process.output


# Faults: a process killed and restarted ------------------------------------------

def wait_for_level(spinner, probe, level, timeout, after=0):
    """Wait for a monitor status of ``level`` among those after the ``after``-th."""
    spinner.spin_until(
        lambda: any(s.level == level for s in probe.statuses.get(STATUS_NAME, [])[after:]),
        timeout, f'the monitor at {LEVEL_NAMES[level]}')


def converged_after(spinner, probe, since, steps=100, timeout=40.0):
    """Wait until, after stamp ``since``, at least ``steps`` estimates are paired
    with the truth and the last 30 of them are within 0.6 rad of it.

    Not "converged by step 100": a process that joins late may match the
    gyro's increments before its measurements (Fast DDS discovers each topic
    on its own; on a loaded machine that took seconds once), and until then
    the observer only propagates. The timeout bounds the wait.
    """
    def paired():
        return sorted(t for t in probe.estimates if t in probe.truths and t > since)

    def late_error():
        late = paired()
        if len(late) < steps:
            return np.inf
        late = late[-30:]
        return np.mean(attitude_error(np.array([probe.estimates[t] for t in late]),
                                      np.array([probe.truths[t] for t in late])))

    deadline = time.monotonic() + timeout
    while late_error() >= 0.6:
        if time.monotonic() > deadline:
            status = probe.last_status('observer: inputs')
            pytest.fail(f'not converged within {timeout} s: {len(paired())} estimates paired, '
                        f'mean error of the last 30 {late_error():.3f} rad; observer inputs '
                        f'{values_of(status) if status else "(no status)"}')
        spinner.spin_for(0.05)
    assert all(np.isfinite(q).all() for q in map(np.array, probe.estimates.values()))


def start_pipeline(ros_processes):
    gyro = ros_processes([installed('gyro_node'), '--ros-args', '-p', 'rate_hz:=50.0',
                          '-p', 'seed:=5'])
    monitor = ros_processes([
        installed('monitor_node'), '--ros-args', '-p', 'diagnostic_period:=0.2',
        '-p', 'window:=20', '-p', 'stale_timeout:=1.0'])
    return gyro, monitor, start_observer(ros_processes)


def start_observer(ros_processes):
    return ros_processes([
        installed('observer_node'), '--ros-args', '-p', 'initial_estimate:=[1.3, 0.0, 0.0, 0.0]',
        '-p', 'step_period:=0.02', '-p', 'diagnostic_period:=0.2'])


def test_gyro_killed_and_restarted(ros_processes, ros_context, spinner):
    probe = spinner.add(Probe(ros_context))
    gyro, monitor, observer = start_pipeline(ros_processes)
    wait_for_nodes(spinner, probe, ['gyro', 'observer', 'monitor'])
    converged_after(spinner, probe, 0)
    wait_for_level(spinner, probe, DiagnosticStatus.OK, 10.0)

    # SIGKILL mid-run: no goodbye on the graph. The monitor goes STALE; the
    # observer stays up.
    gyro.kill()
    last_before = max(probe.truths)
    seen = len(probe.statuses.get(STATUS_NAME, []))
    wait_for_level(spinner, probe, DiagnosticStatus.STALE, 10.0, after=seen)
    assert observer.process.poll() is None and monitor.process.poll() is None

    # A new gyro (another seed: another truth): the observer resumes on the new
    # stamps (a forward gap, propagated) and converges to the new truth; the
    # monitor is OK again.
    ros_processes([installed('gyro_node'), '--ros-args', '-p', 'rate_hz:=50.0',
                   '-p', 'seed:=6'])
    seen = len(probe.statuses.get(STATUS_NAME, []))
    converged_after(spinner, probe, last_before)
    # A bound, not a speed: the monitor's window must fill with the new estimates.
    wait_for_level(spinner, probe, DiagnosticStatus.OK, 30.0, after=seen)
    spinner.spin_until(lambda: int(values_of(probe.last_status('observer: inputs')).get(
        'forward_gaps', 0)) >= 1, 5.0, 'the forward gap in the diagnostics')
    values = values_of(probe.last_status('observer: inputs'))
    assert int(values['inputs_received']) == (
        int(values['inputs_processed']) + int(values['inputs_dropped'])
        + int(values['inputs_waiting']))
    observer.interrupt(timeout=10.0)
    assert_clean_exit(observer)


def test_observer_killed_and_restarted_starts_over(ros_processes, ros_context, spinner):
    probe = spinner.add(Probe(ros_context))
    gyro, monitor, observer = start_pipeline(ros_processes)
    wait_for_nodes(spinner, probe, ['gyro', 'observer', 'monitor'])
    converged_after(spinner, probe, 0)

    observer.kill()
    last_before = max(probe.estimates)
    seen = len(probe.statuses.get(STATUS_NAME, []))
    wait_for_level(spinner, probe, DiagnosticStatus.STALE, 10.0, after=seen)
    assert gyro.process.poll() is None and monitor.process.poll() is None

    # The new observer starts over (its counters from zero, its estimate from
    # initial_estimate) and converges.
    probe.statuses.pop('observer: inputs', None)
    start_observer(ros_processes)
    seen = len(probe.statuses.get(STATUS_NAME, []))
    converged_after(spinner, probe, last_before)
    # A bound, not a speed: the monitor's window must fill with the new estimates.
    wait_for_level(spinner, probe, DiagnosticStatus.OK, 30.0, after=seen)
    # Its counters start from zero too: no more steps than the gyro made since
    # (give or take 50, 1 s of truths still on their way to the probe; the
    # first observer had made 100 or more).
    count = len(probe.statuses['observer: inputs'])
    spinner.spin_until(lambda: len(probe.statuses['observer: inputs']) > count, 5.0,
                       'a fresh observer status')
    steps_after = int(values_of(probe.last_status('observer: inputs'))['steps'])
    assert steps_after <= (max(probe.truths) - last_before) * 50 // 10 ** 9 + 50
