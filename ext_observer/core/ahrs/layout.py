"""
A flat state's layout declared once: named fields with sizes, offsets computed.

Each kernel module lists its fields in order, one line each
(``S_Q = AHRS.field('q', 4)``): the offset is the sum of the sizes before,
so a field is added or resized in one place. The constants stay plain
module-level integers, which numba compiles as constants;
:mod:`~ext_observer.core.ahrs.compiled` joins this file ahead of the
kernels, so the joined module computes the same offsets.
"""


class Layout:
    """
    The fields of one flat state, in order: ``name -> (offset, size)``.

    Parameters
    ----------
    start : int
        Offset of the first field (a block inside a larger state).

    """

    def __init__(self, start=0):
        self.fields = {}
        self.parameters = []
        self.size = start

    def field(self, name, size=1):
        """Append a field of ``size`` slots; its offset."""
        if name in self.fields:
            raise ValueError(f'field {name!r} declared twice')
        if size < 1:
            raise ValueError(f'field {name!r}: size must be at least 1, got {size}')
        offset = self.size
        self.fields[name] = (offset, size)
        self.size += size
        return offset

    def parameter(self, name):
        """Append a field set from the estimator's parameter ``name`` (same name); its offset."""
        self.parameters.append(name)
        return self.field(name)

    def offset(self, name):
        """The first slot of field ``name``."""
        return self.fields[name][0]

    def read(self, s, name):
        """Field ``name`` of state ``s``: a float, or a tuple of floats for a vector."""
        offset, size = self.fields[name]
        if size == 1:
            return float(s[offset])
        return tuple(float(s[offset + i]) for i in range(size))
