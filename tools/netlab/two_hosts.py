"""The live graph across two hosts: the sim in host A; correction, validator, recorder and a
watcher in host B; the hosts are network namespaces joined by a veth pair (``netns.TwoHosts``).

Discovery is configured as a lab would, in one of two ways (``DISCOVERY``):

* ``static_peers``: ``ROS_STATIC_PEERS=<the other host>`` with ``ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET``,
  and ``FASTDDS_BUILTIN_TRANSPORTS=UDPv4``;
* ``xml``: a Fast DDS profile (``FASTRTPS_DEFAULT_PROFILES_FILE``) with one UDPv4 transport, no
  built-in transports and both hosts as initial peers, with ``ROS_AUTOMATIC_DISCOVERY_RANGE=SYSTEM_DEFAULT``
  so the rmw leaves the profile's discovery alone.

Both turn Fast DDS's shared-memory transport off. Fast DDS uses it between participants it takes
to be on one host (the same host id, which it derives from the interface addresses); /dev/shm is
shared by the namespaces, so the data could then bypass the link. (With it left on, our runs still
crossed the veth, the two namespaces having different addresses; off, it cannot happen.) The veth
counters and the RTPS packet counter show that the data crossed the link.

``python -m netlab.two_hosts watch`` is the watcher: run in host B, it prints every score, the
recorder's progress and the readers of the topics that cross the link as JSON lines.
"""
from __future__ import annotations

import dataclasses
import json
import os
import queue
import re
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

from force_tester_common.core.channels import BLOCK_TYPES, PULL_EVENT_TOPIC
from ft_cli.graph import Graph, ScoreCollector, ros_param_args
from ft_cli.paths import executable

from .netns import DEV, Host, Impairment, TwoHosts

DISCOVERY = ('static_peers', 'xml')
SNIFF = Path(__file__).resolve().with_name('rtps_sniff.py')
BLOCK_TOPIC_NAMES = tuple(topic for topic, _fields in BLOCK_TYPES.values())
LINK_TOPICS = (*BLOCK_TOPIC_NAMES, PULL_EVENT_TOPIC)   # published in host A, read in host B
B_NODES = (('force_correction', 'correction_node'), ('force_correction', 'validator_node'),
           ('bag_tools', 'recorder_node'))
READERS = 3   # /force: correction, validator, recorder; /pull_event: validator, recorder, watcher
DONE_RE = re.compile(r'done: (\d+) pull\(s\), (\d+) samples per channel, (\d+) blocks per topic')
_DISCOVERY_VARS = ('ROS_LOCALHOST_ONLY', 'ROS_AUTOMATIC_DISCOVERY_RANGE', 'ROS_STATIC_PEERS',
                   'FASTDDS_BUILTIN_TRANSPORTS', 'FASTRTPS_DEFAULT_PROFILES_FILE', 'FASTDDS_DEFAULT_PROFILES_FILE',
                   'RMW_FASTRTPS_USE_QOS_FROM_XML')


# Blocks across the link: 1 ms (50 samples, 0.4-1.6 KB a message, one or two IP packets). 10 ms
# blocks (8-16 KB, a dozen IP fragments: losing one loses the message) did not get through the
# lossy link (2 % loss, 5 ms delay): reliable resends fell behind and the sim exited with
# unacknowledged blocks. docs/nodes.md, "Across two hosts".
LINK_BLOCK_SAMPLES = 50


def fastdds_profile(peers) -> str:
    """A Fast DDS (2.x) XML profile: UDPv4 only (no shared memory), the given hosts as initial peers."""
    locators = ''.join(f'<locator><udpv4><address>{p}</address></udpv4></locator>' for p in peers)
    return ('<?xml version="1.0" encoding="UTF-8" ?>\n'
            '<dds><profiles xmlns="http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles">\n'
            '  <transport_descriptors><transport_descriptor>\n'
            '    <transport_id>udp_only</transport_id><type>UDPv4</type>\n'
            '  </transport_descriptor></transport_descriptors>\n'
            '  <participant profile_name="two_hosts" is_default_profile="true"><rtps>\n'
            '    <userTransports><transport_id>udp_only</transport_id></userTransports>\n'
            '    <useBuiltinTransports>false</useBuiltinTransports>\n'
            f'    <builtin><initialPeersList>{locators}</initialPeersList></builtin>\n'
            '  </rtps></participant>\n'
            '</profiles></dds>\n')


