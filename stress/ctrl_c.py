"""
Ctrl-C and SIGTERM at random moments: does every node end, cleanly?

``python stress/ctrl_c.py --starts N --seed S`` starts the installed
``imu_filter_node`` and ``observer_node`` (next to this Python) one at a
time, on both executors, and sends each SIGINT or SIGTERM at a random moment
0.05–4 s after its start (some while it still imports), with the machine
idle or with a busy loop on every core. It counts the starts that ended
cleanly (exit 0, no traceback, no fatal error), the hangs (not ended 15 s
after the signal: then SIGABRT, which faulthandler turns into every thread's
stack in the log, then SIGKILL), the aborts and the tracebacks, and prints
a table of them with the command. Not part of ``make test``
(``make ctrl-c-stress``). Every process it starts it ends; nothing loops
without a bound.
"""

import argparse
import collections
import contextlib
import json
import os
import random
import shlex
import shutil
import signal
import statistics
import subprocess
import sys
import tempfile
import time

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, REPO)
from bench.procs import reserved_domain_id  # noqa: E402 (the repository's, found above)

EXECUTABLES = ('imu_filter_node', 'observer_node')
EXECUTORS = ('events', 'single')
SIGNALS = {'int': signal.SIGINT, 'term': signal.SIGTERM}
# Seconds after the start at which the signal comes.
EARLIEST, LATEST = 0.05, 4.0
# A node not ended this long after the signal hangs; after SIGABRT it has
# this long to write its threads' stacks.
HANG_SECONDS = 15.0
DUMP_SECONDS = 5.0
# ROS domains of this command: apart from the benchmark's (40-60); held
# with domain_coordinator's convention (a TCP port at 32768 + id) so that a
# test run on the same machine never picks the same one.
DOMAINS = range(61, 101)
# What an abort or a crash leaves in the output.
FATAL = ('Fatal Python error', 'Destroying callback manager', 'terminate called',
         'Segmentation fault', 'core dumped')
CRASH_SIGNALS = (signal.SIGABRT, signal.SIGSEGV, signal.SIGBUS, signal.SIGILL, signal.SIGFPE)
# Where a compiling child of imu_filter_node says whose it is
# (ext_observer.pipeline.kernel_cache).
COMPILE_PARENT = 'EXT_OBSERVER_COMPILE_PARENT'


@contextlib.contextmanager
def busy_loops(count):
    """A busy loop on ``count`` cores for the context; each ended at its end."""
    loops = [subprocess.Popen([sys.executable, '-c', 'while True: pass'],
                              stdin=subprocess.DEVNULL, start_new_session=True)
             for _ in range(count)]
    try:
        yield loops
    finally:
        for loop in loops:
            loop.kill()
        for loop in loops:
            loop.wait(10)


def plan(starts, seed, signals, load):
    """
    Return the starts to make: one dict per start, in the order run.

    With ``load`` ``both``, the first half runs idle and the second busy;
    with ``signals`` ``both``, each start draws SIGINT or SIGTERM.
    """
    rng = random.Random(seed)
    runs = []
    for index in range(starts):
        if load == 'both':
            condition = 'idle' if index < starts // 2 else 'busy'
        else:
            condition = load
        name = signals if signals != 'both' else rng.choice(tuple(SIGNALS))
        runs.append({'index': index, 'executable': rng.choice(EXECUTABLES),
                     'executor': rng.choice(EXECUTORS), 'signal': name,
                     'delay': round(rng.uniform(EARLIEST, LATEST), 3), 'load': condition})
    return runs


def classify(returncode, output, hung):
    """
    Return how a start ended: ``clean``, ``hang``, ``abort``, ``traceback`` or ``exit``.

    ``exit`` is any other end: a nonzero exit code without a traceback
    (killed by the signal it was sent, an error exit).
    """
    if hung:
        return 'hang'
    if any(text in output for text in FATAL) or (
            returncode is not None and returncode < 0 and -returncode in CRASH_SIGNALS):
        return 'abort'
    if 'Traceback (most recent call last)' in output:
        return 'traceback'
    if returncode != 0:
        return 'exit'
    return 'clean'


def compile_children(parent):
    """Return the pids of the running compiling children of node ``parent``."""
    marker = f'{COMPILE_PARENT}={parent}'.encode()
    pids = []
    for entry in os.listdir('/proc'):
        if not entry.isdigit():
            continue
        try:
            with open(f'/proc/{entry}/environ', 'rb') as environ:
                if marker in environ.read().split(b'\0'):
                    pids.append(int(entry))
        except OSError:
            continue
    return pids


