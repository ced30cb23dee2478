"""The Nodes panel's rows, ROS-free: what the monitor publishes on /monitor/nodes (a DiagnosticArray that
Foxglove's Diagnostics panel renders) from the /diagnostics it hears.

Studio 1.48's panel gives each row one line of message (30 px): a longer message wraps and pushes the rows
below it out of view. So a row's message is one short line and the whole text goes into its values
(``detail``). A node silent for STALE_S (the heartbeat is 1 Hz) is STALE, its message saying for how long,
as ``./ft monitor`` shows it; a node's level is the worst of its reports of the last HOLD_S seconds
(``NodeStates(hold_s=HOLD_S)``), so a newer OK does not hide an ERROR made a moment before.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

from force_tester_common.core.health import LEVEL_STALE

#: /monitor/nodes is published this often (s): a node gone silent shows STALE within STALE_S + this
NODES_PERIOD_S = 0.5
#: the longest message a row shows (the panel's width at 1366 px holds about 90 characters of it)
SHORT_MESSAGE_CHARS = 64
DETAIL_KEY = 'detail'


class ShortMessage(NamedTuple):
    """A status message as a row shows it: one line of at most SHORT_MESSAGE_CHARS, cut at a word with an ellipsis,
    and the whole text when it was cut (else '')."""

    line: str
    whole: str


def short_message(text: str) -> ShortMessage:
    """``text`` as a row shows it (``ShortMessage``)."""
    one = ' '.join(str(text).split())
    if len(one) <= SHORT_MESSAGE_CHARS:
        return ShortMessage(one, '')
    cut = one[:SHORT_MESSAGE_CHARS - 1]
    space = cut.rfind(' ')
    if space >= SHORT_MESSAGE_CHARS // 2:
        cut = cut[:space]
    return ShortMessage(cut.rstrip(' ,;:(') + '\u2026', one)


@dataclass(frozen=True)
class NodeRow:
    name: str
    hardware_id: str
    level: int
    message: str       # one short line
    values: tuple      # ((key, value), ...): the whole message first (DETAIL_KEY) when it was cut


def node_rows(states) -> list:
    """NodeRows of ``NodeStates.states(now)``: a STALE node's message says how long it has been silent, and its
    last message goes to the detail."""
    rows = []
    for st in states:
        short, detail = short_message(st.message)
        if st.level == LEVEL_STALE:
            short, detail = f'STALE: no report for {st.age_s:.0f} s', ' '.join(st.message.split())
        values = ((DETAIL_KEY, detail),) if detail else ()
        rows.append(NodeRow(st.name, st.hardware_id, st.level, short, values + tuple(st.values)))
    return rows
