"""sim node: publishes the simulated rig's motor, encoder, accelerometer and force topics in blocks.

Topics: /motor, /encoder, /accel, /force (sample blocks, header stamped at the block's first
sample), /pull_event (start and end of each 2 s pull), /diagnostics.
Each pull is simulated by the ROS-free core (one pull ahead, in a worker process) and published
block by block on a sample clock that starts when the node starts publishing; the pace is real
time by default (parameter ``rate`` > 1 runs faster). Changed parameters apply from the next pull.
"""
from __future__ import annotations

import multiprocessing
import os
import threading
import time
from concurrent.futures import ProcessPoolExecutor

from force_tester_msgs.msg import ForceBlock, PullEvent
from rclpy.duration import Duration
from rclpy.node import Node

from force_tester_common.conversions import BLOCK_TOPICS, block_message, ns_to_stamp
from force_tester_common.core.blocks import BLOCK_SAMPLES, BLOCK_SAMPLES_RANGE
from force_tester_common.core.channels import PULL_EVENT_TOPIC
from force_tester_common.core.clock import sample_stamp_ns
from force_tester_common.node_params import NodeParams, ParamSpec
from force_tester_common.ros import BLOCK_QOS, ERROR, EVENT_QOS, OK, WARN, Diagnostics, in_namespace, main_for

from .core.errors import SimError
from .core.sim_config import SimConfig, block_bounds
from .core.simulate import simulate_pull
from .core.worker import exit_with_parent, keep_sigint_from_workers

WAIT_TIMEOUT_S = 120.0   # wait_for_subscribers: how long by default before the sim gives up
FORCE_TOPIC = next(t.topic for t in BLOCK_TOPICS if t.msg_type is ForceBlock)
# what reads each topic the sim waits on (the hint when its readers do not come)
READERS = {PULL_EVENT_TOPIC: 'a validator_node or a recorder_node',
           FORCE_TOPIC: 'a correction_node, a validator_node or a recorder_node'}

SPECS = [
    ParamSpec('test_sets', [1, 2, 3, 4, 5], 'test sets to run, in order (thesis Table 4: 1..5)'),
    ParamSpec('pulls_per_set', 1, 'pulls of each test set', (1, 1000)),
    ParamSpec('seed', 0, 'seed of the pull-to-pull scatter and the sensor noise', (0, 2**31 - 1)),
    ParamSpec('block_size', BLOCK_SAMPLES, 'samples per published block (500 = 10 ms at 50 kHz)', BLOCK_SAMPLES_RANGE),
    ParamSpec('rate', 1.0, 'pace as a real-time factor (1.0 = real time)', (0.01, 1000.0)),
    ParamSpec('rig_file', '', 'rig YAML replacing the nominal constants ("" = nominal)'),
    ParamSpec('noise', True, 'add sensor noise'),
    ParamSpec('drive', True, 'carriage from the motor/PID drive model coupled to the force chain (motor '
                             'channels from the model); false: the prescribed motion profile'),
    ParamSpec('coupons', 'rated', "'rated': coupons break at their rating; 'measured': at thesis Table 7's "
                                  "measured levels, yielding first (the reference campaign's coupons)"),
    ParamSpec('wait_for_subscribers', 1, 'before publishing, wait until /force and /pull_event each have this '
                                         'many matched subscribers, and no more match for SETTLE_S (0: at once)',
              (0, 100), read_only=True),
    ParamSpec('wait_for_block_subscribers', 0, 'wait_for_subscribers for /force alone, when it has more readers '
                                               'than /pull_event (the correction nodes read it too; 0: as many as '
                                               'wait_for_subscribers)', (0, 100), read_only=True),
    ParamSpec('wait_timeout_s', WAIT_TIMEOUT_S, 'wait_for_subscribers: give up after this many seconds '
                                                'without the readers: the node exits (code 2) with one line '
                                                'naming the topics, their readers and what to start (0: wait '
                                                'for good)', (0.0, 86400.0), read_only=True),
    ParamSpec('exit_when_done', False, 'shut the node down after the last pull (once the '
              'subscribers have acknowledged every block, at most ACK_TIMEOUT_S)'),
]
# The worker process simulating the next pull is replaced after this many pulls: its RSS grew by
# about 1 MB a pull (491 -> 777 MB over the 10-minute soak's 300 pulls), and a fresh one starts
# well within the 2 s a pull takes to publish.
WORKER_PULLS = 50
ACK_TIMEOUT_S = 30.0  # exit_when_done: how long to wait for lagging subscribers
SETTLE_S = 1.0        # wait_for_subscribers: no new subscriber for this long, so none misses the first START
# wait_for_subscribers, wait_for_block_subscribers and wait_timeout_s are read-only: the wait is over once the
# first pull starts, so a change at run time would be accepted and do nothing
CONFIG_FIELDS = ('pulls_per_set', 'seed', 'block_size', 'rate', 'rig_file', 'noise', 'coupons', 'drive')


