"""
Samples lost before they reach a node: the share, the longest hole, the lag.

A sensor stream at a steady rate tells its own losses: an interval between
two stamps of about k nominal intervals means k − 1 samples missing. The
node feeds each stamp (ns) to :attr:`StreamHealth.sample` (a bound
``deque.append``: nothing else runs per sample) and asks for a
:meth:`StreamHealth.report` at each status with its clock's time; the
report learns the nominal interval (the median of the intervals since the
last one), counts the samples missing in the holes, and keeps the share
lost over the last :data:`WINDOW` seconds of statuses. An *episode* starts
when that share exceeds :data:`THRESHOLD` and ends at the first report
whose window is back at or below it: :attr:`Report.started` and
:attr:`Report.ended` say so once each, for a log line.

No ROS: the clock is the caller's (integer ns), and so is the meaning of
the lag (that clock's now − the newest stamp: only a lag when the stamps
come from the same clock). Stamps older than the newest open no hole; a
time line that starts again (a bag that loops) needs :meth:`restart`.
"""

import collections
import statistics

__all__ = ['MAX_PENDING', 'MIN_INTERVALS', 'HOLE_FACTOR', 'Report', 'StreamHealth',
           'THRESHOLD', 'WINDOW']

# WARN above this share of samples lost over the window.
THRESHOLD = 0.01
# The window of the share, s of the caller's clock (the statuses within it).
WINDOW = 2.0
# An interval longer than this many nominal intervals is a hole.
HOLE_FACTOR = 1.5
# Intervals needed to learn (or learn again) the nominal one.
MIN_INTERVALS = 8
# Stamps kept between two reports at most (a status that never comes
# must not grow the node): 65 s at 1 kHz; older ones go uncounted.
MAX_PENDING = 65536
SECOND = 1_000_000_000

Report = collections.namedtuple('Report', (
    'received',         # samples in the window
    'lost',             # samples missing in the window (from the stamps)
    'share',            # lost / (received + lost) over the window; 0.0 without samples
    'lost_total',       # samples missing since the start
    'longest_hole',     # s, the longest interval between two samples in the window
    'longest_total',    # s, the same since the start
    'interval',         # s, the nominal interval learned; NaN before it is
    'lag',              # s, now − the latest stamp; NaN before the first
    'warn',             # share > THRESHOLD
    'started',          # this report starts an episode
    'ended',            # this report ends one
))


class StreamHealth:
    """
    The accounting of one stream's stamps; see the module docstring.

    Attributes
    ----------
    sample : callable
        ``sample(stamp_ns)``: one sample received (in arrival order).

    """

    def __init__(self, window=WINDOW, threshold=THRESHOLD):
        self.window = window
        self.threshold = threshold
        self._stamps = collections.deque(maxlen=MAX_PENDING)
        self.sample = self._stamps.append
        self.restart()

    def restart(self):
        """Forget the time line (a reset, a jump of the stamps or the clock)."""
        self._stamps.clear()
        self._last = None           # the latest stamp of the previous reports
        self._interval = None       # ns
        self._buckets = collections.deque()  # (now, received, lost, longest hole ns)
        self.lost_total = 0
        self.longest_total = 0
        self.episode = False

    def _holes(self, stamps):
        """Return ``(lost, longest interval ns)`` of ``stamps`` after the previous ones."""
        previous = self._last
        intervals = []
        for stamp in stamps:
            if previous is None:
                previous = stamp
            elif stamp > previous:
                # From the newest stamp: a late or repeated one opens no hole.
                intervals.append(stamp - previous)
                previous = stamp
        if len(intervals) >= MIN_INTERVALS:
            self._interval = statistics.median_low(intervals)
        nominal = self._interval
        if nominal is None or not intervals:
            return 0, max(intervals, default=0)
        limit = HOLE_FACTOR * nominal
        lost = 0
        for interval in intervals:
            if interval > limit:
                # round(): a jittered stamp is not half a sample lost.
                lost += max(1, round(interval / nominal) - 1)
        return lost, max(intervals)

    def report(self, now):
        """
        Account for the stamps since the last report; return the :class:`Report`.

        Parameters
        ----------
        now : int
            The caller's clock, ns: the window's time and the lag's now.

        """
        stamps = list(self._stamps)
        self._stamps.clear()
        buckets = self._buckets
        if buckets and now < buckets[-1][0]:
            buckets.clear()     # the clock went back: a new window
        lost, longest = self._holes(stamps)
        if stamps:
            self._last = max(stamps) if self._last is None else max(self._last, max(stamps))
        self.lost_total += lost
        self.longest_total = max(self.longest_total, longest)
        buckets.append((now, len(stamps), lost, longest))
        while now - buckets[0][0] > self.window * SECOND:
            buckets.popleft()
        received = sum(b[1] for b in buckets)
        lost_window = sum(b[2] for b in buckets)
        expected = received + lost_window
        share = lost_window / expected if expected else 0.0
        warn = share > self.threshold
        started, ended = warn and not self.episode, self.episode and not warn
        self.episode = warn
        return Report(received, lost_window, share, self.lost_total,
                      max(b[3] for b in buckets) / SECOND, self.longest_total / SECOND,
                      float('nan') if self._interval is None else self._interval / SECOND,
                      float('nan') if self._last is None else (now - self._last) / SECOND,
                      warn, started, ended)
