"""
The commands of README.md and docs/*.md run as written.

Every fenced block in those pages carries a tag that says what it is:

- ``bash``: commands that run here, from the repository's folder after the
  quick start; this test runs every one of them. A command that starts a
  node must come up (its first log line: the node is built, past its
  imports) within :data:`TIMEOUT`, stay up for :data:`STAY_SECONDS`, and
  end with exit code 0 on Ctrl-C (SIGINT); any other command must end with
  exit code 0 within :data:`TIMEOUT`.
- ``shell``: commands that do not run here; each is listed in
  :data:`NOT_RUN` with the reason, and the test fails on one that is not.
- ``python``: Python that runs as it is (in a fresh interpreter of the
  venv), unless listed in :data:`NOT_RUN`.
- ``text``, ``yaml``: output, layouts and file contents, not run.

An untagged block fails the test: a new page must say which of these it is.

Each command runs in the environment its page tells the reader to use:
with ``.venv`` activated after a ``source .venv/bin/activate`` line of its
block, or when the paragraph leading into the block says to run it (names
``source .venv/bin/activate``); else as on a machine whose own Python has
nothing: ``.venv/bin`` is not on ``PATH``, ``python`` and ``python3`` are
an interpreter without packages, and ``pip``, ``pytest`` and the package's
executables are not found (:func:`bare_bin`;
:func:`test_outside_the_venv_nothing_of_the_project_is_found` checks it).
So a command that needs ``.venv`` and is not written so fails here,
whatever the machine has installed; and
:func:`test_a_command_that_needs_the_venv_says_so` fails on one before it runs.
"""

import os
import re
import shlex
import signal
import subprocess
import sys
import time
import venv

import pytest

from conftest import REPO

PAGES = ['README.md'] + sorted(
    os.path.join('docs', name) for name in os.listdir(os.path.join(REPO, 'docs'))
    if name.endswith('.md'))
TAGS = {'bash', 'shell', 'python', 'text', 'yaml'}
# Seconds a command may take, and a node to come up: generous, for a
# machine loaded by the rest of the suite.
TIMEOUT = 120.0
# Seconds a node must stay up once every node of its block is up.
STAY_SECONDS = 1.0
# Seconds a node may take to end on Ctrl-C.
END_SECONDS = 60.0
ACTIVATE = 'source .venv/bin/activate'
# The first line a ROS node logs (rcutils' format): it is built, past its imports.
NODE_LOG_LINE = re.compile(r'^\[(DEBUG|INFO|WARN|ERROR|FATAL)\] \[\d+\.\d+\] \[', re.M)
with open(os.path.join(REPO, 'setup.py'), encoding='utf-8') as _setup:
    EXECUTABLES = tuple(re.findall(r"'(\w+) = ext_observer\.", _setup.read()))
# First words of commands that only run where the venv is: its interpreter,
# its tools and the package's executables.
NEEDS_VENV = ('python', 'python3', 'pip', 'pip3', 'pytest', 'colcon') + EXECUTABLES

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
    'ros2 service': 'ros2cli is not on PyPI; test_imu_filter_node.py calls ~/save_calibration '
                    'with an rclpy client',
    '# before': 'a launch file: ros2 launch (launch_ros) is not on PyPI; test_imu_filter_node.py '
                'starts the node with imu_filter_madgwick\'s parameters instead',
}


def fenced_blocks(page):
    """
    Yield ``(line, tag, text, lead_in)`` of each fenced block of ``page``.

    ``lead_in`` is the paragraph just before the block.
    """
    with open(os.path.join(REPO, page), encoding='utf-8') as file:
        lines = file.read().splitlines()
    start = tag = None
    for number, line in enumerate(lines, 1):
        if not line.startswith('```'):
            continue
        if start is None:
            start, tag = number, line[3:].strip()
        else:
            first = start - 1
            while first > 0 and not lines[first - 1].strip():
                first -= 1
            end = first
            while (first > 0 and lines[first - 1].strip()
                   and not lines[first - 1].startswith('```')):
                first -= 1
            yield start, tag, '\n'.join(lines[start:number - 1]), ' '.join(lines[first:end])
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
            for line, tag, text, _ in fenced_blocks(page)]


