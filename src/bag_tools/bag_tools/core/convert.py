"""Bag <-> DAQ campaign conversion (lossless for samples and stamps).

Bag -> campaign: the block messages of every block topic are cut into pulls by the PullEvent
START/END windows, by sample time (block stamp + k / rate), not by log time. Samples missing
inside a pull (dropped blocks) become NaN rows, with a warning.

Campaign -> bag: each pull is cut into blocks of ``block_size`` samples starting at the pull's
first sample. Block header stamp = the block's first sample; the bag's log time of a block =
the stamp of its LAST sample (the earliest moment the block exists, like a live recording,
so START is logged before the pull's first block and END after its last). PullEvent log time =
its header stamp. Messages are serialised with the rosbags typestore and written by BagWriter.
"""

from __future__ import annotations

import itertools
import math
from pathlib import Path
from typing import Callable, Iterator, Mapping, NamedTuple

import numpy as np
from rosbags.typesys.store import Typestore

from force_tester_common.core.blocks import PullWindows
from force_tester_common.core.channels import (
    ABSENTABLE_CHANNELS,
    BLOCK_TYPES,
    CORE_CHANNELS,
    CORRECTED_TYPE,
    OPTIONAL_CHANNELS,
    PULL_END,
    PULL_EVENT_TOPIC,
    PULL_EVENT_TYPE,
    PULL_START,
    REQUIRED_CHANNELS,
)
from force_tester_common.core.clock import (
    NS_PER_S,
    end_stamp_ns,
    record_stamps_ns,
    sample_stamps_ns,
)
from force_tester_common.core.units import FT_M, G_M_S2, LBF_N

from .daq import (
    CORRECTED_COLUMNS,
    DEFAULT_EPOCH_NS,
    DEFAULT_GAP_NS,
    Campaign,
    DaqPull,
    Mapper,
    Produced,
    PullJob,
    campaign_channels,
    campaign_index,
    check_rate,
    csv_columns,
    failed_line,
    map_pulls_in_order,
    read_campaign,
    read_pull,
    time_column,
    write_campaign,
)
from .daqfiles import NOTHING_TO_CORRECT
from .errors import BagError
from .reader import open_bag
from .typestore import default_typestore, header, stamp_of
from .writer import BagWriter

CORRECTED_NAME, (CORRECTED_TOPIC, CORRECTED_FIELDS) = CORRECTED_TYPE
#: Block types exported to campaign columns: type -> {field: column}.
EXPORT_FIELDS = {t: fields for t, (_topic, fields) in BLOCK_TYPES.items()}
EXPORT_FIELDS[CORRECTED_NAME] = {f: c for f, c in CORRECTED_FIELDS.items() if c != 'raw_n'}

#: Types a bag normally holds that have no DAQ column: skipped without a warning.
QUIET_TYPES = ('force_tester_msgs/msg/PullScore', 'force_tester_msgs/msg/SetSummary',
               'diagnostic_msgs/msg/DiagnosticArray', 'rosgraph_msgs/msg/Log')

Progress = Callable[[int, int], None]


# --------------------------------------------------------------------------- messages
_EMPTY = np.empty(0, dtype=np.float64)


def block_cdr(store: Typestore, type_name: str, stamp_ns: int, rate_hz: float, seq: int,
              arrays: dict, frame_id: str = '') -> bytes:
    """CDR of a block message; fields absent from arrays are empty."""
    cls = store.types[type_name]
    kwargs = {f: np.ascontiguousarray(arrays.get(f, _EMPTY), dtype=np.float64)
              for f in cls.__dataclass_fields__ if f not in ('header', 'sample_rate_hz', 'seq')}
    msg = cls(header=header(store, stamp_ns, frame_id), sample_rate_hz=float(rate_hz),
              seq=int(seq), **kwargs)
    return store.serialize_cdr(msg, type_name)


