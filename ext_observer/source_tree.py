"""
The writers of this repository's docs (``docgen/``), found beside the package in a source tree.

``docgen`` is not installed: ``broad --docs``, ``reproduce --docs`` and
``docs`` write a clone's docs/ and config/, and mean nothing to an installed
package. In a clone (an editable install, or run from its root) they are
imported from the folder beside ``ext_observer/``.
"""

import importlib
import os
import sys

__all__ = ['DOCGEN', 'docgen', 'TREE']

# The folder holding ext_observer/ (and, in a clone, docgen/ and docs/).
TREE = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DOCGEN = 'docgen'


def docgen(module):
    """
    Return the module ``docgen.<module>`` of the source tree.

    Raises
    ------
    RuntimeError
        Where ``docgen`` is neither importable nor beside the package (an
        installed package): the message says what to do instead.

    """
    name = f'{DOCGEN}.{module}'
    try:
        return importlib.import_module(name)
    except ModuleNotFoundError as error:
        if error.name not in (DOCGEN, name):
            raise
    if not os.path.isfile(os.path.join(TREE, DOCGEN, '__init__.py')):
        raise RuntimeError(
            f'writing the docs needs {DOCGEN}/ of a clone of ext_observer, which is not '
            'installed with the package: run the command in the clone (make docs, '
            'make broad, make reproduce), or leave out --docs')
    sys.path.append(TREE)
    return importlib.import_module(name)
