"""Two "hosts" on one machine: network namespaces joined by a veth pair, optionally lossy and slow.

ROS-free (standard library and iproute2 only; needs root). ``TwoHosts`` makes namespaces
``<prefix>-<pid>-a`` and ``-b``, each with loopback up and one end of a veth pair named ``ft0``,
addressed ``<subnet>.1/24`` and ``<subnet>.2/24``. The pair is created inside the namespaces, so
nothing is added to the machine's own network and no traffic leaves them. Leaving the ``with``
block (or a failure while making them) stops every process still inside and deletes both;
entering it first deletes what a crashed earlier run left behind (its pid is dead).

What each end does to the traffic (``tc``):

* multicast (unless ``multicast=True``): IPv4 multicast is dropped on egress by a classic-BPF
  filter under a root ``htb`` (other packets pass it unshaped), as on a lab switch that does not
  forward multicast: discovery across the link must use unicast peers. Counted as the htb's drops.
* loss: a classic-BPF filter on the ``clsact`` *ingress* hook drops an IPv4 packet when the
  kernel's per-packet random number is below L % of 2**32. Counted as the clsact's drops. It is on
  the receiving end so that the sender's packet socket (``rtps_sniff``) sees every transmission,
  the lost ones too, and can tell a retransmission from a first sending.
* delay: ``netem delay D`` when the kernel has ``sch_netem`` (under the htb, or as the root);
  otherwise a user-space delay line: a ``clsact`` egress filter redirects every IPv4 frame to a tap
  device (``mirred``), and ``python netns.py delay-line`` holds each for D and sends it out of
  ``ft0`` again through a packet socket whose ``SO_MARK`` lets it pass the filter.

``python netns.py probe`` prints what this machine supports.
"""
from __future__ import annotations

import collections
import contextlib
import dataclasses
import fcntl
import json
import os
import select
import signal
import socket
import struct
import subprocess
import sys
import time
from pathlib import Path

PREFIX = 'ft2h'           # namespace names: <PREFIX>-<pid of the run>-<host>
SUBNET = '10.231.0'       # a private /24 that exists only inside the namespaces
DEV = 'ft0'               # the veth end in each namespace
TAP = 'ft0delay'          # the delay line's tap device
MARK = 0x2d1a1            # SO_MARK of frames the delay line sends back out (they pass the filter)
TAP_QUEUE = 10_000        # frames the tap holds for the delay line (netem's queue: 1000; a repair comes in bursts)

# classic BPF (linux/filter.h): opcodes, ancillary loads and tc verdicts
_LD_W_ABS, _JEQ_K, _JGT_K, _JGE_K, _RET_K = 0x20, 0x15, 0x25, 0x35, 0x06
_SKF_AD_OFF, _SKF_AD_MARK, _SKF_AD_RANDOM = -0x1000, 20, 56
_TC_ACT_OK, _TC_ACT_SHOT, _TC_ACT_UNSPEC = 0, 2, 0xFFFFFFFF
_IPV4_DST = 14 + 16           # offset of the IPv4 destination in an Ethernet frame
_TUNSETIFF, _IFF_TAP, _IFF_NO_PI, _SO_MARK = 0x400454CA, 0x0002, 0x1000, 36


class NetnsError(RuntimeError):
    """A namespace, link or impairment could not be made; the message says which command and why."""


@dataclasses.dataclass(frozen=True)
class Impairment:
    """Loss (percent of packets, each direction) and one-way delay (ms) on the link."""
    loss_pct: float = 0.0
    delay_ms: float = 0.0

    def __post_init__(self):
        if not 0.0 <= self.loss_pct < 100.0:
            raise NetnsError(f'loss {self.loss_pct} % is invalid; expected a value in [0, 100)')
        if not 0.0 <= self.delay_ms <= 10_000.0:
            raise NetnsError(f'delay {self.delay_ms} ms is invalid; expected a value in [0, 10000]')

    def __bool__(self) -> bool:
        return bool(self.loss_pct or self.delay_ms)

    def describe(self) -> str:
        return f'{self.loss_pct:g} % loss, {self.delay_ms:g} ms delay each way' if self else 'clean link'


