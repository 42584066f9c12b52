"""
The generated sections of the docs pages: one replaced between its two markers.

The one writer of such sections: the parameter tables
(:mod:`docgen.parameter_tables`) and the benchmarks' sections
(:mod:`docgen.compiled_page`) all go through :func:`replaced`.
"""

__all__ = ['replace_section', 'replaced']


def replaced(text, section, begin, end, where='the page'):
    """
    Return ``text`` with ``section`` (markers included) from ``begin`` to the next ``end``.

    Raises
    ------
    ValueError
        If ``text`` lacks either marker (``where`` names it in the message).

    """
    head, found, rest = text.partition(begin)
    if not found or end not in rest:
        raise ValueError(f'{where} has no generated section ({begin} ... {end})')
    _, _, tail = rest.partition(end)
    return head + section + tail


def replace_section(path, section, begin, end):
    """Put ``section`` (markers included) in place of ``path``'s, from ``begin`` to ``end``."""
    with open(path, encoding='utf-8') as f:
        page = f.read()
    page = replaced(page, section, begin, end, where=path)
    with open(path, 'w', encoding='utf-8') as f:
        f.write(page)
    return path
