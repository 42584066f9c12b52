"""
The names the benchmark's results are keyed by, in the order of its tables.

Every result is ``scores[algorithm][mode][trial]``: ``mode`` is one of
:data:`MODES`, ``algorithm`` one of :data:`ALGORITHMS` (ours, ours without
the extension term, our smoothed estimate, then the anchors).
"""

MODES = ('9D', '6D')
OURS = 'ext_observer'
OURS_PLAIN = 'ext_observer_plain'
# Our estimate of each sample from the whole recording (``--smooth``;
# ext_observer.core.ahrs.smoother).
OURS_SMOOTHED = 'ext_observer smoothed'
# Fusion at its package defaults, beside 'Fusion' at its README's settings.
FUSION_DEFAULTS = 'Fusion (package defaults)'
# VQF's offline form (``vqf.offlineVQF``): each sample's estimate from the
# whole recording, the anchor of our smoothed estimate.
OFFLINE_VQF = 'offline VQF'
# The anchors, in the order of the tables.
ANCHORS = ('VQF', 'BasicVQF', OFFLINE_VQF, 'Madgwick', 'Mahony', 'Fusion', FUSION_DEFAULTS)
ALGORITHMS = (OURS, OURS_PLAIN, OURS_SMOOTHED) + ANCHORS


def algorithms_in(result):
    """Return the algorithms scored in ``result`` (from ``run``), in table order."""
    return [a for a in ALGORITHMS if a in result['scores']]
