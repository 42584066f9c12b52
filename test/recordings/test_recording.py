"""
Your own recordings through the Python call
(:func:`~ext_observer.recordings.recording.attitude_from_imu`, on a shipped
BROAD excerpt, ``test/data``, the first 12 s): bad input refused (shapes and
units, time bases), a field at its own times, stamps out of order, repeated
or jumping back dropped and counted as the node does (the bag command
alike), ``imu/data``'s own covariance, the parameters file. The bag and CSV
commands, the codecs, the writer: test_bag.py, test_csvio.py, test_cdr.py,
test_bag_io.py, test_example_data.py beside this file.
"""

import os

import numpy as np
import pytest

from broad_replay import fields_tesla, load, stamps as broad_stamps, TRIALS
from conftest import REPO
from ext_observer.recordings.bag import run_bag
from ext_observer.recordings.example_data import write_bag
from ext_observer.recordings.recording import (attitude_from_imu, node_settings,
                                               parameters_from_yaml)
from recording_excerpt import MAG_EVERY, python_call, read_bag
from recording_excerpt import data, recording  # noqa: F401 (fixtures)


def test_python_call_refuses_shapes_units_and_time_bases(data):
    gyr, acc, rate = data['gyr'], data['acc'], float(data['rate'])
    # Rates in deg/s show once the body turns faster than 35 deg/s.
    moving = load(TRIALS[0])
    cases = [
        (dict(gyr=gyr.T, acc=acc, rate=rate), r'`gyr` to have shape \(N, 3\).*transpose'),
        (dict(gyr=gyr, acc=acc[:-1], rate=rate), 'one row per IMU sample'),
        (dict(gyr=gyr, acc=acc), 'rate .* or its times'),
        (dict(gyr=gyr, acc=acc, rate=rate, times=np.arange(len(gyr)) / rate), 'one of them'),
        (dict(gyr=gyr, acc=acc, rate=-1.0), 'rate must be positive'),
        (dict(gyr=gyr, acc=acc, times=np.r_[0.0, np.nan, np.arange(2, len(gyr))]),
         r'times\[1\] is nan'),
        (dict(gyr=gyr, acc=acc, mag=data['mag'], rate=rate), 'tesla expected.*µT'),
        (dict(gyr=gyr, acc=acc / 9.81, rate=rate), 'acc: .*m/s² expected.*is it g'),
        (dict(gyr=np.degrees(moving['gyr']), acc=moving['acc'], rate=rate),
         'gyr: .*is it deg/s'),
        (dict(gyr=gyr, acc=acc, mag=fields_tesla(data)[::3], rate=rate), 'without mag_times'),
        (dict(gyr=gyr, acc=acc, rate=rate, parameters={'world_frame': 'xyz'}), 'world_frame'),
        (dict(gyr=gyr, acc=acc, rate=rate, parameters={'ahrs.tau_mg': 1.0}),
         "unknown parameter 'ahrs.tau_mg'"),
        (dict(gyr=gyr[:1], acc=acc[:1], rate=rate), 'at least 2'),
    ]
    for kwargs, message in cases:
        with pytest.raises(ValueError, match=message):
            attitude_from_imu(**kwargs)
    # A unit the check refuses runs when asked to, as the node would.
    result = attitude_from_imu(gyr, acc, data['mag'], rate=rate, check_units=False)
    assert result.units['field'][0] == result.counts['fields']
    with pytest.raises(ValueError, match='no estimate from 3 IMU samples.*zero_acceleration 3'):
        attitude_from_imu(gyr[:3], np.zeros((3, 3)), rate=rate, check_units=False)


def test_python_call_field_at_its_own_times_equals_rows_of_nan(data):
    rate = float(data['rate'])
    times = (np.array(broad_stamps(len(data['gyr']), rate)) - 10 ** 12) * 1e-9 + 1.7e3
    rows = python_call(data)
    own = attitude_from_imu(data['gyr'], data['acc'], fields_tesla(data)[::MAG_EVERY],
                            times=times, mag_times=times[::MAG_EVERY])
    np.testing.assert_array_equal(own.ambient, rows.ambient)
    np.testing.assert_array_equal(own.times, times)
    six = attitude_from_imu(data['gyr'], data['acc'], fields_tesla(data)[::MAG_EVERY],
                            times=times, mag_times=times[::MAG_EVERY],
                            parameters={'use_mag': False, 'world_frame': 'ned'})
    assert six.counts['fields'] == 0 and six.world_frame == 'ned'


