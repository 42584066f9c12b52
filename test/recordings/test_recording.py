"""
Your own recordings: the Python call, the bag command and the CSV command.

A bag written from a shipped BROAD excerpt (``test/data``, the first
12 s), in both storage formats, goes through the bag command; its
``attitude_estimate`` and ``imu/data``, read back with ``rosbags``' own
deserializer, equal :func:`~ext_observer.recordings.recording.attitude_from_imu` on the
same arrays and ``test/broad_replay.py``'s offline run (which
``test_raw_imu.py`` proves equal to the node through DDS). ``--compare``
against the optical reference as a topic gives the scores
:mod:`ext_observer.broad` computes for the same samples. Then the CSV round
trip, the parameters file, the codecs against ``rosbags``, the batched
writer against ``Writer.write``, and bad input: shapes and units, stamps out
of order, repeated or jumping back, missing topics, a topic of another type,
truncated bags and messages, an existing output.
"""

import hashlib
import io
import os
import shutil

import numpy as np
import pytest
from rosbags.rosbag2 import Reader
from rosbags.typesys import get_typestore, Stores

from broad_replay import fields_tesla, load, offline, stamps as broad_stamps, TRIALS
from conftest import REPO
from ext_observer.core.ahrs.estimator import AhrsParams
from ext_observer.recordings import bag_io
from ext_observer.recordings import cdr
from ext_observer.recordings.bag import _Progress, compare, main as bag_main, run_bag
from ext_observer.broad import score
from ext_observer.recordings.csvio import main as csv_main, read_columns, read_recording
from ext_observer.recordings.example_data import excerpt, LATENCY, REFERENCE_TOPIC, write_bag, write_csv
from ext_observer.recordings.recording import (attitude_from_imu, node_settings, parameters_from_yaml,
                                    roll_pitch_yaw)

TYPESTORE = get_typestore(Stores.ROS2_JAZZY)
# The same float code on the same float64 values in the same order: equal
# to rounding (measured: 0, bit for bit).
TOLERANCE = 1e-9
SECONDS = 12.0  # of the excerpt: 10 s of rest, then 2 s of movement
MAG_EVERY = 3


def _first(data, seconds):
    """The excerpt cut to its first ``seconds``, as broad_replay reads it."""
    count = int(round(seconds * float(data['rate'])))
    return {key: (value[:count] if np.ndim(value) else value) for key, value in data.items()}


def _read_bag(path):
    """Every message of a bag, deserialized by rosbags: {topic: [(received, msg, raw)]}."""
    out = {}
    with Reader(path) as reader:
        for connection, received, raw in reader.messages():
            out.setdefault(connection.topic, []).append(
                (received, TYPESTORE.deserialize_cdr(raw, connection.msgtype), bytes(raw)))
    return out


def _stamp(msg):
    return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec


def _files_digest(path):
    digest = hashlib.sha256()
    for root, _, names in sorted(os.walk(path)):
        for name in sorted(names):
            with open(os.path.join(root, name), 'rb') as stream:
                digest.update(stream.read())
    return digest.hexdigest()


@pytest.fixture(scope='module')
def data():
    return _first(load(TRIALS[0]), SECONDS)


@pytest.fixture(scope='module')
def recording(data):
    """The excerpt as example_data makes it (the field with every third sample)."""
    return excerpt(data, mag_every=MAG_EVERY)


def _python_call(data, parameters=None):
    mag = fields_tesla(data).copy()
    mag[np.arange(len(mag)) % MAG_EVERY != 0] = np.nan
    return attitude_from_imu(data['gyr'], data['acc'], mag, rate=float(data['rate']),
                             parameters=parameters)


# The shipped defaults, and the other side of each choice the comparison
# below branches on: the calibration off, the covariance orientation_stddev's.
NOT_DEFAULT = {'ahrs.mag_cal': False, 'orientation_covariance_mode': 'fixed'}


@pytest.mark.parametrize('storage, parallel, parameters', [('mcap', True, None),
                                                            ('sqlite3', False, None),
                                                            ('mcap', False, NOT_DEFAULT)])
