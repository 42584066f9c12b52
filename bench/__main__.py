"""
``python -m bench``: run every benchmark, print the tables, write the file.

Sections: batch core (with ``reproduce --seeds 5``), node throughput and
latency (relay and observer, per executor), accuracy beside the limit, the
node's profile, and the raw-IMU estimator (``imu_filter_node`` beside a
relay, its callbacks' parts, the core over BROAD) with its speed goals;
``load`` runs ``python -m bench.load``, which writes its own page,
``docs/load.md``, beside the output.
Progress goes to stderr, the Markdown to stdout and to
``docs/performance.md``. Timing never fails the run; a section that cannot
run (a node that does not start, no BROAD data) is reported as such.
"""

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

from bench import machine
from bench.machine import log
from docgen import performance_page
from bench.procs import REPO, reserved_domain_id, ros_env
from ext_observer.broad.data import shown_command

SECTIONS = ('batch', 'accuracy', 'nodes', 'profile', 'raw_imu', 'compiled', 'load',
            'vehicle')
# The raw-IMU benchmarks, each a command of its own that prints its figures
# and verdict (its output goes to stderr here) and writes them with --json.
RAW_IMU = (
    ('node_events', ['bench.imu_filter_cpu', '--executor', 'events', '--seconds', '8',
                     '--rounds', '5', '--serialized']),
    ('node_single', ['bench.imu_filter_cpu', '--executor', 'single', '--seconds', '8',
                     '--rounds', '3']),
    ('direct', ['bench.raw_imu_direct']),
    ('batch', ['bench.broad_batch', '--runs', '3', '--vectorized']),
)
# A road vehicle: every drive over three seeds, or the level drives once.
VEHICLE = ['bench.vehicle']
VEHICLE_QUICK = ['bench.vehicle', '--quick']
# Lost samples and a busy machine: the whole trial, or a short part of it.
LOAD = ['bench.load']
LOAD_QUICK = ['bench.load', '--start', '30', '--seconds', '20',
              '--speeds', '1', '4', '--modes', '9D', '--fields', '100']
RAW_IMU_QUICK = (
    ('node_events', ['bench.imu_filter_cpu', '--executor', 'events', '--seconds', '2',
                     '--rounds', '1']),
    ('direct', ['bench.raw_imu_direct', '--samples', '1000']),
)


def _batch(quick):
    from bench import core_speed
    result = {}
    log('batch core: observer updates per second ...')
    sizes = (1, 1000) if quick else core_speed.BATCH_SIZES
    result['observer_rates'] = core_speed.observer_rates(sizes)
    result['single'] = core_speed.single_observer_costs()
    log('batch core: products and exp ...')
    result['products'] = core_speed.product_costs()
    result['lean'] = core_speed.lean_prototype_rate()
    result['reproduce'] = []
    if not quick:
        log('batch core: reproduce --seeds 5 ...')
        result['reproduce'].append(core_speed.reproduce_time(5))
        result['reproduce'].append(core_speed.reproduce_time(5, no_plots=True))
    return result


