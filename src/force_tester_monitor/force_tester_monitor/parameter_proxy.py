"""The graph's node parameters for Foxglove's Parameters panel (the monitor node's parameter proxy).

Values come from /parameter_events and, for nodes that declared theirs before the monitor started,
from each node's parameter services; a set from the panel goes to the node's parameter service.
Parameter names on the panel are ``/node.name``.
"""
from __future__ import annotations

import threading
from collections import defaultdict
from typing import Callable

import foxglove
from rcl_interfaces.msg import Parameter as ParameterMsg
from rcl_interfaces.msg import ParameterEvent
from rclpy.node import Node
from rclpy.parameter import Parameter as RosParameter
from rclpy.parameter import parameter_value_to_python
from rclpy.parameter_client import AsyncParameterClient
from rclpy.qos import QoSProfile, ReliabilityPolicy

from force_tester_common.ros import WARN, steady_timer

PARAMETER_EVENTS_TOPIC = '/parameter_events'
FETCH_PERIOD_S = 5.0       # how often nodes not seen yet are looked for


def fox_value(value):
    """A ROS parameter value as a foxglove parameter value (arrays as lists)."""
    if isinstance(value, (list, tuple)) or hasattr(value, 'tolist'):
        return list(value.tolist() if hasattr(value, 'tolist') else value)
    return value


def as_type_of(current, value):
    """A value from a client, in the type of the parameter's current value where that loses nothing.
    JSON has one number type: a float parameter set to 2 in the Parameters panel arrives as the
    integer 2, which the node would refuse as the wrong type."""
    if isinstance(current, int) and not isinstance(current, bool) and isinstance(value, float) \
            and value.is_integer():
        return int(value)
    if isinstance(current, float) and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    return value


class ParameterProxy:
    """The parameters of the graph's nodes, cached for ``values`` (any thread) and published to the
    panel through ``publish(parameters)`` when they change. ``node``: the node whose subscriptions,
    timers and parameter clients it uses; ``diag``: its Diagnostics (refused sets are reported)."""

    def __init__(self, node: Node, diag, publish: Callable[[list], None]):
        self.node, self.diag, self.publish = node, diag, publish
        self._lock = threading.Lock()
        self._cache = {}     # '/node.name' -> python value (under _lock)
        self._clients = {}   # node fqn -> AsyncParameterClient
        self._fetched = set()
        node.create_subscription(ParameterEvent, PARAMETER_EVENTS_TOPIC, self._on_parameter_event,
                                 QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE))
        steady_timer(node, FETCH_PERIOD_S, self._fetch)

    def values(self, names) -> list:
        """The foxglove.Parameters named (all when ``names`` is empty); safe from any thread."""
        with self._lock:
            items = dict(self._cache)
        wanted = items if not names else {n: items[n] for n in names if n in items}
        return [foxglove.Parameter(n, value=fox_value(v)) for n, v in sorted(wanted.items())]

    def refresh(self) -> None:
        """Read every node's parameters again (a client subscribed to them)."""
        self._fetch(force=True)

    def set(self, values) -> None:
        """[(name, value)] from the panel, sent to each node's parameter service."""
        by_node = defaultdict(list)
        with self._lock:
            current = dict(self._cache)
        for name, value in values:
            fqn, _, pname = name.rpartition('.')
            by_node[fqn].append(RosParameter(pname, value=as_type_of(current.get(name), value)))
        for fqn, ps in by_node.items():
            self._client(fqn).set_parameters(ps).add_done_callback(lambda f, n=fqn: self._on_set(f, n))

    def _store(self, node_fqn: str, params) -> list:
        changed = []
        with self._lock:
            for p in params:
                name = f'{node_fqn}.{p.name}'
                self._cache[name] = parameter_value_to_python(p.value)
                changed.append(name)
        return changed

    def _on_parameter_event(self, msg: ParameterEvent) -> None:
        changed = self._store(msg.node, [*msg.new_parameters, *msg.changed_parameters])
        with self._lock:
            for p in msg.deleted_parameters:
                self._cache.pop(f'{msg.node}.{p.name}', None)
        if changed:
            self.publish(self.values(changed))

    def _client(self, node_fqn: str) -> AsyncParameterClient:
        if node_fqn not in self._clients:
            self._clients[node_fqn] = AsyncParameterClient(self.node, node_fqn)
        return self._clients[node_fqn]

    def _fetch(self, force: bool = False) -> None:
        """Read the parameters of nodes not seen yet (a monitor started after them missed their
        declarations on /parameter_events)."""
        me = self.node.get_fully_qualified_name()
        for name, ns in self.node.get_node_names_and_namespaces():
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
        changed = self._store(fqn, [ParameterMsg(name=n, value=v) for n, v in zip(names, result.values)])
        if changed:
            self.publish(self.values(changed))

    def _on_set(self, future, fqn) -> None:
        result = future.result()
        if result is None:
            return
        for r in result.results:
            if not r.successful:
                self.diag.report(WARN, f'parameter set from a Foxglove client refused by {fqn}: {r.reason}',
                                 key=('set', fqn))
