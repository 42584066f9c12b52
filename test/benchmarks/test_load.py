"""
Checks of the load benchmark's logic (``pytest test/benchmarks/test_load.py``).

The figures of a case from made-up outputs and statuses, the page from
them, the busy loops' own end; and one short case through DDS (a few
seconds of a BROAD excerpt into ``imu_filter_node``).
"""

import math
import os
import signal
import subprocess
import sys
import time
import types

import numpy as np
import psutil
import pytest

from bench import load, load_dds
from docgen import load_page
from ext_observer.broad.data import shown_command
from bench.procs import REPO
from ext_observer.broad.data import Trial

RATE = 200.0
COUNT = 100
HEADING_ERROR = math.radians(2.0)


def _trial():
    movement = np.zeros(COUNT, dtype=bool)
    movement[20:] = True
    identity = np.tile([1.0, 0.0, 0.0, 0.0], (COUNT, 1))
    return Trial('07_made_up', np.zeros((COUNT, 3)), np.tile([0.0, 0.0, 9.81], (COUNT, 1)),
                 np.tile([20.0, 0.0, -40.0], (COUNT, 1)), identity, movement, RATE)


def _turned(count):
    """2° about the world vertical: a heading error alone."""
    return np.tile([math.cos(HEADING_ERROR / 2), 0.0, 0.0, math.sin(HEADING_ERROR / 2)],
                   (count, 1))


def _status(level, message, **values):
    return {'time': 0.0, 'level': level, 'message': message,
            'values': {k: str(v) for k, v in values.items()}}


def _case(statuses, answered=np.arange(40, 90)):
    trial = _trial()
    stamps = np.array(load_dds.stamps_of(COUNT, RATE), dtype=np.int64)[answered]
    covariances = np.zeros((len(answered), 9))
    covariances[:, 0] = 1e-4
    covariances[:, 8] = HEADING_ERROR ** 2
    # One output twice (the recorder saw it twice) and one of another stamp line.
    stamps = np.append(stamps, [stamps[0], stamps[-1] + 10**12])
    quaternions = _turned(len(stamps))
    covariances = np.vstack([covariances, covariances[:2]])
    reference = types.SimpleNamespace(quaternions=_turned(COUNT))
    return load_dds.analyze(trial, '9D', (stamps, quaternions, covariances), statuses,
                            reference)


def test_a_case_counts_its_answers_and_its_losses_by_where_they_happened():
    row = _case([_status(0, 'ok', imu_samples=90, steps=80, dropped_dt_too_large=3)])
    assert row['answered'] == 50 and row['sent'] == COUNT
    assert row['share'] == pytest.approx(0.5)
    assert row['share_movement'] == pytest.approx(50 / 80)
    assert row['lost'] == {'received': 90, 'steps': 80, 'before_node': 10, 'in_node': 10,
                           'after_node': 30, 'node_drops': {'dt_too_large': 3}}
    # The same error as the batch run, which was as wrong on every sample.
    assert row['dds']['total_rmse_deg'] == pytest.approx(2.0)
    assert row['ratio'] == pytest.approx(1.0)
    assert row['z2']['heading'] == pytest.approx(1.0)
    assert row['z2']['inclination'] == pytest.approx(0.0, abs=1e-12)
    assert row['apart_max_deg'] == pytest.approx(0.0, abs=1e-6)
    # Samples 1-39 and 90-99 (sample 0 only starts the time line).
    assert row['holes'] == {'count': 2, 'longest_ms': pytest.approx(39 / RATE * 1e3),
                            'first_s': pytest.approx(1 / RATE)}


def test_a_status_without_the_counters_leaves_the_causes_unknown():
    row = _case([_status(0, 'ok')])
    assert row['lost']['before_node'] is None and row['lost']['after_node'] is None


def test_only_a_warn_that_speaks_of_the_loss_counts():
    calibration = _status(1, 'magnetometer calibration learning: heading held on the gyro')
    row = _case([calibration])
    assert row['diagnostics']['worst'] == 'WARN'
    assert row['diagnostics']['warned_of_loss'] is False
    row = _case([calibration, _status(1, '12 % of the IMU samples lost', samples_lost_share=0.12)])
    assert row['diagnostics']['warned_of_loss'] is True
    assert row['diagnostics']['loss_keys'] == {'samples_lost_share': 0.12}
    # At most 1 % lost: nothing to say.
    row = _case([calibration], answered=np.arange(1, COUNT))
    assert row['diagnostics']['warned_of_loss'] is None


def test_the_field_rows_follow_the_field_rate():
    assert list(load_dds.field_rows(10, 285.7, 'imu')) == list(range(10))
    rows = load_dds.field_rows(2857, 285.7, 100.0)
    assert rows[0] == 0 and len(rows) == 1000
    assert set(np.diff(rows)) <= {2, 3}


def test_a_cut_is_the_part_of_the_trial_asked_for():
    trial = _trial()
    trial.gyr[:, 0] = np.arange(COUNT)
    part = load.cut(trial, 0.1, 0.2)
    assert len(part) == 40 and part.gyr[0, 0] == 20 and part.movement.all()
    assert len(load.cut(trial, 0.25)) == COUNT - 50


