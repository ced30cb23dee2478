"""Offline correction and scoring of a bag or a campaign with the live nodes' core.

Bag input: the /force and /accel blocks (by type) are paired by force_correction's BlockAligner
in log order, exactly as correction_node does, and the filter restarts where the aligner
reports a discontinuity (pair.continuous False), exactly as the node does. Each continuous run
goes through correct_block whole or in segments with the state carried over: the core
guarantees the result equals block-by-block streaming bit for bit, so the numbers equal the
live node's. Pulls are cut by the PullEvent START/END windows by sample time and scored with
score_pull (what PullAccumulator.score does) and SetStatistics, like validator_node.

Fast path (the usual bag: one uncompressed MCAP file, blocks that pair one to one without
drops): the blocks are decoded a topic at a time with numpy (fastcdr, mcapfile), corrected,
scored and written in segments of one or more pulls (cut where pull windows start; about
SEGMENT_SAMPLES to twice that), and the output bag is the input file copied byte for byte
plus the result topics (mcapfile.ExtendedBag). Anything else takes the generic
path (rosbags message by message, the BlockAligner itself), which gives the same numbers.

Campaign input: each pull is one run; consecutive pulls form one run only when the second's
start_ns is exactly where the first ends (a contiguous recording, as the sim publishes).
"""

from __future__ import annotations

import json
import shutil
import tempfile
from contextlib import nullcontext
from dataclasses import asdict, replace
from heapq import merge
from pathlib import Path
from typing import Any, Callable

import numpy as np

from force_correction.core.extension import Extension, ForcePrefilter
from force_correction.core import (BlockAligner, CorrectionError, CorrectionParams,
                                   SetStatistics, correct_block, initial_state, score_pull)
from force_tester_common.core.channels import PULL_EVENT_TYPE

from .convert import CORRECTED_NAME, CORRECTED_TOPIC, header, place_pulls, stamp_of
from force_tester_common.core.clock import NS_PER_S, end_stamp_ns, record_stamps_ns

from .daq import CAMPAIGN_FILE, Campaign, DaqPull, read_campaign, write_campaign
from .errors import BagError
from .fastcdr import FastPathError, block_lengths, decode_blocks, encode_blocks
from .mcapfile import ExtendedBag, McapBag, read_topics_raw
from .reader import open_bag
from .typestore import default_typestore, shared_typestore, type_definition
from .writer import BagWriter

FORCE_TYPE = 'force_tester_msgs/msg/ForceBlock'
ACCEL_TYPE = 'force_tester_msgs/msg/AccelBlock'
SCORE_TYPE = 'force_tester_msgs/msg/PullScore'
SUMMARY_TYPE = 'force_tester_msgs/msg/SetSummary'
RESULT_TOPICS = ((CORRECTED_TOPIC, CORRECTED_NAME), ('/pull_score', SCORE_TYPE),
                 ('/set_summary', SUMMARY_TYPE))  # what correct adds to a bag
OUTPUT_TOPICS = tuple(t for t, _ty in RESULT_TOPICS)
SCORE_FIELDS = ('stationary_peak_n', 'raw_peak_n', 'corrected_peak_n', 'filtered_peak_n',
                'raw_diff_pct', 'corrected_diff_pct', 'filtered_diff_pct', 'raw_rms_n',
                'corrected_rms_n', 'filtered_rms_n')

Progress = Callable[[int, int], None]


def source_kind(src: str | Path) -> str:
    p = Path(src)
    if (p / CAMPAIGN_FILE).is_file():
        return 'campaign'
    if (p / 'metadata.yaml').is_file() or any(p.glob('*.mcap')):
        return 'bag'
    if not p.exists():
        raise BagError(f'source {str(p)!r} does not exist; expected a bag or a campaign folder')
    raise BagError(f'source {str(p)!r} is neither a bag (metadata.yaml) nor a campaign '
                   f'({CAMPAIGN_FILE})')


def _params(mass_kg, window) -> CorrectionParams:
    try:
        return CorrectionParams(mass_kg=mass_kg, window=window)
    except CorrectionError as exc:
        raise BagError(str(exc)) from None


def _pull_event(msg, starts: dict, windows: list, warnings: list) -> None:
    """A PullEvent: a START opens a pull; its END closes it into (start, end, set, pull_id)."""
    if int(msg.event) == 0:
        starts[int(msg.pull_id)] = (stamp_of(msg), int(msg.test_set))
        return
    st = starts.pop(int(msg.pull_id), None)
    if st is None:
        warnings.append(f'END of pull {msg.pull_id} without its START; not scored')
    else:
        windows.append((st[0], stamp_of(msg), st[1], int(msg.pull_id)))


