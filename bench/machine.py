"""The machine and software a benchmark ran on, and where its progress, results and page go."""

import datetime
import json
import os
import platform
import signal
import subprocess
import sys
import time
from importlib import metadata

from bench.procs import REPO


def _version(*distributions):
    for name in distributions:
        try:
            return metadata.version(name)
        except metadata.PackageNotFoundError:
            continue
    return 'not installed'


def _cpu_model():
    try:
        with open('/proc/cpuinfo') as cpuinfo:
            for line in cpuinfo:
                if line.startswith('model name'):
                    return line.split(':', 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or 'unknown'


def _commit():
    try:
        done = subprocess.run(['git', 'rev-parse', '--short', 'HEAD'], cwd=REPO,
                              capture_output=True, text=True, timeout=10)
    except (OSError, subprocess.TimeoutExpired):
        return 'unknown'
    return done.stdout.strip() or 'unknown'


def describe():
    """Return the facts shown at the top of the report, as a dict."""
    import numpy
    return {
        'date': datetime.datetime.now(datetime.timezone.utc).strftime(
            '%Y-%m-%d %H:%M UTC'),
        'cores': os.cpu_count(),
        'cpu': _cpu_model(),
        'python': platform.python_version(),
        'numpy': numpy.__version__,
        'rclpy': _version('ros-jazzy-rclpy', 'ros-rclpy', 'rclpy'),
        'rmw': os.environ.get('RMW_IMPLEMENTATION',
                              'rmw_fastrtps_cpp (default)'),
        'rmw_fastrtps_cpp': _version('ros-jazzy-rmw-fastrtps-cpp',
                                     'ros-rmw-fastrtps-cpp'),
        'commit': _commit(),
        'load_start': load(),
    }


def load():
    """The 1-minute load average (other work on the machine skews timings)."""
    try:
        return round(os.getloadavg()[0], 2)
    except OSError:
        return None


def load_range(runs):
    """The lowest and highest 1-minute load average seen around ``runs``, as text."""
    seen = [x for run in runs for x in run.get('load') or () if x is not None]
    if not seen:
        return 'unknown'
    low, high = min(seen), max(seen)
    return f'{low:g}' if low == high else f'{low:g}–{high:g}'


def log(text):
    """A benchmark's progress: one line on stderr (its figures and page go to stdout)."""
    print(text, file=sys.stderr, flush=True)


def save_json(path, result):
    """Write a benchmark's results to ``path`` (``--json``); nothing without a path."""
    if path:
        with open(path, 'w') as out:
            json.dump(result, out, indent=1)


def add_page_arguments(parser, page=None):
    """
    The options of a benchmark that writes a page: ``--json``, ``--render``.

    With ``page`` (its name in docs/), also ``--output`` (default
    ``docs/<page>``) and ``--no-write``; :func:`page_path` reads them.
    """
    if page:
        parser.add_argument('--output', default=os.path.join(REPO, 'docs', page),
                            help=f'Markdown file to write (default docs/{page})')
        parser.add_argument('--no-write', action='store_true', help='print only, write no file')
    parser.add_argument('--json', metavar='PATH', help='also write the raw results')
    parser.add_argument('--render', metavar='JSON', help='only render results saved by --json')


def page_path(args):
    """Where ``--output`` and ``--no-write`` say the page goes (None: nowhere)."""
    return None if args.no_write else args.output


def page_main(args, command, run, render, path):
    """
    A benchmark that writes a page: its results, then the page (``render(results)``) at ``path``.

    The results are ``run()``'s with the machine, ``command`` and the
    ``seconds`` it took, or ``--render``'s file; ``--json`` saves them.
    SIGTERM ends a run through the ``finally`` blocks that stop its
    children. Returns :func:`write_page`'s code.
    """
    if args.render:
        with open(args.render) as saved:
            results = json.load(saved)
    else:
        signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))
        start = time.monotonic()
        results = {'machine': describe(), 'command': command}
        results.update(run())
        results['seconds'] = time.monotonic() - start
        results['machine']['load_end'] = load()
        save_json(args.json, results)
    return write_page(render(results), path)


def write_page(text, path):
    """Print a benchmark's page and, unless ``path`` is None, write it there."""
    print(text)
    if path is not None:
        os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
        with open(path, 'w') as out:
            out.write(text)
        log(f'wrote {os.path.relpath(path, REPO)}')
    return 0
