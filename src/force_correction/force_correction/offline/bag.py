"""Offline `correct` on a bag: read the /force and /accel blocks and the pull events into a
CorrectionStream, and write the results (/force_corrected, /pull_score, /set_summary).

Two readers give the same numbers:
- the fast path (the usual bag: one uncompressed MCAP file whose blocks pair one to one):
  whole topics decoded with numpy (bag_tools' fastcdr and mcapfile), the aligner's outcome
  checked with its own rules on arrays (``pairing.clean_pairing``), the samples corrected,
  scored and written in segments; the output bag is the input copied byte for byte plus the
  result topics (mcapfile.ExtendedBag);
- the generic path (anything else): rosbags message by message through the BlockAligner
  itself, as correction_node does.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass
from heapq import merge
from pathlib import Path

import numpy as np

from bag_tools.core.errors import BagError
from bag_tools.core.fastcdr import FastPathError, block_lengths, decode_blocks, decode_flat, encode_blocks, encode_flat
from bag_tools.core.mcapfile import ExtendedBag, McapBag, read_topics_raw
from bag_tools.core.typefacts import flat_layout, type_facts
from force_tester_common.core.blocks import PullWindows
from force_tester_common.core.channels import (
    ACCEL_FIELDS,
    ACCEL_TYPE,
    CORRECTED_FIELDS,
    CORRECTED_TYPE,
    FORCE_FIELDS,
    FORCE_TYPE,
    PULL_EVENT_TYPE,
    PULL_SCORE_TOPIC,
    PULL_SCORE_TYPE,
    SET_SUMMARY_TOPIC,
    SET_SUMMARY_TYPE,
)
from force_tester_common.core.clock import ns_to_stamp, record_stamps_ns, sample_stamps_ns, stamp_to_ns
from force_tester_common.core.correction import MAX_PENDING
from force_tester_common.core.scores import PULL_SCORE_FIELDS, SET_SUMMARY_FIELDS, pull_status

from ..core.errors import CorrectionError
from ..core.pairing import BlockAligner, BlockHeaders, clean_pairing, follows
from .scorer import block_sample_stamps
from .stream import CorrectionStream, segments

CORRECTED_NAME, (CORRECTED_TOPIC, _) = CORRECTED_TYPE
RESULT_TOPICS = ((CORRECTED_TOPIC, CORRECTED_NAME), (PULL_SCORE_TOPIC, PULL_SCORE_TYPE),
                 (SET_SUMMARY_TOPIC, SET_SUMMARY_TYPE))  # what correct adds to a bag
OUTPUT_TOPICS = tuple(t for t, _ty in RESULT_TOPICS)


@dataclass(frozen=True)
class BagRead:
    """What reading a bag gives besides the corrected pieces: the paired blocks (stamps, sample
    counts, rates), the pull windows, the stamps of dropped or unmatched blocks, the frame id."""

    blocks: tuple
    windows: list
    drops: list
    frame: str


def pull_event(event: int, pull_id: int, stamp_ns: int, test_set: int, pulls: PullWindows, windows: list,
               warnings: list) -> None:
    """A PullEvent's fields: a START opens a pull; its END closes it into (start, end, set, pull_id)."""
    w = pulls.add(int(event), int(pull_id), stamp_ns, int(test_set))
    if w is None:
        return
    if w.start_ns is None:
        warnings.append(f'END of pull {pull_id} without its START; not scored')
    else:
        windows.append((w.start_ns, w.end_ns, w.meta, w.pull_id))


def _topic_of(topics: dict, type_name: str, default: str) -> str | None:
    found = sorted(n for n, ty in topics.items() if ty == type_name)
    return default if default in found else (found[0] if found else None)


def fast_bag(src: Path) -> McapBag | None:
    """The bag as one MCAP file the fast path can read, or None."""
    try:
        return McapBag(src)
    except FastPathError:
        return None


