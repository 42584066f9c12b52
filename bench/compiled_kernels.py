"""
The compiled kernels against the plain ones and VQF: ``python -m bench.compiled_kernels``.

Figures for the raw-IMU estimator's compiled step (core/ahrs/compiled.py, numba),
printed and, with ``--docs DIR``, written to ``DIR/compiled.md``
(:mod:`docgen.compiled_page`):

1. **BROAD, 22 trials × 9D and 6D**, in one run: VQF (C++, the ``vqf``
   package, one process), ours compiled (warm cache) in one process and in
   two (``estimate_batch(workers=2)``: the recordings shared between the
   cores), and ours plain (``EXT_OBSERVER_COMPILED=0``, two processes); the
   largest difference of the estimates and of BROAD's total RMSE between
   compiled and plain.
2. **Per sample, on floats**: ``AhrsObserver.update`` (what the node calls)
   compiled and plain, and the compiled whole-recording loop, on the shipped
   excerpt (9D with the calibration, and 6D).
3. **Start-up**: a fresh process getting the kernels with an empty cache
   (compiling) and with a warm one; ``imu_filter_node`` and
   ``observer_node`` from launch to their first ``/diagnostics`` (cold and
   warm cache), and ``imu_filter_node`` to its first status on the compiled
   kernels (cold: after its background compile); ``python -m ext_observer
   broad --no-anchors`` on the 22 trials, cold and warm.
4. **The BROAD command whole**: ``python -m ext_observer broad
   --no-anchors`` on the 22 trials (9D and 6D; a warm cache), the whole
   process, against VQF doing the same work in one process
   (``python -m bench.broad_vqf``: read, estimate both modes, score), runs
   interleaved, medians; and the command's time to its first estimate (its
   line announcing the batched call).

Every ROS process runs with ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``.
The node's CPU per sample against a bare relay is ``python -m bench.imu_filter_cpu``
(also in ``make bench``); ``--node`` runs it here too.
"""

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time

import numpy as np

from bench.machine import log, save_json
from bench.rosutil import kernels_of

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
EXCERPT = os.path.join(REPO, 'test', 'data', 'broad_01_undisturbed_slow_rotation_A.npz')
# The compiled kernels' goals: the node's CPU per IMU sample within this factor of a
# bare relay's; BROAD's wall time within this factor of VQF's (aim: 1), the
# scores unchanged to this many degrees, the step on floats within this many
# µs, a node's first start within these seconds (cold, warm); the BROAD
# command's whole process within this factor of VQF's doing the same work
# (aim: the second).
COMPILED_NODE_GOAL = 1.1
BROAD_GOAL = 3.0
SCORE_TOLERANCE = 1e-9
STEP_GOAL_US = 2.0
COLD_GOAL_S = 10.0
WARM_GOAL_S = 2.0
WHOLE_GOAL = 1.0
WHOLE_AIM = 0.5


def _env(**extra):
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    env.update(extra)
    return env


# --- 1. BROAD -------------------------------------------------------------------------

