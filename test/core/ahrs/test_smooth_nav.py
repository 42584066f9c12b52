"""
The stretches' rotations from the velocity across holes (``core/ahrs/smooth_nav.py``):
the block-tridiagonal solve against a dense one, and the per-stretch tilts recovered on
synthetic bounded motion.
"""

import types

import numpy as np

from ext_observer.core import quaternion as quat
from ext_observer.core.ahrs.smooth_holes import gaps_of
from ext_observer.core.ahrs.smooth_nav import block_tridiagonal, join_velocity
from ext_observer.core.ahrs.smooth_strapdown import rotate_rows
from ext_observer.core.ahrs.smoother import SmoothParams


def test_the_block_tridiagonal_solve_is_the_dense_one():
    rng = np.random.default_rng(4)
    count, k = 6, 4
    upper = rng.normal(size=(count - 1, k, k))
    dense = np.zeros((count * k, count * k))
    for s in range(count - 1):
        dense[s * k:(s + 1) * k, (s + 1) * k:(s + 2) * k] = upper[s]
        dense[(s + 1) * k:(s + 2) * k, s * k:(s + 1) * k] = upper[s].T
    dense += (np.abs(dense).sum(axis=1).max() + 1.0) * np.eye(count * k)
    diagonal = np.stack([dense[s * k:(s + 1) * k, s * k:(s + 1) * k] for s in range(count)])
    rhs = rng.normal(size=(count, k))
    x = block_tridiagonal(diagonal, upper, rhs)
    np.testing.assert_allclose(x.ravel(), np.linalg.solve(dense, rhs.ravel()), atol=1e-12)


def _tilt_deg(p, q):
    e = quat.multiply(p, quat.conjugate(q))
    w, z = np.abs(e[:, 0]), np.abs(e[:, 3])
    return np.degrees(2.0 * np.arccos(np.clip(np.sqrt(w * w + z * z), 0.0, 1.0)))


def test_each_stretch_s_tilt_is_recovered_from_bounded_motion():
    """30 s at 100 Hz, 200 ms lost every 2 s; each stretch tilted ~2°, the bridges exact."""
    t = np.arange(3000) / 100.0
    truth = quat.normalize(quat.quaternion_from_rotation_vector(np.stack(
        (0.5 * np.sin(1.3 * t), 0.4 * np.cos(0.7 * t), 2.0 * np.sin(0.3 * t)), axis=1)))
    position = np.stack((0.5 * np.sin(2.1 * t), 0.3 * np.sin(1.7 * t + 1.0),
                         0.2 * np.sin(2.9 * t)), axis=1)
    force = np.gradient(np.gradient(position, t, axis=0), t, axis=0) + (0.0, 0.0, 9.81)
    acc = rotate_rows(quat.conjugate(truth), force)
    keep = np.mod(t, 2.0) >= 0.2
    keep[0] = True
    truth, acc, t = truth[keep], acc[keep], t[keep]
    dt = np.concatenate(([0.01], np.diff(t)))
    axis = types.SimpleNamespace(dt=dt, times=t - t[0], usual=0.01)
    gaps = gaps_of(axis, 0.05)
    stretch = np.searchsorted(gaps[1], np.arange(len(t)), side='right')
    offsets = np.random.default_rng(1).normal(0.0, 0.03, (stretch[-1] + 1, 3))
    tilted = quat.normalize(quat.multiply(
        quat.quaternion_from_rotation_vector(offsets[stretch]), truth))
    p = SmoothParams(nav=True, nav_speed=0.5, nav_accel=5.0, nav_tilt=1.0, nav_bridge=1.0)
    bridge = np.full((len(gaps[0]), 3), 1e-6)
    joined = join_velocity(tilted, truth, acc, bridge, gaps, axis, p)
    before = np.sqrt(np.mean(np.square(_tilt_deg(tilted, truth))))
    after = np.sqrt(np.mean(np.square(_tilt_deg(joined, truth))))
    assert before > 2.0 and after < 0.2
