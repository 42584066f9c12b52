"""
The magnetometer's own frame (mag_mounting; the deprecated mag_frame_rpy) and a
lost field (mag_timeout).

A field measured in a rotated frame, with the mounting set, gives the estimate
of the field in the IMU frame; a field that stops holds the heading within its
covariance and comes back without a step; the node warns of both.
"""

import math

from diagnostic_msgs.msg import DiagnosticStatus
import numpy as np
import pytest
from rclpy.parameter import Parameter

from broad_replay import fields_tesla, load, START, SECOND
from ext_observer.broad.scoring import error_angles
from ext_observer.core.quaternion import conjugate, multiply
from ext_observer.nodes.imu_filter_node import ImuFilterNode
from ext_observer.pipeline.imu_filter_outputs import mounting_matrix, quaternion_from_rpy
from ext_observer.recordings.recording import attitude_from_imu
from imu_driver import connect, Driver
from ros_helpers import overrides, values_of

TRIAL = '01_undisturbed_slow_rotation_A'
MOUNTING = (0.3, -1.1, 2.4)  # roll, pitch, yaw, rad: far from any axis
SAME_DEG = 0.1               # the mounted field's estimate against the IMU frame's
GAP_START = 30.0             # s into the excerpt, once the calibration has converged
COVERED = 0.95               # share of samples whose heading error is within 2σ
STEP_SIGMAS = 3.0            # the largest heading step at the return, in σ


@pytest.fixture(scope='module')
def excerpt():
    return load(TRIAL)


def _run(data, mag, **parameters):
    return attitude_from_imu(data['gyr'], data['acc'], mag, rate=float(data['rate']),
                             parameters=parameters or None)


def signed_heading(q, ref):
    """The heading error of ``q`` against ``ref`` (rad, signed): e = q ⊗ ref⁻¹ about z."""
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    e = multiply(q, conjugate(ref / np.linalg.norm(ref, axis=-1, keepdims=True)))
    w = np.where(e[..., 0] < 0.0, -1.0, 1.0)
    return 2.0 * np.arctan2(w * e[..., 3], np.abs(e[..., 0]))


def test_the_mounting_matrix_is_tf2s_rpy():
    r = np.array(mounting_matrix((0.0, 0.0, math.pi / 2))).reshape(3, 3)
    assert np.allclose(r @ (1.0, 0.0, 0.0), (0.0, 1.0, 0.0))
    r = np.array(mounting_matrix(MOUNTING)).reshape(3, 3)
    assert np.allclose(r @ r.T, np.eye(3))
    assert mounting_matrix((0.0, 0.0, 0.0)) is None


def test_a_field_in_a_mounted_frame_gives_the_imu_frames_estimate(excerpt):
    mag = fields_tesla(excerpt)
    r = np.array(mounting_matrix(MOUNTING)).reshape(3, 3)
    mounted = mag @ r  # m_mag = Rᵀ m_imu, row by row
    plain = _run(excerpt, mag)
    turned = _run(excerpt, mounted, mag_mounting=list(quaternion_from_rpy(MOUNTING)))
    total = error_angles(turned.quaternions, plain.quaternions)[0]
    assert np.degrees(np.nanmax(total)) <= SAME_DEG
    # The deprecated spelling, warned of, gives the same estimates (the same
    # rotation; its matrix from the angles differs by rounding only).
    with pytest.warns(FutureWarning, match='mag_frame_rpy is deprecated'):
        by_angles = _run(excerpt, mounted, mag_frame_rpy=list(MOUNTING))
    assert np.nanmax(np.abs(by_angles.quaternions - turned.quaternions)) < 1e-9
    # Without the mounting the estimate is another one: the test can fail.
    wrong = _run(excerpt, mounted)
    assert np.degrees(np.nanmax(error_angles(wrong.quaternions, plain.quaternions)[0])) > 5.0


