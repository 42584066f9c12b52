"""
Checks of the vehicle benchmark: the simulator's physics and the report's logic.

No ROS, no timing. The physics is checked against what it must be (gravity
alone at rest and at constant speed, ``v ω`` in a turn, the world
acceleration differentiated numerically, the gyro integrated back to the
attitude); the report on made-up results.
"""

import json
import math

import numpy as np
import pytest

from bench import vehicle, vehicle_sim
from docgen import vehicle_page
from bench.vehicle_sim import GRAVITY, Scenario, Segment
from ext_observer.core.quaternion import (multiply, quaternion_from_rotation_vector,
                                         rotation_matrices)

SLOPES = (0.0, vehicle_sim.SLOPE_DEG)


def _world(sim, body_vectors):
    return np.einsum('nij,nj->ni', rotation_matrices(sim.quat), body_vectors)


def _drive(*segments, slope=0.0, speed0=0.0, yaw_rate0=0.0, heading0=90.0):
    return Scenario(name='test', description='', segments=segments, slope_deg=slope,
                    speed0=speed0, yaw_rate0=yaw_rate0, heading0_deg=heading0)


@pytest.mark.parametrize('slope', SLOPES)
@pytest.mark.parametrize('speed', [0.0, 12.0])
def test_at_rest_and_at_constant_speed_the_specific_force_is_gravity_alone(slope, speed):
    sim = vehicle_sim.simulate(_drive(Segment(5.0), slope=slope, speed0=speed, heading0=30.0),
                               noise=False)
    np.testing.assert_allclose(_world(sim, sim.acc_true), np.tile((0.0, 0.0, GRAVITY),
                                                                  (len(sim.times), 1)),
                               atol=1e-12)
    np.testing.assert_allclose(sim.gyr_true, 0.0)
    # On a slope the sensor sees gravity's reaction tilted, by the slope.
    tilt = math.degrees(math.acos(sim.acc_true[0, 2] / GRAVITY))
    assert tilt == pytest.approx(slope, abs=1e-9)


@pytest.mark.parametrize('slope', SLOPES)
def test_in_a_constant_turn_the_horizontal_specific_force_is_v_omega_towards_the_centre(slope):
    speed, omega = 15.0, 0.3
    sim = vehicle_sim.simulate(_drive(Segment(20.0), slope=slope, speed0=speed,
                                      yaw_rate0=omega), noise=False)
    r = rotation_matrices(sim.quat)
    normal = r[:, :, 2]  # the road's normal, the body's z
    world = _world(sim, sim.acc_true)
    in_plane = world - np.einsum('ni,ni->n', world, normal)[:, None] * normal
    gravity_in_plane = np.array([0.0, 0.0, GRAVITY]) - GRAVITY * normal[:, 2:3] * normal
    centripetal = in_plane - gravity_in_plane
    np.testing.assert_allclose(np.linalg.norm(centripetal, axis=1), speed * omega, rtol=1e-12)
    # Towards the centre: the body's left for a positive (counter-clockwise) yaw rate.
    np.testing.assert_allclose(np.einsum('ni,ni->n', centripetal, r[:, :, 1]), speed * omega)
    if slope == 0.0:
        np.testing.assert_allclose(world[:, 2], GRAVITY, atol=1e-12)


def test_the_specific_force_is_the_world_acceleration_of_the_velocity_minus_gravity():
    # Accelerating, braking and steering at once on a slope: d/dt (R v_b),
    # by central differences, against what the simulator computes.
    drive = _drive(Segment(4.0, accel=2.0, yaw_rate=0.4), Segment(4.0, accel=-1.5, yaw_rate=-0.2),
                   slope=5.0, speed0=3.0, heading0=10.0)
    sim = vehicle_sim.simulate(drive, noise=False)
    dt = 1.0 / vehicle_sim.RATE
    v_world = _world(sim, sim.velocity)
    a_world = (v_world[2:] - v_world[:-2]) / (2 * dt)
    specific = a_world + np.array([0.0, 0.0, GRAVITY])
    inner = slice(1, -1)
    # Away from the segments' corners, where the acceleration jumps.
    smooth = np.abs(sim.times[inner] - 4.0) > 2 * dt
    # Central differences err by about dt² · |d³v/dt³| / 6 (1e-5 m/s² here); a
    # wrong sign or a missing ω × v would err by metres per second squared.
    np.testing.assert_allclose(_world(sim, sim.acc_true)[inner][smooth], specific[smooth],
                               atol=1e-4)


