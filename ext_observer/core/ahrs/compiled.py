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
temporary folder where none of these can be written.

``EXT_OBSERVER_COMPILED`` chooses for the whole process: ``0`` plain, ``1``
compiled (an error without numba), unset or ``auto``: compiled where numba
imports.

A process that compiles holds a lock in the cache folder, so processes
started together compile once: the others wait, then load. A marker
(``<name>.ready``) says the cache holds every kernel a node calls. A node
waits for neither (:func:`start_plan`, :class:`BackgroundCompile`): it
starts on the plain kernels; a child process compiles where the cache is
not ready, a thread loads the compiled kernels, and the node goes on with
them from the same state (the estimates are the same to the bit).
"""

import ast
import fcntl
import hashlib
import importlib.util
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time

import numpy as np

__all__ = ['BackgroundCompile', 'CompiledUnavailable', 'Kernels', 'cache_ready',
           'compiled_available', 'kernels', 'plain_warning', 'start_plan',
           'warn_if_plain']

# In this order: each file's names are defined before the next one's functions use them.
_SOURCES = ('layout.py', 'magcal_layout.py', 'magcal_filter.py', 'magcal_kernel.py',
            'ahrs_kernel.py', 'uncertainty_kernel.py')
_ENV = 'EXT_OBSERVER_COMPILED'
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
        node's call per sample; compiled, the machine code of its one
        signature (float64 arrays and floats) called directly, without
        numba's dispatch on the arguments' types (half the cost of a call).
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
    if os.environ.get(_ENV, 'auto').strip().lower() not in ('', 'auto'):
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


def _wanted(compiled):
    if compiled is not None:
        return bool(compiled), bool(compiled)
    value = os.environ.get(_ENV, 'auto').strip().lower()
    if value in ('0', 'false', 'no', 'off'):
        return False, False
    if value in ('1', 'true', 'yes', 'on'):
        return True, True
    if value not in ('', 'auto'):
        raise ValueError(f'{_ENV} must be 0, 1 or auto, got {value!r}')
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
    want, required = _wanted(compiled)
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
    folder = os.path.dirname(os.path.abspath(__file__))
    parts, defined = [], {}
    for name in _SOURCES:
        with open(os.path.join(folder, name), encoding='utf-8') as f:
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
            definition = ast.unparse(node)
            for target in targets:
                if target.startswith('__'):
                    continue
                # The same constant in both files is harmless; anything else
                # is not (a call, such as a Layout(), made twice is two objects).
                if target in defined and (defined[target][1] != definition
                                          or any(isinstance(n, ast.Call)
                                                 for n in ast.walk(node))):
                    raise RuntimeError(f'{target} is defined in both {defined[target][0]} and '
                                       f'{name}: the kernels are joined into one module')
                defined[target] = (name, definition)
        kept = ['' if i in drop else line for i, line in enumerate(lines)]
        parts.append(f'# --- {name} ---\n' + '\n'.join(kept) + '\n')
    text = '\n'.join(parts)
    return text, hashlib.sha256(text.encode('utf-8')).hexdigest()


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


def _names():
    """The joined source's text, its module name and the cache folder."""
    text, digest = joined_source()
    return text, f'ext_observer_kernels_{digest[:16]}', cache_folder()


def cache_ready():
    """
    Whether the cache holds the compiled kernels a node calls (no compiling at start).

    False where numba's cache has not been filled by this version of the
    kernels (a first start, a changed kernel, an emptied cache folder).
    """
    try:
        _, name, folder = _names()
    except CompiledUnavailable:
        return False
    return os.path.exists(os.path.join(folder, name + '.ready'))


