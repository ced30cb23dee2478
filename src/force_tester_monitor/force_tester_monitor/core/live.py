"""Sample blocks -> the monitor's derived topics (ROS-free).

``ForceJoin`` joins each /force_corrected block with the /force block of the same stamp (the
correction stamps its output with the force block's stamp) to get the stationary cell beside the
raw, corrected and filtered moving cell. ``LiveTrace`` turns joined blocks into MonitorForce
scalars, ``PullTraces`` turns them into one PullTrace per pull. Forces are N in and lbf out (the
monitor topics are for display; see MonitorForce.msg).
"""
from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass, field
from typing import List, Optional

import numpy as np

from force_tester_common.core.clock import NS_PER_S, record_stamps_ns, sample_stamp_ns
from force_tester_common.core.correction import LOADED_FRACTION
from force_tester_common.core.scores import peak_text
from force_tester_common.core.units import n_to_lbf

from .errors import MonitorError

SIGNALS = ('stationary', 'raw', 'corrected', 'filtered')
#: the live trace's lbf values are rounded to this many decimals (0.01 lbf, well below the cells' noise): Studio's
#: legend prints a value's every digit, and shows 17 of them for an unrounded float
LBF_DECIMALS = 2
#: a force block whose corrected block has not come this long (of stamps) after it is shown alone (ForceJoin): longer
#: than the corrected stream lags on a loaded machine (seconds), else a lagging block would miss its pull trace
ALONE_AFTER_S = 5.0


@dataclass
class JoinedBlock:
    stamp_ns: int
    seq: int                # the /force_corrected seq
    rate_hz: float
    stationary: np.ndarray  # N
    raw: np.ndarray
    corrected: np.ndarray
    filtered: np.ndarray

    @property
    def end_ns(self) -> int:
        """The stamp just after the block's last sample."""
        return sample_stamp_ns(self.stamp_ns, self.stationary.size, self.rate_hz)


class ForceJoin:
    """Force blocks waiting for their corrected block, keyed by stamp. The corrected stream lags the force
    stream; a force block whose corrected block has not come ``alone_after_s`` (of stamps) behind the newest force
    block (the correction is down, or lost it) is given back by ``add_force`` alone: its stationary and raw moving
    cell, corrected and filtered NaN, so the live trace keeps the stationary force while the correction is down
    (it vanished entirely). At most ``max_pending`` blocks wait."""

    def __init__(self, max_pending: int = 20_000, alone_after_s: float = ALONE_AFTER_S):
        if max_pending < 1:
            raise MonitorError(f'max_pending {max_pending!r} is invalid; expected >= 1')
        self.max_pending = max_pending
        self.alone_after_ns = int(alone_after_s * NS_PER_S)
        self._waiting: OrderedDict = OrderedDict()   # stamp -> (rate, stationary, moving)
        self._seq = 0        # the last corrected seq joined: what a block shown alone carries
        self.unmatched = 0  # corrected blocks that found no force block

    def add_force(self, stamp_ns: int, stationary: np.ndarray, rate_hz: float = float('nan'),
                  moving: Optional[np.ndarray] = None) -> List[JoinedBlock]:
        """Keep a force block for its corrected block; returns the blocks that waited too long, alone."""
        stamp_ns = int(stamp_ns)
        self._waiting[stamp_ns] = (float(rate_hz), stationary, moving)
        alone = []
        while self._waiting:
            oldest = next(iter(self._waiting))
            if stamp_ns - oldest <= self.alone_after_ns and len(self._waiting) <= self.max_pending:
                break
            rate, s, m = self._waiting.popitem(last=False)[1]
            if rate == rate:   # a rate known: the block can be placed in time
                none = np.full(s.size, np.nan)
                alone.append(JoinedBlock(oldest, self._seq, rate, s, none if m is None or m.size != s.size
                                         else np.asarray(m), none, none))
        return alone

    def add_corrected(self, stamp_ns: int, seq: int, rate_hz: float, raw, corrected, filtered
                      ) -> Optional[JoinedBlock]:
        waiting = self._waiting.pop(int(stamp_ns), None)
        if waiting is None or waiting[1].size != np.size(raw):
            self.unmatched += 1
            return None
        # force blocks older than this one will never be joined: their corrected block is gone
        while self._waiting:
            oldest = next(iter(self._waiting))
            if oldest >= stamp_ns:
                break
            self._waiting.popitem(last=False)
        self._seq = int(seq)
        return JoinedBlock(int(stamp_ns), int(seq), float(rate_hz), waiting[1], np.asarray(raw),
                           np.asarray(corrected), np.asarray(filtered))


