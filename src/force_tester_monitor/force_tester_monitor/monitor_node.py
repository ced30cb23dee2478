"""monitor node: the live graph for viewers.

- A Foxglove WebSocket server (foxglove-sdk, 127.0.0.1, parameter ``port``) that forwards the
  graph's topics unchanged: CDR messages on channels with the full ``pkg/msg/Type`` name and the
  embedded ros2msg definition, as in our bags, so one Foxglove layout serves a live graph, a bag
  played back and an opened bag file.
- The derived topics /monitor/force, /monitor/pull_trace, /monitor/pull_score, /monitor/score_history,
  /monitor/nodes (the viewer's Nodes tab: core/nodes.py) and /monitor/health, published on ROS
  (for PlotJuggler and rqt) and forwarded the same way.
- The graph's node parameters for Foxglove's Parameters panel (read from /parameter_events and the
  nodes' parameter services; a set from the panel goes to the node's parameter service).

Namespaces: on ROS the node subscribes and publishes relative names, so under ``-r __ns:=/rig3`` it watches
``/rig3/force``, ... and publishes ``/rig3/monitor/*`` (remaps apply); /diagnostics stays the machine's. Its
Foxglove channels keep the graph's names (``/force``, ``/monitor/force``): one monitor (one port) serves one
rig, and the one layout works for any rig.

The server is ``foxglove_bridge``, the parameters ``parameter_proxy``; this node wires them to the
graph's topics and publishes the derived topics.

It subscribes to serialized messages with best-effort, keep-last QoS: a slow monitor (or a slow
viewer behind it) loses messages of its own and never delays a publisher. The server keeps at
most ``backlog`` messages per client and drops the oldest beyond that, so a client that stops
reading costs memory that is bounded and nothing else. The arithmetic is in ``core/``.
"""
from __future__ import annotations

import logging
import time
from collections import defaultdict

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from force_tester_msgs.msg import (
    MonitorForce,
    MonitorHealth,
    MonitorScore,
    PullEvent,
    PullScore,
    PullTrace,
    ScoreRow,
    SetRow,
    SetSummary,
    TopicHealth,
)
from force_tester_msgs.msg import ScoreHistory as ScoreHistoryMsg
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message, serialize_message

from force_tester_common.conversions import message_class, ns_to_stamp, to_field
from force_tester_common.core import channels as CH
from force_tester_common.core.clock import NS_PER_S
from force_tester_common.core.health import HOLD_S, NodeStates, level_of
from force_tester_common.node_params import NodeParams, ParamSpec
from force_tester_common.ros import (
    EVENT_QOS,
    LATCHED_QOS,
    OK,
    SCORE_QOS,
    SUMMARY_QOS,
    WARN,
    Diagnostics,
    in_namespace,
    main_for,
    steady_timer,
)

from .core import params as P
from .core.batch import decode_batch
from .core.health import TopicStats, recorder_counts
from .core.history import ScoreHistory
from .core.live import SIGNALS, ForceJoin, LiveTrace, PullTraces, score_lbf
from .core.nodes import NODES_PERIOD_S, node_rows
from .foxglove_bridge import FoxgloveBridge, sdk_version
from .parameter_proxy import ParameterProxy

DIAGNOSTICS_TYPE = 'diagnostic_msgs/msg/DiagnosticArray'