def broad_figures(trials, progress=print):
    """Wall times on the trials (both modes) and the compiled/plain agreement."""
    from ext_observer.broad import score
    from ext_observer.broad.anchors import anchor_estimates
    from ext_observer.pipeline.batch import estimate_batch
    from ext_observer.pipeline.kernel_cache import load
    load()  # warm
    rate = trials[0].rate
    out = {'samples': int(sum(len(t.gyr) for t in trials)), 'trials': len(trials)}
    runs = {}
    for label, workers, plain in (('compiled, 1 process', 1, False),
                                  ('compiled, 2 processes', 2, False),
                                  ('plain, 2 processes', 2, True)):
        saved = os.environ.get('EXT_OBSERVER_COMPILED')
        os.environ['EXT_OBSERVER_COMPILED'] = '0' if plain else '1'
        try:
            start = time.perf_counter()
            est = {}
            for mode in ('9D', '6D'):
                nine = mode == '9D'
                est[mode] = estimate_batch([t.gyr for t in trials], [t.acc for t in trials],
                                           [t.mag if nine else None for t in trials],
                                           [rate] * len(trials), [nine] * len(trials),
                                           workers=workers)
            out[label] = time.perf_counter() - start
            runs[label] = est
        finally:
            if saved is None:
                del os.environ['EXT_OBSERVER_COMPILED']
            else:
                os.environ['EXT_OBSERVER_COMPILED'] = saved
        progress(f'{label}: {out[label]:.2f} s')
    start = time.perf_counter()
    for mode in ('9D', '6D'):
        for t in trials:
            anchor_estimates('VQF', t.gyr, t.acc, t.mag, t.rate, mode == '9D')
    out['VQF, 1 process'] = time.perf_counter() - start
    progress(f'VQF: {out["VQF, 1 process"]:.2f} s')
    a, b = runs['compiled, 2 processes'], runs['plain, 2 processes']
    dq, dscore = 0.0, 0.0
    for mode in ('9D', '6D'):
        for t, qa, qb in zip(trials, a[mode], b[mode]):
            dq = max(dq, float(np.max(np.abs(qa - qb))))
            key = 'total_rmse_deg' if mode == '9D' else 'inclination_rmse_deg'
            dscore = max(dscore, abs(score(qa, t.quat, t.movement)[key]
                                     - score(qb, t.quat, t.movement)[key]))
    out['max_dq'] = dq
    out['max_dscore'] = dscore
    return out


# --- 2. per sample ------------------------------------------------------------------------

def step_figures():
    """µs per sample of ``update`` (compiled, plain) and of the compiled loop."""
    from ext_observer.core.ahrs.ahrs_observer import AhrsObserver, AhrsParams
    d = np.load(EXCERPT)
    gyr, acc, mag, dt = d['gyr'], d['acc'], d['mag'], 1.0 / float(d['rate'])
    g, a, m = gyr.tolist(), acc.tolist(), mag.tolist()
    out = {'samples': len(g)}
    for mode, use_mag in (('9D', True), ('6D', False)):
        for compiled in (True, False):
            best = np.inf
            for _ in range(3):
                est = AhrsObserver(AhrsParams(), use_mag=use_mag, compiled=compiled)
                update = est.update
                start = time.perf_counter()
                for k in range(len(g)):
                    update(g[k], a[k], m[k], dt)
                best = min(best, time.perf_counter() - start)
            out[(mode, 'update', compiled)] = best / len(g) * 1e6
        best = np.inf
        for _ in range(3):
            est = AhrsObserver(AhrsParams(), use_mag=use_mag, compiled=True)
            start = time.perf_counter()
            est.run(gyr, acc, mag if use_mag else None, dt)
            best = min(best, time.perf_counter() - start)
        out[(mode, 'run', True)] = best / len(g) * 1e6
    return out


# --- 3. start-up ----------------------------------------------------------------------------

def _kernel_process(cache):
    start = time.perf_counter()
    subprocess.run([sys.executable, '-c',
                    'from ext_observer.pipeline.kernel_cache import load; load()'],
                   check=True, env=_env(EXT_OBSERVER_CACHE=cache), timeout=600)
    return time.perf_counter() - start


def _node_start(executable, cache, domain_id, timeout=300.0):
    """
    Seconds from launching ``executable`` to its first /diagnostics, and to compiled kernels.

    Returns
    -------
    first : float
        To the first ``/diagnostics`` (NaN: none within ``timeout``).
    compiled : float or None
        To the first status whose ``kernels`` says ``compiled`` (None for a
        node without kernels; NaN: not within ``timeout``).

    """
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.executors import SingleThreadedExecutor
    context = rclpy.Context()
    rclpy.init(context=context, domain_id=domain_id)
    node = rclpy.create_node('bench_start_probe', context=context)
    seen = []
    node.create_subscription(DiagnosticArray, '/diagnostics',
                             lambda msg: seen.append((time.perf_counter(), msg)), 10)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    # This interpreter's own executable first: not another install's on PATH.
    path = os.path.join(os.path.dirname(sys.executable), executable)
    path = path if os.path.exists(path) else shutil.which(executable)
    env = _env(EXT_OBSERVER_CACHE=cache, ROS_DOMAIN_ID=str(domain_id))
    start = time.perf_counter()
    proc = subprocess.Popen([path, '--ros-args', '-p', 'diagnostic_period:=0.05'], env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)

    def compiled_at():
        for at, msg in seen:
            value = kernels_of(msg)
            if value == 'compiled':
                return at - start
        return None

    try:
        while not seen and time.perf_counter() - start < timeout:
            executor.spin_once(timeout_sec=0.01)
        if not seen:
            return float('nan'), float('nan')
        first = seen[0][0] - start
        if kernels_of(seen[0][1]) is None:
            return first, None
        while compiled_at() is None and time.perf_counter() - start < timeout:
            executor.spin_once(timeout_sec=0.01)
        at = compiled_at()
        return first, float('nan') if at is None else at
    finally:
        proc.send_signal(2)
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        executor.shutdown()
        node.destroy_node()
        rclpy.shutdown(context=context)


