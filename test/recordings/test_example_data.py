"""
The example-data command (``recordings/example_data.py``): a bag and a CSV
from a shipped excerpt, and the speed measure.
"""

import io
import shutil

from rosbags.rosbag2 import Reader

from recording_excerpt import quiet


def test_example_data_command_and_the_speed_measure(tmp_path):
    from ext_observer.recordings.example_data import main as example_main
    out = io.StringIO()
    # Both sides with the same parameters (here the calibration off).
    params = tmp_path / 'params.yaml'
    params.write_text('imu_filter:\n  ros__parameters:\n    ahrs:\n      mag_cal: false\n')
    assert quiet(example_main, ['--out', str(tmp_path), '--seconds', '2', '--rate', '400',
                                 '--mag-every', '4', '--storage', 'sqlite3', '--no-reference',
                                 '--speed', '--rounds', '1', '--params', str(params)],
                  out) == 0
    text = out.getvalue()
    assert 'sqlite3 bag, 800 IMU samples at 400 Hz, 200 fields: bag command' in text
    assert 'x (wall clock, medians of 1); CPU' in text
    assert "one run in this process: the estimator's process" in text
    with Reader(str(tmp_path / 'broad_01_sqlite3')) as reader:
        assert sorted(c.topic for c in reader.connections) == ['/imu/data_raw', '/imu/mag']
    shutil.rmtree(tmp_path / 'broad_01_sqlite3')
