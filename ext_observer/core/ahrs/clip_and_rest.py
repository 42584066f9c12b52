"""
What the gyro's own samples say: a rate at the sensor's range, and a body at rest.

Functions on the estimator's state (``REST`` and ``GYRO``, declared here),
in the compiled subset of Python as :mod:`~ext_observer.core.ahrs.ahrs_kernel`,
which calls them on every gyro sample: :func:`clipped_variance` finds the
clipped axes (from ``gyro_range``, or a rate stuck at its peak) and
:func:`detect_rest` the rest that the bias is learned from (VQF's rest
detection, Laidig & Seel 2023). What the estimator does about a clipped
sample stays in the kernel.
"""

import math

from .ahrs_filters import clip, first_order_step, vertical_in_body
from .bias_kernel import BIAS_P_XX, BIAS_P_YY, BIAS_P_ZZ
from .record import Group


# What the gyro's samples say: rates at the range, and rest.
REST = Group('rest', 'Rest: the body still, the bias learned from the rate at rest', [
    ('detected', '1', 'rest is detected'),
    ('time', 's', 'time below both rest thresholds so far'),
    ('gyr_lp', 'rad/s', 'the rate, low-passed (tau_rest) for rest detection', 3),
    ('acc_lp', 'm/s²', 'the specific force, low-passed (tau_rest) for rest detection', 3),
    ('acc_still', '1', "the specific force is within rest_acc of its low-pass"),
])
GYRO = Group('gyro', "The gyro's recent rates and a clipped gyro", [
    ('clips', '', 'clipped samples counted'),
    ('clipped', 'rad²', "the last sample's clipped variance (0: not clipped)"),
    ('clipped_vertical', 'rad²', "its part about the world's vertical: the heading's"),
    ('last', 'rad/s', "the latest sample's rate, as measured", 3),
    ('prev', 'rad/s', 'the rate of the sample before the latest', 3),
    ('peak', 'rad/s', 'the largest |rate| on any axis seen'),
    ('stuck', '', 'samples each axis has repeated its rate at the peak', 3),
    ('clip_left', 's', 'of the recovery from a clipped sample still to run'),
])

def rest_reset(s):
    """Not at rest, no time below the thresholds (the low-passed rate and force stay)."""
    s.rest.detected = 0.0
    s.rest.time = 0.0


def gyro_reset(s):
    """No clipped sample to weigh, no recovery to run (the rates and counts stay)."""
    s.gyro.clipped = 0.0
    s.gyro.clipped_vertical = 0.0
    s.gyro.clip_left = 0.0


# σ of the bias learned at rest (rad/s), VQF's value: the low-passed rate of
# a body at rest is a far better measurement than any correction in motion.
_REST_BIAS_SIGMA = math.radians(0.03)
# Rad/s: no gyro's range is below this (the smallest common one, ±125 °/s, is
# 2.18 rad/s): a rate stuck at its largest magnitude below it is not clipped.
_CLIP_FLOOR = 2.0
# A rate this close to a known range (relative) is at it.
_AT_RANGE = 1e-4
# Unknown range: a rate repeated this many times more at the largest
# magnitude seen is stuck (a smooth peak of a quantized rate repeats once;
# none of BROAD's 22 trials repeats twice).
_STUCK = 2.0
# A low-passed rate beyond bias_max by more than this share of rest_gyr is
# not rest (a bias beyond bias_max is still learned, clipped, at rest).
_BEYOND = 0.5
# Once the bias has settled at rest (_SETTLED tau_rest after rest began: a
# first offset of bias_max is then 2 % of itself), the low-passed rate may
# lead it by this share of rest_gyr only: a rate that keeps leading it is
# ramping (a vehicle steering slowly into a turn), which the bias would
# otherwise follow to bias_max.
_HELD = 0.25
_SETTLED = 4.0