def test_bag_equals_python_call_and_offline(tmp_path, data, recording, storage, parallel,
                                            parameters):
    bag = write_bag(str(tmp_path / 'in'), recording, storage)
    digest = _files_digest(bag)
    run = run_bag(bag, str(tmp_path / 'out'), parameters=parameters, parallel=parallel)
    assert _files_digest(bag) == digest  # the input is only read
    out = _read_bag(str(tmp_path / 'out'))
    count = len(data['gyr'])
    mag_cal = (parameters or {}).get('ahrs.mag_cal', True)
    expected = offline(data, mag_every=MAG_EVERY, params=AhrsParams(mag_cal=mag_cal))[1:]
    ours = _python_call(data, parameters)
    np.testing.assert_allclose(ours.ambient[1:], expected, rtol=0, atol=TOLERANCE)
    assert not ours.estimated[0] and ours.estimated[1:].all()

    # attitude_estimate: the ambient estimate, stamped like its sample.
    estimates = out['/attitude_estimate']
    assert len(estimates) == count - 1
    ambient = np.array([[m.quaternion.w, m.quaternion.x, m.quaternion.y, m.quaternion.z]
                        for _, m, _ in estimates])
    np.testing.assert_allclose(ambient, expected, rtol=0, atol=TOLERANCE)
    assert [_stamp(m) for _, m, _ in estimates] == recording['stamps'][1:]
    assert {m.header.frame_id for _, m, _ in estimates} == {'world'}
    # imu/data: the input sample, its orientation the normalized estimate.
    inputs = out['/imu/data_raw']
    data_msgs = out['/imu/data']
    assert len(inputs) == count and len(data_msgs) == count - 1
    unit = expected / np.linalg.norm(expected, axis=1, keepdims=True)
    orientation = np.array([[m.orientation.w, m.orientation.x, m.orientation.y,
                             m.orientation.z] for _, m, _ in data_msgs])
    np.testing.assert_allclose(orientation, unit, rtol=0, atol=TOLERANCE)
    for (received, raw_in, _), (received_out, msg, _) in zip(inputs[1:], data_msgs):
        assert received_out == received and _stamp(msg) == _stamp(raw_in)
        assert msg.header.frame_id == raw_in.header.frame_id == 'imu_link'
        np.testing.assert_array_equal(msg.angular_velocity_covariance,
                                      raw_in.angular_velocity_covariance)
        assert (msg.linear_acceleration.z, msg.angular_velocity.x) == (
            raw_in.linear_acceleration.z, raw_in.angular_velocity.x)
    if not node_settings(parameters)['covariance_estimated']:
        # orientation_stddev's (the estimate's own: test_imu_data_carries_...).
        for _, msg, _ in data_msgs:
            np.testing.assert_array_equal(msg.orientation_covariance,
                                          np.diag([0.05 ** 2] * 3).ravel())
    else:
        covariance = np.array([m.orientation_covariance for _, m, _ in data_msgs])
        assert np.isfinite(covariance).all() and (covariance[:, [0, 4, 8]] > 0).all()
        assert len({tuple(c) for c in covariance}) > 1  # the estimate's own, it changes
    # The input topics are copied as they were, at their receive times.
    with Reader(bag) as reader:
        original = {c.topic: [(t, bytes(raw)) for _, t, raw in reader.messages([c])]
                    for c in reader.connections}
    for topic in ('/imu/data_raw', '/imu/mag'):
        assert [(t, raw) for t, _, raw in out[topic]] == original[topic]
    assert run.recording.counts == {'imu_samples': count, 'fields': len(out['/imu/mag']),
                                    'fields_used': len(out['/imu/mag']),
                                    'estimates': count - 1}
    np.testing.assert_array_equal(run.recording.quaternions, ours.quaternions)
    np.testing.assert_array_equal(run.recording.rest, ours.rest)
    np.testing.assert_array_equal(run.recording.mag_disturbed, ours.mag_disturbed)
    # The magnetometer calibration's state after each sample: 'off'
    # throughout with mag_cal off, learning from the start with it on.
    np.testing.assert_array_equal(run.recording.calibration, ours.calibration)
    if mag_cal:
        assert 'learning' in set(ours.calibration) <= {'learning', 'converged'}
    else:
        assert set(ours.calibration) == {'off'}
    assert run.storage == storage
    suffix = 'mcap' if storage == 'mcap' else 'db3'
    assert os.path.exists(os.path.join(tmp_path, 'out', f'out.{suffix}'))


