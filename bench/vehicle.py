"""
``python -m bench.vehicle``: attitude estimators on a simulated road vehicle.

Every drive of :func:`bench.vehicle_sim.scenarios` (long turns on level and
sloped roads, accelerating and braking, a rough road) is simulated with
noise and a gyro bias, and run through ours (``attitude_from_imu``), ours
with the vehicle's velocity (once the core takes one), VQF, Madgwick and
Fusion, in 6D and 9D. Each is scored against the true attitude (BROAD's
error angles): the inclination error's RMS over the manoeuvre and over the
whole run, and in 9D the heading error's. The page
(:mod:`docgen.vehicle_page`) goes to stdout and to docs/vehicle.md, progress
to stderr.

An estimator is one function of ``(simulation, use_mag)`` in
:data:`ESTIMATORS` returning quaternions body → ENU (or a recording whose
``quaternions`` they are, and whose ``rest`` flags are reported too), or
None where it cannot run yet.
"""

import argparse
import inspect
import math
import sys
import time

import numpy as np

from bench import vehicle_sim
from bench.machine import add_page_arguments, log
from ext_observer.core.quaternion import rotation_matrices

MODES = ('6D', '9D')
TESLA_PER_MICROTESLA = 1e-6
# Fusion at the settings its README recommends (ext_observer.broad.anchors'
# FUSION_README), told a gyroscope range of a common MEMS full scale.
FUSION_GYRO_RANGE_DEG = 2000.0  # °/s
# The done-criteria: with the velocity, the inclination error's bound in
# every drive (and its goal); without, ours over VQF's on the turns.
VELOCITY_BOUND_DEG, VELOCITY_GOAL_DEG = 1.0, 0.3
RATIO_BOUND, RATIO_GOAL = 0.5, 0.3
OURS, OURS_VELOCITY = 'ours', 'ours + velocity'
NOT_YET = 'not yet available'
# The figures the long-turn problem was first stated with (level, 6D, no
# gyro bias; inclination error RMS over the turn, °).
BASELINE = (
    {'speed': 15.0, 'yaw_rate': 0.3, 'seconds': 40.0, 'ours': 21.8, 'VQF': 21.6,
     'apparent': 24.6},
    {'speed': 8.0, 'yaw_rate': 0.5, 'seconds': 100.0, 'ours': 14.6, 'VQF': 14.5,
     'apparent': None},
)
BASELINE_STRAIGHT = 10.0  # s at speed before the turn starts


def velocity_parameters():
    """
    Return the velocity inputs ``attitude_from_imu`` accepts, or ().

    ``('velocity', 'velocity_times')``, ``('velocity',)`` (one row per IMU
    sample) or () while the core takes none.
    """
    from ext_observer import attitude_from_imu
    names = inspect.signature(attitude_from_imu).parameters
    if 'velocity' not in names:
        return ()
    return ('velocity', 'velocity_times') if 'velocity_times' in names else ('velocity',)


def run_ours(sim, use_mag, velocity=False):
    """Ours as ``imu_filter_node`` runs (its defaults), with the field in T: a ``Recording``."""
    from ext_observer import attitude_from_imu
    extra = {}
    if velocity:
        accepted = velocity_parameters()
        if not accepted:
            return None
        extra['velocity'] = sim.velocity
        if 'velocity_times' in accepted:
            extra['velocity_times'] = sim.velocity_times
    mag = sim.mag * TESLA_PER_MICROTESLA if use_mag else None
    return attitude_from_imu(sim.gyr, sim.acc, mag, rate=sim.rate,
                             parameters={'use_mag': use_mag}, **extra)


def run_anchor(name, gyro_range=None):
    """An anchor as the BROAD benchmark runs it (``ext_observer.broad.anchors``)."""
    def run(sim, use_mag):
        from ext_observer.broad.anchors import anchor_estimates
        extra = {} if gyro_range is None else {'gyro_range': gyro_range}
        return anchor_estimates(name, sim.gyr, sim.acc, sim.mag, sim.rate, use_mag, **extra)
    return run


ESTIMATORS = {
    OURS: run_ours,
    OURS_VELOCITY: lambda sim, use_mag: run_ours(sim, use_mag, velocity=True),
    'VQF': run_anchor('VQF'),
    'Madgwick': run_anchor('Madgwick'),
    'Fusion': run_anchor('Fusion', gyro_range=math.radians(FUSION_GYRO_RANGE_DEG)),
}