PART_KEYS = ('t', 'stationary', 'raw', 'inertial', 'corrected', 'filtered')
SEGMENT_SAMPLES = 1 << 17  # the fast path corrects, scores and writes this many at a time


class _Scorer:
    """Scores pull windows (start, end, set, pull_id) over corrected samples fed in time order
    (or all at once): a window is scored once a sample at or after its end has been seen (or at
    finish), so only the samples of open windows are held. Same result as slicing the whole
    recording with searchsorted."""

    KEYS = ('stationary', 'raw', 'corrected', 'filtered')

    def __init__(self, windows: list, drops: list, loaded_fraction: float) -> None:
        self.windows = list(windows)
        by_start = sorted(range(len(self.windows)), key=lambda i: self.windows[i][:2])
        self.open = {i: [] for i in by_start}  # stays in start order
        self.outcome: dict = {}
        self.drops = np.array(sorted(drops), dtype=np.int64)
        self.loaded_fraction = loaded_fraction

    def add(self, seg: dict) -> None:
        t = seg['t']
        if not t.size:
            return
        last, latest = int(t[-1]), int(t.max())
        for i in list(self.open):
            start, end = self.windows[i][:2]
            if start > latest:  # this and the later windows have no samples here
                break
            lo, hi = t.searchsorted([start, end])
            if hi > lo:
                self.open[i].append({k: seg[k][lo:hi] for k in self.KEYS})
            if last >= end:
                self._score(i)

    def _score(self, i: int) -> None:
        parts = self.open.pop(i)
        start, end, set_id, pull_id = self.windows[i]
        if not parts:
            self.outcome[i] = f'pull {pull_id} (set {set_id}): no corrected samples; not scored'
            return
        arrays = [np.concatenate([p[k] for p in parts]) if len(parts) > 1 else parts[0][k]
                  for k in self.KEYS]
        try:
            self.outcome[i] = score_pull(*arrays, loaded_fraction=self.loaded_fraction)
        except CorrectionError as exc:
            self.outcome[i] = f'pull {pull_id} (set {set_id}) not scored: {exc}'

    def finish(self, warnings: list) -> tuple:
        """(per-pull dicts, SetStatistics), in window order; problems go to warnings."""
        for i in list(self.open):
            self._score(i)
        stats, pulls = SetStatistics(), []
        for i, (start, end, set_id, pull_id) in enumerate(self.windows):
            s = self.outcome[i]
            if isinstance(s, str):
                warnings.append(s)
                continue
            dropped = int(np.count_nonzero((self.drops >= start) & (self.drops < end)))
            pulls.append({'pull_id': int(pull_id), 'set': int(set_id), 'start_ns': int(start),
                          'end_ns': int(end), 'dropped_blocks': dropped,
                          **{k: float(getattr(s, k)) for k in SCORE_FIELDS}})
            stats.add(set_id, replace(s, dropped_blocks=dropped))
        return pulls, stats


class _Stream:
    """The live correction node's arithmetic over a recording fed in time order, a whole run or
    a segment of a run at a time: the extension's prefilter and m*a + moving average, their
    state carried within a run and reset at each new run (as the node resets after a
    discontinuity; the core guarantees any split gives the same numbers). Each piece goes on to
    the scorer (once the pull windows are known), to an ExtendedBag as /force_corrected blocks
    (with `write_to`), and is kept whole if `keep` or while the pull windows are unknown."""

    def __init__(self, params: CorrectionParams, extension: Extension | None,
                 loaded_fraction: float, keep: bool = True) -> None:
        self.params, self.extension = params, extension
        self.loaded_fraction, self.keep = loaded_fraction, keep
        self.parts: dict = {k: [] for k in PART_KEYS}
        self.nan_count = 0
        self.runs = 0
        self.scorer: _Scorer | None = None
        self.target: tuple | None = None  # (ExtendedBag, channel id)
        self.seq = 0
        self._state = None
        self._prefilter = None

    def windows_known(self, windows: list, drops: list) -> None:
        self.scorer = _Scorer(windows, drops, self.loaded_fraction)

    def write_to(self, target: ExtendedBag, cid: int) -> None:
        self.target = (target, cid)

    def add(self, stamps: np.ndarray, force: np.ndarray, accel: np.ndarray,
            stationary: np.ndarray, rate_hz: float, new_run: bool = True,
            blocks: tuple | None = None, frame: str = '') -> Any:
        """Correct one piece; blocks = (stamps, sample counts, rates) of its blocks, needed
        when writing to a bag."""
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
        seg = dict(zip(PART_KEYS, (stamps, stationary, measured, out.inertial_n,
                                   out.corrected_n, out.filtered_n)))
        if self.scorer is not None:
            self.scorer.add(seg)
        if self.target is not None:
            _corrected_blocks(seg, blocks, frame, self.seq, *self.target)
            self.target[0].commit()
        self.seq += len(blocks[0]) if blocks is not None else 0
        if self.keep or self.scorer is None:  # pulls not known yet: kept for scoring
            if isinstance(stamps, _BlockStamps):
                seg['t'] = stamps.array()
            for k in PART_KEYS:
                self.parts[k].append(seg[k])
        return out

    def arrays(self) -> dict:
        return {k: (v[0] if len(v) == 1 else np.concatenate(v) if v else np.empty(0))
                for k, v in self.parts.items()}

    def scores(self, windows: list, drops: list, warnings: list) -> tuple:
        """(per-pull dicts, SetStatistics): from the scorer fed as the data came when the
        windows were known first, else from the kept arrays."""
        if self.scorer is None:
            self.windows_known(windows, drops)
            self.scorer.add(self.arrays())
        return self.scorer.finish(warnings)