def _load_compiled():
    start = time.perf_counter()
    import numba
    text, name, folder = _names()
    path = os.path.join(folder, name + '.py')
    if not os.path.exists(path):
        partial = f'{path}.{os.getpid()}.tmp'
        with open(partial, 'w', encoding='utf-8') as f:
            f.write(text)
        os.replace(partial, path)  # atomic: processes starting together agree
    # One process compiles at a time: one that waited finds the cache filled
    # and loads from it.
    with open(os.path.join(folder, name + '.lock'), 'a') as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        spec = importlib.util.spec_from_file_location(name, path)
        module = importlib.util.module_from_spec(spec)
        sys.modules[name] = module
        spec.loader.exec_module(module)
        # Every function compiled before any runs, so that calls between them
        # resolve to the compiled ones.
        for key, value in list(vars(module).items()):
            if callable(value) and getattr(value, '__module__', None) == name \
                    and not isinstance(value, type):
                setattr(module, key, numba.njit(cache=True)(value))
        result = Kernels(module, module, True, uncertainty=module)
        _warm_up(result)
        result.sample_step = _entry_point(module.sample_step)
        ready = os.path.join(folder, name + '.ready')
        if not os.path.exists(ready):
            with open(ready, 'w', encoding='utf-8') as f:
                f.write(f'compiled by numba {numba.__version__} in '
                        f'{time.perf_counter() - start:.2f} s\n')
    result.load_seconds = time.perf_counter() - start
    return result


def _warm_up(k):
    """Compile (or load from the cache) what a node's estimator calls, now rather than mid-run."""
    from .estimator import AhrsObserver
    from .ahrs_params import AhrsParams
    from .uncertainty import AttitudeUncertainty
    global _COMPILED
    _COMPILED = k  # AhrsObserver(compiled=True) below asks for these
    try:
        est = AhrsObserver(AhrsParams(), compiled=True)
        dt = 0.01
        for i in range(40):
            a = 0.02 * i
            est.update((0.3, -0.2, 0.5), (0.1, 0.2, 9.8), (20.0 * np.cos(a), 20.0 * np.sin(a),
                                                           -40.0), dt)
        cal = est.calibration
        _ = (cal.quality, cal.bias, cal.soft_iron, cal.field, cal.state, cal.counts,
             cal.heading_turn((20.0, 0.0, -40.0), (0.0, 0.0, 1.0)))
        est.update_mag((20.0, 0.0, -40.0), 0.02)
        # The node's sample: the step, the guard and the covariance in one call.
        tracker = AttitudeUncertainty()
        tracker.use_kernels(k)
        tracker.start(dt)
        tracker.step(dt, (0.3, -0.2, 0.5), est.q, False)
        tracker.field(0.02, 0.1, 0.0, np.nan)
        _ = tracker.covariance
        k.uncertainty.sample_step(est._states[0], tracker.state, np.zeros(9), 0.3, -0.2, 0.5,
                                  0.1, 0.2, 9.8, dt, 0.1)
        est.reset()
        # The rest (the whole-recording loop, loading a calibration, the
        # single steps) compiles when first called: a node never calls it.
    finally:
        _COMPILED = None


def _entry_point(dispatcher):
    """
    The compiled code of a dispatcher's one signature, called without the dispatch.

    numba's dispatcher looks at every argument's type on every call to pick
    the compiled version; the kernels the node calls per sample have one
    (the warm-up's), so its entry point is called directly. The dispatcher
    itself where it has more than one, or where numba keeps it elsewhere.
    """
    try:
        (signature,) = dispatcher.signatures
        return dispatcher.overloads[signature].entry_point
    except (AttributeError, KeyError, TypeError, ValueError):
        return dispatcher


def start_plan():
    """
    How a node starts: ``'compiled'``, ``'plain'`` or ``'background'``.

    ``'compiled'``: this process has the compiled kernels already, or
    ``EXT_OBSERVER_COMPILED=1`` insists (they are loaded, or compiled, before
    the first sample); ``'plain'``: numba is not installed, or
    ``EXT_OBSERVER_COMPILED=0``; ``'background'``: start on the plain
    kernels at once and go on with the compiled ones when
    :class:`BackgroundCompile` has them (compiled in a child process where
    the cache is not ready, then loaded). numba is not imported here.
    """
    value = os.environ.get(_ENV, 'auto').strip().lower()
    if value not in ('', 'auto'):
        return 'compiled' if _wanted(None)[0] else 'plain'
    if _COMPILED is not None:
        return 'compiled'
    if importlib.util.find_spec('numba') is None:
        return 'plain'
    return 'background'


# The compiling child learns its parent from this variable (the node's pid).
_PARENT = 'EXT_OBSERVER_COMPILE_PARENT'


def _die_with_parent():
    """
    In the compiling child: end with the node that started it (also when it is killed).

    Returns False if that node is gone already.
    """
    parent = os.environ.get(_PARENT)
    if not parent:
        return True
    import ctypes
    try:
        ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass
    # Set after the fork: a parent that died in between is not signalled.
    return os.getppid() == int(parent)


