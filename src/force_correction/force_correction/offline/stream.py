"""The live correction node's arithmetic over a whole recording (offline `correct`).

Samples are fed in time order, a whole continuous run or a segment of one at a time: the
extension's prefilter and m*a + moving average keep their state within a run and restart at each
new run (as the node restarts after a discontinuity). The core guarantees that any split gives
the same numbers bit for bit, so segments of any size reproduce the live output.
"""
from __future__ import annotations

from typing import Any, Callable

import numpy as np

from ..core.extension import Extension, ForcePrefilter
from ..core.params import CorrectionParams
from ..core.streaming import correct_block, initial_state
from .result import Scored
from .scorer import BlockStamps, PullScorer

PIECE_KEYS = ('t', 'stationary', 'raw', 'inertial', 'corrected', 'filtered')
SEGMENT_SAMPLES = 1 << 17  # the fast path corrects, scores and writes this many at a time

#: sink(piece, blocks, frame_id, first_seq): writes the piece's /force_corrected blocks
Sink = Callable[[dict, tuple, str, int], None]


class CorrectionStream:
    """Corrects pieces of a recording. Each piece goes on to the scorer (once the pull windows
    are known), to a sink as /force_corrected blocks (with ``write_to``), and is kept whole if
    ``keep`` or while the pull windows are unknown."""

    def __init__(self, params: CorrectionParams, extension: Extension | None,
                 loaded_fraction: float, keep: bool = True, peak_inputs=None) -> None:
        self.params, self.extension, self.peak_inputs = params, extension, peak_inputs
        self.loaded_fraction, self.keep = loaded_fraction, keep
        self.parts: dict = {k: [] for k in PIECE_KEYS}
        self.nan_count = 0
        self.runs = 0
        self.scorer: PullScorer | None = None
        self.sink: Sink | None = None
        self.seq = 0
        self._state = None
        self._prefilter = None
        self.rate_hz = 0.0

    def windows_known(self, windows: list, drops: list) -> None:
        self.scorer = PullScorer(windows, drops, self.loaded_fraction, self.peak_inputs,
                                 short_window=self.params.window)

    def write_to(self, sink: Sink) -> None:
        self.sink = sink

    def add(self, stamps, force: np.ndarray, accel: np.ndarray, stationary: np.ndarray,
            rate_hz: float, new_run: bool = True, blocks: tuple | None = None,
            frame: str = '') -> Any:
        """Correct one piece; ``blocks`` = (stamps, sample counts, rates) of its blocks, needed
        when writing to a sink."""
        self.rate_hz = rate_hz
        if new_run:
            self.runs += 1
            self._state = initial_state(self.params)
            self._prefilter = None if self.extension is None else \
                ForcePrefilter(self.extension, rate_hz)
        measured = force
        if self._prefilter is not None:
            force = self._prefilter.process(force)
        out, self._state = correct_block(force, accel, self.params, self._state)
        self.nan_count += out.nan_count
        piece = dict(zip(PIECE_KEYS, (stamps, stationary, measured, out.inertial_n,
                                      out.corrected_n, out.filtered_n)))
        if self.scorer is not None:
            self.scorer.add(piece, rate_hz)
        if self.sink is not None:
            self.sink(piece, blocks, frame, self.seq)
        self.seq += len(blocks[0]) if blocks is not None else 0
        if self.keep or self.scorer is None:  # pulls not known yet: kept for scoring
            if isinstance(stamps, BlockStamps):
                piece['t'] = stamps.array()
            for k in PIECE_KEYS:
                self.parts[k].append(piece[k])
        return out

    def arrays(self) -> dict:
        return {k: (v[0] if len(v) == 1 else np.concatenate(v) if v else np.empty(0))
                for k, v in self.parts.items()}

    def scores(self, windows: list, drops: list) -> Scored:
        """Every pull scored: from the scorer fed as the data came when the windows were known first, else from
        the kept arrays."""
        if self.scorer is None:
            self.windows_known(windows, drops)
            self.scorer.add(self.arrays(), self.rate_hz)
        return self.scorer.finish()


def segments(ends: np.ndarray, lo: int, hi: int, wanted: np.ndarray,
             size: int = SEGMENT_SAMPLES) -> list:
    """Block boundaries cutting blocks [lo, hi) (ends: cumulative sample counts) into segments
    of ``size`` to 2 * ``size`` samples (unless one block or the run is longer or shorter), cut
    at the wanted boundaries where that allows, else every ``size`` samples."""
    def samples(a, b):
        return int(ends[b - 1]) - (int(ends[a - 1]) if a else 0)

    cuts = [lo]
    for c in [*sorted(set(wanted[(wanted > lo) & (wanted < hi)].tolist())), hi]:
        while samples(cuts[-1], c) > 2 * size:
            base = int(ends[cuts[-1] - 1]) if cuts[-1] else 0
            cuts.append(max(int(np.searchsorted(ends, base + size, 'right')), cuts[-1] + 1))
        if c > cuts[-1] and (c == hi or samples(cuts[-1], c) >= size):
            cuts.append(c)
    return cuts
