"""
A pytest plugin for ``make mutation``: the tests of a mutant, fastest first.

mutmut runs a mutant's tests with ``-x`` (the first failure kills it) in
no particular order; ordered by the durations mutmut measured in its stats
run (``mutmut-stats.json``, in the working directory), a mutant that a fast
test catches is killed in that test's time, not after the slow ones.
Loaded by :mod:`run_mutmut` only (``-p fast_first``).
"""

import json
import os


def pytest_collection_modifyitems(session, config, items):
    try:
        with open(os.path.join(os.getcwd(), 'mutmut-stats.json'), encoding='utf-8') as f:
            durations = json.load(f)['duration_by_test']
    except (OSError, ValueError, KeyError):
        return
    items.sort(key=lambda item: durations.get(item.nodeid, 0.0))
