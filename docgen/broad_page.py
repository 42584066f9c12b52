"""
The page ``docs/broad.md``: one function per section, in the page's order.

:func:`markdown` joins the sections; each reads the run through a
:class:`_Page` (the scores, the groups, how the run was made, where the
figures are) and returns its Markdown lines, ending with a blank one.
"""

import math
import os

from ext_observer.broad.anchors import (BROAD_GYRO_RANGE, FUSION_README, MADGWICK_BETA,
                                        MAHONY_KI, MAHONY_KP)
from ext_observer.broad.data import DEFAULT_DIRS, ENV_VAR, shown_command, shown_path
from ext_observer.broad.result_keys import (algorithms_in, ANCHORS, FUSION_DEFAULTS, MODES, OURS,
                                      OURS_PLAIN)
from docgen.markdown import table as markdown_table
from ext_observer.broad.report import fmt
from ext_observer.broad.scoring import criteria, group_means, summary, VQF_RATIO_GOAL

# The estimator's source, linked from the opening sentence.
_AHRS = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))),
                     'ext_observer', 'core', 'ahrs', 'ahrs_observer.py')
BROAD_URL = 'https://github.com/dlaidig/broad'


class _Page:
    """What the sections read: the run, its groups, its metadata, the links."""

    def __init__(self, result, groups, meta, figures, docs_dir):
        self.result = result
        self.scores = result['scores']
        self.groups = groups
        self.meta = meta
        self.figures = figures
        self.docs_dir = docs_dir
        self.algorithms = algorithms_in(result)
        self.modes = [m for m in MODES if any(m in self.scores[a] for a in self.algorithms)]
        self.n_trials = len(meta['trials'])
        # The plain variant scores like ours (it differs in |q̂| only): in the
        # summary and the |q̂̄q̂ − 1| table, not in the detailed tables.
        self.detailed = [a for a in self.algorithms if a != OURS_PLAIN]

    def means(self, algorithm, mode, key):
        """``{group: mean}`` of one score of one algorithm in one mode."""
        per_trial = self.scores.get(algorithm, {}).get(mode)
        return group_means(per_trial, self.groups, key) if per_trial else {}

    def link(self, path):
        """The link to ``path`` from the page's folder."""
        return os.path.relpath(path, self.docs_dir).replace(os.sep, '/')


def shown_meta(meta):
    """The command and data folder of ``meta`` as a page shows them, no absolute path (older results too)."""
    data = meta.get('data')
    return (shown_command(meta['command'].split(' ')),
            None if data is None else (shown_path(data) if os.path.isabs(data) else data))


def fusion_text(gyro):
    """
    How Fusion runs, for the pages: its README's settings, then its package defaults.

    ``gyro`` says the gyro range it is given (Markdown), e.g. ``'2000 °/s'``.
    """
    s = FUSION_README
    return (f"Fusion (`imufusion`) at its README's settings: gain {s['gain']:g}, gyro range "
            f"{gyro}, acceleration rejection {s['acceleration_rejection']:g}°, magnetic "
            f"rejection {s['magnetic_rejection']:g}°, rejection timeout (recovery trigger "
            f"period) {s['rejection_timeout']:g} s, and its gyro offset correction (`Bias`, "
            f'package settings) before the AHRS; and as "{FUSION_DEFAULTS}", `AhrsSettings` '
            'with the rate only (no rejection, no gyro range, no offset correction)')


def _group_label(group, level):
    if level == 0:
        return 'all trials'
    label = group.replace('_', ' ')
    return f'↳ {label}' if level >= 2 else f'**{label}**'


