"""The Foxglove WebSocket server of the monitor node (foxglove-sdk, 127.0.0.1).

One channel per topic, CDR with the full ``pkg/msg/Type`` name and the embedded ros2msg definition, as in
our bags, so one Foxglove layout serves a live graph, a bag played back and an opened bag file. The server
keeps at most ``backlog`` messages per client and drops the oldest beyond that.

The server's callbacks run on its own threads; what they ask of the node goes on ``requests`` as
callables, which the node's executor thread runs (``serve``): nothing of rclpy is touched from the
server's threads.
"""
from __future__ import annotations

import logging
import threading
from collections import deque
from typing import Callable

import foxglove
from foxglove.websocket import Capability

from bag_tools.core.typestore import default_typestore

from .core.errors import MonitorError
from .core.subprotocol import SubprotocolGate

INVALID_CLIENT_MESSAGE = 'Invalid message'  # how the SDK's log line about a malformed client message starts


class _Listener(foxglove.websocket.ServerListener):
    """Server callbacks (they run on the server's thread): parameters, and client messages, which
    this server does not take (no ClientPublish capability)."""

    def __init__(self, bridge: 'FoxgloveBridge'):
        self.bridge = bridge

    def on_get_parameters(self, client, param_names, request_id=None):
        return self.bridge.parameters.values(param_names)

    def on_set_parameters(self, client, parameters, request_id=None):
        values = [(p.name, p.get_value()) for p in parameters]
        self.bridge.request(lambda: self.bridge.parameters.set(values))
        return self.bridge.parameters.values([p.name for p in parameters])

    def on_parameters_subscribe(self, param_names):
        self.bridge.request(self.bridge.parameters.refresh)

    def on_subscribe(self, client, channel):
        with self.bridge.sub_lock:
            self.bridge.subscribed.setdefault(client.id, set()).add(channel.topic)
        self.bridge.request(self.bridge.on_watch)
        topic = channel.topic
        self.bridge.request(lambda: self.bridge.on_subscribe(topic))

    def on_unsubscribe(self, client, channel):
        with self.bridge.sub_lock:
            topics = self.bridge.subscribed.get(client.id, set())
            topics.discard(channel.topic)
            if not topics:
                self.bridge.subscribed.pop(client.id, None)
        self.bridge.request(self.bridge.on_watch)

    def on_client_advertise(self, client, channel):
        text = f'client {client.id} advertised {channel.topic}'
        self.bridge.request(lambda: self.bridge.on_client_message(text))


class _SdkLog(logging.Handler):
    """The SDK's log records (Python logging, logger 'foxglove.*', emitted on the server's threads),
    handed to the node's executor thread."""

    def __init__(self, bridge: 'FoxgloveBridge'):
        super().__init__(logging.INFO)
        self.bridge = bridge

    def emit(self, record):
        level, text = record.levelno, record.getMessage()
        bridge = self.bridge
        if text.startswith(INVALID_CLIENT_MESSAGE):
            bridge.request(lambda: bridge.on_client_message(text))
        else:
            bridge.request(lambda: bridge.on_sdk_log(level, text))


class FoxgloveBridge:
    """The server and its channels (``types``: topic -> message type name).

    What it asks of the node, each run on the node's thread by ``serve``:
    ``on_watch()``: a client subscribed to or unsubscribed from a channel (``watched()`` says which);
    ``on_subscribe(topic)``: a client subscribed to ``topic`` (a page opened late, reloaded or reconnected);
    ``on_client_message(text)``: a malformed or unwanted client message, which the server ignored;
    ``on_sdk_log(level, text)``: any other log record of the SDK.
    ``parameters``: the Parameters panel's side (``parameter_proxy.ParameterProxy``): ``values(names)``
    (called on the server's thread, so thread-safe), ``set([(name, value)])`` and ``refresh()``.
    """

    def __init__(self, types: dict, host: str, port: int, backlog: int, *, parameters, on_watch: Callable[[], None],
                 on_client_message: Callable[[str], None], on_sdk_log: Callable[[int, str], None],
                 on_subscribe: Callable[[str], None] = lambda topic: None):
        self.parameters = parameters
        self.on_watch, self.on_client_message, self.on_sdk_log = on_watch, on_client_message, on_sdk_log
        self.on_subscribe = on_subscribe
        self.requests: deque = deque()  # callables from the server's threads, run by serve()
        self.subscribed = {}            # Foxglove client id -> topics it subscribes to (under sub_lock)
        self.sub_lock = threading.Lock()
        sdk_logger = logging.getLogger('foxglove')
        sdk_logger.handlers[:] = [_SdkLog(self)]
        sdk_logger.setLevel(logging.INFO)
        sdk_logger.propagate = False
        store = default_typestore()
        self.channels = {}
        for topic, type_name in types.items():
            definition = store.generate_msgdef(type_name, ros_version=2)[0]
            self.channels[topic] = foxglove.Channel(
                topic, message_encoding='cdr',
                schema=foxglove.Schema(name=type_name, encoding='ros2msg', data=definition.encode()))
        # the SDK's server on a loopback port of its own; clients connect through the gate on ``port``, which
        # also accepts the protocol's old name (core/subprotocol.py says why and what it costs)
        self.gate = None
        try:
            self.server = foxglove.start_server(
                name='force tester monitor', host='127.0.0.1', port=0, server_listener=_Listener(self),
                capabilities=[Capability.Parameters], message_backlog_size=backlog)
        except RuntimeError as exc:
            raise MonitorError(f'the Foxglove server cannot start ({exc}); expected a free loopback port') from None
        try:
            self.gate = SubprotocolGate(host, port, self.server.port)
        except MonitorError:
            self.server.stop()
            raise
        self.port = self.gate.port

    def request(self, fn: Callable[[], None]) -> None:
        """Queue ``fn`` for the node's thread (safe from any thread)."""
        self.requests.append(fn)

    def serve(self) -> None:
        """Run the queued requests, oldest first (on the node's thread)."""
        while self.requests:
            self.requests.popleft()()

    def watched(self) -> set:
        """The topics some client subscribes to."""
        with self.sub_lock:
            return set().union(*self.subscribed.values())

    @property
    def clients(self) -> int:
        return len(self.subscribed)

    def publish_parameters(self, parameters: list) -> None:
        self.server.publish_parameter_values(parameters)

    def close(self) -> None:
        if self.gate is not None:
            self.gate.close()
        self.server.stop()


def sdk_version() -> str:
    from importlib.metadata import version
    try:
        return version('foxglove-sdk')
    except Exception:  # noqa: BLE001
        return '?'
