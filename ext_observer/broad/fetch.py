"""
BROAD from its repository into a folder: ``make broad-data``.

``python3 ext_observer/broad/fetch.py [DEST] [--url URL] [--trials NAME ...]``
(DEST: ``data/broad`` beside this source tree, where the benchmark looks;
URL: ``$EXT_OBSERVER_BROAD_URL``, else BROAD's repository on GitHub).

A shallow, sparse, blob-less git clone of the repository: its top-level
files (README, licence) and ``data_hdf5/`` (the recordings), or only the
named trials of it (``make test`` fetches the few its tests read), never the
MATLAB copies nor the videos. ``trials.json`` (the groups, kept in
``data_mat/`` upstream) is copied to DEST's top, where the benchmark looks
first; ``CREDIT.md`` is written beside it (the citation, the licence, CC BY
4.0, the source, its commit and what was taken), and the clone's ``.git``
removed: DEST holds plain files. The clone is made in ``DEST.partial`` and
put in DEST's place once complete, so an interrupted fetch leaves no half
folder for the commands to read. A DEST that holds what is asked (every
trial, or the named ones) is left as it is; one that holds only some
trials (``FETCHED_TRIALS`` lists them) is fetched again with the rest.

Standard library and git only, so that it runs before anything is installed.
"""

import argparse
import glob
import os
import shutil
import subprocess
import sys

URL = 'https://github.com/dlaidig/broad.git'
URL_VAR = 'EXT_OBSERVER_BROAD_URL'
TREE = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
DEST = os.path.join(TREE, 'data', 'broad')
# Where trials.json may be in the clone, in the order they are tried.
TRIALS_JSON = ('trials.json', 'data_hdf5/trials.json', 'data_mat/trials.json')
# In a DEST that holds some of the trials only: their names, one a line.
SUBSET = 'FETCHED_TRIALS'
# A clone that has not finished by then has hung (a network that drops
# packets without refusing); BROAD's 100 MB take under a minute here.
TIMEOUT = 1800  # s

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

Fetched: {taken} and the top-level files of that commit; `trials.json`
from `{trials}`. Left out: the MATLAB copies (`data_mat/`), the example
code and the videos.
"""


def default_url():
    """Return ``$EXT_OBSERVER_BROAD_URL``, else BROAD's repository."""
    return os.environ.get(URL_VAR) or URL


def _trial_names(folder):
    return {os.path.splitext(os.path.basename(p))[0]
            for p in glob.glob(os.path.join(folder, 'data_hdf5', '*.hdf5'))
            + glob.glob(os.path.join(folder, '*.hdf5'))}


def _subset(folder):
    """The trials a partial fetch took (``FETCHED_TRIALS``), or None for a whole copy."""
    try:
        with open(os.path.join(folder, SUBSET), encoding='utf-8') as f:
            return {line.strip() for line in f if line.strip()}
    except FileNotFoundError:
        return None


def holds(folder, trials=None):
    """Whether ``folder`` holds BROAD: every trial (``trials`` None), or the named ones."""
    present = _trial_names(folder)
    if not present:
        return False
    if trials is None:
        return _subset(folder) is None
    return set(trials) <= present


def _git(*args, url):
    """Run git; return its stdout; raise RuntimeError with git's last line."""
    env = dict(os.environ, GIT_TERMINAL_PROMPT='0')  # a bad URL fails, never asks
    try:
        done = subprocess.run(['git', *args], capture_output=True, text=True, env=env,
                              timeout=TIMEOUT)
    except subprocess.TimeoutExpired as error:
        raise RuntimeError(f'cannot fetch BROAD from {url}: git {args[0]} did not end '
                           f'within {TIMEOUT} s') from error
    if done.returncode != 0:
        lines = [line for line in done.stderr.strip().splitlines()
                 if not line.startswith(('warning:', 'hint:'))]
        reason = lines[-1] if lines else f'git {args[0]} exited with {done.returncode}'
        raise RuntimeError(f'cannot fetch BROAD from {url}: {reason}')
    return done.stdout


