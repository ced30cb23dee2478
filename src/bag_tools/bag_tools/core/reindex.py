"""`./ft bag reindex`: make an unfinished rosbag2 MCAP bag whole again.

A recorder that is killed (SIGKILL, power cut) or runs out of disk leaves a bag directory with
no metadata.yaml and an .mcap file that stops somewhere in its data section: no summary, no
footer, maybe a torn last record. Like `ros2 bag reindex`, reindex() writes metadata.yaml from
what the storage files hold; it also finishes each unfinished .mcap in place, so that every
MCAP reader (rosbags, Foxglove's `mcap`, rosbag2's plugin) reads it with its index:

- the data section is scanned record by record; every whole chunk is kept where it is and its
  contents are checked (records that fit, CRC when the writer set one);
- a chunk whose message index records are missing or torn (the last one) gets new ones;
- the complete message records at the start of a torn, uncompressed last chunk are written
  again as a chunk of their own (what reached the disk of a chunk cut by a full disk);
- a rosbag2 metadata record, DataEnd, the summary (schemas, channels, chunk indexes, metadata
  index, statistics), summary offsets and the footer are appended, the torn tail cut off.

Nothing is written before the scan has finished, and metadata.yaml (written atomically) comes
last: a bag interrupted while being reindexed still has no metadata.yaml and can be reindexed
again. Files that already have a valid summary are only read. The split recorder's file in
progress (in the hidden `.<bag>.*.splits` directory beside the bag) is moved into the bag first.
"""

from __future__ import annotations

import mmap
import os
import re
import shutil
import struct
import zlib
from dataclasses import dataclass, field
from io import BytesIO
from pathlib import Path
from typing import Any

import yaml
from mcap.data_stream import ReadDataStream
from mcap.reader import SeekingReader
from mcap.records import (
    Channel,
    Chunk,
    ChunkIndex,
    DataEnd,
    Footer,
    Header,
    MessageIndex,
    Metadata,
    MetadataIndex,
    Schema,
    Statistics,
    SummaryOffset,
)
from mcap.stream_reader import get_chunk_data_stream

from .errors import BagError, one_line
from .mcapfile import MAGIC, serialize
from .metadata import METADATA_FILE, dump_info, write_metadata
from .split_writer import combined_metadata

_OP_HEADER, _OP_SCHEMA, _OP_CHANNEL, _OP_MESSAGE, _OP_CHUNK, _OP_MESSAGE_INDEX = 1, 3, 4, 5, 6, 7
_OP_ATTACHMENT, _OP_METADATA, _OP_DATA_END = 9, 0x0C, 0x0F
_HEAD = struct.Struct('<BQ')               # record opcode, length
_CHUNK_FIXED = struct.Struct('<QQQI')      # chunk: start, end, uncompressed size, crc
_MESSAGE_FIXED = struct.Struct('<HIQ')     # message: channel, sequence, log time
_ROSBAG2_METADATA = 'rosbag2'              # name of the metadata record rosbag2 writers add
#: the space a recording keeps free for finishing its bag (core/recording.py); reindex removes it
RESERVE_NAME = '.reserve'


@dataclass
class FileReport:
    """What reindex found and did in one storage file."""

    name: str
    messages: int
    chunks: int
    repaired: bool           # False: the file was whole and was only read
    kept_bytes: int = 0      # data section kept in place
    cut_bytes: int = 0       # torn bytes cut off the end
    salvaged: int = 0        # messages rewritten from a torn last chunk


@dataclass
class ReindexReport:
    path: Path
    files: list[FileReport]
    moved: list[str] = field(default_factory=list)  # split files moved in from a .splits dir

    @property
    def message_count(self) -> int:
        return sum(f.messages for f in self.files)


def needs_reindex(bag: str | Path) -> bool:
    """True for a bag directory an interrupted recording left: storage files, no metadata.yaml."""
    path = Path(bag)
    return (path.is_dir() and not (path / METADATA_FILE).exists()
            and (any(path.glob('*.mcap')) or bool(_split_dirs(path))))


def reindex(bag: str | Path) -> ReindexReport:
    """Finish every .mcap file of the bag directory and write its metadata.yaml (see the module
    docstring). BagError for a missing path or a directory with no .mcap file; OSError when the
    files cannot be written (a full disk: free space and run it again)."""
    path = Path(bag)
    if not path.is_dir():
        raise BagError(f'bag {str(path)!r} is not a directory; expected a rosbag2 bag directory')
    moved = _adopt_split_in_progress(path)
    (path / RESERVE_NAME).unlink(missing_ok=True)  # a killed recorder's, now free space
    files = sorted(path.glob('*.mcap'), key=_split_order)
    if not files:
        raise BagError(f'bag {str(path)!r} has no .mcap file; expected an MCAP rosbag2 bag '
                       '(reindex rebuilds MCAP bags only)')
    hashes = _TypeHashes()
    reports, infos = [], []
    for f in files:
        report, info = _reindex_file(f, hashes)
        reports.append(report)
        infos.append(info)
    write_metadata(path, combined_metadata(infos))
    return ReindexReport(path, reports, moved)


