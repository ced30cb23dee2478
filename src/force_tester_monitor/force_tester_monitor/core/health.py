"""Topic health as the monitor sees it: rate, sequence gaps, NaN samples, and the latency from a
block's header stamp to its arrival at the monitor (p50, p99), over a sliding window.

The stamp is the block's first sample, so the latency includes the block's own span (1 ms for 50
samples at 50 kHz) plus the transport; it is meaningful when the stamps are wall-clock time, as the
sim's are (a bag played back carries its recording's stamps).
"""
from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from typing import Mapping, Optional

import numpy as np

from force_tester_common.core.clock import NS_PER_S

NS_PER_MS = 1_000_000


@dataclass(frozen=True)
class HealthSnapshot:
    topic: str
    received: int
    rate_hz: float
    seq_gaps: int
    nan_samples: int
    latency_p50_ms: float
    latency_p99_ms: float
    recorded: int = -1


class TopicStats:
    """Arrivals of one topic. ``add`` takes a batch (arrays, one entry per message)."""

    def __init__(self, topic: str, window_s: float):
        self.topic = topic
        self.window_ns = int(window_s * NS_PER_S)
        self.received = 0
        self.seq_gaps = 0
        self.nan_samples = 0
        self.first_arrival_ns: Optional[int] = None
        self._last_seq: Optional[int] = None
        self._chunks: deque = deque()  # (arrival_ns array, latency_ns array or None)

    def add(self, arrival_ns, stamp_ns=None, seq=None, nan_samples: int = 0) -> None:
        arrival = np.asarray(arrival_ns, dtype=np.int64)
        if arrival.size == 0:
            return
        if self.first_arrival_ns is None:
            self.first_arrival_ns = int(arrival[0])
        self.received += int(arrival.size)
        self.nan_samples += int(nan_samples)
        latency = None if stamp_ns is None else arrival - np.asarray(stamp_ns, dtype=np.int64)
        self._chunks.append((arrival, latency))
        if seq is not None:
            self.seq_gaps += self._gaps(np.asarray(seq, dtype=np.int64))

    def _gaps(self, seq: np.ndarray) -> int:
        """Skipped sequence numbers; a step back or a repeat is a restart (a new run), not a gap."""
        if self._last_seq is not None:
            seq_all = np.concatenate(([self._last_seq], seq))
        else:
            seq_all = seq
        self._last_seq = int(seq[-1])
        d = np.diff(seq_all)
        return int(np.sum(d[d > 1] - 1))

    def snapshot(self, now_ns: int, recorded: int = -1) -> HealthSnapshot:
        lo = now_ns - self.window_ns
        while self._chunks and self._chunks[0][0][-1] < lo:
            self._chunks.popleft()
        arrivals = [a for a, _ in self._chunks]
        n = 0
        lat = []
        for a, la in self._chunks:
            keep = a >= lo
            n += int(np.count_nonzero(keep))
            if la is not None:
                lat.append(la[keep])
        span_ns = self.window_ns if self.first_arrival_ns is None else min(self.window_ns,
                                                                           now_ns - self.first_arrival_ns)
        rate = n * NS_PER_S / span_ns if span_ns > 0 and arrivals else 0.0
        lat_all = np.concatenate(lat) if lat else np.empty(0, np.int64)
        if lat_all.size:
            p50, p99 = np.percentile(lat_all, (50, 99)) / NS_PER_MS
        else:
            p50 = p99 = math.nan
        return HealthSnapshot(self.topic, self.received, float(rate), self.seq_gaps, self.nan_samples,
                              float(p50), float(p99), int(recorded))


RECORDER_PREFIX = 'recorder:'      # the recorder's DiagnosticStatus.name starts so (node name 'recorder')
RECORDER_TOTAL_KEY = 'messages'    # its key of the total written


def recorder_counts(status_name: str, values: Mapping[str, str]) -> Optional[dict]:
    """The recorder's counts from one of its progress reports on /diagnostics: {'messages': total,
    topic: written, ...}, or None when the status is not such a report (or a count is not an int)."""
    if not status_name.startswith(RECORDER_PREFIX) or RECORDER_TOTAL_KEY not in values:
        return None
    out = {}
    for key, value in values.items():
        if key == RECORDER_TOTAL_KEY or key.startswith('/'):
            try:
                out[key] = int(value)
            except ValueError:
                return None
    return out
