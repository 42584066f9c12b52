"""
Make the BROAD excerpts of test/data/ from the dataset's HDF5 files.

Usage (from the repository root, with h5py; it is not a test dependency)::

    python test/data/make_excerpt.py /work/shared/broad/data_hdf5

For each trial of :data:`TRIALS`, the samples from ``BEFORE`` s before the
first ``movement`` sample to ``LENGTH`` s after that point are kept (the
rest at the start lets the estimator initialize and learn its references),
as ``broad_<trial>.npz``: ``gyr`` (rad/s), ``acc`` (m/s²), ``mag`` (µT),
all float64 as in the dataset, ``opt_quat`` (w, x, y, z, sensor → ENU; NaN
where the cameras lost the body; float32, enough for a reference scored in
degrees), ``movement`` (bool), ``rate`` (Hz), ``first`` (index of the first
kept sample in the trial) and ``trial`` (the name). ``README.md`` in this
folder says what was cut and credits the dataset.
"""

import argparse
import os

import h5py
import numpy as np

TRIALS = ('01_undisturbed_slow_rotation_A', '28_disturbed_stationary_magnet_A')
BEFORE = 10.0  # s of the rest before the movement
LENGTH = 60.0  # s in all
HERE = os.path.dirname(os.path.abspath(__file__))


def excerpt(path):
    """Return the excerpt of one trial as a dict of arrays."""
    with h5py.File(path, 'r') as trial:
        rate = float(trial.attrs['sampling_rate'])
        movement = np.asarray(trial['movement']).ravel().astype(bool)
        first = max(0, int(np.argmax(movement)) - round(BEFORE * rate))
        end = min(len(movement), first + round(LENGTH * rate))
        cut = slice(first, end)
        return dict(gyr=np.asarray(trial['imu_gyr'][cut], dtype=np.float64),
                    acc=np.asarray(trial['imu_acc'][cut], dtype=np.float64),
                    mag=np.asarray(trial['imu_mag'][cut], dtype=np.float64),
                    opt_quat=np.asarray(trial['opt_quat'][cut], dtype=np.float32),
                    movement=movement[cut], rate=np.float64(rate),
                    first=np.int64(first),
                    trial=np.str_(os.path.splitext(os.path.basename(path))[0]))


def main(argv=None):
    """Write the excerpts; return the exit code."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    parser.add_argument('data', help="BROAD's data_hdf5 folder")
    parser.add_argument('--out', default=HERE, help='where to write (default: this folder)')
    args = parser.parse_args(argv)
    for name in TRIALS:
        arrays = excerpt(os.path.join(args.data, f'{name}.hdf5'))
        out = os.path.join(args.out, f'broad_{name}.npz')
        np.savez_compressed(out, **arrays)
        seconds = len(arrays['gyr']) / arrays['rate']
        print(f'{out}: samples {arrays["first"]} to {arrays["first"] + len(arrays["gyr"])} '
              f'({seconds:.1f} s), {os.path.getsize(out) / 1024:.0f} KiB')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
