"""Liveness, ROS-free: the /diagnostics heartbeat's timing and the nodes' states as a viewer sees
them (the last status of each name, STALE when it is too old).

The nodes' ``Diagnostics`` (force_tester_common.ros) beat at HEARTBEAT_S; the terminal scoreboard
(``./ft monitor``) and the monitor node judge staleness with STALE_S. Times are integer nanoseconds
(``core.clock``); the caller passes the arrival time, so tests stay exact.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Dict

from .clock import NS_PER_S, seconds_to_ns

#: every node publishes its status on /diagnostics at least this often (>= 1 Hz: docs/monitoring.md)
HEARTBEAT_S = 1.0
#: a status older than this is STALE (a viewer's usual timeout is a few heartbeats)
STALE_S = 3.0
#: a WARN/ERROR report stays the node's level in the heartbeats for this long after it was made
HOLD_S = 5.0
# diagnostic_msgs/DiagnosticStatus levels (the message defines them; a test checks these)
LEVEL_OK, LEVEL_WARN, LEVEL_ERROR, LEVEL_STALE = 0, 1, 2, 3
LEVEL_NAMES = {LEVEL_OK: 'OK', LEVEL_WARN: 'WARN', LEVEL_ERROR: 'ERROR', LEVEL_STALE: 'STALE'}


def hardware_id_of(namespace: str) -> str:
    """A node's /diagnostics hardware_id: its namespace without the slashes (the rig it serves; '' at the root)."""
    return namespace.strip('/')


def status_node(name: str, hardware_id: str) -> str:
    """The fully qualified name of the node that sent a status (name "<node>: <what>", hardware_id_of its
    namespace)."""
    node = name.split(':', 1)[0]
    return f'/{hardware_id}/{node}' if hardware_id else f'/{node}'


@dataclass(frozen=True)
class NodeState:
    name: str            # the status name, "node: what"
    hardware_id: str
    level: int           # LEVEL_*; LEVEL_STALE when the last report is older than STALE_S
    message: str
    age_s: float
    values: tuple        # ((key, value), ...) of the last report


class NodeStates:
    """The last /diagnostics status of each name, and whether it is STALE."""

    def __init__(self, stale_s: float = STALE_S):
        self._stale_ns = seconds_to_ns(stale_s)
        self._last: Dict[str, tuple] = {}  # name -> (arrival_ns, hardware_id, level, message, values)

    def add(self, name: str, hardware_id: str, level: int, message: str, values, arrival_ns: int) -> None:
        self._last[name] = (arrival_ns, hardware_id, int(level), message, tuple(values))

    def values(self, prefix: str) -> dict:
        """The key/values of the last status whose name starts with ``prefix`` ({} if none)."""
        for name, (_, _, _, _, values) in self._last.items():
            if name.startswith(prefix):
                return dict(values)
        return {}

    def states(self, now_ns: int) -> list:
        out = []
        for name in sorted(self._last):
            arrival, hw, level, message, values = self._last[name]
            age = now_ns - arrival
            out.append(NodeState(name, hw, LEVEL_STALE if age > self._stale_ns else level, message,
                                 age / NS_PER_S, values))
        return out