@dataclasses.dataclass(frozen=True)
class Support:
    """What this machine can do: namespaces and veth, and each way of impairing the link."""
    netns: bool
    netem: bool          # sch_netem (delay)
    bpf: bool            # cls_bpf on clsact (loss) and under htb (the multicast block)
    delay_line: bool     # tap + mirred (delay without netem)
    reason: str = ''     # why netns is False

    def method(self, impairment: Impairment) -> str:
        parts = ['classic-BPF random drop on the receiving end (clsact ingress)'] if impairment.loss_pct else []
        if impairment.delay_ms:
            parts.append('tc netem delay' if self.netem else
                         'user-space delay line (tap + mirred; this kernel has no sch_netem)')
        return ' + '.join(parts) or 'none'


def _run(*cmd: str, check: bool = True) -> subprocess.CompletedProcess:
    res = subprocess.run(cmd, capture_output=True, text=True)
    if check and res.returncode:
        raise NetnsError(f"`{' '.join(cmd)}` failed (exit {res.returncode}): "
                         f"{(res.stderr or res.stdout).strip()}")
    return res


def bpf_bytecode(program: list) -> str:
    """tc's textual form of a classic BPF program: 'N,code jt jf k,...'."""
    return ','.join([str(len(program))] + [f'{c} {jt} {jf} {k}' for c, jt, jf, k in program])


def loss_program(loss_pct: float) -> list:
    """Drop (SHOT) when the per-packet random number is below loss_pct % of 2**32, else hand on."""
    threshold = min(0xFFFFFFFF, round(loss_pct / 100.0 * 2 ** 32))
    return [(_LD_W_ABS, 0, 0, (_SKF_AD_OFF + _SKF_AD_RANDOM) & 0xFFFFFFFF), (_JGE_K, 1, 0, threshold),
            (_RET_K, 0, 0, _TC_ACT_SHOT), (_RET_K, 0, 0, _TC_ACT_UNSPEC)]


def marked_program() -> list:
    """Frames marked MARK (sent by the delay line) pass (OK); others are handed on."""
    return [(_LD_W_ABS, 0, 0, (_SKF_AD_OFF + _SKF_AD_MARK) & 0xFFFFFFFF), (_JEQ_K, 0, 1, MARK),
            (_RET_K, 0, 0, _TC_ACT_OK), (_RET_K, 0, 0, _TC_ACT_UNSPEC)]


def multicast_program() -> list:
    """IPv4 packets to 224.0.0.0/4 are dropped (SHOT), others handed on."""
    return [(_LD_W_ABS, 0, 0, _IPV4_DST), (_JGE_K, 0, 2, 0xE0000000), (_JGT_K, 1, 0, 0xEFFFFFFF),
            (_RET_K, 0, 0, _TC_ACT_SHOT), (_RET_K, 0, 0, _TC_ACT_UNSPEC)]


MATCH_ALL = [(_RET_K, 0, 0, _TC_ACT_UNSPEC)]   # without direct-action: every packet matches


def _filter(tc: list, where: list, pref: int, program: list, *action: str, direct: bool = True) -> list:
    return [*tc, 'filter', 'add', 'dev', DEV, *where, 'protocol', 'ip', 'pref', str(pref), 'bpf',
            *(['da'] if direct else []), 'bytecode', bpf_bytecode(program), *action]


def _pid_alive(pid: int) -> bool:
    """True for a running process (a zombie, killed but not yet reaped, is not)."""
    try:
        stat = Path(f'/proc/{pid}/stat').read_text()
    except OSError:
        return False
    return stat.rpartition(')')[2].split()[0] != 'Z'


def namespaces() -> list:
    out = _run('ip', '-j', 'netns', 'list', check=False)
    if out.returncode or not out.stdout.strip():
        return []
    return [n['name'] for n in json.loads(out.stdout)]


def delete_namespace(name: str) -> None:
    """Stop every process inside the namespace (started there by a run of this module), then delete it."""
    pids = [int(p) for p in _run('ip', 'netns', 'pids', name, check=False).stdout.split()]
    for sig in (signal.SIGTERM, signal.SIGKILL):
        for pid in pids:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, sig)
        deadline = time.monotonic() + 5.0
        while any(_pid_alive(p) for p in pids) and time.monotonic() < deadline:
            time.sleep(0.05)
        pids = [p for p in pids if _pid_alive(p)]
        if not pids:
            break
    _run('ip', 'netns', 'delete', name, check=False)


def clear_leftovers(prefix: str = PREFIX) -> list:
    """Delete the namespaces a crashed earlier run left behind (their run's pid is gone)."""
    gone = []
    for name in namespaces():
        parts = name.split('-')
        if len(parts) == 3 and parts[0] == prefix and parts[1].isdigit() and not _pid_alive(int(parts[1])):
            delete_namespace(name)
            gone.append(name)
    return gone


