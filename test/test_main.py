"""The command line `python -m ext_observer` (its dispatch and the gains command)."""

import json
import subprocess
import sys

import pytest


def test_gains_command_line_json():
    out = subprocess.run(
        [sys.executable, '-m', 'ext_observer', 'gains', '--epsilon', '0.5',
         '--delta', '0.059', '--optimize-delta', '--json'],
        capture_output=True, text=True, timeout=60, check=True).stdout
    result = json.loads(out)
    for key in ('epsilon', 'delta', 'L', 'd', 'b', 'alpha_max', 'delta_opt',
                'alpha_max_opt'):
        assert key in result
    assert result['L'] == pytest.approx(3.69, abs=0.01)
    assert result['alpha_max'] < 0.016
    assert result['alpha_max_opt'] > result['alpha_max']


def test_gains_command_line_refuses_bad_epsilon():
    proc = subprocess.run(
        [sys.executable, '-m', 'ext_observer', 'gains', '--epsilon', '2'],
        capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2
    assert 'epsilon must be in (0, 1)' in proc.stderr
