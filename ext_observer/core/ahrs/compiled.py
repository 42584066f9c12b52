"""
The raw-IMU estimator's kernels, plain or compiled by numba: :func:`kernels`.

The estimator's steps are written once, in :mod:`~ext_observer.core.ahrs.ahrs_kernel`
and the calibration's kernel (:mod:`~ext_observer.core.ahrs.magcal_layout`,
:mod:`~ext_observer.core.ahrs.magcal_filter`, :mod:`~ext_observer.core.ahrs.magcal_kernel`),
in the part of Python that numba compiles. Without numba (an optional
dependency: ``pip install numba``) they run as they are, on a Python list of
floats. With it, this module joins the files' source into one module (the
imports between them dropped; a name defined differently in two is an
error), compiles every function of it with ``numba.njit(cache=True)`` and
runs them on a float64 array: the same source, compiled.

The joined source is written to a cache folder under a name made of its
hash, so numba's on-disk cache (beside it, in ``__pycache__``) always
belongs to the source it was compiled from: a changed kernel is a new file,
compiled afresh, and a process started later loads the compiled code
instead of compiling it again. The folder: ``$EXT_OBSERVER_CACHE``, else
``$XDG_CACHE_HOME/ext_observer``, else ``~/.cache/ext_observer``; a
temporary folder where none of these can be written. Each function is
compiled when first called; :mod:`ext_observer.pipeline.kernel_cache`
compiles what a node calls ahead of its samples.

``EXT_OBSERVER_COMPILED`` chooses for the whole process: ``0`` plain, ``1``
compiled (an error without numba), unset or ``auto``: compiled where numba
imports.
"""

import ast
import hashlib
import importlib.util
import os
import sys
import tempfile
import time

import numpy as np

__all__ = ['CompiledUnavailable', 'ENV', 'Kernels', 'PLAIN_COST', 'cache_folder',
           'compiled_available', 'compiled_name', 'entry_point', 'joined_source', 'kernels',
           'plain_warning', 'wanted', 'warn_if_plain']

# In this order: each file's names are defined before the next one's functions use them.
_SOURCES = ('layout.py', 'small_matrix.py',
            'magcal_layout.py', 'magcal_filter.py', 'magcal_kernel.py',
            'ahrs_layout.py', 'ahrs_filters.py', 'bias_kernel.py', 'clip_and_rest.py',
            'hole_kernel.py', 'velocity_kernel.py', 'accel_rejection.py', 'field_kernel.py',
            'gravity_kernel.py', 'ahrs_kernel.py', 'uncertainty_kernel.py')
ENV = 'EXT_OBSERVER_COMPILED'
# What running plain costs, measured (docs/compiled.md#without-numba): said
# once at start by imu_filter_node and the broad, csv and bag commands.
PLAIN_COST = ('numba cannot be imported: the estimator runs its plain kernels, about 30x '
              'slower per sample than compiled in 9D (58 µs against 2.0 µs; 6D 8x) and the '
              'BROAD command about 20x slower (48 s of CPU against 2.5 s on its 22 trials); '
              'pip install numba (requirements.txt has it; docs/compiled.md#without-numba)')


class CompiledUnavailable(RuntimeError):
    """The compiled kernels were asked for and cannot be had (numba missing or failing)."""


