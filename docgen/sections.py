"""The generated sections of the docs pages: one replaced between its two markers."""

__all__ = ['replace_section']


def replace_section(path, section, begin, end):
    """Put ``section`` (markers included) in place of ``path``'s, from ``begin`` to ``end``."""
    with open(path, encoding='utf-8') as f:
        page = f.read()
    if begin not in page or end not in page:
        raise ValueError(f'{path} has no generated section ({begin} ... {end})')
    head, rest = page.split(begin, 1)
    _, tail = rest.split(end, 1)
    with open(path, 'w', encoding='utf-8') as f:
        f.write(head + section + tail)
    return path
