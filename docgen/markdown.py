"""The one Markdown table writer of the generated pages and the benchmarks' printed tables."""

__all__ = ['table']


def table(header, rows, numeric=False, text=1):
    """
    Return a Markdown table: ``header`` and ``rows`` (cells of any type, shown with ``str``).

    With ``numeric``, every column after the first ``text`` ones is right-aligned.
    """
    align = ['---'] * text + ['---:' if numeric else '---'] * (len(header) - text)
    lines = ['| ' + ' | '.join(str(cell) for cell in header) + ' |', '|' + '|'.join(align) + '|']
    lines += ['| ' + ' | '.join(str(cell) for cell in row) + ' |' for row in rows]
    return '\n'.join(lines)