def catches(pid, signum):
    """Whether process ``pid`` has a handler for ``signum`` now (False once it ended)."""
    try:
        with open(f'/proc/{pid}/status') as status:
            for line in status:
                if line.startswith('SigCgt:'):
                    return bool(int(line.split()[1], 16) >> (signum - 1) & 1)
    except OSError:
        pass
    return False


def _group_alive(pid):
    try:
        os.killpg(pid, 0)
    except ProcessLookupError:
        return False
    return True


def _kill_group(pid):
    with contextlib.suppress(ProcessLookupError):
        os.killpg(pid, signal.SIGKILL)


def run_one(run, bin_dir, domain, log_path, cold_cache=None):
    """
    Start one node, signal it after ``run['delay']`` s, wait for its end.

    Returns ``run`` with ``outcome``, ``returncode``, ``seconds`` (from the
    signal to the end), ``logged`` (whether the node had logged a line
    before the signal: false while it imports or starts) and ``leftover``
    (processes of the node found after its end, then killed) and
    ``handled`` (whether the node had its SIGTERM handler at the signal).
    """
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST', ROS_DOMAIN_ID=str(domain),
               PYTHONUNBUFFERED='1', PYTHONFAULTHANDLER='1', RCUTILS_COLORIZED_OUTPUT='0')
    if cold_cache is not None:
        env['EXT_OBSERVER_CACHE'] = cold_cache
    argv = [os.path.join(bin_dir, run['executable']), '--executor', run['executor']]
    hung = False
    with open(log_path, 'w+b') as log:
        process = subprocess.Popen(argv, env=env, cwd=REPO, stdin=subprocess.DEVNULL,
                                   stdout=log, stderr=subprocess.STDOUT,
                                   start_new_session=True)
        try:
            try:
                process.wait(run['delay'])
            except subprocess.TimeoutExpired:
                pass
            run['logged'] = os.path.getsize(log_path) > 0
            # Python handles SIGINT from its start, SIGTERM only once the
            # node's own handlers are in (or rclpy's, without them).
            run['handled'] = catches(process.pid, signal.SIGTERM)
            signalled = time.monotonic()
            if process.poll() is None:
                process.send_signal(SIGNALS[run['signal']])
            try:
                process.wait(HANG_SECONDS)
            except subprocess.TimeoutExpired:
                hung = True
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(process.pid, signal.SIGABRT)
                try:
                    process.wait(DUMP_SECONDS)
                except subprocess.TimeoutExpired:
                    pass
            run['seconds'] = round(time.monotonic() - signalled, 3)
        finally:
            if process.poll() is None:
                _kill_group(process.pid)
                process.wait(10)
        # What the node left: a process of its group, a compiling child (its
        # own session; it ends with the node by its parent-death signal).
        leftover = 0
        if _group_alive(process.pid):
            leftover += 1
            _kill_group(process.pid)
        deadline = time.monotonic() + 2.0
        children = compile_children(process.pid)
        while children and time.monotonic() < deadline:
            time.sleep(0.1)
            children = compile_children(process.pid)
        for child in children:
            leftover += 1
            with contextlib.suppress(ProcessLookupError):
                os.kill(child, signal.SIGKILL)
        log.seek(0)
        output = log.read().decode('utf-8', 'replace')
    run['returncode'] = process.returncode
    run['leftover'] = leftover
    run['outcome'] = classify(process.returncode, output, hung)
    return run, output


def table(runs):
    """Return the Markdown table of the outcomes, per executable and executor, and in all."""
    outcomes = ('clean', 'hang', 'abort', 'traceback', 'exit')
    header = ('| executable | executor | load | starts | ' + ' | '.join(outcomes)
              + ' | before first log line | before SIGTERM handler | leftover processes'
              ' | s to end: median, max |')
    lines = [header, '|' + ' --- |' * (header.count('|') - 1)]
    groups = collections.defaultdict(list)
    for run in runs:
        groups[(run['executable'], run['executor'], run['load'])].append(run)
    groups[('all', '', '')] = list(runs)
    for (executable, executor, load), group in sorted(
            groups.items(), key=lambda item: (item[0][0] == 'all', item[0])):
        counts = collections.Counter(run['outcome'] for run in group)
        seconds = [run['seconds'] for run in group]
        lines.append(
            f'| {executable} | {executor} | {load} | {len(group)} | '
            + ' | '.join(str(counts[o]) for o in outcomes)
            + f' | {sum(not run["logged"] for run in group)}'
            + f' | {sum(not run["handled"] for run in group)}'
            + f' | {sum(run["leftover"] for run in group)}'
            + f' | {statistics.median(seconds):.2f}, {max(seconds):.2f} |')
    return '\n'.join(lines)