def read_fast(bag: McapBag, stream: CorrectionStream, warnings: list, progress=None,
              max_pending: int = MAX_PENDING, segment_samples: int | None = None) -> BagRead:
    """Read with whole-topic numpy decoding. Raises FastPathError (before touching the stream)
    whenever the aligner would report anything but discontinuities, so the generic path handles
    it. The samples go through the stream in segments, the pull windows known first."""
    counts = {n: t[1] for n, t in bag.topics().items()}
    topics = {n: t[0] for n, t in bag.topics().items()}
    force_topic = _topic_of(topics, FORCE_TYPE, '/force')
    accel_topic = _topic_of(topics, ACCEL_TYPE, '/accel')
    event_t = [n for n, ty in topics.items() if ty == PULL_EVENT_TYPE]
    if force_topic is None or accel_topic is None or not event_t:
        raise FastPathError('missing topics')
    wanted = [force_topic, accel_topic, *event_t]
    if any(bag.hashes.get(t) != type_facts(topics[t]).rihs01 for t in wanted):
        raise FastPathError('message definitions differ from force_tester_msgs')
    raw, _ = read_topics_raw(bag.mcap, wanted, bag.summary, bag.mm)
    for i, t in enumerate(wanted):
        if int(np.count_nonzero(raw.channel == i)) != counts[t]:
            raise FastPathError('message counts differ from the metadata')
    fsel = np.flatnonzero(raw.channel == 0)
    asel = np.flatnonzero(raw.channel == 1)
    fb = decode_blocks(raw.buf, raw.starts[fsel], raw.lengths[fsel], FORCE_FIELDS)
    ab = decode_blocks(raw.buf, raw.starts[asel], raw.lengths[asel], ACCEL_FIELDS)
    n = fb.counts['moving_n']
    if not np.array_equal(n, fb.counts['stationary_n']) or (len(fb) and (
            (fb.seq >= 2**63).any() or (ab.seq >= 2**63).any())):
        raise FastPathError('ragged force blocks or seqs beyond int64')
    headers = {'force': BlockHeaders(fb.stamp_ns, fb.seq.astype(np.int64), fb.rate_hz, n, fsel),
               'accel': BlockHeaders(ab.stamp_ns, ab.seq.astype(np.int64), ab.rate_hz,
                                     ab.counts['axial_m_s2'], asel)}
    why = clean_pairing(headers, max_pending)
    if why is not None:
        raise FastPathError(why)
    starts = PullWindows()
    windows: list = []
    notes: list = []  # the warnings, given only once the fast path is sure to apply
    layout = flat_layout(PULL_EVENT_TYPE)
    for i in np.flatnonzero(raw.channel >= 2).tolist():  # events (few): one at a time
        f = decode_flat(layout, raw.data(i))
        pull_event(f['event'], f['pull_id'], stamp_to_ns(f['header.stamp.sec'], f['header.stamp.nanosec']),
                   f['test_set'], starts, windows, notes)
    m = len(fb)
    stamps, fr = fb.stamp_ns, fb.rate_hz
    last = sample_stamps_ns(stamps, n - 1, fr)
    if (stamps[1:] <= last[:-1]).any():
        raise FastPathError('blocks overlap in time')
    cont = np.zeros(m, dtype=bool)
    cont[1:] = follows(stamps[:-1], n[:-1], fr[:-1], stamps[1:], fr[1:])
    notes += [f'pull {pid} has no END; not scored' for pid in starts.open]
    warnings += notes
    windows = sorted(windows)
    stream.windows_known(windows, [])
    frame = fb.frame_id(m - 1)
    bounds = [*np.flatnonzero(~cont).tolist(), m]
    ends = np.cumsum(n)
    # blocks where a window starts: a segment boundary there keeps most windows in one
    # segment, which the scorer then takes without copying
    window_blocks = np.searchsorted(last, np.array([w[0] for w in windows], dtype=np.int64))
    size = {} if segment_samples is None else {'size': segment_samples}
    for lo, hi in zip(bounds[:-1], bounds[1:]):  # runs, cut into segments
        cuts = segments(ends, lo, hi, window_blocks, **size)
        for a, b in zip(cuts[:-1], cuts[1:]):
            sel = slice(a, b)
            stream.add(block_sample_stamps(stamps[sel], n[sel], fr[sel]),
                       fb.values('moving_n', sel), ab.values('axial_m_s2', sel),
                       fb.values('stationary_n', sel), float(fr[a]), new_run=a == lo,
                       blocks=(stamps[sel], n[sel], fr[sel]), frame=frame)
            if progress:  # in messages, as the generic path counts
                progress(2 * b, raw.log_ns.size)
    return BagRead((stamps, n, fr), windows, [], frame)


