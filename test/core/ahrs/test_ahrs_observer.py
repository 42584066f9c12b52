"""The raw-IMU estimator (core/ahrs/ahrs_observer.py) on synthetic motion with known truth."""

import math

import numpy as np
from numpy.testing import assert_allclose
import pytest

from ext_observer.core import quaternion as quat
from ext_observer.core.ahrs.compiled import kernels
from ext_observer.pipeline.batch import estimate_batch
from ext_observer.core.ahrs.ahrs_observer import (AhrsObserver, AhrsParams,
                                    initial_attitude, world_from_enu)
from synthetic_motion import errors_deg, FIELD, G, RATE, rotate, synthetic

def run_float(gyr, acc, mag, use_mag=True, params=None, variant='extended'):
    est = AhrsObserver(params, use_mag=use_mag, variant=variant)
    out = np.empty((len(gyr), 4))
    for k in range(len(gyr)):
        out[k] = est.update(tuple(gyr[k]), tuple(acc[k]), tuple(mag[k]), 1.0 / RATE)
    return out, est


@pytest.fixture(scope='module')
def motion():
    return synthetic()


def test_9d_tracks_the_truth_and_learns_the_bias(motion):
    truth, gyr, acc, mag = motion
    q, est = run_float(gyr, acc, mag)
    total, _, _ = errors_deg(q, truth)
    after = int(10 * RATE)
    assert np.sqrt(np.mean(total[after:] ** 2)) < 1.0
    # The bias at rest (first 5 s) is learned to within the noise.
    assert_allclose(est.bias, (0.01, -0.015, 0.008), atol=3e-3)


def test_6d_keeps_the_inclination(motion):
    truth, gyr, acc, mag = motion
    q, _ = run_float(gyr, acc, mag, use_mag=False)
    _, _, incl = errors_deg(q, truth)
    assert np.sqrt(np.mean(incl[int(10 * RATE):] ** 2)) < 1.0


def test_translation_is_filtered_out():
    truth, gyr, acc, mag = synthetic(seed=1, accel=3.0)
    q, _ = run_float(gyr, acc, mag)
    _, _, incl = errors_deg(q, truth)
    # 3 m/s² of translation tilts a raw accelerometer by up to 17°.
    assert np.sqrt(np.mean(incl[int(10 * RATE):] ** 2)) < 2.0


def test_a_disturbed_field_is_rejected_and_never_tilts():
    truth, gyr, acc, mag = synthetic(seed=2, disturb=(20.0, 35.0, 40.0))
    q9, est = run_float(gyr, acc, mag)
    q6, _ = run_float(gyr, acc, mag, use_mag=False)
    total, heading, incl9 = errors_deg(q9, truth)
    _, _, incl6 = errors_deg(q6, truth)
    inside = slice(int(21 * RATE), int(35 * RATE))
    assert np.max(heading[inside]) < 3.0
    # Heading corrections are rotations about the vertical: the inclination
    # is the 6D one up to the coupling through the estimate.
    assert np.max(np.abs(incl9 - incl6)) < 0.5


def test_each_correction_turns_about_the_axis_it_should(motion):
    truth, gyr, acc, mag = motion
    est = AhrsObserver()
    for k in range(400):
        est.update(tuple(gyr[k]), tuple(acc[k]), tuple(mag[k]), 1.0 / RATE)
    est.q = tuple(quat.multiply(quat.exp(np.r_[0.0, 0.05, -0.04, 0.3]), np.asarray(est.q)))
    before = np.asarray(est.q)
    est.update_acc(tuple(acc[400]))
    after_acc = np.asarray(est.q)
    est.update_mag(tuple(mag[400]))
    after_mag = np.asarray(est.q)
    # δ ⊗ q̂: the inclination step turns about a horizontal world axis ...
    r = quat.multiply(after_acc, quat.conjugate(before))
    assert abs(r[3]) < 1e-12 and np.linalg.norm(r[1:3]) > 1e-6
    # ... and the heading step about the world vertical.
    r = quat.multiply(after_mag, quat.conjugate(after_acc))
    assert np.linalg.norm(r[1:3]) < 1e-12 and abs(r[3]) > 1e-6