def _rms_deg(angles):
    return math.degrees(math.sqrt(float(np.mean(angles * angles))))


def score(sim, estimate):
    """
    Inclination and heading errors' RMS (°) over the manoeuvre and the whole run.

    ``estimate``: quaternions, or a recording with ``quaternions`` and
    perhaps ``rest`` (then also the fraction of the manoeuvre taken for rest).
    """
    from ext_observer.broad.scoring import error_angles
    _, heading, inclination = error_angles(getattr(estimate, 'quaternions', estimate), sim.quat)
    m = sim.manoeuvre
    metrics = {'inclination_manoeuvre': _rms_deg(inclination[m]),
               'inclination_whole': _rms_deg(inclination),
               'heading_manoeuvre': _rms_deg(heading[m]), 'heading_whole': _rms_deg(heading)}
    rest = getattr(estimate, 'rest', None)
    if rest is not None:
        metrics['rest_manoeuvre'] = float(np.mean(np.asarray(rest)[m]))
    return metrics


def apparent_gravity(sim):
    """The inclination errors of taking the specific force as gravity."""
    up = np.einsum('nji,j->ni', rotation_matrices(sim.quat), (0.0, 0.0, 1.0))
    cosine = np.sum(up * sim.acc, axis=1) / np.linalg.norm(sim.acc, axis=1)
    angle = np.arccos(np.clip(cosine, -1.0, 1.0))
    return {'inclination_manoeuvre': _rms_deg(angle[sim.manoeuvre]),
            'inclination_whole': _rms_deg(angle)}


def run_scenarios(drives, seeds, estimators=None, progress=log):
    """
    Run every estimator on every drive and seed, in both modes.

    Returns
    -------
    list of dict
        One row per (drive, seed, mode, estimator): its metrics (None where
        the estimator cannot run yet) and the seconds it took; the
        estimator ``apparent gravity`` carries the inclination only.

    """
    estimators = ESTIMATORS if estimators is None else estimators
    rows = []
    for drive in drives:
        progress(f'vehicle: {drive.name} ...')
        for seed in range(seeds):
            sim = vehicle_sim.simulate(drive, seed=seed)
            base = {'scenario': drive.name, 'kind': drive.kind, 'seed': seed}
            for mode in MODES:
                rows.append({**base, 'mode': mode, 'estimator': 'apparent gravity',
                             'seconds': 0.0, **apparent_gravity(sim)})
                for name, run in estimators.items():
                    start = time.perf_counter()
                    estimate = run(sim, mode == '9D')
                    metrics = score(sim, estimate) if estimate is not None else None
                    rows.append({**base, 'mode': mode, 'estimator': name,
                                 'seconds': time.perf_counter() - start, 'metrics': metrics})
    return rows


def baseline(seed=0):
    """
    Measure the long-turn figures of :data:`BASELINE` again.

    A level vehicle, 6D, no gyro bias, at speed for :data:`BASELINE_STRAIGHT`
    s, then the yaw rate steps up and is held; the RMS is over the turn.
    """
    from ext_observer.broad.anchors import anchor_estimates
    Segment, Scenario = vehicle_sim.Segment, vehicle_sim.Scenario
    results = []
    for case in BASELINE:
        step = 1.0 / vehicle_sim.RATE
        drive = Scenario(name='baseline', description='', speed0=case['speed'],
                         gyro_bias_deg=0.0,
                         segments=(Segment(BASELINE_STRAIGHT),
                                   Segment(step, yaw_rate=case['yaw_rate'], manoeuvre=True),
                                   Segment(case['seconds'] - step, manoeuvre=True)))
        sim = vehicle_sim.simulate(drive, seed=seed)
        ours = score(sim, run_ours(sim, False))['inclination_manoeuvre']
        vqf = score(sim, anchor_estimates('VQF', sim.gyr, sim.acc, sim.mag, sim.rate, False))
        results.append({**case, 'measured': {
            'ours': ours, 'VQF': vqf['inclination_manoeuvre'],
            'apparent': apparent_gravity(sim)['inclination_manoeuvre']}})
    return results


def summarize(rows):
    """
    Average the rows over the seeds.

    Returns
    -------
    dict
        ``{(scenario, mode): {estimator: metrics or None}}`` in the rows'
        order; the metrics are the means over the seeds.

    """
    grouped = {}
    for row in rows:
        cell = grouped.setdefault((row['scenario'], row['mode']), {})
        metrics = row.get('metrics', {k: v for k, v in row.items()
                                      if k.startswith(('inclination', 'heading'))})
        cell.setdefault(row['estimator'], []).append(metrics)
    return {key: {name: _mean_metrics(runs) for name, runs in cell.items()}
            for key, cell in grouped.items()}