def host_env(host: Host, hosts, discovery: str, profile: Path, base: dict | None = None) -> dict:
    """The environment of a node in ``host``: the workspace's, with discovery set for two hosts."""
    if discovery not in DISCOVERY:
        raise ValueError(f'discovery {discovery!r} is unknown; expected one of {list(DISCOVERY)}')
    env = {k: v for k, v in (os.environ if base is None else base).items() if k not in _DISCOVERY_VARS}
    env['PYTHONUNBUFFERED'] = '1'
    if discovery == 'static_peers':
        env.update(ROS_AUTOMATIC_DISCOVERY_RANGE='SUBNET', FASTDDS_BUILTIN_TRANSPORTS='UDPv4',
                   ROS_STATIC_PEERS=';'.join(h.address for h in hosts if h != host))
    else:
        env.update(ROS_AUTOMATIC_DISCOVERY_RANGE='SYSTEM_DEFAULT', FASTRTPS_DEFAULT_PROFILES_FILE=str(profile))
    return env


class HostGraph(Graph):
    """Node processes started inside one host (its namespace) with that host's environment."""

    def __init__(self, log_dir: Path, host: Host, env: dict):
        super().__init__(log_dir)
        self.host = host
        self.env = env

    def start_cmd(self, name: str, cmd: list, stdout=None) -> subprocess.Popen:
        log = open(self.log_dir / f'{name}.log', 'a')
        self.procs[name] = subprocess.Popen([*self.host.prefix(), *cmd], env=self.env, stdin=subprocess.DEVNULL,
                                            stdout=stdout or log, stderr=log)
        return self.procs[name]

    def start(self, package: str, name: str, params: dict | None = None, extra: list | None = None):
        return self.start_cmd(name, [str(executable(package, name)), *(extra or []),
                                     *ros_param_args(params or {})])


@dataclasses.dataclass
class LinkRun:
    """One run of the graph across the two hosts, and what the link carried."""
    link: str                 # Impairment.describe()
    method: str               # how loss and delay were made
    discovery: str
    complete: bool            # every pull scored and every block recorded before the timeout
    problem: str              # why not, with the last lines of a log
    sent: dict                # topic -> messages the sim published (its own count)
    received: dict            # topic -> messages in host B's bag
    seq_gaps: dict            # topic -> blocks missing in the bag's sequence numbers
    scores: list
    readers: dict             # topic -> subscribers in host B (each gets its own copy over the link)
    cdr_bytes: dict           # topic -> serialized bytes of the messages in the bag (one copy)
    payload_bytes: int        # the copies host B's readers needed: sum of cdr_bytes x readers
    counters: dict            # netns.TwoHosts.counters() at the end
    sniffed: dict             # host -> what it sent, from rtps_sniff (retransmissions counted)
    seconds: float
    left: list                # namespaces left after the run (none)

    @property
    def wire_ratio(self) -> float:
        """Bytes host A put on the link (lost ones too) per payload byte."""
        return self.counters['a']['tx_bytes'] / self.payload_bytes if self.payload_bytes else float('nan')

    @property
    def retransmitted(self) -> float:
        """User-data bytes host A sent again, per user-data byte it sent the first time."""
        a = self.sniffed.get('a', {})
        return a['data_again_bytes'] / a['data_first_bytes'] if a.get('data_first_bytes') else float('nan')

    def as_dict(self) -> dict:
        return {**dataclasses.asdict(self), 'wire_ratio': self.wire_ratio, 'retransmitted': self.retransmitted}


class _Lines:
    """A process's stdout, read by a thread into a queue of parsed JSON lines."""

    def __init__(self, stream):
        self.queue = queue.Queue()
        threading.Thread(target=self._read, args=(stream,), daemon=True).start()

    def _read(self, stream):
        for line in stream:
            try:
                self.queue.put(json.loads(line))
            except ValueError:
                continue

    def get(self, timeout: float):
        try:
            return self.queue.get(timeout=timeout)
        except queue.Empty:
            return None


