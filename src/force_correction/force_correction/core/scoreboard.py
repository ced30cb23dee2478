"""The live scoreboard's arithmetic (``./ft monitor``), ROS-free: one row per pull in lbf, the running
per-set mean and std of the three % differences (thesis Tables 8 and 9, ``SetStatistics``), a grade of
each difference against a threshold, and the health line's figures.

It lives beside ``scoring`` because it is a view of the validator's scores: the same fields
(``PULL_SCORE_FIELDS``), the same per-set statistics, with the OK pulls only in the set statistics
(as ``/set_summary``). Forces are N inside and lbf only in the rows (``core.units``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Dict, List, Optional, Tuple

from force_tester_common.core.clock import NS_PER_S
from force_tester_common.core.scores import PULL_OK, PULL_SCORE_FIELDS, PULL_STATUS_NAMES
from force_tester_common.core.units import n_to_lbf

from .scoring import PullScoreResult, SetStatistics, SetSummary

#: a peak difference up to this is good (green); up to twice this, fair (yellow); above, poor (red)
DIFF_THRESHOLD_PCT = 5.0
GOOD, FAIR, POOR, NONE = 'good', 'fair', 'poor', 'none'
DIFF_KINDS = ('raw', 'corrected', 'filtered')   # raw moving cell, after m*a, after m*a + moving average


def grade(pct: float, threshold_pct: float = DIFF_THRESHOLD_PCT) -> str:
    """GOOD, FAIR or POOR for a % difference against the threshold; NONE for NaN."""
    if pct is None or math.isnan(pct):
        return NONE
    if abs(pct) <= threshold_pct:
        return GOOD
    return FAIR if abs(pct) <= 2 * threshold_pct else POOR


@dataclass(frozen=True)
class PullRow:
    pull_id: int
    test_set: int
    status: str                  # PULL_STATUS_NAMES
    stationary_lbf: float
    raw_lbf: float
    corrected_lbf: float
    filtered_lbf: float
    raw_pct: float
    corrected_pct: float
    filtered_pct: float
    dropped_blocks: int
    detail: str
    corrected_u_lbf: float = math.nan   # expanded uncertainty of corrected_lbf (k = coverage_factor, 2)


class Scoreboard:
    """Pull scores as they arrive (a PullScore message, or anything with its fields).

    A score is keyed by (pull start stamp, pull_id): a latched score delivered again, or a bag
    played again with its recorded stamps, replaces its row; a new run adds rows.
    """

    def __init__(self, threshold_pct: float = DIFF_THRESHOLD_PCT):
        self.threshold_pct = float(threshold_pct)
        self._scores: Dict[Tuple[int, int], object] = {}

    def add(self, score, start_ns: int = 0) -> None:
        self._scores[(int(start_ns), int(score.pull_id))] = score

    def __len__(self) -> int:
        return len(self._scores)

    def rows(self, last: Optional[int] = None) -> List[PullRow]:
        """The pulls in arrival order of their start stamps (the last ``last`` of them)."""
        out = []
        for key in sorted(self._scores):
            s = self._scores[key]
            out.append(PullRow(int(s.pull_id), int(s.test_set), PULL_STATUS_NAMES.get(int(s.status), str(s.status)),
                               n_to_lbf(s.stationary_peak_n), n_to_lbf(s.raw_peak_n), n_to_lbf(s.corrected_peak_n),
                               n_to_lbf(s.filtered_peak_n), s.raw_diff_pct, s.corrected_diff_pct,
                               s.filtered_diff_pct, int(s.dropped_blocks), s.detail,
                               n_to_lbf(getattr(s, 'corrected_peak_u_n', math.nan))))
        return out if last is None else out[-last:]

    def grades(self, row: PullRow) -> Dict[str, str]:
        return {k: grade(getattr(row, f'{k}_pct'), self.threshold_pct) for k in DIFF_KINDS}

    def sets(self) -> List[SetSummary]:
        """Running statistics per set over its OK pulls (mean, sample std), in set order."""
        stats = SetStatistics()
        for key in sorted(self._scores):
            s = self._scores[key]
            if int(s.status) == PULL_OK:
                stats.add(int(s.test_set), PullScoreResult(
                    **{k: float(getattr(s, k)) for k in PULL_SCORE_FIELDS}, n_samples=0, n_loaded=0,
                    loaded_fraction=math.nan, dropped_blocks=int(s.dropped_blocks)))
        return [stats.summary(k) for k in sorted(stats.sets())]


class CounterRate:
    """Rate of a growing counter (a node's heartbeat counts) between its last two readings apart by
    at least ``min_span_s``; a counter that goes back (a restarted node) starts over."""

    def __init__(self, min_span_s: float = 1.0):
        self._min_span_ns = int(min_span_s * NS_PER_S)
        self._readings: List[Tuple[int, int]] = []   # (time ns, count)
        self.rate_hz = math.nan

    def add(self, now_ns: int, count: int) -> float:
        if self._readings and count < self._readings[-1][1]:
            self._readings = []
            self.rate_hz = math.nan
        self._readings.append((int(now_ns), int(count)))
        while len(self._readings) > 2 and self._readings[-1][0] - self._readings[1][0] >= self._min_span_ns:
            self._readings.pop(0)
        (t0, c0), (t1, c1) = self._readings[0], self._readings[-1]
        if t1 - t0 >= self._min_span_ns:
            self.rate_hz = (c1 - c0) * NS_PER_S / (t1 - t0)
        return self.rate_hz


def fmt(value: float, spec: str = '.1f', none: str = '-') -> str:
    """A number for the table; ``none`` for NaN."""
    return none if value is None or (isinstance(value, float) and math.isnan(value)) else format(value, spec)
