"""
The command line ``python -m ext_observer`` (``ext_observer/__main__.py``):
the gains command as a process and in this one, the other commands handed
their own options, ``docs`` without docgen/ one error.
"""

import json
import subprocess
import sys

import pytest

from ext_observer import source_tree
from ext_observer.__main__ import main


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


def test_a_command_with_its_own_options_is_handed_the_rest(capsys):
    # The subcommand parses its own options: an error there is its own, exit 2.
    with pytest.raises(SystemExit) as done:
        main(['demo', '--steps', '0'])
    assert done.value.code == 2 and 'must be positive, got 0' in capsys.readouterr().err
    with pytest.raises(SystemExit) as done:
        main(['gains', '--bogus'])
    assert done.value.code == 2 and 'unrecognized arguments: --bogus' in capsys.readouterr().err


def test_gains_in_process_prints_the_certificate_and_refuses_a_bad_epsilon(capsys):
    assert main(['gains', '--alpha', '0.01']) == 0
    out = capsys.readouterr().out
    assert out.startswith('Gain certificate on S³') and 'certified factor 1 − bc' in out
    assert main(['gains', '--epsilon', '1.5']) == 2
    assert 'error: epsilon must be in (0, 1)' in capsys.readouterr().err


def test_docs_without_docgen_beside_the_package_is_one_error(monkeypatch, capsys, tmp_path):
    monkeypatch.setitem(sys.modules, 'docgen', None)
    monkeypatch.setitem(sys.modules, 'docgen.parameter_tables', None)
    monkeypatch.setattr(source_tree, 'TREE', str(tmp_path))
    assert main(['docs']) == 2
    assert capsys.readouterr().err.startswith('error: writing the docs needs docgen/')
