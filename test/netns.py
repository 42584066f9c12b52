"""
Two hosts on one machine: network namespaces joined by a veth pair.

The test bed of ``test_hosts.py`` (``make test-hosts``, root only). Each
:class:`TestBed` makes two namespaces, ``extobs-<pid>-a`` and
``extobs-<pid>-b``, each with ``lo`` up and one end of a veth pair
(``veth0``) with an address in a private /24 (:data:`SUBNET`) that exists only
inside them: no route, bridge or interface joins them to the machine's own
network, so nothing a process inside sends can leave the two namespaces.
IPv6 is off inside them. Faults are nftables rules on the input hook of
``veth0`` in both namespaces (the kernel here has no netem): random loss
(``numgen random mod 100 < N drop``) or a partition (every packet dropped).
A guard on the output hook counts and drops anything sent out of ``veth0`` to
an address outside the /24 and multicast; the tests check that it stays 0.

:meth:`TestBed.destroy` kills every process in the namespaces and deletes
them (a namespace's nftables table and veth end go with it); the fixture
calls it in a finalizer, and :func:`cleanup_leftovers` removes the namespaces
of earlier runs whose process is gone (a run killed with SIGKILL).

``python test/netns.py check`` prints what is missing for the test bed in one
line and exits 1 (not root, no ``ip`` or ``nft``, namespaces refused), or
exits 0; as root it installs the Debian packages ``iproute2`` and
``nftables`` first if they are missing. ``python test/netns.py cleanup``
removes leftovers. Only the standard library: it runs before the venv exists.
"""

import json
import os
import shutil
import signal
import subprocess
import sys
import time

PREFIX = 'extobs-'
# A private /24 of this test bed; it exists only inside its namespaces.
SUBNET = '10.212.12'
PREFIX_LENGTH = 24
VETH = 'veth0'
TABLE = 'extobs'
# Environment of every ROS process inside the namespaces: discovery by
# multicast on the subnet (the veth is the only interface besides lo), and
# UDP only: two real machines cannot share memory, so neither may two hosts
# of this test bed (Fast DDS would otherwise be free to use its shared-memory
# transport between processes of one machine).
NAMESPACE_ENV = {
    'ROS_AUTOMATIC_DISCOVERY_RANGE': 'SUBNET',
    'FASTDDS_BUILTIN_TRANSPORTS': 'UDPv4',
}
# Removed from the environment of the processes inside.
CLEARED_ENV = ('ROS_STATIC_PEERS', 'ROS_LOCALHOST_ONLY', 'FASTRTPS_DEFAULT_PROFILES_FILE',
               'FASTDDS_DEFAULT_PROFILES_FILE', 'RMW_IMPLEMENTATION', 'ROS_DISCOVERY_SERVER')


def run(argv, stdin=None, check=True, timeout=30):
    """Run a command; return its stdout. Raise with its stderr if it fails."""
    result = subprocess.run(argv, input=stdin, capture_output=True, text=True,
                            timeout=timeout)
    if check and result.returncode != 0:
        raise RuntimeError(f'{" ".join(argv)}: exit {result.returncode}: '
                           f'{result.stderr.strip() or result.stdout.strip()}')
    return result.stdout


def _apt_install(packages):
    """Install Debian packages as root; return an error text or None."""
    if shutil.which('apt-get') is None:
        return 'no apt-get to install them'
    env = dict(os.environ, DEBIAN_FRONTEND='noninteractive')
    for argv in (['apt-get', 'update', '-q'], ['apt-get', 'install', '-y', '-q'] + packages):
        result = subprocess.run(argv, capture_output=True, text=True, env=env, timeout=600)
        if result.returncode != 0:
            lines = (result.stderr or result.stdout).strip().splitlines() or ['failed']
            return f'{" ".join(argv[:2])} failed: {lines[-1]}'
    return None


