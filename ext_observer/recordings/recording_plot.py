"""
The picture of a recording: ``--plot FILE.png`` of the bag and csv commands.

Panels, sharing the time axis (s from the first sample): roll, pitch and
yaw (deg; :func:`~ext_observer.recordings.recording.roll_pitch_yaw`), the flags (rest,
magnetic disturbance, samples without an estimate of their own, the
magnetometer calibration still learning where the core has one), and, with
a comparison (:func:`ext_observer.recordings.bag.compare`), BROAD's error angles
against the reference. PNG, matplotlib's Agg backend.
"""

import numpy as np

__all__ = ['MAX_POINTS', 'plot_recording']

# Points per line: more are not seen at the figure's width.
MAX_POINTS = 20000


def _broken(angles_deg):
    """An angle in (−180, 180] with NaN at its wraps, so no line crosses the panel."""
    out = angles_deg.astype(float).copy()
    jumps = np.flatnonzero(np.abs(np.diff(out)) > 180.0)
    return np.insert(out, jumps + 1, np.nan), jumps


def plot_recording(recording, path, title='', comparison=None):
    """
    Write the picture of a :class:`~ext_observer.recordings.recording.Recording` as a PNG.

    Parameters
    ----------
    recording : ext_observer.recordings.recording.Recording
    path : str
    title : str
        What was run (shown above the panels with the counts).
    comparison : dict, optional
        :func:`ext_observer.recordings.bag.compare`'s result, with ``topic``.

    """
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    t0 = recording.times[0]
    times = recording.times - t0
    step = max(1, len(times) // MAX_POINTS)
    panels = 3 if comparison is not None else 2
    fig, axes = plt.subplots(panels, 1, figsize=(11, 2.4 + 2.3 * panels), sharex=True,
                             gridspec_kw={'height_ratios': [3, 1.2, 2][:panels]})
    angles = np.degrees(recording.roll_pitch_yaw()[::step])
    shown = times[::step]
    for j, name in enumerate(('roll', 'pitch', 'yaw')):
        values, jumps = _broken(angles[:, j])
        axes[0].plot(np.insert(shown, jumps + 1, np.nan), values, lw=0.9, label=name)
    axes[0].set_ylabel('angle (°)')
    axes[0].set_ylim(-185, 185)
    axes[0].set_yticks(range(-180, 181, 90))
    axes[0].legend(loc='upper right', ncol=3, fontsize=8)
    axes[0].set_title(f'{recording.world_frame.upper()} roll, pitch, yaw '
                      '(R = Rz(yaw) Ry(pitch) Rx(roll))', fontsize=9)

    flags = axes[1]
    rows = (('rest', recording.rest, 'C2'), ('mag disturbed', recording.mag_disturbed, 'C3'),
            ('no estimate', ~recording.estimated, 'C7'))
    if recording.calibration is not None:
        rows += (('mag calibrating', recording.calibration == 'learning', 'C4'),)
    for i, (name, flag, color) in enumerate(rows):
        flags.fill_between(times, i + 0.1, i + 0.9, where=flag, step='post', color=color,
                           lw=0, label=name)
    flags.set_yticks([i + 0.5 for i in range(len(rows))])
    flags.set_yticklabels([name for name, _, _ in rows], fontsize=8)
    flags.set_ylim(0, len(rows))
    flags.set_title(f'flags: rest {recording.rest.mean():.0%} of the samples, magnetic '
                    f'disturbance {recording.mag_disturbed.mean():.0%}, dropped: '
                    f'{recording.dropped_text()}', fontsize=9)

    if comparison is not None:
        errors = axes[2]
        e_times = comparison['times'] - t0
        e_step = max(1, len(e_times) // MAX_POINTS)
        for key, color in (('total', 'k'), ('inclination', 'C0'), ('heading', 'C1')):
            errors.plot(e_times[::e_step], comparison[key][::e_step], lw=0.8, color=color,
                        label=f'{key}: RMSE {comparison[f"{key}_rmse_deg"]:.2f}°')
        errors.set_ylabel('error (°)')
        errors.set_ylim(bottom=0)
        errors.legend(loc='upper right', ncol=3, fontsize=8)
        errors.set_title(f'against {comparison.get("topic", "the reference")}, '
                         f'{comparison["matched"]} samples matched by stamp', fontsize=9)
    axes[-1].set_xlabel('time (s)')
    for ax in axes:
        ax.grid(alpha=0.3)
    counts = recording.counts
    fig.suptitle(f'{title}\n{counts["imu_samples"]} IMU samples, {counts["estimates"]} '
                 f'estimates, {counts["fields_used"]} fields used', fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path
