"""What offline `correct` returns: typed per-pull and per-set results, and their JSON form."""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import NamedTuple

from force_tester_common.core.scores import PULL_SCORE_FIELDS

from ..core.params import CorrectionParams
from ..core.scoring import PullScoreResult, SetStatistics


@dataclass(frozen=True)
class PullRecord:
    """One scored pull: its window on the sample clock and its score (dropped blocks included)."""

    pull_id: int
    test_set: int
    start_ns: int
    end_ns: int
    score: PullScoreResult

    def as_dict(self) -> dict:
        return {'pull_id': self.pull_id, 'set': self.test_set, 'start_ns': self.start_ns,
                'end_ns': self.end_ns, 'dropped_blocks': self.score.dropped_blocks,
                **{k: float(getattr(self.score, k)) for k in PULL_SCORE_FIELDS}}


class Scored(NamedTuple):
    """Every pull of a correction scored: the PullRecords in window order, the per-set statistics, and the
    warnings (a pull that could not be scored, and why)."""

    pulls: tuple
    sets: SetStatistics
    warnings: list


@dataclass(frozen=True)
class CorrectionResult:
    """The outcome of correcting a bag or a campaign.

    pulls: every scored pull in window order; sets: per-set statistics (thesis Tables 8-9);
    nan_samples: non-finite corrected samples; runs: continuous runs (the filter restarts at
    each); path: how the input was read ('fast', 'generic' or 'campaign'); warnings: what was
    skipped or replaced, one line each.
    """

    params: CorrectionParams
    loaded_fraction: float
    pulls: tuple
    sets: tuple
    nan_samples: int
    runs: int
    path: str
    warnings: tuple = ()
    #: events narrower than a few moving-average windows: ({'pull_id', 'start_s', 'width_s', 'window',
    #: 'peak_n', 'filtered_peak_n', 'loss', 'bandwidth_hz', 'bandwidth_window', 'bandwidth_loss'}, ...)
    short_events: tuple = ()

    @property
    def dropped_blocks(self) -> int:
        return sum(p.score.dropped_blocks for p in self.pulls)

    def as_dict(self) -> dict:
        """The JSON form (scores.json of a corrected campaign)."""
        return {'params': {'mass_kg': self.params.mass_kg, 'window': self.params.window,
                           'loaded_fraction': self.loaded_fraction},
                'pulls': [p.as_dict() for p in self.pulls],
                'sets': [dataclasses.asdict(s) for s in self.sets],
                'nan_samples': self.nan_samples, 'runs': self.runs, 'path': self.path,
                'short_events': list(self.short_events), 'warnings': list(self.warnings)}