def pull_event_cdr(store: Typestore, stamp_ns: int, event: int, meta: dict, pull_id: int) -> bytes:
    msg = store.types[PULL_EVENT_TYPE](
        header=header(store, stamp_ns), event=event, pull_id=int(pull_id),
        test_set=int(meta['set']), coupon_break_n=float(meta['coupon_lbf']) * LBF_N,
        velocity_m_s=float(meta['velocity_fps']) * FT_M, decel_m_s2=float(meta['decel_g']) * G_M_S2)
    return store.serialize_cdr(msg, PULL_EVENT_TYPE)


# --------------------------------------------------------------------------- campaign -> bag
class PullPlacer:
    """(start_ns, pull_id) of each pull in turn: start_ns from campaign.yaml, else after the previous pull
    with a DEFAULT_GAP_NS gap (the first at DEFAULT_EPOCH_NS). Overlapping pulls are an error."""

    def __init__(self, rate_hz: float) -> None:
        self.rate = rate_hz
        self.prev_end = None
        self.count = 0

    def __call__(self, meta: Mapping, n: int) -> tuple:
        i = self.count
        start = meta.get('start_ns')
        if start is None:
            start = DEFAULT_EPOCH_NS if self.prev_end is None else self.prev_end + DEFAULT_GAP_NS
        elif self.prev_end is not None and start < self.prev_end:
            raise BagError(f'pull #{i} ({meta["file"]!r}) start_ns {start} is before the end '
                           f'of the previous pull ({self.prev_end} ns); expected pulls in time order, '
                           'not overlapping')
        pid = meta.get('pull_id')
        self.prev_end = end_stamp_ns(start, n, self.rate)
        self.count += 1
        return int(start), i + 1 if pid is None else int(pid)


def place_pulls(camp: Campaign) -> list:
    """(start_ns, pull_id) per pull of a campaign (PullPlacer)."""
    place = PullPlacer(camp.sample_rate_hz)
    return [place(p.meta, len(p.channels['time_s'])) for p in camp.pulls]


def campaign_topics(columns: list) -> list:
    """[(topic, type, {field: column})] of the bag of pulls with these column sets: a block topic when
    any pull has one of its columns, /force_corrected when every pull has the corrected columns."""
    present = set().union(*columns)
    topics = []
    for type_name, (topic, fields) in BLOCK_TYPES.items():
        if any(c in present for c in fields.values()):
            topics.append((topic, type_name, fields))
    if all(c in cols for cols in columns for c in CORRECTED_COLUMNS):
        topics.append((CORRECTED_TOPIC, CORRECTED_NAME,
                       {**EXPORT_FIELDS[CORRECTED_NAME], 'raw_n': 'force_moving_n'}))
    return topics


def _check_block_size(block_size) -> None:
    if isinstance(block_size, bool) or not isinstance(block_size, int) \
            or not 1 <= block_size <= 1_000_000:
        raise BagError(f'block_size {block_size!r} is invalid; expected an integer 1..1000000')


def pull_messages(store: Typestore, topics: list, seqs: dict, start: int, pid: int, pull: DaqPull,
                  rate: float, block_size: int) -> Iterator[tuple]:
    """(topic, type, log_ns, cdr) of one pull placed at ``start``: START, its blocks, END (seqs advance)."""
    ch = pull.channels
    n = len(ch['time_s'])
    stamps = record_stamps_ns(start, n, rate)
    yield PULL_EVENT_TOPIC, PULL_EVENT_TYPE, start, pull_event_cdr(store, start, PULL_START,
                                                                 pull.meta, pid)
    for b0 in range(0, n, block_size):
        b1 = min(b0 + block_size, n)
        first, last = int(stamps[b0]), int(stamps[b1 - 1])
        for topic, type_name, fields in topics:
            arrays = {f: ch[c][b0:b1] for f, c in fields.items() if c in ch}
            yield topic, type_name, last, block_cdr(store, type_name, first, rate,
                                                    seqs[topic], arrays)
            seqs[topic] += 1
    end = end_stamp_ns(start, n, rate)
    yield PULL_EVENT_TOPIC, PULL_EVENT_TYPE, end, pull_event_cdr(store, end, PULL_END,
                                                               pull.meta, pid)


