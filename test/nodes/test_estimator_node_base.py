"""
What the two estimator nodes share (``nodes/estimator_node_base.py``), on a
real node and called directly, without traffic: the reset service and a
clock jump counted by cause, the fault counters by their keys, times never
rounded up. (Through topics, with bad inputs and jumps: ``test_faults.py``.)
"""

from rclpy.clock import ClockChange, TimeJump
from rclpy.duration import Duration
from std_srvs.srv import Trigger

from ext_observer.nodes.estimator_node_base import floor_text
from ext_observer.nodes.imu_filter_node import ImuFilterNode


def test_times_are_rounded_down_to_a_hundredth():
    assert floor_text(0.129) == '0.12' and floor_text(2.0) == '2'
    assert floor_text(0.999999) == '0.99'


def test_a_reset_and_a_clock_jump_back_are_counted_by_cause(ros_context):
    node = ImuFilterNode(context=ros_context)
    try:
        response = node.reset_callback(Trigger.Request(), Trigger.Response())
        assert response.success and response.message
        # rclpy's own jump record, as the clock hands it to the callback.
        back = TimeJump(ClockChange.ROS_TIME_NO_CHANGE, Duration(nanoseconds=-2_000_000_000))
        ahead = TimeJump(ClockChange.ROS_TIME_NO_CHANGE, Duration(nanoseconds=2_000_000_000))
        node.clock_jump_callback(back)
        node.clock_jump_callback(ahead)
        faults = node.faults()
        assert faults['resets_service'] == 1 and faults['resets_clock_jump'] == 1
        assert faults['resets_backward_jump'] == 0 and faults['forward_gaps'] == 0
        assert {key for key in faults if key.startswith('resets_')} == {
            'resets_backward_jump', 'resets_clock_jump', 'resets_forward_gap', 'resets_service'}
        assert 'early_releases' in faults and 'reinitialized_state_non_finite' in faults
    finally:
        node.destroy_node()
