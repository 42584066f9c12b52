"""
``python -m bench.vehicle``: attitude estimators on a simulated road vehicle.

Every drive of :func:`bench.vehicle_sim.scenarios` (long turns on level and
sloped roads, accelerating and braking, a rough road) is simulated with
noise and a gyro bias, and run through ours (``attitude_from_imu``), ours
with the vehicle's velocity (once the core takes one), VQF, Madgwick and
Fusion, in 6D and 9D. Each is scored against the true attitude (BROAD's
error angles): the inclination error's RMS over the manoeuvre and over the
whole run, and in 9D the heading error's. The Markdown goes to stdout and
to docs/vehicle.md, progress to stderr.

An estimator is one function of ``(simulation, use_mag)`` in
:data:`ESTIMATORS` returning quaternions body → ENU (or a recording whose
``quaternions`` they are, and whose ``rest`` flags are reported too), or
None where it cannot run yet.
"""

import argparse
import inspect
import json
import math
import os
import sys
import time

import numpy as np

from bench import vehicle_sim
from bench.procs import REPO

MODES = ('6D', '9D')
TESLA_PER_MICROTESLA = 1e-6
# Fusion at the settings its README recommends: gain 0.5, a gyroscope range
# (a common MEMS full scale), rejection thresholds 10°, 5 s before recovery.
FUSION_GAIN = 0.5
FUSION_GYRO_RANGE_DEG = 2000.0  # °/s
FUSION_REJECTION_DEG = 10.0
FUSION_REJECTION_TIMEOUT = 5.0  # s (imufusion 1.3: seconds; older: 5 · rate samples)
STANDARD_GRAVITY = 9.80665  # m/s²; Fusion takes the specific force in g
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


def _log(text):
    print(text, file=sys.stderr, flush=True)


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


def run_anchor(name):
    """VQF or Madgwick as the BROAD benchmark runs them (``ext_observer.broad.anchors``)."""
    def run(sim, use_mag):
        from ext_observer.broad.anchors import anchor_estimates
        return anchor_estimates(name, sim.gyr, sim.acc, sim.mag, sim.rate, use_mag)
    return run


def run_fusion(sim, use_mag):
    """Fusion (``imufusion``) at its README's settings, with its gyro bias correction."""
    import imufusion
    from ext_observer.broad.anchors import NWU_TO_ENU
    from ext_observer.core.quaternion import multiply
    ahrs = imufusion.Ahrs()
    ahrs.set_settings(imufusion.AhrsSettings(
        sample_rate=sim.rate, gain=FUSION_GAIN, gyroscope_range=FUSION_GYRO_RANGE_DEG,
        acceleration_rejection=FUSION_REJECTION_DEG, magnetic_rejection=FUSION_REJECTION_DEG,
        rejection_timeout=FUSION_REJECTION_TIMEOUT))
    ahrs.set_sample_period(1.0 / sim.rate)
    bias = imufusion.Bias()
    bias.set_settings(imufusion.BiasSettings(sample_rate=sim.rate))
    gyr, acc = np.degrees(sim.gyr), sim.acc / STANDARD_GRAVITY
    q = np.empty((len(gyr), 4))
    for k in range(len(gyr)):
        if use_mag:
            ahrs.update(bias.update(gyr[k]), acc[k], sim.mag[k])
        else:
            ahrs.update_no_magnetometer(bias.update(gyr[k]), acc[k])
        q[k] = ahrs.get_quaternion()
    # Its default convention is NWU (the constructor's is ignored in 1.3).
    return multiply(np.asarray(NWU_TO_ENU), q)


