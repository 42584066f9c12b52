"""
The generated parts of ``docs/``: ``python -m ext_observer docs``.

``docs/parameters.md`` holds one table per node, made by
:func:`markdown_table` from the node's
``ParameterSpec`` rows (``GYRO_PARAMETERS``, ``OBSERVER_PARAMETERS``,
``MONITOR_PARAMETERS``). Each table sits between two marker comments; the
prose around them is written by hand and left as it is. After a change to a
node's parameters, run ``python -m ext_observer docs`` (or ``make docs``);
``test/test_docs.py`` fails while the page and the specs differ.

The same command rewrites the node sections of the params files,
``config/ext_observer.yaml`` (gyro, observer, monitor) and
``config/imu_filter.yaml`` (every parameter with its default and a comment,
:func:`yaml_section`; the header comment is left
as it is); ``test/test_nodes.py`` loads that file and checks it.

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
import textwrap

from docgen.sections import replaced

__all__ = ['CONFIG', 'NODES', 'PAGE', 'main', 'markdown_table', 'parameter_tables', 'render',
           'render_config', 'yaml_section']

PAGE = 'parameters.md'
# The params files, relative to the parent of the docs folder.
CONFIG = os.path.join('config', 'ext_observer.yaml')
IMU_FILTER_CONFIG = os.path.join('config', 'imu_filter.yaml')

# (node name, module, specs, params file, specs of its section there): one
# generated table each, in this order. imu_filter's file leaves out the
# parameters of imu_filter_madgwick it does not use: given, they are warned
# about.
NODES = (
    ('gyro', 'ext_observer.nodes.node_parameters', 'GYRO_PARAMETERS', CONFIG, 'GYRO_PARAMETERS'),
    ('observer', 'ext_observer.nodes.node_parameters', 'OBSERVER_PARAMETERS', CONFIG,
     'OBSERVER_PARAMETERS'),
    ('monitor', 'ext_observer.nodes.node_parameters', 'MONITOR_PARAMETERS', CONFIG,
     'MONITOR_PARAMETERS'),
    ('imu_filter', 'ext_observer.pipeline.imu_filter_parameters', 'IMU_FILTER_PARAMETERS',
     IMU_FILTER_CONFIG, 'IMU_FILTER_OWN'),
)

_BEGIN = ('<!-- generated from {specs} in {path} by python -m ext_observer docs; '
          'edit the specs, not this table -->')
_END = '<!-- end of the generated table -->'


def _begin(module, specs):
    return _BEGIN.format(specs=specs, path=module.replace('.', '/') + '.py')


def markdown_table(specs):
    """
    Return the table of a node's parameters in ``docs/parameters.md``.

    Parameters
    ----------
    specs : sequence of ParameterSpec

    Returns
    -------
    table : str
        Markdown, one row per parameter, ending with a newline.

    """
    rows = ['| parameter | type | default | range | runtime | description |',
            '| --- | --- | --- | --- | --- | --- |']
    for spec in specs:
        bounds = '' if spec.range is None else f'[{spec.range[0]}, {spec.range[1]}]'
        runtime = 'no' if spec.read_only else 'yes'
        description = spec.description
        if spec.constraints:
            description += f' {spec.constraints}'
        description = description.replace('|', '\\|')
        rows.append(f'| `{spec.name}` | {spec.type_name} | `{spec.default_text}` | '
                    f'{bounds} | {runtime} | {description} |')
    return '\n'.join(rows) + '\n'


def yaml_section(node_name, specs):
    """
    Return a node's section of ``config/ext_observer.yaml``.

    Every parameter with its default, under a comment made of its description,
    constraints, range and whether it is start-up only, wrapped at 78
    columns.

    Parameters
    ----------
    node_name : str
        The section is ``/**/<node_name>``.
    specs : sequence of ParameterSpec

    Returns
    -------
    section : str
        YAML, ending with a newline.

    """
    lines = [f'/**/{node_name}:', '  ros__parameters:']
    for spec in specs:
        text = spec.description
        if spec.constraints:
            text += f' {spec.constraints}'
        if spec.range is not None:
            text += f' Range [{spec.range[0]}, {spec.range[1]}].'
        if spec.read_only:
            text += ' Start-up only.'
        lines += textwrap.wrap(text, width=78, initial_indent='    # ',
                               subsequent_indent='    # ', break_on_hyphens=False)
        lines.append(f'    {spec.name}: {spec.default_text}')
    return '\n'.join(lines) + '\n'



def parameter_tables():
    """
    Return the generated parameter tables.

    Returns
    -------
    tables : list of (str, str, str)
        (node name, begin marker, Markdown table) per node of :data:`NODES`.

    """
    tables = []
    for name, module, specs, _, _ in NODES:
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
        try:
            text = replaced(text, f'{begin}\n{table}{_END}', begin + '\n', _END)
        except ValueError:
            raise ValueError(f'no generated table of {name}: the page needs the line\n'
                             f'{begin}\nand, after the table, {_END}') from None
    return text


def render_config(text, config=CONFIG):
    """
    Return a params file with every node's section regenerated from its specs.

    Parameters
    ----------
    text : str
        The file, with a ``/**/<node>:`` section per node of :data:`NODES`
        whose params file is ``config``.
    config : str
        :data:`CONFIG` or :data:`IMU_FILTER_CONFIG`.

    Returns
    -------
    text : str

    Raises
    ------
    ValueError
        If the section of a node is missing.

    """
    for name, module, _, path, specs in NODES:
        if path != config:
            continue
        rows = getattr(importlib.import_module(module), specs)
        pattern = re.compile(rf'^/\*\*/{re.escape(name)}:\n(?:  .*\n)*', re.MULTILINE)
        if not pattern.search(text):
            raise ValueError(f'no section /**/{name}:')
        section = yaml_section(name, rows)
        text = pattern.sub(lambda _: section, text, count=1)
    return text


def _update(path, render, check):
    """Regenerate (or compare) one file; return the exit code."""
    with open(path, encoding='utf-8') as file:
        text = file.read()
    try:
        new = render(text)
    except ValueError as error:
        print(f'error: {path}: {error}', file=sys.stderr)
        return 2
    if new == text:
        print(f'{path}: up to date')
        return 0
    if check:
        print(f'{path}: differs from the parameter specs; run python -m ext_observer docs',
              file=sys.stderr)
        return 1
    with open(path, 'w', encoding='utf-8') as file:
        file.write(new)
    print(f'{path}: regenerated')
    return 0


# docs/layout.md's table of the estimator's state (every field, its unit and meaning).
LAYOUT_PAGE = 'layout.md'
_STATE_BEGIN = ('<!-- generated from STATE in ext_observer/core/ahrs/ahrs_state.py by python -m '
                'ext_observer docs -->')
_STATE_END = '<!-- end of the state table -->'


def render_state(text):
    """``text`` (docs/layout.md) with its table of the estimator's state regenerated."""
    from ext_observer.core.ahrs.ahrs_state import table
    section = f'{_STATE_BEGIN}\n{table()}\n{_STATE_END}'
    return replaced(text, section, _STATE_BEGIN, _STATE_END, where=LAYOUT_PAGE)


def main(argv=None):
    """Regenerate (or, with ``--check``, compare) the page; return the exit code."""
    parser = argparse.ArgumentParser(
        prog='python -m ext_observer docs',
        description=f'Regenerate the parameter tables of DIR/{PAGE} and the node '
                    f'sections of the params file from the parameter specs of the nodes, '
                    f'and the table of the estimator\'s state in DIR/{LAYOUT_PAGE}.')
    parser.add_argument('--docs', default='docs', metavar='DIR',
                        help='the docs folder (default docs)')
    parser.add_argument('--check', action='store_true',
                        help='write nothing; exit 1 if the page differs from the specs')
    args = parser.parse_args(argv)
    code = _update(os.path.join(args.docs, PAGE), render, args.check)
    layout = os.path.join(args.docs, LAYOUT_PAGE)
    if code != 2 and os.path.exists(layout):
        code = max(code, _update(layout, render_state, args.check))
    root = os.path.dirname(os.path.abspath(args.docs))
    for config in (CONFIG, IMU_FILTER_CONFIG):
        path = os.path.join(root, config)
        if code != 2 and os.path.exists(path):
            code = max(code, _update(path, lambda text: render_config(text, config),
                                     args.check))
    return code


if __name__ == '__main__':
    sys.exit(main())
