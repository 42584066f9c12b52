"""
Where the docs' writers are found (``ext_observer/source_tree.py``): beside
the package in a clone, and what an installed package says instead.
"""

import sys

import pytest

from ext_observer import source_tree


def test_in_a_clone_the_writers_are_imported():
    assert source_tree.docgen('sections').__name__ == 'docgen.sections'
    with pytest.raises(ModuleNotFoundError):
        source_tree.docgen('no_such_writer')


def test_without_docgen_beside_the_package_the_error_says_what_to_do(monkeypatch, tmp_path):
    # As where docgen cannot be imported: None in sys.modules halts the import.
    monkeypatch.setitem(sys.modules, 'docgen', None)
    monkeypatch.setitem(sys.modules, 'docgen.sections', None)
    monkeypatch.setattr(source_tree, 'TREE', str(tmp_path))
    with pytest.raises(RuntimeError, match=r'needs docgen/ of a clone .* or leave out --docs'):
        source_tree.docgen('sections')
