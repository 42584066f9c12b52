"""
What a run prints and saves: the short report on stdout and the JSON files.

``--json OUT`` writes ``{algorithm: {mode: {trial: RMSEs}}}`` to OUT and the
rest (the summary, the norms, the times, the groups, how the run was made)
to ``OUT_details.json``. The page with tables and figures is
:mod:`docgen.broad_page`.
"""

import json
import math
import os

from ext_observer.broad.result_keys import MODES
from ext_observer.broad.scoring import summary


def fmt(value, digits=2):
    """Return ``value`` with ``digits`` decimals, or '–' for None and NaN."""
    return '–' if value is None or not math.isfinite(value) else f'{value:.{digits}f}'


def text_report(result, groups, meta):
    """Return the short report printed on stdout."""
    lines = [f'BROAD: {len(meta["trials"])} trials, commit {meta["commit"]}'
             + (' (estimator modified)' if meta['dirty'] else '')]
    for algorithm, per_mode in summary(result, groups).items():
        parts = []
        for mode in MODES:
            m = per_mode.get(mode)
            if not m:
                continue
            if mode == '9D':
                parts.append('9D total ' + ' / '.join(
                    f'{g[:5]} {fmt(m[g]["total_rmse_deg"])}' for g in
                    ('undisturbed', 'disturbed', 'all_trials') if g in m))
            else:
                parts.append('6D incl all '
                             + fmt(m.get('all_trials', {}).get('inclination_rmse_deg')))
        lines.append(f'  {algorithm:20s} ' + '; '.join(parts))
    for variant, norms in result['norms'].items():
        lines.append(f'  |q̂̄q̂ − 1| {variant}: ' + '; '.join(
            f'{mode} mean {n["mean"]:.3g} max {n["max"]:.3g}' for mode, n in norms.items()))
    secs = result['seconds']
    lines.append('  time: ' + ', '.join(f'{k} {v:.1f} s' for k, v in secs.items()))
    return '\n'.join(lines)


def _finite(value):
    """Replace NaN and infinities by None (strict JSON)."""
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_finite(v) for v in value]
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def _dump(path, value):
    with open(path, 'w', encoding='utf-8') as f:
        json.dump(_finite(value), f, indent=1)
        f.write('\n')


def write_json(path, result, groups, meta):
    """Write the scores to ``path`` and the rest to ``<stem>_details<ext>``."""
    folder = os.path.dirname(path)
    if folder:
        os.makedirs(folder, exist_ok=True)
    _dump(path, result['scores'])
    stem, ext = os.path.splitext(path)
    _dump(f'{stem}_details{ext or ".json"}', {
        'summary': summary(result, groups),
        'norms': result['norms'],
        'seconds': result['seconds'],
        'groups': {'order': groups['order'], 'members': groups['members']},
        'meta': {k: v for k, v in meta.items() if k != 'plot_movement'},
    })
