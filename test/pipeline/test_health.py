"""
The estimator's health states (ext_observer/pipeline/health.py), each reached.

On the shipped BROAD excerpts (test/data/README.md) changed as a fault would
change them: the first samples (initializing), the still start (at rest), a
magnet (field rejected), a gyro clipped at a low ``ahrs.gyro_range``, fields
dropped for longer than ``mag_timeout``, a velocity given. Each state in the
batch ``Recording``, and some in ``imu_filter_node``'s ``/diagnostics``.
"""

import math
import os

import numpy as np
import pytest

from ext_observer.nodes.imu_filter_node import ImuFilterNode
from ext_observer.pipeline.health import HEALTH_STATES, health_text, NO_STATE
from ext_observer.recordings.recording import attitude_from_imu
from conftest import REPO
from imu_driver import connect, Driver
from imu_filter_runs import replay, samples
from ros_helpers import overrides, values_of

DATA = os.path.join(REPO, 'test', 'data')
SLOW = '01_undisturbed_slow_rotation_A'
MAGNET = '28_disturbed_stationary_magnet_A'
TAU_ACC = 2.0         # s, ahrs.tau_acc: the running mean of the start and of a recovery
MAG_TIMEOUT = 1.0     # s
GYRO_RANGE = 3.0      # rad/s: the slow excerpt passes it in a few short stretches
LOST = (20.0, 25.0)   # s: no fields
MAGNET_S = (6.0, 14.0)  # s: the magnet near the still body of MAGNET (test_excerpt_flags.py)
PARAMETERS = {'ahrs.tau_acc': TAU_ACC, 'mag_timeout': MAG_TIMEOUT}


def load(trial):
    with np.load(os.path.join(DATA, f'broad_{trial}.npz')) as data:
        return {key: data[key] for key in data.files}


def run(data, gyr=None, mag=None, **options):
    parameters = dict(PARAMETERS, **options.pop('parameters', {}))
    return attitude_from_imu(data['gyr'] if gyr is None else gyr, data['acc'],
                             data['mag'] * 1e-6 if mag is None else mag,
                             rate=float(data['rate']), parameters=parameters, **options)


def seconds(rec, name):
    """The times (s) where the state ``name`` is active."""
    return rec.times[rec.in_state(name)]


@pytest.fixture(scope='module')
def slow():
    data = load(SLOW)
    return data, run(data)


def test_the_names_bits_and_text():
    assert len(set(HEALTH_STATES)) == len(HEALTH_STATES) <= 8  # one uint8 per sample
    assert health_text(()) == NO_STATE
    assert health_text(('at_rest', 'field_lost')) == 'at_rest, field_lost'


def test_initializing_is_the_start_only(slow):
    _, rec = slow
    t = seconds(rec, 'initializing')
    assert t[0] == 0.0 and t[-1] < TAU_ACC <= t[-1] + 0.01
    assert rec.health_states(1)[0] == 'initializing'
    with pytest.raises(ValueError, match='unknown health state'):
        rec.in_state('asleep')


def test_at_rest_and_field_rejected_are_the_flags_of_the_recording(slow):
    _, rec = slow
    assert np.array_equal(rec.in_state('at_rest'), rec.rest)
    assert np.array_equal(rec.in_state('field_rejected'), rec.mag_disturbed)
    # The excerpt starts still: rest after ahrs.rest_time (1.5 s).
    t = seconds(rec, 'at_rest')
    assert 1.5 <= t[0] < 2.0
    # Nothing clipped, lost or aided here.
    for name in ('gyro_clipped', 'field_lost', 'velocity_aided'):
        assert not rec.in_state(name).any(), name


def test_a_magnet_is_field_rejected():
    data = load(MAGNET)
    rec = run(data)
    t = seconds(rec, 'field_rejected')
    during = (t >= MAGNET_S[0]) & (t < MAGNET_S[1])
    assert during.sum() > 0.5 * (MAGNET_S[1] - MAGNET_S[0]) * float(data['rate'])


