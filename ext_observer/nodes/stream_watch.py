"""
A sensor stream's health in a node's status and log: samples lost, holes, lag.

:class:`StreamWatch` holds the ROS-free
:class:`~ext_observer.pipeline.stream_health.StreamHealth` of one input
(fed its stamps by the node's callback), rmw's message-lost count of its
subscription and the node process's CPU share, and turns each status's
report into a WARN text, diagnostic keys and, once per episode, a log line
with the likely cause and what to do (docs/diagnostics.md).
"""

import math
import time

from ext_observer.pipeline.stream_health import StreamHealth, WINDOW

__all__ = ['CPU_BUSY', 'LAG_BEHIND', 'LAG_TRUSTED', 'StreamWatch']

# Lagging the stamps by more than this, s, the node is behind its input.
LAG_BEHIND = 0.05
# A lag beyond this, s (or below 0), says the stamps are not on the node's
# clock (a driver's own time base, a bag replayed without use_sim_time).
LAG_TRUSTED = 10.0
# Process CPU per second of wall time above which the node is saturated.
CPU_BUSY = 0.9

BEHIND = ('the node falls behind its input ({why}): lower the IMU rate, publish fewer '
          'outputs (no imu/data subscriber, publish_debug_topics and publish_tf false), '
          'keep serialized_io true, raise queue_depth to ride out bursts, or give the '
          'node a core of its own')
BEFORE = ('lost before they reach the node, which keeps up ({why}): the driver, its USB '
          'link or a best-effort network drops them; check the driver\'s rate and '
          'link, or raise queue_depth if the node falls behind in bursts')


class StreamWatch:
    """
    The health of one input stream.

    For :class:`~ext_observer.nodes.estimator_node_base.EstimatorNode`.

    Parameters
    ----------
    node : rclpy.node.Node
    words : str
        What the samples are called (``IMU samples``).

    Attributes
    ----------
    sample : callable
        ``sample(stamp_ns)``, per sample received.
    lost_queue : int
        Messages rmw reported lost on the subscription (its message-lost event).
    report : ext_observer.pipeline.stream_health.Report or None
        The last status's.

    """

    def __init__(self, node, words):
        self._node = node
        self._words = words
        self.health = StreamHealth()
        self.sample = self.health.sample
        self.lost_queue = 0
        self._lost_queue_seen = 0
        self.report = None
        self.cpu_share = math.nan
        self._cpu = (time.process_time(), time.monotonic())

    def message_lost(self, info):
        """rmw's message-lost event of the subscription."""
        self.lost_queue += info.total_count_change

    def restart(self):
        """A new time line: forget the stamps."""
        self.health.restart()

    def _measure_cpu(self):
        cpu, wall = time.process_time(), time.monotonic()
        if wall > self._cpu[1]:
            self.cpu_share = (cpu - self._cpu[0]) / (wall - self._cpu[1])
        self._cpu = (cpu, wall)

    def cause(self, report, queue_lost):
        """Return the likely cause and what to do, in words."""
        why = []
        if queue_lost:
            why.append(f'{queue_lost} lost in its queue')
        lag_known = 0.0 <= report.lag <= LAG_TRUSTED
        if lag_known and report.lag > LAG_BEHIND:
            why.append(f'{report.lag * 1e3:.0f} ms behind the stamps')
        if self.cpu_share > CPU_BUSY:
            why.append(f'{self.cpu_share:.0%} of a core')
        if why:
            return BEHIND.format(why='; '.join(why))
        lag = (f'{report.lag * 1e3:.0f} ms behind the stamps' if lag_known
               else 'stamps not on the node clock, lag unknown')
        return BEFORE.format(why=f'{lag}, {self.cpu_share:.0%} of a core')

    def problems(self, now):
        """
        Account for the samples since the last status; return the WARN texts.

        ``now``: the node clock, ns. Logs once when an episode starts (the
        share above the threshold) and once when it ends.
        """
        self._measure_cpu()
        report = self.report = self.health.report(now)
        queue_lost = self.lost_queue - self._lost_queue_seen
        self._lost_queue_seen = self.lost_queue
        text = (f'{report.share:.1%} of the {self._words} lost over the last {WINDOW:g} s '
                f'({report.lost} of {report.received + report.lost}; longest hole '
                f'{report.longest_hole * 1e3:.0f} ms)')
        logger = self._node.get_logger()
        if report.started:
            logger.warning(f'{text}: {self.cause(report, queue_lost)}')
        elif report.ended:
            logger.info(f'{self._words} arriving whole again (at most '
                        f'{self.health.threshold:.0%} lost over {WINDOW:g} s)')
        return [text] if report.warn else []

    def key_values(self):
        """Return the diagnostic pairs (NaN before the first status)."""
        r = self.report
        nan = math.nan
        return [('samples_lost', 0 if r is None else r.lost_total),
                ('samples_lost_share', nan if r is None else r.share),
                ('samples_lost_queue', self.lost_queue),
                ('longest_hole_s', nan if r is None else r.longest_hole),
                ('longest_hole_total_s', nan if r is None else r.longest_total),
                ('sample_interval_s', nan if r is None else r.interval),
                ('lag_s', nan if r is None else r.lag),
                ('cpu_share', self.cpu_share)]