def activated_in_words(page, line):
    """Whether the paragraph leading into the block at ``line`` says to activate the venv."""
    lead_in = next(lead for number, _, _, lead in fenced_blocks(page) if number == line)
    return f'`{ACTIVATE}`' in lead_in


def needs_the_venv(command):
    """Whether ``command`` runs a program that only ``.venv`` has (by its first word)."""
    return shlex.split(command)[0] in NEEDS_VENV


def test_every_block_says_what_it_is():
    untagged = [f'{page}:{line}' for page, line, tag, _ in all_blocks() if tag not in TAGS]
    assert not untagged, ('fenced blocks without a tag (bash: run here; shell: not run, '
                          f'listed in NOT_RUN; python; text; yaml): {untagged}')


def test_every_command_not_run_says_why():
    missing = [f'{page}:{line}: {command}' for page, line, tag, text in all_blocks()
               if tag == 'shell' for command in commands(text)
               if reason_not_run(command) is None]
    assert not missing, f'shell commands with no reason in NOT_RUN: {missing}'


@pytest.fixture(scope='session')
def bare_bin(tmp_path_factory):
    """
    A clean machine's programs: the bin folder of a venv without packages.

    ``python`` and ``python3`` there have no packages; the venv's other
    programs (:data:`NEEDS_VENV`) are there as commands that fail, so that
    no copy elsewhere on this machine's ``PATH`` (pyenv's, the system's) is found.
    """
    folder = tmp_path_factory.mktemp('bare') / 'venv'
    venv.EnvBuilder(with_pip=False).create(folder)
    bin_dir = folder / 'bin'
    for name in NEEDS_VENV:
        if not (bin_dir / name).exists():
            (bin_dir / name).write_text(
                f'#!/bin/sh\necho "{name}: not installed outside .venv" >&2\nexit 127\n')
            (bin_dir / name).chmod(0o755)
    return str(bin_dir)


def _environment(ros_domain_id, active, bare_bin):
    env = dict(os.environ, ROS_DOMAIN_ID=str(ros_domain_id),
               ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST', PYTHONUNBUFFERED='1',
               RCUTILS_LOGGING_BUFFERED_STREAM='0', PYTHONFAULTHANDLER='1')
    for name in ('VIRTUAL_ENV', 'PYTHONPATH', 'PYTHONHOME'):
        env.pop(name, None)
    bin_dir = os.path.dirname(sys.executable)
    path = [p for p in env.get('PATH', '').split(os.pathsep)
            if p and os.path.abspath(p) != bin_dir]
    # What `source .venv/bin/activate` does for the commands after it; else
    # the clean machine's programs come first.
    path.insert(0, bin_dir if active else bare_bin)
    if active:
        env['VIRTUAL_ENV'] = os.path.dirname(bin_dir)
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
        # A process that did not end: SIGABRT first, so that faulthandler
        # writes where its threads were into the log the failure shows.
        os.killpg(process.pid, signal.SIGABRT)
        try:
            process.wait(5)
        except subprocess.TimeoutExpired:
            os.killpg(process.pid, signal.SIGKILL)
            process.wait(10)
        return None


def _wait_until_up(nodes, where):
    """Wait for each node's first log line; fail if one ends or :data:`TIMEOUT` passes."""
    deadline = time.monotonic() + TIMEOUT
    waiting = list(nodes)
    while waiting:
        command, process, log, _ = waiting[0]
        output = log.read_text(errors='replace')
        assert process.poll() is None, f'{where}: {command!r} ended early:\n{output}'
        if NODE_LOG_LINE.search(output):
            waiting.pop(0)
            continue
        assert time.monotonic() < deadline, (
            f'{where}: {command!r} not up (no log line) after {TIMEOUT:g} s:\n{output}')
        time.sleep(0.1)