def read_generic(src: Path, stream: CorrectionStream, warnings: list, progress=None,
                 max_pending: int = MAX_PENDING) -> BagRead:
    """Read message by message with rosbags and pair with the BlockAligner, as the node does."""
    from bag_tools.core.reader import open_bag  # rosbags: only on this path (the fast path does without)
    from bag_tools.core.typestore import stamp_of
    with open_bag(src) as bag:
        topics = {n: t.type_name for n, t in bag.topics().items()}
        force_topic = _topic_of(topics, FORCE_TYPE, '/force')
        accel_topic = _topic_of(topics, ACCEL_TYPE, '/accel')
        for what, found, default in (('ForceBlock', force_topic, '/force'),
                                     ('AccelBlock', accel_topic, '/accel')):
            if found is None:
                raise BagError(f'bag {str(src)!r} has no {what} topic; expected {default} '
                               'blocks to correct')
        event_t = [n for n, ty in topics.items() if ty == PULL_EVENT_TYPE]
        aligner = BlockAligner(('force', 'accel'), max_pending=max_pending)
        pairs: list = []
        run: list = []
        drop_events: list = []
        starts = PullWindows()
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
                           blocks=_block_arrays(blocks), frame=frame)
                pairs.extend(blocks)
                run.clear()

        if not event_t:
            warnings.append(f'bag {str(src)!r} has no {PULL_EVENT_TYPE} topic: corrected, but '
                            'no pull can be scored')
        wanted = [force_topic, accel_topic, *event_t]
        total = sum(bag.topics()[t].count for t in wanted)
        for k, (topic, type_name, _log, cdr) in enumerate(bag.messages(wanted)):
            msg = bag.deserialize(cdr, type_name)
            if type_name == PULL_EVENT_TYPE:
                pull_event(msg.event, msg.pull_id, stamp_of(msg), msg.test_set, starts, windows, warnings)
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
        for pid in starts.open:
            warnings.append(f'pull {pid} has no END; not scored')
    if not pairs:
        raise BagError(f'bag {str(src)!r}: no /force block pairs with an /accel block of the '
                       'same stamp; nothing to correct')
    return BagRead(_block_arrays(pairs), sorted(windows), drop_events, frame)


def _block_arrays(blocks: list) -> tuple:
    """[(stamp, n, rate)] as (stamps int64, counts int64, rates float64)."""
    return tuple(np.array(c, dtype=d) for c, d in zip(zip(*blocks), (np.int64, np.int64, float)))


def corrected_blocks(piece: dict, blocks: tuple, frame: str, seq0: int = 0,
                     target: ExtendedBag | None = None, cid: int = 0):
    """/force_corrected blocks for the input blocks (stamps, sample counts, rates) whose
    samples ``piece`` holds, seq from seq0, logged at their last sample (as the live node
    publishes): encode_blocks' (buffer, starts, lengths) and the log times, or, with a target,
    laid out by target.reserve() and returned as the function that encodes them there (for commit())."""
    stamps, ns, rates = blocks
    last = np.where(ns > 0, sample_stamps_ns(stamps, np.maximum(ns - 1, 0), rates), stamps)
    counts = {f: ns for f in CORRECTED_FIELDS}
    out = starts = None
    if target is not None:
        out, starts = target.reserve(np.full(ns.size, cid),
                                     block_lengths(CORRECTED_FIELDS, counts, frame), last)
    values = {'raw_n': piece['raw'], 'inertial_n': piece['inertial'],
              'corrected_n': piece['corrected'], 'filtered_n': piece['filtered']}

    def encode():
        try:
            return encode_blocks(stamps, rates, seq0 + np.arange(stamps.size), CORRECTED_FIELDS,
                                 counts, values, frame, out=out, starts=starts)
        except FastPathError as exc:
            raise BagError(f'cannot write the corrected blocks: {exc}') from None
    return encode if target is not None else (*encode(), last)