def iter_campaign_messages(camp: Campaign, store: Typestore, block_size: int = 50
                           ) -> Iterator[tuple]:
    """(topic, type, log_ns, cdr) of the bag made from a campaign, in log-time order."""
    _check_block_size(block_size)
    topics = campaign_topics([set(p.channels) for p in camp.pulls])
    seqs = {t[0]: 0 for t in topics}
    for (start, pid), p in zip(place_pulls(camp), camp.pulls):
        yield from pull_messages(store, topics, seqs, start, pid, p, camp.sample_rate_hz, block_size)


def _absent_warning(columns: list) -> list:
    absent = [c for c in OPTIONAL_CHANNELS if all(c not in cols for cols in columns)]
    if not absent:
        return []
    return [f'no {", ".join(absent)} column(s): the bag has no samples of them'
            + (' and no /motor topic' if all(c in absent for c in BLOCK_TYPES[
                'force_tester_msgs/msg/MotorBlock'][1].values()) else '')]


def campaign_to_bag(src: str | Path | Campaign, bag_path: str | Path, block_size: int = 50,
                    typestore: Typestore | None = None, progress: Progress | None = None,
                    warnings: list | None = None, mapper: Mapper | None = None,
                    skip_failed: bool = False, info: dict | None = None) -> Path:
    """Write the bag of a campaign folder (or Campaign). Returns the bag path.

    Optional channels absent from every pull give empty fields (a MotorBlock topic only when
    at least one motor column exists); a warning says so.
    A folder of CSV pulls is streamed: its pull files are read (in parallel with ``mapper``, e.g.
    force_tester_common.engine.map_pulls) and each is written as soon as those before it are, so the
    campaign is never whole in memory; the bag itself is one file, written here in time order.
    skip_failed: a pull file that fails to read is left out with a warning naming it (else BagError).
    info: filled with 'pulls' (written), 'sample_rate_hz' and 'failed' ([(file, one line)]).
    """
    _check_block_size(block_size)
    warnings = [] if warnings is None else warnings
    info = {} if info is None else info
    store = typestore or default_typestore()
    if not isinstance(src, Campaign):
        path, rate, _rig, entries = campaign_index(src)
        cmap, absent = campaign_channels(path)
        columns = [csv_columns(path / meta['file']) for meta, _entry in entries]
        if cmap is None and all(c is not None for c in columns):
            return _stream_to_bag(path, rate, entries, columns, bag_path, block_size, store, progress,
                                  warnings, mapper, skip_failed, info, absent)
        src = read_campaign(src, mapper=mapper, skip_failed=skip_failed)   # TDMS pulls: read them first
    camp = src
    warnings.extend(camp.warnings)
    warnings.extend(_absent_warning([set(p.channels) for p in camp.pulls]))
    done = 0
    with BagWriter(bag_path, store, warnings=warnings, rewritable=True) as writer:
        for topic, type_name, log_ns, cdr in iter_campaign_messages(camp, store, block_size):
            if topic not in writer.topics:
                writer.add_topic(topic, type_name)
            writer.write(topic, log_ns, cdr)
            if progress and topic == PULL_EVENT_TOPIC:
                done += 1
                if done % 2 == 0:
                    progress(done // 2, len(camp.pulls))
    info.update(pulls=len(camp.pulls), sample_rate_hz=camp.sample_rate_hz, failed=list(camp.failed))
    return Path(bag_path)


def _stream_to_bag(path: Path, rate, entries: list, columns: list, bag_path, block_size: int, store,
                   progress, warnings: list, mapper, skip_failed: bool, info: dict, absent=()) -> Path:
    topics = campaign_topics(columns)
    seqs = {t[0]: 0 for t in topics}
    state: dict = {'rate': rate, 'place': None, 'pulls': 0}
    jobs = [PullJob(path / meta['file'], entry.get('map'), rate, None, absent) for meta, entry in entries]
    names = [meta['file'] for meta, _ in entries]
    with BagWriter(bag_path, store, warnings=warnings, rewritable=True) as writer:
        def write(i: int, result: tuple) -> None:
            channels, prate, pull_warnings = result
            warnings.extend(pull_warnings)
            state['rate'] = check_rate(jobs[i].path, prate, state['rate'])
            if state['place'] is None:
                state['place'] = PullPlacer(state['rate'])
            pull = DaqPull(entries[i][0], channels)
            start, pid = state['place'](pull.meta, len(channels['time_s']))
            for topic, type_name, log_ns, cdr in pull_messages(store, topics, seqs, start, pid, pull,
                                                               state['rate'], block_size):
                if topic not in writer.topics:
                    writer.add_topic(topic, type_name)
                writer.write(topic, log_ns, cdr)
            state['pulls'] += 1

        failed = map_pulls_in_order(read_pull, jobs, names, mapper, write, progress)
        if failed and not skip_failed:
            raise BagError(f'campaign {str(path)!r}: {failed_line(failed)}')
        if not state['pulls']:
            raise BagError(f'campaign {str(path)!r}: every pull failed; {failed_line(failed)}')
    warnings.extend(f'pull {name!r} skipped: {why}' for name, why in failed)
    bad = {name for name, _ in failed}
    ok = [cols for cols, (meta, _) in zip(columns, entries) if meta['file'] not in bad]
    miss = [c for c in OPTIONAL_CHANNELS if any(c not in cols for cols in ok)]
    if miss:
        warnings.append(f'campaign {str(path)!r}: optional column(s) {", ".join(miss)} missing '
                        'in some pulls; their topics/fields stay empty and they cannot be '
                        'plotted or exported')
    warnings.extend(_absent_warning(ok))
    info.update(pulls=state['pulls'], sample_rate_hz=state['rate'], failed=failed)
    return Path(bag_path)


# --------------------------------------------------------------------------- bag -> campaign
class _Series:
    """Blocks of one channel: block stamps, lengths and values; per-sample stamps and values
    are assembled (vectorised) at the end."""

    def __init__(self, rate_hz: float) -> None:
        self.rate = rate_hz
        self.stamps: list = []
        self.lengths: list = []
        self.values: list = []

    def add(self, stamp_ns: int, values: np.ndarray) -> None:
        self.stamps.append(stamp_ns)
        self.lengths.append(values.size)
        self.values.append(values)

    def drop_before(self, cutoff_ns: int) -> None:
        """Forget the blocks whose last sample is before cutoff_ns."""
        if not self.stamps:
            return
        first = np.asarray(self.stamps, dtype=np.int64)
        last = sample_stamps_ns(first, np.asarray(self.lengths, dtype=np.int64) - 1, self.rate)
        keep = np.flatnonzero(last >= cutoff_ns)
        if keep.size < first.size:
            self.stamps = [self.stamps[i] for i in keep]
            self.lengths = [self.lengths[i] for i in keep]
            self.values = [self.values[i] for i in keep]

    def arrays(self) -> tuple:
        if not self.stamps:
            return np.empty(0, np.int64), _EMPTY
        lengths = np.asarray(self.lengths, dtype=np.int64)
        first = np.repeat(np.asarray(self.stamps, dtype=np.int64), lengths)
        starts = np.repeat(np.cumsum(lengths) - lengths, lengths)
        t = sample_stamps_ns(first, np.arange(first.size, dtype=np.int64) - starts, self.rate)
        v = np.concatenate(self.values)
        if t.size > 1 and not (np.diff(t) >= 0).all():
            order = np.argsort(t, kind='stable')
            t, v = t[order], v[order]
        return t, v


#: While a bag is read, samples in no pull and older than the newest stamp by this much are dropped (a live
#: recording may log a pull's START a little after its first blocks).
HOLD_NS = 5 * NS_PER_S
#: A pull open (START, no END yet) for longer than this keeps no older samples (a START whose END never
#: comes must not keep the rest of the bag in memory).
MAX_OPEN_NS = 60 * NS_PER_S


class _Cutter:
    """Per-column block series of the part of a bag still needed, cut into pulls as they complete."""

    def __init__(self, bag_path, warnings: list) -> None:
        self.bag_path, self.warnings = bag_path, warnings
        self.series: dict = {}
        self.front: dict = {}      # column -> first stamp of its newest block
        self.rates: set = set()
        self.newest = None

    def add_block(self, topic: str, msg, type_name: str) -> None:
        rate = float(msg.sample_rate_hz)
        if not (math.isfinite(rate) and rate > 0):
            raise BagError(f'{topic} block seq {msg.seq} has sample_rate_hz {rate!r}; '
                           'expected a finite rate > 0 Hz')
        stamp = stamp_of(msg)
        for f, col in EXPORT_FIELDS[type_name].items():
            v = np.asarray(getattr(msg, f), dtype=np.float64)
            if not v.size:
                continue
            ser = self.series.get(col)
            if ser is None:
                ser = self.series[col] = _Series(rate)
            elif ser.rate != rate:
                raise BagError(f'{topic} block seq {msg.seq} has sample_rate_hz {rate!r} '
                               f'but earlier blocks {ser.rate!r}; a campaign has one rate')
            if rate not in self.rates:
                self.rates.add(rate)
                if len(self.rates) > 1:
                    raise BagError(f'bag {str(self.bag_path)!r} mixes sample rates {sorted(self.rates)!r} '
                                   'Hz; a campaign has one rate')
            ser.add(stamp, v)
            self.front[col] = max(self.front.get(col, stamp), stamp)
        self.newest = stamp if self.newest is None else max(self.newest, stamp)

    def passed(self, end_ns: int) -> bool:
        """Every column seen so far has a block starting at or after end_ns: no more samples before it."""
        return bool(self.front) and all(f >= end_ns for f in self.front.values())

    def prune(self, keep_from: int | None) -> None:
        cutoff = self.newest - HOLD_NS if self.newest is not None else None
        if keep_from is not None and cutoff is not None:
            cutoff = min(cutoff, keep_from)
        if cutoff is not None:
            for ser in self.series.values():
                ser.drop_before(cutoff)

    def cut(self, start: int, end: int, meta: dict) -> DaqPull | None:
        """The pull in [start, end): NaN where samples are missing (with a warning)."""
        rate = next(iter(self.rates))
        n = int(round((end - start) * rate / NS_PER_S))
        if n < 2:
            self.warnings.append(f'pull {meta["pull_id"]}: {n} sample(s) between START and END; '
                                 'skipped')
            return None
        ch = {'time_s': time_column(n, rate)}
        for col, ser in self.series.items():
            t, v = ser.arrays()
            lo, hi = np.searchsorted(t, [start, end])
            if hi <= lo:
                continue
            idx = np.rint((t[lo:hi] - start) * (rate / NS_PER_S)).astype(np.int64)
            out = np.full(n, np.nan)
            ok = (idx >= 0) & (idx < n)
            out[idx[ok]] = v[lo:hi][ok]
            iok = idx[ok]
            got = int(np.count_nonzero(np.diff(iok))) + 1 if iok.size else 0  # idx is sorted
            if got < n:
                self.warnings.append(f'pull {meta["pull_id"]}: {n - got} of {n} samples of {col} '
                                     'missing (dropped blocks); written as NaN')
            ch[col] = out
        core = [c for c in CORE_CHANNELS if c not in ch]
        if core:
            raise BagError(f'pull {meta["pull_id"]} in bag {str(self.bag_path)!r} has no samples of '
                           f'{core[0]!r}; {NOTHING_TO_CORRECT}')
        missing = [c for c in REQUIRED_CHANNELS if c not in ch and c not in ABSENTABLE_CHANNELS]
        if missing:
            raise BagError(f'pull {meta["pull_id"]} in bag {str(self.bag_path)!r} has no samples of '
                           f'required column {missing[0]!r}; expected its block topic in the bag')
        return DaqPull(meta, ch)


def _split_topics(topics: dict, bag_path, warnings: list) -> tuple:
    """({block topic: type}, [pull event topics]) of a bag's topics; the others are warned about."""
    block_topics, event_topics = {}, []
    for name, t in sorted(topics.items()):
        if t.type_name in EXPORT_FIELDS:
            block_topics[name] = t.type_name
        elif t.type_name == PULL_EVENT_TYPE:
            event_topics.append(name)
        elif t.type_name not in QUIET_TYPES:
            warnings.append(f'topic {name} ({t.type_name}) skipped: not a block or pull '
                            'event type, it has no DAQ column')
    if not event_topics:
        raise BagError(f'bag {str(bag_path)!r} has no {PULL_EVENT_TYPE} topic; expected '
                       '/pull_event START/END messages to cut the pulls')
    return block_topics, event_topics


def _event_meta(msg) -> dict:
    """A PullEvent's pull as a campaign's metadata row (display units, as the campaign format has them)."""
    return {'set': int(msg.test_set), 'coupon_lbf': float(msg.coupon_break_n) / LBF_N,
            'velocity_fps': float(msg.velocity_m_s) / FT_M, 'decel_g': float(msg.decel_m_s2) / G_M_S2,
            'start_ns': stamp_of(msg), 'pull_id': int(msg.pull_id)}


def iter_bag_pulls(bag_path: str | Path, warnings: list, progress: Progress | None = None,
                   state: dict | None = None) -> Iterator[DaqPull]:
    """The pulls of a bag (meta with start_ns and pull_id), in start order, each yielded as soon as every
    block topic has passed its END (else when the bag ends): the bag is read once, in log-time order, and
    only the samples still needed are kept. state['sample_rate_hz'] is set before the first pull."""
    state = {} if state is None else state
    with open_bag(bag_path) as bag:
        topics = bag.topics()
        block_topics, event_topics = _split_topics(topics, bag_path, warnings)
        cutter = _Cutter(bag_path, warnings)
        pulls = PullWindows()
        closed: list = []   # (start_ns, end_ns, meta), sorted by start
        emitted = 0
        total = sum(topics[t].count for t in [*block_topics, *event_topics])
        for k, (topic, type_name, _log, cdr) in enumerate(
                bag.messages([*block_topics, *event_topics])):
            msg = bag.deserialize(cdr, type_name)
            if type_name == PULL_EVENT_TYPE:
                w = pulls.add(int(msg.event), int(msg.pull_id), stamp_of(msg), _event_meta(msg))
                if w is not None and w.start_ns is None:
                    warnings.append(f'END of pull {msg.pull_id} at {stamp_of(msg)} ns '
                                    'without its START: skipped')
                elif w is not None:
                    closed.append((w.start_ns, w.end_ns, w.meta))
                    closed.sort(key=lambda c: c[0])
            else:
                cutter.add_block(topic, msg, type_name)
            if progress and k % 20000 == 0:
                progress(k, total)
            while closed and cutter.passed(closed[0][1]):
                start, end, meta = closed.pop(0)
                state['sample_rate_hz'] = next(iter(cutter.rates))
                pull = cutter.cut(start, end, meta)
                if pull is not None:
                    meta['file'] = f'pull_{emitted + 1:04d}.csv'
                    emitted += 1
                    yield pull
            if k % 2000 == 1999 and cutter.newest is not None:
                keep = [w[0] for w in closed] + [max(start, cutter.newest - MAX_OPEN_NS)
                                                 for start, _meta in pulls.open.values()]
                cutter.prune(min(keep) if keep else None)
        for pid, (start, _meta) in pulls.open.items():
            warnings.append(f'pull {pid} (START at {start} ns) has no END: skipped')
        if not cutter.rates:
            raise BagError(f'bag {str(bag_path)!r} has no block samples; expected /force, /accel, '
                           '/encoder blocks')
        state['sample_rate_hz'] = next(iter(cutter.rates))
        for start, end, meta in closed:
            pull = cutter.cut(start, end, meta)
            if pull is not None:
                meta['file'] = f'pull_{emitted + 1:04d}.csv'
                emitted += 1
                yield pull
    if not emitted:
        raise BagError(f'bag {str(bag_path)!r} has no complete pull (START and END); nothing '
                       'to export')


#: A pull read from a bag on its own (read_bag_pull) takes the blocks logged from this long before its START (a
#: block is logged at or after its first sample; a block is far shorter than this) until every block topic has
#: passed its END, as the one pass does (a late recorder's blocks are waited for as long as there).
WINDOW_LEAD_NS = NS_PER_S


class BagWindows(NamedTuple):
    """A bag's complete pulls, as read_bag_pull needs them: the sample rate, {block topic: type} and, in start
    order, each pull's BagPullJob."""

    rate_hz: float
    block_topics: dict
    jobs: list


class BagPullJob(NamedTuple):
    """One pull of a bag for read_bag_pull: the bag, {block topic: type}, START and END stamps and the meta."""

    bag_path: Path
    block_topics: dict
    start_ns: int
    end_ns: int
    meta: dict


class BagPullNotes(NamedTuple):
    """What read_bag_pull says of a pull beside its channels: its warnings and the columns it has."""

    warnings: list
    columns: list


def bag_pull_windows(bag_path: str | Path, warnings: list) -> BagWindows:
    """A bag's complete pulls (``BagWindows``), from its /pull_event messages and its first block alone (the blocks
    are not read): what read_bag_pull needs to read each pull by itself. The warnings and errors are
    iter_bag_pulls'."""
    with open_bag(bag_path) as bag:
        block_topics, event_topics = _split_topics(bag.topics(), bag_path, warnings)
        rate = None
        for _topic, type_name, _log, cdr in bag.messages(list(block_topics)):
            msg = bag.deserialize(cdr, type_name)
            if any(np.asarray(getattr(msg, f)).size for f in EXPORT_FIELDS[type_name]):
                rate = float(msg.sample_rate_hz)
                break
        if rate is None:
            raise BagError(f'bag {str(bag_path)!r} has no block samples; expected /force, /accel, '
                           '/encoder blocks')
        if not (math.isfinite(rate) and rate > 0):
            raise BagError(f'bag {str(bag_path)!r}: a block has sample_rate_hz {rate!r}; expected a finite '
                           'rate > 0 Hz')
        pulls, closed = PullWindows(), []
        for _topic, type_name, _log, cdr in bag.messages(event_topics):
            msg = bag.deserialize(cdr, type_name)
            w = pulls.add(int(msg.event), int(msg.pull_id), stamp_of(msg), _event_meta(msg))
            if w is not None and w.start_ns is None:
                warnings.append(f'END of pull {msg.pull_id} at {stamp_of(msg)} ns without its START: skipped')
            elif w is not None:
                closed.append((w.start_ns, w.end_ns, w.meta))
        for pid, (start, _meta) in pulls.open.items():
            warnings.append(f'pull {pid} (START at {start} ns) has no END: skipped')
    closed.sort(key=lambda c: c[0])
    windows = []
    for start, end, meta in closed:
        n = int(round((end - start) * rate / NS_PER_S))
        if n < 2:
            warnings.append(f'pull {meta["pull_id"]}: {n} sample(s) between START and END; skipped')
            continue
        meta['file'] = f'pull_{len(windows) + 1:04d}.csv'
        windows.append(BagPullJob(Path(bag_path), block_topics, start, end, meta))
    if not windows:
        raise BagError(f'bag {str(bag_path)!r} has no complete pull (START and END); nothing to export')
    return BagWindows(rate, block_topics, windows)


def read_bag_pull(job: BagPullJob) -> Produced:
    """One pull of a bag, read from the bag itself (run where the pull is written: a worker reads its pull from
    the shared storage; no samples cross between processes). Returns its channels with ``BagPullNotes``; the
    samples are those
    iter_bag_pulls cuts for the pull, read from the blocks logged from WINDOW_LEAD_NS before its START until
    every block topic has passed its END."""
    bag_path, block_topics, start, end, meta = job
    warnings: list = []
    cutter = _Cutter(bag_path, warnings)
    with open_bag(bag_path) as bag:
        for topic, type_name, _log, cdr in bag.messages(list(block_topics), start_ns=max(0, start - WINDOW_LEAD_NS)):
            cutter.add_block(topic, bag.deserialize(cdr, type_name), type_name)
            if cutter.passed(end):
                break
    if not cutter.rates:
        raise BagError(f'pull {meta["pull_id"]} in bag {str(bag_path)!r} has no block samples; expected /force, '
                       '/accel, /encoder blocks')
    pull = cutter.cut(start, end, meta)
    return Produced(pull.channels, BagPullNotes(warnings, sorted(pull.channels)))


class BagPulls(NamedTuple):
    """A bag's pulls in memory: the sample rate and [DaqPull with meta start_ns/pull_id, file pull_NNNN.csv]."""

    rate_hz: float
    pulls: list


def read_bag_pulls(bag_path: str | Path, warnings: list, progress: Progress | None = None) -> BagPulls:
    """A bag's pulls, all in memory (``BagPulls``)."""
    state: dict = {}
    pulls = list(iter_bag_pulls(bag_path, warnings, progress, state))
    return BagPulls(state['sample_rate_hz'], pulls)


def bag_to_campaign(bag_path: str | Path, out_dir: str | Path, progress: Progress | None = None,
                    warnings: list | None = None, mapper: Mapper | None = None) -> Path:
    """Export a bag's pulls to a campaign folder (written atomically). Returns out_dir.

    Without a mapper the bag is read here in one pass and each pull written as soon as it is complete
    (bounded memory). With one (force_tester_common.engine.map_pulls) only the pull events are read here
    (bag_pull_windows); each worker reads its pull's blocks from the bag itself and formats and writes the
    CSV file (read_bag_pull, write_campaign): the pulls' samples never cross between processes (or hosts:
    a cluster's workers need the bag and the output on shared storage, as for any campaign). Same files.
    """
    warnings = [] if warnings is None else warnings
    out_dir = Path(out_dir)
    if out_dir.exists():  # fail before the (long) read
        raise BagError(f'output {str(out_dir)!r} exists already; expected a new directory name')
    if mapper is not None:
        return _export_on_workers(Path(bag_path), out_dir, progress, warnings, mapper)
    state: dict = {}
    columns: list = []

    def pulls():
        for p in iter_bag_pulls(bag_path, warnings, progress, state):
            columns.append(set(p.channels))
            yield p

    it = pulls()
    first = next(it)   # the rate is known once the first pull is
    absent = [c for c in ABSENTABLE_CHANNELS if c not in first.channels]   # the bag has none of them
    if absent:
        warnings.append(f'bag has no samples of {", ".join(absent)}: named absent in campaign.yaml')
    out = write_campaign(out_dir, itertools.chain([first], it), sample_rate_hz=state['sample_rate_hz'],
                         mapper=mapper, absent=absent, warnings=warnings)   # progress: the reader's, by messages
    absent = [c for c in OPTIONAL_CHANNELS if all(c not in cols for cols in columns)]
    if absent:
        warnings.append(f'bag has no samples of {", ".join(absent)}: column(s) not written')
    return out


def _export_on_workers(bag_path: Path, out_dir: Path, progress, warnings: list, mapper) -> Path:
    rate, _topics, windows = bag_pull_windows(bag_path, warnings)
    # the first pull's channels name what the bag lacks (as the one-pass path's first pull)
    first = read_bag_pull(windows[0]._replace(meta=dict(windows[0].meta))).channels
    absent = [c for c in ABSENTABLE_CHANNELS if c not in first]
    del first
    if absent:
        warnings.append(f'bag has no samples of {", ".join(absent)}: named absent in campaign.yaml')
    notes: list = []
    jobs = [(job.meta, job) for job in windows]
    out = write_campaign(out_dir, jobs, sample_rate_hz=rate, mapper=mapper, produce=read_bag_pull, absent=absent,
                         notes=notes, progress=progress, warnings=warnings)
    for note in notes:
        warnings.extend(note.warnings)
    columns = [set(note.columns) for note in notes]
    absent = [c for c in OPTIONAL_CHANNELS if all(c not in cols for cols in columns)]
    if absent:
        warnings.append(f'bag has no samples of {", ".join(absent)}: column(s) not written')
    return out