def _summaries(stats: SetStatistics) -> list:
    return [asdict(stats.summary(s)) for s in sorted(stats.sets())]


def _running_summaries(pulls: list, stats: SetStatistics) -> list:
    """The per-set summary after each pull (what /set_summary carries live)."""
    running, out, seen = SetStatistics(), [], {}
    for p in pulls:
        k = seen.get(p['set'], 0)
        seen[p['set']] = k + 1
        running.add(p['set'], stats.scores(p['set'])[k])
        out.append(asdict(running.summary(p['set'])))
    return out


# --------------------------------------------------------------------------- bag
FORCE_FIELDS = ('moving_n', 'stationary_n')
ACCEL_FIELDS = ('axial_m_s2', 'lateral_m_s2', 'vertical_m_s2')
CORRECTED_FIELDS = ('raw_n', 'inertial_n', 'corrected_n', 'filtered_n')
_MAX_PENDING = 50  # BlockAligner's default, as correction_node uses


def _fast_bag(src: Path) -> McapBag | None:
    try:
        return McapBag(src)
    except FastPathError:
        return None


def _sample_stamps(first: np.ndarray, k: np.ndarray, rate: np.ndarray) -> np.ndarray:
    """Stamp of sample k of blocks starting at first (sample_stamps_ns' arithmetic)."""
    out = np.empty(np.broadcast(first, k, rate).shape, dtype=np.int64)
    first, k, rate = np.broadcast_arrays(first, k, rate)
    isint = rate == np.floor(rate)
    if isint.any():
        out[isint] = first[isint] + (k[isint] * NS_PER_S) // rate[isint].astype(np.int64)
    if not isint.all():
        nr = ~isint
        out[nr] = first[nr] + np.round(k[nr] * (NS_PER_S / rate[nr])).astype(np.int64)
    return out


class _BlockStamps:
    """The sample stamps of consecutive blocks of one size and rate (block stamps increasing,
    blocks not overlapping) without the per-sample array: what _Scorer reads (size, t[i],
    max(), searchsorted) computed from the blocks; array() gives the samples' stamps."""

    def __init__(self, stamps: np.ndarray, n: int, rate: float) -> None:
        self.stamps, self.n = stamps, n
        self.offsets = _sample_stamps(np.zeros(1, np.int64), np.arange(n), np.full(1, rate))
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


def _block_sample_stamps(stamps: np.ndarray, n: np.ndarray,
                         rate: np.ndarray) -> np.ndarray | _BlockStamps:
    """Concatenated sample_stamps_ns(stamps[i], n[i], rate[i]), as a _BlockStamps when the
    blocks are of one size and rate (the usual case)."""
    if n.size and n[0] > 0 and (n == n[0]).all() and (rate == rate[0]).all():
        return _BlockStamps(stamps, int(n[0]), float(rate[0]))
    k = np.arange(int(n.sum()), dtype=np.int64) - np.repeat(np.cumsum(n) - n, n)
    return _sample_stamps(np.repeat(stamps, n), k, np.repeat(rate, n))