def result_messages(pulls, running) -> list:
    """(log time, order, topic, type, CDR) of the /pull_score and /set_summary messages;
    ``running``: the per-set summary after each pull."""
    score_layout, summary_layout = flat_layout(PULL_SCORE_TYPE), flat_layout(SET_SUMMARY_TYPE)
    out = []
    for p, summ in zip(pulls, running):
        sec, nanosec = ns_to_stamp(p.start_ns)
        head = {'header.stamp.sec': sec, 'header.stamp.nanosec': nanosec, 'header.frame_id': ''}
        status, detail = pull_status(p.score.dropped_blocks)
        score = {**head, 'pull_id': p.pull_id, 'test_set': p.test_set, 'dropped_blocks': p.score.dropped_blocks,
                 'status': status, 'detail': detail, **{f: float(getattr(p.score, f)) for f in PULL_SCORE_FIELDS}}
        out.append((p.end_ns, 1, PULL_SCORE_TOPIC, PULL_SCORE_TYPE, encode_flat(score_layout, score)))
        values = asdict(summ)
        summary = {**head, 'test_set': p.test_set, **{f: values[k] for f, k in SET_SUMMARY_FIELDS.items()}}
        out.append((p.end_ns, 2, SET_SUMMARY_TOPIC, SET_SUMMARY_TYPE, encode_flat(summary_layout, summary)))
    out.sort(key=lambda g: (g[0], g[1]))
    return out


def extension_target(fast: McapBag | None, dst: Path) -> ExtendedBag | None:
    """Where the fast path writes: the input copied byte for byte plus the results, when the
    input is one suitable MCAP file without result topics of its own."""
    if fast is None or set(OUTPUT_TOPICS) & set(fast.topics()):
        return None
    return ExtendedBag(fast, dst)


def extended_sink(target: ExtendedBag):
    """Result topics added to ``target``, and a stream sink writing /force_corrected into it."""
    cids = {t: target.add_topic(t, ty, *type_facts(ty)[:2]) for t, ty in RESULT_TOPICS}

    def sink(piece, blocks, frame, seq0):   # laid out here, encoded and written by the bag's writer thread
        target.commit(corrected_blocks(piece, blocks, frame, seq0, target, cids[CORRECTED_TOPIC]))
    return cids, sink


def write_results(target: ExtendedBag, cids: dict, pulls, running) -> None:
    small = result_messages(pulls, running)
    target.write_messages([cids[g[2]] for g in small], [g[0] for g in small], [g[4] for g in small])


def rewrite_bag(src: Path, dst: Path, arrays: dict, read: BagRead, pulls, running,
                warnings: list) -> None:
    """The generic writer: every input message through rosbags, merged with the results."""
    from bag_tools.core.reader import open_bag  # rosbags: only on this path (the fast path does without)
    from bag_tools.core.typestore import default_typestore
    from bag_tools.core.writer import BagWriter
    store = default_typestore()
    buf, starts, lengths, last = corrected_blocks(arrays, read.blocks, read.frame)
    generated = [(int(lg), 0, CORRECTED_TOPIC, CORRECTED_NAME, buf[a:a + k])
                 for lg, a, k in zip(last.tolist(), starts.tolist(), lengths.tolist())]
    generated += result_messages(pulls, running)
    generated.sort(key=lambda g: (g[0], g[1]))
    with open_bag(src) as bag, BagWriter(dst, store, rewritable=True) as writer:
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
                    store.register(bag.type_closure(type_name))  # with the types it uses
                except Exception:  # noqa: BLE001 - any unparsable definition: skip the topic
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
