"""Tests of the reproduction command on a small run (no ROS)."""

import json
import subprocess
import sys

import pytest

from ext_observer.paper import reproduce


@pytest.fixture(scope='module')
def small():
    return reproduce.run(runs=50, epochs=30, seed=1, seeds=2,
                         keep_histories=True)


def test_structure(small):
    rows = {'extended', 'plain', 'projected', 'extended-rotating',
            'plain-scheduled', 'projected-scheduled'}
    assert rows <= set(small['table'])
    assert set(small['table']) == set(small['table_gyro_noise'])
    for row in small['table'].values():
        for column in ('error', 'distance', 'euclidean_distance'):
            assert set(row[column]) == {'mean', 'std', 'max', 'min'}
    assert 'limit' in small and 'limit' not in small['table']
    assert small['limit'] == pytest.approx(0.1 * 1.5958 / 30 ** 0.5, rel=1e-3)
    hist = small['_histories']['exact']['extended']['error']
    assert hist.shape == (31, 50)


def test_extension_keeps_the_estimate_closer_to_s3(small):
    table = small['table']
    assert table['extended']['distance']['mean'] < table['plain']['distance']['mean']
    assert table['projected']['distance']['max'] < 1e-12
    assert (table['extended-scheduled']['distance']['mean']
            < table['plain-scheduled']['distance']['mean'])


def test_figure1_fit_is_within_the_certificate(small):
    f1 = small['figure1']
    assert 0.0 < f1['fitted_factor'] <= f1['certified_factor'] < 1.0


def test_rows_are_not_copies(small):
    means = [row['error']['mean'] for row in small['table'].values()]
    assert len(set(means)) == len(means)


def test_markdown_has_paper_lines(small):
    text = reproduce.markdown_table(small['table'], rows=reproduce.PAPER_ROWS)
    assert '*extended, paper*' in text and '*difference*' in text
    assert text.count('\n') == 2 + 3 * 2 + 1 - 1


def test_command_line_json_and_figures(tmp_path):
    out = tmp_path / 'r.json'
    proc = subprocess.run(
        [sys.executable, '-m', 'ext_observer', 'reproduce', '--runs', '50',
         '--epochs', '30', '--seeds', '2', '--out', str(tmp_path / 'fig'),
         '--json', str(out)],
        capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    result = json.loads(out.read_text())
    assert result['seeds'] == [0, 1]
    assert result['figure1']['certified_factor'] < 1.0
    for name in ('figure1.png', 'figure2.png', 'gain_modes.png'):
        assert (tmp_path / 'fig' / name).stat().st_size > 10000
    assert '[6/6]' in proc.stderr
    assert '| extended |' in proc.stdout


def test_command_line_refuses_bad_options():
    proc = subprocess.run(
        [sys.executable, '-m', 'ext_observer', 'reproduce', '--epochs', '10',
         '--no-plots'], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2
    assert 'must exceed 25' in proc.stderr
