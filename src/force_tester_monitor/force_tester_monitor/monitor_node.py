"""monitor node: the live graph for viewers.

- A Foxglove WebSocket server (foxglove-sdk, 127.0.0.1, parameter ``port``) that forwards the
  graph's topics unchanged: CDR messages on channels with the full ``pkg/msg/Type`` name and the
  embedded ros2msg definition, as in our bags, so one Foxglove layout serves a live graph, a bag
  played back and an opened bag file.
- The derived topics /monitor/force, /monitor/pull_trace and /monitor/health, published on ROS
  (for PlotJuggler and rqt) and forwarded the same way.
- The graph's node parameters for Foxglove's Parameters panel (read from /parameter_events and the
  nodes' parameter services; a set from the panel goes to the node's parameter service).

It subscribes to serialized messages with best-effort, keep-last QoS: a slow monitor (or a slow
viewer behind it) loses messages of its own and never delays a publisher. The server keeps at
most ``backlog`` messages per client and drops the oldest beyond that, so a client that stops
reading costs memory that is bounded and nothing else. The arithmetic is in ``core/``.
"""
from __future__ import annotations

import importlib
import logging
import threading
import time
from collections import defaultdict, deque

import foxglove
from diagnostic_msgs.msg import DiagnosticArray
from force_tester_msgs.msg import MonitorForce, MonitorHealth, PullEvent, PullTrace, TopicHealth
from foxglove.websocket import Capability
from rcl_interfaces.msg import Parameter as ParameterMsg
from rcl_interfaces.msg import ParameterEvent
from rclpy.node import Node
from rclpy.parameter import Parameter as RosParameter
from rclpy.parameter import parameter_value_to_python
from rclpy.parameter_client import AsyncParameterClient
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message, serialize_message

from bag_tools.core.typestore import default_typestore
from force_tester_common.conversions import ns_to_stamp, to_field
from force_tester_common.core import channels as CH
from force_tester_common.core.clock import NS_PER_S
from force_tester_common.node_params import NodeParams, ParamSpec
from force_tester_common.ros import EVENT_QOS, OK, SCORE_QOS, SUMMARY_QOS, WARN, Diagnostics, main_for

from .core import params as P
from .core.batch import decode_batch
from .core.errors import MonitorError
from .core.health import TopicStats, recorder_counts
from .core.live import SIGNALS, ForceJoin, LiveTrace, PullTraces

DIAGNOSTICS_TYPE = 'diagnostic_msgs/msg/DiagnosticArray'
PARAMETER_EVENTS_TOPIC = '/parameter_events'

SPECS = [
    ParamSpec('port', P.PORT, f'Foxglove WebSocket port on {P.HOST} (0: any free port)', P.PORT_RANGE,
              read_only=True),
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
    ParamSpec('backlog', P.BACKLOG, 'messages the server queues per client (the oldest is dropped when full)',
              P.BACKLOG_RANGE, read_only=True),
    ParamSpec('depth', P.DEPTH, 'subscription queue depth (best effort, keep last)', P.DEPTH_RANGE,
              read_only=True),
    ParamSpec('on_demand', P.ON_DEMAND, f'subscribe to {", ".join(P.ON_DEMAND_TOPICS)} only while a Foxglove '
                                        'client watches them (false: always)', read_only=True),
]


def _config(values: dict) -> P.MonitorParams:
    return P.MonitorParams(**values)


def _msg_class(type_name: str):
    pkg, _, name = type_name.split('/')
    return getattr(importlib.import_module(f'{pkg}.msg'), name)


# topic -> (type name, float64[] fields or None for a non-block topic)
FORWARDED = {topic: (t, tuple(fields)) for t, (topic, fields) in CH.BLOCK_TYPES.items()}
FORWARDED[CH.CORRECTED_TYPE[1][0]] = (CH.CORRECTED_NAME, CH.CORRECTED_FIELDS)
FORWARDED.update({CH.PULL_EVENT_TOPIC: (CH.PULL_EVENT_TYPE, None),
                  CH.PULL_SCORE_TOPIC: (CH.PULL_SCORE_TYPE, None),
                  CH.SET_SUMMARY_TOPIC: (CH.SET_SUMMARY_TYPE, None),
                  CH.DIAGNOSTICS_TOPIC: (DIAGNOSTICS_TYPE, None)})
