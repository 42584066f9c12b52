"""
How a node gets its kernels (``pipeline/kernel_cache.py``): the start plan
from ``EXT_OBSERVER_COMPILED`` and what this process has, the kernels a
process will run. (A node starting plain and switching mid-run, through
DDS: ``test_raw_imu_through_dds.py``.) Stopping a background compile waits
for what cannot be interrupted.
"""

import fcntl
import threading
import time

import pytest

from ext_observer.core.ahrs import compiled
from ext_observer.pipeline import kernel_cache


@pytest.mark.parametrize('value, plan', [('0', 'plain'), ('off', 'plain')])
def test_the_environment_decides_the_plan_when_it_says_so(monkeypatch, value, plan):
    monkeypatch.setenv(compiled.ENV, value)
    assert kernel_cache.start_plan() == plan
    assert not kernel_cache.preload().compiled


def test_auto_compiles_in_the_background_unless_this_process_has_them(monkeypatch):
    monkeypatch.setenv(compiled.ENV, 'auto')
    monkeypatch.setattr(kernel_cache, '_LOADED', None)
    expected = 'background' if compiled.compiled_available() else 'plain'
    assert kernel_cache.start_plan() == expected
    monkeypatch.setattr(kernel_cache, '_LOADED', object())
    assert kernel_cache.start_plan() == 'compiled'
    assert kernel_cache.load() is kernel_cache._LOADED


def test_a_cache_without_numba_is_never_ready(monkeypatch):
    def unavailable():
        raise compiled.CompiledUnavailable('no numba')

    monkeypatch.setattr(compiled, 'compiled_name', unavailable)
    assert kernel_cache.cache_ready() is False


def test_stop_waits_for_a_load_it_cannot_interrupt(monkeypatch):
    # Importing numba and loading the kernels cannot be cut short; a node
    # that exits while its thread is inside them can abort. stop() waits.
    monkeypatch.setattr(kernel_cache, 'cache_ready', lambda: True)

    def slow_load(stopped=None):
        time.sleep(2.5)     # whatever stopped says, as an import
        return object()

    monkeypatch.setattr(kernel_cache, 'load', slow_load)
    compile_ = kernel_cache.BackgroundCompile()
    assert not compile_.compiling
    time.sleep(0.2)
    start = time.monotonic()
    assert compile_.stop() is True
    assert not compile_.running
    assert time.monotonic() - start > 1.5


@pytest.mark.skipif(not compiled.compiled_available(), reason='numba is not installed')
def test_a_stopped_load_does_not_wait_for_another_process_lock(monkeypatch):
    monkeypatch.setattr(kernel_cache, '_LOADED', None)
    lock_path, _ = kernel_cache._paths()
    stopped = threading.Event()
    with open(lock_path, 'a') as held:
        fcntl.flock(held, fcntl.LOCK_EX)    # another open file: as another process
        threading.Timer(0.3, stopped.set).start()
        start = time.monotonic()
        assert kernel_cache.load(stopped) is None
        assert time.monotonic() - start < 5.0
