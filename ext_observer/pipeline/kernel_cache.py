"""
The compiled kernels for a node: filled once on disk, loaded without waiting.

:mod:`~ext_observer.core.ahrs.compiled` compiles the kernels (numba,
``cache=True``) as they are first called. A node wants them compiled
before its samples depend on them, and not to wait for that: :func:`load`
calls everything a node's estimator calls (compiling it, or loading it from
numba's on-disk cache), then marks the cache ready (``<name>.ready``);
processes started together compile once (a lock in the cache folder, the
others wait, then load). :class:`BackgroundCompile` does it in a child
process where the cache is not ready, while the node runs the plain
kernels, and hands the compiled ones over (the estimates are the same to
the bit). ``python -m ext_observer.pipeline.kernel_cache`` fills the cache
ahead of a first start.
"""

import fcntl
import importlib.util
import os
import signal
import subprocess
import sys
import threading
import time

import numpy as np

from ext_observer.core.ahrs import compiled
from ext_observer.core.ahrs.ahrs_params import AhrsParams
from ext_observer.core.ahrs.ahrs_observer import AhrsObserver
from ext_observer.core.ahrs.uncertainty import AttitudeUncertainty

__all__ = ['BackgroundCompile', 'cache_ready', 'load', 'main', 'preload', 'start_plan']

_LOADED = None


def _paths():
    """The lock and the ready marker of this version of the kernels."""
    name, folder = compiled.compiled_name()
    return os.path.join(folder, name + '.lock'), os.path.join(folder, name + '.ready')


def cache_ready():
    """
    Whether the cache holds the compiled kernels a node calls (no compiling at start).

    False where numba's cache has not been filled by this version of the
    kernels (a first start, a changed kernel, an emptied cache folder).
    """
    try:
        return os.path.exists(_paths()[1])
    except compiled.CompiledUnavailable:
        return False


def load(stopped=None):
    """
    The compiled kernels, everything a node calls compiled (or loaded from the cache).

    With ``stopped`` (a ``threading.Event``), returns None if it is set
    while another process holds the cache's lock. Raises
    ``CompiledUnavailable`` without numba.
    """
    global _LOADED
    if _LOADED is not None:
        return _LOADED
    start = time.perf_counter()
    lock_path, ready = _paths()
    # One process compiles at a time: one that waited finds the cache filled
    # and loads from it.
    with open(lock_path, 'a') as lock:
        if not _lock(lock, stopped):
            return None
        k = compiled.kernels(True)
        _warm_up(k)
        k.sample_step = compiled.entry_point(k.uncertainty.sample_step)
        if not os.path.exists(ready):
            import numba
            with open(ready, 'w', encoding='utf-8') as f:
                f.write(f'compiled by numba {numba.__version__} in '
                        f'{time.perf_counter() - start:.2f} s\n')
    k.load_seconds = time.perf_counter() - start
    _LOADED = k
    return k


def _lock(lock, stopped):
    """Take the cache's lock; with ``stopped``, give up (False) once it is set."""
    if stopped is None:
        fcntl.flock(lock, fcntl.LOCK_EX)
        return True
    while True:
        try:
            fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
            return True
        except BlockingIOError:
            if stopped.wait(0.05):
                return False


def preload(node=True):
    """
    The kernels this process will run (``EXT_OBSERVER_COMPILED``), compiled ones ready now.

    :func:`load` where the compiled kernels are wanted (with ``node``
    false, only what :func:`~ext_observer.pipeline.batch.estimate_batch`
    calls: the broad command's whole recordings, without the node's
    per-sample kernels); the plain ones where they are not, or where numba
    fails and they are not required.
    """
    want, required = compiled.wanted(None)
    if want:
        try:
            if not node:
                k = compiled.kernels(True)
                AhrsObserver(AhrsParams(), use_mag=False, compiled=True).run(
                    np.zeros((1, 3)), np.array([[0.0, 0.0, 9.8]]), None, 0.01)
                return k
            return load()
        except Exception:  # numba missing or failing: as kernels() falls back
            if required:
                raise
    return compiled.kernels()


