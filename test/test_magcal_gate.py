"""
The calibration's gate: an improbable field is not learned (a fault that matters), no ROS.

A magnet passing by adds a field for a moment; the calibration's Kalman
filter refuses a field whose innovation is improbable (``GATE``), so such a
moment teaches nothing. Without the gate (a mutant of mutation/mutants.toml,
which the rest of the suite let through) three half-second passes move the
learned offset by 5 % of the field.
"""

import numpy as np

from ext_observer.core import quaternion as quat
from ext_observer.core.ahrs.magcal import MagCalibrator
from synthetic_motion import rotate, synthetic
from test_magcal import distort, distortion, NORM, RATE


def test_a_passing_magnet_is_gated_and_teaches_nothing():
    truth, _, _, mag = synthetic(seconds=60.0, seed=11)
    s, b = distortion(1)
    raw = distort(mag, s, b)
    passing = np.zeros(len(truth), dtype=bool)
    for start in (12.0, 25.0, 40.0):  # s: three passes of 0.5 s
        passing[int(start * RATE):int((start + 0.5) * RATE)] = True
    raw[passing] += 0.6 * NORM * np.array([0.0, 0.6, 0.8])
    cal = MagCalibrator()
    up = rotate(quat.conjugate(truth), np.array([0.0, 0.0, 1.0]))
    previous = truth[0]
    learned = range(0, len(truth), 2)  # 100 Hz
    for k in learned:
        turn = quat.multiply(quat.conjugate(previous), truth[k])
        previous = truth[k]
        cal.learn(tuple(raw[k]), tuple(turn), 2.0 / RATE, (0.0, 0.0, 0.0), tuple(up[k]))
    counts = {key: int(v[0]) for key, v in cal.counts.items()}
    assert counts['gated'] == passing[::2].sum() == 150
    assert counts['used'] == len(learned) - 150
    assert cal.state == 'converged'
    assert np.linalg.norm(cal.bias - b) < 0.02 * NORM
