"""
Which BROAD trials chose the estimator's defaults, and which judge them: the one split.

A trial is a **tuning** trial when any default of the estimator was chosen
on it, else **held out**. Two rounds of choosing made :data:`TUNING`: the
first defaults of :class:`~ext_observer.core.ahrs.ahrs_params.AhrsParams`
on 11 trials (docs/broad_tuning.md: the 22 of BROAD's folder sorted by
name, taken alternately from the first), and the later ones (the defaults of
:class:`~ext_observer.core.ahrs.ahrs_params.UncertaintyParams`, the start in
motion, the clipped gyro, the holes: docs/covariance.md, docs/raw_imu.md)
on the 14 even-numbered trials. So four trials of the folder are held out,
with the 17 BROAD trials not in it. A trial's side follows from its number
alone, never from which other trials a run loads; every page, benchmark
and experiment that speaks of tuning and held-out trials asks this module,
and a default chosen from now on is chosen on the tuning trials alone.
"""

# The numbers the tuning trials' names start with.
TUNING = ('01', '02', '03', '04', '05', '06', '08', '10', '12', '14', '15', '18',
          '24', '26', '28', '30', '32', '34')
SPLITS = ('tuning', 'held-out')

__all__ = ['held_out_trials', 'split_of', 'SPLITS', 'trial_number', 'TUNING', 'tuning_trials']


def trial_number(name):
    """Return the number a BROAD trial's name starts with (``'28_...'``: 28), or None."""
    head = name.split('_', 1)[0]
    return int(head) if head.isdigit() else None


def split_of(name):
    """``'tuning'`` or ``'held-out'`` for a BROAD trial's name; None for one without a number."""
    number = trial_number(name)
    if number is None:
        return None
    return 'tuning' if f'{number:02d}' in TUNING else 'held-out'


def tuning_trials(names):
    """The names (or trials, by ``.name``) among ``names`` that chose the defaults, in order."""
    return [n for n in names if split_of(getattr(n, 'name', n)) == 'tuning']


def held_out_trials(names):
    """The names (or trials, by ``.name``) among ``names`` that played no part in choosing them."""
    return [n for n in names if split_of(getattr(n, 'name', n)) == 'held-out']