DERIVED = {CH.MONITOR_FORCE_TOPIC: (CH.MONITOR_FORCE_TYPE, MonitorForce),
           CH.PULL_TRACE_TOPIC: (CH.PULL_TRACE_TYPE, PullTrace),
           CH.MONITOR_HEALTH_TOPIC: (CH.MONITOR_HEALTH_TYPE, MonitorHealth)}
FORCE_TOPIC = CH.BLOCK_TYPES[CH.FORCE_TYPE][0]
CORRECTED = CH.CORRECTED_TYPE[1][0]


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


def _fox_value(value):
    """A ROS parameter value as a foxglove parameter value (arrays as lists)."""
    if isinstance(value, (list, tuple)) or hasattr(value, 'tolist'):
        return list(value.tolist() if hasattr(value, 'tolist') else value)
    return value


def _as_type_of(current, value):
    """A value from a client, in the type of the parameter's current value where that loses nothing.
    JSON has one number type: a float parameter set to 2 in the Parameters panel arrives as the
    integer 2, which the node would refuse as the wrong type."""
    if isinstance(current, int) and not isinstance(current, bool) and isinstance(value, float) \
            and value.is_integer():
        return int(value)
    if isinstance(current, float) and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    return value


class _Listener(foxglove.websocket.ServerListener):
    """Server callbacks (they run on the server's thread): parameters, and client messages, which
    this server does not take (no ClientPublish capability) and reports once."""

    def __init__(self, node: 'MonitorNode'):
        self.node = node

    def on_get_parameters(self, client, param_names, request_id=None):
        return self.node.parameters_for(param_names)

    def on_set_parameters(self, client, parameters, request_id=None):
        self.node.requests.append(('set', [(p.name, p.get_value()) for p in parameters]))
        return self.node.parameters_for([p.name for p in parameters])

    def on_parameters_subscribe(self, param_names):
        self.node.requests.append(('refresh', None))

    def on_subscribe(self, client, channel):
        with self.node.sub_lock:
            self.node.subscribed.setdefault(client.id, set()).add(channel.topic)
        self.node.requests.append(('watch', None))

    def on_unsubscribe(self, client, channel):
        with self.node.sub_lock:
            topics = self.node.subscribed.get(client.id, set())
            topics.discard(channel.topic)
            if not topics:
                self.node.subscribed.pop(client.id, None)
        self.node.requests.append(('watch', None))

    def on_client_advertise(self, client, channel):
        self.node.requests.append(('client_message', f'client {client.id} advertised {channel.topic}'))


class _SdkLog(logging.Handler):
    """The SDK's log records (Python logging, logger 'foxglove.*', emitted on the server's threads),
    handed to the node's executor thread."""

    def __init__(self, node: 'MonitorNode'):
        super().__init__(logging.INFO)
        self.node = node

    def emit(self, record):
        self.node.requests.append(('sdk_log', (record.levelno, record.getMessage())))


INVALID_CLIENT_MESSAGE = 'Invalid message'  # how the SDK's log line about a malformed client message starts