def format_report(report: ReindexReport) -> str:
    lines = [f'reindexed {report.path}: {report.message_count} messages in '
             f'{len(report.files)} file(s); {METADATA_FILE} written']
    for name in report.moved:
        lines.append(f'  {name}: moved in from the unfinished split directory')
    for f in report.files:
        if not f.repaired:
            lines.append(f'  {f.name}: whole, {f.messages} messages in {f.chunks} chunks')
            continue
        extra = f', {f.salvaged} salvaged from a torn chunk' if f.salvaged else ''
        lines.append(f'  {f.name}: finished, {f.messages} messages in {f.chunks} chunks{extra}; '
                     f'{f.cut_bytes} torn bytes cut')
    return '\n'.join(lines)


# --------------------------------------------------------------------------- bag directory
def _split_dirs(path: Path) -> list[Path]:
    return sorted(p for p in path.parent.glob(f'.{path.name}.*.splits') if p.is_dir())


def _adopt_split_in_progress(path: Path) -> list[str]:
    """Move the split recorder's unfinished file (.<bag>.*.splits/<name>/<name>.mcap) into the
    bag and remove the hidden directory."""
    moved = []
    for tmp in _split_dirs(path):
        for src in sorted(tmp.glob('*/*.mcap')):
            if not (path / src.name).exists():
                os.replace(src, path / src.name)
                moved.append(src.name)
        shutil.rmtree(tmp, ignore_errors=True)
    return moved


def _split_order(p: Path):
    m = re.search(r'_(\d+)$', p.stem)
    return (int(m.group(1)) if m else -1, p.name)


# --------------------------------------------------------------------------- one file
class _TypeHashes:
    """RIHS01 type hashes (metadata.yaml's type_description_hash) from embedded definitions."""

    def __init__(self) -> None:
        self._store = None

    def __call__(self, schema: Schema | None, channel: Channel) -> str:
        if channel.metadata.get('topic_type_hash'):
            return channel.metadata['topic_type_hash']
        if schema is None or schema.encoding != 'ros2msg':
            return ''
        try:
            from rosbags.typesys import Stores, get_types_from_msg, get_typestore
            if self._store is None:
                self._store = get_typestore(Stores.ROS2_JAZZY)
            if schema.name not in self._store.types:
                self._store.register(get_types_from_msg(schema.data.decode(), schema.name))
            return self._store.hash_rihs01(schema.name)
        except Exception:  # noqa: BLE001 - a definition rosbags cannot parse has no hash here
            return ''


def _qos(channel: Channel) -> Any:
    text = channel.metadata.get('offered_qos_profiles', '')
    try:
        return yaml.safe_load(text) or [] if text else []
    except yaml.YAMLError:
        return text


def _file_info(name: str, schemas: dict, channels: dict, counts: dict, start: int, end: int,
               hashes: _TypeHashes) -> dict[str, Any]:
    """The metadata.yaml mapping of one storage file (the shape combined_metadata takes)."""
    total = sum(counts.values())
    if not total:
        start = end = 0
    topics = []
    for cid, ch in sorted(channels.items()):
        schema = schemas.get(ch.schema_id)
        topics.append({'topic_metadata': {
            'name': ch.topic, 'type': schema.name if schema else '',
            'serialization_format': ch.message_encoding, 'offered_qos_profiles': _qos(ch),
            'type_description_hash': hashes(schema, ch)}, 'message_count': counts.get(cid, 0)})
    span = {'starting_time': {'nanoseconds_since_epoch': start},
            'duration': {'nanoseconds': max(0, end - start)}}
    return {'relative_file_paths': [name], **span, 'message_count': total,
            'topics_with_message_count': topics, 'compression_format': '',
            'compression_mode': '', 'custom_data': {'reindexed_by': 'bag_tools.core'}}


def _whole_summary(path: Path):
    """The summary of a finished file, or None when it has none (or a broken one)."""
    try:
        with path.open('rb') as fh:
            return SeekingReader(fh).get_summary()
    except Exception:  # noqa: BLE001 - no footer, torn summary: the file needs finishing
        return None


