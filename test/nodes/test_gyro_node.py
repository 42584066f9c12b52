"""
The simulated gyro's node (``nodes/gyro_node.py``) through real topics: it
publishes its steps and stops.
"""

from ext_observer.nodes.gyro_node import GyroNode
from ros_helpers import overrides, Probe, values_of


def test_gyro_publishes_its_steps_and_stops(ros_context, spinner):
    probe = spinner.add(Probe(ros_context))
    initial = [0.0, 0.0, 0.0, 2.0]
    gyro = spinner.add(GyroNode(context=ros_context, parameter_overrides=overrides(
        rate_hz=100.0, steps=5, seed=3, initial_attitude=initial, frame_id='map',
        increment_max=0.5)))
    # Its first status has measured no rate yet: NaN, not a stalled 0.
    assert values_of(gyro.status())['achieved_rate_hz'] == 'nan'
    spinner.spin_until(lambda: gyro.finished and len(probe.increments) == 5
                       and len(probe.truths) == 5, 10.0, 'five steps')
    # Stopped: ten more periods publish nothing (more time only makes a sixth
    # step likelier to show).
    spinner.spin_for(0.1)
    assert gyro.steps_published == 5 and len(probe.truths) == 5
    first = min(probe.truths)
    assert probe.truths[first] == (0.0, 0.0, 0.0, 1.0)
    assert all(0.0 <= v <= 0.5 for theta in probe.increments.values() for v in theta)