class MonitorNode(Node):
    def __init__(self, **kwargs):
        super().__init__('monitor', **kwargs)
        self.diag = Diagnostics(self, 'live monitor')
        self.params = NodeParams(self, SPECS, _config)
        cfg: P.MonitorParams = self.params.config
        self.cfg = cfg
        self.requests = deque()  # from the server's thread: (kind, payload)
        self.subscribed = {}     # Foxglove client id -> topics it subscribes to (under sub_lock)
        self.sub_lock = threading.Lock()
        self._param_lock = threading.Lock()
        self._param_cache = {}   # '/node.name' -> python value
        self._param_clients = {}  # node fqn -> AsyncParameterClient
        self._fetched = set()
        self.counts = defaultdict(int)

        sdk_logger = logging.getLogger('foxglove')
        sdk_logger.handlers[:] = [_SdkLog(self)]
        sdk_logger.setLevel(logging.INFO)
        sdk_logger.propagate = False
        store = default_typestore()
        self.channels = {}
        for topic, (type_name, _fields) in {**FORWARDED, **{t: (n, None) for t, (n, _c) in DERIVED.items()}}.items():
            definition = store.generate_msgdef(type_name, ros_version=2)[0]
            self.channels[topic] = foxglove.Channel(
                topic, message_encoding='cdr',
                schema=foxglove.Schema(name=type_name, encoding='ros2msg', data=definition.encode()))
        try:
            self.server = foxglove.start_server(
                name='force tester monitor', host=P.HOST, port=cfg.port, server_listener=_Listener(self),
                capabilities=[Capability.Parameters], message_backlog_size=cfg.backlog)
        except RuntimeError as exc:
            reason = 'is already in use' if 'in use' in str(exc) else f'cannot be opened ({exc})'
            raise MonitorError(f'port {cfg.port} on {P.HOST} {reason}; expected a free port '
                               f'(-p port:=<another>, or 0 for any)') from None
        self.port = self.server.port
        self.diag.report(OK, f'Foxglove WebSocket at ws://{P.HOST}:{self.port} (foxglove-sdk '
                             f'{_sdk_version()}, subprotocol foxglove.sdk.v1)', port=self.port)

        self.pending = {topic: [] for topic in FORWARDED}
        self.stats = {topic: TopicStats(topic, cfg.health_window_s) for topic in FORWARDED}
        self.join = ForceJoin()
        self.live = LiveTrace(cfg.force_every)
        self.traces = PullTraces(cfg.trace_margin_s, cfg.max_trace_s, cfg.trace_timeout_s)
        self.recorder = {}
        self.recorder_seen_ns = None
        self.pubs = {topic: self.create_publisher(cls, topic, EVENT_QOS) for topic, (_n, cls) in DERIVED.items()}
        self.force_seq = 0
        self.on_demand = P.ON_DEMAND_TOPICS if cfg.on_demand else ()
        self.subs = {}           # topic -> its rclpy subscription, while watched
        for topic in FORWARDED:
            if topic not in self.on_demand:
                self._watch(topic)
        self.create_subscription(ParameterEvent, PARAMETER_EVENTS_TOPIC, self._on_parameter_event,
                                 QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE))
        self.create_timer(cfg.period_s, self._tick)
        self.create_timer(cfg.health_period_s, self._health)
        self.create_timer(5.0, self._fetch_parameters)

    # ------------------------------------------------------------------ receiving
    def _watch(self, topic: str) -> None:
        self.stats[topic] = TopicStats(topic, self.cfg.health_window_s)  # a new run: no gap across the pause
        self.subs[topic] = self.create_subscription(_msg_class(FORWARDED[topic][0]), topic, self._receiver(topic),
                                                    _qos(topic, self.cfg.depth), raw=True)

    def _update_watched(self) -> None:
        """Subscribe to an on-demand topic while some client watches it, and only then."""
        with self.sub_lock:
            wanted = set().union(*self.subscribed.values())
        for topic in self.on_demand:
            if topic in wanted and topic not in self.subs:
                self._watch(topic)
            elif topic not in wanted and topic in self.subs:
                self.destroy_subscription(self.subs.pop(topic))

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
        for topic in (CH.PULL_SCORE_TOPIC, CH.SET_SUMMARY_TOPIC):
            items = self._take(topic)
            if items:
                self.stats[topic].add([a for a, _ in items])
        self._diagnostics()
        self._serve_requests()

    def _blocks(self, topic: str, fields) -> int:
        items = self._take(topic)
        if not items:
            return 0
        batch = decode_batch(items, fields)
        for problem in batch.problems:
            self._bad(topic, problem)
        self.stats[topic].add(batch.arrival_ns, batch.stamp_ns, batch.seq, batch.nan_samples)
        if topic == FORCE_TOPIC:
            for stamp, s in zip(batch.stamp_ns, batch.values['stationary_n']):
                if s.size:
                    self.join.add_force(int(stamp), s)
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
        self.counts['pull_traces'] += 1

    def _health(self) -> None:
        now = time.time_ns()
        msg = MonitorHealth(window_s=self.cfg.health_window_s, clients=len(self.subscribed),
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
        self.diag.report(OK, 'monitoring', log=False, port=self.port, clients=len(self.subscribed),
                         corrected_blocks=blocks, pull_traces=self.counts['pull_traces'],
                         bad_messages=self.counts['bad_messages'],
                         invalid_client_messages=self.counts['invalid_client_messages'])

    # ------------------------------------------------------------------ parameters
    def parameters_for(self, names) -> list:
        with self._param_lock:
            items = dict(self._param_cache)
        wanted = items if not names else {n: items[n] for n in names if n in items}
        return [foxglove.Parameter(n, value=_fox_value(v)) for n, v in sorted(wanted.items())]

    def _store_parameters(self, node_fqn: str, params) -> list:
        changed = []
        with self._param_lock:
            for p in params:
                name = f'{node_fqn}.{p.name}'
                self._param_cache[name] = parameter_value_to_python(p.value)
                changed.append(name)
        return changed

    def _on_parameter_event(self, msg: ParameterEvent) -> None:
        changed = self._store_parameters(msg.node, [*msg.new_parameters, *msg.changed_parameters])
        with self._param_lock:
            for p in msg.deleted_parameters:
                self._param_cache.pop(f'{msg.node}.{p.name}', None)
        if changed:
            self.server.publish_parameter_values(self.parameters_for(changed))

    def _client(self, node_fqn: str) -> AsyncParameterClient:
        if node_fqn not in self._param_clients:
            self._param_clients[node_fqn] = AsyncParameterClient(self, node_fqn)
        return self._param_clients[node_fqn]

    def _fetch_parameters(self, force: bool = False) -> None:
        """Read the parameters of nodes not seen yet (a monitor started after them missed their
        declarations on /parameter_events)."""
        me = self.get_fully_qualified_name()
        for name, ns in self.get_node_names_and_namespaces():
            fqn = f'{ns.rstrip("/")}/{name}'
            if fqn == me or (fqn in self._fetched and not force) or name.startswith('_'):
                continue
            client = self._client(fqn)
            if not client.services_are_ready():
                continue
            self._fetched.add(fqn)
            client.list_parameters().add_done_callback(lambda f, c=client, n=fqn: self._on_list(f, c, n))

    def _on_list(self, future, client, fqn) -> None:
        result = future.result()
        if result is None:
            return
        names = list(result.result.names)
        client.get_parameters(names).add_done_callback(lambda f: self._on_get(f, fqn, names))

    def _on_get(self, future, fqn, names) -> None:
        result = future.result()
        if result is None:
            return
        changed = self._store_parameters(fqn, [ParameterMsg(name=n, value=v)
                                               for n, v in zip(names, result.values)])
        if changed:
            self.server.publish_parameter_values(self.parameters_for(changed))

    def _serve_requests(self) -> None:
        while self.requests:
            kind, payload = self.requests.popleft()
            if kind == 'watch':
                self._update_watched()
            elif kind == 'refresh':
                self._fetch_parameters(force=True)
            elif kind == 'set':
                by_node = defaultdict(list)
                with self._param_lock:
                    current = dict(self._param_cache)
                for name, value in payload:
                    fqn, _, pname = name.rpartition('.')
                    by_node[fqn].append(RosParameter(pname, value=_as_type_of(current.get(name), value)))
                for fqn, ps in by_node.items():
                    self._client(fqn).set_parameters(ps).add_done_callback(
                        lambda f, n=fqn: self._on_set(f, n))
            elif kind == 'client_message':
                self._client_message(payload)
            elif kind == 'sdk_log':
                level, text = payload
                if text.startswith(INVALID_CLIENT_MESSAGE):
                    self._client_message(text)
                elif level >= logging.WARNING:
                    self.diag.report(WARN, f'Foxglove server: {text}', key=('sdk', text.split(':')[0]))
                else:
                    self.get_logger().info(f'Foxglove server: {text}')

    def _client_message(self, text: str) -> None:
        """A malformed (or unwanted) client message: the server ignored it; the first is reported,
        the others are counted (in the heartbeat's invalid_client_messages)."""
        self.counts['invalid_client_messages'] += 1
        if self.counts['invalid_client_messages'] == 1:
            self.diag.report(WARN, f'a Foxglove client sent a message this server does not take, ignored: {text} '
                                   '(reported once; later ones are only counted)')

    def _on_set(self, future, fqn) -> None:
        result = future.result()
        if result is None:
            return
        for r in result.results:
            if not r.successful:
                self.diag.report(WARN, f'parameter set from a Foxglove client refused by {fqn}: {r.reason}',
                                 key=('set', fqn))

    def close(self) -> None:
        self.server.stop()


def _sdk_version() -> str:
    from importlib.metadata import version
    try:
        return version('foxglove-sdk')
    except Exception:  # noqa: BLE001
        return '?'


main = main_for(MonitorNode)


if __name__ == '__main__':
    main()