def _anomalous(recording):
    """A repeated stamp (sample 100), one out of order (200), a jump back by 5 s (from 300)."""
    bad = dict(recording)
    stamps = list(recording['stamps'])
    stamps[100] = stamps[99]
    stamps[200] = stamps[199] - 1000
    stamps[300:] = [stamp - 5_000_000_000 for stamp in stamps[300:]]
    bad['stamps'] = stamps
    return bad


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_bad_stamps_are_dropped_and_counted_as_the_node_does(tmp_path, data, recording,
                                                             storage):
    bad = _anomalous(recording)
    bag = write_bag(str(tmp_path / 'in'), bad, storage)
    run = run_bag(bag, str(tmp_path / 'out'))
    stamps = np.array(bad['stamps'], dtype=np.int64)
    mag = fields_tesla(data).copy()
    mag[np.arange(len(mag)) % MAG_EVERY != 0] = np.nan
    ours = attitude_from_imu(data['gyr'], data['acc'], mag, times=(stamps - stamps[0]) * 1e-9)
    assert run.recording.drops == ours.drops
    # The jump back starts a new time line: the sample waiting is discarded.
    assert {reason: n for reason, n in ours.drops.items() if n} == {
        'duplicate_increment': 1, 'stale_increment': 1, 'discarded_increment': 1}
    assert run.recording.resets['backward_jump'] == ours.resets['backward_jump'] == 1
    np.testing.assert_array_equal(run.recording.ambient, ours.ambient)
    np.testing.assert_array_equal(run.recording.estimated, ours.estimated)
    # Dropped samples and the first of each time line have no estimate of their own.
    assert np.flatnonzero(~ours.estimated).tolist() == [0, 100, 200, 300]
    out = read_bag(str(tmp_path / 'out'))
    assert len(out['/attitude_estimate']) == len(stamps) - 4


@pytest.mark.parametrize('parallel', [True, False])
def test_imu_data_carries_the_estimates_own_covariance_when_the_node_does(
        tmp_path, recording, monkeypatch, parallel):
    """With orientation_covariance_mode 'estimate', imu/data's covariance is the estimate's."""
    import collections
    import ext_observer.recordings.bag as bag_module
    import ext_observer.recordings.bag_worker as worker_module
    from ext_observer.recordings.recording import PipelineRun

    Wide = collections.namedtuple('Wide', 'state covariance')

    class Run(PipelineRun):
        def imu(self, stamp, gyr, acc):
            estimate = super().imu(stamp, gyr, acc)
            return None if estimate is None else Wide(
                estimate.state, tuple(float(k) for k in range(9)))

    settings = node_settings()
    monkeypatch.setattr(bag_module, 'node_settings', lambda *args, **kwargs: dict(
        settings, orientation_covariance_mode='estimate', covariance_estimated=True))
    monkeypatch.setattr(worker_module, 'PipelineRun', Run)
    short = dict(recording, stamps=recording['stamps'][:300],
                 received=recording['received'][:300], gyr=recording['gyr'][:300],
                 acc=recording['acc'][:300], field_index=recording['field_index'][:100])
    bag = write_bag(str(tmp_path / 'in'), short, 'sqlite3', reference=False)
    run = run_bag(bag, str(tmp_path / 'out'), parallel=parallel)
    out = read_bag(str(tmp_path / 'out'))
    assert len(out['/imu/data']) == 299
    for _, msg, _ in out['/imu/data']:
        np.testing.assert_array_equal(msg.orientation_covariance, np.arange(9.0))
    estimates = np.array([[m.quaternion.w, m.quaternion.x, m.quaternion.y, m.quaternion.z]
                          for _, m, _ in out['/attitude_estimate']])
    np.testing.assert_array_equal(estimates, run.recording.ambient[1:])


def test_parameters_file(tmp_path):
    values = parameters_from_yaml(os.path.join(REPO, 'config', 'imu_filter.yaml'))
    assert node_settings(values, strict_types=True) == node_settings()
    path = tmp_path / 'p.yaml'
    path.write_text('imu_filter:\n  ros__parameters:\n    world_frame: ned\n'
                    '    ahrs:\n      tau_mag: 10.0\nother_node:\n  ros__parameters:\n'
                    '    world_frame: nwu\n')
    assert parameters_from_yaml(str(path)) == {'world_frame': 'ned', 'ahrs.tau_mag': 10.0}
    path.write_text('/**:\n  ros__parameters:\n    ahrs.tau_mag: 10\n')
    with pytest.raises(ValueError, match=r'ahrs.tau_mag: a float is expected.*10.0'):
        node_settings(parameters_from_yaml(str(path)), strict_types=True)
    assert node_settings({'ahrs.tau_mag': 10})['ahrs.tau_mag'] == 10.0
    with pytest.raises(ValueError, match=r'orientation_stddev must lie in \[0.0, 10.0\]'):
        node_settings({'orientation_stddev': 11.0})
    path.write_text('camera:\n  other: 1\n')
    with pytest.raises(ValueError, match='no section with ros__parameters'):
        parameters_from_yaml(str(path))


def test_a_params_file_with_mag_frame_rpy_still_runs_with_a_warning(tmp_path):
    # The commands' path (csv, bag: --params): the deprecated spelling taken, warned of.
    path = tmp_path / 'p.yaml'
    path.write_text('/**:\n  ros__parameters:\n    mag_frame_rpy: [0.0, 0.0, 0.5]\n')
    with pytest.warns(FutureWarning, match=r'mag_frame_rpy is deprecated.*mag_mounting \['):
        settings = node_settings(parameters_from_yaml(str(path)), strict_types=True)
    assert settings['mag_frame_rpy'] == [0.0, 0.0, 0.5]
    path.write_text('/**:\n  ros__parameters:\n    mag_frame_rpy: [0.0, 0.0, 0.5]\n'
                    '    mag_mounting: [0.0, 0.0, 0.0, 1.0]\n')
    with pytest.raises(ValueError, match='mag_mounting .* and mag_frame_rpy .* are both set'):
        node_settings(parameters_from_yaml(str(path)), strict_types=True)
