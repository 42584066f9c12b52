"""
Shared fixtures of the ROS tests.

- Every ROS participant started by the suite, in this process or in a child
  process, discovers on localhost only (``ROS_AUTOMATIC_DISCOVERY_RANGE``).
- Each test that uses ROS gets its own ``ROS_DOMAIN_ID`` from
  ``domain_coordinator`` (the way ament's test runner does it), held for the
  whole test, so that parallel test runs on one machine never talk.
- Child processes are started through :func:`ros_processes`, which ends every
  one of them at teardown (SIGINT, then SIGKILL of its process group), also
  when the test failed.

The core tests need none of this; importing rclpy is deferred to the fixtures.
"""

import os
import random
import signal
import subprocess
import time

import pytest

os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
CONFIG = os.path.join(REPO, 'config', 'ext_observer.yaml')


@pytest.fixture
def ros_domain_id():
    """Reserve a ROS domain for this test."""
    from domain_coordinator import domain_id

    rng = random.Random()
    with domain_id(selector=lambda: rng.randint(1, 100)) as reserved:
        yield reserved


@pytest.fixture
def ros_context(ros_domain_id):
    """Return an initialized rclpy context of its own, shut down at teardown."""
    import rclpy
    from rclpy.context import Context

    context = Context()
    rclpy.init(args=[], context=context, domain_id=ros_domain_id)
    try:
        yield context
    finally:
        rclpy.try_shutdown(context=context)


class Spinner:
    """A SingleThreadedExecutor with the nodes of one test."""

    def __init__(self, context):
        from rclpy.executors import SingleThreadedExecutor

        self.context = context
        self.executor = SingleThreadedExecutor(context=context)
        self.nodes = []

    def add(self, node):
        """Add a node; it is destroyed at teardown. Return the node."""
        self.nodes.append(node)
        self.executor.add_node(node)
        return node

    def spin_until(self, predicate, timeout, message='condition'):
        """Spin until ``predicate()`` is true; fail after ``timeout`` seconds."""
        deadline = time.monotonic() + timeout
        while not predicate():
            if time.monotonic() > deadline:
                pytest.fail(f'timed out after {timeout} s waiting for {message}')
            self.executor.spin_once(timeout_sec=0.05)

    def spin_for(self, seconds):
        """Spin for ``seconds``."""
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            self.executor.spin_once(timeout_sec=0.05)

    def close(self):
        """Destroy the nodes."""
        self.executor.shutdown()
        for node in self.nodes:
            node.destroy_node()


@pytest.fixture
def spinner(ros_context):
    """Return a :class:`Spinner` on the test's own context."""
    spinner = Spinner(ros_context)
    try:
        yield spinner
    finally:
        spinner.close()


class RosProcess:
    """A child process whose output goes to a file."""

    def __init__(self, argv, env, log_path):
        self.argv = list(argv)
        self.log_path = log_path
        self._log = open(log_path, 'wb')
        self.process = subprocess.Popen(
            self.argv, env=env, stdin=subprocess.DEVNULL, stdout=self._log,
            stderr=subprocess.STDOUT, start_new_session=True)

    @property
    def output(self):
        """Return everything the process wrote so far."""
        self._log.flush()
        with open(self.log_path, 'rb') as log:
            return log.read().decode(errors='replace')

    def interrupt(self, timeout=10.0):
        """Send SIGINT (Ctrl-C) and wait; return the exit code."""
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGINT)
        return self.wait(timeout)

    def wait(self, timeout):
        """Wait for the end; fail (after killing it) if it takes too long."""
        try:
            return self.process.wait(timeout)
        except subprocess.TimeoutExpired:
            self.kill()
            pytest.fail(f'{self.argv[0]} did not end within {timeout} s:\n{self.output}')

    def kill(self):
        """End the process and its group for good."""
        if self.process.poll() is None:
            try:
                os.killpg(self.process.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
            self.process.wait(10)
        self._log.close()


@pytest.fixture
def ros_processes(ros_domain_id, tmp_path):
    """
    Return ``start(argv, env=None) -> RosProcess``; every process ends at teardown.

    The processes run with the test's ROS domain and localhost discovery.
    """
    started = []

    def start(argv, env=None):
        full_env = dict(os.environ if env is None else env)
        full_env.update(ROS_DOMAIN_ID=str(ros_domain_id),
                        ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST',
                        PYTHONUNBUFFERED='1', RCUTILS_COLORIZED_OUTPUT='0')
        name = os.path.basename(argv[0])
        process = RosProcess(argv, full_env, tmp_path / f'{len(started)}-{name}.log')
        started.append(process)
        return process

    try:
        yield start
    finally:
        for process in started:
            if process.process.poll() is None:
                process.process.send_signal(signal.SIGINT)
        deadline = time.monotonic() + 5.0
        for process in started:
            try:
                process.process.wait(max(0.1, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                pass
            process.kill()


def pytest_sessionstart(session):
    """
    Get the estimator's compiled kernels once, before any test starts a node.

    With numba installed (requirements-test.txt), the first process to ask
    compiles them into the on-disk cache (10 to 25 s on two cores); the
    nodes in this process use them, and node processes started later load
    them from there (about a second, on the plain kernels meanwhile) instead
    of each compiling in the background.
    ``EXT_OBSERVER_COMPILED=0`` skips it (the plain kernels).
    """
    from ext_observer.pipeline.kernel_cache import preload
    preload()
