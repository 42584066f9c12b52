"""
The calibrate command (``recordings/calibrate.py``): the params file of a
calibration and of a gyro bias, read back or refused by what is missing,
recordings read by their extension, the calibration learned offline from
the BROAD excerpt and written, what the command refuses. (The calibration
itself: ``core/ahrs/test_magcal.py``.)
"""

import os

import numpy as np
from numpy.testing import assert_allclose, assert_array_equal
import pytest
import yaml

from conftest import REPO
from ext_observer.recordings import calibrate

DATA = os.path.join(REPO, 'test', 'data')


def test_the_params_file_says_what_it_holds_and_reads_back(tmp_path):
    s = np.array([[1.1, 0.02, 0.0], [0.02, 0.95, 0.0], [0.0, 0.0, 1.0]])
    text = calibrate.params_text(None, None, node='imu', gyro_bias=(0.01, -0.02, 0.0))
    assert yaml.safe_load(text) == {'imu': {'ros__parameters': {
        'gyro_bias_x': 0.01, 'gyro_bias_y': -0.02, 'gyro_bias_z': 0.0}}}
    path = tmp_path / 'cal.yaml'
    calibrate.write_params(str(path), (1e-6, 2e-6, -3e-6), s.ravel(), node='imu',
                           comment='made here')
    assert path.read_text().startswith('# made here\nimu:\n  ros__parameters:\n')
    bias, soft_iron = calibrate.read_params(str(path), node='imu')
    assert_array_equal(bias, [1e-6, 2e-6, -3e-6])
    assert_array_equal(soft_iron, s)


def test_a_params_file_without_the_calibration_is_refused_by_what_is_missing(tmp_path):
    path = tmp_path / 'bias.yaml'
    calibrate.write_params(str(path), None, None, gyro_bias=(0.0, 0.0, 0.0))
    with pytest.raises(ValueError, match=r"missing \['mag_bias_x', 'mag_bias_y', 'mag_bias_z', "
                                         r"'mag_soft_iron'\]"):
        calibrate.read_params(str(path))
    with pytest.raises(ValueError, match='no other: ros__parameters: section'):
        calibrate.read_params(str(path), node='other')


def test_recordings_are_read_by_their_extension(tmp_path):
    path = tmp_path / 'r.npz'
    gyr, acc, mag = np.zeros((5, 3)), np.ones((5, 3)), np.full((5, 3), 2.0)
    np.savez(path, gyr=gyr, acc=acc, mag=mag, rate=100.0)
    g, a, m, rate, unit = calibrate.read_recording(str(path))
    assert_array_equal(m, mag) and rate == 100.0 and unit == 'uT'
    np.savez(tmp_path / 'bad.npz', gyr=gyr, acc=acc)
    with pytest.raises(ValueError, match=r"missing \['mag', 'rate'\]"):
        calibrate.read_recording(str(tmp_path / 'bad.npz'))
    with pytest.raises(ValueError, match=r"no reader for '.txt' files \(known: .hdf5"):
        calibrate.read_recording(str(tmp_path / 'r.txt'))


def test_the_broad_excerpt_with_an_offset_calibrates_offline(tmp_path):
    with np.load(os.path.join(DATA, 'broad_01_undisturbed_slow_rotation_A.npz')) as f:
        gyr, acc, mag, rate = f['gyr'], f['acc'], f['mag'], float(f['rate'])
    norm = float(np.mean(np.linalg.norm(mag, axis=1)))
    b = 1.5 * norm * np.array([0.6, -0.48, 0.64])
    result = calibrate.estimate_calibration(gyr, acc, mag + b, rate)
    assert result.state == 'converged' and result.applied
    assert result.converged_at < 40.0  # of 60 s; the body moves from 10 s on
    assert np.linalg.norm(result.bias - b) < 0.05 * norm
    # The command writes it, in T.
    src = str(tmp_path / 'excerpt.npz')
    np.savez(src, gyr=gyr, acc=acc, mag=mag + b, rate=rate)
    out = str(tmp_path / 'cal.yaml')
    assert calibrate.main(['--data', src, '--out', out]) == 0
    bias, soft_iron = calibrate.read_params(out)
    assert_allclose(bias, result.bias * 1e-6, rtol=1e-12)
    assert_allclose(soft_iron, result.soft_iron, rtol=1e-12)


def test_the_command_refuses_what_it_cannot_use(tmp_path, capsys):
    src = str(tmp_path / 'still.npz')
    n = 2000
    np.savez(src, gyr=np.zeros((n, 3)), acc=np.tile([0.0, 0.0, 9.81], (n, 1)),
             mag=np.tile([20.0, 0.0, -40.0], (n, 1)), rate=100.0)
    out = str(tmp_path / 'cal.yaml')
    # At rest nothing is learned: not converged, no file.
    assert calibrate.main(['--data', src, '--out', out]) == 1
    assert 'not converged' in capsys.readouterr().err and not os.path.exists(out)
    assert calibrate.main(['--data', str(tmp_path / 'x.csv'), '--out', out]) == 2
    assert 'x.csv' in capsys.readouterr().err
    assert calibrate.main(['--data', str(tmp_path / 'x.txt'), '--out', out]) == 2
    assert "no reader for '.txt'" in capsys.readouterr().err
    with pytest.raises(ValueError, match=r'shape \(N, 3\)'):
        calibrate.estimate_calibration(np.zeros((5, 2)), np.zeros((5, 3)), np.zeros((5, 3)),
                                       100.0)
