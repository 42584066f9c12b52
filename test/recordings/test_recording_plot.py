"""
The picture of a recording (``recordings/recording_plot.py``): an angle
broken at its wraps so that no line crosses the panel, and the PNG written
for a short recording, with a comparison's panel. (The commands' ``--plot``:
``recordings/test_csvio.py``.)
"""

import numpy as np
from numpy.testing import assert_array_equal
import pytest

from ext_observer.recordings.recording import attitude_from_imu
from ext_observer.recordings.recording_plot import _broken, plot_recording


def test_an_angle_is_broken_where_it_wraps_and_nowhere_else():
    values, jumps = _broken(np.array([170, 179, -179, -170, -90, 90, 100]))
    assert_array_equal(jumps, [1])
    assert_array_equal(values, [170, 179, np.nan, -179, -170, -90, 90, 100])
    values, jumps = _broken(np.array([0, 180, -0.5]))
    assert_array_equal(jumps, [1]) and len(values) == 4


def test_the_png_is_written_with_and_without_a_comparison(tmp_path):
    pytest.importorskip('matplotlib')
    n = 400
    t = np.arange(n) / 100.0
    gyr = np.stack([0 * t, 0 * t, np.where(t > 1.0, 2.0, 0.0)], axis=1)
    acc = np.tile([0.0, 0.0, 9.81], (n, 1))
    recording = attitude_from_imu(gyr, acc, None, rate=100.0)
    plot_recording(recording, str(tmp_path / 'a.png'), title='a turn')
    angles = np.zeros(n)
    comparison = {'topic': '/truth', 'times': recording.times, 'total': angles + 1.0,
                  'heading': angles, 'inclination': angles + 1.0, 'total_rmse_deg': 1.0,
                  'heading_rmse_deg': 0.0, 'inclination_rmse_deg': 1.0, 'matched': n}
    plot_recording(recording, str(tmp_path / 'b.png'), comparison=comparison)
    assert (tmp_path / 'a.png').stat().st_size > 10000
    assert (tmp_path / 'b.png').stat().st_size > (tmp_path / 'a.png').stat().st_size