def markdown(result, groups, meta, figures, docs_dir, tuning=None):
    """
    Return the page ``broad.md``.

    Parameters
    ----------
    result : dict
        From ``run``.
    groups : dict
        From ``find_groups``.
    meta : dict
        ``command``, ``commit``, ``machine``, ``params``, ... (see ``main``).
    figures : dict
        ``{key: path}`` of the PNG files.
    docs_dir : str
        The folder of the page (links are relative to it).
    tuning : str, optional
        Path of the page on the tuning (``broad_tuning.md``), linked under
        "How the defaults were chosen"; without it the section says that the
        tuning fills it.

    """
    page = _Page(result, groups, meta, figures, docs_dir)
    sections = (_intro(page), _method(page), _summary(page), _group_tables(page),
                _heading_and_inclination(page), _trial_figure(page), _norms(page),
                _run_time(page), _per_trial(page), _anchor_frames(), _defaults(page, tuning),
                _reproduce())
    return '\n'.join(line for section in sections for line in section)


def _intro(page):
    meta = page.meta
    command, data = shown_meta(meta)
    made_by = f'**Made by** `{command}`'
    if data:
        made_by += f' on the data in `{data}`'
    made_by += (f' at commit `{meta["commit"]}`'
                + (' (with uncommitted changes to the estimator or this benchmark)'
                   if meta.get('dirty') else '')
                + f', {meta["date"]}, on {meta["machine"]}.')
    lines = [
        '# Real data: the BROAD benchmark',
        '',
        'This page measures the raw-IMU estimator of ext_observer (gyro + accelerometer, '
        f'+ magnetometer in 9D; [`{os.path.basename(_AHRS)}`]({page.link(_AHRS)})) '
        'on real recordings with optical ground truth, against VQF, BasicVQF, offline VQF, '
        "Madgwick, Mahony and Fusion (at its README's settings, and at its package defaults) "
        'run in the same command, each at the settings its authors advise, so that its '
        'accuracy can be judged '
        'against the best open estimators. It is generated; do not edit it '
        'by hand.',
        '',
        '**Data.** BROAD (Laidig et al. 2021): D. Laidig, M. Caruso, A. Cereatti, T. Seel, '
        '"BROAD — A Benchmark for Robust Inertial Orientation Estimation", *Data* 6(7):72, '
        '2021, [doi:10.3390/data6070072](https://doi.org/10.3390/data6070072), licensed '
        '[CC BY 4.0](https://creativecommons.org/licenses/by/4.0/). '
        f'{page.n_trials} of its 39 trials are used here (groups from '
        f'{meta["groups_source"]}).',
        '',
        f'**Getting it.** `make broad-data` fetches BROAD from [its repository]({BROAD_URL}) '
        '(a shallow git clone of its HDF5 files and `trials.json` only) into `data/broad/`, '
        'which git ignores, and writes the licence and this credit beside the files '
        '(`data/broad/CREDIT.md`). Without `--data DIR`, the command reads the folder '
        f'`${ENV_VAR}` names, else `{DEFAULT_DIRS[0]}`, else `{DEFAULT_DIRS[1]}` (both '
        'beside the repository); when none holds the files it stops with one line '
        'naming `make broad-data`.',
        '',
        made_by,
        '',
    ]
    if meta.get('head'):
        lines += [f'**Quick check only:** each trial cut to its first {meta["head"]:g} s '
                  '(`--head`); these are not BROAD figures.', '']
    return lines


def _method(page):
    meta = page.meta
    return [
        '**Our estimator** runs with its shipped defaults, one parameter set for all '
        'trials (`AhrsParams()`: '
        + ', '.join(f'{k} = {v:g}' for k, v in meta['params'].items()) + '), '
        'all trials and both modes in one batched call. '
        '**Anchors**, from PyPI, each at the settings its authors advise: VQF and '
        "BasicVQF (`vqf`, causal `updateBatch`) at their defaults, the authors' "
        f'recommendation; Madgwick (`ahrs`, β = {MADGWICK_BETA}) and Mahony (`ahrs`, '
        f"Kp = {MAHONY_KP}, Ki = {MAHONY_KI}) at BROAD's trial-agnostic best, started "
        "from the first sample's gravity and field (gravity alone in 6D) as BROAD's "
        'example does; ' + fusion_text(
            f"{math.degrees(BROAD_GYRO_RANGE):.0f} °/s (BROAD's sensor, a myon aktos-t: its "
            'files do not state its range; the recordings reach 1352 °/s, beyond a 1000 °/s '
            'range)') + '. '
        'Versions: ' + ', '.join(f'{k} {v}' for k, v in meta['versions'].items()) + '.',
        '',
        '**Scoring**, as BROAD does: both quaternions normalized, e = q̂ ⊗ q_ref⁻¹ '
        '(error in the world frame), total angle 2·acos(|e_w|), heading 2·atan(|e_z/e_w|), '
        'inclination 2·acos(√(e_w² + e_z²)); the RMSE over the `movement` samples, NaN '
        'reference samples skipped, in degrees; trials averaged per group. In 6D the '
        'heading is free, so only the inclination counts.',
        '',
    ]


