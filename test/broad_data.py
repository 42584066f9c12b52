"""
Where the tests on BROAD find it, what they read of it, and its fetch for ``make test``.

The folder is the benchmark's own default (``ext_observer.broad.data_dir``:
``$EXT_OBSERVER_BROAD_DATA``, else ``data/broad``, else ``../shared/broad``).
Without it a test on real data fails, saying how to get the data;
``EXT_OBSERVER_ALLOW_NO_BROAD=1`` makes it a skip, for a machine that cannot
have the data.

``python test/broad_data.py`` (the first step of ``make test``): where no
folder holds the trials of :data:`TRIALS`, fetch those (and only those)
into ``data/broad`` with the project's own fetch
(:mod:`ext_observer.broad.fetch`; the source: ``$EXT_OBSERVER_BROAD_URL``,
else BROAD's repository). A folder named by ``$EXT_OBSERVER_BROAD_DATA`` is
never fetched into. When the fetch fails it prints one line and exits 1
(0 with ``EXT_OBSERVER_ALLOW_NO_BROAD=1``: the tests on the data skip).
"""

import os
import sys

from ext_observer import broad
from ext_observer.broad import data, fetch

ALLOW_NO_DATA = 'EXT_OBSERVER_ALLOW_NO_BROAD'
# Every trial a test reads: what make test fetches. A test that reads
# another must add it here (broad_data_dir says so).
TRIALS = ('01_undisturbed_slow_rotation_A', '09_undisturbed_fast_rotation_with_breaks_B',
          '14_undisturbed_slow_translation_with_breaks_B', '15_undisturbed_fast_translation_A',
          '18_undisturbed_fast_translation_with_breaks_B', '28_disturbed_stationary_magnet_A',
          '29_disturbed_stationary_magnet_B', '32_disturbed_attached_magnet_1cm')


def _missing(folder, trials):
    present = {name for name, _ in broad.find_trials(folder)} if broad.has_trials(folder) \
        else set()
    return [t for t in trials if t not in present]


def broad_data_dir(trials):
    """
    Return BROAD's folder, holding ``trials``; else fail (skip with EXT_OBSERVER_ALLOW_NO_BROAD=1).

    ``trials`` must be among :data:`TRIALS`, so that ``make test`` fetches them.
    """
    import pytest

    outside = [t for t in trials if t not in TRIALS]
    if outside:
        pytest.fail(f'{outside} are not in test/broad_data.py TRIALS: add them, so that '
                    'make test fetches them', pytrace=False)
    try:
        folder = broad.data_dir()
    except ValueError as error:
        reason = str(error)
    else:
        missing = _missing(folder, trials)
        if not missing:
            return folder
        reason = (f'{folder} lacks {missing}: python test/broad_data.py (run by make test) '
                  f'fetches them into data/broad; or {broad.HOW_TO_GET}')
    if os.environ.get(ALLOW_NO_DATA) == '1':
        pytest.skip(f'{reason} ({ALLOW_NO_DATA}=1)')
    pytest.fail(f'{reason}; without the data, {ALLOW_NO_DATA}=1 skips the tests on it',
                pytrace=False)



def run_against_page(trials, page, page_figures):
    """
    The page's per-trial figures, our run of ``trials`` (both modes, no anchors), the trials.

    Fails when the page lacks a trial or the data lacks one.
    """
    folder = broad_data_dir(trials)
    with open(page, encoding='utf-8') as f:
        reported = page_figures(f.read())
    missing = [t for t in trials if t not in reported]
    assert not missing, (f'{page} has no per-trial figures for {missing}: '
                         'regenerate it with make broad (all trials)')
    loaded = [broad.load_trial(path, name) for name, path in broad.find_trials(folder, trials)]
    assert [t.name for t in loaded] == list(trials), f'{folder} lacks some of {trials}'
    result = broad.run(loaded, broad.MODES, anchors=(), workers=min(2, os.cpu_count() or 1),
                       progress=lambda text: None)
    return reported, result, loaded

def ensure(trials=TRIALS, dest=None):
    """
    Fetch ``trials`` into ``dest`` (``data/broad``) where no folder holds them; return the folder.

    Raises
    ------
    RuntimeError
        The fetch failed (one line: the URL and git's reason).

    """
    named = os.environ.get(broad.ENV_VAR)
    if named:
        return named
    try:
        folder = broad.data_dir()
    except ValueError:
        folder = None
    if folder is not None and not _missing(folder, trials):
        return folder
    dest = dest or os.path.join(data.TREE, data.DEFAULT_DIRS[0])
    return fetch.fetch(dest, trials=trials)


def main():
    """Fetch what the tests read where it is missing; return the exit code."""
    try:
        ensure()
    except (RuntimeError, OSError) as error:
        allowed = os.environ.get(ALLOW_NO_DATA) == '1'
        after = ('the tests on it skip' if allowed else
                 f'set {fetch.URL_VAR} to a mirror, {broad.ENV_VAR} to a folder with the '
                 f'files, or {ALLOW_NO_DATA}=1 to skip the tests on it')
        print(f'{"warning" if allowed else "error"}: no BROAD data for the tests and {error} '
              f'({after})', file=sys.stderr)
        return 0 if allowed else 1
    return 0


if __name__ == '__main__':
    sys.exit(main())