def _segments(ends: np.ndarray, lo: int, hi: int, wanted: np.ndarray) -> list:
    """Block boundaries cutting blocks [lo, hi) (ends: cumulative sample counts) into
    segments of SEGMENT_SAMPLES to 2 * SEGMENT_SAMPLES samples (unless one block or the run is
    longer or shorter), cut at the wanted boundaries where that allows, else every
    SEGMENT_SAMPLES."""
    def samples(a, b):
        return int(ends[b - 1]) - (int(ends[a - 1]) if a else 0)

    cuts = [lo]
    for c in [*sorted(set(wanted[(wanted > lo) & (wanted < hi)].tolist())), hi]:
        while samples(cuts[-1], c) > 2 * SEGMENT_SAMPLES:
            base = int(ends[cuts[-1] - 1]) if cuts[-1] else 0
            cuts.append(max(int(np.searchsorted(ends, base + SEGMENT_SAMPLES, 'right')),
                            cuts[-1] + 1))
        if c > cuts[-1] and (c == hi or samples(cuts[-1], c) >= SEGMENT_SAMPLES):
            cuts.append(c)
    return cuts


def _read_bag_fast(bag: McapBag, stream: _Stream, warnings: list,
                   progress: Progress | None = None) -> dict:
    """_read_bag for the common case, with whole-topic numpy decoding. The aligner's result
    is computed in closed form; raises FastPathError (before touching the stream) whenever the
    aligner would report anything but discontinuities, so the generic path handles it. The
    samples go through the stream in segments (_segments), windows known first."""
    topics = bag.topics()
    force_t = [n for n, t in topics.items() if t[0] == FORCE_TYPE]
    accel_t = [n for n, t in topics.items() if t[0] == ACCEL_TYPE]
    event_t = [n for n, t in topics.items() if t[0] == PULL_EVENT_TYPE]
    if not force_t or not accel_t or not event_t:
        raise FastPathError('missing topics')
    force_topic = '/force' if '/force' in force_t else sorted(force_t)[0]
    accel_topic = '/accel' if '/accel' in accel_t else sorted(accel_t)[0]
    wanted = [force_topic, accel_topic, *event_t]
    store = shared_typestore()
    if any(bag.hashes.get(t) != type_definition(topics[t][0])[1] for t in wanted):
        raise FastPathError('message definitions differ from force_tester_msgs')
    raw, _ = read_topics_raw(bag.mcap, wanted, bag.summary, bag.mm)
    for i, t in enumerate(wanted):
        if int(np.count_nonzero(raw.channel == i)) != topics[t][1]:
            raise FastPathError('message counts differ from the metadata')
    fsel = np.flatnonzero(raw.channel == 0)
    asel = np.flatnonzero(raw.channel == 1)
    fb = decode_blocks(raw.buf, raw.starts[fsel], raw.lengths[fsel], FORCE_FIELDS)
    ab = decode_blocks(raw.buf, raw.starts[asel], raw.lengths[asel], ACCEL_FIELDS)
    m = len(fb)
    if m == 0 or len(ab) != m:
        raise FastPathError('unpaired blocks')
    n = fb.counts['moving_n']
    if not (np.array_equal(fb.stamp_ns, ab.stamp_ns) and np.array_equal(n, ab.counts[
            'axial_m_s2']) and np.array_equal(n, fb.counts['stationary_n'])):
        raise FastPathError('blocks do not pair one to one')
    for b in (fb, ab):
        if (b.seq >= 2**63).any() or (np.diff(b.seq.astype(np.int64)) != 1).any() \
                or (np.diff(b.stamp_ns) <= 0).any():
            raise FastPathError('dropped or out-of-order blocks')
    fr, ar = fb.rate_hz, ab.rate_hz
    if not (np.isfinite(fr).all() and (fr > 0).all() and np.isfinite(ar).all()
            and (ar > 0).all()):
        raise FastPathError('bad rates')
    if (np.abs(ar - fr) > 1e-9 * np.maximum(np.abs(ar), np.abs(fr))).any():
        raise FastPathError('rate mismatch')
    # how many blocks wait in a channel for their partner (aligner max_pending)
    idx = np.arange(m)
    for mine, other in ((fsel, asel), (asel, fsel)):
        before = np.searchsorted(other, mine)
        if (idx - before + 1).max() > _MAX_PENDING:
            raise FastPathError('blocks wait longer than max_pending')
    # events (few): generic deserialisation
    starts: dict = {}
    windows: list = []
    for i in np.flatnonzero(raw.channel >= 2).tolist():
        _pull_event(store.deserialize_cdr(raw.data(i), PULL_EVENT_TYPE), starts, windows,
                    warnings)
    stamps = fb.stamp_ns
    last = _sample_stamps(stamps, n - 1, fr)
    if (stamps[1:] <= last[:-1]).any():
        raise FastPathError('blocks overlap in time')
    cont = np.zeros(m, dtype=bool)
    if m > 1:
        expected = stamps[:-1] + n[:-1] * 1e9 / fr[:-1]
        cont[1:] = ((np.abs(fr[:-1] - fr[1:]) <= 1e-9 * np.maximum(np.abs(fr[:-1]),
                                                                     np.abs(fr[1:])))
                    & (np.abs(stamps[1:] - expected) <= 0.5e9 / fr[1:]))
    for pid in starts:
        warnings.append(f'pull {pid} has no END; not scored')
    windows = sorted(windows)
    stream.windows_known(windows, [])
    frame = fb.frame_id(m - 1)
    bounds = [*np.flatnonzero(~cont).tolist(), m]
    ends = np.cumsum(n)
    # blocks where a window starts: a segment boundary there keeps most windows in one
    # segment, which the scorer then takes without copying
    window_blocks = np.searchsorted(last, np.array([w[0] for w in windows], dtype=np.int64))
    for lo, hi in zip(bounds[:-1], bounds[1:]):  # runs, cut into segments
        segs = _segments(ends, lo, hi, window_blocks)
        for a, b in zip(segs[:-1], segs[1:]):
            sel = slice(a, b)
            stream.add(_block_sample_stamps(stamps[sel], n[sel], fr[sel]),
                       fb.values('moving_n', sel), ab.values('axial_m_s2', sel),
                       fb.values('stationary_n', sel), float(fr[a]), new_run=a == lo,
                       blocks=(stamps[sel], n[sel], fr[sel]), frame=frame)
            if progress:  # in messages, as the generic path counts
                progress(2 * b, raw.log_ns.size)
    return {'pairs': (stamps, n, fr), 'windows': windows, 'drops': [], 'frame': frame}


