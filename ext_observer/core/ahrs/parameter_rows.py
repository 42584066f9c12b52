"""
A parameter declared once: :class:`Tunable` (name, default, unit, range, one line).

:class:`~ext_observer.core.ahrs.ahrs_params.AhrsParams` and
:class:`~ext_observer.core.ahrs.ahrs_params.UncertaintyParams` are
:class:`Tunables`: their fields, defaults and checks come from a table of
rows, and so do the node's declarations (ranges included), the generated
docs and the YAML (:mod:`ext_observer.pipeline.raw_imu_parameters`). The
range is the rule: the node enforces the core's.
"""

import dataclasses
import math
from typing import Optional, Union

__all__ = ['Tunable', 'Tunables']


@dataclasses.dataclass(frozen=True)
class Tunable:
    """
    One parameter.

    Attributes
    ----------
    name : str
    default : float or bool
    unit : str
        ``''`` for a ratio or a flag.
    low, high : float, optional
        The range (None for a flag). ``low`` excluded unless ``low_closed``;
        ``high`` included unless ``high_open``.
    text : str
        One line: what it is (the unit is appended where it is said).
    low_closed, high_open : bool
    zero_off : bool
        0 turns the feature off (said in the rule).

    """

    name: str
    default: Union[float, bool]
    unit: str
    low: Optional[float]
    high: Optional[float]
    text: str
    low_closed: bool = False
    high_open: bool = False
    zero_off: bool = False

    @property
    def flag(self):
        """Whether it is a bool."""
        return isinstance(self.default, bool)

    @property
    def description(self):
        """The line with its unit: ``'time constant of ..., s.'``."""
        return f'{self.text}, {self.unit}.' if self.unit else f'{self.text}.'

    @property
    def rule(self):
        """The range in words (ParameterDescriptor.additional_constraints)."""
        if self.flag:
            return ''
        low = f'>= {self.low:g}' if self.low_closed else f'> {self.low:g}'
        high = f'< {self.high:g}' if self.high_open else f'<= {self.high:g}'
        off = ' (0: off)' if self.zero_off else ''
        return f'Must be {low}{off} and {high}.'

    def check(self, value):
        """``value`` as the parameter's type; ValueError naming it when out of its range."""
        name = self.name
        if self.flag:
            if value not in (True, False):
                raise ValueError(f'{name} must be true or false, got {value!r}')
            return bool(value)
        value = float(value)
        if not math.isfinite(value):
            raise ValueError(f'{name} must be finite, got {value}')
        if self.low_closed and not value >= self.low:
            zero = ' (0: off)' if self.zero_off else ''
            raise ValueError(f'{name} must be >= {self.low:g}{zero}, got {value}')
        if not self.low_closed and not value > self.low:
            raise ValueError(f'{name} must be ' + ('positive' if self.low == 0.0 else
                                                   f'> {self.low:g}') + f', got {value}')
        if self.high_open and not value < self.high:
            raise ValueError(f'{name} must be below {self.high:g}, got {value}')
        if not self.high_open and not value <= self.high:
            raise ValueError(f'{name} must be <= {self.high:g}, got {value}')
        return value


class Tunables:
    """
    Parameters from a table of :class:`Tunable` rows (a subclass sets ``TABLE``).

    ``Tunables(**values)``: the defaults, with ``values`` in their place;
    each checked (``ValueError`` with the name and the reason). The fields
    are attributes; ``DEFAULTS`` is ``{name: default}``.
    """

    TABLE = ()
    DEFAULTS = {}

    def __init_subclass__(cls, **kwargs):
        super().__init_subclass__(**kwargs)
        cls.ROWS = {row.name: row for row in cls.TABLE}
        cls.DEFAULTS = {row.name: row.default for row in cls.TABLE}

    def __init__(self, **values):
        unknown = set(values) - set(self.ROWS)
        if unknown:
            raise ValueError(f'unknown parameters: {sorted(unknown)}')
        for name, row in self.ROWS.items():
            setattr(self, name, row.check(values.get(name, row.default)))

    def as_dict(self):
        """Return the parameters as a dict."""
        return {name: getattr(self, name) for name in self.ROWS}

    def __repr__(self):
        items = ', '.join(f'{k}={v}' if isinstance(v, bool) else f'{k}={v:g}'
                          for k, v in self.as_dict().items())
        return f'{type(self).__name__}({items})'