def config_from(values: dict) -> SimConfig:
    return SimConfig(test_sets=tuple(int(s) for s in values['test_sets']),
                     **{k: values[k] for k in CONFIG_FIELDS})


def waiting_for(wants) -> str:
    """'waiting for N on each' or 'waiting for N and M' (the /pull_event and /force readers wanted)."""
    return f'waiting for {wants[0]} on each' if wants[0] == wants[1] else f'waiting for {wants[0]} and {wants[1]}'


class SimNode(Node):
    def __init__(self, **kwargs):
        super().__init__('sim', **kwargs)
        self.params = NodeParams(self, SPECS, config_from)
        self.failure = None   # why the node stopped itself (spin_nodes prints it and exits non-zero)
        self.progress = {'pulls': 0, 'blocks_per_topic': 0}   # published so far: the heartbeat's counters
        self.diag = Diagnostics(self, 'simulator', counters=lambda: self.progress)
        self.block_pubs = [(t, self.create_publisher(t.msg_type, in_namespace(t.topic), BLOCK_QOS))
                           for t in BLOCK_TOPICS]
        self.event_pub = self.create_publisher(PullEvent, in_namespace(PULL_EVENT_TOPIC), EVENT_QOS)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name='sim-publisher', daemon=True)
        self._thread.start()

    # -- the publishing thread -------------------------------------------------------------
    def _schedule(self, config: SimConfig):
        rig = config.rig()
        pull_id = 0
        for test_set in config.test_sets:
            for spec in config.pull_specs(rig, test_set, config.seed + 7919 * test_set):
                yield pull_id, rig, spec
                pull_id += 1

    def _run(self):
        try:
            self._publish_all()
        except Exception as exc:  # noqa: BLE001 - keep the node alive and say what went wrong
            if self._stop.is_set():   # the node is shutting down (Ctrl-C): its pool and context go away
                return
            self.diag.report(ERROR, f'simulation stopped: {exc}', latch=True)

    def _wait_for_subscribers(self, want: int, want_blocks: int, timeout_s: float) -> bool:
        """Wait until the event publisher has ``want`` matched subscribers and the block publisher
        ``want_blocks`` (0: want), and the counts have not changed for SETTLE_S (readers discovered
        together all match; a pull event or block sent before a reader matched would be lost to it).
        False if the node stops, or after ``timeout_s`` (0: no limit): then the node fails
        (``failure``, one line)."""
        if not want and not want_blocks:
            return True
        pubs = [self.event_pub] + [p for t, p in self.block_pubs if t.topic == FORCE_TOPIC]
        wants = [want, want_blocks or want]
        counts, start = None, time.monotonic()
        since = start
        while True:
            now = [p.get_subscription_count() for p in pubs]
            if now != counts:
                counts, since = now, time.monotonic()
                self.get_logger().info('matched subscribers: ' + ', '.join(
                    f'{p.topic_name} {n}' for p, n in zip(pubs, now)) + f' ({waiting_for(wants)})')
            if all(n >= w for n, w in zip(now, wants)) and time.monotonic() - since >= SETTLE_S:
                return True
            if timeout_s and time.monotonic() - start >= timeout_s:
                self._give_up(pubs, now, wants, timeout_s)
                return False
            if self._stop.wait(0.05):
                return False

    def _give_up(self, pubs, counts, wants, timeout_s: float) -> None:
        """The readers never came: one line saying which topics (resolved names), the readers they
        have, the readers wanted and what to start; then the node shuts down (spin_nodes prints it)."""
        have = []
        for pub, n in zip(pubs, counts):
            nodes = sorted({f"{i.node_namespace.rstrip('/')}/{i.node_name}"
                            for i in self.get_subscriptions_info_by_topic(pub.topic_name)})
            have.append(f"{pub.topic_name} has {n} ({', '.join(nodes) or 'no reader'})")
        short = [(pub.topic_name, topic)
                 for pub, n, w, topic in zip(pubs, counts, wants, (PULL_EVENT_TOPIC, FORCE_TOPIC)) if n < w]
        start = '; '.join(f'{name}: {READERS[topic]}' for name, topic in short)
        namespace = self.get_namespace()
        where = f' with -r __ns:={namespace}' if namespace != '/' else ''
        params = (f'wait_for_subscribers {wants[0]}' + ('' if wants[0] == wants[1] else
                                                       f', wait_for_block_subscribers {wants[1]}'))
        self.failure = SimError(
            f'no readers after {timeout_s:g} s (wait_timeout_s): {"; ".join(have)}; {waiting_for(wants)} '
            f'({params}). Start the missing '
            f'reader(s){where} ({start}), or set wait_for_subscribers to the readers you run')
        self.diag.report(ERROR, str(self.failure), log=False, latch=True)
        self.context.try_shutdown()

    def _publish_all(self):
        values = self.params.values
        if not self._wait_for_subscribers(values['wait_for_subscribers'], values['wait_for_block_subscribers'],
                                          values['wait_timeout_s']):
            return
        config = self.params.config
        pulls = list(self._schedule(config))
        self.diag.report(OK, f'publishing {len(pulls)} pull(s) of sets {list(config.test_sets)}')
        t0_ns = t0_mono = None   # the sample clock starts once the first pull is simulated
        index = 0  # samples published so far: the sample clock
        seqs = [0] * len(self.block_pubs)
        # the next pull is simulated in a worker process, so the publishing thread keeps its pace
        # (with SIGINT blocked: a terminal's Ctrl-C reaches the whole process group, and shutting the
        # worker down is this node's job)
        keep_sigint_from_workers()
        with ProcessPoolExecutor(max_workers=1, mp_context=multiprocessing.get_context('spawn'),
                                 max_tasks_per_child=WORKER_PULLS, initializer=exit_with_parent,
                                 initargs=(os.getpid(),)) as pool:
            def simulate(i):
                _, rig, spec = pulls[i]
                return pool.submit(simulate_pull, rig, spec, config.noise, config.drive)
            upcoming = simulate(0) if pulls else None
            for i, (pull_id, rig, spec) in enumerate(pulls):
                channels = upcoming.result()
                upcoming = simulate(i + 1) if i + 1 < len(pulls) else None
                if t0_ns is None:   # (the worker process's start-up is not the data's lateness)
                    t0_ns, t0_mono = time.time_ns(), time.monotonic()
                rate_hz = rig.daq.sample_rate_hz
                n = len(channels['time_s'])
                config = self.params.config  # parameter changes apply from here
                self._event(PullEvent.START, sample_stamp_ns(t0_ns, index, rate_hz), pull_id, rig, spec)
                for start, stop in block_bounds(n, config.block_size):
                    due = (index + stop) / rate_hz / config.rate  # the block's last sample has happened
                    delay = due - (time.monotonic() - t0_mono)
                    if delay > 0 and self._stop.wait(delay):
                        return
                    stamp = sample_stamp_ns(t0_ns, index + start, rate_hz)
                    for k, (topic, pub) in enumerate(self.block_pubs):
                        pub.publish(block_message(topic, channels, start, stop, stamp, rate_hz, seqs[k]))
                        seqs[k] += 1
                    self.progress['blocks_per_topic'] = seqs[0]
                index += n
                self._event(PullEvent.END, sample_stamp_ns(t0_ns, index, rate_hz), pull_id, rig, spec)
                self.progress['pulls'] += 1
        self.diag.report(OK, f'done: {len(pulls)} pull(s), {index} samples per channel, {seqs[0]} blocks per topic',
                         blocks_per_topic=seqs[0])
        if self.params.values['exit_when_done']:
            # a reliable reader that lags (a recorder on a busy machine) has not acknowledged
            # the last blocks yet; they would be lost with this process
            late = [pub.topic_name for pub in [*(p for _t, p in self.block_pubs), self.event_pub]
                    if not pub.wait_for_all_acked(Duration(seconds=ACK_TIMEOUT_S))]
            if late:
                self.diag.report(WARN, f'exiting with unacknowledged messages on {late} after '
                                 f'{ACK_TIMEOUT_S:g} s')
            self.context.try_shutdown()

    def _event(self, kind, stamp_ns, pull_id, rig, spec):
        msg = PullEvent(event=kind, pull_id=pull_id, test_set=spec.test_set,
                        coupon_break_n=float(rig.test_set(spec.test_set).coupon_n),
                        velocity_m_s=float(spec.velocity_m_s), decel_m_s2=float(spec.decel_m_s2))
        msg.header.stamp = ns_to_stamp(stamp_ns)
        self.event_pub.publish(msg)

    def close(self):
        self._stop.set()
        self._thread.join(timeout=2.0)


main = main_for(SimNode)