def _read_bag(src: Path, fast: McapBag | None, stream: _Stream, warnings: list,
              progress: Progress | None) -> dict:
    if fast is not None:
        try:
            return _read_bag_fast(fast, stream, warnings, progress)
        except FastPathError:
            pass
    with open_bag(src) as bag:
        topics = bag.topics()
        force_t = [n for n, t in topics.items() if t.type_name == FORCE_TYPE]
        accel_t = [n for n, t in topics.items() if t.type_name == ACCEL_TYPE]
        event_t = [n for n, t in topics.items() if t.type_name == PULL_EVENT_TYPE]
        for what, found, default in (('ForceBlock', force_t, '/force'),
                                     ('AccelBlock', accel_t, '/accel')):
            if not found:
                raise BagError(f'bag {str(src)!r} has no {what} topic; expected {default} '
                               'blocks to correct')
        force_topic = '/force' if '/force' in force_t else sorted(force_t)[0]
        accel_topic = '/accel' if '/accel' in accel_t else sorted(accel_t)[0]
        aligner = BlockAligner(('force', 'accel'))
        pairs: list = []
        run: list = []
        drop_events: list = []
        starts: dict = {}
        windows: list = []
        frame = ''

        def flush():
            if run:
                f = np.concatenate([p[1] for p in run])
                a = np.concatenate([p[2] for p in run])
                s = np.concatenate([p[3] for p in run])
                st = np.concatenate([record_stamps_ns(p[0].stamp_ns, p[0].n_samples,
                                                      p[0].sample_rate_hz) for p in run])
                blocks = [(p[0].stamp_ns, p[0].n_samples, p[0].sample_rate_hz) for p in run]
                stream.add(st, f, a, s, float(run[0][0].sample_rate_hz),
                           blocks=tuple(np.array(c, dtype=d) for c, d in zip(
                               zip(*blocks), (np.int64, np.int64, float))), frame=frame)
                pairs.extend(blocks)
                run.clear()

        if not event_t:
            warnings.append(f'bag {str(src)!r} has no {PULL_EVENT_TYPE} topic: corrected, but '
                            'no pull can be scored')
        wanted = [force_topic, accel_topic, *event_t]
        total = sum(topics[t].count for t in wanted)
        for k, (topic, type_name, _log, cdr) in enumerate(bag.messages(wanted)):
            msg = bag.deserialize(cdr, type_name)
            if type_name == PULL_EVENT_TYPE:
                _pull_event(msg, starts, windows, warnings)
                continue
            channel = 'force' if topic == force_topic else 'accel'
            n = len(msg.moving_n) if channel == 'force' else len(msg.axial_m_s2)
            if channel == 'force':
                frame = msg.header.frame_id
            try:
                new, events = aligner.push(channel, stamp_of(msg), int(msg.seq),
                                           float(msg.sample_rate_hz), n, msg)
            except CorrectionError as exc:
                raise BagError(f'{topic} block seq {msg.seq}: {exc}') from None
            for ev in events:
                if ev.kind in ('dropped', 'unmatched'):
                    drop_events.append(ev.stamp_ns)
                if ev.kind != 'discontinuity':
                    warnings.append(f'{ev.kind} block on {ev.channel}: {ev.detail}')
            for pair in new:
                if not pair.continuous:
                    flush()
                fm, am = pair['force'], pair['accel']
                run.append((pair, np.asarray(fm.moving_n, dtype=np.float64),
                            np.asarray(am.axial_m_s2, dtype=np.float64),
                            np.asarray(fm.stationary_n, dtype=np.float64)))
            if progress and k % 20000 == 0:
                progress(k, total)
        flush()
        for pid in starts:
            warnings.append(f'pull {pid} has no END; not scored')
    if not pairs:
        raise BagError(f'bag {str(src)!r}: no /force block pairs with an /accel block of the '
                       'same stamp; nothing to correct')
    stamps, ns, rates = (np.array(c, dtype=d) for c, d in zip(zip(*pairs),
                                                               (np.int64, np.int64, float)))
    return {'pairs': (stamps, ns, rates), 'windows': sorted(windows), 'drops': drop_events,
            'frame': frame}


