"""
A flat state's fields declared once (`core/ahrs/layout.py`): offsets
computed, a field twice or empty refused.
"""

import pytest

from ext_observer.core.ahrs.layout import Layout


def test_a_layout_refuses_a_field_declared_twice_or_empty():
    layout = Layout()
    assert layout.field('q', 4) == 0 and layout.field('bias', 3) == 4 and layout.size == 7
    with pytest.raises(ValueError, match='twice'):
        layout.field('q')
    with pytest.raises(ValueError, match='at least 1'):
        layout.field('none', 0)


def test_a_block_starts_where_it_is_told_and_parameters_keep_their_order():
    layout = Layout(start=10)
    assert layout.parameter('alpha') == 10 and layout.field('q', 4) == 11
    assert layout.parameter('beta') == 15 and layout.size == 16
    assert layout.parameters == ['alpha', 'beta']
    assert layout.offset('q') == 11 and layout.fields['beta'] == (15, 1)


def test_a_field_is_read_by_name_as_a_float_or_a_tuple():
    layout = Layout()
    layout.field('x')
    layout.field('v', 3)
    s = [1, 2, 3, 4.25]  # as a plain kernel's list may hold them
    assert layout.read(s, 'x') == 1.0 and type(layout.read(s, 'x')) is float
    assert layout.read(s, 'v') == (2.0, 3.0, 4.25)
    assert all(type(value) is float for value in layout.read(s, 'v'))