BASH = [(page, line, text) for page, line, tag, text in all_blocks() if tag == 'bash']


def test_a_command_that_needs_the_venv_says_so():
    # A reader who jumps to a block must see that it runs in .venv: in the
    # block (the activate line, or .venv/bin/ in front) or just before it.
    unsaid = []
    for page, line, text in BASH:
        active = activated_in_words(page, line)
        for command in commands(text):
            active = active or command == ACTIVATE
            if not active and needs_the_venv(command):
                unsaid.append(f'{page}:{line}: {command[:60]}')
    assert not unsaid, (f'commands that need .venv with no `{ACTIVATE}` in or just before '
                        f'their block, nor .venv/bin/ in front: {unsaid}')


def test_outside_the_venv_nothing_of_the_project_is_found(ros_domain_id, bare_bin):
    # What makes a command that needs .venv fail outside it, on any machine.
    outside = _environment(ros_domain_id, False, bare_bin)
    inside = _environment(ros_domain_id, True, bare_bin)
    for python in ('python', 'python3'):
        # (ext_observer itself imports from this folder, up to its numpy.)
        for module in ('numpy', 'rclpy', 'ext_observer.core'):
            probe = [python, '-c', f'import {module}']
            assert subprocess.run(probe, cwd=REPO, env=outside,
                                  capture_output=True).returncode != 0, probe
    for name in NEEDS_VENV[2:]:
        done = subprocess.run(['bash', '-c', f'{name} --help'], cwd=REPO, env=outside,
                              capture_output=True, text=True, timeout=TIMEOUT)
        assert done.returncode != 0, (name, done.stdout)
    # The same commands run in the activated venv.
    done = subprocess.run(['bash', '-c', 'python -c "import numpy, ext_observer.core, rclpy" '
                           '&& pytest --version && command -v ' + ' '.join(EXECUTABLES)],
                          cwd=REPO, env=inside, capture_output=True, text=True, timeout=TIMEOUT)
    assert done.returncode == 0, done.stderr
    assert len(EXECUTABLES) >= 4


@pytest.mark.parametrize('page, line, text', BASH, ids=[f'{p}:{n}' for p, n, _ in BASH])
def test_bash_block_runs_as_written(page, line, text, ros_domain_id, bare_bin, tmp_path):
    where = f'{page}:{line}'
    active = activated_in_words(page, line)
    runs = []
    try:
        for index, command in enumerate(commands(text)):
            if command == ACTIVATE:
                active = True
                continue
            assert reason_not_run(command) is None, (
                f'{where}: {command!r} is in NOT_RUN: tag its block shell')
            env = _environment(ros_domain_id, active, bare_bin)
            process, log = _run(command, env, tmp_path, index)
            runs.append((command, process, log, _starts_a_node(command)))
            if not runs[-1][3]:
                code = _end(process, TIMEOUT)
                assert code == 0, (f'{where}: {command!r} ended with {code}:\n'
                                   f'{log.read_text(errors="replace")}')
        # The nodes of the block run side by side: each must come up and stay
        # up, then end cleanly on Ctrl-C.
        nodes = [run for run in runs if run[3]]
        _wait_until_up(nodes, where)
        if nodes:
            time.sleep(STAY_SECONDS)
        for command, process, log, _ in nodes:
            assert process.poll() is None, (f'{where}: {command!r} ended early:\n'
                                            f'{log.read_text(errors="replace")}')
        for _, process, _, _ in nodes:
            os.killpg(process.pid, signal.SIGINT)
        for command, process, log, _ in nodes:
            code = _end(process, END_SECONDS)
            output = log.read_text(errors='replace')
            assert code == 0, f'{where}: {command!r} ended with {code} on Ctrl-C:\n{output}'
            assert 'Traceback' not in output, f'{where}: {command!r}:\n{output}'
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
