"""Which pull each aligned pair belongs to, across restarts and replays (the validator's bookkeeping).

Two streams say where pulls are: the pull events (START, END) and the aligned blocks. Both can
start over: a restarted source, a bag played again or looped. The blocks say so through the
aligner's ``new_run`` event; the events by a START that is not after the previous START (or
that reuses the id of an open pull). Either may come first. :class:`PullTracker` keeps a block
*epoch* (incremented at every new run of the blocks) and gives each open pull the epoch whose
blocks it takes, so a pull is never scored from a mix of two runs: pulls that straddle a
restart are closed as aborted, with the reason.

A restart of the correction alone (its output starts over while the source goes on) is not a new
run: the open pulls note the gap in the corrected stream and are scored as incomplete. A change
of the correction's parameters mid-pull is noted as well (reconfigured).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, field
from typing import Dict, List, Optional, Tuple

import numpy as np

from force_tester_common.core.correction import ABORT_TIMEOUT_S

from .pairing import AlignedPair, AlignerEvent
from .scoring import PullAccumulator

RECENT_PAIRS = 4000      # pairs kept to replay into a pull whose START arrives late (4 s of 1 ms blocks)
FINISH_TIMEOUT_S = 5.0   # after END, score what arrived once no new data has come for this long


@dataclass(frozen=True)
class Finished:
    """A pull that is over: its samples, what was noted on the way ((kind, text) pairs, kind
    'incomplete' or 'reconfigured') and, if it never ended properly, why (aborted)."""

    acc: PullAccumulator
    notes: tuple = ()
    aborted: str = ''

    @property
    def pull_id(self) -> int:
        return self.acc.pull_id


@dataclass
class _Open:
    acc: PullAccumulator
    epoch: int                        # the block epoch whose pairs this pull takes
    idle_s: Optional[float] = None    # seconds since END without data reaching it (None before END)
    quiet_s: float = 0.0              # seconds without a block of the source (before END)
    notes: list = field(default_factory=list)


class PullTracker:
    """Open pulls, recent pairs and the run epochs. Feed it events and pairs; it returns the
    pulls that are over (:class:`Finished`). ``add(acc, pair)`` puts a pair's samples into
    an accumulator (the caller knows the payload types)."""

    def __init__(self, add, abort_timeout_s: float = ABORT_TIMEOUT_S, recent_pairs: int = RECENT_PAIRS,
                 finish_timeout_s: float = FINISH_TIMEOUT_S):
        self._add = add
        self._abort_s = abort_timeout_s
        self.recent: deque = deque(maxlen=recent_pairs)
        self.open: Dict[int, _Open] = {}
        self.epoch = 0
        self._epoch_at_start = 0
        self._last_start_ns: Optional[int] = None
        self._timeout_s = finish_timeout_s
        self._gap_from: Optional[int] = None   # end of the last pair before the correction restarted

    # -- pull events ---------------------------------------------------------------------
    def start(self, stamp_ns: int, pull_id: int, set_id: int) -> List[Finished]:
        """A START event. Returns the pulls it aborted (when the events started over)."""
        closed: List[Finished] = []
        epoch = self.epoch
        if (self._last_start_ns is not None and stamp_ns <= self._last_start_ns) or pull_id in self.open:
            closed = self._close(lambda o: True, 'the pull events started over (a restarted source or a '
                                                 'replay) before this pull ended')
            if self.epoch == self._epoch_at_start:
                # the blocks have not started over yet: what is held is the old run's, and the
                # new pull takes the blocks of the next run only
                self.recent.clear()
                epoch = self.epoch + 1
        self._last_start_ns = stamp_ns
        self._epoch_at_start = self.epoch
        o = _Open(PullAccumulator(stamp_ns, set_id=set_id, pull_id=pull_id), epoch)
        if epoch == self.epoch:
            for pair in self.recent:
                self._add(o.acc, pair)
        self.open[pull_id] = o
        return closed

    def end(self, stamp_ns: int, pull_id: int) -> Tuple[bool, List[Finished]]:
        """An END event: (known pull?, pulls ready to score)."""
        o = self.open.get(pull_id)
        if o is None:
            return False, []
        o.acc.finish(stamp_ns)
        o.idle_s = 0.0
        if self.recent and o.epoch == self.epoch and self.recent[-1].end_stamp_ns >= stamp_ns:
            return True, [self._pop(pull_id)]
        return True, []

    # -- blocks --------------------------------------------------------------------------
    def new_run(self) -> List[Finished]:
        """The blocks started over. Pulls holding data of the old run are aborted; pulls without
        data yet move to the new run."""
        self.epoch += 1
        self.recent.clear()
        self._gap_from = None
        closed = self._close(lambda o: o.epoch < self.epoch and o.acc.n_samples > 0,
                             'the blocks started over (a restarted source or a replay) mid-pull')
        for o in self.open.values():
            o.epoch = max(o.epoch, self.epoch) if o.acc.n_samples == 0 else o.epoch
        return closed

    def correction_restarted(self) -> None:
        """The corrected stream started over while the source went on: the open pulls will note
        the gap (its span is known at the next pair)."""
        if self.recent and self._gap_from is None:
            self._gap_from = self.recent[-1].end_stamp_ns

    def source_heard(self) -> None:
        """A block of the source arrived (paired or not): the source is alive, nothing is aborted."""
        for o in self.open.values():
            o.quiet_s = 0.0

    def reconfigured(self, what: str) -> None:
        """The correction's parameters changed: every open pull notes it."""
        for o in self.open.values():
            o.notes.append(('reconfigured', what))

    def block_lost(self, event: AlignerEvent) -> None:
        """The aligner's 'dropped' or 'unmatched' event: a lost /force block (unmatched: its payload is known)
        carries the stationary force it held, which dropped() charges with the block."""
        lost = getattr(event.payload, 'stationary_n', None) if event.channel == 'force' else None
        peak = math.nan
        if lost is not None and np.size(lost) and not np.isnan(lost).all():
            peak = float(np.nanmax(lost))
        self.dropped(event.stamp_ns, peak)

    def dropped(self, stamp_ns: int, lost_peak_n: float = math.nan) -> None:
        """A block stamped STAMP_NS was lost (the sequence skipped it, or it found no partner): the open pulls
        whose window holds that stamp note it, with the largest stationary force it carried (NaN: not known).
        Each pull counts its own lost blocks (a correction restart's whole gap was charged to every open pull)."""
        for o in self.open.values():
            if o.acc.start_ns <= stamp_ns and (o.acc.end_ns is None or stamp_ns < o.acc.end_ns):
                o.acc.note_dropped(lost_peak_n=lost_peak_n)

    def pair(self, pair: AlignedPair) -> List[Finished]:
        """An aligned pair: added to the open pulls of this epoch; returns the pulls it completes."""
        self.recent.append(pair)
        gap, self._gap_from = self._gap_from, None
        ready = []
        for pull_id, o in list(self.open.items()):
            if o.epoch != self.epoch:
                continue
            if gap is not None:
                o.notes.append(('incomplete', f'the correction restarted: no corrected samples for '
                                              f'{(pair.stamp_ns - gap) / 1e6:.1f} ms from stamp {gap} ns'))
            self._add(o.acc, pair)
            o.quiet_s = 0.0
            if o.idle_s is not None:
                o.idle_s = 0.0  # data is still coming
            if o.acc.finished and pair.end_stamp_ns >= o.acc.end_ns:
                ready.append(self._pop(pull_id))
        return ready

    # -- time ----------------------------------------------------------------------------
    def tick(self, dt_s: float) -> List[Finished]:
        """Time passed. Ended pulls whose data stopped coming for the finish timeout are over
        (incomplete: their data stopped before the END); pulls without END and without data for
        the abort timeout are aborted."""
        over = []
        for pull_id, o in list(self.open.items()):
            if o.idle_s is not None:
                o.idle_s += dt_s
                if o.idle_s >= self._timeout_s:
                    o.notes.append(('incomplete', f'the data stopped before the END (no block for '
                                                  f'{self._timeout_s:g} s)'))
                    over.append(self._pop(pull_id))
            else:
                o.quiet_s += dt_s
        return over + self._close(lambda o: o.idle_s is None and o.quiet_s >= self._abort_s,
                                  f'no data and no END for {self._abort_s:g} s (the source stopped mid-pull)')

    def _pop(self, pull_id: int) -> Finished:
        o = self.open.pop(pull_id)
        return Finished(o.acc, tuple(o.notes))

    def _close(self, which, reason: str) -> List[Finished]:
        ids = [pid for pid, o in self.open.items() if which(o)]
        return [Finished(o.acc, tuple(o.notes), reason) for o in (self.open.pop(pid) for pid in ids)]