def _nodes(quick, log_dir):
    from bench import nodes
    targets = nodes.relay_targets()
    notes = ['Queue depth 10 (reliable, keep last) except the `-depth100` '
             'targets and the polling relay (100: `--depth 100`; the observer '
             'node\'s default `queue_depth`); the probe keeps 1000.',
             'relay/events-poll2ms is `bench.relay.PollingRelay`: its '
             'subscriptions are never spun, one 2 ms timer on the '
             'EventsExecutor takes every waiting message and pairs them (fewer '
             'wake-ups, messages taken in batches; up to 2 ms added latency).']
    if os.path.exists(os.path.join(REPO, 'ext_observer', 'nodes', 'observer_node.py')):
        targets += nodes.observer_targets()
        notes.append('observer/single and observer/events are the shipped entry '
                     'point (`python -m ext_observer.nodes.observer_node --executor '
                     'single|events -p queue_depth:=10`); observer/events-depth100 '
                     'is the entry point as shipped, with its defaults '
                     '(EventsExecutor, `queue_depth` 100); observer/multi hosts '
                     'the same `ObserverNode` class on a MultiThreadedExecutor in '
                     '`bench/observer_host.py`. Parameters: the defaults '
                     '(extended, paper gain) and `diagnostic_period:=0.1`.')
    else:
        notes.append('The observer node is not in the repository yet: '
                     'relay only.')
    rates = nodes.RATES
    seconds, latency_seconds = nodes.SEGMENT_SECONDS, nodes.LATENCY_SECONDS
    if quick:
        rates, seconds, latency_seconds = (250, 1000, 4000), 1.0, 1.0
    results = []
    for index, target in enumerate(targets):
        log(f'node throughput: {target.name} ...')
        results += nodes.sweep(target, index, rates, seconds, latency_seconds,
                               log_dir=log_dir, progress=log)
    return results, list(rates), notes


def _profile(log_dir):
    from bench import profile_node
    if not os.path.exists(os.path.join(REPO, 'ext_observer', 'nodes', 'observer_node.py')):
        return None, []
    log('profile: the node\'s callbacks, direct ...')
    direct = profile_node.profile_direct(index=10, log_dir=log_dir)
    loops = []
    for index, (node, executor) in enumerate(
            (('observer', 'single'), ('relay', 'single'),
             ('observer', 'events'), ('relay', 'events'))):
        log(f'profile: {node}/{executor} at {profile_node.LOOP_RATE} Hz ...')
        loops.append(profile_node.profile_loop(executor, index=11 + index,
                                               log_dir=log_dir, node=node))
    return direct, loops


def _raw_imu(quick, log_dir):
    result = {}
    with tempfile.TemporaryDirectory(prefix='bench-') as tmp:
        for index, (key, args) in enumerate(RAW_IMU_QUICK if quick else RAW_IMU):
            log(f'raw IMU: python -m {" ".join(args)} ...')
            extra = ['--log-dir', log_dir] if log_dir and key.startswith('node') else []
            # The direct timing starts a node in this process's child: a
            # domain of its own.
            result[key] = _json_result(args, extra, os.path.join(tmp, f'{key}.json'), 30 + index,
                                       sys.stderr)
    return result


def _compiled(quick):
    """The compiled kernels' figures: ``python -m bench.compiled_kernels --json``.

    The node's CPU is section 6's.
    """
    args = ['bench.compiled_kernels'] + (['--sections', 'steps'] if quick else [])
    log(f'compiled kernels: python -m {" ".join(args)} ...')
    os.makedirs(os.path.join(REPO, 'out'), exist_ok=True)
    # Relative to the repository, as the page shows the command (a reader can rerun it).
    return _json_result(args, [], os.path.join('out', 'bench_compiled.json'), 40,
                        subprocess.DEVNULL)


def _json_result(args, extra, out, index, stdout):
    """``python -m args extra --json out`` in a ROS domain of its own: its results, or why none."""
    path = os.path.join(REPO, out)
    if os.path.exists(path):
        os.remove(path)
    with reserved_domain_id(index) as domain_id:
        done = subprocess.run([sys.executable, '-m', *args, *extra, '--json', out], cwd=REPO,
                              env=ros_env(domain_id), stdout=stdout)
    if not os.path.exists(path):
        return {'error': f'`python -m {" ".join(args)}` ended with exit code '
                         f'{done.returncode} and no result'}
    with open(path) as f:
        return json.load(f)


def _load(quick, args):
    """Run ``python -m bench.load`` (its page beside the output); return a note."""
    extra = [] if args.no_write else ['--docs', os.path.dirname(os.path.abspath(args.output))]
    if args.log_dir:
        extra += ['--log-dir', args.log_dir]
    return _page_benchmark('Lost samples and a busy machine', LOAD_QUICK if quick else LOAD,
                           extra, None if args.no_write else 'load.md')