def test_a_clipped_gyro_recovers_for_tau_acc_and_is_not_a_start(slow):
    data, unclipped = slow
    rate = float(data['rate'])
    gyr = np.clip(data['gyr'], -GYRO_RANGE, GYRO_RANGE)
    rec = run(data, gyr=gyr, parameters={'ahrs.gyro_range': GYRO_RANGE})
    at_range = (np.abs(gyr) >= GYRO_RANGE).any(axis=1)
    assert at_range[int(TAU_ACC * rate):].any()
    recovering = rec.in_state('gyro_clipped')
    assert recovering[at_range].all()
    # The recovery ends tau_acc after the last clipped sample of a stretch.
    last = np.flatnonzero(at_range)[-1]
    after = int(math.ceil(TAU_ACC * rate))
    assert recovering[last:last + after - 2].all()
    assert not recovering[last + after + 2:].any()
    # A recovery is told from the start: not initializing.
    assert np.array_equal(rec.in_state('initializing'), unclipped.in_state('initializing'))


def test_a_field_lost_for_mag_timeout(slow):
    data, _ = slow
    rate = float(data['rate'])
    mag = data['mag'] * 1e-6
    mag[int(LOST[0] * rate):int(LOST[1] * rate)] = np.nan
    rec = run(data, mag=mag)
    t = seconds(rec, 'field_lost')
    # The last field before the gap at LOST[0] − 1/rate; lost mag_timeout later; back with it.
    assert LOST[0] + MAG_TIMEOUT - 2.0 / rate <= t[0] <= LOST[0] + MAG_TIMEOUT + 1.0 / rate
    assert LOST[1] - 2.0 / rate <= t[-1] < LOST[1]
    # In 6D there is no field to lose.
    rec_6d = run(data, mag=mag, parameters={'use_mag': False})
    assert not rec_6d.in_state('field_lost').any()


def test_a_velocity_given_is_velocity_aided(slow):
    data, _ = slow
    count = len(data['gyr'])
    rec = run(data, velocity=np.zeros((count, 3)))
    aided = rec.in_state('velocity_aided')
    assert aided[1:].all()
    # Only the first 10 s given: the aid stops velocity_timeout after the last.
    rate = float(data['rate'])
    given = int(10.0 * rate)
    rec = run(data, velocity=np.zeros((given, 3)), velocity_times=np.arange(given) / rate)
    aided = rec.in_state('velocity_aided')
    assert aided[1:given].all() and not aided[given + int(rate):].any()


def test_a_long_turn_without_a_velocity_is_accelerometer_rejected():
    # A level vehicle at 15 m/s, still for 10 s, then turning at 0.3 rad/s
    # (0.46 g): the low-passed force leaves the carried vertical and is rejected;
    # with rejection off the state never comes.
    rate, still = 100.0, 10.0
    t = np.arange(int(40.0 * rate)) / rate
    yaw = np.where(t >= still, 0.3, 0.0)
    zero = np.zeros_like(t)
    gyr = np.column_stack((zero, zero, yaw))
    acc = np.column_stack((zero, yaw * 15.0, np.full_like(t, 9.81)))
    params = {'use_mag': False}
    rejected = attitude_from_imu(gyr, acc, rate=rate, parameters=params).in_state(
        'accelerometer_rejected')
    assert not rejected[:int(still * rate)].any() and rejected[int(20.0 * rate):].mean() > 0.9
    off = attitude_from_imu(gyr, acc, rate=rate,
                            parameters=dict(params, **{'ahrs.acc_reject': 0.0}))
    assert not off.in_state('accelerometer_rejected').any()


def test_the_node_states_its_health_in_diagnostics(ros_context, spinner):
    node = spinner.add(ImuFilterNode(context=ros_context, parameter_overrides=overrides(
        diagnostic_period=60.0, **{'ahrs.gyro_range': 0.5, 'ahrs.tau_acc': 0.5})))
    driver = spinner.add(Driver(ros_context))
    connect(spinner, driver, node)

    def health():
        return values_of(node.status())['health']

    assert health() == 'initializing'
    # Still for longer than rest_time (1.5 s at 100 Hz), after the start's tau_acc.
    replay(spinner, driver, [node], samples(200, gyr=(0.0, 0.0, 0.0)))
    assert health() == 'at_rest'
    # The gyro at its range, then within it: clipped and recovering, not starting.
    clipped = samples(20, gyr=(0.0, 0.0, 0.5))
    replay(spinner, driver, [node], [(stamp + 2 * 10 ** 9, *rest)
                                     for stamp, *rest in clipped])
    assert 'gyro_clipped' in health() and 'initializing' not in health()