def _commit():
    try:
        done = subprocess.run(['git', 'rev-parse', '--short', 'HEAD'], cwd=REPO,
                              capture_output=True, text=True, timeout=10)
        dirty = subprocess.run(['git', 'status', '--porcelain', '--untracked-files=no'],
                               cwd=REPO, capture_output=True, text=True, timeout=10)
    except (OSError, subprocess.TimeoutExpired):
        return 'unknown'
    return done.stdout.strip() + (' (with uncommitted changes)' if dirty.stdout.strip() else '')


def main(argv=None):
    """Run the starts, print the table; exit 1 if any start did not end cleanly."""
    parser = argparse.ArgumentParser(prog='python stress/ctrl_c.py', description=__doc__.split(
        '\n\n')[0].strip())
    parser.add_argument('--starts', type=int, default=40, help='node starts (default 40)')
    parser.add_argument('--seed', type=int, default=0, help='seed of the plan (default 0)')
    parser.add_argument('--signals', choices=('int', 'term', 'both'), default='both',
                        help='SIGINT, SIGTERM or a random one per start (default both)')
    parser.add_argument('--load', choices=('idle', 'busy', 'both'), default='both',
                        help='a busy loop on every core or not; both: the first half idle '
                        '(default both)')
    parser.add_argument('--cold', type=float, default=0.1,
                        help='share of the imu_filter_node starts with an empty kernel cache '
                        '(EXT_OBSERVER_CACHE): the node compiles in a child process '
                        '(default 0.1)')
    parser.add_argument('--logs', default=os.path.join(REPO, 'out', 'ctrl_c'),
                        help='folder for the output of every start that did not end cleanly')
    parser.add_argument('--json', help='write every start and its outcome here')
    parser.add_argument('--bin', default=os.path.dirname(sys.executable),
                        help='folder of the executables (default: next to this Python)')
    args = parser.parse_args(argv)
    # The nodes start as from a terminal: SIGINT and SIGTERM at their
    # defaults, also where this command runs as a background job of a
    # script (SIGINT ignored, and so in every child).
    for signum in SIGNALS.values():
        if signal.getsignal(signum) is signal.SIG_IGN:
            signal.signal(signum, signal.default_int_handler if signum == signal.SIGINT
                          else signal.SIG_DFL)
    for name in EXECUTABLES:
        if not os.path.exists(os.path.join(args.bin, name)):
            parser.error(f'{name} is not in {args.bin}: make venv installs it')
    command = 'python stress/ctrl_c.py ' + shlex.join(sys.argv[1:] if argv is None else argv)
    runs = plan(args.starts, args.seed, args.signals, args.load)
    rng = random.Random(args.seed + 1)
    for run in runs:
        run['cold'] = run['executable'] == 'imu_filter_node' and rng.random() < args.cold
    os.makedirs(args.logs, exist_ok=True)
    commit = _commit()
    cores = os.cpu_count() or 1
    start = time.monotonic()
    done = []
    with reserved_domain_id(domains=DOMAINS) as domain, contextlib.ExitStack() as stack:
        busy = None
        for run in runs:
            if run['load'] == 'busy' and busy is None:
                busy = stack.enter_context(busy_loops(cores))
            log_path = os.path.join(args.logs, f'start-{run["index"]:04d}.log')
            cold = tempfile.mkdtemp(prefix='ctrl_c-cache-') if run['cold'] else None
            try:
                run, output = run_one(run, args.bin, domain, log_path, cold)
            finally:
                if cold is not None:
                    shutil.rmtree(cold, ignore_errors=True)
            if run['outcome'] == 'clean':
                os.remove(log_path)
            else:
                run['log'] = log_path
            done.append(run)
            print(f'{run["index"] + 1}/{len(runs)} {run["executable"]} {run["executor"]} '
                  f'SIG{run["signal"].upper()} at {run["delay"]:.2f} s ({run["load"]}'
                  f'{", cold cache" if run["cold"] else ""}): {run["outcome"]}, exit '
                  f'{run["returncode"]}, {run["seconds"]:.2f} s'
                  + (f', log {log_path}' if run['outcome'] != 'clean' else ''),
                  file=sys.stderr, flush=True)
    print(f'{command}\n\ncommit {commit}, {len(done)} starts in '
          f'{time.monotonic() - start:.0f} s, signal {EARLIEST}-{LATEST} s after the start, '
          f'hang: not ended within {HANG_SECONDS:.0f} s\n')
    print(table(done))
    if args.json:
        with open(args.json, 'w', encoding='utf-8') as out:
            json.dump({'command': command, 'commit': commit, 'runs': done}, out, indent=1)
    return 0 if all(run['outcome'] == 'clean' for run in done) else 1


if __name__ == '__main__':
    sys.exit(main())
