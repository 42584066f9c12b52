"""
The generated parts of ``docs/``: ``python -m ext_observer docs``.

``docs/parameters.md`` holds one table per node, made by
:func:`~ext_observer.node_common.markdown_table` from the node's
``ParameterSpec`` rows (``GYRO_PARAMETERS``, ``OBSERVER_PARAMETERS``,
``MONITOR_PARAMETERS``). Each table sits between two marker comments; the
prose around them is written by hand and left as it is. After a change to a
node's parameters, run ``python -m ext_observer docs`` (or ``make docs``);
``test/test_docs.py`` fails while the page and the specs differ.

The other generated pages have their own commands: ``docs/reproduction.md``
and its figures ``make reproduce``, ``docs/performance.md`` ``make bench``,
``docs/figures/demo.png``
``python -m ext_observer demo --plot docs/figures/demo.png``.
"""

import argparse
import importlib
import os
import re
import sys

__all__ = ['NODES', 'PAGE', 'main', 'parameter_tables', 'render']

PAGE = 'parameters.md'

# (node name, module, specs): one generated table each, in this order.
NODES = (
    ('gyro', 'ext_observer.gyro_node', 'GYRO_PARAMETERS'),
    ('observer', 'ext_observer.observer_node', 'OBSERVER_PARAMETERS'),
    ('monitor', 'ext_observer.monitor_node', 'MONITOR_PARAMETERS'),
)

_BEGIN = ('<!-- generated from {specs} in {path} by python -m ext_observer docs; '
          'edit the specs, not this table -->')
_END = '<!-- end of the generated table -->'


def _begin(module, specs):
    return _BEGIN.format(specs=specs, path=module.replace('.', '/') + '.py')


def parameter_tables():
    """
    Return the generated parameter tables.

    Returns
    -------
    tables : list of (str, str, str)
        (node name, begin marker, Markdown table) per node of :data:`NODES`.

    """
    from ext_observer.node_common import markdown_table

    tables = []
    for name, module, specs in NODES:
        rows = getattr(importlib.import_module(module), specs)
        tables.append((name, _begin(module, specs), markdown_table(rows)))
    return tables


def render(text):
    """
    Return ``text`` with every generated table replaced by the current one.

    Parameters
    ----------
    text : str
        The page, with the marker comments of every node.

    Returns
    -------
    text : str

    Raises
    ------
    ValueError
        If the markers of a node are missing.

    """
    for name, begin, table in parameter_tables():
        pattern = re.compile(re.escape(begin) + r'\n.*?' + re.escape(_END), re.DOTALL)
        if not pattern.search(text):
            raise ValueError(f'no generated table of {name}: the page needs the line\n'
                             f'{begin}\nand, after the table, {_END}')
        text = pattern.sub(lambda _: f'{begin}\n{table}{_END}', text, count=1)
    return text


def main(argv=None):
    """Regenerate (or, with ``--check``, compare) the page; return the exit code."""
    parser = argparse.ArgumentParser(
        prog='python -m ext_observer docs',
        description=f'Regenerate the parameter tables of DIR/{PAGE} from the '
                    'parameter specs of the nodes.')
    parser.add_argument('--docs', default='docs', metavar='DIR',
                        help='the docs folder (default docs)')
    parser.add_argument('--check', action='store_true',
                        help='write nothing; exit 1 if the page differs from the specs')
    args = parser.parse_args(argv)
    path = os.path.join(args.docs, PAGE)
    with open(path, encoding='utf-8') as page:
        text = page.read()
    try:
        new = render(text)
    except ValueError as error:
        print(f'error: {path}: {error}', file=sys.stderr)
        return 2
    if new == text:
        print(f'{path}: up to date')
        return 0
    if args.check:
        print(f'{path}: differs from the parameter specs; run python -m ext_observer docs',
              file=sys.stderr)
        return 1
    with open(path, 'w', encoding='utf-8') as page:
        page.write(new)
    print(f'{path}: regenerated')
    return 0


if __name__ == '__main__':
    sys.exit(main())
