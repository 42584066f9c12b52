"""
The compiled kernels (numba) and the plain ones: one source, the same estimates.

The raw-IMU estimator's steps (core/ahrs/ahrs_kernel.py, core/ahrs/magcal_kernel.py)
run as plain Python, or compiled by numba where it is installed
(core/ahrs/compiled.py). Here both run the shipped BROAD excerpts, sample by
sample and whole, and must agree to 1e-12; every kernel function must be
compiled, each module keeping its own names; and without numba the package
must run plain.
"""

import os
import subprocess
import sys
import time

import numpy as np
import pytest

from conftest import REPO
from general_steps import general_step
from ext_observer.core.ahrs import compiled as compiled_module
from ext_observer.core.ahrs.ahrs_observer import AhrsObserver, AhrsParams
from ext_observer.pipeline.batch import estimate_batch

DATA = os.path.join(REPO, 'test', 'data')
EXCERPTS = sorted(f for f in os.listdir(DATA) if f.endswith('.npz'))

needs_numba = pytest.mark.skipif(not compiled_module.compiled_available(),
                                 reason='numba is not installed (requirements-test.txt has it)')


def _excerpt(name):
    d = np.load(os.path.join(DATA, name))
    return d['gyr'], d['acc'], d['mag'], float(d['rate'])


def _per_sample(est, gyr, acc, mag, rate):
    g, a, m = gyr.tolist(), acc.tolist(), mag.tolist()
    return np.array([est.update(g[k], a[k], m[k], 1.0 / rate) for k in range(len(g))])


@needs_numba
@pytest.mark.parametrize('name', EXCERPTS)
@pytest.mark.parametrize('mode', ['9D', '6D', 'no-calibration', 'motion-bias'])
def test_compiled_and_plain_agree_to_1e_12_on_the_excerpts(name, mode):
    gyr, acc, mag, rate = _excerpt(name)
    params = AhrsParams(mag_cal=mode != 'no-calibration',
                        tau_bias=30.0 if mode == 'motion-bias' else 0.0)
    runs = {}
    for compiled in (False, True):
        est = AhrsObserver(params, use_mag=mode != '6D', compiled=compiled)
        assert est.compiled is compiled
        runs[compiled] = (_per_sample(est, gyr, acc, mag, rate), est)
    q_plain, plain = runs[False]
    q_jit, jit = runs[True]
    assert np.max(np.abs(q_jit - q_plain)) <= 1e-12
    assert np.max(np.abs(np.subtract(jit.bias, plain.bias))) <= 1e-12
    if plain.calibration is not None:
        assert jit.calibration_state == plain.calibration_state
        for key in plain.calibration.counts:
            np.testing.assert_array_equal(jit.calibration.counts[key],
                                          plain.calibration.counts[key])
        np.testing.assert_allclose(jit.calibration.bias, plain.calibration.bias,
                                   rtol=0, atol=1e-9 * np.max(np.abs(mag)))
        assert abs(jit.calibration.quality - plain.calibration.quality) <= 1e-12
    # The whole-recording loop gives the per-sample estimates.
    est = AhrsObserver(params, use_mag=mode != '6D', compiled=True)
    whole = est.run(gyr, acc, mag, 1.0 / rate)
    assert np.max(np.abs(whole - q_jit)) <= 1e-12


@pytest.mark.parametrize('compiled', [False, pytest.param(True, marks=needs_numba)])
def test_the_whole_recording_loop_gives_the_per_sample_estimates(compiled):
    gyr, acc, mag, rate = _excerpt(EXCERPTS[0])
    gyr, acc, mag = gyr[:3000], acc[:3000], mag[:3000]
    per_sample = _per_sample(AhrsObserver(compiled=compiled), gyr, acc, mag, rate)
    whole = AhrsObserver(compiled=compiled).run(gyr, acc, mag, 1.0 / rate)
    assert whole.shape == per_sample.shape
    assert np.max(np.abs(whole - per_sample)) <= 1e-12
    # estimate_batch runs the same loop, in this process or in workers.
    both = estimate_batch([gyr, gyr[:2000]], [acc, acc[:2000]], [mag, mag[:2000]],
                          [rate, rate], [True, True], workers=2)
    assert np.max(np.abs(both[0] - per_sample)) <= 1e-12
    assert np.max(np.abs(both[1] - per_sample[:2000])) <= 1e-12


