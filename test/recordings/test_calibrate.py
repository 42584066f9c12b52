"""
The calibrate command's reading and writing (``recordings/calibrate.py``):
the params file of a calibration and of a gyro bias, read back or refused
by what is missing, recordings read by their extension. (The calibration
learned from a recording, offline and as the node would:
``core/ahrs/test_magcal.py``.)
"""

import numpy as np
from numpy.testing import assert_array_equal
import pytest
import yaml

from ext_observer.recordings import calibrate


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
