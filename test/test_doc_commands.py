"""
The commands of README.md and docs/*.md run as written.

Every fenced block in those pages carries a tag that says what it is:

- ``bash``: commands that run here, from the repository's folder after the
  quick start; this test runs every one of them. A command that starts a
  node must stay up for :data:`UP_SECONDS` and end with exit code 0 on
  Ctrl-C (SIGINT); any other command must end with exit code 0 within
  :data:`TIMEOUT`. ``source .venv/bin/activate`` is applied to the commands
  after it, as in a shell; a page that says its commands are written "as
  after ``source .venv/bin/activate``" runs them so from the start.
- ``shell``: commands that do not run here; each is listed in
  :data:`NOT_RUN` with the reason, and the test fails on one that is not.
- ``python``: Python that runs as it is (in a fresh interpreter of the
  venv), unless listed in :data:`NOT_RUN`.
- ``text``, ``yaml``: output, layouts and file contents, not run.

An untagged block fails the test: a new page must say which of these it is.
"""

import os
import re
import shlex
import signal
import subprocess
import sys
import time

import pytest

from conftest import REPO

PAGES = ['README.md'] + sorted(
    os.path.join('docs', name) for name in os.listdir(os.path.join(REPO, 'docs'))
    if name.endswith('.md'))
TAGS = {'bash', 'shell', 'python', 'text', 'yaml'}
TIMEOUT = 120.0
# How a page says that its commands run in the activated venv.
ACTIVATED = 'as after `source .venv/bin/activate`'
UP_SECONDS = 3.0

# Commands (their first words) and Python blocks (their first line) that do
# not run here, with the reason.
NOT_RUN = {
    'make demo': 'the quick start\'s main job, about 30 s; '
                 'test_processes.py::test_demo_converges_and_writes_the_plot runs the demo it '
                 'runs after installing',
    'make test': 'the suite itself (this test is part of it)',
    'make soak': 'the soak, 70 s; CI runs it after make test',
    'make test-hosts': 'needs root and network namespaces, about 3 minutes; CI runs it',
    'make bench': 'minutes, rewrites docs/performance.md; run by hand',
    'make broad': 'minutes, needs the BROAD files, rewrites docs/broad.md; run by hand',
    'make broad-data': 'fetches BROAD from GitHub: this machine reaches package registries '
                       'only',
    'make reproduce': 'rewrites docs/reproduction.md and its figures; run by hand',
    'python -m ext_observer reproduce': 'rewrites docs/reproduction.md; make reproduce',
    'mkdir -p ~/ws/src': 'a colcon workspace with ROS 2 installed (ros2cli is not on PyPI); '
                         'test_colcon.py builds one in a temporary folder',
    'cd ~/ws': 'the same colcon workspace',
    'source install/setup.bash': 'the same colcon workspace',
    'ros2 run': 'ros2cli is not on PyPI; test_colcon.py runs the installed executable',
    'ros2 service': 'ros2cli is not on PyPI; test_imu_filter.py calls ~/save_calibration '
                    'with an rclpy client',
    '# before': 'a launch file: ros2 launch (launch_ros) is not on PyPI; test_imu_filter.py '
                'starts the node with imu_filter_madgwick\'s parameters instead',
}


def fenced_blocks(page):
    """Yield ``(line, tag, text)`` of each fenced block of ``page``."""
    with open(os.path.join(REPO, page), encoding='utf-8') as file:
        lines = file.read().splitlines()
    start = tag = None
    for number, line in enumerate(lines, 1):
        if not line.startswith('```'):
            continue
        if start is None:
            start, tag = number, line[3:].strip()
        else:
            yield start, tag, '\n'.join(lines[start:number - 1])
            start = None


def commands(text):
    """Return the commands of a shell block: continuations joined, comments dropped."""
    out, current = [], ''
    for line in text.splitlines():
        stripped = line.strip()
        if not current and (not stripped or stripped.startswith('#')):
            continue
        if stripped.endswith('\\'):
            current += stripped[:-1] + ' '
            continue
        out.append((current + stripped).split(' #')[0].strip())
        current = ''
    return out


def reason_not_run(command):
    for prefix, reason in NOT_RUN.items():
        if command.startswith(prefix):
            return reason
    return None


def all_blocks():
    return [(page, line, tag, text) for page in PAGES
            for line, tag, text in fenced_blocks(page)]


def test_every_block_says_what_it_is():
    untagged = [f'{page}:{line}' for page, line, tag, _ in all_blocks() if tag not in TAGS]
    assert not untagged, ('fenced blocks without a tag (bash: run here; shell: not run, '
                          f'listed in NOT_RUN; python; text; yaml): {untagged}')


