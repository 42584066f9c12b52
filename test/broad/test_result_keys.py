"""
The names the benchmark's results are keyed by (``broad/result_keys.py``):
the algorithms a result holds, in table order.
"""

from ext_observer.broad.result_keys import (ALGORITHMS, algorithms_in, ANCHORS, OURS, OURS_PLAIN,
                                           OURS_SMOOTHED)


def test_the_algorithms_of_a_result_come_in_table_order():
    assert ALGORITHMS[:3] == (OURS, OURS_PLAIN, OURS_SMOOTHED) and ALGORITHMS[3:] == ANCHORS
    scores = {'Madgwick': {}, 'unknown': {}, OURS: {}, 'VQF': {}}
    assert algorithms_in({'scores': scores}) == [OURS, 'VQF', 'Madgwick']
    assert algorithms_in({'scores': {}}) == []