@pytest.mark.parametrize('gap', [5.0, None])
def test_a_lost_field_holds_the_heading_within_its_covariance(excerpt, gap):
    rate = float(excerpt['rate'])
    mag = fields_tesla(excerpt).copy()
    k0 = int(GAP_START * rate)
    k1 = len(mag) if gap is None else k0 + int(gap * rate)
    mag[k0:k1] = np.nan
    run = _run(excerpt, mag)
    heading = signed_heading(run.quaternions, excerpt['opt_quat'])
    sigma = run.heading_std
    after = np.arange(k0, len(mag))
    scored = after[np.isfinite(heading[after]) & excerpt['movement'][after]]
    assert np.mean(np.abs(heading[scored]) <= 2.0 * sigma[scored]) >= COVERED
    # The heading's σ grows while the gyro alone carries it.
    assert sigma[k1 - 1] > sigma[k0]
    if gap is not None:
        # The return: no sample moves the heading by more than 3σ of the heading at it.
        window = slice(k1 - 1, k1 + int(rate))
        step = np.max(np.abs(np.diff(heading[window])))
        assert step <= STEP_SIGMAS * sigma[k1 - 1]
        assert step <= math.radians(0.5), math.degrees(step)


def test_a_returning_field_comes_back_at_tau_mags_rate(excerpt):
    # Without mag_timeout the first field back takes the gain of the whole
    # gap (one step); with it, a regular field's.
    rate = float(excerpt['rate'])
    mag = fields_tesla(excerpt).copy()
    k0, k1 = int(GAP_START * rate), int((GAP_START + 20.0) * rate)
    mag[k0:k1] = np.nan
    steps = {}
    for timeout in (0.0, 1.0):
        run = _run(excerpt, mag, mag_timeout=timeout)
        heading = signed_heading(run.quaternions, excerpt['opt_quat'])
        steps[timeout] = abs(heading[k1 + 1] - heading[k1])
    assert steps[1.0] < steps[0.0]


def _status_after(spinner, observer, predicate, what):
    spinner.spin_until(lambda: predicate(observer.status()), 5.0, what)
    return observer.status()