def _with_ratio(value, reference):
    """``value`` and, when there is a reference, ``(value / reference ×)``."""
    ratio = f' ({value / reference:.2f}×)' if value is not None and reference else ''
    return fmt(value) + ratio


def _summary(page):
    """The averages the done-criteria read, their ratio to VQF, the criteria."""
    have9, have6 = '9D' in page.modes, '6D' in page.modes
    columns = []  # (mode, key, group, header)
    if have9:
        columns += [('9D', 'total_rmse_deg', g, f'9D total, {label}') for g, label in
                    (('undisturbed', 'undisturbed'), ('disturbed', 'disturbed'),
                     ('all_trials', 'all'))]
    if have6:
        columns.append(('6D', 'inclination_rmse_deg', 'all_trials', '6D inclination, all'))
    rows = []
    for algorithm in page.algorithms:
        row = [f'**{algorithm}**' if algorithm == OURS else algorithm]
        for mode, key, group, _ in columns:
            row.append(_with_ratio(page.means(algorithm, mode, key).get(group),
                                   page.means('VQF', mode, key).get(group)))
        rows.append(row)
    lines = ['## Summary', '',
             'Mean RMSE over the trials of each group, in degrees; in parentheses the '
             'ratio to VQF. The done-criteria: ours below BasicVQF, Madgwick, Mahony '
             'and Fusion on the undisturbed and on the disturbed 9D averages, at most '
             '1.1× VQF (goal), and at most 1.1× VQF in 6D inclination.', '']
    lines += [markdown_table(['algorithm'] + [c[3] for c in columns], rows, numeric=True)] + ['']
    lines += _criteria_lines(criteria(summary(page.result, page.groups)))
    if 'groups' in page.figures:
        lines += [f'![Mean RMSE per group and algorithm]({page.link(page.figures["groups"])})',
                  '']
    return lines


def _criteria_lines(found):
    """The done-criteria as a list, after 'At this run:'."""
    lines = []
    for c in found:
        met = 'met' if c['met'] else 'not met'
        if c['mode'] == '9D':
            text = f'- 9D, {c["group"]} average: {c["value"]:.2f}°; below ' + (
                ', '.join(c['beaten']) if c['beaten'] else 'none of the others')
            if c['others']:
                text += (': **all four**' if len(c['beaten']) == len(c['others']) == 4 else
                         f' ({len(c["beaten"])} of {len(c["others"])})')
            if c['ratio'] is not None:
                text += (f'; {c["ratio"]:.2f}× VQF (goal ≤ {VQF_RATIO_GOAL}×: {met}'
                         + ('; below VQF' if c['ratio'] < 1.0 else '') + ')')
        else:
            text = f'- 6D, inclination over all trials: {c["value"]:.2f}°'
            if c['ratio'] is not None:
                text += (f'; {c["ratio"]:.2f}× VQF ({c["vqf"]:.2f}°; criterion ≤ '
                         f'{VQF_RATIO_GOAL}×: {met})')
        lines.append(text + '.')
    return (['At this run:', ''] + lines + ['']) if lines else []


