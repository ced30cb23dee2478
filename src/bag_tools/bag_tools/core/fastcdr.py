"""Vectorised CDR for the project's block messages, and batch access to MCAP bags.

The block types of force_tester_msgs (ForceBlock, AccelBlock, ...) share one fixed layout
(plain little-endian CDR, as rmw writes and rosbags reads/writes), offsets relative to the
byte after the 4-byte encapsulation header:

    0  int32  header.stamp.sec
    4  uint32 header.stamp.nanosec
    8  uint32 len(frame_id) + 1, then the bytes and a NUL
       float64 sample_rate_hz   (aligned to 8)
       uint64  seq
    then per float64[] field: uint32 count (aligned to 4), then, only when count > 0,
    padding to 8 and count * 8 bytes. No trailing padding.

decode_blocks() decodes many such messages held in one buffer with a few numpy calls per
field (no per-message Python); encode_blocks() is the inverse. Both equal rosbags'
deserialize_cdr / serialize_cdr (tests/test_bag_fastcdr.py checks it). Anything that does not
fit (big-endian CDR, inconsistent lengths) raises FastPathError; callers then use the generic
rosbags path, which reports the problem as before.

read_topics_raw() returns the raw messages of some topics of an MCAP bag as arrays (log
times, offsets and lengths into one buffer), read via the MCAP summary's message indexes
without per-message parsing; McapBatch writes many messages into a rosbags MCAP writer at
once: the same records, messages and log times as message-by-message writes (the message-index
records inside a chunk may come in another channel order, so the file bytes can differ).
"""

from __future__ import annotations

import mmap
import struct
from collections.abc import Sequence
from pathlib import Path

import numpy as np

NS_PER_S = 1_000_000_000
_U8 = np.uint8


class FastPathError(Exception):
    """The data does not fit the fast path; use the generic code."""


# --------------------------------------------------------------------------- gathers
def _gather(buf: np.ndarray, offs: np.ndarray, dtype: str) -> np.ndarray:
    size = np.dtype(dtype).itemsize
    if offs.size and (int(offs.min()) < 0 or int(offs.max()) + size > buf.size):
        raise FastPathError('field outside the message buffer')
    idx = offs[:, None] + np.arange(size, dtype=np.int64)
    return buf[idx].copy().view(dtype).reshape(-1)