def _at_range(s, i, g):
    """Whether rate ``g`` on axis ``i`` is at the gyro's range (and the axis's memory)."""
    a = abs(g)
    rng = s.par.gyro_range
    if rng > 0.0:
        at = a >= rng * (1.0 - _AT_RANGE)
    else:
        # Unknown range: stuck at the largest magnitude seen.
        same = a >= _CLIP_FLOOR and a == abs(s.gyro.last[i]) and a >= s.gyro.peak
        s.gyro.stuck[i] = s.gyro.stuck[i] + 1.0 if same else 0.0
        at = s.gyro.stuck[i] >= _STUCK
    s.gyro.prev[i] = s.gyro.last[i]  # a hole's end correction takes the slope
    s.gyro.last[i] = g
    return at


def clipped_variance(s, gx, gy, gz):
    """
    The attitude variance a sample at the gyro's range adds (rad²); 0.0 if none is.

    The rate beyond the range is unknown: each clipped axis adds
    ``(range dt)²`` (``S_CLIPPED``, for the covariance), and the sample is
    counted (``S_CLIPS``). The part about the world's vertical, each clipped
    axis's times the square of its vertical component
    (:func:`~ext_observer.core.ahrs.ahrs_filters.vertical_in_body`), is the heading's (``gyro.clipped_vertical``); the rest turns
    the tilt.
    """
    dt = s.coef.dt
    cx = _at_range(s, 0, gx)
    cy = _at_range(s, 1, gy)
    cz = _at_range(s, 2, gz)
    peak = max(abs(gx), max(abs(gy), abs(gz)))
    if peak > s.gyro.peak:
        s.gyro.peak = peak
    top = max(s.par.gyro_range, s.gyro.peak) * dt
    var = ((1.0 if cx else 0.0) + (1.0 if cy else 0.0) + (1.0 if cz else 0.0)) * top * top
    s.gyro.clipped = var
    s.gyro.clipped_vertical = 0.0
    if var != 0.0:
        s.gyro.clips += 1.0
        ux, uy, uz = vertical_in_body(s)
        s.gyro.clipped_vertical = ((ux * ux if cx else 0.0) + (uy * uy if cy else 0.0)
                                   + (uz * uz if cz else 0.0)) * top * top
    return var


def detect_rest(s, gx, gy, gz):
    """
    Rest: gyro and specific force still for ``rest_time``.

    At rest the bias is the low-passed rate.
    """
    k = s.coef.k_rest
    lx, ly, lz = first_order_step(s.rest.gyr_lp, k, gx, gy, gz)
    bx, by, bz = s.bias.rate[0], s.bias.rate[1], s.bias.rate[2]
    ex, ey, ez = gx - lx, gy - ly, gz - lz
    dev = ex * ex + ey * ey + ez * ez
    mx, my, mz = lx - bx, ly - by, lz - bz
    mean = mx * mx + my * my + mz * mz
    th = s.par.rest_gyr * s.par.rest_gyr
    settled = s.rest.time > s.par.rest_time + _SETTLED * s.par.tau_rest
    held = _HELD * _HELD * th if settled else th
    # A rate well beyond bias_max on any axis is no bias: a steady turn is not rest.
    big = max(abs(lx), max(abs(ly), abs(lz))) > s.par.bias_max + _BEYOND * s.par.rest_gyr
    still = (dev < th) and (mean < held) and s.rest.acc_still != 0.0 and not big
    s.rest.time = (s.rest.time + s.coef.dt) if still else 0.0
    rest = s.rest.time >= s.par.rest_time
    s.rest.detected = 1.0 if rest else 0.0
    # At rest the bias is the low-passed rate, within bias_max per axis
    # as in motion.
    kr = k if rest else 0.0
    m = s.par.bias_max
    s.bias.rate[0] = clip(bx + kr * mx, -m, m)
    s.bias.rate[1] = clip(by + kr * my, -m, m)
    s.bias.rate[2] = clip(bz + kr * mz, -m, m)
    if rest:
        # Its variance as that of a measurement whose steady σ is
        # _REST_BIAS_SIGMA's: (1 − k)² P + k² r, r = 2 σ² / k.
        a = (1.0 - k) * (1.0 - k)
        add = 2.0 * k * _REST_BIAS_SIGMA * _REST_BIAS_SIGMA
        for i in range(6):
            diagonal = i == BIAS_P_XX or i == BIAS_P_YY or i == BIAS_P_ZZ
            s.bias.p[i] = a * s.bias.p[i] + (add if diagonal else 0.0)