def test_every_kernel_function_is_compiled_in_a_module_of_its_own():
    pytest.importorskip('numba')
    k = compiled_module.kernels(True)
    from ext_observer.core.ahrs import ahrs_kernel, magcal_filter, magcal_kernel
    package = k.ahrs.__name__.rpartition('.')[0]
    for module in (ahrs_kernel, magcal_filter, magcal_kernel):
        twin = sys.modules[f'{package}.{module.__name__.rpartition(".")[2]}']
        names = [n for n, v in vars(module).items()
                 if callable(v) and getattr(v, '__module__', '') == module.__name__]
        assert names
        for n in names:
            assert hasattr(vars(twin)[n], 'py_func'), n  # a numba dispatcher
    # Each twin keeps its own names: one module's private name is not another's.
    assert '_TINY' in vars(k.ahrs) and '_TINY' not in vars(k.magcal)
    assert len(compiled_module.source_digest()) == 64


def test_without_numba_the_estimator_runs_plain():
    # A process where numba cannot be imported: auto falls back to plain,
    # and asking for the compiled kernels names why they are not there.
    code = '\n'.join([
        'import sys',
        "sys.modules['numba'] = None",
        'from ext_observer.core.ahrs.ahrs_observer import AhrsObserver',
        'from ext_observer.core.ahrs.compiled import CompiledUnavailable, compiled_available',
        'assert not compiled_available()',
        'est = AhrsObserver()',
        'assert not est.compiled',
        'q = est.update((0.0, 0.0, 0.1), (0.0, 0.0, 9.8), (20.0, 0.0, -40.0), 0.01)',
        'assert len(q) == 4',
        'try:',
        '    AhrsObserver(compiled=True)',
        'except CompiledUnavailable as exc:',
        "    print('refused:', exc)",
        'else:',
        "    raise SystemExit('compiled without numba')",
    ])
    env = dict(os.environ, EXT_OBSERVER_COMPILED='auto')
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                         env=env, timeout=120)
    assert out.returncode == 0, out.stderr
    assert 'refused: the compiled kernels are not available' in out.stdout


def test_the_environment_chooses_the_kernels(monkeypatch):
    monkeypatch.setenv('EXT_OBSERVER_COMPILED', '0')
    assert not AhrsObserver().compiled
    monkeypatch.setenv('EXT_OBSERVER_COMPILED', 'maybe')
    with pytest.raises(ValueError, match='EXT_OBSERVER_COMPILED must be 0, 1 or auto'):
        AhrsObserver()


@needs_numba
@pytest.mark.parametrize('mode', ['9D', '6D'])
def test_switching_kernels_mid_run_changes_no_estimate(mode):
    # A node that started on the plain kernels while the compiled ones were
    # being compiled goes on with them from the same state (and back).
    gyr, acc, mag, rate = _excerpt(EXCERPTS[1])
    gyr, acc, mag = gyr[:6000], acc[:6000], mag[:6000]
    use_mag = mode == '9D'
    reference = AhrsObserver(use_mag=use_mag, compiled=False)
    expected = _per_sample(reference, gyr, acc, mag, rate)
    est = AhrsObserver(use_mag=use_mag, compiled=False)
    first = _per_sample(est, gyr[:2500], acc[:2500], mag[:2500], rate)
    est.use_kernels(compiled_module.kernels(True))
    assert est.compiled and isinstance(est._states[0], np.ndarray)
    second = _per_sample(est, gyr[2500:4500], acc[2500:4500], mag[2500:4500], rate)
    est.use_kernels(compiled_module.kernels(False))
    assert not est.compiled and isinstance(est._states[0], list)
    third = _per_sample(est, gyr[4500:], acc[4500:], mag[4500:], rate)
    assert np.max(np.abs(np.concatenate([first, second, third]) - expected)) <= 1e-12
    if use_mag:
        # The calibration went along: the same state, counts and offset.
        assert est.calibration_state == reference.calibration_state
        assert est.calibration.counts['used'][0] == reference.calibration.counts['used'][0] > 0
        np.testing.assert_allclose(est.calibration.bias, reference.calibration.bias,
                                   rtol=0, atol=1e-12 * np.max(np.abs(mag)))