def _broad_process(cache, data):
    start = time.perf_counter()
    subprocess.run([sys.executable, '-m', 'ext_observer', 'broad', '--no-anchors', '--quiet',
                    '--data', data], check=True, env=_env(EXT_OBSERVER_CACHE=cache),
                   stdout=subprocess.DEVNULL, timeout=1800)
    return time.perf_counter() - start


def start_figures(data, domain_id=None, progress=print):
    """
    Cold (an empty cache folder) and warm start-up times, s.

    The nodes run in ``domain_id``; by default one reserved as the tests
    reserve theirs (a node of a fixed domain would take the samples of a
    test that drew the same one).

    Returns
    -------
    dict
        ``{what: (cold, warm)}``; a node with kernels has two rows: to its
        first ``/diagnostics`` and to its first status on the compiled
        kernels (cold: the background compile switched them in).

    """
    if domain_id is None:
        from bench.procs import reserved_domain_id
        with reserved_domain_id(17) as reserved:
            return start_figures(data, reserved, progress)
    out = {}
    cache = tempfile.mkdtemp(prefix='ext_observer-cache-')

    def node_rows(executable):
        def run():
            first, compiled = _node_start(executable, cache, domain_id)
            return first, compiled
        cold, warm = run(), run()
        rows = {f'{executable} to its first /diagnostics': (cold[0], warm[0])}
        if cold[1] is not None:
            rows[f'{executable} to the compiled kernels'] = (cold[1], warm[1])
        return rows

    try:
        for name, run in (('kernels in a fresh process', lambda: _kernel_process(cache)),
                          ('imu_filter_node', lambda: node_rows('imu_filter_node')),
                          ('observer_node', lambda: node_rows('observer_node')),
                          ('broad --no-anchors (22 trials, 9D and 6D)',
                           lambda: _broad_process(cache, data))):
            shutil.rmtree(cache)
            os.makedirs(cache)
            if name.endswith('_node'):
                rows = run()
            else:
                rows = {name: (run(), run())}
            for row, (cold, warm) in rows.items():
                out[row] = (cold, warm)
                progress(f'{row}: cold {cold:.2f} s, warm {warm:.2f} s')
    finally:
        shutil.rmtree(cache, ignore_errors=True)
    return out


# --- 4. the BROAD command whole --------------------------------------------------------------

# Printed by the broad command on stderr just before its estimator starts.
FIRST_ESTIMATE_LINE = 'in one batched call'


def _timed(argv):
    """Wall time of a process and when it printed FIRST_ESTIMATE_LINE on stderr (s)."""
    start = time.perf_counter()
    proc = subprocess.Popen(argv, env=_env(), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            text=True)
    first = None
    for line in proc.stderr:
        if first is None and FIRST_ESTIMATE_LINE in line:
            first = time.perf_counter() - start
    if proc.wait(1800) != 0:
        raise RuntimeError(f'{" ".join(argv)} exited with {proc.returncode}')
    return time.perf_counter() - start, first