@dataclass(frozen=True)
class ForceScalars:
    """One MonitorForce message's content (lbf)."""
    stamp_ns: int   # the last covered sample
    seq: int
    blocks: int
    last: dict      # signal -> last sample, lbf
    max: dict       # signal -> max over the covered blocks, lbf (NaN samples skipped; NaN if all are)


def _nanmax(a: np.ndarray) -> float:
    finite = a[np.isfinite(a)]
    return float(finite.max()) if finite.size else float('nan')


class LiveTrace:
    """Joined blocks -> one ForceScalars per ``every`` blocks (``flush`` emits a partial group)."""

    def __init__(self, every: int):
        if every < 1:
            raise MonitorError(f'every {every!r} is invalid; expected >= 1 blocks per message')
        self.every = every
        self._group: List[JoinedBlock] = []

    def add(self, block: JoinedBlock) -> Optional[ForceScalars]:
        self._group.append(block)
        return self.flush() if len(self._group) >= self.every else None

    def flush(self) -> Optional[ForceScalars]:
        if not self._group:
            return None
        group, self._group = self._group, []
        last = group[-1]
        return ForceScalars(
            stamp_ns=sample_stamp_ns(last.stamp_ns, last.stationary.size - 1, last.rate_hz),
            seq=last.seq, blocks=len(group),
            last={s: round(float(n_to_lbf(getattr(last, s)[-1])), LBF_DECIMALS) for s in SIGNALS},
            max={s: round(_nanmax(n_to_lbf(np.concatenate([getattr(b, s) for b in group]))), LBF_DECIMALS)
                 for s in SIGNALS})


@dataclass
class Trace:
    """One PullTrace message's content: the pull's loaded window at full rate (lbf)."""
    pull_id: int
    test_set: int
    start_ns: int
    rate_hz: float
    time_s: np.ndarray       # from the pull's START
    signals: dict            # signal -> lbf array


@dataclass
class _Pull:
    pull_id: int
    test_set: int
    start_ns: int
    end_ns: Optional[int] = None
    ended_at_ns: Optional[int] = None  # monotonic time the END arrived
    blocks: list = field(default_factory=list)
    samples: int = 0


def loaded_window(stationary: np.ndarray, loaded_fraction: float = LOADED_FRACTION) -> Optional[slice]:
    """The samples from the first to the last where the stationary force exceeds
    ``loaded_fraction`` times its peak (the scoring's loaded window), or None if it never does."""
    finite = np.isfinite(stationary)
    if not finite.any():
        return None
    peak = stationary[finite].max()
    if not peak > 0:
        return None
    idx = np.flatnonzero(finite & (stationary > loaded_fraction * peak))
    return slice(int(idx[0]), int(idx[-1]) + 1)