def _corrected_blocks(arr: dict, blocks: tuple, frame: str, seq0: int = 0,
                      target: ExtendedBag | None = None, cid: int = 0) -> tuple:
    """/force_corrected blocks for the input blocks (stamps, sample counts, rates) whose
    samples arr holds, seq from seq0, logged at their last sample (as the live node publishes):
    encode_blocks' (buffer, starts, lengths) and the log times, or, with a target, encoded
    into the space target.reserve() lays out."""
    stamps, ns, rates = blocks
    last = np.where(ns > 0, _sample_stamps(stamps, np.maximum(ns - 1, 0), rates), stamps)
    counts = {f: ns for f in CORRECTED_FIELDS}
    out = starts = None
    if target is not None:
        out, starts = target.reserve(np.full(ns.size, cid),
                                     block_lengths(CORRECTED_FIELDS, counts, frame), last)
    try:
        enc = encode_blocks(stamps, rates, seq0 + np.arange(stamps.size), CORRECTED_FIELDS,
                            counts, {'raw_n': arr['raw'], 'inertial_n': arr['inertial'],
                                     'corrected_n': arr['corrected'],
                                     'filtered_n': arr['filtered']},
                            frame, out=out, starts=starts)
    except FastPathError as exc:
        raise BagError(f'cannot write the corrected blocks: {exc}') from None
    return (*enc, last)


def _result_messages(store, pulls: list, by_pull: list) -> list:
    """(log time, order, topic, type, CDR) of the /pull_score and /set_summary messages."""
    T = store.types
    out = []
    for p, summ in zip(pulls, by_pull):
        msg = T[SCORE_TYPE](header=header(store, p['start_ns']), pull_id=p['pull_id'],
                            test_set=p['set'], dropped_blocks=p['dropped_blocks'],
                            **{f: p[f] for f in SCORE_FIELDS})
        out.append((p['end_ns'], 1, '/pull_score', SCORE_TYPE,
                    bytes(store.serialize_cdr(msg, SCORE_TYPE))))
        msg = T[SUMMARY_TYPE](
            header=header(store, p['start_ns']), test_set=p['set'], pulls=summ['pulls'],
            stationary_peak_mean_n=summ['mean_stationary_peak_n'],
            raw_diff_mean_pct=summ['raw_mean_pct'], raw_diff_std_pct=summ['raw_std_pct'],
            corrected_diff_mean_pct=summ['corrected_mean_pct'],
            corrected_diff_std_pct=summ['corrected_std_pct'],
            filtered_diff_mean_pct=summ['filtered_mean_pct'],
            filtered_diff_std_pct=summ['filtered_std_pct'])
        out.append((p['end_ns'], 2, '/set_summary', SUMMARY_TYPE,
                    bytes(store.serialize_cdr(msg, SUMMARY_TYPE))))
    out.sort(key=lambda g: (g[0], g[1]))
    return out