def whole_figures(data, runs=5, progress=print):
    """
    The BROAD command's whole process against VQF's for the same work, s.

    Returns
    -------
    dict
        ``ours``, ``ours, 1 process`` (``--workers 1``), ``VQF``: the wall
        times of every run; ``first estimate``: ours to its first estimate;
        ``load``: the 1-minute load average before and after.

    """
    ours = [sys.executable, '-m', 'ext_observer', 'broad', '--no-anchors', '--data', data]
    argvs = {'ours': ours, 'ours, 1 process': ours + ['--workers', '1'],
             'VQF': [sys.executable, '-m', 'bench.broad_vqf', '--data', data]}
    out = {label: [] for label in argvs}
    out['first estimate'] = []
    before = os.getloadavg()[0]
    _timed(ours)  # the cache warm, the files in the page cache
    for _ in range(runs):
        for label, argv in argvs.items():
            wall, first = _timed(argv)
            out[label].append(wall)
            if label == 'ours':
                out['first estimate'].append(first)
    out['load'] = [before, os.getloadavg()[0]]
    from docgen.compiled_page import whole_medians
    progress('BROAD command, whole process: ' + ', '.join(
        f'{k} {v:.2f} s' for k, v in whole_medians(out).items()))
    return out


def main(argv=None):
    """Measure the sections asked for; print the page's section, write it with ``--docs``."""
    from docgen import compiled_page
    from ext_observer.broad import data_dir, find_trials, load_trial
    parser = argparse.ArgumentParser(prog='python -m bench.compiled_kernels',
                                     description=__doc__.split('\n\n')[0])
    parser.add_argument('--data', default=None, help='BROAD folder (as ext_observer broad)')
    parser.add_argument('--sections', default='broad,steps,starts,whole',
                        help='comma-separated: broad, steps, starts, whole')
    parser.add_argument('--node', action='store_true',
                        help='also python -m bench.imu_filter_cpu (the node against a relay)')
    parser.add_argument('--docs', default=None, metavar='DIR', help='write DIR/compiled.md')
    parser.add_argument('--json', metavar='PATH',
                        help='also write the figures there (what make bench reports)')
    args = parser.parse_args(argv)
    sections = set(args.sections.split(','))
    folder = data_dir(args.data)

    progress = log
    broad = steps = starts = node = whole = None
    if 'broad' in sections:
        trials = [load_trial(path, name) for name, path in find_trials(folder, None)]
        broad = broad_figures(trials, progress)
    if 'steps' in sections:
        steps = step_figures()
    if 'starts' in sections:
        starts = start_figures(folder, progress=progress)
    if 'whole' in sections:
        whole = whole_figures(folder, progress=progress)
    if args.node:
        from bench import imu_filter_cpu
        result = imu_filter_cpu.compare(rounds=5, progress=progress)
        ratio = result['ratio']
        node = (imu_filter_cpu.table(result) + '\n\n' + imu_filter_cpu.goal_line(result) + '\n\n'
                f'goal (compiled kernels): imu_filter ≤ {COMPILED_NODE_GOAL:g}× the relay\'s CPU '
                f'per IMU sample: {ratio:.2f}× (the same medians): '
                f'{imu_filter_cpu.verdict(ratio is not None and ratio <= COMPILED_NODE_GOAL)}')
    import numba
    from bench import machine
    facts = machine.describe()
    from ext_observer.broad.data import shown_command
    meta = {'command': shown_command(['python -m bench.compiled_kernels', *(argv or sys.argv[1:])]),
            'commit': facts['commit'], 'numba': numba.__version__,
            'machine': f'{facts["cpu"]}, {facts["cores"]} cores, Python {facts["python"]}, '
                       f'{facts["date"]}'}
    section = compiled_page.markdown(broad, steps, starts, meta, node, whole)
    print(section)
    if args.docs:
        progress(f'wrote {compiled_page.write_docs(args.docs, section)}')
    save_json(args.json, as_json(broad, steps, starts, section, whole))
    return 0


def as_json(broad, steps, starts, section, whole=None):
    """The figures as JSON: a step's key as ``'9D update compiled'``, a start ``[cold, warm]``."""
    return {'broad': broad, 'whole': whole,
            'steps': None if steps is None else {
                key if isinstance(key, str) else
                f'{key[0]} {key[1]} {"compiled" if key[2] else "plain"}': value
                for key, value in steps.items()},
            'starts': None if starts is None else {k: list(v) for k, v in starts.items()},
            'section': section}


if __name__ == '__main__':
    sys.exit(main())