def fetch(dest=DEST, url=None, trials=None):
    """
    Fetch BROAD into ``dest``; return ``dest``.

    Parameters
    ----------
    dest : str
    url : str, optional
        A git URL (default: :func:`default_url`).
    trials : iterable of str, optional
        Only these trials (names without ``.hdf5``); a ``dest`` that holds
        some trials already keeps them (they are fetched again with these).

    Raises
    ------
    RuntimeError
        git is missing, or a git step failed (in one line: the URL and
        git's reason), or the clone lacks an asked trial or holds no HDF5
        files.

    """
    url = url or default_url()
    if holds(dest, trials):
        print(f'{dest} already holds BROAD{" (the trials asked)" if trials else ""}; '
              'nothing to do (remove it to fetch again)')
        return dest
    if shutil.which('git') is None:
        raise RuntimeError('fetching BROAD needs git (apt-get install git)')
    wanted = None
    if trials is not None:
        present = _subset(dest)
        wanted = sorted(set(trials) | (present if present is not None else set()))
    partial = dest + '.partial'
    shutil.rmtree(partial, ignore_errors=True)
    os.makedirs(os.path.dirname(os.path.abspath(dest)), exist_ok=True)
    what = f'{len(wanted)} trials of BROAD' if wanted else 'BROAD'
    print(f'fetching {what} from {url} into {dest} ...', flush=True)
    # --sparse checks out the top-level files only; the sparse patterns then
    # add data_hdf5/ or the named files of it; blob:none fetches the
    # contents of those files only.
    _git('clone', '--quiet', '--depth', '1', '--filter=blob:none', '--sparse', url, partial,
         url=url)
    if wanted is None:
        _git('-C', partial, 'sparse-checkout', 'set', 'data_hdf5', url=url)
    else:
        _git('-C', partial, 'sparse-checkout', 'set', '--no-cone', '/*', '!/*/',
             *(f'/data_hdf5/{name}.hdf5' for name in wanted), url=url)
    found = _trial_names(partial)
    if wanted is not None and set(wanted) - found:
        shutil.rmtree(partial, ignore_errors=True)
        raise RuntimeError(f'{url}: no {sorted(set(wanted) - found)} under data_hdf5/')
    if not found:
        raise RuntimeError(f'{url}: no HDF5 files under data_hdf5/ (left in {partial})')
    trials_json = _copy_trials_json(partial)
    commit = _git('-C', partial, 'rev-parse', 'HEAD', url=url).strip()
    # The files are what the benchmark reads; their history would double
    # the space, and CREDIT.md names the commit.
    shutil.rmtree(os.path.join(partial, '.git'))
    taken = '`data_hdf5/`' if wanted is None else (
        f'{len(wanted)} trials of `data_hdf5/` (listed in `{SUBSET}`; '
        '`make broad-data` fetches them all)')
    with open(os.path.join(partial, 'CREDIT.md'), 'w', encoding='utf-8') as f:
        f.write(CREDIT.format(url=url, commit=commit, taken=taken,
                              trials=trials_json or 'nowhere (not found)'))
    if wanted is not None:
        with open(os.path.join(partial, SUBSET), 'w', encoding='utf-8') as f:
            f.write(''.join(f'{name}\n' for name in wanted))
    _replace(partial, dest)
    count = len(glob.glob(os.path.join(dest, 'data_hdf5', '*.hdf5')))
    print(f'{dest}: {count} trials of BROAD (CC BY 4.0, credit in {dest}/CREDIT.md)')
    return dest


def _replace(partial, dest):
    """Put the complete ``partial`` in ``dest``'s place (an older copy removed after)."""
    old = dest + '.old'
    shutil.rmtree(old, ignore_errors=True)
    if os.path.lexists(dest):
        os.rename(dest, old)
    os.rename(partial, dest)
    shutil.rmtree(old, ignore_errors=True)


def _copy_trials_json(clone):
    """Write the first ``trials.json`` of the commit to the clone's top; return its path."""
    for path in TRIALS_JSON:
        # git show fetches the one blob on demand (the clone has no others).
        done = subprocess.run(['git', '-C', clone, 'show', f'HEAD:{path}'],
                              capture_output=True, env=dict(os.environ, GIT_TERMINAL_PROMPT='0'),
                              timeout=TIMEOUT)
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
    parser.add_argument('--url', default=None,
                        help=f'the git repository (default: ${URL_VAR}, else {URL})')
    parser.add_argument('--trials', nargs='+', metavar='NAME',
                        help='only these trials (file names without .hdf5)')
    args = parser.parse_args(argv)
    try:
        fetch(args.dest, args.url, args.trials)
    except (RuntimeError, OSError) as error:
        print(f'error: {error}', file=sys.stderr)
        return 1
    return 0


if __name__ == '__main__':
    sys.exit(main())
