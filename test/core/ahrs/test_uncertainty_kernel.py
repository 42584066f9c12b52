"""
The uncertainty's kernel (``uncertainty_kernel.py``) against its documented model (no ROS).

The heading variance's growth with the gyro's noise, the model written as
2 × 2 matrices per axis against the kernel's scalar arithmetic, the
node's sample in one call (``sample_step``) against the steps one at a
time and what it refuses, a start's variance and the published sums, an
unbridged hole, the named state and many recordings at once. The
covariance end to end (the pipeline, the node, its coverage bounds on
BROAD): test_covariance.py.
"""

import copy
import math

import numpy as np
import pytest

from ext_observer.core.ahrs import compiled as compiled_module, uncertainty_kernel
from ext_observer.core.ahrs.ahrs_observer import AhrsObserver, AhrsParams
from ext_observer.core.ahrs.ahrs_params import UncertaintyParams
from ext_observer.core.ahrs.ahrs_state import STATE
from ext_observer.core.ahrs.uncertainty import AttitudeUncertainty
from ext_observer.core.constants import STANDARD_GRAVITY as GRAVITY


@pytest.mark.parametrize('rate', [(0.0, 0.0, 0.0), (0.3, -0.4, 1.2)])
def test_the_heading_variance_grows_with_the_gyros_noise_in_6d(rate):
    # No bias (known to be zero) and no correction of the heading: each
    # sample adds the gyro's angle variance, (σ² + σ_r² |ω|²) dt: a random walk.
    params = UncertaintyParams(bias_std=0.0, bias_init=0.0, gyro_noise=2e-3,
                               gyro_rate_noise=1e-2, stamp_error=0.0)
    dt, count = 0.01, 1000
    tracker = AttitudeUncertainty(params, use_mag=False)
    tracker.start(dt)
    tracker.step(dt, rate, (1.0, 0.0, 0.0, 0.0), False)
    before = tracker.heading_variance
    for _ in range(count):
        tracker.step(dt, rate, (1.0, 0.0, 0.0, 0.0), False)
    w2 = sum(v * v for v in rate)
    expected = count * (2e-3 ** 2 + 1e-2 ** 2 * w2) * dt
    assert tracker.heading_variance - before == pytest.approx(expected, rel=1e-9)


