"""The gain certificate of Theorem 1 on S³ (no ROS): exact and sampled."""

import numpy as np
import pytest

from ext_observer.core import (certified_alpha_max, estimate_certificate, optimal_delta,
                               s3_certificate, sphere_extension)
from ext_observer.core import quaternion as quat

from sphere_shell import kinematics, shell_samples


def test_paper_certificate():
    cert = s3_certificate(0.5, 0.059, alpha=0.01)
    assert cert.L == pytest.approx(3.69, abs=0.01)
    assert cert.alpha_max < 0.016
    assert cert.alpha_max == pytest.approx(0.059 / cert.L)
    # Exact d: 12 (√(1 + √ε) + δ)² − 4; the paper states 15.87.
    assert cert.d == pytest.approx(18.377, abs=1e-3)
    assert cert.b == pytest.approx(16 * (1 - np.sqrt(0.5)))
    assert 0.0 < cert.factor < 1.0
    assert cert.certifies(0.01) and not cert.certifies(0.02)


def test_optimal_delta_balances_the_two_bounds():
    delta, alpha_max = optimal_delta(0.5)
    cert = s3_certificate(0.5, delta)
    assert delta / cert.L == pytest.approx(2.0 / cert.d, rel=1e-9)
    assert alpha_max > s3_certificate(0.5, 0.059).alpha_max
    for other in (0.5 * delta, 0.9 * delta, 1.1 * delta, 2 * delta):
        assert s3_certificate(0.5, other).alpha_max < alpha_max
    assert certified_alpha_max(0.5) == alpha_max


@pytest.mark.parametrize('epsilon, delta', [(0.0, 0.1), (1.0, 0.1), (0.5, 0.0),
                                            (float('nan'), 0.1)])
def test_certificate_refuses_invalid_constants(epsilon, delta):
    with pytest.raises(ValueError):
        s3_certificate(epsilon, delta)


@pytest.mark.parametrize('epsilon, delta, alpha', [
    (0.5, 0.059, 0.01), (0.5, 0.059, 0.0159), (0.3, 0.2, 0.05)])
def test_certified_contraction_holds_on_every_sample(epsilon, delta, alpha):
    """Theorem 1: V(x⁺) ≤ (1 − bc) V(x) for every x in V⁻¹([0, ε])."""
    cert = s3_certificate(epsilon, delta, alpha)
    assert cert.certifies(alpha)
    rng = np.random.default_rng(2)
    ext = sphere_extension()
    x = shell_samples(rng, epsilon, 100000)
    theta = rng.uniform(0.0, 10.0, (100000, 3))
    x_next = ext.step(kinematics, x, alpha, theta)
    assert np.all(ext.V(x_next) <= cert.factor * ext.V(x) + 1e-15)


def test_sampled_certificate_estimates_the_exact_one():
    rng = np.random.default_rng(5)
    samples = quat.random_unit_quaternions(rng, (20000,)) * np.sqrt(
        rng.uniform(0.0, 2.0, 20000))[:, None]
    est = estimate_certificate(sphere_extension(), samples, 0.5, 0.059, rng=rng)
    exact = s3_certificate(0.5, 0.059)
    assert est.estimated and not exact.estimated
    assert est.L == pytest.approx(exact.L, rel=0.01)
    assert est.d == pytest.approx(exact.d, rel=0.02)
    assert est.b == pytest.approx(exact.b, rel=0.02)
    assert est.L <= exact.L * (1 + 1e-12) and est.d <= exact.d * (1 + 1e-12)