def gather_f64(buf: np.ndarray, starts: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """Concatenation of counts[i] float64 (LE) at byte offsets starts[i] of buf."""
    counts = counts.astype(np.int64)
    total = int(counts.sum())
    out = np.empty(total, dtype='<f8')
    if total == 0:
        return out.astype(np.float64)
    dest0 = np.cumsum(counts) - counts
    residues = starts % 8
    for r in np.unique(residues[counts > 0]).tolist():
        sel = (residues == r) & (counts > 0)
        view = np.frombuffer(buf, dtype='<f8', offset=r, count=(buf.size - r) // 8)
        c = counts[sel]
        e0 = (starts[sel] - r) // 8
        d0 = dest0[sel]
        ctot = int(c.sum())
        rep_src = np.repeat(e0 - (np.cumsum(c) - c), c)
        rep_dst = np.repeat(d0 - (np.cumsum(c) - c), c)
        k = np.arange(ctot, dtype=np.int64)
        out[rep_dst + k] = view[rep_src + k]
    return out.astype(np.float64, copy=False)


# --------------------------------------------------------------------------- decode
class Blocks:
    """Decoded block messages: per message stamp_ns, rate, seq, and per field counts/values."""

    def __init__(self, stamp_ns, rate_hz, seq, counts, starts, buf, frame_ids):
        self.stamp_ns = stamp_ns      # int64 (m,)
        self.rate_hz = rate_hz        # float64 (m,)
        self.seq = seq                # uint64 (m,)
        self.counts = counts          # {field: int64 (m,)}
        self._starts = starts         # {field: int64 (m,) byte offsets of the values}
        self._buf = buf
        self._frame = frame_ids       # (offsets, lengths) of the frame_id bytes

    def __len__(self) -> int:
        return int(self.stamp_ns.size)

    def values(self, field: str, sel: np.ndarray | None = None) -> np.ndarray:
        """Concatenated values of field over the messages sel (index array; default all)."""
        starts, counts = self._starts[field], self.counts[field]
        if sel is not None:
            starts, counts = starts[sel], counts[sel]
        return gather_f64(self._buf, starts, counts)

    def frame_id(self, i: int) -> str:
        off, ln = int(self._frame[0][i]), int(self._frame[1][i])
        return self._buf[off:off + ln].tobytes().decode('utf-8')


def decode_blocks(buf, starts: np.ndarray, lengths: np.ndarray,
                  fields: Sequence[str]) -> Blocks:
    """Decode block messages (CDR incl. encapsulation header) at buf[starts[i]:+lengths[i]].

    fields: the float64[] field names of the type, in order.
    """
    b = buf if isinstance(buf, np.ndarray) else np.frombuffer(buf, dtype=_U8)
    starts = np.asarray(starts, dtype=np.int64)
    lengths = np.asarray(lengths, dtype=np.int64)
    m = starts.size
    if m == 0:
        z = np.zeros(0, np.int64)
        return Blocks(z, np.zeros(0), np.zeros(0, np.uint64), {f: z for f in fields},
                      {f: z for f in fields}, b, (z, z))
    if (lengths < 24).any():
        raise FastPathError('message too short')
    enc = _gather(b, starts, 'u2')
    if (enc != 0x0100).any():  # bytes 00 01: CDR_LE
        raise FastPathError('not little-endian CDR')
    body = starts + 4
    end = starts + lengths
    sec = _gather(b, body, '<i4').astype(np.int64)
    nsec = _gather(b, body + 4, '<u4').astype(np.int64)
    slen = _gather(b, body + 8, '<u4').astype(np.int64)
    if (slen < 1).any() or (body + 12 + slen > end).any():
        raise FastPathError('bad frame_id length')
    cur = (12 + slen + 7) & ~7
    if (body + cur + 16 > end).any():
        raise FastPathError('message too short')
    rate = _gather(b, body + cur, '<f8')
    seq = _gather(b, body + cur + 8, '<u8')
    cur = cur + 16
    counts, vstarts = {}, {}
    for f in fields:
        cur = (cur + 3) & ~3
        if (body + cur + 4 > end).any():
            raise FastPathError('message too short')
        n = _gather(b, body + cur, '<u4').astype(np.int64)
        cur = cur + 4
        cur = np.where(n > 0, (cur + 7) & ~7, cur)
        if (body + cur + 8 * n > end).any():
            raise FastPathError('array beyond the message end')
        counts[f], vstarts[f] = n, body + cur
        cur = cur + 8 * n
    if (body + cur != end).any():
        raise FastPathError('message length does not match its fields')
    return Blocks(sec * NS_PER_S + nsec, rate, seq, counts, vstarts, b,
                  (body + 12, slen - 1))


# --------------------------------------------------------------------------- encode
def encode_blocks(stamps_ns, rate_hz, seqs, fields: Sequence[str], counts: dict,
                  values: dict, frame_id: str = '') -> tuple:
    """CDR of m block messages -> (buffer bytes, starts, lengths).

    stamps_ns, seqs: int arrays (m,); rate_hz scalar or (m,); fields: float64[] field names in
    type order; counts[f]: (m,) sample counts (absent: all 0); values[f]: concatenated values.
    """
    stamps = np.asarray(stamps_ns, dtype=np.int64)
    m = stamps.size
    rate = np.broadcast_to(np.asarray(rate_hz, dtype='<f8'), (m,))
    try:
        seq = np.asarray(seqs, dtype=np.int64)
    except OverflowError:
        raise FastPathError('seq beyond int64') from None
    if (seq < 0).any():
        raise FastPathError('negative seq')
    sec = stamps // NS_PER_S
    if m and (sec.min() < -2**31 or sec.max() >= 2**31):
        raise FastPathError('stamp out of int32 seconds')
    nsec = stamps % NS_PER_S
    fb = frame_id.encode('utf-8') + b'\x00'
    off = 12 + len(fb)
    off = (off + 7) & ~7
    head_len = off + 16
    cnt = {f: (np.asarray(counts[f], dtype=np.int64) if f in counts
               else np.zeros(m, np.int64)) for f in fields}
    # per message, per field: offset of the count and of the data (relative to body)
    size = np.full(m, head_len, dtype=np.int64)
    pos_c, pos_d = {}, {}
    for f in fields:
        size = (size + 3) & ~3
        pos_c[f] = size.copy()
        size = size + 4
        n = cnt[f]
        size = np.where(n > 0, (size + 7) & ~7, size)
        pos_d[f] = size.copy()
        size = size + 8 * n
    lengths = size + 4
    starts = np.cumsum(lengths) - lengths
    total = int(lengths.sum())
    out = np.zeros(total, dtype=_U8)
    body = starts + 4
    fixed = np.zeros(head_len + 4, dtype=_U8)
    fixed[:4] = (0, 1, 0, 0)
    fixed[16:16 + len(fb)] = np.frombuffer(fb, dtype=_U8)
    fixed[12:16] = np.frombuffer(struct.pack('<I', len(fb)), dtype=_U8)
    idx = starts[:, None] + np.arange(head_len + 4, dtype=np.int64)
    hdr = np.broadcast_to(fixed, (m, head_len + 4)).copy()
    hdr[:, 4:8] = sec.astype('<i4').view(_U8).reshape(m, 4)
    hdr[:, 8:12] = nsec.astype('<u4').view(_U8).reshape(m, 4)
    hdr[:, 4 + off:12 + off] = rate.astype('<f8').view(_U8).reshape(m, 8)
    hdr[:, 12 + off:20 + off] = seq.astype('<u8').view(_U8).reshape(m, 8)
    out[idx] = hdr
    for f in fields:
        n = cnt[f]
        ci = (body + pos_c[f])[:, None] + np.arange(4, dtype=np.int64)
        out[ci] = n.astype('<u4').view(_U8).reshape(m, 4)
        tot = int(n.sum())
        if tot:
            v = np.ascontiguousarray(values[f], dtype='<f8')
            if v.size != tot:
                raise FastPathError(f'{f}: {v.size} values for {tot} samples')
            dst0 = body + pos_d[f]
            rep = np.repeat(dst0 - 8 * (np.cumsum(n) - n), n)
            byte_pos = rep + 8 * np.arange(tot, dtype=np.int64)
            res = byte_pos % 8
            for r in np.unique(res).tolist():
                sel = res == r
                view = out[r:r + 8 * ((total - r) // 8)].view('<f8')
                view[(byte_pos[sel] - r) // 8] = v[sel]
    return out.tobytes(), starts, lengths


# --------------------------------------------------------------------------- MCAP reading
class RawMessages:
    """Raw messages of one or more topics: arrays in log order (ties as rosbags orders)."""

    def __init__(self, buf: np.ndarray, log_ns: np.ndarray, channel: np.ndarray,
                 starts: np.ndarray, lengths: np.ndarray, holder=None) -> None:
        self.buf = buf
        self.log_ns = log_ns
        self.channel = channel  # topic index per message
        self.starts = starts
        self.lengths = lengths
        self._holder = holder

    def select(self, mask: np.ndarray) -> RawMessages:
        return RawMessages(self.buf, self.log_ns[mask], self.channel[mask], self.starts[mask],
                           self.lengths[mask], self._holder)

    def data(self, i: int) -> bytes:
        s = int(self.starts[i])
        return self.buf[s:s + int(self.lengths[i])].tobytes()


def _mcap_index(data: memoryview, size: int) -> tuple:
    """(channel id -> topic, [(chunk_start, records_start, records_size, {cid: mi_offset})])."""
    if size < 8 + 37 or bytes(data[:8]) != b'\x89MCAP0\r\n' \
            or bytes(data[size - 8:size]) != b'\x89MCAP0\r\n':
        raise FastPathError('not an MCAP file')
    # footer: opcode 0x02, len 20, summary_start u64, summary_offset_start u64, crc u32
    fo = size - 8 - 29
    if data[fo] != 0x02:
        raise FastPathError('no MCAP footer')
    summary_start, = struct.unpack_from('<Q', data, fo + 9)
    if summary_start == 0 or summary_start >= fo:
        raise FastPathError('MCAP without summary')
    topics: dict = {}
    chunks = []
    pos = summary_start
    while pos < fo:
        op = data[pos]
        ln, = struct.unpack_from('<Q', data, pos + 1)
        rec = pos + 9
        if rec + ln > fo:
            raise FastPathError('truncated summary')
        if op == 0x04:  # channel
            cid, _sid, tlen = struct.unpack_from('<HHI', data, rec)
            topics[cid] = bytes(data[rec + 8:rec + 8 + tlen]).decode('utf-8')
        elif op == 0x08:  # chunk index
            _st, _et, cstart, _clen, mlen = struct.unpack_from('<QQQQI', data, rec)
            mi = {}
            p = rec + 36
            for _ in range(mlen // 10):
                cid, moff = struct.unpack_from('<HQ', data, p)
                mi[cid] = moff
                p += 10
            _mil, = struct.unpack_from('<Q', data, p)
            clen_s, = struct.unpack_from('<I', data, p + 8)
            comp = bytes(data[p + 12:p + 12 + clen_s]).decode()
            if comp:
                raise FastPathError(f'compressed chunks ({comp})')
            chunks.append((cstart, mi))
        pos = rec + ln
    out = []
    for cstart, mi in chunks:
        if data[cstart] != 0x06:
            raise FastPathError('chunk index does not point to a chunk')
        p = cstart + 9 + 28
        clen_s, = struct.unpack_from('<I', data, p)
        p += 4 + clen_s
        rsize, = struct.unpack_from('<Q', data, p)
        out.append((cstart, p + 8, rsize, mi))
    return topics, out


def read_topics_raw(mcap_path: str | Path, topics: Sequence[str]) -> tuple:
    """(RawMessages of the topics in log order, [topic per channel index]) of one .mcap file.

    Only uncompressed MCAP with a summary and message indexes (what rosbags writes); anything
    else raises FastPathError.
    """
    path = Path(mcap_path)
    with path.open('rb') as fh:
        size = path.stat().st_size
        if size == 0:
            raise FastPathError('empty file')
        mm = mmap.mmap(fh.fileno(), 0, access=mmap.ACCESS_READ)
    data = memoryview(mm)
    try:
        cid_topic, chunks = _mcap_index(data, size)
    except (struct.error, IndexError, UnicodeDecodeError) as exc:
        raise FastPathError(f'cannot parse MCAP index: {exc}') from None
    buf = np.frombuffer(mm, dtype=_U8)
    want = {t: i for i, t in enumerate(topics)}
    logs, chans, offs, ords, cks = [], [], [], [], []
    for k, (cstart, rstart, rsize, mi) in enumerate(chunks):
        for cid, moff in mi.items():
            t = cid_topic.get(cid)
            if t not in want:
                continue
            if data[moff] != 0x07:
                raise FastPathError('bad message index')
            _cid, blen = struct.unpack_from('<HI', data, moff + 9)
            ent = np.frombuffer(mm, dtype='<u8', count=blen // 8,
                                offset=moff + 15).reshape(-1, 2)
            rel = ent[:, 1].astype(np.int64)
            if rel.size and (rel.min() < 0 or rel.max() + 31 > rsize):
                raise FastPathError('message offset outside its chunk')
            logs.append(ent[:, 0].astype(np.int64))
            offs.append(rstart + rel)
            ords.append(rel)
            chans.append(np.full(rel.size, want[t], dtype=np.int64))
            cks.append(np.full(rel.size, cstart, dtype=np.int64))
    if not logs:
        z = np.zeros(0, np.int64)
        return RawMessages(buf, z, z, z, z, mm), list(topics)
    log = np.concatenate(logs)
    off = np.concatenate(offs)
    chan = np.concatenate(chans)
    if (buf[off] != 0x05).any():
        raise FastPathError('message index does not point to messages')
    rec_len = _gather(buf, off + 1, '<u8').astype(np.int64)
    rec_log = _gather(buf, off + 15, '<u8').astype(np.int64)
    if (rec_log != log).any() or (rec_len < 22).any() or (off + 9 + rec_len > size).any():
        raise FastPathError('message index disagrees with the messages')
    # rosbags order: log time, then chunk start offset, then position in the chunk
    order = np.lexsort((np.concatenate(ords), np.concatenate(cks), log))
    return RawMessages(buf, log[order], chan[order], (off + 31)[order],
                       (rec_len - 22)[order], mm), list(topics)


# --------------------------------------------------------------------------- MCAP writing
class McapBatch:
    """Append many messages to an open rosbags rosbag2 Writer using MCAP storage.

    Produces what calling writer.write() for each message would (same messages, log times,
    chunking at > 1 MiB, message and chunk indexes); within a chunk the message-index records are
    in channel-id order, so the bytes may differ from the per-message writer's. Raises FastPathError when the
    writer is not the rosbags MCAP writer this was written against.
    """

    def __init__(self, writer) -> None:
        storage = getattr(writer, 'storage', None)
        need = ('chunk', 'chunks', 'channel_stats', 'compression', 'bio', 'close_chunk')
        if storage is None or type(storage).__name__ != 'McapWriter' \
                or any(not hasattr(storage, a) for a in need) or storage.compression:
            raise FastPathError('not an uncompressed rosbags MCAP writer')
        self.writer = writer
        self.storage = storage
        storage.close_chunk = lambda: _close_chunk(storage)

    def write(self, cids: np.ndarray, log_ns: np.ndarray, sources: Sequence,
              src_index: np.ndarray, starts: np.ndarray, lengths: np.ndarray) -> None:
        """Write messages in the given order: message i is channel id cids[i] at log_ns[i],
        data = sources[src_index[i]][starts[i]:starts[i] + lengths[i]] (buffers)."""
        st = self.storage
        m = int(log_ns.size)
        if m == 0:
            return
        cids = np.asarray(cids, dtype=np.int64)
        log_ns = np.asarray(log_ns, dtype=np.int64)
        lengths = np.asarray(lengths, dtype=np.int64)
        rec_size = 31 + lengths
        hdr = np.zeros(m, dtype=np.dtype([('op', 'u1'), ('len', '<u8'), ('cid', '<u2'),
                                          ('seq', '<u4'), ('log', '<u8'), ('pub', '<u8')]))
        hdr['op'] = 5
        hdr['len'] = 22 + lengths
        hdr['cid'] = cids
        hdr['log'] = log_ns
        hdr['pub'] = log_ns
        hbytes = hdr.tobytes()
        mvs = [memoryview(s).cast('B') if not isinstance(s, np.ndarray) else
               memoryview(s) for s in sources]
        a_list = starts.tolist()
        e_list = (np.asarray(starts) + lengths).tolist()
        s_list = np.asarray(src_index).tolist()
        i = 0
        while i < m:
            chunk = st.chunk
            pos0 = chunk.bio.tell()
            # rosbags closes the chunk after the first message that takes it past 1 MiB
            ends = pos0 + np.cumsum(rec_size[i:])
            over = np.flatnonzero(ends > 2**20)
            j = i + (int(over[0]) + 1 if over.size else m - i)
            parts = []
            for k in range(i, j):
                parts.append(hbytes[31 * k:31 * k + 31])
                parts.append(mvs[s_list[k]][a_list[k]:e_list[k]])
            chunk.bio.write(b''.join(parts))
            offs = pos0 + np.concatenate(([0], np.cumsum(rec_size[i:j - 1])))
            lg = log_ns[i:j]
            lo, hi = int(lg.min()), int(lg.max())
            chunk.message_start_time = min(lo, chunk.message_start_time)
            chunk.message_end_time = max(hi, chunk.message_end_time)
            st.message_start_time = min(lo, st.message_start_time)
            st.message_end_time = max(hi, st.message_end_time)
            cj = cids[i:j]
            for cid in np.unique(cj).tolist():
                sel = cj == cid
                chunk.msgs[cid].extend(zip(lg[sel].tolist(), offs[sel].tolist()))
                st.channel_stats[cid] += int(sel.sum())
            if chunk.bio.tell() > 2**20:
                _close_chunk(st)
            i = j


def _close_chunk(st) -> None:
    """rosbags McapWriter.close_chunk with the message index written by numpy."""
    from io import BytesIO

    from rosbags.rosbag2.storage_mcap import PendingChunk, write_record
    from collections import defaultdict
    chunk = st.chunk
    raw = chunk.bio.getvalue()
    rec = BytesIO()
    rec.write(struct.pack('<QQQI', chunk.message_start_time, chunk.message_end_time,
                          len(raw), 0))
    compressed = st.compressor(raw)
    comp = st.compression.encode()
    rec.write(struct.pack('<I', len(comp)) + comp + struct.pack('<Q', len(compressed)))
    rec.write(compressed)
    chunk_start = st.bio.tell()
    write_record(st.bio, 0x06, rec)
    chunk_end = st.bio.tell()
    offsets = []
    for cid, msgs in chunk.msgs.items():
        offsets.append((cid, st.bio.tell()))
        ent = np.asarray(msgs, dtype='<u8').reshape(-1, 2)
        body = struct.pack('<HI', cid, len(msgs) * 16) + ent.tobytes()
        st.bio.write(b'\x07' + struct.pack('<Q', len(body)) + body)
    rec = BytesIO()
    rec.write(struct.pack('<QQQQI', chunk.message_start_time, chunk.message_end_time,
                          chunk_start, chunk_end - chunk_start, len(offsets) * 10))
    for cid, offset in offsets:
        rec.write(struct.pack('<HQ', cid, offset))
    rec.write(struct.pack('<Q', st.bio.tell() - chunk_end))
    rec.write(struct.pack('<I', len(comp)) + comp)
    rec.write(struct.pack('<QQ', len(compressed), len(raw)))
    st.chunks.append(rec)
    st.chunk = PendingChunk(2**63 - 1, 0, BytesIO(), defaultdict(list))
