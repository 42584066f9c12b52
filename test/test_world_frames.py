"""
What ``world_frame`` (ENU, NWU, NED) changes, tested in each of the three.

The estimator runs in ENU; the frame is applied where an estimate leaves it.
Each place, and the test that runs it in every frame:

- the published orientation (``imu/data``, ``attitude_estimate``):
  ``test_raw_imu_through_dds.py::test_world_frames_rotate_the_enu_estimate``;
- ``declination`` and ``yaw_offset`` (their sign about the frame's own z):
  ``test_imu_filter_node.py::test_declination_turns_the_heading_to_true_north_in_every_frame``;
- ``remove_gravity_vector`` (gravity from the estimator's ENU attitude, not the
  published one) and the debug topics ``imu/rpy/filtered`` and ``imu/rpy/raw``:
  ``test_imu_tools_dropin.py::test_debug_topics_are_imu_datas_rpy_and_gravity_is_removed_at_rest``;
- the estimated orientation covariance (its heading axis is the vertical in
  each): ``test_orientation_covariance.py::test_the_covariance_is_the_same_in_every_world_frame``;
- the fixed orientation covariance (``orientation_stddev``) and the batch
  API's output (``attitude_from_imu``, the ``csv`` and ``bag`` commands): here.

The TF (``publish_tf``) is ``transform_from_estimate`` of the published
orientation, whatever the frame
(``test_imu_filter_outputs.py::test_transform_is_imu_filter_madgwicks_and_its_reverse``);
its broadcaster needs tf2_ros, which pip does not install.
"""

import numpy as np
import pytest

from ext_observer.core.ahrs.ahrs_observer import world_from_enu
from ext_observer.recordings.recording import attitude_from_imu
from imu_driver import connect, Driver
from ros_helpers import overrides, SECOND

RATE = 100.0
FIELD = (2e-5, 1e-5, -4e-5)  # T, as the sensor reads it at the start


def _turning(count):
    """A sensor tilted and turning about its z axis at 0.5 rad/s, with a field each sample."""
    t = np.arange(count) / RATE
    gyr = np.tile([0.0, 0.0, 0.5], (count, 1))
    acc = np.tile([0.6, -0.4, 9.76], (count, 1))
    c, s = np.cos(0.5 * t), np.sin(0.5 * t)
    mag = np.stack([FIELD[0] * c + FIELD[1] * s, -FIELD[0] * s + FIELD[1] * c,
                    np.full(count, FIELD[2])], axis=1)
    return gyr, acc, mag


@pytest.mark.parametrize('frame', ['nwu', 'ned'])
def test_the_batch_api_gives_the_estimate_in_its_world_frame(frame):
    gyr, acc, mag = _turning(300)
    enu = attitude_from_imu(gyr, acc, mag, rate=RATE, check_units=False)
    other = attitude_from_imu(gyr, acc, mag, rate=RATE, check_units=False,
                              parameters={'world_frame': frame})
    assert other.world_frame == frame
    np.testing.assert_allclose(other.ambient, world_from_enu(enu.ambient, frame), atol=1e-12)
    np.testing.assert_allclose(other.quaternions, world_from_enu(enu.quaternions, frame),
                               atol=1e-12)
    # Not the ENU estimate relabelled: NED turns it upside down.
    assert np.abs(other.quaternions - enu.quaternions).max() > 0.5


@pytest.mark.parametrize('frame', ['enu', 'nwu', 'ned'])
def test_a_fixed_orientation_covariance_is_the_same_in_every_frame(ros_context, spinner,
                                                                   frame):
    from ext_observer.nodes.imu_filter_node import ImuFilterNode

    node = spinner.add(ImuFilterNode(context=ros_context, parameter_overrides=overrides(
        world_frame=frame, orientation_stddev=0.2)))
    driver = spinner.add(Driver(ros_context))
    connect(spinner, driver, node)
    start = 1_700_000_000 * SECOND
    for k in range(3):
        driver.send_field(start + k * SECOND // 100, FIELD)
        driver.send_imu(start + k * SECOND // 100, (0.0, 0.0, 0.0), (0.0, 0.0, 9.81))
    spinner.spin_until(lambda: len(driver.outputs) == 2, 10.0, 'imu/data')
    # stddev² on each axis: a covariance that no rotation of the world changes.
    for msg in driver.outputs.values():
        assert list(msg.orientation_covariance) == pytest.approx(
            [0.04, 0, 0, 0, 0.04, 0, 0, 0, 0.04], abs=1e-15)
        o = msg.orientation
        up = {'enu': 1.0, 'nwu': 1.0, 'ned': -1.0}[frame]
        # Level: the sensor's z is the world's up (ENU, NWU) or down (NED).
        assert 1.0 - 2.0 * (o.x * o.x + o.y * o.y) == pytest.approx(up, abs=1e-9)
