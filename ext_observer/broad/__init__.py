"""
The BROAD benchmark: ``python -m ext_observer broad [--data DIR]``.

Runs the raw-IMU estimator of :mod:`ext_observer.core.ahrs.ahrs_observer` on the recordings
of BROAD (D. Laidig, M. Caruso, A. Cereatti, T. Seel, "BROAD — A Benchmark
for Robust Inertial Orientation Estimation", Data 6(7):72, 2021,
doi:10.3390/data6070072, CC BY 4.0), scores it the way BROAD does, and runs
the anchors in the same command: VQF and BasicVQF (``vqf``), Madgwick and
Mahony (``ahrs``) and Fusion (``imufusion``). The anchors are for comparison
only; the estimator never calls them.

One module per step, each importing only the ones above it in this list:

- :mod:`~ext_observer.broad.result_keys`: the modes and algorithms, in table order;
- :mod:`~ext_observer.broad.data`: where the data is, the trials, the groups;
- :mod:`~ext_observer.broad.split`: the trials that chose the defaults and
  the held-out ones, one rule for every page;
- :mod:`~ext_observer.broad.scoring`: BROAD's error angles, RMSE, averages;
- :mod:`~ext_observer.broad.anchors`: the other filters, brought to ENU;
- :mod:`~ext_observer.broad.run`: ours and the anchors on the trials, scored;
- :mod:`~ext_observer.broad.report`: stdout and JSON;
- :mod:`~ext_observer.broad.stress`, :mod:`~ext_observer.broad.stress_run`:
  the robustness benchmark (``--stress``): the trials made harder, their
  run and tables;
- :mod:`~ext_observer.broad.cli`: the command (``--docs``: the pages and
  figures of a clone's docs/, written by ``docgen/``, not installed);
- :mod:`~ext_observer.broad.fetch` (standard library only, apart): BROAD from
  its repository into ``data/broad`` (``make broad-data``).

Conventions: quaternions scalar first ``(w, x, y, z)``, sensor → ENU (BROAD's
``opt_quat`` and the estimator alike). Angular rate rad/s, specific force
m/s², field µT (BROAD's units); angles in the report in degrees.

Nothing here imports ROS; h5py is needed only to read the HDF5 files
(requirements-test.txt) and the anchor packages only for the anchors
(requirements-test.txt, ``make test``). Every public name of the modules
is importable from here.
"""

from ext_observer.broad.anchors import (anchor_estimates, ANCHOR_PACKAGES,
                                        attitude_from_acc_mag, BROAD_GYRO_RANGE,
                                        FUSION_README, fusion_settings, IDENTITY,
                                        MADGWICK_BETA, MAHONY_KI, MAHONY_KP,
                                        missing_anchor_packages, NWU_TO_ENU,
                                        STANDARD_GRAVITY)
from ext_observer.broad.cli import build_parser, main, PLOT_TRIAL
from ext_observer.broad.data import (data_dir, DEFAULT_DIRS, ENV_VAR, find_groups,
                                     find_trials, groups_from_name, has_trials, HOW_TO_GET,
                                     load_trial, load_trials, shown_command, shown_path,
                                     Trial)
from ext_observer.broad.result_keys import (algorithms_in, ALGORITHMS, ANCHORS, FUSION_DEFAULTS,
                                            MODES, OFFLINE_VQF, OURS, OURS_PLAIN,
                                            OURS_SMOOTHED)
from ext_observer.broad.report import fmt, text_report, write_json
from ext_observer.broad.run import estimate_ours, log, run, smoothed_estimate
from ext_observer.broad.scoring import (combined_norms, criteria, error_angles, group_means,
                                        norm_deviation, norm_parts, rmse_deg, score, summary,
                                        VQF_RATIO_GOAL)
from ext_observer.broad.stress import (BIAS, bias_of, blocks, clip_gyro, cut_at_movement,
                                       DESCRIPTIONS, downsample, first_movement,
                                       GYRO_RANGE, LABELS, LOW_RATE, RATIO_DONE,
                                       RATIO_GOAL, variant, VARIANTS, variants, with_bias)
from ext_observer.broad.split import (held_out_trials, split_of, SPLITS, trial_number, TUNING,
                                      tuning_trials)
from ext_observer.broad.stress_run import (algorithms_of, half_counts, HALVES, MODE_KEYS,
                                           GYRO_RANGES, modes_of, ratio_to_vqf, run_stress,
                                           STRESS_ANCHORS, stress_summary, table_rows,
                                           text_table, write_stress_json)

__all__ = [
    'ALGORITHMS', 'ANCHOR_PACKAGES', 'ANCHORS', 'BROAD_GYRO_RANGE', 'DEFAULT_DIRS', 'ENV_VAR',
    'FUSION_DEFAULTS', 'FUSION_README', 'HOW_TO_GET', 'fusion_settings',
    'IDENTITY', 'MADGWICK_BETA', 'MAHONY_KI', 'MAHONY_KP', 'MODES', 'NWU_TO_ENU',
    'OFFLINE_VQF', 'OURS', 'OURS_PLAIN', 'OURS_SMOOTHED', 'PLOT_TRIAL',
    'STANDARD_GRAVITY', 'Trial', 'VQF_RATIO_GOAL',
    'algorithms_in', 'anchor_estimates', 'attitude_from_acc_mag', 'build_parser',
    'combined_norms', 'criteria', 'data_dir', 'error_angles', 'estimate_ours', 'find_groups',
    'find_trials',
    'fmt', 'group_means', 'groups_from_name', 'has_trials', 'load_trial', 'load_trials', 'log',
    'main',
    'missing_anchor_packages', 'norm_deviation', 'norm_parts', 'rmse_deg',
    'run',
    'score', 'smoothed_estimate', 'shown_command', 'shown_path', 'summary', 'text_report',
    'write_json',
    # The robustness benchmark (--stress).
    'BIAS', 'DESCRIPTIONS', 'GYRO_RANGE', 'GYRO_RANGES', 'HALVES', 'LABELS', 'LOW_RATE',
    'MODE_KEYS',
    'RATIO_DONE', 'RATIO_GOAL',
    'STRESS_ANCHORS', 'VARIANTS', 'algorithms_of', 'bias_of', 'blocks', 'clip_gyro',
    'cut_at_movement', 'downsample', 'first_movement', 'half_counts', 'modes_of',
    'ratio_to_vqf', 'run_stress', 'stress_summary',
    'table_rows', 'text_table', 'trial_number', 'variant', 'variants', 'with_bias',
    'write_stress_json',
    # The split of the trials.
    'SPLITS', 'TUNING', 'held_out_trials', 'split_of', 'tuning_trials',
]
