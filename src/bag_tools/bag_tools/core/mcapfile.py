"""MCAP at the record level: the summary of a file, batch reading of messages, batch writing,
and ExtendedBag, a new bag that is an input bag plus new topics.

The summary is read, and summary, metadata and footer records are written, with Foxglove's
`mcap` library. Only the batch paths are hand-written, as numpy over the mapped file: message
records, chunk headers and message indexes (`./ft bench bag` justifies them; the layouts follow
https://mcap.dev/spec). Everything here works on uncompressed, indexed files (what rosbags and
`ros2 bag record` write by default); anything else raises FastPathError and callers use the
generic rosbags path.

ExtendedBag copies the input file's data section byte for byte (os.copy_file_range, in a
thread, while the caller computes), then appends the new topics' chunks, a new summary and
footer, and a metadata.yaml made from the input's. The input chunks keep their offsets, so
their chunk indexes are copied too. The new chunks overlap the input's in time, which MCAP
allows: log-time-order readers (rosbag2's MCAP plugin for `ros2 bag play`, rosbags) merge
the chunks.
"""

from __future__ import annotations

import mmap
import os
import queue
import shutil
import struct
import threading
from collections import defaultdict
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from mcap.data_stream import RecordBuilder
from mcap.reader import SeekingReader
from mcap.records import (
    Channel,
    ChunkIndex,
    DataEnd,
    Footer,
    Metadata,
    MetadataIndex,
    Schema,
    Statistics,
    SummaryOffset,
)
from mcap.summary import Summary

from force_tester_common.core.partial import Marked, clear_stale, tell

from .errors import BagError, one_line
from .fastcdr import FastPathError, gather_struct, stride_runs
from .metadata import METADATA_VERSION, dump_info, load_metadata, write_metadata
from .sources import check_new_bag_path

MAGIC = b'\x89MCAP0\r\n'
CHUNK_HEADER = 9 + 8 + 8 + 8 + 4 + 4 + 8  # chunk record up to its records, without compression name
CHUNK_BYTES = 2**20  # new chunks hold about this many bytes of records (as rosbags)
RECORD_HEADER = 31   # message record: opcode u8, length u64, channel u16, seq u32, log, publish
_U8 = np.uint8


# --------------------------------------------------------------------------- summary
def records_start(c: ChunkIndex) -> int:
    """Offset of the first record inside the chunk c (after the chunk record's header)."""
    return c.chunk_start_offset + CHUNK_HEADER + len(c.compression.encode())


def serialize(*records) -> bytes:
    """MCAP records (mcap.records objects) as bytes, as the mcap library writes them."""
    out = RecordBuilder()
    for r in records:
        r.write(out)
    return out.end()


@dataclass
class McapSummary:
    """The summary section of an MCAP file, as the mcap library reads it."""

    path: Path
    summary: Summary

    @property
    def schemas(self) -> dict:
        return self.summary.schemas

    @property
    def channels(self) -> dict:
        return self.summary.channels

    @property
    def chunks(self) -> list:
        return self.summary.chunk_indexes

    @property
    def statistics(self) -> Statistics | None:
        return self.summary.statistics

    @property
    def channel_counts(self) -> dict:
        return dict(self.statistics.channel_message_counts) if self.statistics else {}

    def topic_ids(self) -> dict:
        return {c.topic: cid for cid, c in self.channels.items()}

    @property
    def chunks_end(self) -> int:
        """End of the last chunk's message indexes: the input bytes ExtendedBag copies."""
        return max((c.chunk_start_offset + c.chunk_length + c.message_index_length
                    for c in self.chunks), default=0)


def read_summary(path: str | Path) -> McapSummary:
    """The summary section of an MCAP file (FastPathError if it has none or is odd)."""
    path = Path(path)
    try:
        with path.open('rb') as fh:
            summary = SeekingReader(fh).get_summary()
    except OSError as exc:
        raise FastPathError(f'cannot read {str(path)!r}: {exc}') from None
    except Exception as exc:  # noqa: BLE001 - the mcap library's errors on odd files vary
        raise FastPathError(f'cannot parse MCAP summary: {one_line(exc)}') from None
    if summary is None:
        raise FastPathError('MCAP without summary')
    return McapSummary(path, summary)