def _extension_target(fast: McapBag | None, dst: Path) -> ExtendedBag | None:
    """Where the fast path writes: the input copied byte for byte plus the results, when the
    input is one suitable MCAP file without result topics of its own."""
    if fast is None or set(OUTPUT_TOPICS) & set(fast.topics()):
        return None
    return ExtendedBag(fast, dst)


def _add_result_topics(target: ExtendedBag) -> dict:
    return {t: target.add_topic(t, ty, *type_definition(ty)) for t, ty in RESULT_TOPICS}


def _write_bag(src: Path, dst: Path, arr: dict, data: dict, pulls: list, by_pull: list,
               warnings: list) -> None:
    """The generic writer: every input message through rosbags, merged with the results."""
    store = default_typestore()
    buf, starts, lengths, last = _corrected_blocks(arr, data['pairs'], data['frame'])
    generated = [(int(lg), 0, CORRECTED_TOPIC, CORRECTED_NAME, buf[a:a + k])
                 for lg, a, k in zip(last.tolist(), starts.tolist(), lengths.tolist())]
    generated += _result_messages(store, pulls, by_pull)
    generated.sort(key=lambda g: (g[0], g[1]))
    with open_bag(src) as bag, BagWriter(dst, store) as writer:
        topics = bag.topics()
        keep = [t for t in topics if t not in OUTPUT_TOPICS]
        replaced = [t for t in topics if t in OUTPUT_TOPICS]
        if replaced:
            warnings.append(f'input topics {", ".join(replaced)} replaced by the offline '
                            'results')
        for t in keep:
            type_name = topics[t].type_name
            if type_name not in store.types:
                try:
                    store.register({type_name: bag.typestore.fielddefs[type_name]})
                except Exception:  # noqa: BLE001
                    warnings.append(f'topic {t} ({type_name}) not copied: its type is unknown')
                    continue
            writer.add_topic(t, type_name)
        for t, type_name in RESULT_TOPICS:
            writer.add_topic(t, type_name)
        keep = [t for t in keep if t in writer.topics]
        src_iter = ((m.stamp_ns, -1, m.topic, m.type_name, m.cdr) for m in bag.messages(keep)) \
            if keep else iter(())
        for log, _o, topic, _type, cdr in merge(src_iter, iter(generated),
                                                 key=lambda g: (g[0], g[1])):
            writer.write(topic, log, cdr)


# --------------------------------------------------------------------------- campaign
def _campaign_runs(camp: Campaign, stream: _Stream) -> tuple:
    """Correct each pull (joining contiguous pulls into one run). Returns (windows, outs)."""
    rate = camp.sample_rate_hz
    placed = place_pulls(camp)
    windows = []
    groups: list = []
    prev_end = None
    for (start, pid), p in zip(placed, camp.pulls):
        n = len(p.channels['time_s'])
        contiguous = p.meta.get('start_ns') is not None and prev_end == start
        if contiguous:
            groups[-1].append((start, n, p))
        else:
            groups.append([(start, n, p)])
        prev_end = end_stamp_ns(start, n, rate) if p.meta.get('start_ns') is not None else None
        windows.append((start, end_stamp_ns(start, n, rate), int(p.meta['set']), pid))
    outs = []
    for g in groups:
        ch = [x[2].channels for x in g]
        out = stream.add(np.concatenate([record_stamps_ns(s, n, rate) for s, n, _ in g]),
                         np.concatenate([c['force_moving_n'] for c in ch]),
                         np.concatenate([c['accel_axial_m_s2'] for c in ch]),
                         np.concatenate([c['force_stationary_n'] for c in ch]), rate)
        pos = 0
        for _s, n, _p in g:
            outs.append({k: getattr(out, k)[pos:pos + n] for k in
                         ('inertial_n', 'corrected_n', 'filtered_n')})
            pos += n
    return windows, outs


