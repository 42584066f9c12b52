"""
Table 1 as Markdown (``paper/table1.py``): the run's rows, the paper's
beside them and the difference in percent, pipes escaped.
"""

from ext_observer.paper.table1 import markdown_table, PAPER_TABLE


def stats(mean, std, high, low):
    return {'mean': mean, 'std': std, 'max': high, 'min': low}


def test_a_row_of_the_paper_gets_its_values_and_the_difference():
    table = {'extended': {'error': stats(0.15, 0.07, 1.816, 0.007),
                          'distance': stats(0.084, 0.072, 250.0, 0.0)},
             'mine': {'error': stats(1.0, 0.0, 1.0, 1.0), 'distance': stats(0, 0, 0, 0)}}
    spread = {row: {c: stats(0.0, 0.0, 0.0, 0.0) for c in ('error', 'distance')}
              for row in table}
    spread['extended']['error']['mean'] = 0.01
    lines = markdown_table(table, spread).splitlines()
    assert lines[0].startswith('| Observer | ‖q − q̂‖ Mean | ‖q − q̂‖ Std |')
    assert '\\|q̂̄q̂ − 1\\| Min |' in lines[0]
    assert lines[1] == '|' + '---|' * 9
    assert lines[2] == ('| extended | 0.150 ± 0.010 | 0.070 | 1.816 | 0.007 | 0.084 | 0.072 '
                        '| 250.0 | 0.000 |')
    assert lines[3].startswith('| *extended, paper* | *0.138* | *0.07* |')
    assert lines[4] == '| *difference* | +9% | +0% | +0% | +0% | +0% | +0% | +11357% | — |'
    assert lines[5] == '| mine | 1.000 | 0.000 | 1.000 | 1.000 | 0.000 | 0.000 | 0.000 | 0.000 |'
    assert len(lines) == 6 and PAPER_TABLE['plain']['distance']['max'] == 25.121