def sent_by_sim(log: Path) -> dict:
    """What the sim says it published (its log's last 'done:' line): topic -> messages."""
    found = DONE_RE.findall(log.read_text(errors='replace')) if log.is_file() else []
    if not found:
        return {}
    pulls, _samples, blocks = (int(x) for x in found[-1])
    return {**{t: blocks for t in BLOCK_TOPIC_NAMES}, PULL_EVENT_TOPIC: 2 * pulls}


def bag_counts(bag: Path) -> tuple:
    """(messages, sequence gaps, serialized bytes) per topic of the recorded bag."""
    from bag_tools.core.errors import BagError
    from bag_tools.core.info import bag_info
    from bag_tools.core.reader import open_bag
    try:
        info = bag_info(bag)['topics']
    except BagError:  # a closed bag with no message: nothing crossed
        return {t: 0 for t in LINK_TOPICS}, {}, {}
    size = {}
    with open_bag(bag) as b:
        for topic, _type, _stamp, cdr in b.messages(list(LINK_TOPICS)):
            size[topic] = size.get(topic, 0) + len(cdr)
    return ({t: info.get(t, {}).get('count', 0) for t in LINK_TOPICS},
            {t: info[t].get('seq_gaps', 0) for t in BLOCK_TOPIC_NAMES if t in info}, size)