def _reindex_file(path: Path, hashes: _TypeHashes) -> tuple[FileReport, dict]:
    summary = _whole_summary(path)
    if summary is not None and summary.statistics is not None:
        st = summary.statistics
        counts = dict(st.channel_message_counts)
        info = _file_info(path.name, summary.schemas, summary.channels, counts,
                          st.message_start_time, st.message_end_time, hashes)
        return FileReport(path.name, sum(counts.values()), len(summary.chunk_indexes), False), info
    with path.open('r+b') as fh:
        size = os.fstat(fh.fileno()).st_size
        head = _read(fh, 0, len(MAGIC))
        if head != MAGIC[:len(head)]:
            raise BagError(f'storage file {str(path)!r} is not MCAP (no MCAP magic at its start)')
        if size <= len(MAGIC):  # killed before its header reached the disk: an empty file
            scan = _Scan(b'', 0)
            scan.keep_end = 0
        else:
            mm = mmap.mmap(fh.fileno(), 0, prot=mmap.PROT_READ)
            try:
                scan = _Scan(mm, size)
                scan.run()
            finally:
                mm.close()
        tail, info = scan.finish(path.name, hashes)
        os.pwrite(fh.fileno(), tail, scan.keep_end)
        os.ftruncate(fh.fileno(), scan.keep_end + len(tail))
        os.fsync(fh.fileno())
    report = FileReport(path.name, sum(scan.counts.values()), len(scan.chunk_indexes), True,
                        kept_bytes=scan.keep_end,
                        cut_bytes=max(0, size - scan.keep_end - len(scan.salvage_data)),
                        salvaged=scan.salvaged)
    return report, info


def _read(fh, offset: int, n: int) -> bytes:
    return os.pread(fh.fileno(), n, offset)


class _TornChunk(Exception):
    """A chunk that cannot be kept whole."""


@dataclass
class _ChunkRecords:
    """The records inside one chunk: what the summary and the message indexes need."""

    schemas: list = field(default_factory=list)
    channels: list = field(default_factory=list)
    entries: dict = field(default_factory=dict)  # channel -> [(log time, offset in the chunk)]
    start: int = 2**63 - 1
    end: int = 0
    used: int = 0                                # bytes of whole records


def _parse_records(data: bytes | memoryview, whole: bool) -> _ChunkRecords:
    """The records of a chunk's (uncompressed) record section. whole=False: stop at the first
    torn record (salvage); whole=True: a torn or odd record raises _TornChunk."""
    out = _ChunkRecords()
    pos, n = 0, len(data)
    while pos < n:
        if pos + 9 > n:
            break
        op, length = _HEAD.unpack_from(data, pos)
        end = pos + 9 + length
        if end > n:
            break
        if op == _OP_MESSAGE:
            if length < 22:
                break
            cid, _seq, log = _MESSAGE_FIXED.unpack_from(data, pos + 9)
            out.entries.setdefault(cid, []).append((log, pos))
            out.start, out.end = min(out.start, log), max(out.end, log)
        elif op in (_OP_SCHEMA, _OP_CHANNEL):
            try:
                rec = (Schema if op == _OP_SCHEMA else Channel).read(_stream(data[pos + 9:end]))
            except Exception:  # noqa: BLE001
                break
            (out.schemas if op == _OP_SCHEMA else out.channels).append(rec)
        pos = end
        out.used = pos
    if whole and out.used != n:
        raise _TornChunk(f'record at {out.used} of {n} is torn')
    return out


def _stream(data) -> ReadDataStream:
    return ReadDataStream(BytesIO(bytes(data)))


def _decompress(compression: str, data: bytes, size: int) -> bytes:
    """A chunk's record section, decompressed by the mcap library (zstd, lz4) when needed."""
    if compression == '':
        return data
    chunk = Chunk(compression=compression, data=data, message_start_time=0,
                  message_end_time=0, uncompressed_crc=0, uncompressed_size=size)
    try:
        stream, n = get_chunk_data_stream(chunk)
        return stream.read(n)
    except Exception as exc:  # noqa: BLE001 - unsupported or corrupt compressed data
        raise _TornChunk(f'{compression} chunk does not decompress: {one_line(exc)}') from None