def test_compare_reproduces_the_broad_scores(tmp_path):
    data = _first(load(TRIALS[1]), 20.0)
    bag = write_bag(str(tmp_path / 'in'), excerpt(data, mag_every=MAG_EVERY), 'mcap')
    run = run_bag(bag, str(tmp_path / 'out'), compare_topic='mocap/orientation')
    expected = score(offline(data, mag_every=MAG_EVERY), data['opt_quat'], data['movement'])
    comparison = run.comparison
    scored = data['movement'] & np.isfinite(data['opt_quat']).all(axis=1)
    assert comparison['matched'] == scored.sum() > 2500
    for key, value in expected.items():
        assert comparison[key] == pytest.approx(value, abs=1e-9), key
    assert comparison['topic'] == REFERENCE_TOPIC
    assert comparison['type'] == cdr.QUATERNION_TYPE
    # The same through the command line, with the picture.
    png = tmp_path / 'plot.png'
    out = io.StringIO()
    assert _quiet(bag_main, [bag, '--out', str(tmp_path / 'out2'), '--compare',
                             REFERENCE_TOPIC, '--plot', str(png)], out) == 0
    assert f'RMSE total {expected["total_rmse_deg"]:.3f}°' in out.getvalue()
    assert png.stat().st_size > 20000


def _quiet(main, argv, out=None):
    """Run a command's main with stdout (and stderr) captured."""
    import contextlib
    out = io.StringIO() if out is None else out
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(out):
        return main(argv)


def test_compare_matches_the_nearest_stamp_within_half_a_sample(data):
    ours = _python_call(data)
    stamps = np.round(ours.times * 1e9).astype(np.int64)
    # A reference at a quarter of the rate, 1 ms late (half a sample is 1.75
    # ms): only the samples it was taken with match.
    result = compare(ours, stamps[::4] + 1_000_000, ours.quaternions[::4])
    assert result['matched'] == np.count_nonzero(ours.estimated[::4])
    assert result['total_max_deg'] < 1e-5
    with pytest.raises(ValueError, match='no reference stamp within'):
        compare(ours, [10 ** 15], [(1.0, 0.0, 0.0, 0.0)])


def test_csv_round_trip(tmp_path, data, recording):
    path = write_csv(str(tmp_path / 'in.csv'), recording)
    times, gyr, acc, mag = read_recording(path)
    np.testing.assert_array_equal(gyr, data['gyr'])
    np.testing.assert_array_equal(acc, data['acc'])
    with_field = ~np.isnan(mag).all(axis=1)
    np.testing.assert_array_equal(np.flatnonzero(with_field), recording['field_index'])
    np.testing.assert_array_equal(mag[with_field], fields_tesla(data)[with_field])
    assert _quiet(csv_main, [path, '--out', str(tmp_path / 'out.csv'), '--plot',
                             str(tmp_path / 'csv.png')]) == 0
    columns = read_columns(str(tmp_path / 'out.csv'), ('t', 'qw', 'qx', 'qy', 'qz', 'roll',
                                                       'pitch', 'yaw', 'rest', 'mag_disturbed'))
    expected = _python_call(data)
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
    assert _quiet(csv_main, [str(path), '--out', str(tmp_path / 'o.csv')], err) == 2
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
    rows = _python_call(data)
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
    out = _read_bag(str(tmp_path / 'out'))
    assert len(out['/attitude_estimate']) == len(stamps) - 4


