"""What makes an incoming sample block or pull event usable (pure Python: no ROS import).

Anything on a topic is input from outside. A node checks every field it will use with these
functions before it touches the message; a message with a problem is counted, reported and
dropped, and the node goes on.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping, Optional, Sequence

from .channels import PULL_END, PULL_START
from .clock import NS_PER_S

# Samples per block a live source publishes (the sim's block_size): 500 = 10 ms at 50 kHz. A message
# costs about the same in rclpy and DDS whatever its length, so 1 ms blocks (50) spend most of a
# node's CPU on messages; 10 ms blocks pay that 100 times a second instead of 1000, and 10 ms is
# less than a display frame. ./ft bench rigs --block 50,100,250,500 measures it (docs/speed.md).
BLOCK_SAMPLES = 500
BLOCK_SAMPLES_RANGE = (1, 100_000)
MAX_BLOCK_SAMPLES = 1_000_000       # 20 s at 50 kHz: a longer block is not a block
MAX_SAMPLE_RATE_HZ = 100e6          # no DAQ here samples faster
PULL_EVENT_CODES = (PULL_START, PULL_END)


def stamp_problem(sec: int, nanosec: int) -> Optional[str]:
    """Why a header stamp is not a time, or None."""
    if sec < 0 or not 0 <= nanosec < NS_PER_S:
        return f'stamp {sec} s {nanosec} ns is invalid; expected sec >= 0 and 0 <= nanosec < {NS_PER_S}'
    return None


def block_problem(rate_hz: float, lengths: Mapping[str, int], required: Sequence[str]) -> Optional[str]:
    """Why a sample block cannot be used, or None.

    lengths: the length of every array field of the block; required: the fields the caller
    uses, which must be present (non-empty). Every non-empty field must have the same length.
    """
    if not (isinstance(rate_hz, (int, float)) and math.isfinite(rate_hz) and 0 < rate_hz <= MAX_SAMPLE_RATE_HZ):
        return f'sample_rate_hz {rate_hz!r} is invalid; expected a finite rate in (0, {MAX_SAMPLE_RATE_HZ:g}] Hz'
    empty = [f for f in required if not lengths.get(f)]
    if empty:
        return f'field(s) {", ".join(empty)} are empty; expected samples'
    sizes = {f: n for f, n in lengths.items() if n}
    if len(set(sizes.values())) > 1:
        return f'ragged block: field lengths {sizes}; expected one length for every field'
    n = next(iter(sizes.values()))
    if n > MAX_BLOCK_SAMPLES:
        return f'block of {n} samples; expected at most {MAX_BLOCK_SAMPLES}'
    return None


def event_problem(event: int) -> Optional[str]:
    """Why a pull event cannot be used, or None."""
    if event not in PULL_EVENT_CODES:
        return f'pull event code {event} is unknown; expected one of {list(PULL_EVENT_CODES)} (START, END)'
    return None


@dataclass(frozen=True)
class PullWindow:
    """What a pull's END closes: from its START's stamp to the END's, with what the caller kept with
    the START (``meta``). ``start_ns`` is None for an END without its START."""
    pull_id: int
    start_ns: Optional[int]
    end_ns: int
    meta: Any = None


class PullWindows:
    """START/END pull events into pull windows, the one rule: a START opens pull ``pull_id``, the next
    event of that pull that is not a START (its END) closes it. ``open``: pull_id -> (start_ns, meta) of
    the pulls whose END has not come (in the order their STARTs came)."""

    def __init__(self) -> None:
        self.open: dict = {}

    def add(self, event: int, pull_id: int, stamp_ns: int, meta: Any = None) -> Optional[PullWindow]:
        """A START: remembered, None. An END: the window it closes (start_ns None without a START)."""
        if event == PULL_START:
            self.open[pull_id] = (stamp_ns, meta)
            return None
        start_ns, start_meta = self.open.pop(pull_id, (None, None))
        return PullWindow(pull_id, start_ns, stamp_ns, start_meta)