def run_two_hosts(out: Path, impairment: Impairment | None = None, discovery: str = 'static_peers',
                  sets=(1,), pulls: int = 1, rate: float = 1.0, seed: int = 0, timeout: float = 240.0,
                  say=print) -> LinkRun:
    """Run the sim in host A and the rest in host B until every pull is scored and the recorder
    holds every message the sim published (or ``timeout``); stop everything, delete both hosts.
    ``out`` gets the bag, the nodes' logs per host and the Fast DDS profile (an earlier run's
    bag and logs there are removed first)."""
    impairment = impairment or Impairment()
    bag = out / 'bag'
    for old in (bag, out / 'logs'):  # an earlier run's
        if old.exists():
            shutil.rmtree(old)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.monotonic()
    expected = len(sets) * pulls
    scores, recorded, readers, problem = [], {}, {}, ''
    net = TwoHosts(impairment, log_dir=out)
    with net:
        profile = out / 'fastdds_two_hosts.xml'
        profile.write_text(fastdds_profile([h.address for h in net.hosts]))
        graphs = {h.name: HostGraph(out / 'logs' / f'host_{h.name}', h,
                                    host_env(h, net.hosts, discovery, profile)) for h in net.hosts}
        a, b = graphs['a'], graphs['b']
        say(f'two hosts: {net.a.netns} ({net.a.address}) and {net.b.netns} ({net.b.address}); '
            f'{impairment.describe()} ({net.method}); discovery {discovery}')
        sniffers = {h.name: net.start(h, f'sniff_{h.name}', [sys.executable, str(SNIFF), DEV]) for h in net.hosts}
        for h, proc in sniffers.items():
            if proc.stdout.readline().strip() != b'ready':
                raise RuntimeError(f'the packet counter in host {h} did not start (exit {proc.poll()})')
        try:
            for package, name in B_NODES:
                b.start(package, name, {'bag_path': str(bag)} if name == 'recorder_node' else None)
            watcher = _Lines(b.start_cmd('watcher', [sys.executable, '-m', 'netlab.two_hosts', 'watch'],
                                         stdout=subprocess.PIPE).stdout)
            deadline = t0 + timeout
            sent, sim = {}, None
            while time.monotonic() < deadline:
                item = watcher.get(timeout=0.2)
                if item is not None:
                    if 'score' in item:
                        scores.append(item['score'])
                        say(f"two hosts: pull {item['score']['pull_id']} scored {item['score']['status']}")
                    recorded = item.get('recorder', recorded)
                    readers = item.get('readers', readers)
                if sim is None and min(readers.get(t, 0) for t in ('/force', PULL_EVENT_TOPIC)) >= READERS:
                    # host B's graph is up (as the demo waits for its local graph): the sim may start
                    sim = a.start('force_tester_sim', 'sim_node', {
                        'test_sets': '[' + ','.join(str(s) for s in sets) + ']', 'pulls_per_set': pulls,
                        'seed': seed, 'rate': float(rate), 'wait_for_subscribers': READERS, 'exit_when_done': True,
                        'block_size': LINK_BLOCK_SAMPLES})
                dead = [n for n, p in {**a.procs, **b.procs}.items() if p.poll() not in (None, 0)]
                if dead or b.procs['watcher'].poll() is not None:
                    problem = f'{(dead or ["watcher"])[0]} stopped'
                    break
                if sim is not None and sim.poll() == 0 and not sent:
                    sent = sent_by_sim(a.log_dir / 'sim_node.log')
                    if not sent:
                        problem = 'the sim exited without its done: line'
                        break
                if sent and len(scores) >= expected and all(
                        int(recorded.get(t, 0)) >= n for t, n in sent.items()):
                    break
            else:
                problem = (f'timed out after {timeout:g} s: {len(scores)} of {expected} pulls scored; '
                           f'sent {sent or ("(sim still running)" if sim else "(sim not started: no readers in B)")}, '
                           f'recorder reports {recorded}')
        finally:
            codes = {**b.stop(), **a.stop()}
        counters = net.counters()
        sniffed = {}
        for h, proc in sniffers.items():
            proc.terminate()
            line = proc.stdout.readline()
            sniffed[h] = json.loads(line) if line.strip() else {}
    left = net.left()
    if not problem and codes.get('recorder_node') not in (0, -signal.SIGINT):
        problem = f'the recorder exited with {codes.get("recorder_node")}'
    received, gaps, size = {}, {}, {}
    if (bag / 'metadata.yaml').is_file():
        received, gaps, size = bag_counts(bag)
    elif not problem:
        problem = 'the recorder did not close its bag'
    if problem:
        name = next((n for n in ('sim_node', 'recorder_node', 'validator_node', 'correction_node', 'watcher')
                     if n in problem), 'sim_node')
        graph = a if name == 'sim_node' else b
        problem += f'\nlast lines of {name}:\n{graph.tail(name)}'
    payload = sum(size.get(t, 0) * int(readers.get(t, 0)) for t in LINK_TOPICS)
    return LinkRun(link=impairment.describe(), method=net.method, discovery=discovery, complete=not problem,
                   problem=problem, sent=sent, received=received, seq_gaps=gaps,
                   scores=sorted(scores, key=lambda s: s['pull_id']), readers=readers, cdr_bytes=size,
                   payload_bytes=payload, counters=counters, sniffed=sniffed, seconds=time.monotonic() - t0, left=left)


def watch() -> int:
    """Host B's watcher: every /pull_score, the recorder's progress and the readers of LINK_TOPICS
    (its own /pull_event reader included), as JSON lines on stdout, until SIGINT."""
    from force_tester_msgs.msg import PullEvent
    from rclpy.executors import ExternalShutdownException

    from force_tester_common.ros import EVENT_QOS
    collector = ScoreCollector()
    collector.node.create_subscription(PullEvent, PULL_EVENT_TOPIC, lambda _msg: None, EVENT_QOS)
    emitted, last_recorded, last_readers = 0, None, None

    def emit(**item):
        print(json.dumps(item), flush=True)
    try:
        while True:
            collector.executor.spin_once(timeout_sec=0.1)
            for score in collector.scores[emitted:]:
                emit(score=score)
            emitted = len(collector.scores)
            if collector.recorded and collector.recorded[-1][1] != last_recorded:
                last_recorded = collector.recorded[-1][1]
                emit(recorder=last_recorded)
            now = {t: collector.node.count_subscribers(t) for t in LINK_TOPICS}
            if now != last_readers:
                last_readers = now
                emit(readers=now)
    except (KeyboardInterrupt, ExternalShutdownException):
        return 0
    finally:
        collector.close()


if __name__ == '__main__':
    if sys.argv[1:] != ['watch']:
        sys.exit('usage: python -m netlab.two_hosts watch')
    sys.exit(watch())