def test_bag_errors_name_the_topic(tmp_path, recording):
    bag = write_bag(str(tmp_path / 'in'), recording, 'mcap')
    cases = [
        (dict(imu_topic='/camera/imu'), r'no topic /camera/imu in the bag \(the IMU, '
                                        r'--imu-topic\); its topics: /imu/data_raw \('),
        (dict(mag_topic='mag'), r'no topic /mag .*--no-mag for 6D'),
        (dict(imu_topic=REFERENCE_TOPIC), 'topic /mocap/orientation carries geometry_msgs/'
                                          'msg/QuaternionStamped; the IMU must be sensor_msgs'),
        (dict(compare_topic='/imu/mag'), 'the reference must be sensor_msgs/msg/Imu or'),
        (dict(compare_topic='/imu/data_raw'), r'no orientation on /imu/data_raw \(a '
                                              r'sensor_msgs/Imu with orientation_covariance'),
        (dict(data_topic='/imu/data_raw'), 'both an input'),
        (dict(parameters={'declination': 1}), 'declination: a float is expected'),
    ]
    for kwargs, message in cases:
        out = str(tmp_path / 'out')
        with pytest.raises(ValueError, match=message):
            run_bag(bag, out, **kwargs)
        assert not os.path.exists(out)
    os.makedirs(tmp_path / 'exists')
    with pytest.raises(ValueError, match='exists'):
        run_bag(bag, str(tmp_path / 'exists'))
    with pytest.raises(ValueError, match='is inside the input bag'):
        run_bag(bag, os.path.join(bag, 'out'))
    with pytest.raises(ValueError, match='no such bag'):
        run_bag(str(tmp_path / 'nothing'), str(tmp_path / 'out'))
    # 6D needs no magnetometer topic.
    run = run_bag(bag, str(tmp_path / 'six'), mag_topic='mag', parameters={'use_mag': False})
    assert run.recording.counts['fields'] == 0 and 'mag' not in run.topics


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_truncated_bag_is_an_error_and_leaves_no_output(tmp_path, recording, storage):
    bag = write_bag(str(tmp_path / 'in'), recording, storage)
    (name,) = [n for n in os.listdir(bag) if not n.endswith('.yaml')]
    path = os.path.join(bag, name)
    os.truncate(path, os.path.getsize(path) // 2)
    err = io.StringIO()
    assert _quiet(bag_main, [bag, '--out', str(tmp_path / 'out')], err) == 2
    assert f'error: cannot read the bag {bag}' in err.getvalue()
    assert not os.path.exists(tmp_path / 'out')


def test_undecodable_messages_are_counted(tmp_path, data, recording):
    writer = bag_io.BagWriter(str(tmp_path / 'in'), 'sqlite3',
                              [('/imu/data_raw', cdr.IMU_TYPE, []),
                               ('/imu/mag', cdr.FIELD_TYPE, [])])
    imu, mag = writer.ids
    for k, (stamp, gyr, acc) in enumerate(zip(recording['stamps'][:500],
                                              data['gyr'].tolist(), data['acc'].tolist())):
        raw = cdr.encode_imu(stamp, 'imu', gyr, acc)
        writer.write(imu, stamp + LATENCY, raw[:100] if k == 50 else raw)
        writer.write(mag, stamp + LATENCY + 1, cdr.encode_field(stamp, 'imu',
                                                                fields_tesla(data)[k]))
    writer.close()
    run = run_bag(str(tmp_path / 'in'), str(tmp_path / 'out'))
    assert run.undecodable == {'/imu/data_raw': 1}
    assert run.recording.counts['imu_samples'] == 499
    assert run.topics['imu'][2] == 500  # copied as it was


def test_compare_with_the_imus_own_orientation(tmp_path, data, recording):
    """An IMU with an onboard AHRS: its sensor_msgs/Imu carries the reference too."""
    count = 2000
    ours = _python_call(_first(data, count / float(data['rate'])))
    onboard = ours.quaternions[::-1]  # any orientation, known here
    writer = bag_io.BagWriter(str(tmp_path / 'in'), 'mcap',
                              [('/imu/data', cdr.IMU_TYPE, []), ('/imu/mag', cdr.FIELD_TYPE, [])])
    imu, mag = writer.ids
    for k in range(count):
        stamp = recording['stamps'][k]
        writer.write(imu, stamp + LATENCY, cdr.encode_imu(stamp, 'imu', data['gyr'][k],
                                                          data['acc'][k], onboard[k], 1e-4))
        if k % MAG_EVERY == 0:
            writer.write(mag, stamp + LATENCY + 1, cdr.encode_field(stamp, 'imu',
                                                                    fields_tesla(data)[k]))
    writer.close()
    run = run_bag(str(tmp_path / 'in'), str(tmp_path / 'out'), imu_topic='imu/data',
                  compare_topic='imu/data', data_topic='imu/data_ext')
    assert run.comparison['matched'] == count - 1
    expected = score(ours.quaternions[1:], onboard[1:], None)
    for key, value in expected.items():
        assert run.comparison[key] == pytest.approx(value, abs=1e-9), key
    assert run.topics['reference'] == run.topics['imu'] == ('/imu/data', cdr.IMU_TYPE, count)
    assert sorted(_read_bag(str(tmp_path / 'out'))) == [
        '/attitude_estimate', '/imu/data', '/imu/data_ext', '/imu/mag']


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
    out = _read_bag(str(tmp_path / 'out'))
    assert len(out['/imu/data']) == 299
    for _, msg, _ in out['/imu/data']:
        np.testing.assert_array_equal(msg.orientation_covariance, np.arange(9.0))
    estimates = np.array([[m.quaternion.w, m.quaternion.x, m.quaternion.y, m.quaternion.z]
                          for _, m, _ in out['/attitude_estimate']])
    np.testing.assert_array_equal(estimates, run.recording.ambient[1:])


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_batched_writer_equals_rosbags_writer(tmp_path, storage):
    rng = np.random.default_rng(0)
    topics = [('/a', cdr.IMU_TYPE, []), ('/b', cdr.QUATERNION_TYPE, [])]
    rows = [(1 + k % 2, 10 ** 12 + 1000 * k, rng.bytes(int(rng.integers(40, 400))))
            for k in range(20000)]
    bags = []
    for batched in (True, False):
        path = str(tmp_path / f'{batched}')
        writer = bag_io.BagWriter(path, storage, topics)
        if not batched:
            writer._store = None
        for cid, received, raw in rows:
            writer.write(writer.ids[cid - 1], received, raw)
        writer.close()
        with Reader(path) as reader:
            bags.append(([(c.topic, t, bytes(raw)) for c, t, raw in reader.messages()],
                         reader.message_count, reader.start_time, reader.end_time,
                         {c.topic: c.msgcount for c in reader.connections}))
    assert bags[0] == bags[1]
    assert len(bags[0][0]) == len(rows)


def test_codecs_agree_with_rosbags():
    rng = np.random.default_rng(1)
    for frame in ('', 'a', 'imu_link', 'seven77', 'eight888'):
        stamp = int(rng.integers(1, 2 ** 31)) * 1_000_000_000 + int(rng.integers(0, 10 ** 9))
        gyr, acc, field = (tuple(rng.normal(size=3)) for _ in range(3))
        msg = TYPESTORE.deserialize_cdr(cdr.encode_imu(stamp, frame, gyr, acc), cdr.IMU_TYPE)
        assert (_stamp(msg), msg.header.frame_id, msg.orientation_covariance[0]) == (
            stamp, frame, -1.0)
        assert (msg.angular_velocity.y, msg.linear_acceleration.z) == (gyr[1], acc[2])
        msg = TYPESTORE.deserialize_cdr(cdr.encode_field(stamp, frame, field), cdr.FIELD_TYPE)
        assert msg.magnetic_field.x == field[0]
        q = tuple(rng.normal(size=4))
        msg = TYPESTORE.deserialize_cdr(cdr.encode_quaternion_stamped(stamp, frame, q),
                                        cdr.QUATERNION_TYPE)
        assert (msg.quaternion.w, msg.quaternion.z) == (q[0], q[3])
        for little in (True, False):
            raw = bytes(TYPESTORE.serialize_cdr(
                TYPESTORE.deserialize_cdr(cdr.encode_imu(stamp, frame, gyr, acc), cdr.IMU_TYPE),
                cdr.IMU_TYPE, little_endian=little))
            assert cdr.decode_imu(raw) == (stamp, gyr, acc)
            order, body = cdr.imu_layout(raw)[:2]
            filled = TYPESTORE.deserialize_cdr(cdr.ImuData(0.1)(raw, order, body, *q),
                                               cdr.IMU_TYPE)
            n = np.linalg.norm(q)
            assert filled.orientation.x == pytest.approx(q[1] / n, abs=1e-15)
            assert filled.orientation_covariance[8] == pytest.approx(0.01)
            assert filled.linear_acceleration.y == acc[1]
            assert cdr.decode_orientation(raw, cdr.IMU_TYPE) == (stamp, None)
    with pytest.raises(cdr.Undecodable):
        cdr.decode_imu(cdr.encode_imu(1, 'imu', (0, 0, 0), (0, 0, 9.8))[:200])


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


def test_progress_on_long_bags():
    stream = io.StringIO()
    progress = _Progress(100000, stream)
    for done in range(1, 100001):
        if done >= progress.next:
            progress(done)
    progress.finish(100000)
    lines = stream.getvalue().splitlines()
    assert len(lines) == 10 and lines[-1].startswith('bag: 100 % (100000 / 100000')
    quiet = io.StringIO()
    _Progress(10, quiet).finish(10)
    assert quiet.getvalue() == ''


def test_example_data_command_and_the_speed_measure(tmp_path):
    from ext_observer.recordings.example_data import main as example_main
    out = io.StringIO()
    # Both sides with the same parameters (here the calibration off).
    params = tmp_path / 'params.yaml'
    params.write_text('imu_filter:\n  ros__parameters:\n    ahrs:\n      mag_cal: false\n')
    assert _quiet(example_main, ['--out', str(tmp_path), '--seconds', '2', '--rate', '400',
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