ESTIMATORS = {
    OURS: run_ours,
    OURS_VELOCITY: lambda sim, use_mag: run_ours(sim, use_mag, velocity=True),
    'VQF': run_anchor('VQF'),
    'Madgwick': run_anchor('Madgwick'),
    'Fusion': run_fusion,
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
    up = np.einsum('nji,j->ni', vehicle_sim.matrices(sim.quat), (0.0, 0.0, 1.0))
    cosine = np.sum(up * sim.acc, axis=1) / np.linalg.norm(sim.acc, axis=1)
    angle = np.arccos(np.clip(cosine, -1.0, 1.0))
    return {'inclination_manoeuvre': _rms_deg(angle[sim.manoeuvre]),
            'inclination_whole': _rms_deg(angle)}


def run_scenarios(drives, seeds, estimators=None, progress=_log):
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


# The report.

COLUMNS = ('apparent gravity', OURS, OURS_VELOCITY, 'VQF', 'Madgwick', 'Fusion')


def _cell(metrics, metric, whole=None):
    if metrics is None:
        return NOT_YET
    text = f'{metrics[metric]:.2f}'
    return f'{text} ({metrics[whole]:.2f})' if whole else text


def error_table(summary, mode, metric, whole=None, columns=COLUMNS):
    """One Markdown table: a row per drive, a column per estimator, then ours/VQF."""
    names = [c for c in columns if any(c in summary[key] for key in summary if key[1] == mode)]
    lines = ['| drive | ' + ' | '.join(names) + ' | ours/VQF |',
             '|---|' + '---:|' * (len(names) + 1)]
    for (scenario, m), cell in summary.items():
        if m != mode:
            continue
        value = ratio(summary, (scenario, m), metric)
        cells = [_cell(cell[n], metric, whole) if n in cell else '–' for n in names]
        lines.append(f'| {scenario} | ' + ' | '.join(cells)
                     + f' | {"–" if value is None else f"{value:.2f}"} |')
    return '\n'.join(lines)


def rest_table(summary):
    """Share of each drive's manoeuvre that ours took for rest, per mode (%)."""
    lines = ['| drive | ' + ' | '.join(MODES) + ' |', '|---|' + '---:|' * len(MODES)]
    for scenario in dict.fromkeys(key[0] for key in summary):
        cells = []
        for mode in MODES:
            metrics = summary.get((scenario, mode), {}).get(OURS)
            rest = None if not metrics else metrics.get('rest_manoeuvre')
            cells.append('–' if rest is None else f'{100.0 * rest:.0f} %')
        lines.append(f'| {scenario} | ' + ' | '.join(cells) + ' |')
    return '\n'.join(lines)


def _baseline_section(results):
    lines = ['| turn | stated: ours / VQF / apparent gravity | measured here |', '|---|---|---|']
    for case in results:
        stated = ' / '.join('–' if case[k] is None else f'{case[k]:.1f}°'
                            for k in ('ours', 'VQF', 'apparent'))
        measured = ' / '.join(f'{case["measured"][k]:.1f}°' for k in ('ours', 'VQF', 'apparent'))
        a_c = case['speed'] * case['yaw_rate'] / vehicle_sim.STANDARD_G
        lines.append(f'| {case["speed"]:g} m/s at {case["yaw_rate"]:g} rad/s '
                     f'({a_c:.2f} g) for {case["seconds"]:g} s | {stated} | {measured} |')
    return '\n'.join(lines)


def _drives_section(drives):
    lines = ['| drive | what | manoeuvre | whole run |', '|---|---|---:|---:|']
    for drive in drives:
        times, *_, manoeuvre = vehicle_sim.profile(drive)
        road = f', road {drive.slope_deg:g}° (plane tilted about east)' if drive.slope_deg else ''
        lines.append(f'| {drive.name} | {drive.description}{road} | '
                     f'{manoeuvre.sum() / vehicle_sim.RATE:.0f} s | {times[-1]:.0f} s |')
    return '\n'.join(lines)


def _made_by(results):
    m = results['machine']
    return (f'**Made by** `{results["command"]}` at commit `{m["commit"]}`, {m["date"]}, on '
            f'{m["cpu"]}, {m["cores"]} cores, Python {m["python"]}, numpy {m["numpy"]}; '
            f'{results["versions"]}; the run took {results["seconds"]:.0f} s '
            f'(1-minute load average {m["load_start"]} at the start, on a shared machine).')


def render(results):
    """Return docs/vehicle.md from the results of :func:`main`."""
    return '\n\n'.join(_method_parts(results) + _result_parts(results)) + '\n'


def _method_parts(results):
    """The page's head: what was simulated, run and scored, and how it was made."""
    seeds = results['seeds']
    s = vehicle_sim
    return [
        '# A road vehicle: long turns, braking, a rough road',
        'An IMU on a vehicle feels gravity plus the vehicle\'s own acceleration: in a long '
        'turn the centripetal part never averages out, and every filter that takes the '
        'specific force for gravity tilts towards it. This page measures by how much, on '
        'simulated drives, for ours and the anchors. Generated by `python -m bench.vehicle` '
        '(`bench/vehicle.py`, the simulator `bench/vehicle_sim.py`); do not edit it by hand.',
        _made_by(results),
        '## The drives',
        f'Simulated at {s.RATE:g} Hz. World ENU, gravity {s.GRAVITY:g} m/s² down (the '
        'accelerometer reads +g up at rest); body x forward, y left, z up; the IMU in the '
        'body frame. The vehicle drives on a plane (level, or tilted about east: heading '
        'north climbs), without side slip: body velocity `(v, 0, 0)`, angular velocity '
        '`(0, 0, ψ̇)`, specific force `f = (v̇, ψ̇ v, 0) + R^T (0, 0, g)` '
        '(`dv_b/dt + ω × v_b` plus gravity\'s reaction). Every drive starts with '
        f'{s.REST:g} s at rest; the turns are reached after {s.CRUISE_SPEED / s.START_ACCEL:g} s '
        f'at {s.START_ACCEL:g} m/s² and 10 s straight. Centripetal `a_c = v ω`.',
        _drives_section(results['drives']),
        f'**Sensors.** Gyro white noise {s.GYRO_NOISE:g} rad/s per sample and a constant '
        f'bias of {s.GYRO_BIAS_DEG:g} °/s along a direction drawn from the seed; '
        f'accelerometer noise {s.ACC_NOISE:g} m/s²; magnetometer {s.FIELD_UT:g} µT dipping '
        f'{s.FIELD_DIP_DEG:g}°, noise {s.MAG_NOISE:g} µT, undisturbed. The rough road adds '
        f'band-limited vibration ({s.VIBRATION_BAND[0]:g}–{s.VIBRATION_BAND[1]:g} Hz, RMS '
        f'{", ".join(f"{v:g}" for v in s.VIBRATION_RMS)} m/s² on x, y, z, fading in below '
        f'{s.VIBRATION_FULL_SPEED:g} m/s) to the specific force; the stored velocity is the '
        f'wheels\', without it. Seeds 0–{seeds - 1}: each figure is the mean over the seeds.',
        '**Estimators**, each on the same samples: ours (`ext_observer.attitude_from_imu`, '
        'the node\'s defaults, field in T); ours with the vehicle\'s body velocity '
        + (f'(shown as "{NOT_YET}" until `attitude_from_imu` takes a `velocity`)'
           if not velocity_parameters() else
           '(the velocity aid, [raw_imu.md](raw_imu.md#a-velocity-aid-vehicles))')
        + '; VQF (`vqf`, '
        'defaults) and Madgwick (`ahrs`, β = 0.12, BROAD\'s trial-agnostic best) as the '
        'BROAD benchmark runs them ([broad.md](broad.md)); Fusion (`imufusion`, '
        'x-io Technologies) at the settings its README recommends: gain '
        f'{FUSION_GAIN:g}, gyroscope range {FUSION_GYRO_RANGE_DEG:g} °/s, acceleration and '
        f'magnetic rejection {FUSION_REJECTION_DEG:g}°, {FUSION_REJECTION_TIMEOUT:g} s before '
        'a recovery, with its gyroscope bias correction (`imufusion.Bias`) before it. '
        '"apparent gravity" is the inclination of the specific force itself.',
        '**Scoring.** BROAD\'s error angles ([broad.md](broad.md)) of the estimate against '
        'the true attitude: the RMS, in degrees, over the manoeuvre (the turn with its '
        'ramps; the accelerating and braking; the rough stretch), and in parentheses over '
        'the whole run; ours/VQF is over the manoeuvre.',
    ]


def _result_parts(results):
    summary = summarize(results['rows'])
    kinds = {row['scenario']: row['kind'] for row in results['rows']}
    s = vehicle_sim
    return [
        '## The long turn as first measured',
        f'A level vehicle, 6D, gyro noise {s.GYRO_NOISE:g} rad/s, accelerometer noise '
        f'{s.ACC_NOISE:g} m/s², no gyro bias: {BASELINE_STRAIGHT:g} s straight at speed, '
        'then the yaw rate steps to its value and stays; the inclination error\'s RMS over '
        'the turn (seed 0).',
        _baseline_section(results['baseline']),
        'The estimate tilts towards a low-passed apparent gravity, whose horizontal part '
        'turns with the vehicle at ω: the faster the turn, the more the filter lags behind '
        'it and the less it tilts. A second-order Butterworth low-pass with VQF\'s τ_acc = '
        '3 s (cut-off √2 / (2π τ), as VQF defines it) passes 93 % of the tilt at 0.3 rad/s '
        '(22.8° of 24.6°) and 66 % at 0.5 rad/s (14.7° of 22.2°), which the figures '
        'above approach once the start of the turn has passed.',
        '## 6D: inclination error (°)',
        error_table(summary, '6D', 'inclination_manoeuvre', 'inclination_whole'),
        '## 9D: inclination error (°)',
        error_table(summary, '9D', 'inclination_manoeuvre', 'inclination_whole'),
        '## 9D: heading error (°)',
        error_table(summary, '9D', 'heading_manoeuvre', 'heading_whole', columns=COLUMNS[1:]),
        '## Rest detected by ours during the manoeuvre',
        'Rest is where ours learns its gyro bias fast: a manoeuvre taken for rest (a turn '
        'at a constant rate and speed keeps gyro and specific force steady) teaches it the '
        'turn\'s yaw rate as a bias, up to `ahrs.bias_max`, which the heading then pays for.',
        rest_table(summary),
        '## The done-criteria',
        'With the vehicle\'s velocity, the inclination error at most '
        f'{VELOCITY_BOUND_DEG:g}° RMS in every drive (goal {VELOCITY_GOAL_DEG:g}°); without '
        f'it, ours at most {RATIO_BOUND:g}× VQF\'s on the turns (goal {RATIO_GOAL:g}×), '
        'over the manoeuvre.',
        '| criterion | measured | verdict |\n|---|---|---|\n' + '\n'.join(
            f'| {a} | {b} | {c} |' for a, b, c in verdicts(summary, kinds)),
        '## The velocity aid\'s input',
        'The harness passes ours the vehicle\'s velocity as soon as `attitude_from_imu` '
        'has a `velocity` parameter (found by its signature): `velocity`, shape (M, 3), m/s, '
        'the body\'s velocity in the IMU\'s frame (here the body frame: no mounting rotation, '
        'no lever arm), and `velocity_times`, shape (M,), s, on the IMU\'s clock, where the '
        'signature has it (here M = N, the IMU\'s times). The estimator removes '
        '`dv/dt + ω × v` from the specific force before taking it for gravity.',
        '## Runtime',
        _runtime(results['rows']),
    ]


def _runtime(rows):
    totals = {}
    for row in rows:
        if row['estimator'] != 'apparent gravity' and row.get('metrics') is not None:
            totals[row['estimator']] = totals.get(row['estimator'], 0.0) + row['seconds']
    return ('Seconds spent in each estimator over every drive, seed and mode: '
            + ', '.join(f'{name} {seconds:.1f} s' for name, seconds in totals.items()) + '.')


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
    parser.add_argument('--output', default=os.path.join(REPO, 'docs', 'vehicle.md'),
                        help='Markdown file to write (default docs/vehicle.md)')
    parser.add_argument('--no-write', action='store_true', help='print only, write no file')
    parser.add_argument('--json', metavar='PATH', help='also write the raw results')
    parser.add_argument('--render', metavar='JSON', help='only render results saved by --json')
    return parser


def main(argv=None):
    """Run the benchmark, print and write the page; return 0."""
    from bench import machine
    argv = sys.argv[1:] if argv is None else list(argv)
    args = build_parser().parse_args(argv)
    if args.render:
        with open(args.render) as saved:
            results = json.load(saved)
    else:
        start = time.monotonic()
        drives = vehicle_sim.scenarios()
        seeds = args.seeds
        if args.quick:
            drives, seeds = [d for d in drives if not d.slope_deg], 1
        results = {'machine': machine.describe(), 'versions': _versions(), 'seeds': seeds,
                   'command': ' '.join(['python -m bench.vehicle'] + argv)}
        _log('vehicle: the long turn as first measured ...')
        results['baseline'] = baseline()
        results['rows'] = run_scenarios(drives, seeds)
        results['seconds'] = time.monotonic() - start
        results['drive_names'] = [d.name for d in drives]
        if args.json:
            with open(args.json, 'w') as out:
                json.dump(results, out, indent=1)
    by_name = {d.name: d for d in vehicle_sim.scenarios()}
    results['drives'] = [by_name[n] for n in results['drive_names'] if n in by_name]
    # `python -m bench`'s own writer: print, and write unless --no-write.
    return machine.write_page(render(results), None if args.no_write else args.output)


if __name__ == '__main__':
    sys.exit(main())