_SUPPORT = None


def probe() -> Support:
    """Try, in throwaway namespaces, what this machine supports (cached)."""
    global _SUPPORT
    if _SUPPORT is not None:
        return _SUPPORT
    if os.geteuid() != 0:
        _SUPPORT = Support(False, False, False, False, f'network namespaces need root (this is uid {os.geteuid()})')
        return _SUPPORT
    a, b = f'{PREFIX}-{os.getpid()}-p', f'{PREFIX}-{os.getpid()}-q'
    clear_leftovers()
    try:
        try:
            _run('ip', 'netns', 'add', a)
            _run('ip', 'netns', 'add', b)
            _run('ip', 'link', 'add', DEV, 'netns', a, 'type', 'veth', 'peer', 'name', DEV, 'netns', b)
        except (NetnsError, OSError) as exc:
            _SUPPORT = Support(False, False, False, False, f'cannot make namespaces joined by veth: {exc}')
            return _SUPPORT

        def works(*cmd) -> bool:
            return not _run(*cmd, check=False).returncode
        tc_a, tc_b = ['ip', 'netns', 'exec', a, 'tc'], ['ip', 'netns', 'exec', b, 'tc']
        netem = works(*tc_b, 'qdisc', 'add', 'dev', DEV, 'root', 'netem', 'delay', '1ms')
        bpf = (works(*tc_a, 'qdisc', 'add', 'dev', DEV, 'root', 'handle', '1:', 'htb')
               and works(*_filter(tc_a, ['parent', '1:'], 1, multicast_program()))
               and works(*tc_a, 'qdisc', 'add', 'dev', DEV, 'clsact')
               and works(*_filter(tc_a, ['ingress'], 1, loss_program(1.0))))
        line = (bpf and works('ip', '-n', a, 'tuntap', 'add', 'dev', TAP, 'mode', 'tap')
                and works(*_filter(tc_a, ['egress'], 1, MATCH_ALL, 'action', 'mirred', 'egress', 'redirect',
                                   'dev', TAP, direct=False)))
        _SUPPORT = Support(True, netem, bpf, line)
        return _SUPPORT
    finally:
        for name in (a, b):
            if name in namespaces():
                delete_namespace(name)


def udp_counters(h: Host) -> dict:
    """The host's UDP datagrams received and those its sockets had no room for (/proc/net/snmp)."""
    lines = [ln.split() for ln in _run(*h.prefix(), 'cat', '/proc/net/snmp').stdout.splitlines()
             if ln.startswith('Udp:')]
    udp = dict(zip(lines[0][1:], (int(v) for v in lines[1][1:])))
    return {'udp_in': udp.get('InDatagrams', 0), 'udp_rcvbuf_errors': udp.get('RcvbufErrors', 0)}


@dataclasses.dataclass(frozen=True)
class Host:
    name: str        # 'a' or 'b'
    netns: str
    address: str

    def prefix(self) -> list:
        """Run a command inside this host: prepend this to it."""
        return ['ip', 'netns', 'exec', self.netns]


