"""
A field gone for a while, then back: the heading's σ while it is gone, its error after.

``python -m ext_observer broad --data DIR --covariance --field-gap 60:120``
runs each trial in 9D through the node's pipeline
(:func:`~ext_observer.broad.covariance.run_all`) with every field and without
those of the gap, and judges per trial, per split and over the trials with a
magnet on the board (:data:`MAGNET_GROUP`): the heading's mean e²/σ² with the
field present (:data:`MEAN_PASS`), the share of samples within 2σ while the
field is gone (:data:`GAP_FRACTION`), and the RMS heading error in the
:data:`RETURN_TIME` s after its return against the same seconds without a gap
(docs/covariance.md).
"""

import math

import numpy as np

from ext_observer.broad.covariance import errors, run_all
from ext_observer.broad.split import split_of, SPLITS

# s: how long after a field's return its heading is judged.
RETURN_TIME = 10.0
# The return's RMS heading error may exceed that of the same seconds without a
# gap by this factor, or by this much (rad), whichever allows more.
RETURN_FACTOR, RETURN_MARGIN = 1.5, math.radians(1.5)
# The share of the samples without a field whose heading must be within 2σ.
GAP_FRACTION = 0.95
# The BROAD group whose trials carry a magnet on the board.
MAGNET_GROUP = 'attached_magnet'


def parse_gap(text):
    """``'60:120'`` → ``(60.0, 120.0)``: seconds into each trial, the field gone between."""
    try:
        lo, hi = (float(v) for v in text.split(':'))
    except ValueError:
        raise ValueError(f'a field gap is START:END in seconds, e.g. 60:120; got {text!r}')
    if not 0.0 <= lo < hi < math.inf:
        raise ValueError(f'a field gap needs 0 <= START < END (finite); got {text!r}')
    return lo, hi


def gap_trial(trial, run, gapped, gap):
    """
    One trial's field-gap figures: its heading with the field present, gone, and back.

    Parameters
    ----------
    trial : Trial
    run, gapped : dict
        :func:`run_trial`'s in 9D, without and with ``gap``.
    gap : (float, float)
        s into the trial.

    Returns
    -------
    dict of ndarray
        ``present`` (e²/σ² of the heading over the scored samples without a
        gap), ``gone`` (e²/σ² of the gapped run's heading over the scored
        samples without a field), ``back`` and ``back_ref`` (the heading
        errors, rad, over the scored samples of the :data:`RETURN_TIME` s
        after the field's return, with and without the gap; empty where the
        trial ends before it returns).

    """
    t = np.arange(len(trial)) / trial.rate
    _, heading, scored = errors(trial, run)
    _, heading_gap, scored_gap = errors(trial, gapped)
    gone = scored_gap & (t >= gap[0]) & (t < gap[1])
    back = scored & scored_gap & (t >= gap[1]) & (t < gap[1] + RETURN_TIME)
    return {'present': heading[scored] ** 2 / run['heading'][scored],
            'gone': heading_gap[gone] ** 2 / gapped['heading'][gone],
            'back': heading_gap[back], 'back_ref': heading[back]}


def gap_figures(parts):
    """
    The pooled figures of :func:`gap_trial`'s outputs ``parts``, and whether they pass.

    Returns
    -------
    dict
        ``present_mean_z2``, ``gone_within_2sigma`` (NaN: no sample without
        a field), ``back_rms`` and ``back_rms_ref`` (rad; NaN: no return),
        ``present_ok`` (the mean within :data:`MEAN_PASS`), ``gone_ok``,
        ``back_ok`` (None where there is nothing to judge).

    """
    def cat(key):
        return np.concatenate([p[key] for p in parts])

    present, gone, back, ref = cat('present'), cat('gone'), cat('back'), cat('back_ref')
    f = {'present_mean_z2': float(np.mean(present)) if present.size else math.nan,
         'gone_within_2sigma': float(np.mean(gone <= 4.0)) if gone.size else math.nan,
         'back_rms': float(np.sqrt(np.mean(back ** 2))) if back.size else math.nan,
         'back_rms_ref': float(np.sqrt(np.mean(ref ** 2))) if ref.size else math.nan}
    lo, hi = MEAN_PASS
    f['present_ok'] = bool(lo <= f['present_mean_z2'] <= hi) if present.size else None
    f['gone_ok'] = bool(f['gone_within_2sigma'] >= GAP_FRACTION) if gone.size else None
    f['back_ok'] = (bool(f['back_rms'] <= max(RETURN_FACTOR * f['back_rms_ref'],
                                               f['back_rms_ref'] + RETURN_MARGIN))
                    if back.size else None)
    return f


