"""
The figures of the page: the group means, and the error over time on one trial.

Both are written as PNG files (``broad_groups.png``,
``broad_disturbed_trial.png``) with matplotlib's Agg backend; ours is drawn
in black, the anchors in matplotlib's colour cycle.
"""

import os

import numpy as np

from ext_observer.broad.result_keys import algorithms_in, MODES, OURS, OURS_PLAIN
from ext_observer.broad.scoring import group_means


def plot(result, groups, meta, out_dir):
    """Write the figures as PNG files in ``out_dir``; return ``{key: path}``."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    os.makedirs(out_dir, exist_ok=True)
    # The plain variant scores like ours (it differs in |q̂| only): tables only.
    algorithms = [a for a in algorithms_in(result) if a != OURS_PLAIN]
    colors = {a: f'C{i}' for i, a in enumerate(a for a in algorithms if a != OURS)}
    colors[OURS] = 'k'
    figures = {'groups': os.path.join(out_dir, 'broad_groups.png')}
    _plot_groups(plt, result['scores'], groups, algorithms, colors, figures['groups'])
    if result['series'] and meta.get('plot_trial'):
        figures['trial'] = os.path.join(out_dir, 'broad_disturbed_trial.png')
        _plot_trial(plt, result['series'], meta, algorithms, colors, figures['trial'])
    return figures


def _plot_groups(plt, scores, groups, algorithms, colors, path):
    """Bars: the mean RMSE of each group, 9D total and 6D inclination."""
    modes = [m for m in MODES if any(m in scores[a] for a in algorithms)]
    panels = [(m, k, t) for m, k, t in (('9D', 'total_rmse_deg', '9D total RMSE'),
                                        ('6D', 'inclination_rmse_deg', '6D inclination RMSE'))
              if m in modes]
    shown = list(groups['order'])
    fig, axes = plt.subplots(len(panels), 1, figsize=(11, 3.6 * len(panels)), squeeze=False)
    width = 0.8 / max(len(algorithms), 1)
    x = np.arange(len(shown))
    for ax, (mode, key, title) in zip(axes[:, 0], panels):
        for i, a in enumerate(algorithms):
            per_trial = scores[a].get(mode)
            if not per_trial:
                continue
            m = group_means(per_trial, groups, key)
            ax.bar(x + (i - (len(algorithms) - 1) / 2) * width,
                   [m.get(g, np.nan) for g, _ in shown], width, label=a, color=colors[a])
        ax.set_xticks(x)
        ax.set_xticklabels([g.replace('_', ' ') for g, _ in shown], rotation=30, ha='right',
                           fontsize=8)
        ax.set_ylabel('mean RMSE (°)')
        ax.set_title(f'{title} per group')
        ax.grid(axis='y', alpha=0.3)
    axes[0, 0].legend(ncol=len(algorithms), fontsize=8, loc='upper left')
    fig.subplots_adjust(left=0.07, right=0.99, top=0.95, bottom=0.14, hspace=0.75)
    fig.savefig(path, dpi=100)
    plt.close(fig)


def _plot_trial(plt, series, meta, algorithms, colors, path):
    """Lines: heading and inclination error over time on ``meta['plot_trial']``."""
    rate = meta['rate']
    fig, axes = plt.subplots(2, 1, figsize=(11, 6), sharex=True)
    step = max(1, int(rate // 20))  # 20 points per second are enough to see
    for a in algorithms:
        s9 = series.get(a, {}).get('9D')
        if s9 is not None:
            ours = a == OURS
            style = dict(color=colors[a], lw=1.4 if ours else 0.8, zorder=3 if ours else 2,
                         alpha=1.0 if ours else 0.85, label=a)
            t = np.arange(len(s9[0]))[::step] / rate
            axes[0].plot(t, np.degrees(s9[1][::step]), **style)
            axes[1].plot(t, np.degrees(s9[2][::step]), **style)
    s6 = series.get(OURS, {}).get('6D')
    if s6 is not None:
        t = np.arange(len(s6[0]))[::step] / rate
        axes[1].plot(t, np.degrees(s6[2][::step]), color='0.45', lw=1.0, ls='--', zorder=3,
                     label=f'{OURS} 6D')
    # Shade the rest phases: they are not scored.
    still = ~np.asarray(meta['plot_movement'], dtype=bool)
    edges = np.flatnonzero(np.diff(np.r_[0, still.astype(int), 0]))
    for ax in axes:
        for start, stop in zip(edges[::2], edges[1::2]):
            ax.axvspan(start / rate, stop / rate, color='0.9', zorder=0)
        ax.grid(alpha=0.3)
    axes[0].set_ylabel('9D heading error (°)')
    axes[1].set_ylabel('inclination error (°)')
    axes[1].set_xlabel('time (s)')
    axes[0].set_title(meta['plot_trial'])
    for ax, ncol in zip(axes, (6, 7)):
        if ax.get_legend_handles_labels()[0]:  # 6D alone draws no heading
            ax.legend(ncol=ncol, fontsize=8, loc='upper left')
    fig.subplots_adjust(left=0.07, right=0.99, top=0.94, bottom=0.09, hspace=0.12)
    fig.savefig(path, dpi=100)
    plt.close(fig)