class TwoHosts:
    """Two namespaces joined by veth, with optional loss and delay; a context manager."""

    def __init__(self, impairment: Impairment | None = None, multicast: bool = False, subnet: str = SUBNET,
                 prefix: str = PREFIX, log_dir: Path | None = None):
        self.impairment = impairment or Impairment()
        self.multicast = multicast   # False: the link drops IPv4 multicast, as many lab switches do
        self.prefix = prefix
        tag = f'{prefix}-{os.getpid()}'
        self.hosts = (Host('a', f'{tag}-a', f'{subnet}.1'), Host('b', f'{tag}-b', f'{subnet}.2'))
        self.log_dir = log_dir
        self.support = None
        self.method = 'none'
        self._procs = []   # delay lines and anything else started with start()

    @property
    def a(self) -> Host:
        return self.hosts[0]

    @property
    def b(self) -> Host:
        return self.hosts[1]

    def __enter__(self) -> TwoHosts:
        self.support = probe()
        if not self.support.netns:
            raise NetnsError(self.support.reason)
        imp = self.impairment
        if (imp.loss_pct or not self.multicast) and not self.support.bpf:
            raise NetnsError('cannot drop packets on the link here: no cls_bpf filter on clsact and htb')
        if imp.delay_ms and not (self.support.netem or self.support.delay_line):
            raise NetnsError('cannot delay packets here: no sch_netem and no tap + mirred')
        self.method = self.support.method(imp)
        clear_leftovers(self.prefix)
        try:
            self._make()
        except BaseException:
            self.close()
            raise
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _make(self) -> None:
        a, b = self.hosts
        for h in self.hosts:
            _run('ip', 'netns', 'add', h.netns)
        _run('ip', 'link', 'add', DEV, 'netns', a.netns, 'type', 'veth', 'peer', 'name', DEV, 'netns', b.netns)
        for h in self.hosts:
            _run('ip', '-n', h.netns, 'link', 'set', 'lo', 'up')
            _run('ip', '-n', h.netns, 'addr', 'add', f'{h.address}/24', 'dev', DEV)
            _run('ip', '-n', h.netns, 'link', 'set', DEV, 'up')
            self._shape(h)
        self._wait_up()

    def _wait_up(self, timeout: float = 10.0) -> None:
        """Wait until both ends have carrier (operstate UP: the kernel sets it up to a second after
        `link set up`). A DDS participant made before that sees loopback only, announces 127.0.0.1
        as its address and is never reached from the other host."""
        deadline = time.monotonic() + timeout
        while True:
            states = [json.loads(_run('ip', '-n', h.netns, '-j', 'link', 'show', 'dev', DEV).stdout)[0]
                      .get('operstate') for h in self.hosts]
            if all(s == 'UP' for s in states):
                return
            if time.monotonic() > deadline:
                raise NetnsError(f'the veth ends are {states} after {timeout:g} s; expected UP')
            time.sleep(0.02)

    def _shape(self, h: Host) -> None:
        tc = [*h.prefix(), 'tc']
        imp = self.impairment
        netem = ['netem', 'delay', f'{imp.delay_ms:g}ms'] if imp.delay_ms and self.support.netem else []
        if not self.multicast:
            _run(*tc, 'qdisc', 'add', 'dev', DEV, 'root', 'handle', '1:', 'htb', *(['default', '1'] if netem else []))
            _run(*_filter(tc, ['parent', '1:'], 1, multicast_program()))
            if netem:
                _run(*tc, 'class', 'add', 'dev', DEV, 'parent', '1:', 'classid', '1:1', 'htb', 'rate', '100gbit')
                _run(*tc, 'qdisc', 'add', 'dev', DEV, 'parent', '1:1', *netem)
        elif netem:
            _run(*tc, 'qdisc', 'add', 'dev', DEV, 'root', *netem)
        line = imp.delay_ms and not netem
        if not (imp.loss_pct or line):
            return
        _run(*tc, 'qdisc', 'add', 'dev', DEV, 'clsact')
        if imp.loss_pct:
            _run(*_filter(tc, ['ingress'], 1, loss_program(imp.loss_pct)))
        if line:  # the delay line must hold the tap open before packets are sent to it
            _run('ip', '-n', h.netns, 'tuntap', 'add', 'dev', TAP, 'mode', 'tap')
            _run('ip', '-n', h.netns, 'link', 'set', TAP, 'txqueuelen', str(TAP_QUEUE), 'up')
            self._delay_line(h)
            _run(*_filter(tc, ['egress'], 1, marked_program()))
            _run(*_filter(tc, ['egress'], 2, MATCH_ALL, 'action', 'mirred', 'egress', 'redirect', 'dev', TAP,
                          direct=False))

    def _delay_line(self, h: Host) -> None:
        """Start host h's delay line (it holds the tap) and wait for its 'ready'."""
        proc = self.start(h, f'delay_line_{h.name}', [sys.executable, str(Path(__file__).resolve()),
                                                      'delay-line', TAP, DEV, str(self.impairment.delay_ms / 1000.0)])
        if proc.stdout.readline().strip() != b'ready':
            raise NetnsError(f'the delay line in host {h.name} did not start (exit {proc.poll()})')

    def start(self, h: Host, name: str, cmd: list) -> subprocess.Popen:
        """A helper process inside host h (stdout piped, stderr to log_dir/<name>.log); stopped by close()."""
        log = open(self.log_dir / f'{name}.log', 'w') if self.log_dir else subprocess.DEVNULL
        proc = subprocess.Popen([*h.prefix(), *cmd], stdout=subprocess.PIPE, stderr=log, stdin=subprocess.DEVNULL)
        self._procs.append(proc)
        return proc

    def counters(self) -> dict:
        """Per host: its veth end's rx/tx bytes and packets as the device counts them (rx
        includes what the loss then drops), the packets the loss dropped as they came in, the
        multicast packets blocked going out, the delay line's own drops (its tap overflowed), and
        the UDP datagrams received and dropped for a full socket buffer (a receiver that fell behind)."""
        out = {}
        for h in self.hosts:
            link = json.loads(_run('ip', '-n', h.netns, '-s', '-j', 'link', 'show', 'dev', DEV).stdout)[0]
            stats = link['stats64']
            qdiscs = json.loads(_run(*h.prefix(), 'tc', '-s', '-j', 'qdisc', 'show', 'dev', DEV).stdout or '[]')
            drops = {q.get('kind'): q.get('drops', 0) for q in qdiscs}
            c = {'rx_bytes': stats['rx']['bytes'], 'rx_packets': stats['rx']['packets'],
                 'tx_bytes': stats['tx']['bytes'], 'tx_packets': stats['tx']['packets'],
                 'lost': drops.get('clsact', 0), 'multicast_blocked': drops.get('htb', 0), 'delay_line_dropped': 0}
            c.update(udp_counters(h))
            if self.impairment.delay_ms and not self.support.netem:
                tap = json.loads(_run('ip', '-n', h.netns, '-s', '-j', 'link', 'show', 'dev', TAP).stdout)[0]
                c['delay_line_dropped'] = tap['stats64']['tx']['dropped']
            out[h.name] = c
        return out

    def close(self) -> None:
        """Stop the helper processes and everything else inside, and delete both namespaces."""
        for proc in self._procs:
            if proc.poll() is None:
                proc.terminate()
            with contextlib.suppress(subprocess.TimeoutExpired):
                proc.wait(5)
            if proc.poll() is None:
                proc.kill()
                proc.wait()
        self._procs = []
        present = namespaces()
        for h in self.hosts:
            if h.netns in present:
                delete_namespace(h.netns)

    def left(self) -> list:
        """Namespaces of this run that still exist (none after close)."""
        present = namespaces()
        return [h.netns for h in self.hosts if h.netns in present]