def _pipeline_run(pipeline, gyr, acc, mag, rate, in_place, general=False, switch_at=None):
    """The pipeline on an excerpt (a field every 10th sample): estimates and covariances."""
    states, covariances = [], []
    period = round(1e9 / rate)
    for k in range(len(gyr)):
        if switch_at is not None and k == switch_at:
            pipeline.estimator.use_kernels(compiled_module.kernels(True))
        stamp = 1_000_000_000 + k * period
        if k % 10 == 0:
            pipeline.field(stamp - period // 2, tuple(1e-6 * mag[k]))
        if general:
            # What the estimator did before sample_step: the core's step,
            # the guard, then the covariance's, one call each.
            est = pipeline.estimator
            started = est.core.initialized
            outcome, steps = pipeline.pairer.add_sample(stamp, tuple(gyr[k]), tuple(acc[k]))
            for step in steps:
                state, reason = general_step(est, tuple(gyr[k]), tuple(acc[k]),
                                             (step.end - step.stamp) * 1e-9)
                assert reason is None or not started
                states.append(state)
                covariances.append(est.uncertainty.covariance)
            continue
        cov = np.zeros(9) if in_place else None
        _, estimate = pipeline.imu(stamp, tuple(gyr[k]), tuple(acc[k]), cov)
        if estimate is not None:
            states.append(estimate.state)
            covariances.append(tuple(estimate.covariance))
            if in_place:
                assert estimate.covariance is cov
    return np.array(states), np.array(covariances)


@pytest.mark.parametrize('compiled', [False, pytest.param(True, marks=needs_numba)])
@pytest.mark.parametrize('mode', ['9D', '6D'])
def test_the_one_call_sample_gives_what_the_steps_one_by_one_give(compiled, mode):
    # sample_step (the core's step, the guard and the covariance's step in
    # one call) against the three calls it replaces, and the covariance
    # written into the caller's array against the tuple.
    from node_settings import node_settings
    from ext_observer.pipeline.raw_imu import RawImuPipeline
    gyr, acc, mag, rate = _excerpt(EXCERPTS[0])
    gyr, acc, mag = gyr[:4000], acc[:4000], mag[:4000]
    settings = node_settings(use_mag=mode == '9D')
    runs = [_pipeline_run(RawImuPipeline(settings, compiled=compiled), gyr, acc, mag, rate,
                          in_place, general)
            for in_place, general in ((False, False), (True, False), (False, True))]
    for states, covariances in runs[1:]:
        assert states.shape == runs[0][0].shape
        assert np.max(np.abs(states - runs[0][0])) <= 1e-12
        assert np.max(np.abs(covariances - runs[0][1])) <= 1e-12 * np.max(runs[0][1])
    assert np.all(np.isfinite(runs[0][1])) and np.all(runs[0][1][:, [0, 4, 8]] > 0.0)


@needs_numba
def test_the_covariance_goes_along_when_the_kernels_change_mid_run():
    # The node starts plain and switches to the compiled kernels between two
    # samples: the covariance's state goes along (the same figures as a
    # pipeline that ran plain throughout).
    from node_settings import node_settings
    from ext_observer.pipeline.raw_imu import RawImuPipeline
    gyr, acc, mag, rate = _excerpt(EXCERPTS[1])
    gyr, acc, mag = gyr[:3000], acc[:3000], mag[:3000]
    reference = _pipeline_run(RawImuPipeline(node_settings(), compiled=False), gyr, acc, mag,
                              rate, True)
    pipeline = RawImuPipeline(node_settings(), compiled=False)
    switched = _pipeline_run(pipeline, gyr, acc, mag, rate, True, switch_at=1500)
    assert pipeline.estimator.core.compiled
    tracker = pipeline.estimator.uncertainty
    assert isinstance(tracker.state, np.ndarray)
    # Its attributes read as Python values still (diagnostics, replays).
    assert type(tracker.heading_set) is bool
    assert all(type(v) is float for v in tracker.covariance + tracker.last_field[:2])
    assert np.max(np.abs(switched[0] - reference[0])) <= 1e-12
    assert np.max(np.abs(switched[1] - reference[1])) <= 1e-12 * np.max(reference[1])
    # The node's compiled sample_step (kernel_cache.load: compiled ahead of
    # the samples) is called past numba's dispatch (one signature).
    from ext_observer.pipeline.kernel_cache import load
    k = load()
    assert k is compiled_module.kernels(True)
    assert k.sample_step is not k.uncertainty.sample_step


@pytest.mark.parametrize('compiled', [False, pytest.param(True, marks=needs_numba)])
def test_a_covariance_array_the_kernels_cannot_write_is_refused(compiled):
    # The compiled kernels write into the array's memory as 9 contiguous
    # float64, unchecked: anything else is refused before a step runs.
    from node_settings import node_settings
    from ext_observer.pipeline.raw_imu import RawImuPipeline
    pipeline = RawImuPipeline(node_settings(), compiled=compiled)
    for k in range(3):
        pipeline.imu(1_000_000_000 + k * 1_000_000, (0.1, 0.0, 0.0), (0.0, 0.0, 9.8),
                     np.zeros(9))
    readonly = np.zeros(9)
    readonly.flags.writeable = False
    state = pipeline.estimator.state
    wide = np.zeros(18)
    for bad in (np.zeros(9, dtype=np.float32), [0.0] * 9, wide[::2], np.zeros(8),
                np.zeros((3, 3)), readonly):
        with pytest.raises(ValueError, match='C-contiguous float64 array of 9'):
            pipeline.estimator.step((0.1, 0.0, 0.0), (0.0, 0.0, 9.8), 0.001, bad)
    assert pipeline.estimator.state == state and not wide.any()


@pytest.mark.parametrize('command', ['csv', 'bag', 'broad'])
def test_without_numba_each_command_warns_once_with_the_cost(command, monkeypatch, capsys,
                                                            tmp_path):
    from ext_observer.__main__ import main
    argv = {'csv': ['csv', str(tmp_path / 'in.csv'), '--out', str(tmp_path / 'out.csv')],
            'bag': ['bag', str(tmp_path / 'no_bag'), '--out', str(tmp_path / 'out')],
            'broad': ['broad', '--data', str(tmp_path), '--no-anchors']}[command]
    monkeypatch.setitem(sys.modules, 'numba', None)
    monkeypatch.delenv('EXT_OBSERVER_COMPILED', raising=False)
    assert main(argv) == 2  # no input: the error comes after the warning
    lines = capsys.readouterr().err.splitlines()
    assert lines[0] == f'warning: {compiled_module.plain_warning()}' and len(lines) == 2
    for needed in ('numba cannot be imported', 'per sample', 'BROAD command', 'pip install'):
        assert needed in lines[0]
    # Plain on purpose, or numba there: nothing said.
    monkeypatch.setenv('EXT_OBSERVER_COMPILED', '0')
    assert main(argv) == 2 and 'warning' not in capsys.readouterr().err
    monkeypatch.delitem(sys.modules, 'numba')
    monkeypatch.delenv('EXT_OBSERVER_COMPILED')
    if compiled_module.compiled_available():
        assert main(argv) == 2 and 'warning' not in capsys.readouterr().err


@pytest.mark.ros
@pytest.mark.timeout(120)
def test_without_numba_the_node_warns_once_with_the_cost(ros_processes):
    code = ('import sys; sys.modules["numba"] = None; '
            'from ext_observer.nodes.imu_filter_node import main; sys.exit(main())')
    env = {k: v for k, v in os.environ.items() if k != 'EXT_OBSERVER_COMPILED'}
    node = ros_processes([sys.executable, '-c', code], env=env)
    deadline = time.monotonic() + 60.0
    while 'raw IMU on' not in node.output and time.monotonic() < deadline:
        assert node.process.poll() is None, node.output
        time.sleep(0.1)
    assert node.interrupt() == 0, node.output
    assert node.output.count('numba cannot be imported') == 1, node.output
    line = next(li for li in node.output.splitlines() if 'numba cannot be imported' in li)
    assert line.startswith('[WARN]') and line.endswith(compiled_module.PLAIN_COST), line


@needs_numba
@pytest.mark.parametrize('mode', ['9D', '6D'])
def test_compiled_and_plain_agree_to_the_bit_across_holes(mode):
    # Samples lost at random and in bursts (holes bridged, means restarted,
    # the covariance grown and restarted; one hole not bridged): the same estimates and
    # covariances, bit for bit.
    from node_settings import node_settings
    from ext_observer.pipeline.raw_imu import RawImuPipeline
    gyr, acc, mag, rate = _excerpt(EXCERPTS[0])
    rng = np.random.default_rng(7)
    keep = rng.random(len(gyr)) >= 0.3
    keep &= np.mod(np.arange(len(gyr)) / rate, 2.0) >= 0.15
    # And one hole too long to bridge (over max_dt): the estimate holds, its doubt grows.
    seconds = np.arange(len(gyr)) / rate
    keep &= (seconds < 8.0) | (seconds >= 9.5)
    keep[:2] = True
    index = np.flatnonzero(keep)[:5000]
    period = round(1e9 / rate)
    runs = []
    for compiled in (False, True):
        pipeline = RawImuPipeline(node_settings(use_mag=mode == '9D'), compiled=compiled)
        states, covariances = [], []
        for k in index:
            stamp = 1_000_000_000 + int(k) * period
            pipeline.field(stamp, tuple(1e-6 * mag[k]))
            _, estimate = pipeline.imu(stamp, tuple(gyr[k]), tuple(acc[k]))
            if estimate is not None:
                states.append(estimate.state)
                covariances.append(tuple(estimate.covariance))
        runs.append((np.array(states), np.array(covariances),
                     pipeline.estimator.core.holes, pipeline.pairer.drops['dt_too_large']))
    assert runs[0][2] == runs[1][2] > 100
    assert runs[0][3] == runs[1][3] == 1
    np.testing.assert_array_equal(runs[0][0], runs[1][0])
    np.testing.assert_array_equal(runs[0][1], runs[1][1])
