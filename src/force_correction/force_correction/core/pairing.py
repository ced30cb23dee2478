"""Pair blocks of separately arriving channels by exact integer-ns stamp, never misaligned.

Each channel publishes blocks in sequence order: (stamp_ns of the first sample, seq, sample
rate, n_samples, payload). :class:`BlockAligner` emits an :class:`AlignedPair` once every
channel holds a block with the same ``stamp_ns`` (exact int match), equal length and equal
rate. Anything that cannot be paired is discarded and reported as an :class:`AlignerEvent`:

- ``dropped``: a channel's seq jumped (blocks lost upstream); detail quotes expected/got.
- ``new_run``: a new stream on a channel: its seq or stamp went back (a restarted source, a bag
  played again or looped) or its stamp jumped forward by more than ``new_run_gap_ns``. The
  block is kept as the first of the new run; on a restart the channel's pending blocks (the old
  run's) are discarded, so no pair mixes two runs. Callers that accumulate over time (the
  validator) close what they hold.
- ``duplicate``: the same seq and stamp as the channel's previous block; discarded.
- ``unmatched``: a pending block was discarded because a later stamp was paired (it can never
  pair: channels are in order) or it waited more than ``max_pending`` blocks.
- ``rate_mismatch`` / ``length_mismatch``: blocks with the same stamp disagree; all discarded.
- ``discontinuity``: an emitted pair does not follow the previous pair without a gap (see
  :func:`follows`). The pair carries ``continuous=False``; callers should reset filter state.
  (Not reported for the first pair, nor for the first pair of a new run: both are also
  ``continuous=False``, and the new run was reported once, as ``new_run``.)

The rules are also exported as functions on arrays (:func:`rates_equal`, :func:`follows`,
:func:`clean_pairing`), so a reader that decodes whole topics at once (offline ``correct``'s
fast path) applies exactly the aligner's rules without a second copy of them.
"""

from __future__ import annotations

import math
import numbers
from collections import OrderedDict
from dataclasses import dataclass, field
from typing import Any, Dict, Iterable, List, Mapping, Optional, Tuple

import numpy as np

from force_tester_common.core.clock import NS_PER_S, end_stamp_ns, seconds_to_ns
from force_tester_common.core.correction import MAX_PENDING, MAX_PENDING_RANGE, NEW_RUN_GAP_RANGE_S, NEW_RUN_GAP_S

from .errors import CorrectionError

EVENT_KINDS = frozenset(
    {'dropped', 'unmatched', 'rate_mismatch', 'length_mismatch', 'new_run', 'duplicate',
     'discontinuity'})

RATE_RTOL = 1e-9  # two blocks' rates are equal within this relative tolerance


def rates_equal(a, b):
    """The aligner's rate rule, elementwise: |a - b| <= RATE_RTOL * max(|a|, |b|)."""
    return np.abs(a - b) <= RATE_RTOL * np.maximum(np.abs(a), np.abs(b))


def follows(prev_stamp_ns, prev_n, prev_rate_hz, stamp_ns, rate_hz):
    """The continuity rule, elementwise: a block follows the previous one without a gap when the
    rates are equal and its stamp lies within half a sample of where the previous one ended
    (prev_stamp + prev_n / prev_rate)."""
    expected = prev_stamp_ns + prev_n * NS_PER_S / prev_rate_hz
    return rates_equal(prev_rate_hz, rate_hz) & (np.abs(stamp_ns - expected) <= 0.5 * NS_PER_S / rate_hz)


@dataclass(frozen=True)
class BlockHeaders:
    """One channel's block headers as arrays, in arrival order (what a bag reader decodes in one
    pass). ``arrival``: each block's position in the arrival order of all channels together."""

    stamp_ns: np.ndarray
    seq: np.ndarray
    rate_hz: np.ndarray
    n_samples: np.ndarray
    arrival: np.ndarray