class PullTraces:
    """Joined blocks and pull events -> one Trace per pull, after its END once the joined stream
    has passed the END; or, when the stream stops short of it, once neither the END nor a block
    has arrived for ``timeout_s`` (with what came). The corrected stream may lag the events by
    seconds on a busy machine: only a stream that has stopped cuts a trace short."""

    def __init__(self, margin_s: float, max_s: float, timeout_s: float,
                 loaded_fraction: float = LOADED_FRACTION):
        self.margin_s, self.max_s, self.timeout_ns = margin_s, max_s, int(timeout_s * NS_PER_S)
        self.loaded_fraction = loaded_fraction
        self._pulls: List[_Pull] = []
        self._last_block_at_ns: Optional[int] = None  # monotonic time of the last add()

    def start(self, pull_id: int, test_set: int, start_ns: int) -> None:
        # an unfinished pull that another START replaces never ends: forget it
        self._pulls = [p for p in self._pulls if p.end_ns is not None]
        self._pulls.append(_Pull(int(pull_id), int(test_set), int(start_ns)))

    def end(self, pull_id: int, end_ns: int, now_ns: int) -> None:
        for p in self._pulls:
            if p.pull_id == pull_id and p.end_ns is None:
                p.end_ns, p.ended_at_ns = int(end_ns), int(now_ns)

    def add(self, block: JoinedBlock, now_ns: int) -> List[Trace]:
        self._last_block_at_ns = now_ns
        done = []
        for p in self._pulls:
            if block.stamp_ns < p.start_ns or (p.end_ns is not None and block.stamp_ns >= p.end_ns):
                continue
            if p.samples < self.max_s * block.rate_hz:
                p.blocks.append(block)
                p.samples += block.stationary.size
        for p in list(self._pulls):
            if p.end_ns is not None and block.end_ns >= p.end_ns:
                done.append(p)
        return [t for t in (self._finish(p) for p in done) if t is not None]

    def expire(self, now_ns: int) -> List[Trace]:
        """Traces of ended pulls whose data stopped short of the END: nothing came for ``timeout_s``."""
        last = self._last_block_at_ns or 0
        late = [p for p in self._pulls
                if p.ended_at_ns is not None and now_ns - max(p.ended_at_ns, last) >= self.timeout_ns]
        return [t for t in (self._finish(p) for p in late) if t is not None]

    def _finish(self, p: _Pull) -> Optional[Trace]:
        self._pulls.remove(p)
        if not p.blocks:
            return None
        rate = p.blocks[0].rate_hz
        stamps, arrays = _on_one_grid(p.blocks, rate)
        window = loaded_window(arrays['stationary'], self.loaded_fraction)
        if window is None:
            window = slice(0, stamps.size)
        margin = int(round(self.margin_s * rate))
        sel = slice(max(window.start - margin, 0), min(window.stop + margin, stamps.size))
        return Trace(p.pull_id, p.test_set, p.start_ns, rate, (stamps[sel] - p.start_ns) / NS_PER_S,
                     {s: n_to_lbf(a[sel]) for s, a in arrays.items()})


def _on_one_grid(blocks: List[JoinedBlock], rate_hz: float):
    """The blocks' samples on one uniform grid from the first block's stamp to the last block's end: a block the
    monitor lost (it subscribes best effort) is a run of NaN where it belongs, so a plot shows a gap rather than
    drawing across it, and the time axis stays uniform."""
    first = blocks[0].stamp_ns
    offsets = [int(round((b.stamp_ns - first) * rate_hz / NS_PER_S)) for b in blocks]
    n = max(o + b.stationary.size for o, b in zip(offsets, blocks))
    stamps = record_stamps_ns(first, n, rate_hz)
    arrays = {s: np.full(n, np.nan) for s in SIGNALS}
    for o, b in zip(offsets, blocks):
        for s in SIGNALS:
            arrays[s][o:o + b.stationary.size] = getattr(b, s)
    return stamps, arrays


def score_lbf(score) -> dict:
    """A PullScore (or anything with its fields) as MonitorScore's fields in lbf: the corrected peak with its
    expanded uncertainty, as numbers and as text."""
    def lbf(name):
        return float(n_to_lbf(float(getattr(score, name))))
    out = {'pull_id': int(score.pull_id), 'test_set': int(score.test_set), 'status': int(score.status),
           'coverage_factor': float(score.coverage_factor),
           **{f'{k}_diff_pct': float(getattr(score, f'{k}_diff_pct')) for k in ('raw', 'corrected', 'filtered')},
           **{f'{k}_lbf': lbf(f'{k}_n') for k in ('stationary_peak', 'corrected_peak', 'corrected_peak_u',
                                                  'filtered_peak', 'filtered_peak_u')}}
    out['corrected_peak'] = peak_text(out['corrected_peak_lbf'], out['corrected_peak_u_lbf'], out['coverage_factor'])
    return out