def test_the_noise_free_gyro_integrates_back_to_the_true_attitude():
    drive = vehicle_sim.scenarios()[4]  # a turn on the slope, with its ramps
    sim = vehicle_sim.simulate(drive, noise=False)
    dt = 1.0 / vehicle_sim.RATE
    q = sim.quat[0]
    # Trapezoid increments in the body frame: exact for a piecewise-linear rate about a fixed axis.
    steps = quaternion_from_rotation_vector(0.5 * (sim.gyr_true[1:] + sim.gyr_true[:-1]) * dt)
    worst = 0.0
    for k, step in enumerate(steps, start=1):
        q = multiply(q, step)
        worst = max(worst, float(np.linalg.norm(q - sim.quat[k])))
    assert worst < 1e-9
    turned = sim.yaw_rate.sum() * dt
    assert abs(turned) > 1.0  # the test did turn the vehicle


def test_the_field_is_the_earths_seen_from_the_body():
    sim = vehicle_sim.simulate(vehicle_sim.scenarios()[2], noise=False)
    np.testing.assert_allclose(_world(sim, sim.mag), np.tile(vehicle_sim.earth_field(),
                                                             (len(sim.times), 1)), atol=1e-9)


def test_noise_bias_and_vibration_are_as_stated_and_fixed_by_the_seed():
    drive = vehicle_sim.scenarios()[-1]
    assert drive.rough
    sim = vehicle_sim.simulate(drive, seed=3)
    again = vehicle_sim.simulate(drive, seed=3)
    np.testing.assert_array_equal(sim.acc, again.acc)
    assert not np.array_equal(sim.acc, vehicle_sim.simulate(drive, seed=4).acc)
    assert math.degrees(np.linalg.norm(sim.gyro_bias)) == pytest.approx(
        vehicle_sim.GYRO_BIAS_DEG)
    gyro_noise = sim.gyr - sim.gyr_true - sim.gyro_bias
    assert np.std(gyro_noise) == pytest.approx(vehicle_sim.GYRO_NOISE, rel=0.05)
    shaking = sim.speed >= vehicle_sim.VIBRATION_FULL_SPEED
    rest = sim.speed == 0.0
    vertical = (sim.acc - sim.acc_true)[:, 2]
    expected = math.hypot(vehicle_sim.VIBRATION_RMS[2], vehicle_sim.ACC_NOISE)
    assert np.sqrt(np.mean(vertical[shaking] ** 2)) == pytest.approx(expected, rel=0.1)
    assert np.std(vertical[rest]) == pytest.approx(vehicle_sim.ACC_NOISE, rel=0.1)


def test_band_limited_vibration_stays_in_its_band():
    rng = np.random.default_rng(0)
    signal = vehicle_sim.band_limited(rng, 4096, 100.0, (10.0, 30.0), 2.0)
    assert np.sqrt(np.mean(signal ** 2)) == pytest.approx(2.0)
    power = np.abs(np.fft.rfft(signal)) ** 2
    frequencies = np.fft.rfftfreq(4096, 0.01)
    outside = (frequencies < 10.0) | (frequencies > 30.0)
    assert power[outside].sum() < 1e-20 * power.sum()