def test_float_and_batch_paths_agree():
    runs = [synthetic(seconds=12.0, seed=s) for s in (3, 4)]
    gyr = [r[1] for r in runs]
    acc = [r[2] for r in runs]
    mag = [r[3] for r in runs]
    gyr[1], acc[1], mag[1] = gyr[1][:1800], acc[1][:1800], mag[1][:1800]
    batch = estimate_batch(gyr, acc, mag, [RATE, RATE], [True, False])
    assert [b.shape for b in batch] == [(2400, 4), (1800, 4)]
    for i, use_mag in enumerate((True, False)):
        single, _ = run_float(gyr[i], acc[i], mag[i], use_mag=use_mag)
        assert_allclose(batch[i], single, rtol=0, atol=1e-12)


def test_the_float_path_stays_on_floats_whatever_dt_is():
    # A numpy dt (1 / a numpy rate) once made every quantity a numpy scalar
    # and the node's step 3× slower; jittering stamps change dt every sample.
    est = AhrsObserver()
    for dt in (np.float64(0.005), 0.0051, np.float64(0.0049)):
        q = est.update((0.1, 0.0, -0.02), (0.3, 0.1, 9.8), (20.0, 1.0, -40.0), dt)
        est.update_mag((20.0, 1.0, -40.0), np.float64(0.01))
        assert all(type(v) is float for v in q + est.bias + est.field('lp')), q
        assert type(est.field('k_acc')) is float and type(est.field('k_mag')) is float


def test_workers_give_the_vectorized_estimates():
    # workers=2: each recording on floats in a forked process, longest first;
    # per-recording parameters and held non-finite samples included.
    runs = [synthetic(seconds=6.0, seed=s) for s in (5, 6, 7)]
    gyr = [r[1] for r in runs]
    acc = [r[2].copy() for r in runs]
    mag = [r[3] for r in runs]
    gyr[2], acc[2], mag[2] = gyr[2][:900], acc[2][:900], None
    acc[0][300:310] = np.nan
    params = AhrsParams(mag_cal=False)  # 6 s: a calibration would still be learning
    params.tau_mag = np.array([15.0, 5.0, 15.0])
    args = (gyr, acc, mag, [RATE] * 3, [True, True, False], params)
    vectorized = estimate_batch(*args)
    forked = estimate_batch(*args, workers=2)
    assert [f.shape for f in forked] == [(1200, 4), (1200, 4), (900, 4)]
    for v, f in zip(vectorized, forked):
        assert_allclose(f, v, rtol=0, atol=1e-12)
    # then: run on each estimate where it is made, its results in order.
    norms = lambda i, q: (i, float(np.sum(q * q)))  # noqa: E731
    for workers in (1, 2):
        estimates, after = estimate_batch(*args, workers=workers, then=norms)
        assert after == [(i, float(np.sum(v * v))) for i, v in enumerate(vectorized)]
        for v, f in zip(vectorized, estimates):
            assert_allclose(f, v, rtol=0, atol=1e-12)
    # The second recording's own tau_mag made a difference.
    alone = estimate_batch(gyr[1:2], acc[1:2], mag[1:2], [RATE], [True],
                           params=AhrsParams(mag_cal=False), workers=1)[0]
    assert np.max(np.abs(alone - forked[1])) > 1e-6


def test_the_extension_term_holds_the_estimate_near_s3(motion):
    truth, gyr, acc, mag = motion
    for variant, check in (('extended', lambda d: max(d[-500:]) < 1e-5),
                           ('plain', lambda d: d[-1] > 0.1)):
        est = AhrsObserver(variant=variant)
        est.update(tuple(gyr[0]), tuple(acc[0]), tuple(mag[0]), 1.0 / RATE)
        est.q = tuple(1.3 * v for v in est.q)  # start off S³
        defect = []
        for k in range(1, 2000):
            q = est.update(tuple(gyr[k]), tuple(acc[k]), tuple(mag[k]), 1.0 / RATE)
            defect.append(abs(sum(v * v for v in q) - 1.0))
        assert check(defect), (variant, defect[-1])


