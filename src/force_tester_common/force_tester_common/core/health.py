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


def level_of(status) -> int:
    """A DiagnosticStatus's level as an int: a byte in rclpy (b'\\x00'), an int elsewhere."""
    lv = status.level
    return lv[0] if isinstance(lv, (bytes, bytearray)) else int(lv)


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
    """The last /diagnostics status of each name, and whether it is STALE. With ``hold_s`` > 0 a status's
    level and message are the worst of its reports of the last ``hold_s`` seconds (the newest of equals), so a
    newer, better report does not hide a WARN or ERROR made a moment before; its values stay the newest's."""

    def __init__(self, stale_s: float = STALE_S, hold_s: float = 0.0):
        self._stale_ns = seconds_to_ns(stale_s)
        self._hold_ns = seconds_to_ns(hold_s)
        self._last: Dict[str, tuple] = {}  # name -> (arrival_ns, hardware_id, level, message, values)
        self._recent: Dict[str, list] = {}  # name -> [(arrival_ns, level, message)] of the last hold_s

    def add(self, name: str, hardware_id: str, level: int, message: str, values, arrival_ns: int) -> None:
        self._last[name] = (arrival_ns, hardware_id, int(level), message, tuple(values))
        if self._hold_ns > 0:
            recent = [r for r in self._recent.get(name, ()) if arrival_ns - r[0] <= self._hold_ns]
            self._recent[name] = [*recent, (arrival_ns, int(level), message)]

    def _worst(self, name: str, now_ns: int, level: int, message: str) -> tuple:
        held = [r for r in self._recent.get(name, ()) if now_ns - r[0] <= self._hold_ns and r[1] > level]
        if not held:
            return level, message
        _t, level, message = max(held, key=lambda r: (r[1], r[0]))
        return level, message

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
            if self._hold_ns > 0:
                level, message = self._worst(name, now_ns, level, message)
            age = now_ns - arrival
            out.append(NodeState(name, hw, LEVEL_STALE if age > self._stale_ns else level, message,
                                 age / NS_PER_S, values))
        return out