class _Scan:
    """One pass over an unfinished file's data section."""

    def __init__(self, mm: mmap.mmap, size: int) -> None:
        self.mm, self.size = mm, size
        self.schemas: dict[int, Schema] = {}
        self.channels: dict[int, Channel] = {}
        self.counts: dict[int, int] = {}
        self.chunk_indexes: list[ChunkIndex] = []
        self.metadata: list[tuple[int, int, str]] = []     # (offset, length, name) kept
        self.keep_end = len(MAGIC)
        self.new_indexes = b''          # message indexes for the last whole chunk
        self.salvage: _ChunkRecords | None = None
        self.salvage_data = b''
        self.salvaged = 0
        self.has_header = False
        self._open: tuple | None = None  # last chunk: (index, records, {cid: offset}, end)

    def _register(self, rec: _ChunkRecords) -> None:
        for s in rec.schemas:
            self.schemas[s.id] = s
        for c in rec.channels:
            self.channels[c.id] = c
        for cid, e in rec.entries.items():
            self.counts[cid] = self.counts.get(cid, 0) + len(e)

    def run(self) -> None:
        mm, size, pos = self.mm, self.size, len(MAGIC)
        while pos + 9 <= size:
            op, length = _HEAD.unpack_from(mm, pos)
            end = pos + 9 + length
            if op == _OP_CHUNK:
                if not self._chunk(pos, end):
                    break
            elif op == _OP_MESSAGE_INDEX:
                if end > size or self._open is None or length < 6:
                    break
                cid, blen = struct.unpack_from('<HI', mm, pos + 9)
                if 6 + blen != length or blen % 16:
                    break
                self._open[2][cid] = pos
                self._open = (*self._open[:3], end)
            elif op == _OP_HEADER and pos == len(MAGIC):
                if end > size:
                    break
                self.has_header = True
            elif op in (_OP_SCHEMA, _OP_CHANNEL) and end <= size:  # unchunked definitions
                self._close_chunk(last=False)
                self._register(_parse_records(mm[pos:end], whole=True))
            elif op in (_OP_METADATA, _OP_ATTACHMENT) and end <= size:
                name = self._metadata_name(pos)
                if op == _OP_METADATA and name == _ROSBAG2_METADATA:
                    break       # written at close: the summary after it is what was torn
                self._close_chunk(last=False)
                if op == _OP_METADATA:
                    self.metadata.append((pos, end - pos, name))
            elif op == _OP_MESSAGE:
                raise BagError('storage file has messages outside chunks; reindex handles '
                               'chunked MCAP (what rosbag2 and rosbags write)')
            else:               # DataEnd, a summary record, garbage: the data section ends
                break
            pos = end
            self.keep_end = end
        self._close_chunk(last=True)

    def _metadata_name(self, pos: int) -> str:
        n = struct.unpack_from('<I', self.mm, pos + 9)[0]
        return bytes(self.mm[pos + 13:pos + 13 + n]).decode(errors='replace')

    def _chunk(self, pos: int, end: int) -> bool:
        """Take the chunk record at pos; False when it is torn (then the scan stops)."""
        mm = self.mm
        if pos + 9 + _CHUNK_FIXED.size + 4 > self.size:
            return False
        start, stop, usize, crc = _CHUNK_FIXED.unpack_from(mm, pos + 9)
        clen = struct.unpack_from('<I', mm, pos + 9 + _CHUNK_FIXED.size)[0]
        comp_at = pos + 9 + _CHUNK_FIXED.size + 4
        if comp_at + clen + 8 > min(self.size, end):
            return False
        compression = bytes(mm[comp_at:comp_at + clen]).decode(errors='replace')
        rlen = struct.unpack_from('<Q', mm, comp_at + clen)[0]
        rstart = comp_at + clen + 8
        if end > self.size or rstart + rlen != end:
            if end > self.size and compression == '':
                self._salvage(start, stop, rstart, min(self.size, rstart + rlen))
            return False
        try:
            data = _decompress(compression, mm[rstart:end], usize)
            if len(data) != usize or (crc and zlib.crc32(data) != crc):
                raise _TornChunk('chunk size or CRC does not match its contents')
            rec = _parse_records(data, whole=True)
        except _TornChunk:
            return False
        self._close_chunk(last=False)  # a whole chunk follows the previous one
        index = ChunkIndex(message_start_time=start, message_end_time=stop,
                           chunk_start_offset=pos, chunk_length=end - pos,
                           message_index_offsets={}, message_index_length=0,
                           compression=compression, compressed_size=rlen,
                           uncompressed_size=usize)
        self._register(rec)
        self._open = (index, rec, {}, end)
        return True

    def _close_chunk(self, last: bool) -> None:
        """Done with the chunk before: its message index records are kept as found (the last
        chunk's are made anew when some are missing or torn)."""
        if self._open is None:
            return
        index, rec, offsets, mi_end = self._open
        self._open = None
        chunk_end = index.chunk_start_offset + index.chunk_length
        if set(offsets) == set(rec.entries) or not last:
            index.message_index_offsets = dict(offsets)
            index.message_index_length = mi_end - chunk_end
        else:           # missing or torn: cut after the chunk and write them again
            self.keep_end = chunk_end
            self.new_indexes = _message_indexes(rec)
            index.message_index_offsets = None  # set in finish() once their place is known
        self.chunk_indexes.append(index)

    def _salvage(self, start: int, stop: int, rstart: int, rend: int) -> None:
        rec = _parse_records(self.mm[rstart:rend], whole=False)
        if not rec.entries:
            return
        self.salvage, self.salvage_data = rec, bytes(self.mm[rstart:rstart + rec.used])
        self._register(rec)
        self.salvaged = sum(len(e) for e in rec.entries.values())

    # -- the appended tail -------------------------------------------------------------
    def finish(self, name: str, hashes: _TypeHashes) -> tuple[bytes, dict]:
        out = bytearray(MAGIC if self.size <= len(MAGIC) else b'')
        pos = self.keep_end
        if not self.has_header:  # torn in the header record itself
            out += serialize(Header(profile='ros2', library='bag_tools reindex'))
        if self.chunk_indexes and self.chunk_indexes[-1].message_index_offsets is None:
            last = self.chunk_indexes[-1]
            last.message_index_offsets = _index_offsets(self.new_indexes, pos + len(out))
            last.message_index_length = len(self.new_indexes)
            out += self.new_indexes
        if self.salvage is not None:
            rec = self.salvage
            chunk = serialize(Chunk(compression='', data=self.salvage_data,
                                    message_start_time=rec.start, message_end_time=rec.end,
                                    uncompressed_crc=zlib.crc32(self.salvage_data),
                                    uncompressed_size=len(self.salvage_data)))
            chunk_at = pos + len(out)
            out += chunk
            indexes = _message_indexes(rec)
            self.chunk_indexes.append(ChunkIndex(
                message_start_time=rec.start, message_end_time=rec.end,
                chunk_start_offset=chunk_at, chunk_length=len(chunk),
                message_index_offsets=_index_offsets(indexes, chunk_at + len(chunk)),
                message_index_length=len(indexes), compression='',
                compressed_size=len(self.salvage_data), uncompressed_size=len(self.salvage_data)))
            out += indexes
        starts = [c.message_start_time for c in self.chunk_indexes if c.message_start_time <= c.message_end_time]
        ends = [c.message_end_time for c in self.chunk_indexes if c.message_start_time <= c.message_end_time]
        start, end = (min(starts), max(ends)) if starts and sum(self.counts.values()) else (0, 0)
        info = _file_info(name, self.schemas, self.channels, self.counts, start, end, hashes)
        meta_at = pos + len(out)
        out += serialize(Metadata(name=_ROSBAG2_METADATA,
                                  metadata={'serialized_metadata': dump_info(info).strip()}))
        metadata = [MetadataIndex(offset=o, length=n, name=m) for o, n, m in self.metadata]
        metadata.append(MetadataIndex(offset=meta_at, length=pos + len(out) - meta_at,
                                      name=_ROSBAG2_METADATA))
        out += serialize(DataEnd(data_section_crc=0))
        summary_start = pos + len(out)
        offsets = []
        stats = Statistics(
            message_count=sum(self.counts.values()), schema_count=len(self.schemas),
            channel_count=len(self.channels), attachment_count=0, metadata_count=len(metadata),
            chunk_count=len(self.chunk_indexes), message_start_time=start, message_end_time=end,
            channel_message_counts={cid: self.counts.get(cid, 0) for cid in sorted(self.channels)})
        for group in (list(self.schemas.values()), list(self.channels.values()),
                      self.chunk_indexes, metadata, [stats]):
            if not group:
                continue
            data = serialize(*group)
            offsets.append(SummaryOffset(group_opcode=data[0], group_start=pos + len(out),
                                         group_length=len(data)))
            out += data
        offsets_start = pos + len(out)
        out += serialize(*offsets, Footer(summary_start=summary_start,
                                          summary_offset_start=offsets_start, summary_crc=0))
        out += MAGIC
        return bytes(out), info


def _message_indexes(rec: _ChunkRecords) -> bytes:
    return serialize(*(MessageIndex(channel_id=cid, records=entries)
                       for cid, entries in sorted(rec.entries.items())))


def _index_offsets(indexes: bytes, at: int) -> dict[int, int]:
    """{channel: file offset} of the message index records in `indexes`, written at `at`."""
    out, pos = {}, 0
    while pos < len(indexes):
        _op, length = _HEAD.unpack_from(indexes, pos)
        out[struct.unpack_from('<H', indexes, pos + 9)[0]] = at + pos
        pos += 9 + length
    return out