def test_the_drives_are_what_the_benchmark_says():
    drives = vehicle_sim.scenarios()
    turns = [d for d in drives if d.kind == 'turn']
    assert len(turns) == 6 and {d.slope_deg for d in turns} == set(SLOPES)
    for drive in turns:
        sim = vehicle_sim.simulate(drive, noise=False)
        held = sim.manoeuvre & (np.abs(np.diff(sim.yaw_rate, append=0.0)) < 1e-12)
        lateral = sim.speed[held] * sim.yaw_rate[held] / vehicle_sim.STANDARD_G
        assert float(lateral.max()) in [pytest.approx(g) for g in vehicle_sim.TURN_G]
        assert held.sum() / vehicle_sim.RATE >= vehicle_sim.TURN_SECONDS - 0.05
    for drive in drives:
        sim = vehicle_sim.simulate(drive, noise=False)
        assert sim.speed[0] == 0.0 and sim.manoeuvre.any()
        assert np.all(sim.speed[:int(vehicle_sim.REST * vehicle_sim.RATE)] == 0.0)
    braking = [d for d in drives if d.name.startswith('accelerate')]
    for drive in braking:
        sim = vehicle_sim.simulate(drive, noise=False)
        assert np.max(np.abs(sim.acc_true[:, 0] - sim.acc_true[0, 0])) == pytest.approx(
            vehicle_sim.BRAKE_G * vehicle_sim.STANDARD_G)
        assert sim.speed[-1] == pytest.approx(0.0, abs=1e-9)


def test_a_drive_that_would_reverse_is_refused():
    with pytest.raises(ValueError, match='negative'):
        vehicle_sim.profile(_drive(Segment(2.0, accel=-1.0), speed0=1.0))


# The harness and the report.

def test_the_truth_scores_zero_and_the_apparent_gravity_its_tilt():
    sim = vehicle_sim.simulate(_drive(Segment(3.0, manoeuvre=True), speed0=15.0,
                                      yaw_rate0=0.3), noise=False)
    assert vehicle.score(sim, sim.quat)['inclination_whole'] < 1e-6
    tilt = math.degrees(math.atan(15.0 * 0.3 / GRAVITY))
    assert vehicle.apparent_gravity(sim)['inclination_manoeuvre'] == pytest.approx(tilt)


def test_the_velocity_is_passed_once_the_core_takes_it(monkeypatch):
    import ext_observer
    sim = vehicle_sim.simulate(_drive(Segment(2.0), speed0=5.0), noise=False)
    seen = {}

    def takes_velocity(gyr, acc, mag=None, *, rate=None, parameters=None, velocity=None,
                       velocity_times=None):
        seen.update(velocity=velocity, velocity_times=velocity_times)
        return type('Recording', (), {'quaternions': sim.quat})()

    real = vehicle.velocity_parameters()
    assert (vehicle.ESTIMATORS[vehicle.OURS_VELOCITY](sim, False) is None) == (real == ())
    monkeypatch.setattr(ext_observer, 'attitude_from_imu', takes_velocity)
    assert vehicle.velocity_parameters() == ('velocity', 'velocity_times')
    estimate = vehicle.ESTIMATORS[vehicle.OURS_VELOCITY](sim, True)
    np.testing.assert_array_equal(estimate.quaternions, sim.quat)
    np.testing.assert_array_equal(seen['velocity'], sim.velocity)
    np.testing.assert_array_equal(seen['velocity_times'], sim.times)


