"""
Synthetic rotations, a sensor's view of world vectors, BROAD's trial names
and a source tree without BROAD (the fixture ``tree``), for the benchmark's
tests.
"""

import math

import numpy as np
import pytest

import broad_data
from ext_observer import broad
from ext_observer.broad import data
from ext_observer.core.quaternion import conjugate, multiply


NAMES = ['04_undisturbed_slow_rotation_with_breaks_A', '15_undisturbed_fast_translation_A',
         '26_disturbed_phone_vibration_A', '32_disturbed_attached_magnet_1cm']


def rotation(axis, angle):
    axis = np.asarray(axis, dtype=float)
    return np.r_[math.cos(angle / 2), math.sin(angle / 2) * axis / np.linalg.norm(axis)]


def in_sensor_frame(q, v):
    """Coordinates in the sensor frame of a world vector, for q sensor → world."""
    return multiply(multiply(conjugate(q), np.r_[0.0, v]), q)[1:]


@pytest.fixture
def tree(tmp_path, monkeypatch):
    """A source tree of its own, with no BROAD beside it nor named in the environment."""
    folder = tmp_path / 'work' / 'main'
    folder.mkdir(parents=True)
    monkeypatch.setattr(data, 'TREE', str(folder))
    monkeypatch.delenv(broad.ENV_VAR, raising=False)
    monkeypatch.delenv(broad_data.ALLOW_NO_DATA, raising=False)
    return folder