class Kernels:
    """
    One set of kernels.

    Attributes
    ----------
    ahrs, magcal, uncertainty : module
        The functions and layout constants of
        :mod:`~ext_observer.core.ahrs.ahrs_kernel`,
        :mod:`~ext_observer.core.ahrs.magcal_kernel` and
        :mod:`~ext_observer.core.ahrs.uncertainty_kernel` (one joined module when
        compiled).
    sample_step : callable
        :func:`~ext_observer.core.ahrs.uncertainty_kernel.sample_step`, the
        node's call per sample; once :func:`ext_observer.pipeline.kernel_cache.load`
        has compiled it, the machine code of its one signature (float64
        arrays and floats) called directly, without numba's dispatch on the
        arguments' types (half the cost of a call).
    compiled : bool
    load_seconds : float
        How long getting them took (compiling, or loading numba's cache).
    """

    def __init__(self, ahrs, magcal, compiled, load_seconds=0.0, uncertainty=None):
        self.ahrs = ahrs
        self.magcal = magcal
        self.uncertainty = uncertainty if uncertainty is not None else ahrs
        self.sample_step = self.uncertainty.sample_step
        self.compiled = compiled
        self.load_seconds = load_seconds

    def container(self, size):
        """A zeroed state of ``size`` slots: a float64 array compiled, a list plain."""
        return np.zeros(size) if self.compiled else [0.0] * size


_PLAIN = None
_COMPILED = None
_FAILURE = None


def _plain():
    global _PLAIN
    if _PLAIN is None:
        from . import ahrs_kernel, magcal_kernel, uncertainty_kernel
        _PLAIN = Kernels(ahrs_kernel, magcal_kernel, False, uncertainty=uncertainty_kernel)
    return _PLAIN


def compiled_available():
    """Whether numba imports (the compiled kernels can be had)."""
    try:
        import numba  # noqa: F401
    except Exception:  # ImportError, or a broken install
        return False
    return True


def plain_warning():
    """
    The one line to say at start where the plain kernels will run for want of numba; else None.

    None also where ``EXT_OBSERVER_COMPILED`` chooses (``0``: plain on
    purpose). numba is looked for, not imported.
    """
    if os.environ.get(ENV, 'auto').strip().lower() not in ('', 'auto'):
        return None
    try:
        if importlib.util.find_spec('numba') is not None:
            return None
    except (ImportError, ValueError):
        pass
    return PLAIN_COST


def warn_if_plain(stream=None):
    """A command's start: write :func:`plain_warning` to ``stream`` (stderr) if there is one."""
    warning = plain_warning()
    if warning:
        print(f'warning: {warning}', file=stream or sys.stderr, flush=True)


def wanted(compiled):
    """``(want compiled, required)`` for ``compiled`` (True, False or None: the environment)."""
    if compiled is not None:
        return bool(compiled), bool(compiled)
    value = os.environ.get(ENV, 'auto').strip().lower()
    if value in ('0', 'false', 'no', 'off'):
        return False, False
    if value in ('1', 'true', 'yes', 'on'):
        return True, True
    if value not in ('', 'auto'):
        raise ValueError(f'{ENV} must be 0, 1 or auto, got {value!r}')
    return compiled_available(), False


def kernels(compiled=None):
    """
    The kernels to run: compiled or plain.

    Parameters
    ----------
    compiled : bool, optional
        True: compiled (``CompiledUnavailable`` without numba); False:
        plain; None: as ``EXT_OBSERVER_COMPILED`` says (default: compiled
        where numba imports, else plain).

    Returns
    -------
    Kernels

    """
    global _COMPILED, _FAILURE
    want, required = wanted(compiled)
    if not want:
        return _plain()
    if _COMPILED is None and _FAILURE is None:
        try:
            _COMPILED = _load_compiled()
        except Exception as exc:  # numba missing, or it failed: say why when asked
            _FAILURE = exc
    if _COMPILED is not None:
        return _COMPILED
    if required:
        raise CompiledUnavailable(f'the compiled kernels are not available: {_FAILURE}') \
            from _FAILURE
    return _plain()