def missing(install=True):
    """
    Return what the test bed lacks here, in one line, or None.

    As root, missing ``ip`` or ``nft`` are installed first (``iproute2``,
    ``nftables``) when ``install``. Then a throwaway namespace with a veth
    pair and an nftables table proves that the kernel allows them.
    """
    if os.geteuid() != 0:
        return ('make test-hosts needs root (network namespaces, veth, nftables); '
                f'running as uid {os.geteuid()}')
    tools = {'ip': 'iproute2', 'nft': 'nftables'}
    absent = [tool for tool in tools if shutil.which(tool) is None]
    if absent and install:
        error = _apt_install([tools[tool] for tool in absent])
        absent = [tool for tool in tools if shutil.which(tool) is None]
        if absent:
            return (f'make test-hosts needs {" and ".join(absent)} (Debian: '
                    f'{" ".join(tools[t] for t in absent)}): {error or "not installed"}')
    if absent:
        return (f'make test-hosts needs {" and ".join(absent)} (Debian: '
                f'{" ".join(tools[t] for t in absent)})')
    probe = f'{PREFIX}{os.getpid()}-check'
    try:
        run(['ip', 'netns', 'add', probe])
        run(['ip', '-n', probe, 'link', 'add', 'c0', 'type', 'veth', 'peer', 'name', 'c1'])
        run(['ip', 'netns', 'exec', probe, 'nft', '-f', '-'],
            stdin=f'table inet {TABLE} {{\n chain input {{\n type filter hook input '
                  'priority 0; policy accept;\n iifname "c0" numgen random mod 100 < 20 '
                  'drop\n }\n}\n')
    except (RuntimeError, subprocess.TimeoutExpired) as error:
        return f'make test-hosts cannot make its network namespaces here: {error}'
    finally:
        subprocess.run(['ip', 'netns', 'del', probe], capture_output=True)
    return None


def namespaces():
    """Return the names of the network namespaces on this machine."""
    return [line.split()[0] for line in run(['ip', 'netns', 'list']).splitlines()
            if line.strip()]


def namespace_pids(namespace):
    """Return the ids of the processes inside ``namespace``."""
    output = run(['ip', 'netns', 'pids', namespace], check=False)
    return [int(pid) for pid in output.split()]


def kill_namespace_processes(namespace, timeout=5.0):
    """SIGKILL every process inside ``namespace`` and wait until none is left."""
    deadline = time.monotonic() + timeout
    while True:
        pids = namespace_pids(namespace)
        if not pids:
            return
        for pid in pids:
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
        if time.monotonic() > deadline:
            raise RuntimeError(f'processes {pids} in {namespace} survive SIGKILL')
        time.sleep(0.05)


def _alive(pid):
    """Whether process ``pid`` runs (a zombie, killed but not reaped, does not)."""
    try:
        with open(f'/proc/{pid}/stat') as stat:
            return stat.read().rsplit(')', 1)[1].split()[0] not in ('Z', 'X')
    except (FileNotFoundError, ProcessLookupError, IndexError):
        return False


def cleanup_leftovers():
    """
    Remove the namespaces of earlier test beds whose process is gone.

    Their processes are killed first. Return the names removed.
    """
    removed = []
    for name in namespaces():
        if not name.startswith(PREFIX):
            continue
        owner = name[len(PREFIX):].split('-')[0]
        if owner.isdigit() and _alive(int(owner)) and int(owner) != os.getpid():
            continue
        kill_namespace_processes(name)
        run(['ip', 'netns', 'del', name], check=False)
        removed.append(name)
    return removed


