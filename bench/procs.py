"""
Child processes of the benchmark: environment, domain ids, line control.

Every process that starts a ROS node gets ``ROS_AUTOMATIC_DISCOVERY_RANGE=
LOCALHOST`` and a ``ROS_DOMAIN_ID`` reserved here in the benchmark range
(40–60), with the port convention of ``domain_coordinator`` (a TCP port
bound at 32768 + id) so that concurrent test runs that use it never pick
the same id. Children start in their own session so that the whole group
can be ended, also when the benchmark fails. A process's CPU time comes
from psutil (:func:`cpu_seconds`).
"""

import contextlib
import os
import queue
import signal
import socket
import subprocess
import sys
import threading
import time

import psutil

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DOMAIN_RANGE = range(40, 61)
_PORT_BASE = 32768  # domain_coordinator's convention


@contextlib.contextmanager
def reserved_domain_id(start=0, domains=DOMAIN_RANGE):
    """
    Reserve a ROS_DOMAIN_ID (of ``domains``: 40–60) for the duration of the context.

    Parameters
    ----------
    start : int
        Index in the range to try first (so consecutive targets get fresh
        ids and never see a previous target's lingering endpoints).
    domains : range
        The ids to choose from (another command's own range: stress/ctrl_c.py).

    Yields
    ------
    domain_id : int

    """
    ids = list(domains)
    ids = ids[start % len(ids):] + ids[:start % len(ids)]
    for domain_id in ids:
        sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        try:
            sock.bind(('', _PORT_BASE + domain_id))
        except OSError:
            sock.close()
            continue
        try:
            yield domain_id
        finally:
            sock.close()
        return
    raise RuntimeError(f'no free ROS_DOMAIN_ID in {domains}')


def cpu_seconds(pid):
    """User + system CPU time of a process (all its threads), s; None when it is gone."""
    try:
        times = psutil.Process(pid).cpu_times()
    except psutil.Error:
        return None
    return times.user + times.system


def installed_node(name):
    """The command of the package's executable ``name``: its script beside this Python, or ``-m``."""
    script = os.path.join(os.path.dirname(sys.executable), name)
    return [script] if os.path.exists(script) else [sys.executable, '-m',
                                                   f'ext_observer.nodes.{name}']


def ros_env(domain_id):
    """Return the environment of a child that starts a ROS node."""
    env = dict(os.environ)
    env['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    env['ROS_DOMAIN_ID'] = str(domain_id)
    env['PYTHONUNBUFFERED'] = '1'
    path = env.get('PYTHONPATH')
    env['PYTHONPATH'] = REPO if not path else REPO + os.pathsep + path
    return env


class Child:
    """
    A child process controlled by lines on stdin and stdout.

    Parameters
    ----------
    name : str
        Shown in error messages.
    args : list of str
        Command line (``sys.executable`` is prepended when it starts with
        ``-m``).
    env : dict
    log_path : str
        Where the child's stderr goes.

    """

    def __init__(self, name, args, env, log_path):
        if args[0] == '-m':
            args = [sys.executable] + list(args)
        self.name = name
        self.args = args
        self.log_path = log_path
        self._log = open(log_path, 'wb')
        self.proc = subprocess.Popen(
            args, env=env, cwd=REPO, stdin=subprocess.PIPE,
            stdout=subprocess.PIPE, stderr=self._log, text=True, bufsize=1,
            start_new_session=True)
        self._lines = queue.Queue()
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self):
        for line in self.proc.stdout:
            self._lines.put(line.rstrip('\n'))
        self._lines.put(None)

    def send(self, line):
        """Write one command line to the child."""
        self.proc.stdin.write(line + '\n')
        self.proc.stdin.flush()

    def expect(self, prefix, timeout):
        """
        Wait for a line starting with ``prefix``; return the rest of it.

        Raises
        ------
        RuntimeError
            If the child exits or the line does not come in ``timeout`` s;
            the message ends with the tail of the child's log.

        """
        deadline = time.monotonic() + timeout
        while True:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise RuntimeError(f'{self.name}: no {prefix!r} within '
                                   f'{timeout} s{self.log_tail()}')
            try:
                line = self._lines.get(timeout=remaining)
            except queue.Empty:
                continue
            if line is None:
                raise RuntimeError(f'{self.name} exited with '
                                   f'{self.proc.wait()}{self.log_tail()}')
            if line.startswith(prefix):
                return line[len(prefix):].strip()

    def log_tail(self, lines=15):
        """Return the last lines of the child's stderr, for error messages."""
        try:
            with open(self.log_path, 'rb') as log:
                text = log.read().decode(errors='replace')
        except OSError:
            return ''
        tail = '\n'.join(text.splitlines()[-lines:])
        return f'\n--- {self.log_path} ---\n{tail}' if tail else ''

    def stop(self, timeout=5.0):
        """End the child: SIGINT, then SIGKILL to its group; return the code."""
        if self.proc.poll() is None:
            with contextlib.suppress(OSError):
                self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(timeout)
            except subprocess.TimeoutExpired:
                with contextlib.suppress(OSError):
                    os.killpg(self.proc.pid, signal.SIGKILL)
                self.proc.wait(timeout)
        # The group may hold grandchildren (a console-script wrapper).
        with contextlib.suppress(OSError):
            os.killpg(self.proc.pid, signal.SIGKILL)
        for stream in (self.proc.stdin, self.proc.stdout):
            with contextlib.suppress(OSError):
                stream.close()
        self._log.close()
        return self.proc.returncode


@contextlib.contextmanager
def children():
    """Yield a list to append :class:`Child` objects to; stop all at exit."""
    started = []
    try:
        yield started
    finally:
        for child in reversed(started):
            child.stop()
