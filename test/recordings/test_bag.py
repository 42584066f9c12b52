"""
The bag command (``recordings/bag.py``) on a bag written from a shipped BROAD
excerpt, in both storage formats: its ``attitude_estimate`` and ``imu/data``,
read back with ``rosbags``' own deserializer, equal the Python call and
``test/broad_replay.py``'s offline run (which ``test_raw_imu_through_dds.py`` proves equal
to the node through DDS); ``--compare`` against the optical reference as a
topic gives the scores :mod:`ext_observer.broad` computes for the same
samples; bad input: missing topics, a topic of another type, truncated bags
and messages; the progress on long bags.
"""

import io
import os

import numpy as np
import pytest
from rosbags.rosbag2 import Reader

from broad_replay import fields_tesla, load, offline, TRIALS
from ext_observer.core.ahrs.ahrs_observer import AhrsParams
from ext_observer.recordings import bag_io
from ext_observer.recordings import cdr
from ext_observer.recordings.bag import _Progress, compare, main as bag_main, run_bag
from ext_observer.broad import score
from ext_observer.recordings.example_data import excerpt, LATENCY, REFERENCE_TOPIC, write_bag
from ext_observer.recordings.recording import attitude_from_imu, node_settings
from recording_excerpt import (MAG_EVERY, TOLERANCE, files_digest, first_seconds, header_stamp,
                               python_call, quiet, read_bag)
from recording_excerpt import data, recording  # noqa: F401 (fixtures)


# The shipped defaults, and the other side of each choice the comparison
# below branches on: the calibration off, the covariance orientation_stddev's.
NOT_DEFAULT = {'ahrs.mag_cal': False, 'orientation_covariance_mode': 'fixed'}


@pytest.mark.parametrize('storage, parallel, parameters', [('mcap', True, None),
                                                            ('sqlite3', False, None),
                                                            ('mcap', False, NOT_DEFAULT)])
def test_bag_equals_python_call_and_offline(tmp_path, data, recording, storage, parallel,
                                            parameters):
    bag = write_bag(str(tmp_path / 'in'), recording, storage)
    digest = files_digest(bag)
    run = run_bag(bag, str(tmp_path / 'out'), parameters=parameters, parallel=parallel)
    assert files_digest(bag) == digest  # the input is only read
    out = read_bag(str(tmp_path / 'out'))
    count = len(data['gyr'])
    mag_cal = (parameters or {}).get('ahrs.mag_cal', True)
    expected = offline(data, mag_every=MAG_EVERY, params=AhrsParams(mag_cal=mag_cal))[1:]
    ours = python_call(data, parameters)
    np.testing.assert_allclose(ours.ambient[1:], expected, rtol=0, atol=TOLERANCE)
    assert not ours.estimated[0] and ours.estimated[1:].all()

    # attitude_estimate: the ambient estimate, stamped like its sample.
    estimates = out['/attitude_estimate']
    assert len(estimates) == count - 1
    ambient = np.array([[m.quaternion.w, m.quaternion.x, m.quaternion.y, m.quaternion.z]
                        for _, m, _ in estimates])
    np.testing.assert_allclose(ambient, expected, rtol=0, atol=TOLERANCE)
    assert [header_stamp(m) for _, m, _ in estimates] == recording['stamps'][1:]
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
        assert received_out == received and header_stamp(msg) == header_stamp(raw_in)
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
    data = first_seconds(load(TRIALS[1]), 20.0)
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
    assert quiet(bag_main, [bag, '--out', str(tmp_path / 'out2'), '--compare',
                             REFERENCE_TOPIC, '--plot', str(png)], out) == 0
    assert f'RMSE total {expected["total_rmse_deg"]:.3f}°' in out.getvalue()
    assert png.stat().st_size > 20000


def test_compare_matches_the_nearest_stamp_within_half_a_sample(data):
    ours = python_call(data)
    stamps = np.round(ours.times * 1e9).astype(np.int64)
    # A reference at a quarter of the rate, 1 ms late (half a sample is 1.75
    # ms): only the samples it was taken with match.
    result = compare(ours, stamps[::4] + 1_000_000, ours.quaternions[::4])
    assert result['matched'] == np.count_nonzero(ours.estimated[::4])
    assert result['total_max_deg'] < 1e-5
    with pytest.raises(ValueError, match='no reference stamp within'):
        compare(ours, [10 ** 15], [(1.0, 0.0, 0.0, 0.0)])


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
    assert quiet(bag_main, [bag, '--out', str(tmp_path / 'out')], err) == 2
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
    ours = python_call(first_seconds(data, count / float(data['rate'])))
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
    assert sorted(read_bag(str(tmp_path / 'out'))) == [
        '/attitude_estimate', '/imu/data', '/imu/data_ext', '/imu/mag']


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


def test_bag_smooth_writes_the_smoothed_estimate(tmp_path, data, recording):
    bag = write_bag(str(tmp_path / 'in'), recording, 'mcap')
    out = io.StringIO()
    assert quiet(bag_main, [bag, '--out', str(tmp_path / 'out'), '--smooth'], out) == 0
    assert 'smoothed' in out.getvalue()
    written = read_bag(str(tmp_path / 'out'))
    stamps = np.array(recording['stamps'], dtype=np.int64)
    mag = np.full((len(stamps), 3), np.nan)
    mag[recording['field_index']] = recording['field'][recording['field_index']]
    expected = attitude_from_imu(recording['gyr'], recording['acc'], mag,
                                 times=(stamps - stamps[0]) * 1e-9, smooth=True)
    online = python_call(data)
    data_msgs = written['/imu/data']
    # The same messages as the online run writes: one per estimate.
    assert [header_stamp(m) for _, m, _ in data_msgs] == recording['stamps'][1:]
    orientation = np.array([[m.orientation.w, m.orientation.x, m.orientation.y,
                             m.orientation.z] for _, m, _ in data_msgs])
    np.testing.assert_allclose(orientation, expected.quaternions[1:], rtol=0, atol=TOLERANCE)
    assert np.abs(orientation - online.quaternions[1:]).max() > 1e-4
    covariance = np.array([m.orientation_covariance for _, m, _ in data_msgs])
    tilt = expected.inclination_std[1:] ** 2 / 2
    np.testing.assert_allclose(covariance[:, [0, 4, 8]],
                               np.column_stack([tilt, tilt, expected.heading_std[1:] ** 2]),
                               rtol=1e-12)
    ambient = np.array([[m.quaternion.w, m.quaternion.x, m.quaternion.y, m.quaternion.z]
                        for _, m, _ in written['/attitude_estimate']])
    np.testing.assert_allclose(ambient, expected.quaternions[1:], rtol=0, atol=TOLERANCE)
