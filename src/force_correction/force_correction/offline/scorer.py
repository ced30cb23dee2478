"""Scoring pull windows over a corrected recording fed in time order (offline `correct`).

A pull window is (start_ns, end_ns, set, pull_id) on the sample clock, from the PullEvent
START/END pair. The scorer holds the samples of open windows only, scores a window once a sample
at or after its end has been seen (or at finish), and gives the same result as slicing the whole
recording with searchsorted: what the validator node's PullAccumulator does live. With
``short_window`` it also searches each pull that the moving average cuts (or that cannot be scored) for
events shorter than a few windows, on the samples it holds anyway: no second read of the recording.
"""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from force_tester_common.core.clock import sample_stamps_ns

from ..core.errors import CorrectionError
from ..core.scoring import SetStatistics, score_pull
from ..core.short_events import short_events
from .result import PullRecord, Scored

SCORED = ('stationary', 'raw', 'corrected', 'filtered', 'inertial')
#: a pull whose filtered peak is below its corrected peak by more than this share is searched for short events
LOSSY = 0.02


def lossy(score) -> bool:
    c, f = abs(float(score.corrected_peak_n)), abs(float(score.filtered_peak_n))
    return not (f >= (1 - LOSSY) * c) if c > 0 else False


class PullScorer:
    """Scores windows over pieces {'t', 'stationary', 'raw', 'corrected', 'filtered'} fed in time
    order; ``drops`` are the stamps of blocks lost upstream (counted into their pull)."""

    def __init__(self, windows: list, drops: list, loaded_fraction: float, peak_inputs=None,
                 short_window: int = 0) -> None:
        self.windows = list(windows)
        self.short_window = short_window
        self.rates: dict = {}     # window -> the blocks' sample rate of its first piece (short events, the peak's U)
        self.events: list = []    # (pull_id, ShortEvent, rate_hz) in the order the pulls were scored
        by_start = sorted(range(len(self.windows)), key=lambda i: self.windows[i][:2])
        self.open = {i: [] for i in by_start}  # stays in start order
        self.outcome: dict = {}
        self.drops = np.array(sorted(drops), dtype=np.int64)
        self.loaded_fraction = loaded_fraction
        self.peak_inputs = peak_inputs

    def add(self, piece: dict, rate_hz: float = 0.0) -> None:
        t = piece['t']
        if not t.size:
            return
        last, latest = int(t[-1]), int(t.max())
        for i in list(self.open):
            start, end = self.windows[i][:2]
            if start > latest:  # this and the later windows have no samples here
                break
            lo, hi = t.searchsorted([start, end])
            if hi > lo:
                self.open[i].append({k: piece[k][lo:hi] if k in piece else np.full(hi - lo, np.nan)
                                     for k in SCORED})   # a piece without m*a: the peak's U unknown
                self.rates.setdefault(i, rate_hz)
            if last >= end:
                self._score(i)

    def _score(self, i: int) -> None:
        parts = self.open.pop(i)
        start, end, set_id, pull_id = self.windows[i]
        if not parts:
            self.outcome[i] = f'pull {pull_id} (set {set_id}): no corrected samples; not scored'
            return
        arrays = [np.concatenate([p[k] for p in parts]) if len(parts) > 1 else parts[0][k]
                  for k in SCORED]
        rate = self.rates.get(i, 0.0)
        try:
            *scored, inertial = arrays
            top = inertial.max() if inertial.size else math.nan   # finite: m*a known (NaN: it propagates)
            known = math.isfinite(top) or bool(np.isfinite(inertial).any())
            self.outcome[i] = score_pull(*scored, loaded_fraction=self.loaded_fraction,
                                         inertial=inertial if known else None,
                                         sample_rate_hz=rate or None, peak_inputs=self.peak_inputs)
        except CorrectionError as exc:
            self.outcome[i] = f'pull {pull_id} (set {set_id}) not scored: {exc}'
        if self.short_window and rate > 0 and (isinstance(self.outcome[i], str) or lossy(self.outcome[i])):
            self.events += [(int(pull_id), e, rate) for e in short_events(arrays[1], arrays[2], rate,
                                                                          self.short_window)]

    def finish(self) -> Scored:
        """Every pull scored (``Scored``: PullRecords in window order)."""
        for i in list(self.open):
            self._score(i)
        stats, pulls, warnings = SetStatistics(), [], []
        for i, (start, end, set_id, pull_id) in enumerate(self.windows):
            s = self.outcome[i]
            if isinstance(s, str):
                warnings.append(s)
                continue
            dropped = int(np.count_nonzero((self.drops >= start) & (self.drops < end)))
            s = replace(s, dropped_blocks=dropped)
            pulls.append(PullRecord(int(pull_id), int(set_id), int(start), int(end), s))
            stats.add(set_id, s)
        return Scored(tuple(pulls), stats, warnings)


def running_summaries(pulls, stats: SetStatistics) -> list:
    """The per-set SetSummary after each pull (what /set_summary carries live)."""
    running, out, seen = SetStatistics(), [], {}
    for p in pulls:
        k = seen.get(p.test_set, 0)
        seen[p.test_set] = k + 1
        running.add(p.test_set, stats.scores(p.test_set)[k])
        out.append(running.summary(p.test_set))
    return out


class BlockStamps:
    """The sample stamps of consecutive blocks of one size and rate (block stamps increasing,
    blocks not overlapping) without the per-sample array: what PullScorer reads (size, t[i],
    max(), searchsorted), computed from the blocks; array() gives the samples' stamps."""

    def __init__(self, stamps: np.ndarray, n: int, rate: float) -> None:
        self.stamps, self.n = stamps, n
        self.offsets = sample_stamps_ns(0, np.arange(n), rate)
        self.size = stamps.size * n

    def __getitem__(self, i: int) -> np.int64:
        i = range(self.size)[i]
        return self.stamps[i // self.n] + self.offsets[i % self.n]

    def max(self) -> np.int64:
        return self[-1]

    def searchsorted(self, values) -> np.ndarray:
        """np.searchsorted(self.array(), values) (side 'left'): samples stamped before each
        value. The blocks before the last block starting before it lie wholly before it."""
        v = np.asarray(values, dtype=np.int64)
        b = np.searchsorted(self.stamps, v)
        prev = np.maximum(b - 1, 0)
        return np.where(b > 0, prev * self.n + np.searchsorted(self.offsets,
                                                               v - self.stamps[prev]), 0)

    def array(self) -> np.ndarray:
        return (self.stamps[:, None] + self.offsets[None, :]).reshape(-1)


def block_sample_stamps(stamps: np.ndarray, n: np.ndarray, rate: np.ndarray):
    """The concatenated sample stamps of blocks (first stamps, sample counts, rates): a
    BlockStamps when the blocks are of one size and rate (the usual case), else an array."""
    if n.size and n[0] > 0 and (n == n[0]).all() and (rate == rate[0]).all():
        return BlockStamps(stamps, int(n[0]), float(rate[0]))
    k = np.arange(int(n.sum()), dtype=np.int64) - np.repeat(np.cumsum(n) - n, n)
    return sample_stamps_ns(np.repeat(stamps, n), k, np.repeat(rate, n))
