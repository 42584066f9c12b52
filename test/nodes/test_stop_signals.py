"""
The stop signals of a node's process (``nodes/stop_signals.py``), in a child
process without ROS: a signal is recorded, not raised; a second one ends the
process at once; the executables' entry module imports nothing heavy. (The
nodes stopped by them: ``test_processes.py``.)
"""

import signal
import subprocess
import sys

import pytest

STOPPING = '''
import signal, sys, time
signal.signal(signal.SIGINT, signal.SIG_IGN)    # as a background job starts
from ext_observer.nodes import stop_signals
stop_signals.install()
print('installed', flush=True)
deadline = time.monotonic() + 20.0
while stop_signals.received() is None and time.monotonic() < deadline:
    time.sleep(0.01)
print(f'received {stop_signals.received()!r}', flush=True)
time.sleep(20.0)     # a node that takes long to end
print('ended slowly', flush=True)
'''


def _child(code):
    return subprocess.Popen([sys.executable, '-c', code], stdin=subprocess.DEVNULL,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


@pytest.mark.parametrize('first, second', [(signal.SIGINT, signal.SIGTERM),
                                           (signal.SIGTERM, signal.SIGINT)])
def test_a_signal_is_recorded_and_a_second_one_ends_the_process(first, second):
    child = _child(STOPPING)
    try:
        assert child.stdout.readline().strip() == 'installed'
        child.send_signal(first)
        assert child.stdout.readline().strip() == f'received {signal.Signals(first)!r}'
        child.send_signal(second)
        assert child.wait(10.0) == -second
        rest = child.stdout.read()
        assert 'Traceback' not in rest and 'ended slowly' not in rest
    finally:
        child.kill()
        child.wait(10.0)


def test_the_entry_points_install_the_handlers_before_any_heavy_import():
    code = ('import sys; import ext_observer.nodes.executables; '
            'print(sorted({"rclpy", "numpy", "numba"} & set(sys.modules)))')
    done = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                          timeout=60)
    assert done.stdout.strip() == '[]', done.stderr
