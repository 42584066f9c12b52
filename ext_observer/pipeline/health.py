"""
The estimator's health: which of a few named states it is in, without ROS.

``imu_filter_node`` states them in ``/diagnostics`` (key ``health``) and
:func:`~ext_observer.recordings.recording.attitude_from_imu` per sample
(``Recording.health``, ``Recording.in_state``); docs/diagnostics.md says
when each starts and ends. It only reads the estimator: the estimates are
the same with or without it.

A state more is one line in ``_STATES`` (its name and whether it is
active); :data:`HEALTH_STATES` and the Recording's bits follow the table.
"""

from ext_observer.core.ahrs.ahrs_state import STATE

__all__ = ['HEALTH_STATES', 'HealthWatch', 'NO_STATE', 'health_text']

# Each state: its name, and whether it is active, from the HealthWatch ``w``,
# the estimator's state ``s`` (a view by attribute) and the pipeline ``p``.
# Meanings: docs/diagnostics.md.
_STATES = (
    ('initializing', lambda w, s, p: w.initializing),
    ('at_rest', lambda w, s, p: s.rest.detected != 0.0),
    ('accelerometer_rejected', lambda w, s, p: s.rej.time > 0.0),
    ('field_rejected', lambda w, s, p: s.field.mag_dist != 0.0),
    ('gyro_clipped', lambda w, s, p: w.recovering),
    ('field_lost', lambda w, s, p: field_lost(p)),
    ('velocity_aided', lambda w, s, p: s.vel.used != 0.0),
)
# The names, in the order of their bits in ``Recording.health`` (bit i: HEALTH_STATES[i]).
HEALTH_STATES = tuple(name for name, _ in _STATES)
_BITS = {name: 1 << i for i, name in enumerate(HEALTH_STATES)}
# The health text when no state is active: the estimate is tracking normally.
NO_STATE = 'tracking'


def health_text(states):
    """The states joined by ``', '``, or :data:`NO_STATE` when there are none."""
    return ', '.join(states) if states else NO_STATE


class HealthWatch:
    """
    The health of one :class:`~ext_observer.pipeline.raw_imu.RawImuPipeline`.

    The start runs the inclination's running mean (the kernel's start slot
    below ``tau_acc``), and so may a clipped stretch or a hole; what tells
    them apart is remembered here: whether the mean has handed over since the
    estimator (re)started (the slot going back without a clip is a restart),
    and whether a sample clipped since the last call. A clip's recovery is
    the kernel's (``tau_acc`` after the last clipped sample). Asked at every sample
    (the Recording) or at every status (the node: at least once per ``tau_acc``).
    """

    def __init__(self):
        self.initializing = True   # the start's running mean has not handed over yet
        self.recovering = False    # tau_acc has not passed since the last clipped sample
        self._handed_over = False
        self._clips = 0
        self._start = 0.0
        self._holder = self._view = None

    def __call__(self, pipeline):
        """Return the active states, a tuple in :data:`HEALTH_STATES`' order."""
        # The state read through a view: asked at every sample of a recording.
        holder = pipeline.estimator.core.state
        if holder is not self._holder:
            self._holder, self._view = holder, STATE.view(holder)
        s = self._view
        self._follow(s)
        return tuple(name for name, active in _STATES if active(self, s, pipeline))

    def mask(self, pipeline):
        """The active states as bits: bit i set for ``HEALTH_STATES[i]``."""
        return sum(_BITS[name] for name in self(pipeline))

    def _follow(self, s):
        """Update :attr:`initializing` and :attr:`recovering` from the state (a view)."""
        clips = s.gyro.clips
        clipped = clips != self._clips or s.gyro.clipped != 0.0
        self._clips = clips
        if s.est.init == 0.0:
            self.initializing, self.recovering = True, False
            self._handed_over = False
            self._start = 0.0
            return
        start = s.inc.start
        if start < self._start and not clipped:
            # The mean restarted without a clip: the estimator restarted
            # (a reset between two calls, a hole in the stream).
            self._handed_over = False
        self._start = start
        starting = start < s.par.tau_acc
        # A clip's recovery: the kernel's, tau_acc after the last clipped sample.
        self.recovering = s.gyro.clip_left > 0.0
        if not starting:
            self._handed_over = True
        self.initializing = not self._handed_over


def field_lost(pipeline):
    """No field for ``mag_timeout`` s of the IMU's stamps (9D, a field seen before, a timeout)."""
    timeout = pipeline.estimator._mag_timeout
    if timeout <= 0.0 or not pipeline.estimator.core.use_mag:
        return False
    silence = pipeline.field_silence()
    return silence is not None and timeout <= silence