def _mean_metrics(runs):
    if any(run is None for run in runs):
        return None
    return {k: float(np.mean([run[k] for run in runs])) for k in runs[0]}


def ratio(summary, key, metric='inclination_manoeuvre'):
    """Ours over VQF for one (scenario, mode), or None."""
    ours, vqf = summary[key].get(OURS), summary[key].get('VQF')
    if not ours or not vqf or vqf[metric] == 0.0:
        return None
    return ours[metric] / vqf[metric]


def verdicts(summary, kinds):
    """
    The done-criteria, as rows ``(criterion, measured, verdict)``.

    ``kinds`` maps a scenario's name to its kind (``'turn'`` or another).
    """
    rows = []
    with_velocity = [cell.get(OURS_VELOCITY) for cell in summary.values()]
    if any(m is None for m in with_velocity) or not with_velocity:
        rows.append((f'with the velocity: inclination ≤ {VELOCITY_BOUND_DEG:g}° RMS in every '
                     f'drive (goal {VELOCITY_GOAL_DEG:g}°)', NOT_YET, 'not yet'))
    else:
        worst = max(m['inclination_manoeuvre'] for m in with_velocity)
        rows.append((f'with the velocity: inclination ≤ {VELOCITY_BOUND_DEG:g}° RMS in every '
                     f'drive (goal {VELOCITY_GOAL_DEG:g}°)', f'worst {worst:.2f}°',
                     _verdict(worst, VELOCITY_BOUND_DEG, VELOCITY_GOAL_DEG)))
    for (scenario, mode) in summary:
        if kinds.get(scenario) != 'turn':
            continue
        value = ratio(summary, (scenario, mode))
        rows.append((f'without: ours/VQF ≤ {RATIO_BOUND:g} on {scenario}, {mode} '
                     f'(goal {RATIO_GOAL:g})', '–' if value is None else f'{value:.2f}',
                     'unknown' if value is None else _verdict(value, RATIO_BOUND, RATIO_GOAL)))
    return rows


def _verdict(value, bound, goal):
    if value <= goal:
        return 'goal met'
    return 'met' if value <= bound else 'not met'


def _versions():
    from importlib import metadata
    found = []
    for name in ('vqf', 'AHRS', 'imufusion'):
        try:
            found.append(f'{name.lower()} {metadata.version(name)}')
        except metadata.PackageNotFoundError:
            found.append(f'{name.lower()} not installed')
    return ', '.join(found)


def build_parser():
    """Return the parser of ``python -m bench.vehicle``."""
    parser = argparse.ArgumentParser(
        prog='python -m bench.vehicle',
        description='Attitude estimators on a simulated road vehicle; writes docs/vehicle.md.')
    parser.add_argument('--seeds', type=int, default=3, help='noise seeds per drive (3)')
    parser.add_argument('--quick', action='store_true',
                        help='one seed, the level drives only (a smoke run)')
    add_page_arguments(parser, 'vehicle.md')
    return parser


def main(argv=None):
    """Run the benchmark, print and write the page; return 0."""
    from bench import machine
    from ext_observer.broad.data import shown_command
    # As the package's commands find their pages: the page imports this module.
    from ext_observer.source_tree import docgen
    vehicle_page = docgen('vehicle_page')
    argv = sys.argv[1:] if argv is None else list(argv)
    args = build_parser().parse_args(argv)

    def run():
        drives = vehicle_sim.scenarios()
        seeds = args.seeds
        if args.quick:
            drives, seeds = [d for d in drives if not d.slope_deg], 1
        log('vehicle: the long turn as first measured ...')
        return {'versions': _versions(), 'seeds': seeds, 'baseline': baseline(),
                'rows': run_scenarios(drives, seeds), 'drive_names': [d.name for d in drives]}

    def render(results):
        by_name = {d.name: d for d in vehicle_sim.scenarios()}
        drives = [by_name[n] for n in results['drive_names'] if n in by_name]
        return vehicle_page.render(dict(results, drives=drives))
    return machine.page_main(args, shown_command(['python -m bench.vehicle', *argv]), run, render,
                             machine.page_path(args))

if __name__ == '__main__':
    sys.exit(main())
