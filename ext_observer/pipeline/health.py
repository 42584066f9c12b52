"""
The estimator's health: which of a few named states it is in, without ROS.

``imu_filter_node`` states them in ``/diagnostics`` (key ``health``) and
:func:`~ext_observer.recordings.recording.attitude_from_imu` per sample
(``Recording.health``, ``Recording.in_state``); docs/diagnostics.md says
when each starts and ends. It only reads the estimator: the estimates are
the same with or without it.

A state more is one entry in :data:`HEALTH_STATES` and one line in
:meth:`HealthWatch.__call__`'s table; the Recording's bits follow the tuple.
"""

from ext_observer.core.ahrs.ahrs_layout import (P_TAU_ACC, S_CLIPPED, S_CLIPS, S_INIT,
                                                 S_MAG_DIST, S_REST, S_START, S_VEL_USED)

__all__ = ['HEALTH_STATES', 'HealthWatch', 'NO_STATE', 'health_text']

# The states, in the order of their bits in ``Recording.health`` (bit i: HEALTH_STATES[i]).
HEALTH_STATES = (
    'initializing',    # no estimate yet, or the start's running mean of the vertical
    'at_rest',         # rest detected: the gyro bias is learned
    'field_rejected',  # the latest field disagrees with the reference: heading on the gyro
    'gyro_clipped',    # a sample at the gyro's range, or the inclination coming back from one
    'field_lost',      # no field for mag_timeout: running 6D, the heading held on the gyro
    'velocity_aided',  # a fresh velocity: the body's acceleration removed from the specific force
)
_BITS = {name: 1 << i for i, name in enumerate(HEALTH_STATES)}
# The health text when no state is active: the estimate is tracking normally.
NO_STATE = 'tracking'


def health_text(states):
    """The states joined by ``', '``, or :data:`NO_STATE` when there are none."""
    return ', '.join(states) if states else NO_STATE


class HealthWatch:
    """
    The health of one :class:`~ext_observer.pipeline.raw_imu.RawImuPipeline`.

    The start and a recovery from a clipped gyro both run the inclination's
    running mean (the kernel's start slot below ``tau_acc``); what tells them
    apart is remembered here: whether the mean has handed over since the
    estimator (re)started (the slot going back without a clip is a restart),
    and whether a sample clipped since the last call. Asked at every sample
    (the Recording) or at every status (the node: at least once per ``tau_acc``).
    """

    def __init__(self):
        self._handed_over = False
        self._recovering = False
        self._clips = 0
        self._start = 0.0

    def __call__(self, pipeline):
        """Return the active states, a tuple in :data:`HEALTH_STATES`' order."""
        # The flat state's slots, read directly: asked at every sample of a recording.
        s = pipeline.estimator.core.flat_state
        # First: it also updates the clipped gyro's recovery.
        initializing = self._initializing(s)
        active = {
            'initializing': initializing,
            'at_rest': s[S_REST] != 0.0,
            'field_rejected': s[S_MAG_DIST] != 0.0,
            'gyro_clipped': self._recovering,
            'field_lost': field_lost(pipeline),
            'velocity_aided': s[S_VEL_USED] != 0.0,
        }
        return tuple(name for name in HEALTH_STATES if active[name])

    def mask(self, pipeline):
        """The active states as bits: bit i set for ``HEALTH_STATES[i]``."""
        return sum(_BITS[name] for name in self(pipeline))

    def _initializing(self, s):
        clips = s[S_CLIPS]
        clipped = clips != self._clips or s[S_CLIPPED] != 0.0
        self._clips = clips
        if s[S_INIT] == 0.0:
            self._handed_over = self._recovering = False
            self._start = 0.0
            return True
        start = s[S_START]
        if start < self._start and not clipped:
            # The mean restarted without a clip: the estimator restarted
            # (a reset between two calls, a hole in the stream).
            self._handed_over = False
        self._start = start
        starting = start < s[P_TAU_ACC]
        self._recovering = starting and (clipped or self._recovering)
        if not starting:
            self._handed_over = True
        return not self._handed_over


def field_lost(pipeline):
    """No field for ``mag_timeout`` s of the IMU's stamps (9D, a field seen before, timeout > 0)."""
    timeout = pipeline.estimator._mag_timeout
    if timeout <= 0.0 or not pipeline.estimator.core.use_mag:
        return False
    silence = pipeline.field_silence()
    return silence is not None and timeout <= silence
