"""
A state with names: groups of named fields, declared beside the code that owns them.

A :class:`Group` lists its fields, one line each (name, unit, meaning,
size), and may hold other groups: the estimator's state is a group of
groups (``s.rest.time``, ``s.bias.p[3]``). Every field is a float64 (a
flag is 0.0 or 1.0), so the one source of the kernels runs on two
containers of the same names:

- plain Python: an object of a class made from the group (``__slots__``,
  floats, lists of floats for vectors, an object per sub-group), whose
  fields may also hold numpy arrays ``(B,)`` (many recordings at once);
- compiled by numba: a record of the group's structured ``numpy.dtype``,
  read and written at fixed offsets (docs/layout.md says why and what it
  costs).

What the wrappers hold is a *holder*: a one-element structured array
(compiled) or a one-element list (plain); ``holder[0]`` is the record.
numba takes a one-element array from Python ten times faster than a
record, so the kernels that Python calls per sample take a holder.
"""

import ctypes

import numpy as np

__all__ = ['Group', 'holder_of']


class Group:
    """
    Named float64 fields and sub-groups, in order.

    Parameters
    ----------
    name : str
        The group's attribute in the group that holds it.
    doc : str
        What the group is (one line).
    members : list
        Fields ``(name, unit, meaning)`` or ``(name, unit, meaning, size)``,
        and sub-groups (:class:`Group`).

    """

    def __init__(self, name, doc, members):
        self.name = name
        self.doc = doc
        self.members = []
        seen = set()
        for member in members:
            if isinstance(member, Group):
                entry = member
            else:
                field_name, unit, meaning, *size = member
                size = size[0] if size else 1
                if size < 1:
                    raise ValueError(f'{name}.{field_name}: size must be at least 1, got {size}')
                entry = (field_name, unit, meaning, size)
            key = entry.name if isinstance(entry, Group) else entry[0]
            if key in seen:
                raise ValueError(f'{name}: member {key!r} declared twice')
            seen.add(key)
            self.members.append(entry)
        self._plain_class = None
        self._dtype = None
        self._paths = None
        self._offsets = None
        self._ctypes_class = None

    def __getstate__(self):
        # The made class and the caches are made again where unpickled.
        state = self.__dict__.copy()
        state['_plain_class'] = state['_dtype'] = state['_paths'] = state['_offsets'] = None
        state['_ctypes_class'] = None
        return state

    # --- the two containers -----------------------------------------------------

    @property
    def dtype(self):
        """The structured dtype (nested, float64 fields) of the compiled container."""
        if self._dtype is None:
            parts = []
            for m in self.members:
                if isinstance(m, Group):
                    parts.append((m.name, m.dtype))
                elif m[3] == 1:
                    parts.append((m[0], np.float64))
                else:
                    parts.append((m[0], np.float64, (m[3],)))
            self._dtype = np.dtype(parts)
        return self._dtype

    @property
    def size(self):
        """The number of floats in the group."""
        return self.dtype.itemsize // 8

    def plain(self):
        """A zeroed plain record (the class is made once)."""
        if self._plain_class is None:
            self._plain_class = _plain_class(self)
        return self._plain_class()

    def holder(self, compiled):
        """A zeroed holder: a one-element structured array (compiled) or ``[plain record]``."""
        if compiled:
            return np.zeros(1, self.dtype)
        return [self.plain()]

    # --- names --------------------------------------------------------------------

    def fields(self, prefix=()):
        """Every field as ``(path, unit, meaning, size)``, ``path`` a tuple of names."""
        out = []
        for m in self.members:
            if isinstance(m, Group):
                out.extend(m.fields(prefix + (m.name,)))
            else:
                out.append((prefix + (m[0],), m[1], m[2], m[3]))
        return out

    def path(self, name):
        """The path of field ``name`` (``'rest.time'`` or a name unique in the group)."""
        if self._paths is None:
            paths = {}
            for path, _, _, size in self.fields():
                paths['.'.join(path)] = (path, size)
            short = {}
            for path, _, _, size in self.fields():
                short.setdefault(path[-1], []).append((path, size))
            for key, found in short.items():
                if len(found) == 1 and key not in paths:
                    paths[key] = found[0]
            self._paths = paths
        try:
            return self._paths[name]
        except KeyError:
            raise KeyError(f'{self.name} has no field {name!r}') from None

    def offset(self, name):
        """Where field ``name`` starts among the group's floats (its first, for a vector)."""
        found = self._offsets.get(name) if self._offsets is not None else None
        if found is not None:
            return found
        path, _ = self.path(name)
        dtype, at = self.dtype, 0
        for n in path:
            sub, byte = dtype.fields[n][:2]
            dtype, at = sub, at + byte
        if self._offsets is None:
            self._offsets = {}
        self._offsets[name] = at // 8
        return at // 8

    def view(self, holder):
        """
        A holder's record, read and written by attribute from Python (``v.rest.time``).

        Plain, the record itself. Compiled, a ``ctypes`` structure per group
        over the holder's memory (sub-groups as attributes): its fields read
        and written as Python floats by C code, several times faster than
        numpy's access to a structured record's fields by name. Made once per
        holder by the code that keeps one: for Python that reads the state
        at every sample (the kernels take the holder itself).
        """
        if isinstance(holder, np.ndarray):
            return _ctypes_view(self, holder, 0)
        return holder[0]

    def get(self, record, name):
        """Field ``name`` of a record: a float (a vector: a tuple of floats)."""
        path, size = self.path(name)
        value = _walk(record, path[:-1])
        value = _item(value, path[-1])
        if size == 1:
            return value if np.ndim(value) else float(value)
        return tuple(float(v) for v in value)

    def set(self, record, name, value):
        """Set field ``name`` of a record (a vector from a sequence of its size)."""
        path, size = self.path(name)
        parent = _walk(record, path[:-1])
        if size == 1:
            _set_item(parent, path[-1], value)
            return
        if len(value) != size:
            raise ValueError(f'{name} has {size} values, got {len(value)}')
        target = _item(parent, path[-1])
        for i in range(size):
            target[i] = float(value[i])

    def flat(self, record):
        """The record's values in declaration order, a list of floats."""
        if isinstance(record, np.void):
            return _flat_void(record)
        values = []
        for m in self.members:
            if isinstance(m, Group):
                values.extend(m.flat(getattr(record, m.name)))
            elif m[3] == 1:
                values.append(float(getattr(record, m[0])))
            else:
                values.extend(float(v) for v in getattr(record, m[0]))
        return values

    def load(self, record, values, start=0):
        """Write ``values`` (declaration order) into ``record``; the index after them."""
        i = start
        for m in self.members:
            if isinstance(m, Group):
                i = m.load(_item(record, m.name), values, i)
            elif m[3] == 1:
                _set_item(record, m[0], float(values[i]))
                i += 1
            else:
                target = _item(record, m[0])
                for k in range(m[3]):
                    target[k] = float(values[i + k])
                i += m[3]
        return i

    def copy(self, source, target):
        """Copy a record into another (plain or compiled, either way)."""
        self.load(target, self.flat(source))


