"""
The accelerometer's step (core/ahrs/gravity_kernel.py): fast known answers for mutmut (no ROS).

Most of the step is tested through the kernel (test_ahrs_kernel.py) and at
a hole (test_hole_kernel.py); here the correction's gain over the steps a
hole's sample stands for, against the rule the docstring states: the
rotation ``δ`` taking the filtered force to the vertical, applied as
``r = (1 − κ) + κ δ`` with ``κ = 1 − (1 − k_acc)ⁿ`` for ``n`` steps.
"""

import math

import pytest

from ext_observer.core.ahrs.ahrs_filters import rotate, steady
from ext_observer.core.ahrs.ahrs_observer import AhrsObserver, AhrsParams
from ext_observer.core.ahrs.gravity_kernel import ahrs_update_acc

DT = 0.01
UP = (0.0, 0.0, 9.81)
STILL = (0.0, 0.0, 0.0)


@pytest.mark.parametrize('steps', [1.0, 2.0, 3.0])
def test_a_holes_sample_turns_the_inclination_by_the_gain_of_the_steps_it_stands_for(steps):
    # Settled, then tilted 5° about x with the low-pass steady at the tilted
    # force: the filtered force is that force, δ the turn back to vertical.
    est = AhrsObserver(AhrsParams(tau_bias=0.0, acc_reject=0.0), use_mag=False, compiled=False)
    for _ in range(500):
        est.update(STILL, UP, None, DT)
    s = est.state[0]
    half = 0.5 * math.radians(5.0)
    q = (math.cos(half), math.sin(half), 0.0, 0.0)
    s.est.q[:] = list(q)
    fx, fy, fz = rotate(*q, *UP)
    steady(s.coef.bw, s.inc.lp, 0, fx, fy, fz)
    s.hole.steps = steps
    kap = 1.0 - (1.0 - s.coef.k_acc) ** steps
    ahrs_update_acc(s, *UP)
    # δ ∝ (1 + u_z, u_y, −u_x, 0) for u = f/|f|: a turn about x only here.
    n = math.sqrt(fx * fx + fy * fy + fz * fz)
    dw, dx = 1.0 + fz / n, fy / n
    dn = math.hypot(dw, dx)
    rw, rx = 1.0 - kap + kap * dw / dn, kap * dx / dn
    w, x = rw * q[0] - rx * q[1], rw * q[1] + rx * q[0]
    assert abs(s.est.q[2]) < 1e-15 and abs(s.est.q[3]) < 1e-15
    assert [s.est.q[0], s.est.q[1]] == pytest.approx([w, x], rel=1e-12)
    # The tilt left: the 5° less r's turn back, the same side (no overshoot).
    left = 2.0 * math.atan2(s.est.q[1], s.est.q[0])
    assert left == pytest.approx(math.radians(5.0) + 2.0 * math.atan2(rx, rw), rel=1e-9)
    assert 0.0 < left < math.radians(5.0)