# --------------------------------------------------------------------------- batch reading
class RawMessages:
    """Raw messages of one or more topics: arrays in log order (ties as rosbags orders)."""

    def __init__(self, buf: np.ndarray, log_ns: np.ndarray, channel: np.ndarray,
                 starts: np.ndarray, lengths: np.ndarray, holder=None) -> None:
        self.buf = buf
        self.log_ns = log_ns
        self.channel = channel  # topic index per message
        self.starts = starts
        self.lengths = lengths
        self._holder = holder  # keeps the file mapping under buf alive

    def data(self, i: int) -> bytes:
        s = int(self.starts[i])
        return self.buf[s:s + int(self.lengths[i])].tobytes()


def map_file(path: str | Path, populate: bool = True) -> mmap.mmap:
    """The file mapped read-only, its pages mapped in at once where the OS allows (faster
    than one page fault per touched page when most of the file is read), or with ``populate``
    False as they are touched (fault_in)."""
    path = Path(path)
    with path.open('rb') as fh:
        if path.stat().st_size == 0:
            raise FastPathError('empty file')
        return mmap.mmap(fh.fileno(), 0, flags=mmap.MAP_SHARED | (getattr(mmap, 'MAP_POPULATE', 0) if populate else 0),
                         prot=mmap.PROT_READ)


FAULT_STRIDE = 1 << 16   # Linux maps up to 64 KiB of a file's cached pages around each fault (fault_around_bytes)


def fault_in(mm: mmap.mmap) -> None:
    """Map a mapping's pages in by reading one byte every FAULT_STRIDE, in numpy's loop, which runs without the GIL
    (CPython 3.11's mmap() holds it, MAP_POPULATE with it): 230 MB of cached file in ~14 ms beside the caller's
    Python (benchmarks/bench_startup.py --stages measures the command)."""
    np.frombuffer(mm, dtype=np.uint8)[::FAULT_STRIDE].max(initial=0)


_RECORD = np.dtype([('op', 'u1'), ('len', '<u8'), ('channel', '<u2'), ('seq', '<u4'),
                    ('log', '<u8'), ('publish', '<u8')])  # message record header, 31 bytes
_RECORD_HEAD = np.dtype({'names': ['op', 'len', 'log'], 'formats': ['u1', '<u8', '<u8'],
                         'offsets': [0, 1, 15], 'itemsize': 23})  # up to the log time
_INDEX_ENTRY = np.dtype([('log', '<u8'), ('offset', '<u8')])  # message index entry