def test_every_estimator_runs_on_a_short_drive_and_the_report_renders(tmp_path):
    drive = Scenario(name='short turn', description='', kind='turn', speed0=10.0,
                     segments=(Segment(3.0), Segment(2.0, yaw_rate=0.3, manoeuvre=True)))
    rows = vehicle.run_scenarios([drive], seeds=1, progress=lambda text: None)
    assert {r['mode'] for r in rows} == {'6D', '9D'}
    by = {(r['mode'], r['estimator']): r for r in rows}
    for name in ('ours', 'VQF', 'Madgwick', 'Fusion'):
        metrics = by[('9D', name)]['metrics']
        assert 0.0 <= metrics['inclination_manoeuvre'] < 20.0, name
    # Ours reports its rest flags: the share of the manoeuvre it took for rest.
    assert 0.0 <= by[('6D', 'ours')]['metrics']['rest_manoeuvre'] <= 1.0
    summary = vehicle.summarize(rows)
    assert vehicle.ratio(summary, ('short turn', '6D')) > 0.0
    assert vehicle_page.rest_table(summary).splitlines()[-1].endswith('% |')
    results = {'rows': rows, 'seeds': 1, 'seconds': 1.0, 'versions': 'v',
               'command': 'python -m bench.vehicle', 'drives': [drive],
               'machine': {'commit': 'abc', 'date': 'd', 'cpu': 'c', 'cores': 2,
                           'python': '3', 'numpy': '2', 'load_start': 1.0},
               'baseline': [{**case, 'measured': {'ours': 1.0, 'VQF': 2.0, 'apparent': 3.0}}
                            for case in vehicle.BASELINE]}
    text = vehicle_page.render(results)
    assert '| short turn |' in text and 'commit `abc`' in text
    assert ('not yet available' in text) == (vehicle.velocity_parameters() == ())
    # Saved results render again (--render), the page written where asked.
    saved, page = tmp_path / 'results.json', tmp_path / 'vehicle.md'
    del results['drives']
    saved.write_text(json.dumps({**results, 'drive_names': [drive.name]}))
    assert vehicle.main(['--render', str(saved), '--output', str(page)]) == 0
    assert '| short turn |' in page.read_text()


def _rows(values, seeds=(0, 1)):
    """Rows as run_scenarios makes them: values[(scenario, estimator)] = inclination."""
    rows = []
    for (scenario, estimator), value in values.items():
        for seed in seeds:
            metrics = None if value is None else {
                'inclination_manoeuvre': value + seed, 'inclination_whole': value,
                'heading_manoeuvre': 0.0, 'heading_whole': 0.0}
            rows.append({'scenario': scenario, 'kind': 'turn' if 'turn' in scenario else 'x',
                         'seed': seed, 'mode': '6D', 'estimator': estimator,
                         'seconds': 0.1, 'metrics': metrics})
    return rows


def test_the_summary_averages_the_seeds_and_the_verdicts_read_the_criteria():
    rows = _rows({('turn a', 'ours'): 2.0, ('turn a', 'VQF'): 9.0,
                  ('turn a', vehicle.OURS_VELOCITY): None,
                  ('turn b', 'ours'): 4.5, ('turn b', 'VQF'): 9.0,
                  ('turn b', vehicle.OURS_VELOCITY): None,
                  ('brake', 'ours'): 9.0, ('brake', 'VQF'): 1.0,
                  ('brake', vehicle.OURS_VELOCITY): None})
    summary = vehicle.summarize(rows)
    assert summary[('turn a', '6D')]['ours']['inclination_manoeuvre'] == 2.5
    assert summary[('turn a', '6D')][vehicle.OURS_VELOCITY] is None
    assert vehicle.ratio(summary, ('turn a', '6D')) == pytest.approx(2.5 / 9.5)
    kinds = {'turn a': 'turn', 'turn b': 'turn', 'brake': 'x'}
    verdicts = vehicle.verdicts(summary, kinds)
    assert verdicts[0][1:] == (vehicle.NOT_YET, 'not yet')
    # The braking drive is no turn: only the two turns are judged by the ratio.
    assert [v[2] for v in verdicts[1:]] == ['goal met', 'not met']
    table = vehicle_page.error_table(summary, '6D', 'inclination_manoeuvre', 'inclination_whole',
                                columns=('ours', vehicle.OURS_VELOCITY, 'VQF'))
    assert '| turn a | 2.50 (2.00) | not yet available | 9.50 (9.00) | 0.26 |' in table


def test_with_the_velocity_the_worst_drive_is_judged():
    rows = _rows({('turn a', 'ours'): 2.0, ('turn a', 'VQF'): 4.0,
                  ('turn a', vehicle.OURS_VELOCITY): 0.1,
                  ('brake', vehicle.OURS_VELOCITY): 0.6})
    verdicts = vehicle.verdicts(vehicle.summarize(rows), {'turn a': 'turn'})
    # Means over seeds 0 and 1: 0.6 and 1.1 with the velocity; the worst decides.
    assert verdicts[0][1:] == ('worst 1.10°', 'not met')
    assert verdicts[1][1:] == ('0.56', 'not met')
