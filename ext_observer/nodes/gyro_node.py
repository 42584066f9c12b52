"""
The ``gyro`` node: a simulated rate-integrating gyro and attitude sensor.

At every tick of a timer at ``rate_hz`` it draws step k from the core's
:class:`~ext_observer.core.SimulatedGyro` and publishes

- ``attitude/ground_truth`` (``QuaternionStamped``): the true ``q_k``;
- ``attitude/measurement`` (``QuaternionStamped``): ``y_k = q_k ⊗ exp(ν_k)``;
- ``gyro/increment`` (``Vector3Stamped``): ``θ_k`` in rad, the body rotation
  over ``[t_k, t_{k+1})``, so that ``q_{k+1} = q_k ⊗ exp(θ_k / 2)``;

all three stamped ``t_k``. The stamps lie on the grid
``t_k = t_0 + k / rate_hz`` (``t_0``: the node clock at the first step), so
that ``t_{k+1} − t_k`` is exactly one period and a consumer can tell which
steps it missed. After ``steps`` steps (0 = never) the node stops publishing
and stays up until it is stopped.

The reported increment may carry gyro errors (``gyro_noise_std``,
``gyro_bias``, ``bias_walk_std``; off by default, the paper's setup); the
truth always moves by the exact one. Every ``diagnostic_period`` the status
``gyro: outputs`` on ``/diagnostics`` gives the steps published and any
subscriber with incompatible QoS (WARN, with the fix).
"""

import math

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from geometry_msgs.msg import QuaternionStamped, Vector3Stamped
from rclpy.node import Node
from rclpy.qos import QoSProfile

from ext_observer.nodes.conversions import quaternion_stamped, vector_stamped
from ext_observer.nodes.node_common import (diagnostic_array, key_values, NodeParameters,
                                      ParameterError, QosWatch, run_node)
from ext_observer.nodes.node_parameters import GYRO_PARAMETERS, gyro_settings, make_gyro

__all__ = ['GyroNode', 'STATUS_SUFFIX', 'main']

# The status is named '<node name>: outputs'.
STATUS_SUFFIX = ': outputs'

