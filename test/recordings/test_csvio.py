"""
The CSV command (``recordings/csvio.py``): the round trip on a BROAD
excerpt, errors that name the column and the line.
"""

import io

import numpy as np
import pytest

from broad_replay import fields_tesla, offline
from ext_observer.recordings.csvio import main as csv_main, read_columns, read_recording
from ext_observer.recordings.example_data import write_csv
from ext_observer.recordings.recording import attitude_from_imu, roll_pitch_yaw
from recording_excerpt import MAG_EVERY, TOLERANCE, python_call, quiet
from recording_excerpt import data, recording  # noqa: F401 (fixtures)


def test_csv_round_trip(tmp_path, data, recording):
    path = write_csv(str(tmp_path / 'in.csv'), recording)
    times, gyr, acc, mag = read_recording(path)
    np.testing.assert_array_equal(gyr, data['gyr'])
    np.testing.assert_array_equal(acc, data['acc'])
    with_field = ~np.isnan(mag).all(axis=1)
    np.testing.assert_array_equal(np.flatnonzero(with_field), recording['field_index'])
    np.testing.assert_array_equal(mag[with_field], fields_tesla(data)[with_field])
    assert quiet(csv_main, [path, '--out', str(tmp_path / 'out.csv'), '--plot',
                             str(tmp_path / 'csv.png')]) == 0
    columns = read_columns(str(tmp_path / 'out.csv'), ('t', 'qw', 'qx', 'qy', 'qz', 'roll',
                                                       'pitch', 'yaw', 'rest', 'mag_disturbed'))
    expected = python_call(data)
    q = np.column_stack([columns[name] for name in ('qw', 'qx', 'qy', 'qz')])
    np.testing.assert_allclose(q, expected.quaternions, rtol=0, atol=1e-12)
    np.testing.assert_allclose(np.column_stack([columns['roll'], columns['pitch'],
                                                columns['yaw']]),
                               roll_pitch_yaw(q), rtol=0, atol=1e-12)
    np.testing.assert_array_equal(columns['t'], times)
    np.testing.assert_array_equal(columns['rest'].astype(bool), expected.rest)
    np.testing.assert_array_equal(columns['mag_disturbed'].astype(bool), expected.mag_disturbed)
    estimates = offline(data, mag_every=MAG_EVERY)[1:]
    np.testing.assert_allclose(q[1:], estimates / np.linalg.norm(estimates, axis=1,
                                                                 keepdims=True),
                               rtol=0, atol=TOLERANCE)
    assert (tmp_path / 'csv.png').stat().st_size > 20000


def test_csv_errors_name_the_column_and_the_line(tmp_path):
    path = tmp_path / 'bad.csv'
    path.write_text('t,gyr_x,gyr_y,gyr_z,acc_x,acc_y\n0,0,0,0,0,0\n')
    err = io.StringIO()
    assert quiet(csv_main, [str(path), '--out', str(tmp_path / 'o.csv')], err) == 2
    assert 'no column acc_z' in err.getvalue()
    path.write_text('t,gyr_x,gyr_y,gyr_z,acc_x,acc_y,acc_z,mag_x\n0,0,0,0,0,0,9.8,1\n')
    with pytest.raises(ValueError, match='no column mag_y, mag_z'):
        read_recording(str(path))
    path.write_text('t,gyr_x,gyr_y,gyr_z,acc_x,acc_y,acc_z\n0,0,0,0,0,0,9.8\n0.01,0,x,0,0,0,9.8\n')
    with pytest.raises(ValueError, match=r"line 3, column gyr_y: 'x' is not a number"):
        read_recording(str(path))
    path.write_text('t,gyr_x,gyr_y,gyr_z,acc_x,acc_y,acc_z\n0,0,0,0,0,0\n')
    with pytest.raises(ValueError, match='line 2: 6 cells, the header has 7'):
        read_recording(str(path))


def test_csv_smooth_writes_the_smoothed_estimate(tmp_path, data, recording):
    path = write_csv(str(tmp_path / 'in.csv'), recording)
    out = io.StringIO()
    assert quiet(csv_main, [path, '--out', str(tmp_path / 'out.csv'), '--smooth'], out) == 0
    assert 'smoothed' in out.getvalue()
    columns = read_columns(str(tmp_path / 'out.csv'), ('qw', 'qx', 'qy', 'qz', 'rest'))
    q = np.column_stack([columns[name] for name in ('qw', 'qx', 'qy', 'qz')])
    times, gyr, acc, mag = read_recording(path)
    expected = attitude_from_imu(gyr, acc, mag, times=times, smooth=True)
    np.testing.assert_allclose(q, expected.quaternions, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(columns['rest'].astype(bool), expected.rest)
    assert np.abs(q - python_call(data).quaternions).max() > 1e-4  # not the online estimate