# The field-gap benchmark's band for the heading's mean e²/σ² with the field
# present: wider than MEAN_RANGE, pooled over trials of every kind.
MEAN_PASS = (0.3, 3.0)


def field_gap(trials, groups, gap, workers=1, progress=None):
    """
    A field gone for a while in each trial (9D): the heading's error and σ before, during, after.

    Each trial runs through the node's pipeline twice, with every field and
    without those of ``gap``; a trial shorter than ``gap[0]`` loses no field
    and is left out of the gap's figures, one that ends before ``gap[1]``
    counts only while the field is gone. Rows: each trial, then pooled per
    split (tuning, held-out, all) over every trial and over those of
    :data:`MAGNET_GROUP`.

    Returns
    -------
    list of (str, dict)
        The row's name and :func:`gap_figures`'s.

    """
    if progress:
        progress(f'{len(trials)} trials × 9D with and without the field from {gap[0]:g} to '
                 f'{gap[1]:g} s, {workers} process{"es" if workers > 1 else ""} ...')
    full = run_all(trials, ('9D',), workers=workers, progress=progress)['9D']
    gapped = run_all(trials, ('9D',), values=None, workers=workers, progress=progress,
                     gap=gap)['9D']
    parts = {t.name: gap_trial(t, full[t.name], gapped[t.name], gap) for t in trials}
    magnet = set(groups['members'].get(MAGNET_GROUP, []))
    rows = [(t.name, gap_figures([parts[t.name]])) for t in trials]
    for split in (*SPLITS, 'all'):
        chosen = [t.name for t in trials if split in ('all', split_of(t.name))]
        if chosen:
            rows.append((f'{split}: every trial', gap_figures([parts[n] for n in chosen])))
        with_magnet = [n for n in chosen if n in magnet]
        if with_magnet:
            rows.append((f'{split}: {MAGNET_GROUP}',
                         gap_figures([parts[n] for n in with_magnet])))
    return rows


def gap_table(rows, gap):
    """:func:`field_gap`'s rows as a text table."""
    def verdict(ok):
        return '   -' if ok is None else (' yes' if ok else '  NO')

    lines = [f'heading, 9D: field present (mean e²/σ², {MEAN_PASS[0]:g}–{MEAN_PASS[1]:g}); '
             f'field gone {gap[0]:g}–{gap[1]:g} s (within 2σ, ≥ {100 * GAP_FRACTION:g} %); '
             f'the {RETURN_TIME:g} s after its return (RMS error, ≤ max({RETURN_FACTOR:g}×, '
             f'+{math.degrees(RETURN_MARGIN):g}°) that without a gap)',
             f'{"trial":40} {"present":>8} {"ok":>4} {"gone 2σ":>8} {"ok":>4} '
             f'{"back":>7} {"no gap":>7} {"ok":>4}']
    for name, f in rows:
        lines.append(f'{name:40} {f["present_mean_z2"]:8.2f} {verdict(f["present_ok"])} '
                     f'{100 * f["gone_within_2sigma"]:7.1f}% {verdict(f["gone_ok"])} '
                     f'{math.degrees(f["back_rms"]):6.2f}° '
                     f'{math.degrees(f["back_rms_ref"]):6.2f}° {verdict(f["back_ok"])}')
    return '\n'.join(lines)
