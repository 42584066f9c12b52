"""
A parameter row and a table of them (``core/ahrs/parameter_rows.py``): the range
in words and in checks, a flag, defaults, unknown names.
"""

import math

import pytest

from ext_observer.core.ahrs.parameter_rows import Tunable, Tunables

TAU = Tunable('tau', 3.0, 's', 0.0, 100.0, 'time constant of the correction')
SHARE = Tunable('share', 0.5, '', 0.0, 1.0, 'share of the samples', low_closed=True,
                high_open=True, zero_off=True)
FLAG = Tunable('on', True, '', None, None, 'whether it runs')


class Params(Tunables):
    TABLE = (TAU, SHARE, FLAG)


def test_the_rule_and_description_say_the_range_and_unit():
    assert TAU.description == 'time constant of the correction, s.'
    assert SHARE.description == 'share of the samples.'
    assert TAU.rule == 'Must be > 0 and <= 100.'
    assert SHARE.rule == 'Must be >= 0 (0: off) and < 1.'
    assert FLAG.flag and FLAG.rule == '' and not TAU.flag


@pytest.mark.parametrize('row, value, reason', [
    (TAU, 0.0, 'tau must be positive, got 0.0'),
    (TAU, 100.5, 'tau must be <= 100, got 100.5'),
    (TAU, math.inf, 'tau must be finite'),
    (SHARE, -0.1, r'share must be >= 0 \(0: off\), got -0.1'),
    (SHARE, 1.0, 'share must be below 1, got 1.0'),
    (FLAG, 'yes', "on must be true or false, got 'yes'"),
])
def test_a_value_outside_the_range_is_refused_with_its_name(row, value, reason):
    with pytest.raises(ValueError, match=reason):
        row.check(value)


def test_the_edges_of_the_range_are_taken_as_stated():
    assert TAU.check(100) == 100.0 and type(TAU.check(100)) is float
    assert SHARE.check(0) == 0.0
    assert FLAG.check(0) is False
    assert Tunable('x', 1.0, '', 2.0, 5.0, 'x').rule == 'Must be > 2 and <= 5.'
    with pytest.raises(ValueError, match='x must be > 2, got 2.0'):
        Tunable('x', 3.0, '', 2.0, 5.0, 'x').check(2.0)


def test_a_table_gives_defaults_checked_values_and_refuses_unknown_names():
    assert Params.DEFAULTS == {'tau': 3.0, 'share': 0.5, 'on': True}
    params = Params(tau=2, on=False)
    assert params.as_dict() == {'tau': 2.0, 'share': 0.5, 'on': False}
    assert repr(params) == 'Params(tau=2, share=0.5, on=False)'
    with pytest.raises(ValueError, match=r"unknown parameters: \['gain'\]"):
        Params(gain=1.0)
    with pytest.raises(ValueError, match='tau must be positive'):
        Params(tau=-1.0)