def _rotation(q):
    """The rotation matrix of ``q`` (any nonzero norm), body → world."""
    w, x, y, z = np.asarray(q, dtype=float) / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def test_the_uncertainty_is_its_documented_model_in_matrix_form():
    # core/ahrs/uncertainty.py's model, written here as 2×2 matrices per axis
    # (x = [θ, β]: F P Fᵀ + Q between samples, the rest and the inclination
    # corrections as congruences plus their noise), against the kernel's
    # scalar arithmetic, over samples of changing intervals, rates,
    # attitudes and rest: equal to rounding. 6D: nothing corrects the heading.
    params = UncertaintyParams(gyro_noise=3e-3, gyro_rate_noise=2e-2, bias_std=4e-3,
                               bias_time=30.0, bias_init=1e-2, acc_noise=0.05,
                               inclination_floor=0.0, heading_floor=0.0, stamp_error=2e-3)
    tau_acc, tau_rest = 1.5, 0.7
    tracker = AttitudeUncertainty(params, tau_acc=tau_acc, tau_rest=tau_rest, use_mag=False)
    rng = np.random.default_rng(31)
    dt = 0.01
    tracker.start(dt)
    r_acc = (0.05 / GRAVITY) ** 2
    tilt = np.array([[r_acc / dt, 0.0], [0.0, 1e-2 ** 2]])
    heading = np.array([[3e-3 ** 2 * dt, 0.0], [0.0, 1e-2 ** 2]])
    for k in range(400):
        dt = (0.01, 0.005, 0.02)[k // 100 % 3]
        rate = rng.normal(0.0, 1.0, 3)
        q = rng.normal(0.0, 1.0, 4)
        rest = k % 50 < 20
        tracker.step(dt, tuple(rate), tuple(q), rest)
        phi = math.exp(-dt / 30.0)
        f = np.array([[1.0, dt], [0.0, phi]])
        noise = np.diag([(3e-3 ** 2 + (2e-2 * np.linalg.norm(rate)) ** 2) * dt,
                         4e-3 ** 2 * (1.0 - phi * phi)])
        tilt = f @ tilt @ f.T + noise
        heading = f @ heading @ f.T + noise
        if rest:
            kr = 1.0 - math.exp(-dt / tau_rest)
            g = np.diag([1.0, 1.0 - kr])
            learned = np.diag([0.0, kr * kr * 3e-3 ** 2 / dt])
            tilt = g @ tilt @ g.T + learned
            heading = g @ heading @ g.T + learned
        ka = 1.0 - math.exp(-dt / tau_acc)
        h = np.diag([1.0 - ka, 1.0])
        tilt = h @ tilt @ h.T + np.diag([ka * ka * r_acc / dt, 0.0])
        vertical = (_rotation(q) @ rate)[2]
        stamp2 = 2e-3 ** 2
        assert tracker.tilt_variance == pytest.approx(
            tilt[0, 0] + 0.5 * stamp2 * (rate @ rate - vertical ** 2), rel=1e-9)
        assert tracker.heading_variance == pytest.approx(
            heading[0, 0] + stamp2 * vertical ** 2, rel=1e-9)


ROLLED = (0.0, 6.9367, 6.9367)  # m/s²: gravity seen rolled by 45°


def _pair(use_mag=False):
    """An estimator and its uncertainty, started from one still sample rolled 45° (100 Hz)."""
    est = AhrsObserver(AhrsParams(), use_mag=use_mag)
    tracker = AttitudeUncertainty.for_estimator(est.params, use_mag=use_mag)
    tracker.use_kernels(est.kernels)  # the estimator's kind of state: one call steps both
    est.update((0.0, 0.0, 0.0), ROLLED, None, 0.01)
    tracker.start(0.01, ROLLED)
    return est, tracker


@pytest.mark.parametrize('use_mag', [False, True])
def test_the_one_call_sample_step_is_the_general_steps(use_mag):
    # sample_step (the node's usual sample in one call) against the steps
    # one at a time: the estimate, and the covariance it writes (diag(V_t,
    # V_t, V_h), zeros elsewhere), through rest (the bias learned) and a turn
    # of 1.75 rad about the body's z (every component of the estimate large),
    # the interval changing now and then.
    # In 9D the samples come without a field (fields have their own calls):
    # the whole state stays that of the general steps, the field's part too.
    one, one_tracker = _pair(use_mag)
    general, tracker = _pair(use_mag)
    cov = np.full(9, np.nan)
    rng = np.random.default_rng(5)
    for k in range(600):
        moving = k >= 300
        dt = (0.01, 0.005, 0.02)[k // 50 % 3]
        gyr = tuple(rng.normal(0.0, 0.002, 3) + (0.0, 0.0, 0.5 if moving else 0.0))
        acc = tuple(np.array(ROLLED) + rng.normal(0.0, 0.05, 3))
        outcome, *q = one.kernels.uncertainty.sample_step(
            one.state, one_tracker.state, cov, *gyr, *acc, dt, 0.01)
        assert outcome == uncertainty_kernel.SAMPLE_OK
        expected = general.update(gyr, acc, None, dt)
        # 0.005 s to 0.02 s is a hole: the step keeps the usual interval.
        hole, usual = general.hole_variance, general.step_interval
        tracker.step(usual, gyr, expected, general.rest, general.bias_variance,
                     general.clip_variance, acc,
                     (dt - usual, hole, general.hole_restart) if hole else None,
                     general.held)
        assert tuple(q) == tuple(expected)
        assert tuple(cov) == tuple(tracker.covariance)
        t, h = tracker.tilt_variance, tracker.heading_variance
        assert tuple(cov) == (t, 0.0, 0.0, 0.0, t, 0.0, 0.0, 0.0, h)
        assert np.array_equal(np.array(STATE.flat(one.state[0])),
                              np.array(STATE.flat(general.state[0])), equal_nan=True)
    assert general.rest is False and tracker.heading_variance > 0.0
    assert min(abs(v) for v in general.q) > 0.1


def test_the_one_call_sample_step_refuses_what_it_cannot_run():
    est = AhrsObserver(AhrsParams(), use_mag=False)
    tracker = AttitudeUncertainty.for_estimator(est.params, use_mag=False)
    tracker.use_kernels(est.kernels)
    cov = np.zeros(9)
    step = est.kernels.uncertainty.sample_step  # the kernels (plain or compiled) of its state
    still = (0.0, 0.0, 0.0) + ROLLED
    assert step(est.state, tracker.state, cov, *still, 0.01, 0.01)[0] == (
        uncertainty_kernel.SAMPLE_NOT_STARTED)
    est, tracker = _pair()
    for dt in (0.0, -0.01, math.inf, math.nan):
        assert step(est.state, tracker.state, cov, *still, dt, 0.01)[0] == (
            uncertainty_kernel.SAMPLE_BAD_DT), dt
    assert not cov.any()  # nothing written
    # The guard: |q̂̄q̂ − 1| above max_residual fails, at it passes.
    turn = (3.0, -2.0, 1.0) + ROLLED
    _, *q = step(copy.deepcopy(est.state), copy.deepcopy(tracker.state), cov, *turn, 0.01, 1.0)
    residual = abs(sum(v * v for v in q) - 1.0)
    assert residual > 0.0
    for max_residual, expected in ((residual, uncertainty_kernel.SAMPLE_OK),
                                   (0.5 * residual, uncertainty_kernel.SAMPLE_RESIDUAL)):
        outcome = step(copy.deepcopy(est.state), copy.deepcopy(tracker.state), cov, *turn,
                       0.01, max_residual)[0]
        assert outcome == expected


@pytest.mark.parametrize('first, then', [((3.0, 0.0, GRAVITY), (0.5, -0.3, GRAVITY + 0.2)),
                                         ((0.3, 0.0, GRAVITY), (3.0, -2.0, GRAVITY + 0.5))])
def test_a_starts_variance_is_its_documented_model_then_decays_sample_by_sample(first, then):
    # uncertainty_start's model (its docstring): until tau_acc, the running
    # mean m of e = max(dz², (fx² + fy²)/2)/g² (and the first sample's e, if
    # larger) owes atan(√max(m, e₁))² c/(c + t) per horizontal axis; then the
    # low-pass forgets it by (1 − k)² per sample, to zero below 1e-16. The
    # first sample's error larger than the rest's, then smaller (the mean
    # rules).
    tracker = AttitudeUncertainty.for_estimator(AhrsParams(tau_acc=0.2), use_mag=False)
    dt = 0.01
    tracker.start(dt)
    u = tracker.state[0]
    K, C = uncertainty_kernel, uncertainty_kernel.START_CORRELATION
    st = u.start
    st.time = st.count = st.mean = st.var = st.first = 0.0
    forces = [first] + [then] * 40
    errors = [max((fz - GRAVITY) ** 2, 0.5 * (fx * fx + fy * fy)) / GRAVITY ** 2
              for fx, fy, fz in forces]
    tau, k = u.par.tau_acc, u.coef.k_acc   # the accelerometer's low-pass (0.25 s here)
    assert k == pytest.approx(1.0 - math.exp(-dt / tau), rel=1e-12)
    phases = []
    for n, f in enumerate(forces, start=1):
        t, before = st.time, st.var
        K.uncertainty_start(u, dt, *f)
        if t < tau:
            a = math.atan(math.sqrt(max(np.mean(errors[:n]), errors[0])))
            assert st.var == pytest.approx(a * a * C / (C + t), rel=1e-9), n
        else:
            assert st.var == pytest.approx((1.0 - k) ** 2 * before, rel=1e-12), n
        phases.append(t < tau)
    assert abs(sum(phases) - round(tau / dt)) <= 1 and not phases[-1]
    assert st.var > 1e-6


def test_the_published_variances_are_the_sum_of_their_parts_and_b_the_larger():
    # uncertainty_variances' sums, each part nonzero and distinct; the bias
    # variance B the larger of its own and the estimator's, exactly (also
    # when equal).
    K = uncertainty_kernel
    u = K.UNC.plain()
    parts = {'axes.pt': 1.0, 'start.var': 2.0, 'par.tilt_floor': 4.0, 'par.stamp2': 8.0,
             'rate.wh2': 16.0, 'axes.ph': 32.0, 'head.unknown': 64.0, 'head.heading_set': 1.0,
             'par.heading_floor': 128.0, 'head.calibration': 256.0, 'rate.wz2': 512.0,
             'head_start.sigma': 3.0}
    for name, value in parts.items():
        K.UNC.set(u, name, value)
    t, h = K.uncertainty_variances(u)
    assert t == 1.0 + 2.0 + 4.0 + 0.5 * 8.0 * 16.0
    assert h == 32.0 + 64.0 + 1.0 * (128.0 + 256.0) + 8.0 * 512.0 + 3.0 * 3.0
    # The fields' lag: counted where its square beyond the field's own error
    # (floor and calibration) says more; a lost field's scale and axes terms
    # (in quadrature) then add as σ.
    u.held.yaw = -1000.0
    u.held.rotation = 3000.0
    held = math.hypot(K.GYRO_SCALE_SIGMA * 1000.0, K.GYRO_MOTION_SIGMA * 3000.0)
    u.head.lag = 60.0  # 3600 − 384 < 4489: nothing
    assert K.uncertainty_variances(u)[1] == h + held * held
    u.head.lag = -100.0
    assert K.uncertainty_variances(u)[1] == pytest.approx(
        (math.sqrt(10000.0 - 384.0) + held) ** 2, rel=1e-15)
    for before, var, after in ((2e-6, 1e-6, 2e-6), (1e-6, 2e-6, 2e-6), (1e-6, 1e-6, 1e-6)):
        u.axes.b = before
        K.uncertainty_bias(u, var)
        assert u.axes.b == after


def test_a_lost_fields_rotation_counts_every_axis_unsigned_and_a_used_field_shrinks_it():
    # After FIELD_SILENT without a field, each sample adds |ω| dt to the
    # rotation held (turning back and forth about a horizontal axis too) and
    # ω's vertical part, signed, to the yaw held; a field that corrects the
    # heading with gain κ keeps 1 − κ of both.
    K = uncertainty_kernel
    tracker = AttitudeUncertainty(use_mag=True)
    tracker.start(0.01)
    u = tracker.state[0]
    dt, rates = 0.01, ((0.0, 0.0, 2.0), (3.0, 0.0, -4.0), (-3.0, 0.0, 0.0))
    for _ in range(int(K.FIELD_SILENT / dt) + 1):
        K.uncertainty_propagate(u, dt, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    assert u.held.rotation == 0.0
    for g in rates:
        K.uncertainty_propagate(u, dt, *g, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    assert u.held.rotation == pytest.approx(dt * (2.0 + 5.0 + 3.0), rel=1e-12)
    assert u.held.yaw == pytest.approx(dt * (2.0 - 4.0), rel=1e-12)
    tracker.field(0.01, 0.25)
    assert u.held.rotation == pytest.approx(0.75 * dt * 10.0, rel=1e-12)
    assert u.held.field_age == 0.0


def test_a_holes_step_corrects_the_inclination_variance_as_the_steps_it_missed():
    uk = uncertainty_kernel
    tracker = AttitudeUncertainty(use_mag=False)
    u = tracker.state[0]
    uk.uncertainty_coefficients(u, 0.01)
    u.axes.pt, u.axes.ct, u.axes.b = 1e-3, 1e-5, 0.0
    uk.uncertainty_hole(u, 0.02, 0.0, True)  # two steps missed: three in all
    a = (1.0 - u.coef.k_acc) ** 2
    g = u.par.gyro_noise
    assert u.axes.pt == pytest.approx(a * a * 1e-3 + g * g * 0.02)
    assert u.axes.ct == pytest.approx(a * 1e-5)


@pytest.mark.parametrize('compiled', [False, pytest.param(True, marks=pytest.mark.skipif(
    not compiled_module.compiled_available(), reason='numba is not installed'))])
def test_an_unbridged_holes_covariance_grows_by_its_rotation_the_heading_at_most_unknown(
        compiled):
    # covariance_unbridged: the gyro's noise and the bias over the hole and
    # the rotation it may have hidden; the tilt's only where the
    # inclination's mean was kept (t0 < 0), else the mean restarts; the
    # heading's capped at an unknown heading's; the hole is time without a
    # field. Plain and compiled alike, to the bit.
    K = uncertainty_kernel
    dt, var = 3.0, 0.01
    out = {}
    for t0 in (-1.0, 0.5):
        tracker = AttitudeUncertainty(use_mag=False)
        if compiled:
            tracker.use_kernels(compiled_module.kernels(True))
        tracker.start(0.01)
        u = tracker.state[0]
        before = K.UNC.flat(u)
        tracker.unbridged(dt, var, t0)
        g = K.UNC.get(u, 'par.gyro_noise')
        grow = g * g * dt + K.UNC.get(u, 'axes.b') * dt * dt + var
        get = dict(zip(['.'.join(p) for p, *_ in K.UNC.fields()], before)).get
        assert K.UNC.get(u, 'axes.ph') == get('axes.ph') + grow
        assert K.UNC.get(u, 'held.field_age') == get('held.field_age') + dt
        if t0 < 0.0:
            assert K.UNC.get(u, 'axes.pt') == get('axes.pt') + grow
        else:
            assert K.UNC.get(u, 'axes.pt') == K.UNC.get(u, 'coef.r_acc')
            assert K.UNC.get(u, 'start.time') == t0
        tracker.unbridged(1e3, 10.0, t0)
        assert K.UNC.get(u, 'axes.ph') == K.HEADING_UNKNOWN
        out[t0] = K.UNC.flat(u)
    if compiled:
        for t0, values in out.items():
            plain = AttitudeUncertainty(use_mag=False)
            plain.start(0.01)
            plain.unbridged(dt, var, t0)
            plain.unbridged(1e3, 10.0, t0)
            assert K.UNC.flat(plain.state[0]) == values


def test_the_state_is_named_float64_fields_each_with_its_unit_and_meaning():
    K = uncertainty_kernel
    fields = K.UNC.fields()
    assert {path[0] for path, *_ in fields} == {
        'par', 'coef', 'axes', 'rate', 'head', 'start', 'head_start', 'held'}
    assert all(isinstance(unit, str) and meaning and size == 1
               for _, unit, meaning, size in fields)
    assert K.UNC.size == len(fields) and K.UNC.dtype.itemsize == 8 * len(fields)
    # The holders the kernels take: a one-element structured array, [plain record].
    compiled, plain = K.UNC.holder(True), K.UNC.holder(False)
    assert compiled.shape == (1,) and len(plain) == 1
    assert K.UNC.flat(compiled[0]) == K.UNC.flat(plain[0]) == [0.0] * len(fields)


def test_many_recordings_at_once_step_as_each_alone():
    # AttitudeUncertainty on arrays (B,) (a replay of many recordings): the
    # same covariance_step, the start's share counted recording by
    # recording after it: to the bit what each recording's own tracker does
    # on floats.
    rng = np.random.default_rng(11)
    use_mag = np.array([True, False, True])
    count, dt = 300, 0.01
    many = AttitudeUncertainty(use_mag=use_mag)
    alone = [AttitudeUncertainty(use_mag=bool(m)) for m in use_mag]
    first = np.array(ROLLED)[:, None] + rng.normal(0.0, 0.5, (3, 3))
    many.start(dt, tuple(first))
    for b, tracker in enumerate(alone):
        tracker.start(dt, tuple(float(v) for v in first[:, b]))
    for k in range(count):
        gyr = rng.normal(0.0, 0.5, (3, 3))
        q = rng.normal(0.0, 1.0, (4, 3))
        acc = np.array(ROLLED)[:, None] + rng.normal(0.0, 1.0, (3, 3))
        rest = rng.random(3) < 0.3
        bias_var = rng.random(3) * 1e-5
        clip_var = np.where(rng.random(3) < 0.1, 1e-4, 0.0)
        many.step(dt, tuple(gyr), tuple(q), rest, bias_var, clip_var, tuple(acc))
        for b, tracker in enumerate(alone):
            tracker.step(dt, tuple(gyr[:, b]), tuple(q[:, b]), bool(rest[b]),
                         float(bias_var[b]), float(clip_var[b]), tuple(acc[:, b]))
        if k % 50 == 49:  # a field for the 9D ones (gain 0, no dip: nothing for the 6D one)
            gain, dip = use_mag * 0.2, np.where(use_mag, 1.0, np.nan)
            many.field(dt, gain, 0.01, np.nan, dip)
            for b, tracker in enumerate(alone):
                tracker.field(dt, float(gain[b]), 0.01, math.nan, float(dip[b]))
    for b, tracker in enumerate(alone):
        assert many.tilt_variance[b] == tracker.tilt_variance
        assert many.heading_variance[b] == tracker.heading_variance
        assert many.state[0].start.var[b] == tracker.state[0].start.var > 0.0


def test_a_bridged_hole_grows_the_variances_by_its_noise_its_bias_and_its_bridge():
    # Known answer of uncertainty_hole through the one step order (covariance_step):
    # beyond the usual step, g² T + B T² + var, on the inclination only where its
    # mean was kept; what was there before is corrected by the steps the hole missed.
    K = uncertainty_kernel
    u = K.UNC.plain()
    u.par.gyro_noise, u.coef.k_acc, u.coef.dt = 2e-3, 0.01, 0.01
    u.axes.pt, u.axes.ct, u.axes.ph, u.axes.b = 4e-4, 1e-6, 9e-4, 2.5e-5
    before = copy.deepcopy(u)
    extra, var = 0.05, 3e-5
    K.uncertainty_hole(u, extra, var, True)
    a = (1.0 - 0.01) ** (extra / 0.01)
    grow = 2e-3 ** 2 * extra + 2.5e-5 * extra ** 2 + var
    assert u.axes.pt == pytest.approx(a * a * 4e-4 + grow, rel=1e-14)
    assert u.axes.ct == pytest.approx(a * 1e-6, rel=1e-14)
    assert u.axes.ph == pytest.approx(9e-4 + grow, rel=1e-14)
    kept = copy.deepcopy(before)
    K.uncertainty_hole(kept, extra, var, False)  # the mean restarted: the tilt only shrinks
    assert kept.axes.pt == pytest.approx(a * a * 4e-4, rel=1e-14)
    # covariance_step adds the hole only where there is one.
    holes = []
    for hole_var in (0.0, var):
        w = copy.deepcopy(before)
        K.covariance_step([w], 0.01, 0.1, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0,
                          extra, hole_var, -1.0, 0.0, 0.0, 9.8, False)
        holes.append((w.axes.ph, w.axes.b))
    (without, b), (with_hole, _) = holes  # the bias's variance as the step left it
    assert with_hole - without == pytest.approx(2e-3 ** 2 * extra + b * extra ** 2 + var,
                                                rel=1e-9)


@pytest.mark.parametrize('turn', [0.0, 0.5])
def test_held_on_the_gyro_the_tilt_grows_with_the_bias_unless_the_body_turns_it_round(turn):
    # The inclination held on the gyro (the force rejected: no correction):
    # a bias error β of variance B tilts the world along R β. A body that
    # does not turn: the tilt's variance grows by B t²; one turning about the
    # vertical at Ω carries β round: 2 B (1 − cos Ω t) / Ω², never above 4 B / Ω².
    b, dt, seconds = 1e-6, 0.01, 20.0
    params = UncertaintyParams(gyro_noise=1e-9, gyro_rate_noise=0.0, bias_std=1e-3,
                               bias_init=1e-3, bias_time=1e6, acc_noise=0.05)
    tracker = AttitudeUncertainty(params, use_mag=False)
    tracker.start(dt)
    u = tracker.state[0]
    u.axes.pt, u.axes.ct, u.axes.ct_turned, u.axes.b = 0.0, 0.0, 0.0, b
    count = int(seconds / dt)
    for _ in range(count):
        tracker.step(dt, (0.0, 0.0, turn), (1.0, 0.0, 0.0, 0.0), False, held=True)
    t = count * dt
    expected = (b * t * t if turn == 0.0
                else 2.0 * b * (1.0 - math.cos(turn * t)) / turn ** 2)
    # (To the order of Ω dt: the steps turn C after it added to the tilt.)
    assert u.axes.pt == pytest.approx(expected + b * t * dt, rel=2e-3 + turn * dt * 4.0)
    # Not held, the force corrects it every sample: back near the accelerometer's own.
    for _ in range(count):
        tracker.step(dt, (0.0, 0.0, turn), (1.0, 0.0, 0.0, 0.0), False)
    assert u.axes.pt < 0.1 * b * t * t
