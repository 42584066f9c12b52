"""
How a node gets its kernels (``pipeline/kernel_cache.py``): the start plan
from ``EXT_OBSERVER_COMPILED`` and what this process has, the kernels a
process will run. (A node starting plain and switching mid-run, through
DDS: ``test_raw_imu_through_dds.py``.)
"""

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
