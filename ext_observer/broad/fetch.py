"""
BROAD from its repository into a folder: ``make broad-data``.

``python3 ext_observer/broad/fetch.py [DEST] [--url URL]`` (DEST:
``data/broad`` beside this source tree, where the benchmark looks).

A shallow, sparse, blob-less git clone of https://github.com/dlaidig/broad:
its top-level files (README, licence) and ``data_hdf5/`` (the recordings),
not the MATLAB copies nor the videos. ``trials.json`` (the groups, kept in
``data_mat/`` upstream) is copied to DEST's top, where the benchmark looks
first; ``CREDIT.md`` is written beside it (the citation, the licence, CC BY
4.0, the source and its commit), and the clone's ``.git`` removed: DEST
holds plain files. The clone is made in ``DEST.partial`` and renamed to
DEST once complete, so an interrupted fetch leaves no half folder for the
commands to read. A DEST that already holds HDF5 files is left as it is.

Standard library and git only, so that it runs before anything is installed.
"""

import argparse
import glob
import os
import shutil
import subprocess
import sys

URL = 'https://github.com/dlaidig/broad.git'
TREE = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
DEST = os.path.join(TREE, 'data', 'broad')
# Where trials.json may be in the clone, in the order they are tried.
TRIALS_JSON = ('trials.json', 'data_hdf5/trials.json', 'data_mat/trials.json')

CREDIT = """\
# BROAD, fetched by `make broad-data`

Berlin Robust Orientation Estimation Assessment Dataset: D. Laidig, M. Caruso,
A. Cereatti, T. Seel, "BROAD — A Benchmark for Robust Inertial Orientation
Estimation", Data 6(7):72, 2021, doi:10.3390/data6070072.

Licence: Creative Commons Attribution 4.0 International (CC BY 4.0),
https://creativecommons.org/licenses/by/4.0/ — give this credit wherever the
data, or an excerpt of it, is used or shipped.

Source: {url}
Commit: {commit}

Fetched: `data_hdf5/` and the top-level files of that commit; `trials.json`
from `{trials}`. Left out: the MATLAB copies (`data_mat/`), the example
code and the videos.
"""


def _has_hdf5(folder):
    return bool(glob.glob(os.path.join(folder, 'data_hdf5', '*.hdf5'))
                or glob.glob(os.path.join(folder, '*.hdf5')))


def _git(*args):
    """Run git; return its stdout; raise RuntimeError with git's message."""
    done = subprocess.run(['git', *args], capture_output=True, text=True)
    if done.returncode != 0:
        raise RuntimeError(f'git {" ".join(args)} failed: {done.stderr.strip()}')
    return done.stdout


def fetch(dest=DEST, url=URL):
    """
    Fetch BROAD into ``dest``; return ``dest``.

    Raises
    ------
    RuntimeError
        git is missing, or a git step failed (its message included), or
        the clone holds no HDF5 files.

    """
    if _has_hdf5(dest):
        print(f'{dest} already holds BROAD; nothing to do (remove it to fetch again)')
        return dest
    if shutil.which('git') is None:
        raise RuntimeError('make broad-data needs git (apt-get install git)')
    partial = dest + '.partial'
    shutil.rmtree(partial, ignore_errors=True)
    os.makedirs(os.path.dirname(os.path.abspath(dest)), exist_ok=True)
    print(f'fetching BROAD from {url} into {dest} ...', flush=True)
    # --sparse checks out the top-level files only; the cone then adds
    # data_hdf5/; blob:none fetches the contents of those files only.
    _git('clone', '--depth', '1', '--filter=blob:none', '--sparse', url, partial)
    _git('-C', partial, 'sparse-checkout', 'set', 'data_hdf5')
    if not _has_hdf5(partial):
        raise RuntimeError(f'{url}: no HDF5 files under data_hdf5/ (left in {partial})')
    trials = _copy_trials_json(partial)
    commit = _git('-C', partial, 'rev-parse', 'HEAD').strip()
    # The files are what the benchmark reads; their history would double
    # the space, and CREDIT.md names the commit.
    shutil.rmtree(os.path.join(partial, '.git'))
    with open(os.path.join(partial, 'CREDIT.md'), 'w', encoding='utf-8') as f:
        f.write(CREDIT.format(url=url, commit=commit, trials=trials or 'nowhere (not found)'))
    os.rename(partial, dest)
    count = len(glob.glob(os.path.join(dest, 'data_hdf5', '*.hdf5')))
    print(f'{dest}: {count} trials of BROAD (CC BY 4.0, credit in {dest}/CREDIT.md)')
    return dest


def _copy_trials_json(clone):
    """Write the first ``trials.json`` of the commit to the clone's top; return its path."""
    for path in TRIALS_JSON:
        # git show fetches the one blob on demand (the clone has no others).
        done = subprocess.run(['git', '-C', clone, 'show', f'HEAD:{path}'],
                              capture_output=True)
        if done.returncode == 0:
            if path != 'trials.json':
                with open(os.path.join(clone, 'trials.json'), 'wb') as f:
                    f.write(done.stdout)
            return path
    return None


def main(argv=None):
    """Run the fetch; return the exit code."""
    parser = argparse.ArgumentParser(
        prog='make broad-data',
        description='Fetch BROAD (Laidig et al. 2021, CC BY 4.0) for the benchmark.')
    parser.add_argument('dest', nargs='?', default=DEST,
                        help=f'the folder to create (default: {DEST})')
    parser.add_argument('--url', default=URL, help=f'the repository (default: {URL})')
    args = parser.parse_args(argv)
    try:
        fetch(args.dest, args.url)
    except (RuntimeError, OSError) as error:
        print(f'error: {error}', file=sys.stderr)
        return 1
    return 0


if __name__ == '__main__':
    sys.exit(main())