def test_every_command_not_run_says_why():
    missing = [f'{page}:{line}: {command}' for page, line, tag, text in all_blocks()
               if tag == 'shell' for command in commands(text)
               if reason_not_run(command) is None]
    assert not missing, f'shell commands with no reason in NOT_RUN: {missing}'


def _environment(ros_domain_id, active):
    env = dict(os.environ, ROS_DOMAIN_ID=str(ros_domain_id),
               ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST', PYTHONUNBUFFERED='1')
    env.pop('VIRTUAL_ENV', None)
    bin_dir = os.path.dirname(sys.executable)
    path = [p for p in env.get('PATH', '').split(os.pathsep) if p != bin_dir]
    if active:
        # What `source .venv/bin/activate` does for the commands after it.
        env['VIRTUAL_ENV'] = os.path.dirname(bin_dir)
        path.insert(0, bin_dir)
    env['PATH'] = os.pathsep.join(path)
    return env


def _starts_a_node(command):
    return os.path.basename(shlex.split(command)[0]).endswith('_node')


def _run(command, env, tmp_path, index):
    log = tmp_path / f'{index}.log'
    with open(log, 'wb') as out:
        process = subprocess.Popen(['bash', '-c', command], cwd=REPO, env=env,
                                   stdin=subprocess.DEVNULL, stdout=out,
                                   stderr=subprocess.STDOUT, start_new_session=True)
    return process, log


def _end(process, timeout):
    try:
        return process.wait(timeout)
    except subprocess.TimeoutExpired:
        os.killpg(process.pid, signal.SIGKILL)
        process.wait(10)
        return None


BASH = [(page, line, text) for page, line, tag, text in all_blocks() if tag == 'bash']


@pytest.mark.parametrize('page, line, text', BASH, ids=[f'{p}:{n}' for p, n, _ in BASH])
def test_bash_block_runs_as_written(page, line, text, ros_domain_id, tmp_path):
    with open(os.path.join(REPO, page), encoding='utf-8') as file:
        active = ACTIVATED in ' '.join(file.read().split())
    runs = []
    try:
        for index, command in enumerate(commands(text)):
            if command == 'source .venv/bin/activate':
                active = True
                continue
            assert reason_not_run(command) is None, (
                f'{page}:{line}: {command!r} is in NOT_RUN: tag its block shell')
            env = _environment(ros_domain_id, active)
            process, log = _run(command, env, tmp_path, index)
            runs.append((command, process, log, _starts_a_node(command)))
            if not runs[-1][3]:
                code = _end(process, TIMEOUT)
                assert code == 0, (f'{page}:{line}: {command!r} ended with {code}:\n'
                                   f'{log.read_text(errors="replace")}')
        # The nodes of the block run side by side: each must stay up, then end
        # cleanly on Ctrl-C.
        nodes = [run for run in runs if run[3]]
        deadline = time.monotonic() + UP_SECONDS
        while time.monotonic() < deadline and all(p.poll() is None for _, p, _, _ in nodes):
            time.sleep(0.1)
        for command, process, log, _ in nodes:
            assert process.poll() is None, (f'{page}:{line}: {command!r} ended early:\n'
                                            f'{log.read_text(errors="replace")}')
        for _, process, _, _ in nodes:
            os.killpg(process.pid, signal.SIGINT)
        for command, process, log, _ in nodes:
            code = _end(process, 15.0)
            output = log.read_text(errors='replace')
            assert code == 0, f'{page}:{line}: {command!r} ended with {code} on Ctrl-C:\n{output}'
            assert 'Traceback' not in output, f'{page}:{line}: {command!r}:\n{output}'
    finally:
        # Whatever failed above, no process of the block outlives the test.
        for _, process, _, _ in runs:
            try:
                os.killpg(process.pid, signal.SIGKILL)
            except ProcessLookupError:  # the group has ended
                pass
            process.wait(10)


PYTHON = [(page, line, text) for page, line, tag, text in all_blocks()
          if tag == 'python' and reason_not_run(text.splitlines()[0].strip()) is None]


@pytest.mark.parametrize('page, line, text', PYTHON, ids=[f'{p}:{n}' for p, n, _ in PYTHON])
def test_python_block_runs_as_written(page, line, text, tmp_path):
    result = subprocess.run([sys.executable, '-c', text], cwd=tmp_path, capture_output=True,
                            text=True, timeout=TIMEOUT)
    assert result.returncode == 0, f'{page}:{line}:\n{result.stdout}\n{result.stderr}'


def test_the_commands_are_found():
    # Guards the parser: the pages do hold runnable commands.
    assert len(BASH) >= 5
    assert any(re.search(r'\bimu_filter_node\b', text) for _, _, text in BASH)