def holder_of(holder, name):
    """The holder of sub-group ``name`` of a holder's record (a view, not a copy)."""
    if isinstance(holder, np.ndarray):
        return holder[name]
    return [getattr(holder[0], name)]


def _ctypes_view(group, holder, offset):
    """The ``ctypes`` structure of ``group`` at byte ``offset`` of ``holder``, sub-groups too."""
    cls = group._ctypes_class
    if cls is None:
        # The group's fields; a sub-group's span is padding here, its own
        # structure an attribute.
        fields = [(f'_{m.name}_span', ctypes.c_double * m.size) if isinstance(m, Group)
                  else (m[0], ctypes.c_double if m[3] == 1 else ctypes.c_double * m[3])
                  for m in group.members]
        cls = group._ctypes_class = type(f'{group.name}_view', (ctypes.Structure,),
                                         {'_fields_': fields})
    view = cls.from_buffer(holder, offset)
    for m in group.members:
        if isinstance(m, Group):
            setattr(view, m.name, _ctypes_view(m, holder, offset + group.dtype.fields[m.name][1]))
    return view


def _flat_void(record):
    values = []

    def walk(v):
        if v.dtype.names is None:
            values.extend(float(x) for x in np.ravel(v))
            return
        for n in v.dtype.names:
            walk(v[n])

    walk(record)
    return values


def _walk(record, names):
    for n in names:
        record = _item(record, n)
    return record


def _item(record, name):
    if isinstance(record, np.void):
        return record[name]
    return getattr(record, name)


def _set_item(record, name, value):
    if isinstance(record, np.void):
        record[name] = value
    else:
        setattr(record, name, value)


def _plain_class(group):
    """A class with a slot per member: floats, lists of floats, sub-group objects."""
    names = tuple(m.name if isinstance(m, Group) else m[0] for m in group.members)
    members = group.members

    def __init__(self):
        for m in members:
            if isinstance(m, Group):
                setattr(self, m.name, m.plain())
            elif m[3] == 1:
                setattr(self, m[0], 0.0)
            else:
                setattr(self, m[0], [0.0] * m[3])

    def __reduce__(self):
        return _rebuild, (group, group.flat(self))

    def __repr__(self):
        return f'<{group.name}: {", ".join(f"{n}={getattr(self, n)!r}" for n in names)}>'

    return type(f'{group.name}_record', (), {'__slots__': names, '__init__': __init__,
                                             '__reduce__': __reduce__, '__repr__': __repr__})


def _rebuild(group, values):
    record = group.plain()
    group.load(record, values)
    return record
