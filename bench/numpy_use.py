"""
Which functions of a run use numpy, and how often: the hot-path check.

A call of a function *uses numpy* when, during that call, the function's
own code

- calls into numpy: a function of numpy's own modules (``np.linalg.norm``,
  ``np.ones``) or a C function or method of numpy (``np.asarray``,
  ``ndarray.sum``, ``ufunc.reduce``); or
- holds a numpy object (an array or a numpy scalar) as an argument, a local
  or its return value when it returns. This catches what a profiler does not
  report as a call: a ufunc called directly (``np.sqrt(a)``) and an
  operator on arrays (``a * 2.0``) take or make arrays.

The function is what counts, never its module: ``core/quaternion.py`` has
float functions (``multiply_floats``) beside numpy ones (``normalize``).
Calls inside numpy are numpy's own; only the frame that calls into numpy
from outside is named. C code that calls numpy without going through Python
(an extension converting a message) is not seen.
"""

import os
import sys
import types

__all__ = ['is_numpy_object', 'numpy_use', 'numpy_use_per_step']

_NUMPY_DIR = os.sep + 'numpy' + os.sep


def _numpy_name(name):
    return (name or '').partition('.')[0] == 'numpy'


def is_numpy_object(value):
    """Return whether ``value`` is an instance of a numpy type (array, scalar, ufunc)."""
    return _numpy_name(getattr(type(value), '__module__', ''))


def _is_numpy_c_function(function):
    if _numpy_name(getattr(function, '__module__', None)):
        return True
    owner = getattr(function, '__self__', None)
    if isinstance(owner, types.ModuleType):
        return _numpy_name(owner.__name__)
    return owner is not None and is_numpy_object(owner)


def _in_numpy(code):
    return _NUMPY_DIR in code.co_filename


def _label(code):
    return f'{os.path.basename(code.co_filename)}:{code.co_name}'


class _Tracer:
    """A ``sys.setprofile`` hook that counts the calls that use numpy."""

    def __init__(self, harness=None):
        self.uses = {}  # label → {'calls': int, 'numpy': set of str}
        self._using = {}  # id(frame) → label, for the frames alive now
        self._harness = harness

    def _note(self, frame, what):
        if frame.f_code is self._harness:
            return
        label = _label(frame.f_code)
        self._using[id(frame)] = label
        self.uses.setdefault(label, {'calls': 0, 'numpy': set()})['numpy'].add(what)

    def __call__(self, frame, event, arg):
        if event == 'c_call':
            if not _in_numpy(frame.f_code) and _is_numpy_c_function(arg):
                self._note(frame, f'numpy {getattr(arg, "__qualname__", repr(arg))}')
        elif event == 'call':
            caller = frame.f_back
            if (caller is not None and _in_numpy(frame.f_code)
                    and not _in_numpy(caller.f_code)):
                name = frame.f_code.co_name
                if not name.endswith('_dispatcher'):  # numpy's __array_function__ hook
                    module = frame.f_globals.get('__name__', 'numpy')
                    self._note(caller, f'{module}.{name}')
        elif event == 'return' and not _in_numpy(frame.f_code):
            held = [v for v in (arg, *frame.f_locals.values()) if is_numpy_object(v)]
            if held:
                self._note(frame, f'holds {type(held[0]).__name__}')
            label = self._using.pop(id(frame), None)
            if label is not None:
                self.uses[label]['calls'] += 1


def _trace(function, args, kwargs, harness=None):
    tracer = _Tracer(harness)
    previous = sys.getprofile()
    sys.setprofile(tracer)
    try:
        result = function(*args, **kwargs)
    finally:
        sys.setprofile(previous)
    uses = {label: {'calls': entry['calls'], 'numpy': sorted(entry['numpy'])}
            for label, entry in tracer.uses.items() if entry['calls']}
    return uses, result


def numpy_use(function, *args, **kwargs):
    """
    Run ``function(*args, **kwargs)`` and return the calls that used numpy.

    Returns
    -------
    uses : dict
        ``{'file.py:function': {'calls': n, 'numpy': [what, ...]}}``: how
        many calls of each function used numpy, and what they called or held
        (``numpy asarray``, ``numpy.linalg._linalg.norm``, ``holds ndarray``).
        Empty when nothing did.
    result
        What ``function`` returned.

    """
    return _trace(function, args, kwargs)


def numpy_use_per_step(steps, loop, *args):
    """
    Run ``loop(*args)``, which runs ``steps`` steps, and return what used numpy per step.

    ``loop``'s own frame (the harness that feeds the steps) is not counted.

    Returns
    -------
    dict
        ``{'file.py:function': {'per_step': float, 'numpy': [what, ...]}}``;
        empty when no function used numpy.

    """
    uses, _ = _trace(loop, args, {}, harness=loop.__code__)
    return {label: {'per_step': entry['calls'] / steps, 'numpy': entry['numpy']}
            for label, entry in uses.items()}