def _results(rows, **more):
    results = {'machine': {'commit': 'abc1234', 'date': 'today', 'cores': 2, 'cpu': 'cpu',
                           'python': '3', 'numpy': '2', 'rclpy': '7', 'rmw': 'rmw',
                           'load_start': 1.0, 'load_end': 2.0},
               'command': shown_command(['python -m bench.load', '--json', os.path.join(
                   REPO, 'out', 'load.json')]),
               'seconds': 12.0,
               'dds': {'trial': {'name': '07_made_up', 'samples': COUNT, 'rate': RATE,
                                 'seconds': COUNT / RATE, 'movement': 80}, 'rows': rows}}
    results.update(more)
    return results


def _rows():
    row = _case([_status(1, 'inputs lost', imu_samples=90, steps=80)])
    row.update(load='busy', speed=1.0, mode='9D', field_rate=100.0, rate=RATE,
               cpu_us_per_sample=250.0, replay={'late_max_ms': 1.5}, load_average=2.0)
    failed = {'load': 'idle', 'speed': 4.0, 'mode': '6D', 'field_rate': None, 'rate': RATE,
              'error': 'no connection within 60 s'}
    return [row, failed]


def test_the_page_holds_every_case_the_verdicts_and_no_path_of_this_machine():
    page = load_page.render(_results(_rows()))
    lines = page.splitlines()
    table = [line for line in lines if line.startswith('| busy') or line.startswith('| idle')]
    assert len(table) == 2
    assert '62.5 % / 50.0 %' in table[0] and '10 / 10 / 30' in table[0]
    assert 'failed: no connection' in table[1]
    assert any('lowest 62.5 %, **not met**' in line for line in lines)
    assert 'out/load.json' in page
    assert REPO not in page
    assert 'raw_imu.md#holes-in-the-stream' in page


def test_the_busy_loops_end_by_themselves_and_with_their_context():
    with load_dds.busy_cores(0.5, cores=1) as pids:
        deadline = time.monotonic() + 10.0
        while _alive(pids[0]) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert not _alive(pids[0])
    with load_dds.busy_cores(60.0, cores=1) as pids:
        assert _alive(pids[0])
    assert not _alive(pids[0])


# A parent that starts a busy loop or a guarded process, says its pid, and waits.
_PARENT = {
    'busy': 'with load_dds.busy_cores(60.0, cores=1) as pids:\n'
            '    print(pids[0], flush=True)\n'
            '    time.sleep(60.0)',
    'guarded': 'p = subprocess.Popen(load_dds.guarded(["/bin/sleep", "60"]))\n'
               'print(p.pid, flush=True)\n'
               'time.sleep(60.0)',
}


@pytest.mark.parametrize('kind', sorted(_PARENT))
def test_what_the_benchmark_starts_ends_when_it_is_killed(kind):
    source = 'import subprocess, time\nfrom bench import load_dds\n' + _PARENT[kind]
    parent = subprocess.Popen([sys.executable, '-c', source], cwd=REPO, stdout=subprocess.PIPE,
                              text=True)
    pid = None
    try:
        pid = int(parent.stdout.readline())
        assert _alive(pid)
        parent.kill()
        parent.wait(5.0)
        deadline = time.monotonic() + 5.0
        while _alive(pid) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert not _alive(pid)
    finally:
        parent.kill()
        parent.wait(5.0)
        parent.stdout.close()
        if pid is not None and _alive(pid):
            os.kill(pid, signal.SIGKILL)


def _alive(pid):
    """Running (not a zombie waiting for its parent)."""
    try:
        return psutil.Process(pid).status() != psutil.STATUS_ZOMBIE
    except psutil.Error:
        return False


@pytest.mark.timeout(120)
def test_a_short_case_through_dds_gives_the_batch_runs_estimates(tmp_path):
    pytest.importorskip('rclpy')
    with np.load(os.path.join(REPO, 'test', 'data',
                              'broad_01_undisturbed_slow_rotation_A.npz')) as data:
        start = max(0, int(np.argmax(data['movement'])) - 200)
        cut = slice(start, start + 800)
        trial = Trial('01_excerpt', data['gyr'][cut], data['acc'][cut], data['mag'][cut],
                      data['opt_quat'][cut], data['movement'][cut], float(data['rate']))
    [row] = load_dds.dds_rows(trial, [('idle', 2.0, '9D', 100.0)], str(tmp_path),
                              settle=False)
    assert 'error' not in row, row.get('error')
    assert row['answered'] > 0.5 * row['sent']
    lost = row['lost']
    assert lost['before_node'] + lost['in_node'] + lost['after_node'] == (
        row['sent'] - row['answered'])
    # The node computes what the batch run computes from the same samples.
    if row['answered'] == row['sent'] - 1:
        assert row['apart_max_deg'] < 1e-3
    assert row['cpu_us_per_sample'] > 0.0
    assert row['diagnostics']['statuses'] >= 1