STAR_PREFIX = 'ftst'      # namespace names of a Star: <STAR_PREFIX>-<pid of the run>-<host> (and -sw, the switch)
STAR_SUBNET = '10.232.0'
SWITCH = 'sw'             # the switch's namespace suffix; its bridge is BRIDGE, its port to host X is 'p' + X
BRIDGE = 'br0'


class Star(TwoHosts):
    """N hosts on one switch: a namespace per host, each with one veth end ``ft0`` (``<subnet>.<i+1>``),
    whose other end is a port of a bridge in a switch namespace; a context manager, like TwoHosts.

    Each host's end is shaped as TwoHosts shapes an end (delay on what it sends, loss on what it
    receives, multicast dropped unless asked for), so every path between two hosts has the
    impairment's delay and loss each way, as the two-host link has; the switch adds none.
    ``cut(name)`` takes a host's switch port down (a pulled cable), ``kill(name)`` SIGKILLs every
    process inside the host (a power cut), ``plug(name)`` brings the port up again."""

    def __init__(self, names=('a', 'b', 'c'), impairment: Impairment | None = None, multicast: bool = False,
                 subnet: str = STAR_SUBNET, prefix: str = STAR_PREFIX, log_dir: Path | None = None):
        if len(set(names)) != len(names) or SWITCH in names or not 1 <= len(names) <= 250 or \
                not all(n.isalnum() and len(n) <= 8 for n in names):
            raise NetnsError(f'host names {list(names)} are invalid; expected 1-250 distinct alphanumeric names '
                             f'of at most 8 characters, not {SWITCH!r}')
        super().__init__(impairment, multicast=multicast, subnet=subnet, prefix=prefix, log_dir=log_dir)
        tag = f'{prefix}-{os.getpid()}'
        self.hosts = tuple(Host(n, f'{tag}-{n}', f'{subnet}.{i + 1}') for i, n in enumerate(names))
        self.switch = f'{tag}-{SWITCH}'

    def host(self, name: str) -> Host:
        for h in self.hosts:
            if h.name == name:
                return h
        raise NetnsError(f'host {name!r} is unknown; expected one of {[h.name for h in self.hosts]}')

    def _make(self) -> None:
        _run('ip', 'netns', 'add', self.switch)
        _run('ip', '-n', self.switch, 'link', 'add', BRIDGE, 'type', 'bridge')
        _run('ip', '-n', self.switch, 'link', 'set', BRIDGE, 'up')
        for h in self.hosts:
            _run('ip', 'netns', 'add', h.netns)
            port = f'p{h.name}'
            _run('ip', 'link', 'add', DEV, 'netns', h.netns, 'type', 'veth', 'peer', 'name', port,
                 'netns', self.switch)
            _run('ip', '-n', self.switch, 'link', 'set', port, 'master', BRIDGE)
            _run('ip', '-n', self.switch, 'link', 'set', port, 'up')
            _run('ip', '-n', h.netns, 'link', 'set', 'lo', 'up')
            _run('ip', '-n', h.netns, 'addr', 'add', f'{h.address}/24', 'dev', DEV)
            _run('ip', '-n', h.netns, 'link', 'set', DEV, 'up')
            self._shape(h)
        self._wait_up()

    def _set_port(self, name: str, state: str) -> None:
        _run('ip', '-n', self.switch, 'link', 'set', f'p{self.host(name).name}', state)

    def cut(self, name: str) -> None:
        """Take host ``name``'s switch port down: nothing it sends arrives, nothing reaches it."""
        self._set_port(name, 'down')

    def plug(self, name: str) -> None:
        """Bring host ``name``'s switch port up again and wait for its carrier; a user-space delay line
        that kill() ended is started again."""
        h = self.host(name)
        if self.impairment.delay_ms and not self.support.netem and not any(
                _pid_alive(int(p)) for p in _run('ip', 'netns', 'pids', h.netns, check=False).stdout.split()):
            self._delay_line(h)
        self._set_port(name, 'up')
        self._wait_up()

    def kill(self, name: str) -> list:
        """SIGKILL every process inside host ``name`` (no goodbye); returns their pids once they are gone.
        The host's delay line, if any, is one of them (plug() starts it again)."""
        netns = self.host(name).netns
        pids = [int(p) for p in _run('ip', 'netns', 'pids', netns, check=False).stdout.split()]
        for pid in pids:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
        deadline = time.monotonic() + 10.0
        while any(_pid_alive(p) for p in pids):
            if time.monotonic() > deadline:
                raise NetnsError(f'processes {[p for p in pids if _pid_alive(p)]} in {netns} outlived SIGKILL '
                                 'for 10 s; expected them gone')
            time.sleep(0.02)
        return pids

    def close(self) -> None:
        super().close()
        if self.switch in namespaces():
            delete_namespace(self.switch)

    def left(self) -> list:
        present = namespaces()
        return [n for n in (*(h.netns for h in self.hosts), self.switch) if n in present]