SPECS = [
    ParamSpec('host', P.HOST, 'address the Foxglove WebSocket listens on (0.0.0.0: every interface, for browsers '
                              'on the lab network)', read_only=True),
    ParamSpec('port', P.PORT, 'Foxglove WebSocket port (0: any free port)', P.PORT_RANGE, read_only=True),
    ParamSpec('force_every', P.FORCE_EVERY, '/force_corrected blocks per /monitor/force message',
              P.FORCE_EVERY_RANGE, read_only=True),
    ParamSpec('period_s', P.PERIOD_S, 'the monitor works through what arrived this often', P.PERIOD_RANGE_S,
              read_only=True),
    ParamSpec('health_period_s', P.HEALTH_PERIOD_S, '/monitor/health period', P.HEALTH_PERIOD_RANGE_S,
              read_only=True),
    ParamSpec('health_window_s', P.HEALTH_WINDOW_S, 'span of the rates and latency percentiles',
              P.HEALTH_WINDOW_RANGE_S, read_only=True),
    ParamSpec('trace_margin_s', P.TRACE_MARGIN_S, 'pull trace: time kept before and after the loaded window',
              P.TRACE_MARGIN_RANGE_S, read_only=True),
    ParamSpec('max_trace_s', P.MAX_TRACE_S, 'pull trace: at most this much of a pull is kept',
              P.MAX_TRACE_RANGE_S, read_only=True),
    ParamSpec('trace_timeout_s', P.TRACE_TIMEOUT_S, "an ended pull's trace goes out when no block came for this long "
                                                    '(the data stopped short)', P.TRACE_TIMEOUT_RANGE_S,
              read_only=True),
    ParamSpec('history_rows', P.HISTORY_ROWS, '/monitor/score_history: the newest pulls it lists',
              P.HISTORY_ROWS_RANGE, read_only=True),
    ParamSpec('backlog', P.BACKLOG, 'messages the server queues per client (the oldest is dropped when full)',
              P.BACKLOG_RANGE, read_only=True),
    ParamSpec('depth', P.DEPTH, 'subscription queue depth (best effort, keep last)', P.DEPTH_RANGE,
              read_only=True),
    ParamSpec('on_demand', P.ON_DEMAND, f'subscribe to {", ".join(P.ON_DEMAND_TOPICS)} only while a Foxglove '
                                        'client watches them (false: always)', read_only=True),
]


def _config(values: dict) -> P.MonitorParams:
    return P.MonitorParams(**values)


# topic -> (type name, float64[] fields or None for a non-block topic)
FORWARDED = {topic: (t, tuple(fields)) for t, (topic, fields) in CH.BLOCK_TYPES.items()}
FORWARDED[CH.CORRECTED_TYPE[1][0]] = (CH.CORRECTED_NAME, CH.CORRECTED_FIELDS)
FORWARDED.update({CH.PULL_EVENT_TOPIC: (CH.PULL_EVENT_TYPE, None),
                  CH.PULL_SCORE_TOPIC: (CH.PULL_SCORE_TYPE, None),
                  CH.SET_SUMMARY_TOPIC: (CH.SET_SUMMARY_TYPE, None),
                  CH.DIAGNOSTICS_TOPIC: (DIAGNOSTICS_TYPE, None)})
DERIVED = {CH.MONITOR_FORCE_TOPIC: (CH.MONITOR_FORCE_TYPE, MonitorForce),
           CH.PULL_TRACE_TOPIC: (CH.PULL_TRACE_TYPE, PullTrace),
           CH.MONITOR_SCORE_TOPIC: (CH.MONITOR_SCORE_TYPE, MonitorScore),
           CH.SCORE_HISTORY_TOPIC: (CH.SCORE_HISTORY_TYPE, ScoreHistoryMsg),
           CH.MONITOR_HEALTH_TOPIC: (CH.MONITOR_HEALTH_TYPE, MonitorHealth),
           CH.MONITOR_NODES_TOPIC: (DIAGNOSTICS_TYPE, DiagnosticArray)}
FORCE_TOPIC = CH.BLOCK_TYPES[CH.FORCE_TYPE][0]
CORRECTED = CH.CORRECTED_TYPE[1][0]


def ros_name(topic: str) -> str:
    """The name the node gives rclpy for a graph topic: relative (in its namespace), but /diagnostics."""
    return topic if topic == CH.DIAGNOSTICS_TOPIC else in_namespace(topic)


