"""
Magnitudes that only a wrong unit explains, in raw IMU samples; no ROS.

``sensor_msgs`` fixes the units: rad/s, m/s², tesla. Drivers get them
wrong in a few common ways, and the estimator would run on without a word
(a field in µT is only a 10⁶ times longer vector to it). :class:`UnitCheck`
looks at the magnitudes:

- a field stronger than :data:`FIELD_MAX` (1 mT, twenty times the strongest
  geomagnetic field) or weaker than :data:`FIELD_MIN` (0.1 µT): µT, gauss or
  nT read as tesla (Earth's field is 25–65 µT: 25–65 in µT, 0.25–0.65 in
  gauss);
- a specific force whose mean over :data:`ACC_WINDOW` samples is below
  :data:`ACC_MIN` (3 m/s²) or above :data:`ACC_MAX` (50 m/s²): an
  accelerometer in g reads about 1 at rest, one in mg about 1000, where
  m/s² reads 9.81 (the mean over a window, so that a moment of free fall or
  a shock is not taken for a unit);
- an angular rate above :data:`RATE_MAX` (35 rad/s, ±2000 °/s, the widest
  range of common MEMS gyros) on any axis: a gyro in deg/s as soon as the
  body turns faster than 35 °/s.

Each finding is counted per sample (:attr:`UnitCheck.counts`) and described
in words with the magnitude seen and the unit expected
(:attr:`UnitCheck.findings`); the samples are still used, as they are: the
check reports, it does not convert.
"""

import math

__all__ = ['ACC_MAX', 'ACC_MIN', 'ACC_WINDOW', 'FIELD_MAX', 'FIELD_MIN', 'KINDS', 'RATE_MAX',
           'UnitCheck']

FIELD_MAX = 1e-3    # T
FIELD_MIN = 1e-7    # T
ACC_MIN = 3.0       # m/s², mean over a window
ACC_MAX = 50.0      # m/s², mean over a window
ACC_WINDOW = 100    # samples
RATE_MAX = 35.0     # rad/s, any axis

KINDS = ('field', 'acceleration', 'angular_velocity')


class UnitCheck:
    """
    Count the samples whose magnitude only a wrong unit explains.

    Attributes
    ----------
    counts : dict
        Samples found implausible, by kind (:data:`KINDS`).
    findings : dict
        ``kind -> text`` of the latest finding of each kind: what was seen,
        what unit is expected, what the unit probably is.

    """

    def __init__(self):
        self.counts = dict.fromkeys(KINDS, 0)
        self.findings = {}
        self._acc_sum = 0.0
        self._acc_count = 0

    def imu(self, gyr, acc):
        """Look at one IMU sample: angular velocity (rad/s), specific force (m/s²)."""
        g0, g1, g2 = gyr
        # Every axis within the range (the usual sample): nothing to look at.
        if not (-RATE_MAX <= g0 <= RATE_MAX and -RATE_MAX <= g1 <= RATE_MAX
                and -RATE_MAX <= g2 <= RATE_MAX):
            peak = max(abs(g0), abs(g1), abs(g2))
            if peak > RATE_MAX and math.isfinite(peak):
                self.counts['angular_velocity'] += 1
                self.findings['angular_velocity'] = (
                    f'angular velocity {peak:.4g} on one axis, above the range of common '
                    f'gyros in rad/s ({RATE_MAX:g} rad/s = 2000 °/s): rad/s expected, is '
                    'it deg/s?')
        a0, a1, a2 = acc
        norm = math.sqrt(a0 * a0 + a1 * a1 + a2 * a2)
        if not math.isfinite(norm):
            return
        self._acc_sum += norm
        self._acc_count += 1
        if self._acc_count < ACC_WINDOW:
            return
        mean = self._acc_sum / self._acc_count
        self._acc_sum, self._acc_count = 0.0, 0
        if ACC_MIN <= mean <= ACC_MAX:
            return
        self.counts['acceleration'] += ACC_WINDOW
        guess = 'g' if 0.5 <= mean <= 2.0 else 'mg' if 500.0 <= mean <= 2000.0 else None
        self.findings['acceleration'] = (
            f'specific force of norm {mean:.4g} on average over {ACC_WINDOW} samples: '
            'm/s² expected (about 9.81 at rest)'
            + (f', is it {guess}?' if guess else ''))

    def field(self, field):
        """Look at one magnetometer sample (T)."""
        norm = math.sqrt(field[0] * field[0] + field[1] * field[1] + field[2] * field[2])
        if not math.isfinite(norm) or norm == 0.0 or FIELD_MIN <= norm <= FIELD_MAX:
            return
        self.counts['field'] += 1
        if norm > FIELD_MAX:
            guess = ('µT' if 10.0 <= norm <= 100.0 else 'gauss' if 0.1 <= norm <= 1.0
                     else 'nT' if 1e4 <= norm <= 1e5 else None)
        else:
            guess = None
        self.findings['field'] = (
            f'magnetic field of norm {norm:.4g}: tesla expected (Earth: 2.5e-05 to '
            '6.5e-05 T)' + (f', is it {guess}?' if guess else ''))