def joined_source():
    """The kernels' source as one module: ``(text, sha256 hex)``."""
    global _JOINED
    folder = os.path.dirname(os.path.abspath(__file__))
    paths = [os.path.join(folder, name) for name in _SOURCES]
    # Read once per process, unless a file changed since (its size or time).
    stamp = tuple((os.stat(p).st_mtime_ns, os.stat(p).st_size) for p in paths)
    if _JOINED is not None and _JOINED[0] == stamp:
        return _JOINED[1]
    parts, defined = [], {}
    for name, path in zip(_SOURCES, paths):
        with open(path, encoding='utf-8') as f:
            text = f.read()
        tree = ast.parse(text)
        lines = text.splitlines()
        drop = set()
        for node in tree.body:
            if isinstance(node, ast.ImportFrom) and node.level > 0:
                drop.update(range(node.lineno - 1, node.end_lineno))
                continue
            targets = []
            if isinstance(node, (ast.FunctionDef, ast.ClassDef)):
                targets = [node.name]
            elif isinstance(node, ast.Assign):
                targets = [t.id for t in node.targets if isinstance(t, ast.Name)]
            for target in targets:
                if target.startswith('__'):
                    continue
                # The same constant in both files is harmless; anything else
                # is not (a call, such as a Layout(), made twice is two objects).
                if target in defined and (ast.unparse(defined[target][1]) != ast.unparse(node)
                                          or any(isinstance(n, ast.Call)
                                                 for n in ast.walk(node))):
                    raise RuntimeError(f'{target} is defined in both {defined[target][0]} and '
                                       f'{name}: the kernels are joined into one module')
                defined[target] = (name, node)
        kept = ['' if i in drop else line for i, line in enumerate(lines)]
        parts.append(f'# --- {name} ---\n' + '\n'.join(kept) + '\n')
    text = '\n'.join(parts)
    joined = text, hashlib.sha256(text.encode('utf-8')).hexdigest()
    _JOINED = stamp, joined
    return joined


_JOINED = None


def cache_folder():
    """Where the joined source and numba's cache of it live (created if needed)."""
    candidates = []
    if os.environ.get('EXT_OBSERVER_CACHE'):
        candidates.append(os.environ['EXT_OBSERVER_CACHE'])
    base = os.environ.get('XDG_CACHE_HOME') or os.path.join(os.path.expanduser('~'), '.cache')
    candidates.append(os.path.join(base, 'ext_observer'))
    candidates.append(os.path.join(tempfile.gettempdir(), f'ext_observer-{os.getuid()}'))
    for folder in candidates:
        try:
            os.makedirs(folder, exist_ok=True)
            probe = os.path.join(folder, f'.probe-{os.getpid()}')
            with open(probe, 'w', encoding='utf-8'):
                pass
            os.remove(probe)
            return folder
        except OSError:
            continue
    raise CompiledUnavailable(f'no writable cache folder among {candidates}')


def compiled_name():
    """The joined module's name (after its hash) and the cache folder."""
    _, digest = joined_source()
    return f'ext_observer_kernels_{digest[:16]}', cache_folder()


def _load_compiled():
    start = time.perf_counter()
    import numba
    text, _ = joined_source()
    name, folder = compiled_name()
    path = os.path.join(folder, name + '.py')
    if not os.path.exists(path):
        partial = f'{path}.{os.getpid()}.tmp'
        with open(partial, 'w', encoding='utf-8') as f:
            f.write(text)
        os.replace(partial, path)  # atomic: processes starting together agree
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    # Every function wrapped before any runs, so that calls between them
    # resolve to the compiled ones.
    for key, value in list(vars(module).items()):
        if callable(value) and getattr(value, '__module__', None) == name \
                and not isinstance(value, type):
            setattr(module, key, numba.njit(cache=True)(value))
    return Kernels(module, module, True, load_seconds=time.perf_counter() - start,
                   uncertainty=module)


def entry_point(dispatcher):
    """
    The compiled code of a dispatcher's one signature, called without the dispatch.

    numba's dispatcher looks at every argument's type on every call to pick
    the compiled version; the kernels the node calls per sample have one
    (compiled by :func:`ext_observer.pipeline.kernel_cache.load`), so its
    entry point is called directly. The dispatcher
    itself where it has more than one, or where numba keeps it elsewhere.
    """
    try:
        (signature,) = dispatcher.signatures
        return dispatcher.overloads[signature].entry_point
    except (AttributeError, KeyError, TypeError, ValueError):
        return dispatcher