def _qos(topic: str, depth: int) -> QoSProfile:
    """Scores and the set summary: reliable and transient local, as published (keep last: the
    publisher never waits for us), so a monitor started late gets them. Everything else: best
    effort, keep last ``depth``."""
    if topic == CH.PULL_SCORE_TOPIC:
        return SCORE_QOS
    if topic == CH.SET_SUMMARY_TOPIC:
        return SUMMARY_QOS
    if topic == CH.PULL_EVENT_TOPIC:
        return EVENT_QOS
    return QoSProfile(depth=depth, reliability=ReliabilityPolicy.BEST_EFFORT, history=HistoryPolicy.KEEP_LAST)


class MonitorNode(Node):
    def __init__(self, **kwargs):
        super().__init__('monitor', **kwargs)
        self.diag = Diagnostics(self, 'live monitor')
        self.params = NodeParams(self, SPECS, _config)
        cfg: P.MonitorParams = self.params.config
        self.cfg = cfg
        self.counts = defaultdict(int)
        self.parameters = ParameterProxy(self, self.diag, lambda ps: self.bridge.publish_parameters(ps))
        types = {**{t: n for t, (n, _f) in FORWARDED.items()}, **{t: n for t, (n, _c) in DERIVED.items()}}
        self.bridge = FoxgloveBridge(types, cfg.host, cfg.port, cfg.backlog, parameters=self.parameters,
                                     on_watch=self._update_watched, on_client_message=self._client_message,
                                     on_sdk_log=self._sdk_log, on_subscribe=self._client_subscribed)
        self.channels = self.bridge.channels
        self.port = self.bridge.port
        self.diag.report(OK, f'Foxglove WebSocket at ws://{cfg.host}:{self.port} (foxglove-sdk '
                             f'{sdk_version()}, subprotocol foxglove.sdk.v1)', port=self.port)

        self.pending = {topic: [] for topic in FORWARDED}
        self.stats = {topic: TopicStats(topic, cfg.health_window_s) for topic in FORWARDED}
        self.join = ForceJoin()
        self.live = LiveTrace(cfg.force_every)
        self.traces = PullTraces(cfg.trace_margin_s, cfg.max_trace_s, cfg.trace_timeout_s)
        self.history = ScoreHistory(cfg.history_rows)
        self.recorder = {}
        self.recorder_seen_ns = None
        self.node_states = NodeStates(hold_s=HOLD_S)   # the Nodes panel's rows (/monitor/nodes)
        self.last_trace = None   # the last /monitor/pull_trace, sent again to a client that subscribes
        # the score history latched (the newest only), so a late `ros2 topic echo --once` gets it
        self.pubs = {topic: self.create_publisher(cls, ros_name(topic),
                                                  LATCHED_QOS if topic == CH.SCORE_HISTORY_TOPIC else EVENT_QOS)
                     for topic, (_n, cls) in DERIVED.items()}
        self.force_seq = 0
        self.on_demand = P.ON_DEMAND_TOPICS if cfg.on_demand else ()
        self.subs = {}           # topic -> its rclpy subscription, while watched
        for topic in FORWARDED:
            if topic not in self.on_demand:
                self._watch(topic)
        steady_timer(self, cfg.period_s, self._tick)
        steady_timer(self, cfg.health_period_s, self._health)
        steady_timer(self, NODES_PERIOD_S, self._publish_nodes)

    # ------------------------------------------------------------------ receiving
    def _watch(self, topic: str) -> None:
        self.stats[topic] = TopicStats(topic, self.cfg.health_window_s)  # a new run: no gap across the pause
        self.subs[topic] = self.create_subscription(message_class(FORWARDED[topic][0]), ros_name(topic),
                                                    self._receiver(topic),
                                                    _qos(topic, self.cfg.depth), raw=True)

    def _update_watched(self) -> None:
        """Subscribe to an on-demand topic while some client watches it, and only then."""
        wanted = self.bridge.watched()
        for topic in self.on_demand:
            if topic in wanted and topic not in self.subs:
                self._watch(topic)
            elif topic not in wanted and topic in self.subs:
                self.destroy_subscription(self.subs.pop(topic))

    def _client_subscribed(self, topic: str) -> None:
        """A client subscribed (a page opened late, reloaded, or back after a monitor restart): the topics that
        change only on a score or a pull go out again now, so it shows the whole test at once, not from the next
        score on: the score history with every set's statistics, and the last pull's trace. Every subscriber of
        the channel gets them again (the SDK logs to a channel, not to a client): a table or the trace plot shows
        the newest message, so nothing changes for them."""
        if topic == CH.SCORE_HISTORY_TOPIC:
            self._publish_history()
        elif topic == CH.PULL_TRACE_TOPIC and self.last_trace is not None:
            self.channels[topic].log(serialize_message(self.last_trace), log_time=time.time_ns())

    def _receiver(self, topic: str):
        channel, pending = self.channels[topic], self.pending[topic]

        def receive(data: bytes):
            now = time.time_ns()
            channel.log(data, log_time=now)
            pending.append((now, data))
        return receive

    def _take(self, topic: str) -> list:
        pending = self.pending[topic]  # the receiver holds this list: empty it, do not replace it
        items = pending[:]
        pending.clear()
        return items

    def _bad(self, topic: str, problem: str) -> None:
        self.counts['bad_messages'] += 1
        self.diag.report(WARN, f'bad message on {topic} left out of the monitor topics (still forwarded): '
                               f'{problem}', key=('bad', topic), topic=topic, bad_messages=self.counts['bad_messages'])

    def _tick(self) -> None:
        now = time.time_ns()
        for topic, (_type, fields) in FORWARDED.items():
            if fields is not None and topic not in (FORCE_TOPIC, CORRECTED):
                self._blocks(topic, fields)
        self._blocks(FORCE_TOPIC, FORWARDED[FORCE_TOPIC][1])
        self._events(now)
        joined = self._blocks(CORRECTED, FORWARDED[CORRECTED][1])
        if not joined:
            self._publish_force(self.live.flush())
        for trace in self.traces.expire(time.monotonic_ns()):
            self._publish_trace(trace)
        scores, summaries = self._take(CH.PULL_SCORE_TOPIC), self._take(CH.SET_SUMMARY_TOPIC)
        for topic, items in ((CH.PULL_SCORE_TOPIC, scores), (CH.SET_SUMMARY_TOPIC, summaries)):
            if items:
                self.stats[topic].add([a for a, _ in items])
        if self._scores(scores) + self._summaries(summaries):
            self._publish_history()
        self._diagnostics()
        self.bridge.serve()

    def _blocks(self, topic: str, fields) -> int:
        items = self._take(topic)
        if not items:
            return 0
        batch = decode_batch(items, fields)
        for problem in batch.problems:
            self._bad(topic, problem)
        self.stats[topic].add(batch.arrival_ns, batch.stamp_ns, batch.seq, batch.nan_samples)
        if topic == FORCE_TOPIC:
            for i, s in enumerate(batch.values['stationary_n']):
                if s.size:   # a block the correction never answered comes back alone: the live trace keeps it
                    for alone in self.join.add_force(int(batch.stamp_ns[i]), s, float(batch.rate_hz[i]),
                                                     batch.values['moving_n'][i]):
                        self._publish_force(self.live.add(alone))
        elif topic == CORRECTED:
            v = batch.values
            for i in range(len(batch)):
                block = self.join.add_corrected(int(batch.stamp_ns[i]), int(batch.seq[i]), float(batch.rate_hz[i]),
                                                v['raw_n'][i], v['corrected_n'][i], v['filtered_n'][i])
                if block is None:
                    continue
                self._publish_force(self.live.add(block))
                for trace in self.traces.add(block, time.monotonic_ns()):
                    self._publish_trace(trace)
        return len(batch)

    def _events(self, now_ns: int) -> None:
        items = self._take(CH.PULL_EVENT_TOPIC)
        for _arrival, data in items:
            try:
                msg = deserialize_message(data, PullEvent)
            except Exception as exc:  # noqa: BLE001 - input from outside
                self._bad(CH.PULL_EVENT_TOPIC, f'undecodable: {exc}')
                continue
            stamp = msg.header.stamp.sec * NS_PER_S + msg.header.stamp.nanosec
            if msg.event == PullEvent.START:
                self.traces.start(msg.pull_id, msg.test_set, stamp)
            elif msg.event == PullEvent.END:
                self.traces.end(msg.pull_id, stamp, time.monotonic_ns())
            else:
                self._bad(CH.PULL_EVENT_TOPIC, f'pull event code {msg.event} is unknown')
        if items:
            self.stats[CH.PULL_EVENT_TOPIC].add([a for a, _ in items])

    def _decoded(self, topic: str, items, cls) -> list:
        out = []
        for _arrival, data in items:
            try:
                out.append(deserialize_message(data, cls))
            except Exception as exc:  # noqa: BLE001 - input from outside
                self._bad(topic, f'undecodable: {exc}')
        return out

    def _scores(self, items) -> int:
        """Each /pull_score again on /monitor/pull_score in lbf, its corrected peak with its uncertainty, and
        into the score history. Returns how many there were."""
        scores = self._decoded(CH.PULL_SCORE_TOPIC, items, PullScore)
        for score in scores:
            msg = MonitorScore(**score_lbf(score))
            msg.header.stamp = score.header.stamp
            self._send(CH.MONITOR_SCORE_TOPIC, msg)
            self.history.add_score(score, score.header.stamp.sec * NS_PER_S + score.header.stamp.nanosec)
        return len(scores)

    def _summaries(self, items) -> int:
        summaries = self._decoded(CH.SET_SUMMARY_TOPIC, items, SetSummary)
        for summary in summaries:
            self.history.add_summary(summary)
        return len(summaries)

    def _publish_history(self) -> None:
        msg = ScoreHistoryMsg(pulls=[ScoreRow(**row) for row in self.history.pulls()],
                              sets=[SetRow(**row) for row in self.history.sets()],
                              coverage_factor=self.history.coverage_factor)
        msg.header.stamp = ns_to_stamp(self.history.newest_stamp_ns())
        self._send(CH.SCORE_HISTORY_TOPIC, msg)

    def _diagnostics(self) -> None:
        items = self._take(CH.DIAGNOSTICS_TOPIC)
        if not items:
            return
        self.stats[CH.DIAGNOSTICS_TOPIC].add([a for a, _ in items])
        for arrival, data in items:
            try:
                msg = deserialize_message(data, DiagnosticArray)
            except Exception:  # noqa: BLE001 - input from outside; forwarded as it came
                continue
            for status in msg.status:
                self.node_states.add(status.name, status.hardware_id, level_of(status), status.message,
                                     [(kv.key, kv.value) for kv in status.values], arrival)
                counts = recorder_counts(status.name, {kv.key: kv.value for kv in status.values})
                if counts is not None:
                    self.recorder, self.recorder_seen_ns = counts, arrival

    # ------------------------------------------------------------------ publishing
    def _send(self, topic: str, msg) -> None:
        self.pubs[topic].publish(msg)
        self.channels[topic].log(serialize_message(msg), log_time=time.time_ns())

    def _publish_force(self, scalars) -> None:
        if scalars is None:
            return
        msg = MonitorForce(seq=scalars.seq, blocks=scalars.blocks)
        msg.header.stamp = ns_to_stamp(scalars.stamp_ns)
        for s in SIGNALS:
            setattr(msg, f'{s}_lbf', scalars.last[s])
            setattr(msg, f'{s}_max_lbf', scalars.max[s])
        self._send(CH.MONITOR_FORCE_TOPIC, msg)
        self.force_seq += 1

    def _publish_trace(self, trace) -> None:
        msg = PullTrace(pull_id=trace.pull_id, test_set=trace.test_set, sample_rate_hz=trace.rate_hz,
                        time_s=to_field(trace.time_s))
        msg.header.stamp = ns_to_stamp(trace.start_ns)
        for s in SIGNALS:
            setattr(msg, f'{s}_lbf', to_field(trace.signals[s]))
        self._send(CH.PULL_TRACE_TOPIC, msg)
        self.last_trace = msg
        self.counts['pull_traces'] += 1

    def _health(self) -> None:
        now = time.time_ns()
        msg = MonitorHealth(window_s=self.cfg.health_window_s, clients=self.bridge.clients,
                            recorder_messages=self.recorder.get('messages', -1) if self.recorder else -1,
                            recorder_report_age_s=(now - self.recorder_seen_ns) / NS_PER_S
                            if self.recorder_seen_ns is not None else float('nan'))
        msg.header.stamp = ns_to_stamp(now)
        for topic, stats in self.stats.items():
            if topic not in self.subs:
                continue
            snap = stats.snapshot(now, self.recorder.get(topic, -1))
            msg.topics.append(TopicHealth(topic=topic, received=snap.received, rate_hz=snap.rate_hz,
                                          seq_gaps=snap.seq_gaps, nan_samples=snap.nan_samples,
                                          latency_p50_ms=snap.latency_p50_ms, latency_p99_ms=snap.latency_p99_ms,
                                          recorded=snap.recorded))
        self._send(CH.MONITOR_HEALTH_TOPIC, msg)
        blocks = self.stats[CORRECTED].received
        self.diag.report(OK, 'monitoring', log=False, port=self.port, clients=self.bridge.clients,
                         corrected_blocks=blocks, pull_traces=self.counts['pull_traces'],
                         bad_messages=self.counts['bad_messages'],
                         invalid_client_messages=self.counts['invalid_client_messages'])

    def _publish_nodes(self) -> None:
        """/monitor/nodes: every node's row, one short line, STALE when silent (core/nodes.py)."""
        self._diagnostics()   # what arrived since the last tick, so a report is never judged late
        now_ns = time.time_ns()
        msg = DiagnosticArray()
        msg.header.stamp = ns_to_stamp(now_ns)
        for row in node_rows(self.node_states.states(now_ns)):
            msg.status.append(DiagnosticStatus(level=bytes([row.level]), name=row.name, message=row.message,
                                               hardware_id=row.hardware_id,
                                               values=[KeyValue(key=k, value=str(v)) for k, v in row.values]))
        self._send(CH.MONITOR_NODES_TOPIC, msg)

    # ------------------------------------------------------------------ the server's requests
    def _client_message(self, text: str) -> None:
        """A malformed (or unwanted) client message: the server ignored it; the first is reported,
        the others are counted (in the heartbeat's invalid_client_messages)."""
        self.counts['invalid_client_messages'] += 1
        if self.counts['invalid_client_messages'] == 1:
            self.diag.report(WARN, f'a Foxglove client sent a message this server does not take, ignored: {text} '
                                   '(reported once; later ones are only counted)')

    def _sdk_log(self, level: int, text: str) -> None:
        # the SDK's server listens on a loopback port of its own behind the gate: its INFO lines ('Started server on
        # 127.0.0.1:<that port>') would name a port no client should use, so they are debug lines here
        if level >= logging.WARNING:
            self.diag.report(WARN, f'Foxglove server: {text}', key=('sdk', text.split(':')[0]))
        else:
            self.get_logger().debug(f'Foxglove server: {text}')

    def close(self) -> None:
        self.bridge.close()


main = main_for(MonitorNode)


if __name__ == '__main__':
    main()
