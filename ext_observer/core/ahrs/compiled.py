"""
The raw-IMU estimator's kernels, plain or compiled by numba: :func:`kernels`.

The estimator's steps are written once, in the kernel files of this folder
(:data:`KERNEL_SOURCES`), in the part of Python that numba compiles.
Without numba (``pip install numba``; requirements.txt has it) they run as
they are, on plain records (:mod:`~ext_observer.core.ahrs.record`). With it,
this module imports the same files a second time as the modules of a
package of their own (``ext_observer.core._kernels_<hash>``: each module
keeps its own names, private ones too), compiles every function of them with
``numba.njit(cache=True)`` and binds every name of a kernel function to the
compiled one: the same source, compiled, on structured records.

numba's on-disk cache lives in a folder named after the hash of all the
kernel files (:func:`source_digest`), so that it always belongs to the
source it was compiled from: a changed kernel is a new folder, compiled
afresh, and a process started later loads the compiled code instead of
compiling it again. The folder: ``$EXT_OBSERVER_CACHE``, else
``$XDG_CACHE_HOME/ext_observer``, else ``~/.cache/ext_observer``; a
temporary folder where none of these can be written. Each function is
compiled when first called; :mod:`ext_observer.pipeline.kernel_cache`
compiles what a node calls ahead of its samples.

``EXT_OBSERVER_COMPILED`` chooses for the whole process: ``0`` plain, ``1``
compiled (an error without numba), unset or ``auto``: compiled where numba
imports.
"""

import hashlib
import importlib
import importlib.util
import os
import sys
import tempfile
import time
import types

__all__ = ['CompiledUnavailable', 'ENV', 'KERNEL_SOURCES', 'Kernels', 'PLAIN_COST',
           'cache_folder', 'compiled_available', 'compiled_name', 'entry_point', 'kernel_paths',
           'kernels', 'plain_warning', 'source_digest', 'wanted', 'warn_if_plain']

# The files of the kernels: every function of them is compiled.
KERNEL_SOURCES = ('small_matrix.py',
            'magcal_layout.py', 'magcal_filter.py', 'magcal_kernel.py',
            'ahrs_filters.py', 'bias_kernel.py', 'clip_and_rest.py',
            'hole_kernel.py', 'velocity_kernel.py', 'accel_rejection.py', 'field_references.py',
            'field_kernel.py',
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


# The kernel modules a wrapper calls, by their short names (ahrs: ahrs_kernel.py).
_WRAPPED = ('ahrs', 'magcal', 'uncertainty')


class Kernels:
    """
    One set of kernels.

    Attributes
    ----------
    ahrs, magcal, uncertainty : module
        The kernel modules the wrappers call (their ``*_in`` functions, on
        holders): :mod:`~ext_observer.core.ahrs.ahrs_kernel`,
        :mod:`~ext_observer.core.ahrs.magcal_kernel` and
        :mod:`~ext_observer.core.ahrs.uncertainty_kernel` (their compiled
        twins when compiled).
    sample_step : callable
        :func:`~ext_observer.core.ahrs.uncertainty_kernel.sample_step`, the
        node's call per sample; once :func:`ext_observer.pipeline.kernel_cache.load`
        has compiled it, the machine code of its one signature (the two
        holders, the covariance array and floats) called directly, without
        numba's dispatch on the arguments' types (half the cost of a call).
    compiled : bool
    load_seconds : float
        How long getting them took (compiling, or loading numba's cache).
    """

    def __init__(self, modules, compiled, load_seconds=0.0):
        for name in _WRAPPED:
            setattr(self, name, modules[f'{name}_kernel'])
        self.sample_step = self.uncertainty.sample_step
        self.compiled = compiled
        self.load_seconds = load_seconds


_PLAIN = None
_COMPILED = None
_FAILURE = None


def _plain():
    global _PLAIN
    if _PLAIN is None:
        _PLAIN = Kernels({f'{name}_kernel': importlib.import_module(f'{__package__}.{name}_kernel')
                          for name in _WRAPPED}, False)
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


def kernel_paths():
    """The kernel files, in :data:`KERNEL_SOURCES`'s order: their full paths."""
    folder = os.path.dirname(os.path.abspath(__file__))
    return [os.path.join(folder, name) for name in KERNEL_SOURCES]


def source_digest():
    """The sha256 (hex) of the kernel files' text, in order: the compiled kernels' version."""
    global _DIGEST
    paths = kernel_paths()
    # Read once per process, unless a file changed since (its size or time).
    stamp = tuple((os.stat(p).st_mtime_ns, os.stat(p).st_size) for p in paths)
    if _DIGEST is not None and _DIGEST[0] == stamp:
        return _DIGEST[1]
    digest = hashlib.sha256()
    for name, path in zip(KERNEL_SOURCES, paths):
        with open(path, 'rb') as f:
            digest.update(name.encode() + b'\0' + f.read() + b'\0')
    _DIGEST = stamp, digest.hexdigest()
    return _DIGEST[1]


_DIGEST = None


def cache_folder():
    """Where numba's cache of the kernels lives (created if needed)."""
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
    """The compiled kernels' package name (after the sources' hash) and the cache folder."""
    return f'_kernels_{source_digest()[:16]}', cache_folder()


def _load_compiled():
    start = time.perf_counter()
    import numba
    name, folder = compiled_name()
    # The kernel files imported a second time, as modules of a package of
    # their own beside this one: each keeps its own names, as the plain
    # modules do, and their imports of each other resolve to the twins.
    package_name = f'{__package__.rpartition(".")[0]}.{name}'
    package = types.ModuleType(package_name)
    package.__path__ = [os.path.dirname(os.path.abspath(__file__))]
    package.__package__ = package_name
    sys.modules[package_name] = package
    modules = [importlib.import_module(f'{package_name}.{source[:-3]}')
               for source in KERNEL_SOURCES]
    # numba's cache of each function is keyed by its file alone: a folder of
    # this version of all the files keeps a caller compiled against an
    # older callee from being loaded.
    saved = numba.config.CACHE_DIR
    numba.config.CACHE_DIR = os.path.join(folder, name)
    try:
        compiled = {}
        for module in modules:
            for key, value in list(vars(module).items()):
                if isinstance(value, types.FunctionType) and value.__module__ == module.__name__:
                    compiled[value] = numba.njit(cache=True)(value)
                    setattr(module, key, compiled[value])
    finally:
        numba.config.CACHE_DIR = saved
    # Every name bound to a kernel function, in any twin, now calls the
    # compiled one: resolved when a caller is first compiled.
    for module in modules:
        for key, value in list(vars(module).items()):
            if isinstance(value, types.FunctionType) and value in compiled:
                setattr(module, key, compiled[value])
    by_name = {m.__name__.rpartition('.')[2]: m for m in modules}
    return Kernels(by_name, True, load_seconds=time.perf_counter() - start)


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
