"""
Synthetic rotations, a sensor's view of world vectors and BROAD's trial
names, for the benchmark's tests.
"""

import math

import numpy as np

from ext_observer.core.quaternion import conjugate, multiply


NAMES = ['04_undisturbed_slow_rotation_with_breaks_A', '15_undisturbed_fast_translation_A',
         '26_disturbed_phone_vibration_A', '32_disturbed_attached_magnet_1cm']


def rotation(axis, angle):
    axis = np.asarray(axis, dtype=float)
    return np.r_[math.cos(angle / 2), math.sin(angle / 2) * axis / np.linalg.norm(axis)]


def in_sensor_frame(q, v):
    """Coordinates in the sensor frame of a world vector, for q sensor → world."""
    return multiply(multiply(conjugate(q), np.r_[0.0, v]), q)[1:]