def clean_pairing(channels: Mapping[str, BlockHeaders], max_pending: int = MAX_PENDING) -> Optional[str]:
    """None when a BlockAligner fed these blocks in arrival order pairs block i of every channel
    with block i of the others and reports no event but discontinuities; else the first rule
    that fails. Seqs must fit int64."""
    names = list(channels)
    ref = channels[names[0]]
    m = ref.stamp_ns.size
    if m == 0:
        return 'no blocks'
    for name, b in channels.items():
        if b.stamp_ns.size != m:
            return f'{name} has {b.stamp_ns.size} blocks, {names[0]} {m}: unpaired blocks'
        if (np.diff(b.seq) != 1).any() or (np.diff(b.stamp_ns) <= 0).any():
            return f'dropped or out-of-order blocks on {name}'
        if not (np.isfinite(b.rate_hz).all() and (b.rate_hz > 0).all()):
            return f'bad sample rates on {name}'
    for name in names[1:]:
        b = channels[name]
        if not np.array_equal(b.stamp_ns, ref.stamp_ns):
            return f'{name} and {names[0]} stamps differ'
        if not rates_equal(b.rate_hz, ref.rate_hz).all():
            return f'{name} and {names[0]} rates differ'
        if not np.array_equal(b.n_samples, ref.n_samples):
            return f'{name} and {names[0]} block lengths differ'
    index = np.arange(m)
    for name, b in channels.items():
        # partners of this channel's blocks that had arrived when each of them arrived
        before = np.min([np.searchsorted(channels[o].arrival, b.arrival) for o in names if o != name]
                        or [index + 1], axis=0)
        if (index - before + 1).max() > max_pending:
            return f'{name} blocks wait for their partners longer than max_pending {max_pending}'
    return None


@dataclass(frozen=True)
class AlignerEvent:
    """Something the aligner discarded or noticed. ``kind`` is one of EVENT_KINDS."""

    kind: str
    channel: str
    seq: int
    stamp_ns: int
    detail: str
    payload: object = None   # an 'unmatched' block's payload (what was lost); None for the other kinds


@dataclass(frozen=True)
class AlignedPair:
    """Blocks of all channels with the same stamp. ``pair[channel]`` gives the payload."""

    stamp_ns: int
    n_samples: int
    sample_rate_hz: float
    payloads: Dict[str, Any]
    seqs: Dict[str, int]
    continuous: bool

    def __getitem__(self, channel: str) -> Any:
        return self.payloads[channel]

    @property
    def end_stamp_ns(self) -> int:
        """Stamp the next contiguous block would carry (the sample clock's end stamp)."""
        return end_stamp_ns(self.stamp_ns, self.n_samples, self.sample_rate_hz)


@dataclass
class _Block:
    stamp_ns: int
    seq: int
    rate_hz: float
    n: int
    payload: Any
    run: int = 0     # the channel's run the block belongs to (_Channel.run when it came)


@dataclass
class _Channel:
    last_seq: Optional[int] = None
    last_stamp: Optional[int] = None
    last_end: Optional[int] = None   # where the previous block's samples end (its end stamp)
    run: int = 0                     # new runs seen on this channel
    pending: "OrderedDict[int, _Block]" = field(default_factory=OrderedDict)


def _is_int(x) -> bool:
    return isinstance(x, numbers.Integral) and not isinstance(x, bool)


