"""
Where the tests on BROAD find it, and what they do without it.

The folder is the benchmark's own default (``ext_observer.broad.data_dir``:
``$EXT_OBSERVER_BROAD_DATA``, else ``data/broad``, else ``../shared/broad``).
Without it a test on real data fails, saying how to get the data
(``make broad-data``); ``EXT_OBSERVER_ALLOW_NO_BROAD=1`` makes it a skip,
for a machine that cannot have the data.
"""

import os

import pytest

from ext_observer import broad

ALLOW_NO_DATA = 'EXT_OBSERVER_ALLOW_NO_BROAD'


def broad_data_dir():
    """Return BROAD's folder, or fail (skip with EXT_OBSERVER_ALLOW_NO_BROAD=1)."""
    try:
        folder = broad.data_dir()
    except ValueError as error:
        reason = str(error)
    else:
        if broad.has_trials(folder):
            return folder
        reason = f'no HDF5 files in {folder} (from {broad.ENV_VAR}): {broad.HOW_TO_GET}'
    if os.environ.get(ALLOW_NO_DATA) == '1':
        pytest.skip(f'{reason} ({ALLOW_NO_DATA}=1)')
    pytest.fail(f'{reason}; without the data, {ALLOW_NO_DATA}=1 skips the tests on it',
                pytrace=False)
