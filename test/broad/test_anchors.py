"""
The anchors (``broad/anchors.py``): the first attitude from gravity and the
field, each anchor's frames on a synthetic static sensor (their packages are
in requirements-test.txt), Fusion's settings.
"""

import math

import numpy as np
import pytest

from broad_synthetic import in_sensor_frame, rotation
from ext_observer import broad
from ext_observer.core.quaternion import multiply


def test_attitude_from_acc_and_field():
    q = multiply(rotation((0, 0, 1), 0.8), rotation((1, 1, 0), 0.5))
    acc = in_sensor_frame(q, (0.0, 0.0, 9.81))
    mag = in_sensor_frame(q, (0.0, 20.0, -40.0))  # µT, north and down
    q0 = broad.attitude_from_acc_mag(acc, mag)
    assert abs(np.dot(q0, q)) == pytest.approx(1.0, abs=1e-12)
    _, _, inclination = broad.error_angles(broad.attitude_from_acc_mag(acc), q)
    assert inclination == pytest.approx(0.0, abs=1e-7)


@pytest.mark.parametrize('anchor', broad.ANCHORS)
@pytest.mark.parametrize('mode', broad.MODES)
def test_anchor_frames_on_a_static_sensor(anchor, mode):
    """
    A static sensor, tilted and turned: each anchor's converted output is q.

    The specific force points up, the field north and down (ENU); after 20 s
    at 100 Hz each anchor, brought to ENU by its fixed factor, must give the
    attitude (9D) or its inclination (6D). A wrong world frame (NWU read as
    ENU) gives 90° of heading, a conjugate or a scalar-last reading tens of
    degrees of inclination.
    """
    # The anchors are in requirements-test.txt: a missing one fails here.
    q = multiply(rotation((0, 0, 1), math.radians(30.0)),
                 multiply(rotation((1, 0, 0), math.radians(10.0)),
                          rotation((0, 1, 0), math.radians(-15.0))))
    rate, n = 100.0, 2000
    rng = np.random.default_rng(0)
    acc = in_sensor_frame(q, (0.0, 0.0, 9.81)) + 0.01 * rng.standard_normal((n, 3))
    mag = in_sensor_frame(q, (0.0, 20.0, -40.0)) + 0.1 * rng.standard_normal((n, 3))
    # Some gyro noise: Madgwick and Mahony skip samples with a zero rate.
    gyr = 1e-3 * rng.standard_normal((n, 3))
    est = broad.anchor_estimates(anchor, gyr, acc, mag, rate, mode == '9D')
    assert est.shape == (n, 4)
    total, _, inclination = broad.error_angles(est[-200:], np.tile(q, (200, 1)))
    assert np.degrees(inclination).max() < 1.0
    if mode == '9D':
        assert np.degrees(total).max() < 1.0


def _tilted_for_a_while(gyro_noise, rate=100.0, rest=10.0, pushed=3.0):
    """A level sensor at rest, then pushed sideways: its specific force 30° off up."""
    rng = np.random.default_rng(1)
    n, m = int((rest + pushed) * rate), int(pushed * rate)
    acc = np.tile((0.0, 0.0, 9.81), (n, 1))
    acc[-m:] = 9.81 * np.array([math.sin(math.radians(30.0)), 0.0, math.cos(math.radians(30.0))])
    return (gyro_noise * rng.standard_normal((n, 3)), acc + 0.01 * rng.standard_normal((n, 3)),
            np.tile((0.0, 20.0, -40.0), (n, 1)))


def _inclination_at_end(est):
    return math.degrees(broad.error_angles(est[-1], (1.0, 0.0, 0.0, 0.0))[2])


def test_fusion_runs_at_its_readmes_settings_and_at_its_package_defaults():
    imufusion = pytest.importorskip('imufusion')
    assert broad.ANCHORS[-2:] == ('Fusion', broad.FUSION_DEFAULTS)
    assert broad.ANCHOR_PACKAGES[broad.FUSION_DEFAULTS] == 'imufusion'
    readme = broad.fusion_settings(250.0)
    assert readme == pytest.approx({'sample_rate': 250.0, 'gain': 0.5, 'gyroscope_range': 2000.0,
                                    'acceleration_rejection': 10.0, 'magnetic_rejection': 10.0,
                                    'rejection_timeout': 5.0})
    assert broad.fusion_settings(50.0, math.radians(250.0))['gyroscope_range'] == pytest.approx(
        250.0)
    assert broad.fusion_settings(250.0, readme=False) == {'sample_rate': 250.0}
    # The names are the package's: each setting reads back as given.
    given = imufusion.AhrsSettings(**readme)
    assert {k: getattr(given, k) for k in readme} == pytest.approx(readme)


def test_fusions_settings_reach_the_filter():
    """
    Pushed sideways for 3 s, Fusion at its README's settings rejects the accelerometer.

    At the package defaults it follows it; a gyro range below the gyro's
    noise restarts Fusion at every sample (no rejection while it starts),
    one above it does not: the range is passed, and in °/s.
    """
    gyr, acc, mag = _tilted_for_a_while(gyro_noise=math.radians(0.1))

    def inclination(anchor, **kw):
        return _inclination_at_end(broad.anchor_estimates(anchor, gyr, acc, mag, 100.0, False,
                                                          **kw))
    assert inclination('Fusion') < 2.0
    assert inclination('Fusion', gyro_range=math.radians(1.0)) < 2.0
    assert inclination('Fusion', gyro_range=math.radians(0.02)) > 15.0
    assert inclination(broad.FUSION_DEFAULTS) > 15.0
