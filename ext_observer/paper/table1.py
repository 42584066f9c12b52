"""
Table 1 of the paper and the run's beside it, as Markdown.

``python -m ext_observer reproduce`` prints it; the page of a clone
(``docgen/reproduction_page.py``) shows it too.
"""

__all__ = ['COLUMNS', 'markdown_table', 'PAPER_ROWS', 'PAPER_TABLE', 'STATS']

# Table 1 of the paper: ‖q − q̂‖ and dist(q, S³) (which is |q̂̄q̂ − 1|).
PAPER_TABLE = {
    'extended': {'error': {'mean': 0.138, 'std': 0.07, 'max': 1.816, 'min': 0.007},
                 'distance': {'mean': 0.084, 'std': 0.072, 'max': 2.182,
                              'min': 0.0}},
    'plain': {'error': {'mean': 0.148, 'std': 0.076, 'max': 4.747, 'min': 0.007},
              'distance': {'mean': 0.112, 'std': 0.101, 'max': 25.121,
                           'min': 0.0}},
}
STATS = ('mean', 'std', 'max', 'min')
COLUMNS = ('error', 'distance')
PAPER_ROWS = ('extended', 'plain', 'projected')

def markdown_table(table, spread=None, rows=None, columns=COLUMNS,
                   paper=PAPER_TABLE):
    """
    Render Table 1 as Markdown, with the paper's rows and the difference.

    Parameters
    ----------
    table, spread : dict
        Row → column → stat (spread: std over seeds, optional).
    rows : sequence of str, optional
    columns : sequence of str
    paper : dict
        The paper's values; rows present there get a "paper" line and a
        relative difference line.

    Returns
    -------
    text : str

    """
    rows = list(table) if rows is None else rows
    # Pipes are escaped: they would split a Markdown table cell.
    labels = {'error': '‖q − q̂‖', 'distance': '\\|q̂̄q̂ − 1\\|',
              'euclidean_distance': '\\|‖q̂‖ − 1\\|', 'angle': 'angle (rad)'}
    header = '| Observer | ' + ' | '.join(
        f'{labels[c]} {s.capitalize()}' for c in columns for s in STATS) + ' |'
    lines = [header, '|' + '---|' * (1 + len(columns) * len(STATS))]
    for row in rows:
        cells = []
        for c in columns:
            for s in STATS:
                value = table[row][c][s]
                text = f'{value:.3f}' if abs(value) < 100 else f'{value:.1f}'
                if spread is not None and spread[row][c][s] > 0:
                    text += f' ± {spread[row][c][s]:.3f}'
                cells.append(text)
        lines.append(f'| {row} | ' + ' | '.join(cells) + ' |')
        if row in paper and all(c in paper[row] for c in columns):
            lines.append(f'| *{row}, paper* | ' + ' | '.join(
                f'*{paper[row][c][s]:g}*' for c in columns for s in STATS) + ' |')
            diffs = []
            for c in columns:
                for s in STATS:
                    ref = paper[row][c][s]
                    diffs.append('—' if ref == 0 else
                                 f'{100 * (table[row][c][s] - ref) / ref:+.0f}%')
            lines.append('| *difference* | ' + ' | '.join(diffs) + ' |')
    return '\n'.join(lines)