class BlockAligner:
    """Pairs blocks of named channels by exact stamp; see module docstring.

    channels: names of the channels to pair (at least one, unique).
    max_pending: a channel holding more than this many unpaired blocks discards its oldest.
    new_run_gap_s: a stamp this far past the end of the channel's previous block starts a new run.
    """

    def __init__(self, channels: Iterable[str] = ('force', 'accel'), max_pending: int = MAX_PENDING,
                 new_run_gap_s: float = NEW_RUN_GAP_S):
        names = tuple(channels)
        if len(names) < 1 or len(set(names)) != len(names):
            raise CorrectionError(
                f"channels {names!r} are invalid; expected one or more unique names")
        lo, hi = MAX_PENDING_RANGE
        if not _is_int(max_pending) or not lo <= max_pending <= hi:
            raise CorrectionError(
                f"max_pending {max_pending!r} is out of range; expected an integer in "
                f"[{lo}, {hi}]")
        lo, hi = NEW_RUN_GAP_RANGE_S
        if isinstance(new_run_gap_s, bool) or not isinstance(new_run_gap_s, numbers.Real) \
                or not lo <= new_run_gap_s <= hi:
            raise CorrectionError(f"new_run_gap_s {new_run_gap_s!r} is out of range; expected seconds in "
                                  f"[{lo}, {hi}]")
        self._names = names
        self._max_pending = int(max_pending)
        self._new_run_gap_ns = seconds_to_ns(new_run_gap_s)
        self._ch: Dict[str, _Channel] = {c: _Channel() for c in names}
        self._last_pair: Optional[AlignedPair] = None
        self._last_runs: Optional[Tuple[int, ...]] = None   # the runs of the last pair's blocks
        self.pairs_emitted = 0
        self.event_counts: Dict[str, int] = {k: 0 for k in EVENT_KINDS}

    @property
    def channels(self) -> Tuple[str, ...]:
        return self._names

    def pending_count(self, channel: str) -> int:
        return len(self._channel(channel).pending)

    def reset(self) -> None:
        """Forget all pending blocks and sequence history."""
        self._ch = {c: _Channel() for c in self._names}
        self._last_pair = None
        self._last_runs = None

    def _channel(self, channel: str) -> _Channel:
        try:
            return self._ch[channel]
        except KeyError:
            raise CorrectionError(
                f"channel {channel!r} is unknown; expected one of {list(self._names)}") from None

    def _event(self, events, kind, channel, seq, stamp_ns, detail, payload=None):
        self.event_counts[kind] += 1
        events.append(AlignerEvent(kind, channel, int(seq), int(stamp_ns), detail, payload))

    def push(self, channel: str, stamp_ns: int, seq: int, sample_rate_hz: float,
             n_samples: int, payload: Any = None
             ) -> Tuple[List[AlignedPair], List[AlignerEvent]]:
        """Offer one block; returns (pairs now complete, events)."""
        ch = self._channel(channel)
        if not _is_int(stamp_ns):
            raise CorrectionError(
                f"stamp_ns {stamp_ns!r} is not an int; expected integer nanoseconds")
        if not _is_int(seq):
            raise CorrectionError(f"seq {seq!r} is not an int; expected an integer >= 0")
        if not _is_int(n_samples) or n_samples < 0:
            raise CorrectionError(
                f"n_samples {n_samples!r} is out of range; expected an integer >= 0")
        rate = float(sample_rate_hz)
        if not math.isfinite(rate) or rate <= 0.0:
            raise CorrectionError(
                f"sample_rate_hz {sample_rate_hz!r} is out of range; expected a finite "
                f"rate > 0 Hz")
        stamp_ns, seq, n_samples = int(stamp_ns), int(seq), int(n_samples)
        pairs: List[AlignedPair] = []
        events: List[AlignerEvent] = []

        # 1. order within the channel: the same run, a duplicate, or a new run
        if ch.last_seq is not None:
            if seq == ch.last_seq and stamp_ns == ch.last_stamp:
                self._event(events, 'duplicate', channel, seq, stamp_ns,
                            f"seq {seq} stamp {stamp_ns} ns received twice; block discarded")
                return pairs, events
            if seq <= ch.last_seq or stamp_ns <= ch.last_stamp:
                ch.run += 1
                old = len(ch.pending)
                ch.pending.clear()
                self._event(events, 'new_run', channel, seq, stamp_ns,
                            f"seq {seq} stamp {stamp_ns} ns after seq {ch.last_seq} stamp {ch.last_stamp} ns: "
                            f"the source restarted or replays; {old} pending block(s) of the old run discarded")
            elif stamp_ns - ch.last_end > self._new_run_gap_ns:
                ch.run += 1
                self._event(events, 'new_run', channel, seq, stamp_ns,
                            f"stamp {stamp_ns} ns is {(stamp_ns - ch.last_end) / NS_PER_S:.3f} s after the previous "
                            f"block ended (new_run_gap_s {self._new_run_gap_ns / NS_PER_S:g})")
            elif seq != ch.last_seq + 1:
                self._event(events, 'dropped', channel, seq, stamp_ns,
                            f"expected seq {ch.last_seq + 1}, got {seq}: "
                            f"{seq - ch.last_seq - 1} block(s) missing")
        ch.last_seq, ch.last_stamp = seq, stamp_ns
        ch.last_end = end_stamp_ns(stamp_ns, n_samples, rate)
        blk = _Block(stamp_ns, seq, rate, n_samples, payload, ch.run)

        # 2. match against the other channels
        others = [c for c in self._names if c != channel]
        if all(stamp_ns in self._ch[c].pending for c in others):
            group = {channel: blk}
            for c in others:
                group[c] = self._ch[c].pending.pop(stamp_ns)
            self._discard_older(stamp_ns, events)
            bad = self._check_group(group, events)
            if not bad:
                pairs.append(self._make_pair(group, events))
            return pairs, events

        # 3. wait for the partners
        ch.pending[stamp_ns] = blk
        while len(ch.pending) > self._max_pending:
            _, old = ch.pending.popitem(last=False)
            self._event(events, 'unmatched', channel, old.seq, old.stamp_ns,
                        f"no partner after {self._max_pending} blocks "
                        f"(max_pending {self._max_pending}); block discarded", old.payload)
        return pairs, events

    def _discard_older(self, stamp_ns: int, events) -> None:
        for c in self._names:
            pend = self._ch[c].pending
            while pend:
                k = next(iter(pend))
                if k >= stamp_ns:
                    break
                old = pend.pop(k)
                self._event(events, 'unmatched', c, old.seq, old.stamp_ns,
                            f"stamp {old.stamp_ns} ns has no partner; a later stamp "
                            f"{stamp_ns} ns was paired; block discarded", old.payload)

    def _check_group(self, group: Dict[str, _Block], events) -> bool:
        ref_name = self._names[0]
        ref = group[ref_name]
        for c in self._names[1:]:
            b = group[c]
            if not rates_equal(b.rate_hz, ref.rate_hz):
                for name, bb in group.items():
                    self._event(events, 'rate_mismatch', name, bb.seq, bb.stamp_ns,
                                f"stamp {ref.stamp_ns} ns: {ref_name} rate {ref.rate_hz} Hz "
                                f"vs {c} rate {b.rate_hz} Hz; blocks discarded")
                return True
            if b.n != ref.n:
                for name, bb in group.items():
                    self._event(events, 'length_mismatch', name, bb.seq, bb.stamp_ns,
                                f"stamp {ref.stamp_ns} ns: {ref_name} has {ref.n} samples vs "
                                f"{c} {b.n}; blocks discarded")
                return True
        return False

    def _make_pair(self, group: Dict[str, _Block], events) -> AlignedPair:
        ref = group[self._names[0]]
        prev = self._last_pair
        runs = tuple(group[c].run for c in self._names)
        continuous = False
        # the first pair of a new run follows nothing: its new_run event said so, once
        if prev is not None and runs == self._last_runs:
            continuous = bool(follows(prev.stamp_ns, prev.n_samples, prev.sample_rate_hz,
                                      ref.stamp_ns, ref.rate_hz))
            if not continuous:
                expected = prev.stamp_ns + prev.n_samples * NS_PER_S / prev.sample_rate_hz
                self._event(events, 'discontinuity', self._names[0], ref.seq, ref.stamp_ns,
                            f"stamp {ref.stamp_ns} ns, expected {expected:.0f} ns "
                            f"(+/- {0.5 * NS_PER_S / ref.rate_hz:.0f} ns) after stamp {prev.stamp_ns} ns with "
                            f"{prev.n_samples} samples at {prev.sample_rate_hz} Hz; rate now "
                            f"{ref.rate_hz} Hz")
        pair = AlignedPair(
            stamp_ns=ref.stamp_ns, n_samples=ref.n, sample_rate_hz=ref.rate_hz,
            payloads={c: group[c].payload for c in self._names},
            seqs={c: group[c].seq for c in self._names},
            continuous=continuous)
        self._last_pair, self._last_runs = pair, runs
        self.pairs_emitted += 1
        return pair
