"""
The uncertainty model alone (``core/ahrs/uncertainty.py``): its steady state is
the closed form of a first-order correction, rest teaches the bias, a lasting
innovation of the fields is counted as the heading's lag, its parameters
refused with their name.
"""

import math

import pytest

from ext_observer.core.ahrs import compiled as compiled_module
from ext_observer.core.ahrs.ahrs_params import UncertaintyParams
from ext_observer.core.ahrs.uncertainty import AttitudeUncertainty
from ext_observer.core.ahrs.uncertainty_kernel import INNOVATION_TIME
from node_settings import node_settings


def test_steady_state_is_the_closed_form_of_a_first_order_correction():
    # White gyro noise only, an accelerometer correction every sample: the
    # tilt variance settles where growth and shrinkage balance.
    params = UncertaintyParams(bias_std=0.0, bias_init=0.0, gyro_rate_noise=0.0,
                               inclination_floor=0.0, stamp_error=0.0)
    tau, dt = 2.0, 0.01
    tracker = AttitudeUncertainty(params, tau_acc=tau)
    tracker.start(dt)
    for _ in range(20000):
        tracker.step(dt, (0.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0), False)
    k = 1.0 - math.exp(-dt / tau)
    q = params.gyro_noise ** 2 * dt
    r = (params.acc_noise / 9.80665) ** 2 / dt
    exact = ((1 - k) ** 2 * q + k * k * r) / (1 - (1 - k) ** 2)
    assert tracker.tilt_variance == pytest.approx(exact, rel=1e-9)
    # ... which is q τ / 2 + r dt / (2 τ) to first order in dt / τ.
    assert exact == pytest.approx(q * tau / (2 * dt) + r * dt / (2 * tau), rel=0.01)


def test_rest_teaches_the_bias_and_slows_the_heading_drift():
    def drift(rest_first):
        tracker = AttitudeUncertainty(use_mag=False)
        tracker.start(0.01)
        for _ in range(300):
            tracker.step(0.01, (0.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0), rest_first)
        before = tracker.heading_variance
        for _ in range(3000):
            tracker.step(0.01, (0.0, 0.0, 0.5), (1.0, 0.0, 0.0, 0.0), False)
        return tracker.heading_variance - before

    assert drift(True) < 0.1 * drift(False)


@pytest.mark.parametrize('compiled', [False, pytest.param(True, marks=pytest.mark.skipif(
    not compiled_module.compiled_available(), reason='numba is not installed'))])
def test_a_lasting_innovation_is_a_lag_and_a_changing_one_is_noise(compiled):
    # The fields' heading in the estimate's frame: 10° one way for
    # INNOVATION_TIME × 5 is the heading's lag (its square is published);
    # ±10° in turn averages out; a correction of gain 1 clears the lag.
    def run(signs, gain=0.001):
        tracker = AttitudeUncertainty()
        if compiled:
            tracker.use_kernels(compiled_module.kernels(True))
        tracker.start(0.01)
        tracker.field(0.01, 1.0)
        for k in range(int(5 * INNOVATION_TIME / 0.01)):
            tracker.step(0.01, (0.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0), False)
            tracker.field(0.01, gain, innovation=signs[k % len(signs)] * math.radians(10.0))
        return tracker

    lag, noise, none = run([1.0]), run([1.0, -1.0]), run([0.0])
    # l ← (1 − k) l + k ψ settles at ψ; counted beyond the field's own error.
    floor = lag.params.heading_floor
    assert lag.heading_variance == pytest.approx(math.radians(10.0) ** 2 - floor ** 2,
                                                 rel=0.02)
    assert noise.heading_std < 1.01 * none.heading_std < 0.5 * lag.heading_std
    before = lag.heading_std
    lag.field(0.01, 1.0, innovation=0.0)
    assert lag.heading_std < 0.2 * before


def test_parameters_are_refused_with_their_name():
    with pytest.raises(ValueError, match='acc_noise must be positive'):
        UncertaintyParams(acc_noise=0.0)
    with pytest.raises(ValueError, match='stamp_error must be >= 0'):
        UncertaintyParams(stamp_error=-1.0)
    with pytest.raises(ValueError, match='unknown parameters'):
        UncertaintyParams(gain=1.0)
    with pytest.raises(ValueError, match=r'covariance\.\*: heading_floor must be finite'):
        node_settings(**{'covariance.heading_floor': math.nan})


def test_the_variance_held_since_the_last_field_is_what_the_gyro_alone_added():
    # After a field, P grows with the gyro's noise and bias; once the field
    # is lost (FIELD_SILENT) the held term grows with the rotation: the
    # held variance is P's growth since the field plus that term, and the
    # heading variance published grows by exactly as much (the floors, the
    # calibration's and the lag's shares are constant here).
    from ext_observer.core.ahrs.uncertainty_kernel import GYRO_MOTION_SIGMA, GYRO_SCALE_SIGMA
    dt, rate = 0.01, 0.5
    tracker = AttitudeUncertainty(UncertaintyParams(stamp_error=0.0))
    tracker.start(dt)
    for _ in range(100):
        tracker.step(dt, (0.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0), False)
        tracker.field(dt, 0.05)
    assert tracker.held_variance == 0.0
    after_field = tracker.heading_variance
    ph = tracker._u.axes.ph
    steps = 500
    for _ in range(steps):
        tracker.step(dt, (0.0, 0.0, rate), (1.0, 0.0, 0.0, 0.0), False)
    lost = tracker._u.held.yaw  # the turn since the field was lost (FIELD_SILENT), rad
    assert lost == pytest.approx((steps * dt - 1.0) * rate, abs=2.0 * rate * dt)
    assert tracker._u.held.rotation == lost
    held = (GYRO_SCALE_SIGMA * lost) ** 2 + (GYRO_MOTION_SIGMA * lost) ** 2
    grown = tracker._u.axes.ph - ph
    assert grown > 0.0
    assert tracker.held_variance == pytest.approx(grown + held, rel=1e-12)
    assert tracker.heading_variance - after_field == pytest.approx(grown + held, rel=1e-9)