def read_topics_raw(mcap_path: str | Path, topics: Sequence[str],
                    summary: McapSummary | None = None, mm: mmap.mmap | None = None) -> tuple:
    """(RawMessages of the topics in log order, [topic per channel index]) of one .mcap file.

    Only uncompressed MCAP with a summary and message indexes (what rosbags writes); anything
    else raises FastPathError.
    """
    mm = map_file(mcap_path) if mm is None else mm
    summary = read_summary(mcap_path) if summary is None else summary
    if any(c.compression for c in summary.chunks):
        raise FastPathError('compressed chunks')
    buf = np.frombuffer(mm, dtype=_U8)
    size = buf.size
    want = {t: i for i, t in enumerate(topics)}
    index = []  # per message index record: entries start, count, chunk records start/size, topic
    for c in summary.chunks:
        if c.chunk_start_offset + c.chunk_length > size or mm[c.chunk_start_offset] != 0x06:
            raise FastPathError('chunk index does not point to a chunk')
        for cid, moff in c.message_index_offsets.items():
            ch = summary.channels.get(cid)
            if ch is None or ch.topic not in want:
                continue
            t = ch.topic
            if mm[moff] != 0x07:
                raise FastPathError('bad message index')
            _cid, blen = struct.unpack_from('<HI', mm, moff + 9)
            if blen % 16 or moff + 15 + blen > size:
                raise FastPathError('bad message index')
            index.append((moff + 15, blen // 16, records_start(c), c.compressed_size, want[t]))
    counts = np.array([i[1] for i in index], dtype=np.int64)
    if not counts.sum():
        z = np.zeros(0, np.int64)
        return RawMessages(buf, z, z, z, z, mm), list(topics)
    a = np.array(index, dtype=np.int64)
    first = np.cumsum(counts) - counts
    pos = np.repeat(a[:, 0] - 16 * first, counts) + 16 * np.arange(int(counts.sum()))
    ent = gather_struct(buf, pos, _INDEX_ENTRY)  # all entries, in runs of one index each
    log = ent['log'].astype(np.int64)
    rel = ent['offset'].astype(np.int64)
    if (rel < 0).any() or (rel + RECORD_HEADER > np.repeat(a[:, 3], counts)).any():
        raise FastPathError('message offset outside its chunk')
    off = np.repeat(a[:, 2], counts) + rel
    chan = np.repeat(a[:, 4], counts)
    rec = gather_struct(buf, off, _RECORD_HEAD)
    rec_len = rec['len'].astype(np.int64)
    if (rec['op'] != 0x05).any() or (rec['log'].astype(np.int64) != log).any() \
            or (rec_len < 22).any() or (off + 9 + rec_len > size).any():
        raise FastPathError('message index disagrees with the messages')
    # rosbags order: log time, then chunk start offset, then position in the chunk (= offset)
    order = np.lexsort((off, log))
    return RawMessages(buf, log[order], chan[order], (off + RECORD_HEADER)[order],
                       (rec_len - 22)[order], mm), list(topics)


# --------------------------------------------------------------------------- writing
def fill_record_headers(buf: np.ndarray, rec_starts: np.ndarray, data_len: np.ndarray,
                        cids: np.ndarray, log_ns: np.ndarray) -> None:
    """Write the 31-byte message record headers at buf[rec_starts[i]] (sequence 0,
    publish time = log time, as rosbags writes)."""
    head = np.zeros(rec_starts.size, dtype=_RECORD)
    head['op'], head['len'], head['channel'] = 5, 22 + data_len, cids
    head['log'] = head['publish'] = log_ns
    raw = head.view(np.dtype((np.void, RECORD_HEADER)))  # copied whole, not field by field
    for lo, hi, stride in stride_runs(rec_starts):
        np.ndarray((hi - lo,), dtype=raw.dtype, buffer=buf, offset=int(rec_starts[lo]),
                   strides=(stride,))[...] = raw[lo:hi]


class McapBag:
    """A rosbag2 bag of one uncompressed, indexed MCAP file, opened without rosbags: its
    metadata.yaml, MCAP summary and a read-only mapping of the file.

    FastPathError unless it suits the batch paths: metadata version 9, no compression,
    schemas, channels and statistics in the summary agreeing with metadata.yaml, no
    attachments and no metadata records but rosbag2's.
    """

    def __init__(self, src: str | Path) -> None:
        self.path = Path(src)
        try:
            info = load_metadata(self.path)
            files = list(info['relative_file_paths'])
            ok = (int(info['version']) == METADATA_VERSION and len(files) == 1
                  and info.get('storage_identifier') == 'mcap'
                  and not info.get('compression_format') and not info.get('compression_mode'))
            self.hashes = {t['topic_metadata']['name']:
                           t['topic_metadata'].get('type_description_hash', '')
                           for t in info.get('topics_with_message_count') or []}
            known = {t['topic_metadata']['name']: int(t['message_count'])
                     for t in info.get('topics_with_message_count') or []}
        except Exception as exc:  # noqa: BLE001 - anything odd: the generic path reports it
            raise FastPathError(f'metadata.yaml: {one_line(exc)}') from None
        if not ok:
            raise FastPathError('not a one-file uncompressed MCAP bag of metadata version 9')
        self.info = info
        self.mcap = self.path / str(files[0])
        self.summary = s = read_summary(self.mcap)
        self._mm: mmap.mmap | None = None
        self._mapping: threading.Thread | None = None   # map_ahead's
        self._map_error: BaseException | None = None
        if (s.statistics is None or not s.channels or not s.chunks
                or s.statistics.attachment_count or s.summary.attachment_indexes
                or any(c.compression for c in s.chunks)
                or any(m.name != 'rosbag2' for m in s.summary.metadata_indexes)
                or any(c.schema_id not in s.schemas for c in s.channels.values())):
            raise FastPathError('MCAP summary not suited to the batch paths')
        ids = s.topic_ids()
        if len(ids) != len(s.channels) or ids.keys() != known.keys() or any(
                known[t] != s.channel_counts.get(cid, 0) for t, cid in ids.items()):
            raise FastPathError('metadata.yaml and the MCAP statistics differ')

    def map_ahead(self) -> None:
        """Map the file now and its pages in from a background thread (fault_in), while the caller sets up the
        rest; ``mm`` waits for it."""
        if self._mm is None and self._map_error is None:
            self._map(populate=False)
            if self._mm is not None:
                self._mapping = threading.Thread(target=fault_in, args=(self._mm,), name='bag-map', daemon=True)
                self._mapping.start()

    def _map(self, populate: bool = True) -> None:
        try:
            self._mm = map_file(self.mcap, populate)
        except (OSError, ValueError) as exc:
            self._map_error = exc

    @property
    def mm(self) -> mmap.mmap:
        """The file mapped read-only (on first use, or by map_ahead)."""
        if self._mapping is not None:
            self._mapping.join()
            self._mapping = None
        elif self._mm is None and self._map_error is None:
            self._map()
        if self._map_error is not None:
            raise FastPathError(f'cannot map {self.mcap}: {self._map_error}')
        return self._mm

    def topics(self) -> dict:
        """topic -> (type name, message count)."""
        s = self.summary
        counts = s.channel_counts
        return {c.topic: (s.schemas[c.schema_id].name, counts.get(cid, 0))
                for cid, c in s.channels.items()}


QUEUED_BYTES = 1 << 26  # ExtendedBag: committed bytes waiting for the writer thread, at most


class ExtendedBag:
    """A new bag dst = the McapBag src plus new topics (see the module doc).

    Use as a context manager: entering creates dst and starts copying the input; leaving
    finishes the file and writes metadata.yaml (last, so an unfinished bag has none), or
    removes dst if the block raised.
    """

    def __init__(self, src: McapBag, dst: str | Path) -> None:
        self.dst = Path(dst)
        tell(clear_stale(self.dst))   # a bag folder a killed writer left (marked, as BagWriter marks its own)
        check_new_bag_path(self.dst)
        self._mark: Marked | None = None
        self.info = src.info
        self.mcap = src.mcap
        self.summary = s = src.summary
        self.copy_end = s.chunks_end
        self._schema_ids = {v.name: k for k, v in s.schemas.items()}
        self._new_schemas: list = []   # Schema records
        self._new_channels: list = []  # (Channel record, type name, rihs01)
        self._chunk_index: list = []   # ChunkIndex records of the new chunks
        self._counts: dict = defaultdict(int)
        self._times = [s.statistics.message_start_time, s.statistics.message_end_time]
        self._definitions_written = False
        self._pending: list = []  # (file offset, buffer) laid out by reserve(), not yet written
        self._written: list = []  # (written event, buffer) of committed buffers, to reuse
        self._queue: queue.SimpleQueue | None = None  # buffers for the writer thread
        self._fd = -1
        self._pos = 0
        self._threads: list = []  # background copy and writes
        self._errors: list = []

    # -- lifecycle -------------------------------------------------------------------
    def __enter__(self) -> ExtendedBag:
        check_new_bag_path(self.dst)
        self.dst.mkdir()
        try:
            self._mark = Marked(self.dst).__enter__()   # until metadata.yaml is written
            self.out = self.dst / f'{self.dst.name}.mcap'
            self._fd = os.open(self.out, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
            os.ftruncate(self._fd, self.copy_end)
        except BaseException:
            self._abort()
            raise
        self._pos = self.copy_end
        self._background(self._copy)
        return self

    def _background(self, fn, *args) -> threading.Thread:
        def run():
            try:
                fn(*args)
            except BaseException as exc:  # noqa: BLE001 - re-raised by the main thread
                self._errors.append(exc)
        t = threading.Thread(target=run, name='bag-io', daemon=True)
        t.start()
        self._threads.append(t)
        return t

    def _copy(self) -> None:
        with self.mcap.open('rb') as fi:
            done = 0
            while done < self.copy_end:
                try:
                    n = os.copy_file_range(fi.fileno(), self._fd, self.copy_end - done,
                                           done, done)
                except OSError:  # e.g. not supported here: plain copy
                    piece = os.pread(fi.fileno(), min(2**24, self.copy_end - done), done)
                    n = os.pwrite(self._fd, piece, done) if piece else 0
                if n <= 0:
                    raise OSError(f'copy stopped at byte {done} of {self.copy_end}')
                done += n

    def _write_at(self, pos: int, data) -> int:
        view = memoryview(data).cast('B')
        while view.nbytes:
            n = os.pwrite(self._fd, view, pos)
            pos += n
            view = view[n:]
        return pos

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is not None:
            self._abort()
            return
        try:
            self._finish()
        except BaseException:
            self._abort()  # an I/O failure (OSError) is not bad input: it propagates as it is
            raise

    def _join(self) -> None:
        if self._queue is not None:
            self._queue.put(None)  # the writer thread ends after the queued buffers
        for t in self._threads:
            t.join()
        self._threads = []
        if self._errors:
            raise self._errors[0]

    def _abort(self) -> None:
        try:
            if self._queue is not None:
                self._errors.append(BagError('aborted'))  # the writer skips what is left
                self._queue.put(None)
            for t in self._threads:
                t.join()
        finally:
            if self._fd >= 0:
                os.close(self._fd)
                self._fd = -1
            shutil.rmtree(self.dst, ignore_errors=True)
            self._release()

    # -- topics and messages -----------------------------------------------------------
    def add_topic(self, topic: str, type_name: str, msgdef: str, rihs01: str) -> int:
        """A new channel (and schema unless the input has the type); returns its channel id."""
        if self._definitions_written:
            raise BagError(f'topic {topic!r} added after the first message; add topics first')
        if topic in self.summary.topic_ids() or any(c.topic == topic for c, *_ in self._new_channels):
            raise BagError(f'topic {topic!r} is in the bag already')
        sid = self._schema_ids.get(type_name)
        if sid is None:
            sid = max([0, *self._schema_ids.values()]) + 1
            self._schema_ids[type_name] = sid
            self._new_schemas.append(Schema(id=sid, name=type_name, encoding='ros2msg',
                                            data=msgdef.encode('utf-8')))
        cid = max([0, *self.summary.channels, *(c.id for c, *_ in self._new_channels)]) + 1
        if cid >= 2**16:
            raise FastPathError('too many channels')
        channel = Channel(id=cid, topic=topic, message_encoding='cdr', schema_id=sid,
                          metadata={'offered_qos_profiles': '[]', 'topic_type_hash': rihs01})
        self._new_channels.append((channel, type_name, rihs01))
        return cid

    def _write(self, *parts) -> None:
        for part in parts:
            self._pos = self._write_at(self._pos, part)

    def commit(self, fill: Callable[[], object] | None = None) -> None:
        """Queue the buffers of earlier reserve() calls for the writer thread; the rest are written when the bag
        is closed. Their data must be complete, or ``fill()`` completes them: the writer thread calls it first
        (numpy's copies run there without the GIL, beside the caller's next piece). An error in it is raised
        when the bag is closed, and the bag is removed."""
        if self._queue is None:
            self._queue = queue.SimpleQueue()
            self._background(self._writer)
        pending, self._pending = self._pending, []
        for k, (pos, buf) in enumerate(pending):
            done = threading.Event()
            self._queue.put((pos, buf, done, fill if k == 0 else None))
            self._written.append((done, buf))

    def _writer(self) -> None:
        while (item := self._queue.get()) is not None:
            pos, buf, done, fill = item
            try:
                if not self._errors:
                    if fill is not None:
                        fill()
                    self._write_at(pos, buf)
            except BaseException as exc:  # noqa: BLE001 - re-raised by the main thread
                self._errors.append(exc)
            finally:
                done.set()

    def _write_definitions(self) -> None:
        if not self._definitions_written:  # schemas and channels precede their messages
            self._write(serialize(*self._new_schemas, *(c for c, *_ in self._new_channels)))
            self._definitions_written = True

    def reserve(self, cids, data_len, log_ns) -> tuple:
        """Lay out new messages (channel ids, CDR byte lengths, log times; any order) as chunks
        at the end of the file: returns (buf, starts), the uint8 buffer of that stretch of the
        file and, per message in the caller's order, where its CDR data go in buf. Chunk, record
        and message-index headers are filled in here; the caller must write every data byte
        before the bag is closed (when buf is written to the file). In the file the messages
        are in log order (stable)."""
        cids = np.asarray(cids, dtype=np.int64)
        data_len = np.asarray(data_len, dtype=np.int64)
        log_ns = np.asarray(log_ns, dtype=np.int64)
        m = int(cids.size)
        if m == 0:
            return np.zeros(0, _U8), np.zeros(0, np.int64)
        if log_ns.min() < 0 or (data_len < 4).any():
            raise BagError('messages need log times >= 0 and CDR data of >= 4 bytes')
        self._write_definitions()
        order = np.argsort(log_ns, kind='stable')
        if (order == np.arange(m)).all():
            order = None
        c, n, lg = (cids, data_len, log_ns) if order is None else \
            (cids[order], data_len[order], log_ns[order])
        rec_end = np.cumsum(RECORD_HEADER + n)     # record ends relative to the first record
        rec_rel = rec_end - RECORD_HEADER - n
        bounds = [0]
        while bounds[-1] < m:                      # chunks of about CHUNK_BYTES of records
            i = bounds[-1]
            base = int(rec_rel[i])
            bounds.append(max(int(np.searchsorted(rec_end, base + CHUNK_BYTES, 'right')), i + 1))
        # layout: per chunk the chunk record (header CHUNK_HEADER bytes + records), then its indexes
        plan, pos = [], self._pos
        abs_rec = np.empty(m, dtype=np.int64)
        single = int(c[0]) if (c == c[0]).all() else None  # one channel: the usual case
        for i, j in zip(bounds[:-1], bounds[1:]):
            size = int(rec_end[j - 1] - rec_rel[i])
            abs_rec[i:j] = pos + CHUNK_HEADER + rec_rel[i:j] - rec_rel[i]
            ch = c[i:j]
            chans = [single] if single is not None else sorted(set(ch.tolist()))   # not np.unique: it imports numpy.ma
            counts = [j - i] if single is not None else \
                [int(np.count_nonzero(ch == k)) for k in chans]
            mi_len = sum(15 + 16 * k for k in counts)
            plan.append((i, j, pos, size, chans, mi_len))
            pos += CHUNK_HEADER + size + mi_len
        total = pos - self._pos
        buf = None
        # reuse the oldest committed buffer once written; wait for it only when many bytes
        # are queued (the writes share the disk with the input copy and may lag behind)
        if self._written and (self._written[0][0].is_set() or sum(
                b.size for _d, b in self._written) > QUEUED_BYTES):
            done, old = self._written.pop(0)
            done.wait()
            if self._errors:
                raise self._errors[0]
            buf = old[:total] if old.size >= total else None
        if buf is None:
            buf = np.empty(total, dtype=_U8)  # every byte is written: by us or the caller
        shift = self._pos
        self._pending.append((self._pos, buf))
        fill_record_headers(buf, abs_rec - shift, n, c, lg)
        for i, j, start, size, chans, mi_len in plan:
            t0, t1 = int(lg[i:j].min()), int(lg[i:j].max())
            # chunk record header (uncompressed, no CRC): op, length, start and end time,
            # uncompressed size, CRC, compression '' and records size
            head = struct.pack('<BQQQQIIQ', 0x06, CHUNK_HEADER - 9 + size, t0, t1, size, 0, 0, size)
            buf[start - shift:start - shift + CHUNK_HEADER] = np.frombuffer(head, _U8)
            p = start + CHUNK_HEADER + size
            index = []
            rel = abs_rec[i:j] - (start + CHUNK_HEADER)
            for k in chans:
                sel = slice(None) if single is not None else c[i:j] == k
                ent = np.empty((rel[sel].size, 2), dtype='<u8')
                ent[:, 0], ent[:, 1] = lg[i:j][sel], rel[sel]
                rec = struct.pack('<BQHI', 0x07, 6 + ent.nbytes, k, ent.nbytes) + ent.tobytes()
                buf[p - shift:p - shift + len(rec)] = np.frombuffer(rec, _U8)
                index.append((k, p))
                p += len(rec)
            self._chunk_index.append(ChunkIndex(
                message_start_time=t0, message_end_time=t1, chunk_start_offset=start,
                chunk_length=CHUNK_HEADER + size, message_index_offsets=dict(index),
                message_index_length=mi_len, compression='', compressed_size=size,
                uncompressed_size=size))
        self._pos += total
        for k in ([single] if single is not None else sorted(set(c.tolist()))):
            self._counts[k] += int(np.count_nonzero(c == k))
        self._times = [min(self._times[0], int(lg.min())), max(self._times[1], int(lg.max()))]
        data = abs_rec - shift + RECORD_HEADER
        if order is not None:
            out = np.empty(m, dtype=np.int64)
            out[order] = data
            data = out
        return buf, data

    def write_messages(self, cids, log_ns, datas: Sequence[bytes]) -> None:
        """Append messages given as CDR bytes (any order; few: copied one by one)."""
        lens = np.array([len(d) for d in datas], dtype=np.int64)
        buf, starts = self.reserve(cids, lens, log_ns)
        for d, s in zip(datas, starts.tolist()):
            buf[s:s + len(d)] = np.frombuffer(d, _U8)

    # -- closing -----------------------------------------------------------------------
    def _metadata(self) -> dict:
        s = self.summary
        info = dict(self.info)
        counts = dict(s.channel_counts)
        counts.update(self._counts)
        total = sum(counts.values())
        start, end = self._times
        name = self.out.name
        topics = list(info.get('topics_with_message_count') or [])
        for channel, type_name, rihs01 in self._new_channels:
            topics.append({'topic_metadata': {'name': channel.topic, 'type': type_name,
                                              'serialization_format': 'cdr',
                                              'offered_qos_profiles': [],
                                              'type_description_hash': rihs01},
                           'message_count': self._counts.get(channel.id, 0)})
        custom = dict(info.get('custom_data') or {})
        custom['writer'] = 'bag_tools.core'
        info.update({'relative_file_paths': [name], 'message_count': total,
                     'duration': {'nanoseconds': max(0, end - start)},
                     'starting_time': {'nanoseconds_since_epoch': start},
                     'topics_with_message_count': topics, 'custom_data': custom,
                     'files': [{'path': name, 'starting_time': {'nanoseconds_since_epoch': start},
                                'duration': {'nanoseconds': max(0, end - start)},
                                'message_count': total}]})
        return info

    def _finish(self) -> None:
        self._write_definitions()
        self.commit()
        s = self.summary
        info = self._metadata()
        meta_start = self._pos
        self._write(serialize(Metadata(name='rosbag2',
                                       metadata={'serialized_metadata': dump_info(info).strip()})))
        meta = MetadataIndex(offset=meta_start, length=self._pos - meta_start, name='rosbag2')
        self._write(serialize(DataEnd(data_section_crc=0)))
        summary_start = self._pos
        offsets = []

        def group(records):
            start, data = self._pos, serialize(*records)
            self._write(data)
            offsets.append(SummaryOffset(group_opcode=data[0], group_start=start,
                                         group_length=len(data)))

        counts = {**s.channel_counts, **self._counts}
        start, end = self._times
        channels = [*s.channels.values(), *(c for c, *_ in self._new_channels)]
        schemas = [*s.schemas.values(), *self._new_schemas]
        chunks = [*s.chunks, *self._chunk_index]
        for records in (schemas, channels, chunks, [meta], [Statistics(
                message_count=sum(counts.values()), schema_count=len(schemas),
                channel_count=len(channels), attachment_count=0, metadata_count=1,
                chunk_count=len(chunks), message_start_time=start, message_end_time=end,
                channel_message_counts=dict(sorted(counts.items())))]):
            group(records)
        offsets_start = self._pos
        self._write(serialize(*offsets, Footer(summary_start=summary_start,
                                               summary_offset_start=offsets_start, summary_crc=0)),
                    MAGIC)
        self._join()  # the copied input bytes must be complete before the bag is
        os.close(self._fd)
        self._fd = -1
        self._mark.unmark()
        write_metadata(self.dst, info)
        self._release()

    def _release(self) -> None:
        if self._mark is not None:
            self._mark.__exit__()
            self._mark = None