def correct(src: str | Path, dst: str | Path, mass_kg: float = 1.152, window: int = 140,
            loaded_fraction: float = 0.1, to: str | None = None,
            progress: Progress | None = None, warnings: list | None = None,
            extension: str | Path | None = None) -> dict:
    """Correct and score a bag or a campaign; write the result to dst (a new bag or campaign).

    to: 'bag' or 'campaign' (default: the kind of src; a campaign can only be written as a
    campaign here, use `import` afterwards for a bag). Returns {'params', 'pulls' (per-pull
    scores), 'sets' (per-set SetSummary dicts, thesis Tables 8-9), 'nan_samples', 'runs',
    'warnings'}. extension: an extension.yaml of `./ft discover`; its correction: section is undone
    before m*a exactly as the live correction node does (its mass_kg replaces mass_kg).
    """
    warnings = [] if warnings is None else warnings
    ext = None
    if extension is not None:
        try:
            ext = Extension.from_yaml(extension)
        except CorrectionError as exc:
            raise BagError(str(exc)) from None
        if ext.mass_kg is not None:
            mass_kg = ext.mass_kg
    params = _params(mass_kg, window)
    src, dst = Path(src), Path(dst)
    kind = source_kind(src)
    to = to or kind
    if to not in ('bag', 'campaign'):
        raise BagError(f'output kind {to!r} is invalid; expected bag or campaign')
    if dst.exists():
        raise BagError(f'output {str(dst)!r} exists already; expected a new directory name')
    if kind == 'campaign' and to == 'bag':
        # campaign -> bag (the same placement of pulls), then correct that bag
        from .convert import campaign_to_bag
        if not dst.parent.is_dir():
            raise BagError(f'parent directory {str(dst.parent)!r} of output {str(dst)!r} '
                           'does not exist')
        tmp = Path(tempfile.mkdtemp(prefix=f'.{dst.name}.import-', dir=dst.parent))
        try:
            campaign_to_bag(src, tmp / 'bag', warnings=warnings)
            return correct(tmp / 'bag', dst, mass_kg, window, loaded_fraction, 'bag',
                           progress, warnings, extension)
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
    target = None
    if kind == 'bag':
        fast = _fast_bag(src)
        target = _extension_target(fast, dst) if to == 'bag' else None
        stream = _Stream(params, ext, loaded_fraction, keep=target is None)
        with target if target is not None else nullcontext():
            if target is not None:  # results go out as they are computed
                cids = _add_result_topics(target)
                stream.write_to(target, cids[CORRECTED_TOPIC])
            data = _read_bag(src, fast, stream, warnings, progress)
            pulls, stats = stream.scores(data['windows'], data['drops'], warnings)
            by_pull = _running_summaries(pulls, stats)
            if target is not None:
                small = _result_messages(shared_typestore(), pulls, by_pull)
                target.write_messages([cids[g[2]] for g in small], [g[0] for g in small],
                                      [g[4] for g in small])
    else:
        camp = read_campaign(src)
        warnings.extend(camp.warnings)
        stream = _Stream(params, ext, loaded_fraction)
        windows, outs = _campaign_runs(camp, stream)
        pulls, stats = stream.scores(windows, [], warnings)
        by_pull = _running_summaries(pulls, stats)
    result = {'params': {'mass_kg': params.mass_kg, 'window': params.window,
                         'loaded_fraction': loaded_fraction},
              'pulls': pulls, 'sets': _summaries(stats), 'nan_samples': stream.nan_count,
              'runs': stream.runs, 'warnings': warnings}
    if to == 'bag':
        if target is None:
            _write_bag(src, dst, stream.arrays(), data, pulls, by_pull, warnings)
    else:
        if kind == 'bag':
            from .convert import read_bag_pulls
            rate, bpulls = read_bag_pulls(src, [], None)
            arrays = stream.arrays()
            new = []
            for i, p in enumerate(bpulls):
                start = p.meta['start_ns']
                n = len(p.channels['time_s'])
                t = record_stamps_ns(start, n, rate)
                lo, hi = np.searchsorted(arrays['t'], [t[0], t[-1] + 1])
                idx = np.rint((arrays['t'][lo:hi] - start) * (rate / NS_PER_S)).astype(np.int64)
                ch = dict(p.channels)
                for col, key in (('inertial_n', 'inertial'), ('corrected_n', 'corrected'),
                                 ('filtered_n', 'filtered')):
                    out = np.full(n, np.nan)
                    out[idx] = arrays[key][lo:hi]
                    ch[col] = out
                p.meta['file'] = f'pull_{i + 1:04d}.csv'
                new.append(DaqPull(p.meta, ch))
            camp_pulls, rig, rate_out = new, None, rate
        else:
            camp_pulls = [DaqPull(p.meta, {**p.channels, **o}) for p, o in zip(camp.pulls, outs)]
            rig = (camp.path / camp.rig) if camp.rig else None
            rate_out = camp.sample_rate_hz
        doc = {k: v for k, v in result.items() if k != 'warnings'}
        write_campaign(dst, camp_pulls, rig=rig, sample_rate_hz=rate_out,
                       extra={'scores.json': json.dumps(doc, indent=1, default=_json) + '\n'})
    return result


def _json(x):
    if isinstance(x, (np.integer,)):
        return int(x)
    if isinstance(x, (np.floating,)):
        return float(x)
    return str(x)