class GyroNode(Node):
    """
    Publish simulated increments, measurements and the ground truth.

    Parameters
    ----------
    node_name : str
        Default ``gyro``.
    **kwargs
        Passed to ``rclpy.node.Node`` (``context``, ``namespace``,
        ``parameter_overrides``, ...).

    Attributes
    ----------
    steps_published : int
    finished : bool
        True once ``steps`` steps have been published.

    Raises
    ------
    ParameterError
        If a parameter is refused at start-up.

    """

    NODE_NAME = 'gyro'

    def __init__(self, node_name=NODE_NAME, **kwargs):
        super().__init__(node_name, **kwargs)
        try:
            self.parameters = NodeParameters(self, GYRO_PARAMETERS, gyro_settings,
                                             self._apply_parameters)
        except ParameterError:
            self.destroy_node()
            raise
        settings = self.parameters.settings
        self.gyro = make_gyro(settings)
        qos = QoSProfile(depth=settings['queue_depth'])
        self.qos = QosWatch(self)
        self.truth_publisher = self.create_publisher(
            QuaternionStamped, 'attitude/ground_truth', qos,
            event_callbacks=self.qos.publisher('attitude/ground_truth', qos))
        self.measurement_publisher = self.create_publisher(
            QuaternionStamped, 'attitude/measurement', qos,
            event_callbacks=self.qos.publisher('attitude/measurement', qos))
        self.increment_publisher = self.create_publisher(
            Vector3Stamped, 'gyro/increment', qos,
            event_callbacks=self.qos.publisher('gyro/increment', qos))
        diagnostics_qos = QoSProfile(depth=10)
        self.diagnostics_publisher = self.create_publisher(
            DiagnosticArray, '/diagnostics', diagnostics_qos,
            event_callbacks=self.qos.publisher('/diagnostics', diagnostics_qos))
        self.steps_published = 0
        self._rate_mark = None       # (node clock ns, steps) at the last status
        self.finished = False
        self._anchor = None
        self._last_stamp = None
        self._timer = self.create_timer(1.0 / settings['rate_hz'], self.timer_callback)
        self.diagnostic_timer = self.create_timer(
            settings['diagnostic_period'], self.diagnostic_callback)
        errors = ''
        if settings['gyro_noise_std'] or any(settings['gyro_bias']) \
                or settings['bias_walk_std']:
            errors = (f', gyro noise {settings["gyro_noise_std"]:g}, bias '
                      f'{list(settings["gyro_bias"])}, bias walk '
                      f'{settings["bias_walk_std"]:g} (rad per step)')
        self.get_logger().info(
            f'publishing at {settings["rate_hz"]:g} Hz, increments up to '
            f'{settings["increment_max"]:g} rad per axis, measurement noise '
            f'{settings["measurement_noise_std"]:g}' + errors
            + (f', {settings["steps"]} steps' if settings['steps'] else ''))

    def destroy_node(self):
        """Log how many steps went out (the count a user or a test can trust), then destroy."""
        if hasattr(self, 'steps_published'):
            self.get_logger().info(f'stopping: {self.steps_published} steps published')
        return super().destroy_node()

    def _stamp(self):
        rate = self.parameters.settings['rate_hz']
        if self._anchor is None:
            self._anchor = (self.get_clock().now().nanoseconds, self.steps_published)
        start, first = self._anchor
        return start + round((self.steps_published - first) * 1e9 / rate)

    def timer_callback(self):
        """Publish one step."""
        settings = self.parameters.settings
        if settings['steps'] and self.steps_published >= settings['steps']:
            self._finish()
            return
        if self.steps_published == 0 and not self._subscribed(settings):
            return
        sample = self.gyro.step()
        stamp = self._stamp()
        self.truth_publisher.publish(
            quaternion_stamped(sample.attitude, stamp, settings['frame_id']))
        self.measurement_publisher.publish(
            quaternion_stamped(sample.measurement, stamp, settings['frame_id']))
        self.increment_publisher.publish(
            vector_stamped(sample.increment, stamp, settings['body_frame_id']))
        self._last_stamp = stamp
        self.steps_published += 1
        if settings['steps'] and self.steps_published >= settings['steps']:
            self._finish()

    def _subscribed(self, settings):
        wanted = settings['wait_for_subscribers']
        return (self.increment_publisher.get_subscription_count() >= wanted
                and self.measurement_publisher.get_subscription_count() >= wanted)

    def _finish(self):
        if not self.finished:
            self.finished = True
            self._timer.cancel()
            self.get_logger().info(f'published {self.steps_published} steps; idle')

    def status(self):
        """
        Return the current ``DiagnosticStatus`` of the outputs.

        Returns
        -------
        status : diagnostic_msgs.msg.DiagnosticStatus
            WARN while a subscriber with incompatible QoS is present, else OK.

        """
        self.qos.refresh()
        settings = self.parameters.settings
        status = DiagnosticStatus(name=f'{self.get_name()}{STATUS_SUFFIX}',
                                  hardware_id=self.get_fully_qualified_name())
        if self.qos.problems:
            status.level = DiagnosticStatus.WARN
            status.message = 'incompatible QoS on ' + ', '.join(sorted(self.qos.problems))
        else:
            status.level = DiagnosticStatus.OK
            status.message = (f'{self.steps_published} steps published'
                              + (', finished' if self.finished else ''))
        # Steps per second of the node clock since the last status: below
        # rate_hz when the process cannot keep up (the stamps stay on the grid).
        now = self.get_clock().now().nanoseconds
        # NaN at the first status: nothing measured yet (0 would read as a
        # stalled gyro).
        achieved = math.nan
        if self._rate_mark is not None and now > self._rate_mark[0]:
            achieved = (self.steps_published - self._rate_mark[1]) * 1e9 / (
                now - self._rate_mark[0])
        self._rate_mark = (now, self.steps_published)
        status.values = key_values(
            [('steps_published', self.steps_published), ('finished', self.finished),
             ('rate_hz', settings['rate_hz']), ('achieved_rate_hz', achieved)]
            + self.qos.key_values())
        return status

    def diagnostic_callback(self):
        """Publish :meth:`status` on ``/diagnostics``."""
        self.diagnostics_publisher.publish(
            diagnostic_array(self.get_clock().now().to_msg(), [self.status()]))

    def _apply_parameters(self, settings, changed):
        if 'rate_hz' in changed and not self.finished:
            period = 1.0 / settings['rate_hz']
            # The grid restarts one new period after the last stamp.
            if self._last_stamp is not None:
                self._anchor = (self._last_stamp + round(period * 1e9),
                                self.steps_published)
            self.destroy_timer(self._timer)
            self._timer = self.create_timer(period, self.timer_callback)
            self.get_logger().info(f'rate changed to {settings["rate_hz"]:g} Hz')


def main(args=None):
    """Run the ``gyro`` node (``ros2 run ext_observer gyro_node``)."""
    return run_node(GyroNode, args)


if __name__ == '__main__':
    import sys
    sys.exit(main())
