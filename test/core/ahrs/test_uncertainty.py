"""
The uncertainty model alone (``core/ahrs/uncertainty.py``): its steady state is
the closed form of a first-order correction, rest teaches the bias, its
parameters refused with their name.
"""

import math

import pytest

from ext_observer.core.ahrs.ahrs_params import UncertaintyParams
from ext_observer.core.ahrs.uncertainty import AttitudeUncertainty
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


def test_parameters_are_refused_with_their_name():
    with pytest.raises(ValueError, match='acc_noise must be positive'):
        UncertaintyParams(acc_noise=0.0)
    with pytest.raises(ValueError, match='stamp_error must be >= 0'):
        UncertaintyParams(stamp_error=-1.0)
    with pytest.raises(ValueError, match='unknown parameters'):
        UncertaintyParams(gain=1.0)
    with pytest.raises(ValueError, match=r'covariance\.\*: heading_floor must be finite'):
        node_settings(**{'covariance.heading_floor': math.nan})