def _group_tables(page):
    """One table per mode: each group's mean, each algorithm a column."""
    lines = []
    for mode, key, title in (('9D', 'total_rmse_deg', '9D: total RMSE by group'),
                             ('6D', 'inclination_rmse_deg', '6D: inclination RMSE by group')):
        if mode not in page.modes:
            continue
        lines += [f'## {title}', '',
                  'Mean over the trials of each group, degrees; (n) is the number of '
                  'trials.', '']
        table = {a: page.means(a, mode, key) for a in page.detailed}
        rows = []
        for group, level in page.groups['order']:
            n = len([t for t in page.groups['members'][group] if t in page.meta['trials']])
            rows.append([f'{_group_label(group, level)} ({n})']
                        + [fmt(table[a].get(group)) for a in page.detailed])
        lines += [markdown_table(['group (n)'] + page.detailed, rows, numeric=True)] + ['']
    return lines


def _heading_and_inclination(page):
    if '9D' not in page.modes:
        return []
    rows = []
    for group, level in page.groups['order']:
        if level > 1:
            continue
        row = [_group_label(group, level)]
        for a in page.detailed:
            h = page.means(a, '9D', 'heading_rmse_deg').get(group)
            i = page.means(a, '9D', 'inclination_rmse_deg').get(group)
            row.append(f'{fmt(h)} / {fmt(i)}')
        rows.append(row)
    return (['## 9D: heading and inclination', '',
             'The two parts of the 9D error, mean over the trials of each group '
             '(degrees): heading / inclination.', '']
            + [markdown_table(['group'] + page.detailed, rows, numeric=True)] + [''])


def _trial_figure(page):
    if 'trial' not in page.figures:
        return []
    trial = page.meta['plot_trial']
    return ['## Error over time on a magnetically disturbed trial', '',
            f'`{trial}`: a magnet near the path bends the field; the '
            'shaded spans are not scored (rest at the start and end). Heading and '
            'inclination error of the 9D estimates (the inclination panel also shows '
            'ours in 6D).', '',
            f'![Error over time on {trial}]({page.link(page.figures["trial"])})', '']


def _norms(page):
    norms = page.result['norms']
    if not norms:
        return []
    rows = []
    for variant in ('extended', 'plain'):
        for mode in list(page.modes) + ['all']:
            if mode in norms.get(variant, {}):
                n = norms[variant][mode]
                rows.append([variant, mode, f'{n["mean"]:.3g}', f'{n["max"]:.3g}',
                             str(n['samples'])])
    lines = ['## The extension on real data: |q̂̄q̂ − 1|', '',
             'Our estimate lives in R⁴ and nothing on its path renormalizes it; the '
             'extension term −α∇V holds it near S³. Over every sample of every trial '
             '(not only the scored ones), the raw output of `estimate_batch`:', '']
    lines += [markdown_table(['variant', 'mode', 'mean', 'max', 'samples'], rows, numeric=True)] + ['']
    if 'plain' not in norms:
        lines += ['(Run with `--plain` to add the variant without the extension term.)', '']
    return lines


def _run_time(page):
    meta = page.meta
    secs = page.result['seconds']
    load = meta.get('load') or (None, None)
    rows = []
    if OURS in secs:
        workers = meta.get('workers') or 1
        rows.append([OURS, f'{secs[OURS]:.1f} s',
                     f'{page.n_trials} trials × {len(page.modes)} modes, one batched call '
                     '(each estimate scored where it is made)'
                     + (f' ({workers} processes, each recording on floats)' if workers > 1
                        else ' (one process)')])
    if OURS_PLAIN in secs:
        rows.append([OURS_PLAIN, f'{secs[OURS_PLAIN]:.1f} s', 'the same, no extension term'])
    for anchor in ANCHORS:
        if anchor in secs:
            rows.append([anchor, f'{secs[anchor]:.1f} s',
                         'compiled' if anchor in ('VQF', 'BasicVQF', 'Fusion', FUSION_DEFAULTS)
                         else 'pure Python (`ahrs`), one call per sample'])
    if 'anchors_wall' in secs:
        jobs = meta.get('jobs') or 1
        rows.append(['all anchors', f'{secs["anchors_wall"]:.1f} s',
                     f'wall clock, {jobs} process{"es" if jobs > 1 else ""}; the anchor rows '
                     'above add up the time of each run in its process'])
    return (['## Run time', '',
             f'Wall clock on {meta["machine"]}'
             + (f' (1-minute load average {load[0]} at the start, {load[1]} at the end: '
                'the machine is shared)' if load[0] is not None else '') + ':', '']
            + [markdown_table(['algorithm', 'time', 'note'], rows)] + [''])


