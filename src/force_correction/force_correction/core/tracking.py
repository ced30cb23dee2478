"""Which pull each aligned pair belongs to, across restarts and replays (the validator's bookkeeping).

Two streams say where pulls are: the pull events (START, END) and the aligned blocks. Both can
start over: a restarted source, a bag played again or looped. The blocks say so through the
aligner's ``new_run`` event; the events by a START that is not after the previous START (or
that reuses the id of an open pull). Either may come first. :class:`PullTracker` keeps a block
*epoch* (incremented at every new run of the blocks) and gives each open pull the epoch whose
blocks it takes, so a pull is never scored from a mix of two runs: pulls that straddle a
restart are closed unscored, with the reason.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from typing import Dict, List, Optional, Tuple

from force_tester_common.core.correction import ABORT_TIMEOUT_S

from .pairing import AlignedPair
from .scoring import PullAccumulator

RECENT_PAIRS = 4000      # pairs kept to replay into a pull whose START arrives late (4 s of 1 ms blocks)
FINISH_TIMEOUT_S = 5.0   # after END, score what arrived once no new data has come for this long


@dataclass(frozen=True)
class Closed:
    """A pull closed without a score, and why."""

    pull_id: int
    set_id: int
    reason: str


@dataclass
class _Open:
    acc: PullAccumulator
    epoch: int                        # the block epoch whose pairs this pull takes
    idle_s: Optional[float] = None    # seconds since END without data reaching it (None before END)
    quiet_s: float = 0.0              # seconds without data (before END)


class PullTracker:
    """Open pulls, recent pairs and the run epochs. Feed it events and pairs; it returns the
    pulls ready to score and those closed unscored. ``add(acc, pair)`` puts a pair's samples into
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

    # -- pull events ---------------------------------------------------------------------
    def start(self, stamp_ns: int, pull_id: int, set_id: int) -> List[Closed]:
        """A START event. Returns the pulls it closed (when the events started over)."""
        closed: List[Closed] = []
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

    def end(self, stamp_ns: int, pull_id: int) -> Tuple[bool, List[PullAccumulator]]:
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
    def new_run(self) -> List[Closed]:
        """The blocks started over. Pulls holding data of the old run are closed; pulls without
        data yet move to the new run."""
        self.epoch += 1
        self.recent.clear()
        closed = self._close(lambda o: o.epoch < self.epoch and o.acc.n_samples > 0,
                             'the blocks started over (a restarted source or a replay) mid-pull')
        for o in self.open.values():
            o.epoch = max(o.epoch, self.epoch) if o.acc.n_samples == 0 else o.epoch
        return closed

    def dropped(self) -> None:
        """Blocks were lost: every open pull notes it."""
        for o in self.open.values():
            o.acc.note_dropped()

    def pair(self, pair: AlignedPair) -> List[PullAccumulator]:
        """An aligned pair: added to the open pulls of this epoch; returns the pulls it completes."""
        self.recent.append(pair)
        ready = []
        for pull_id, o in list(self.open.items()):
            if o.epoch != self.epoch:
                continue
            self._add(o.acc, pair)
            o.quiet_s = 0.0
            if o.idle_s is not None:
                o.idle_s = 0.0  # data is still coming
            if o.acc.finished and pair.end_stamp_ns >= o.acc.end_ns:
                ready.append(self._pop(pull_id))
        return ready

    # -- time ----------------------------------------------------------------------------
    def tick(self, dt_s: float) -> Tuple[List[PullAccumulator], List[Closed]]:
        """Time passed: (ended pulls whose data stopped coming for the finish timeout: ready to
        score, pulls without END and without data for the abort timeout: closed as aborted)."""
        ready = []
        for pull_id, o in list(self.open.items()):
            if o.idle_s is not None:
                o.idle_s += dt_s
                if o.idle_s >= self._timeout_s:
                    ready.append(self._pop(pull_id))
            else:
                o.quiet_s += dt_s
        closed = self._close(lambda o: o.idle_s is None and o.quiet_s >= self._abort_s,
                             f'aborted: no data and no END for {self._abort_s:g} s (the source stopped mid-pull)')
        return ready, closed

    def _pop(self, pull_id: int) -> PullAccumulator:
        return self.open.pop(pull_id).acc

    def _close(self, which, reason: str) -> List[Closed]:
        closed = [Closed(pid, o.acc.set_id, reason) for pid, o in self.open.items() if which(o)]
        for c in closed:
            del self.open[c.pull_id]
        return closed