@pytest.mark.parametrize('name, value, match', [
    ('tau_acc', 0.0, 'tau_acc must be positive'),
    ('tau_bias', -1.0, 'tau_bias must be >= 0'),
    ('alpha', 0.08, 'alpha must be below 0.0762'),
    ('rest_gyr', float('nan'), 'rest_gyr must be finite'),
    ('tau_magg', 1.0, 'unknown parameters'),
])
def test_invalid_parameters_are_refused(name, value, match):
    with pytest.raises(ValueError, match=match):
        AhrsParams(**{name: value})


def test_recordings_must_share_a_rate():
    z = np.zeros((10, 3))
    with pytest.raises(ValueError, match='one sampling rate'):
        estimate_batch([z, z], [z, z], [z, z], [100.0, 200.0], [True, True])


def test_a_field_at_its_own_rate_corrects_on_its_own_time_constant(motion):
    truth, gyr, acc, mag = motion
    # The same heading error, fields at every sample or at one in ten with
    # their own interval: after 20 s both have corrected about as much.
    finals = []
    for every in (1, 10):
        est = AhrsObserver(AhrsParams(mag_cal=False))  # the heading gain alone
        est.update(tuple(gyr[0]), tuple(acc[0]), tuple(mag[0]), 1.0 / RATE)
        est.q = tuple(quat.multiply(quat.exp(np.r_[0.0, 0.0, 0.0, 0.3]), np.asarray(est.q)))
        est.set_field('mag_used', 1e9)  # past the initial averaging: the steady gain
        for k in range(1, int(20 * RATE)):
            est.update(tuple(gyr[k]), tuple(acc[k]), None, 1.0 / RATE)
            if k % every == 0:
                est.update_mag(tuple(mag[k]), dt=every / RATE)
        _, heading, _ = errors_deg(np.asarray(est.q), truth[int(20 * RATE) - 1])
        finals.append(heading)
    assert finals[0] < 0.5 * 34.4 and abs(finals[0] - finals[1]) < 0.5, finals


def test_non_finite_samples_of_a_recording_are_held(motion):
    truth, gyr, acc, mag = motion
    gyr, acc, mag = gyr[:2000].copy(), acc[:2000].copy(), mag[:2000].copy()
    clean = estimate_batch([gyr], [acc], [mag], [RATE], [True])[0]
    acc[0] = np.nan  # the very first sample too
    gyr[700, 1] = np.inf
    mag[900:905] = np.nan
    held = estimate_batch([gyr], [acc], [mag], [RATE], [True])[0]
    assert np.all(np.isfinite(held))
    total, _, _ = errors_deg(held[1000:], clean[1000:])
    assert np.max(total) < 0.5


@pytest.mark.parametrize('compiled', [False, True])
def test_run_writes_into_the_array_given_and_refuses_one_it_cannot_fill(compiled):
    if compiled and not kernels().compiled:
        pytest.skip('numba is not installed')
    _, gyr, acc, mag = synthetic(seconds=2.0, seed=3)
    expected = AhrsObserver(compiled=compiled).run(gyr, acc, mag, 1.0 / RATE)
    out = np.full((len(gyr), 4), np.nan)
    q = AhrsObserver(compiled=compiled).run(gyr, acc, mag, 1.0 / RATE, out=out)
    assert q is out
    assert_allclose(out, expected, rtol=0, atol=0)
    for bad in (np.zeros((len(gyr) - 1, 4)), np.zeros((4, len(gyr))).T,
                np.zeros((len(gyr), 4), dtype=np.float32)):
        with pytest.raises(ValueError, match='out must be'):
            AhrsObserver(compiled=compiled).run(gyr, acc, mag, 1.0 / RATE, out=bad)
