"""
How the benchmarks time code in their own process: the best of a few repeats, cProfile's top.

On shared cores other work only ever adds time, so each figure is the
smallest of a few runs, the first of which warms caches and lazy imports.
"""

import math
import os
import pstats
import time

MIN_SECONDS = 0.15  # per timed loop, when the number of calls is not given
REPEATS = 3
TOP_FUNCTIONS = 10


def best_seconds(function, calls=None, repeats=REPEATS, min_seconds=MIN_SECONDS):
    """
    The best time of one call of ``function()``, s, over ``repeats`` loops of ``calls`` calls.

    Without ``calls``, as many as make a loop last ``min_seconds``.
    """
    function()
    if calls is None:
        calls = 1
        while True:
            start = time.perf_counter()
            for _ in range(calls):
                function()
            elapsed = time.perf_counter() - start
            if elapsed >= min_seconds / 4:
                break
            calls *= 4
        calls = max(1, int(calls * min_seconds / elapsed))
    best = math.inf
    for _ in range(repeats):
        start = time.perf_counter()
        for _ in range(calls):
            function()
        best = min(best, (time.perf_counter() - start) / calls)
    return best


def best_pass(run, passes):
    """The smallest of ``passes`` results of ``run()`` but the first (it warms up)."""
    return min([run() for _ in range(passes)][1:])


def top_functions(profile, per, skip=(), count=TOP_FUNCTIONS):
    """
    The functions with the most own time under a ``cProfile.Profile``, per ``per`` steps.

    Returns
    -------
    list of dict
        ``function`` (``file:name``), ``own_us`` and ``calls`` per step,
        the largest own time first; the names in ``skip`` left out.

    """
    own = [(tottime / per * 1e6, f'{os.path.basename(path)}:{name}' if path != '~' else name,
            calls / per)
           for (path, _, name), (_, calls, tottime, _, _) in pstats.Stats(profile).stats.items()
           if name not in skip]
    return [{'function': label, 'own_us': us, 'calls': calls}
            for us, label, calls in sorted(own, reverse=True)[:count]]