def test_the_node_warns_of_a_lost_field_and_of_a_field_in_another_frame(ros_context, spinner):
    observer = spinner.add(ImuFilterNode(context=ros_context,
                                         parameter_overrides=overrides(mag_timeout=0.5)))
    driver = spinner.add(Driver(ros_context))
    connect(spinner, driver, observer)
    # The field in 'mag_link', the samples in 'imu_link', no mounting: a WARN.
    for k in range(100):
        stamp = START + k * SECOND // 100
        driver.send_imu(stamp, (0.0, 0.0, 0.1), (0.0, 0.0, 9.81))
        if k < 20:
            driver.send_field(stamp, (2e-5, 0.0, -4e-5), frame_id='mag_link')
    spinner.spin_until(lambda: len(driver.outputs) >= 99, 5.0, 'the estimates')
    status = observer.status()
    values = values_of(status)
    assert status.level == DiagnosticStatus.WARN
    assert 'field lost' in status.message and "frame 'mag_link'" in status.message
    assert values['field_lost'] == 'true' and values['field_frame_mismatch'] == 'true'
    assert float(values['field_silent_s']) >= 0.5
    # The field back, the mounting set: neither.
    observer.set_parameters([Parameter('mag_mounting', value=[0.0, 0.0, 0.0, 1.0])])
    stamp = START + 100 * SECOND // 100
    driver.send_field(stamp, (2e-5, 0.0, -4e-5), frame_id='mag_link')
    driver.send_imu(stamp + SECOND // 100, (0.0, 0.0, 0.1), (0.0, 0.0, 9.81))
    spinner.spin_until(lambda: len(driver.outputs) >= 100, 5.0, 'the last estimate')
    values = values_of(observer.status())
    assert values['field_lost'] == 'false' and values['field_frame_mismatch'] == 'false'


def gap_figures(path, start, gap, parameters=None):
    """
    A BROAD trial's field removed from ``start`` for ``gap`` s (None: for good).

    Returns the share of moving samples from ``start`` on whose heading error
    is within 2σ, and (with a return) the largest heading change between
    two samples in the second after it, in degrees and in σ at the return.
    """
    from ext_observer.broad.data import load_trial
    trial = load_trial(path)
    mag = trial.mag * 1e-6
    k0 = int(start * trial.rate)
    k1 = len(mag) if gap is None else min(k0 + int(gap * trial.rate), len(mag))
    mag[k0:k1] = np.nan
    run = attitude_from_imu(trial.gyr, trial.acc, mag, rate=trial.rate, parameters=parameters)
    heading, sigma = signed_heading(run.quaternions, trial.quat), run.heading_std
    after = np.arange(k0, len(mag))
    scored = after[np.isfinite(heading[after]) & trial.movement[after]]
    covered = float(np.mean(np.abs(heading[scored]) <= 2.0 * sigma[scored]))
    if k1 >= len(mag) - 1:
        return covered, math.nan, math.nan
    step = np.nanmax(np.abs(np.diff(heading[k1 - 1:k1 + int(trial.rate)])))
    return covered, math.degrees(step), step / sigma[k1 - 1]


def hold_figures(path, start, gap):
    """
    A BROAD trial's field removed from ``start`` for ``gap`` s (None: for good).

    Returns the shares of moving samples whose heading error is within 2σ
    while the field is lost (the heading held) and after its return (NaN
    where there are none).
    """
    from ext_observer.broad.data import load_trial
    trial = load_trial(path)
    mag = trial.mag * 1e-6
    k0 = int(start * trial.rate)
    k1 = len(mag) if gap is None else min(k0 + int(gap * trial.rate), len(mag))
    mag[k0:k1] = np.nan
    run = attitude_from_imu(trial.gyr, trial.acc, mag, rate=trial.rate)
    heading, sigma = signed_heading(run.quaternions, trial.quat), run.heading_std
    scored = np.isfinite(heading) & trial.movement
    within = np.abs(heading) <= 2.0 * sigma
    return tuple(float(np.mean(within[a:b][scored[a:b]])) if scored[a:b].any() else math.nan
                 for a, b in ((k0, k1), (k1, len(mag))))


def _every_trial(folder, begin):
    import glob
    import os
    print('| trial | 5 s: held, after | 60 s: held, after | for good: held |')
    print('| --- | --- | --- | --- |')
    for path in sorted(glob.glob(os.path.join(folder, '*.hdf5'))):
        cells = [hold_figures(path, begin, gap) for gap in (5.0, 60.0, None)]
        print(f'| {os.path.basename(path)[:2]} | ' + ' | '.join(
            ', '.join(f'{share:.3f}' for share in cell[:2 if gap else 1])
            for cell, gap in zip(cells, (5.0, 60.0, None))) + ' |', flush=True)


if __name__ == '__main__':
    # python test/test_field_frame_and_timeout.py TRIAL.hdf5 [START]: the figures of
    # docs/raw_imu.md, with mag_timeout at its default and at 0 (the gap's own gain);
    # with a folder (data_hdf5), every trial's shares within 2σ, held and after.
    import os
    import sys
    where, begin = sys.argv[1], float(sys.argv[2]) if len(sys.argv) > 2 else 60.0
    if os.path.isdir(where):
        _every_trial(where, begin)
        sys.exit(0)
    share = gap_figures(where, begin, 0.0)[0]
    print(f'no gap: within 2σ {share:.3f} from {begin:g} s on')
    for length in (5.0, 60.0, None):
        for timeout in (1.0, 0.0):
            share, deg, sigmas = gap_figures(where, begin, length, {'mag_timeout': timeout})
            print(f'gap {length} s, mag_timeout {timeout:g}: within 2σ {share:.3f}, '
                  f'largest step {deg:.3f}° = {sigmas:.3f} σ')