def _warm_up(k):
    """Call what a node's estimator calls, so that it is compiled now rather than mid-run."""
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
    k.uncertainty.sample_step(est.state, tracker.state, np.zeros(9), 0.3, -0.2, 0.5,
                              0.1, 0.2, 9.8, dt, 0.1)
    est.reset()
    # The rest (the whole-recording loop, loading a calibration, the single
    # steps) compiles when first called: a node never calls it.


def start_plan():
    """
    How a node starts: ``'compiled'``, ``'plain'`` or ``'background'``.

    ``'compiled'``: this process has the compiled kernels already, or
    ``EXT_OBSERVER_COMPILED=1`` insists (:func:`load` before the first
    sample); ``'plain'``: numba is not installed, or
    ``EXT_OBSERVER_COMPILED=0``; ``'background'``: start on the plain
    kernels at once and go on with the compiled ones when
    :class:`BackgroundCompile` has them. numba is not imported here.
    """
    value = os.environ.get(compiled.ENV, 'auto').strip().lower()
    if value not in ('', 'auto'):
        return 'compiled' if compiled.wanted(None)[0] else 'plain'
    if _LOADED is not None:
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
    ``python -m ext_observer.pipeline.kernel_cache``, compiles into it on
    another core, leaving this process's interpreter free. A thread then
    loads the compiled kernels from the cache (about a second, with the
    interpreter's switch interval shortened meanwhile so that the caller's
    callbacks keep running). :meth:`take` hands them over once, to the
    thread that runs the estimator.

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
            env = dict(os.environ, **{compiled.ENV: '1', _PARENT: str(os.getpid())})
            self._child = subprocess.Popen(
                [sys.executable, '-m', 'ext_observer.pipeline.kernel_cache', '--quiet'],
                env=env, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                stderr=subprocess.PIPE, start_new_session=True)
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
        # Neither importing numba (llvmlite loading its library) nor loading
        # the kernels can be interrupted: stop() waits for them, and each
        # starts only if the node is not ending.
        try:
            importlib.import_module('numba')
        except ImportError:
            pass    # load() says why
        if self._stopped.is_set():
            return
        previous = sys.getswitchinterval()
        sys.setswitchinterval(self.SWITCH_INTERVAL)
        try:
            k = load(self._stopped)
        except Exception as exc:  # numba missing or failing
            self.error = f'loading the compiled kernels failed: {exc}'
            return
        finally:
            sys.setswitchinterval(previous)
        if k is None:
            return
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

    def stop(self, timeout=60.0):
        """
        End the child if it still runs; wait for the thread (at most ``timeout`` s).

        Returns whether the thread has ended. The wait covers an import of
        numba and a load from the cache on a loaded machine (seconds): a
        process that exits while this thread is inside either can abort.
        """
        self._stopped.set()
        if self._child is not None and self._child.poll() is None:
            self._child.terminate()
            try:
                self._child.wait(5.0)
            except subprocess.TimeoutExpired:
                self._child.kill()
                self._child.wait()
        self._thread.join(timeout)
        return not self._thread.is_alive()


def main(argv=None):
    """
    ``python -m ext_observer.pipeline.kernel_cache [--quiet]``: fill the cache now.

    Prints how long it took (nothing with ``--quiet``); exits 1 with the
    reason when the kernels cannot be compiled.
    """
    argv = sys.argv[1:] if argv is None else argv
    if not _die_with_parent():
        return 1
    try:
        k = load()
    except compiled.CompiledUnavailable as error:
        print(error, file=sys.stderr)
        return 1
    if '--quiet' not in argv:
        print(f'compiled kernels ready in {k.load_seconds:.2f} s '
              f'(cache: {compiled.cache_folder()})')
    return 0


if __name__ == '__main__':
    # The package's module, not this __main__ copy: one set of kernels.
    from ext_observer.pipeline import kernel_cache
    sys.exit(kernel_cache.main())