class Process:
    """A process started inside a namespace, in a process group of its own."""

    def __init__(self, host, argv, env, log_path):
        self.host, self.argv, self.log_path = host, list(argv), log_path
        self._log = open(log_path, 'ab')
        self.process = subprocess.Popen(
            ['ip', 'netns', 'exec', host.namespace] + self.argv, env=env,
            stdin=subprocess.DEVNULL, stdout=self._log, stderr=subprocess.STDOUT,
            start_new_session=True)

    @property
    def output(self):
        """Return everything the process wrote so far."""
        self._log.flush()
        with open(self.log_path, 'rb') as log:
            return log.read().decode(errors='replace')

    def alive(self):
        return self.process.poll() is None

    def interrupt(self, timeout=10.0):
        """SIGINT, wait; SIGKILL the group if it does not end. Return the exit code."""
        if self.alive():
            self.process.send_signal(signal.SIGINT)
        try:
            return self.process.wait(timeout)
        except subprocess.TimeoutExpired:
            self.kill()
            return None

    def kill(self):
        """SIGKILL the process group; wait for the process."""
        if self.alive():
            try:
                os.killpg(self.process.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
        try:
            self.process.wait(10)
        except subprocess.TimeoutExpired:
            pass
        if not self._log.closed:
            self._log.close()


class Host:
    """One namespace of the test bed: its address and the processes started in it."""

    def __init__(self, namespace, address, label):
        self.namespace, self.address, self.label = namespace, address, label
        self.processes = []

    def ip(self, *args):
        return run(['ip', '-n', self.namespace] + list(args))

    def exec(self, *argv, stdin=None):
        """Run a command inside the namespace; return its stdout."""
        return run(['ip', 'netns', 'exec', self.namespace] + list(argv), stdin=stdin)

    def nft(self, script):
        self.exec('nft', '-f', '-', stdin=script)

    def start(self, argv, env, log_path):
        """Start ``argv`` inside the namespace with ``env``; return a :class:`Process`."""
        process = Process(self, argv, env, log_path)
        self.processes.append(process)
        return process

    def kill_all(self):
        """SIGKILL every process of this host: those started here, and any other inside."""
        for process in self.processes:
            process.kill()
        kill_namespace_processes(self.namespace)

    def counters(self, chain):
        """Return ``[(rule text, packets)]`` of the rules with a counter in ``chain``."""
        data = json.loads(self.exec('nft', '-j', 'list', 'chain', 'inet', TABLE, chain))
        rows = []
        for item in data['nftables']:
            rule = item.get('rule')
            if not rule:
                continue
            packets = [e['counter']['packets'] for e in rule['expr'] if 'counter' in e]
            if packets:
                rows.append((json.dumps(rule['expr']), packets[0]))
        return rows


class TestBed:
    """Two namespaces ``a`` and ``b`` joined by a veth pair, with fault injection."""

    __test__ = False  # not a pytest class

    def __init__(self, tag=''):
        base = f'{PREFIX}{os.getpid()}-{tag}' if tag else f'{PREFIX}{os.getpid()}'
        self.a = Host(f'{base}-a', f'{SUBNET}.1', 'A')
        self.b = Host(f'{base}-b', f'{SUBNET}.2', 'B')
        self.hosts = (self.a, self.b)
        self.loss_percent = 0
        self.partitioned = False

    def create(self):
        """Make the namespaces, the veth pair, the addresses and the nftables tables."""
        for host in self.hosts:
            run(['ip', 'netns', 'add', host.namespace])
        run(['ip', 'link', 'add', VETH, 'netns', self.a.namespace, 'type', 'veth',
             'peer', 'name', VETH, 'netns', self.b.namespace])
        for host in self.hosts:
            host.exec('sysctl', '-q', '-w', 'net.ipv6.conf.all.disable_ipv6=1')
            host.exec('sysctl', '-q', '-w', 'net.ipv6.conf.default.disable_ipv6=1')
            host.ip('link', 'set', 'lo', 'up')
            host.ip('addr', 'add', f'{host.address}/{PREFIX_LENGTH}', 'dev', VETH)
            host.ip('link', 'set', VETH, 'up')
            host.nft(
                f'table inet {TABLE} {{\n'
                '  chain input { type filter hook input priority 0; policy accept; }\n'
                '  chain output { type filter hook output priority 0; policy accept;\n'
                f'    oifname != "lo" ip daddr != {{ {SUBNET}.0/{PREFIX_LENGTH}, 224.0.0.0/4 }}'
                ' counter drop\n'
                '    oifname != "lo" meta nfproto ipv6 counter drop\n'
                '  }\n'
                '}\n')
        self.set_loss(0)
        self.wait_for_carrier()
        return self

    def wait_for_carrier(self, timeout=10.0):
        """
        Wait until both veth ends are operationally up.

        The kernel reports the carrier of a veth some time after both ends
        were set up (up to a second); a DDS participant started before that
        may never send on the link: its discovery then fails for good.
        """
        deadline = time.monotonic() + timeout
        while True:
            states = [json.loads(host.exec('ip', '-j', 'link', 'show', VETH))[0]['operstate']
                      for host in self.hosts]
            if states == ['UP', 'UP']:
                return
            if time.monotonic() > deadline:
                raise RuntimeError(f'the veth pair is not up after {timeout} s: {states}')
            time.sleep(0.05)

    def _input_rules(self, rule):
        for host in self.hosts:
            script = (f'flush chain inet {TABLE} input\n'
                      f'add rule inet {TABLE} input iifname "{VETH}" counter\n')
            if rule is not None:
                script += f'add rule inet {TABLE} input iifname "{VETH}" {rule} counter drop\n'
            host.nft(script)

    def set_loss(self, percent):
        """Drop each packet arriving over the link, in both directions, with ``percent`` %."""
        self.loss_percent, self.partitioned = percent, False
        self._input_rules(f'numgen random mod 100 < {int(percent)}' if percent else None)

    def partition(self):
        """Drop every packet over the link."""
        self.loss_percent, self.partitioned = 100, True
        self._input_rules('')

    def heal(self):
        self.set_loss(0)

    def link_counters(self):
        """Return ``(packets in, packets dropped)`` over the link since the last rule change."""
        total = dropped = 0
        for host in self.hosts:
            rows = host.counters('input')
            total += rows[0][1]
            dropped += sum(packets for _, packets in rows[1:])
        return total, dropped

    def escaped_packets(self):
        """Return the packets the guard stopped on their way out of the /24 (should be 0)."""
        return sum(packets for host in self.hosts for _, packets in host.counters('output'))

    def describe(self):
        """Return the interfaces of each namespace, as ``{label: [(name, peer netns)]}``."""
        links = {}
        for host in self.hosts:
            data = json.loads(host.exec('ip', '-j', 'link', 'show'))
            links[host.label] = [(link['ifname'], link.get('link_netnsid')) for link in data]
        return links

    def routes(self, host):
        return json.loads(host.exec('ip', '-j', 'route', 'show', 'table', 'all'))

    def destroy(self):
        """Kill every process inside, delete both namespaces (tables and veth go too)."""
        errors = []
        for host in self.hosts:
            try:
                host.kill_all()
            except RuntimeError as error:
                errors.append(str(error))
        for host in self.hosts:
            if host.namespace in namespaces():
                result = subprocess.run(['ip', 'netns', 'del', host.namespace],
                                        capture_output=True, text=True)
                if result.returncode != 0:
                    errors.append(result.stderr.strip())
        if errors:
            raise RuntimeError('; '.join(errors))

    def __enter__(self):
        try:
            return self.create()
        except BaseException:
            self.destroy()
            raise

    def __exit__(self, *exc):
        self.destroy()


def main(argv):
    if argv[1:] == ['check']:
        problem = missing()
        if problem:
            print(problem, file=sys.stderr)
            return 1
        return 0
    if argv[1:] == ['cleanup']:
        problem = missing(install=False)
        if problem:
            print(problem, file=sys.stderr)
            return 1
        for name in cleanup_leftovers():
            print(f'removed {name}')
        return 0
    print(f'usage: {argv[0]} check|cleanup', file=sys.stderr)
    return 2


if __name__ == '__main__':
    sys.exit(main(sys.argv))
