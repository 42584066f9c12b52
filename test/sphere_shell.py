"""Points near S³ and the paper's kinematics, for the extension's and the certificate's tests."""

import numpy as np

from ext_observer.core import quaternion as quat


def kinematics(x, theta):
    """The paper's f: x ⊗ exp(Ω/2)."""
    return quat.multiply(x, quat.quaternion_from_rotation_vector(theta))


def shell_samples(rng, epsilon, n):
    """Points of H drawn in V⁻¹([0, ε]) = {1 − √ε ≤ |x|² ≤ 1 + √ε}."""
    root = np.sqrt(epsilon)
    n2 = rng.uniform(1.0 - root, 1.0 + root, n)
    return quat.random_unit_quaternions(rng, (n,)) * np.sqrt(n2)[:, None]