def delay_line(tap: str, dev: str, delay_s: float) -> None:
    """Hold every frame that arrives on the tap for delay_s, then send it out of dev, marked so
    the egress filter lets it pass. Run inside the namespace; prints 'ready' once the tap is held."""
    fd = os.open('/dev/net/tun', os.O_RDWR)
    fcntl.ioctl(fd, _TUNSETIFF, struct.pack('16sH', tap.encode(), _IFF_TAP | _IFF_NO_PI))
    os.set_blocking(fd, False)
    out = socket.socket(socket.AF_PACKET, socket.SOCK_RAW)
    out.setsockopt(socket.SOL_SOCKET, _SO_MARK, MARK)
    out.bind((dev, 0))
    held = collections.deque()   # (due, frame): one delay for all, so first in is first out
    stats = {'frames': 0, 'most_held': 0, 'send_errors': 0}

    def stop(*_):
        print(json.dumps(stats), file=sys.stderr, flush=True)
        sys.exit(0)
    signal.signal(signal.SIGTERM, stop)
    print('ready', flush=True)
    while True:
        timeout = max(0.0, held[0][0] - time.monotonic()) if held else None
        ready, _, _ = select.select([fd], [], [], timeout)
        if ready:
            due = time.monotonic() + delay_s
            while True:
                try:
                    held.append((due, os.read(fd, 65536)))
                except BlockingIOError:
                    break
            stats['most_held'] = max(stats['most_held'], len(held))
        now = time.monotonic()
        while held and held[0][0] <= now:
            frame = held.popleft()[1]
            stats['frames'] += 1
            try:
                out.send(frame)
            except OSError:  # a full queue on dev: that frame is lost, as on a wire
                stats['send_errors'] += 1


if __name__ == '__main__':
    if sys.argv[1:2] == ['delay-line']:
        delay_line(sys.argv[2], sys.argv[3], float(sys.argv[4]))
    elif sys.argv[1:2] == ['probe']:
        print(json.dumps(dataclasses.asdict(probe())))
    else:
        sys.exit('usage: netns.py probe | delay-line TAP DEV DELAY_S')