class BackgroundCompile:
    """
    Get the compiled kernels without making the caller wait: compile, then load.

    Where the cache is not ready (:func:`cache_ready`), a child process,
    ``python -m ext_observer.core.ahrs.compiled``, compiles into it on another
    core, leaving this process's interpreter free. A thread then loads the
    compiled kernels from the cache (about a second, with the interpreter's
    switch interval shortened meanwhile so that the caller's callbacks keep
    running). :meth:`take` hands them over once, to the thread that runs the
    estimator.

    The child runs at nice 10 and ends with this process (``prctl``'s
    parent-death signal, set by the child itself), also when the process is
    killed; strictly, with the thread that created this object, so create it
    from the main thread.

    Attributes
    ----------
    compiling : bool
        Whether a child compiles (the cache was not ready).
    pid : int or None
        The child's process id.
    error : str or None
        Why the compiled kernels could not be had (the plain ones go on).
    seconds : float or None
        From the start to the kernels loaded here.
    """

    # Interpreter switch interval while loading, s (default 0.005).
    SWITCH_INTERVAL = 0.0005

    def __init__(self):
        self._start = time.monotonic()
        self.error = None
        self.seconds = None
        self._kernels = None
        self._taken = False
        self._stopped = threading.Event()
        self.compiling = not cache_ready()
        self._child = None
        self.pid = None
        if self.compiling:
            env = dict(os.environ, EXT_OBSERVER_COMPILED='1', **{_PARENT: str(os.getpid())})
            self._child = subprocess.Popen(
                [sys.executable, '-m', 'ext_observer.core.ahrs.compiled', '--quiet'], env=env,
                stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                start_new_session=True)
            self.pid = self._child.pid
            # Below the node in the scheduler's eyes: it must not slow the samples.
            try:
                os.setpriority(os.PRIO_PROCESS, self.pid, 10)
            except OSError:
                pass
        self._thread = threading.Thread(target=self._run, name='ext_observer-kernels',
                                        daemon=True)
        self._thread.start()

    def _run(self):
        if self._child is not None:
            _, err = self._child.communicate()
            if self._stopped.is_set():
                return
            if self._child.returncode != 0:
                lines = err.decode('utf-8', 'replace').strip().splitlines()
                self.error = (f'the compiler exited with {self._child.returncode}'
                              + (f': {lines[-1]}' if lines else ''))
                return
        previous = sys.getswitchinterval()
        sys.setswitchinterval(self.SWITCH_INTERVAL)
        try:
            k = kernels(True)
        except Exception as exc:  # numba missing or failing
            self.error = f'loading the compiled kernels failed: {exc}'
            return
        finally:
            sys.setswitchinterval(previous)
        self.seconds = time.monotonic() - self._start
        self._kernels = k

    @property
    def running(self):
        """Whether the child or the loading still runs."""
        return self._thread.is_alive()

    def take(self):
        """The compiled kernels, the first time they are asked for once ready; else None."""
        if self._kernels is None or self._taken:
            return None
        self._taken = True
        return self._kernels

    def stop(self, timeout=2.0):
        """End the child if it still runs; wait for the thread (at most ``timeout`` s)."""
        self._stopped.set()
        if self._child is not None and self._child.poll() is None:
            self._child.terminate()
            try:
                self._child.wait(timeout)
            except subprocess.TimeoutExpired:
                self._child.kill()
                self._child.wait()
        self._thread.join(timeout)


def main(argv=None):
    """
    ``python -m ext_observer.core.ahrs.compiled [--quiet]``: compile into the cache now.

    Prints how long it took (nothing with ``--quiet``); exits 1 with the
    reason when the kernels cannot be compiled.
    """
    argv = sys.argv[1:] if argv is None else argv
    if not _die_with_parent():
        return 1
    try:
        k = kernels(True)
    except CompiledUnavailable as error:
        print(error, file=sys.stderr)
        return 1
    if '--quiet' not in argv:
        print(f'compiled kernels ready in {k.load_seconds:.2f} s (cache: {cache_folder()})')
    return 0


if __name__ == '__main__':
    # The package's module, not this __main__ copy: one set of kernels.
    from ext_observer.core.ahrs import compiled
    sys.exit(compiled.main())