def _per_trial(page):
    header = ['trial']
    cols = []
    for mode, key, short in (('9D', 'total_rmse_deg', '9D'),
                             ('6D', 'inclination_rmse_deg', '6D incl.')):
        if mode in page.modes:
            for a in page.detailed:
                if mode in page.scores[a]:
                    header.append(f'{a} {short}')
                    cols.append((a, mode, key))
    rows = [[name] + [fmt(page.scores[a][m].get(name, {}).get(k)) for a, m, k in cols]
            for name in page.meta['trials']]
    return (['## Per trial', '',
             '9D total RMSE and 6D inclination RMSE of each trial (degrees).', '',
             '<details><summary>Table per trial</summary>', '']
            + [markdown_table(header, rows, numeric=True)] + ['', '</details>', ''])


def _anchor_frames():
    return ['## How the anchors are run', '',
            'Each anchor gets the raw samples (rad/s, m/s², µT; Fusion °/s and g) and '
            'its output is brought to scalar-first, sensor → ENU by a fixed left factor. '
            'Each factor was checked on the data, not assumed: every candidate (identity, '
            'NWU→ENU, NED→ENU; also the conjugate and the scalar-last reading) was '
            'scored on a trial and the chosen one is the only one with a small '
            'inclination and, in 9D, a small total error; '
            '`test_anchors.py::test_anchor_frames_on_a_static_sensor` keeps it so.', ''] + [markdown_table(
        ['anchor', 'output', 'to ENU'], [
            ['VQF, BasicVQF', 'sensor → ENU', 'identity'],
            ['Madgwick (`ahrs`)', 'sensor → NWU', 'R_z(+90°) ⊗ q'],
            ['Mahony (`ahrs`)', 'sensor → ENU', 'identity'],
            ['Fusion (`imufusion`), both rows', 'sensor → NWU (default convention)',
             'R_z(+90°) ⊗ q'],
        ])] + ['']


def _defaults(page, tuning):
    lines = ['## How the defaults were chosen', '']
    if tuning:
        return lines + ['The defaults were chosen on part of these trials and checked on the '
                        'others (held out); the split, every setting tried and the figures of '
                        f'both halves: [{os.path.basename(tuning)}]({page.link(tuning)}).', '']
    return lines + ['*Filled by the tuning: when `docs/broad_tuning.md` exists, a link to it '
                    'is placed here by the page generator.*', '']


def _reproduce():
    return ['## Reproduce', '',
            '```shell', 'make broad-data   # once: BROAD into data/broad/', 'make broad', '```',
            '',
            'runs `python -m ext_observer broad --mode both --plain --json out/broad.json '
            '--docs docs` on the data folder found as above (`BROAD_DATA=DIR` passes '
            '`--data DIR`: BROAD\'s HDF5 files directly in DIR or under `DIR/data_hdf5/`, '
            'as in a clone of BROAD). `make bench` does not run it; `make test` scores our '
            'estimator on two whole trials against the figures of this page '
            '(`test_broad_whole_trials.py`). Options: `--mode 6D|9D|both`, '
            '`--no-anchors`, `--plain` (also without the extension term), '
            '`--trials NAME...`, `--jobs N` (processes for the anchors) and `--workers N` '
            '(for our batched call; 1: one process), both by default the '
            'CPUs; `make broad BROAD_ARGS="--jobs 1"` passes them on.', '',
            'How the estimator does on harder variants of these trials (a start in motion, '
            'a gyro bias, 50 Hz, a clipped gyro): [robustness.md](robustness.md), by '
            '`make broad BROAD_ARGS="--stress --json out/robustness.json"`.', '']