def _vehicle(quick, args):
    """Run ``python -m bench.vehicle`` (its page beside the output); return a note."""
    extra = (['--no-write'] if args.no_write else
             ['--output', os.path.join(os.path.dirname(os.path.abspath(args.output)),
                                       'vehicle.md')])
    return _page_benchmark('A road vehicle', VEHICLE_QUICK if quick else VEHICLE, extra,
                           None if args.no_write else 'vehicle.md')


def _page_benchmark(label, command, extra, page):
    """Run a benchmark that writes its own page; return the note that says how long it took."""
    log(f'{label.lower()}: python -m {" ".join(command + extra)} ...')
    start = time.monotonic()
    # Its progress goes to stderr; the page it prints is in its own file.
    done = subprocess.run([sys.executable, '-m', *command, *extra], cwd=REPO,
                          stdout=subprocess.DEVNULL)
    return (f'{label}: `python -m {" ".join(command)}` took '
            f'{time.monotonic() - start:.0f} s' + (f', its page is {page}' if page else '')
            + (f' (exit code {done.returncode})' if done.returncode else '') + '.')


def build_parser():
    """Return the parser of ``python -m bench``."""
    parser = argparse.ArgumentParser(
        prog='python -m bench',
        description='Benchmarks of ext_observer; writes docs/performance.md.')
    parser.add_argument('--sections', default=','.join(SECTIONS),
                        help=f'comma-separated subset of {",".join(SECTIONS)}')
    parser.add_argument('--quick', action='store_true',
                        help='a short smoke run (few sizes and rates)')
    parser.add_argument('--log-dir', metavar='DIR',
                        help="keep the child processes' stderr there")
    machine.add_page_arguments(parser, 'performance.md')
    return parser


def main(argv=None):
    """Run the benchmarks; return 0 (timings never fail the run)."""
    argv = sys.argv[1:] if argv is None else list(argv)
    args = build_parser().parse_args(argv)
    sections = [s.strip() for s in args.sections.split(',') if s.strip()]
    unknown = set(sections) - set(SECTIONS)
    if unknown:
        print(f'error: unknown sections {sorted(unknown)}; choose from '
              f'{SECTIONS}', file=sys.stderr)
        return 2
    if args.log_dir:
        os.makedirs(args.log_dir, exist_ok=True)
    return machine.page_main(args, shown_command(['python -m bench', *argv]),
                             lambda: _run(args, sections), performance_page.render,
                             machine.page_path(args))


def _run(args, sections):
    """Run the sections asked for; return the results the page is rendered from."""
    start = time.monotonic()
    results = {}
    notes = []
    if 'batch' in sections:
        results['batch'] = _batch(args.quick)
    if 'accuracy' in sections:
        from bench import core_speed
        log('accuracy: Table 1 setup ...')
        results['accuracy'] = core_speed.accuracy()
    if 'nodes' in sections:
        results['nodes'], results['rates'], results['node_notes'] = _nodes(
            args.quick, args.log_dir)
    if 'profile' in sections:
        try:
            results['profile_direct'], results['profile_loops'] = _profile(
                args.log_dir)
        except RuntimeError as error:
            notes.append(f'profile failed: {error.args[0].splitlines()[0]}')
    if 'raw_imu' in sections:
        results['raw_imu'] = _raw_imu(args.quick, args.log_dir)
    if 'compiled' in sections:
        results['compiled'] = _compiled(args.quick)
    if 'load' in sections:
        notes.append(_load(args.quick, args))
    if 'vehicle' in sections:
        notes.append(_vehicle(args.quick, args))
    notes.append(f'The whole run took {time.monotonic() - start:.0f} s.')
    results['notes'] = notes
    return results

if __name__ == '__main__':
    sys.exit(main())
