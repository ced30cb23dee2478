"""Vectorised CDR for the project's block messages.

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
deserialize_cdr / serialize_cdr (tests/bag_tools/test_bag_fastcdr.py checks it). Anything that does not
fit (big-endian CDR, inconsistent lengths) raises FastPathError; callers then use the generic
rosbags path, which reports the problem as before.

Messages at a regular stride in a buffer (the usual layout of a recording) are read and
written through strided numpy views (stride_runs), irregular ones by fancy indexing.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence

import numpy as np

from force_tester_common.core.clock import NS_PER_S

_U8 = np.uint8


class FastPathError(Exception):
    """The data does not fit the fast path; use the generic code."""


# --------------------------------------------------------------------------- strided access
def stride_runs(offsets: np.ndarray, *keys: np.ndarray) -> list:
    """Split message offsets into runs [lo, hi) with one positive stride (and equal keys[k][i]
    within the run): such a run is one strided numpy view of the buffer. Returns
    [(lo, hi, stride)].

    The step from message i to i + 1 joins them when it is positive, the keys agree and it
    equals the step before or after it; where two such joined stretches of different strides
    meet, the message between them stays with the first. So a lone odd step (e.g. from the
    last message of one MCAP chunk to the first of the next) just ends a run, and irregular
    layouts fall apart into one-message runs."""
    m = int(offsets.size)
    if m == 0:
        return []
    d = np.diff(offsets)
    good = d > 0
    for k in keys:
        good &= k[1:] == k[:-1]
    same = np.zeros(m, dtype=bool)        # same[j]: steps j - 1 and j agree (both good)
    same[1:-1] = good[1:] & good[:-1] & (d[1:] == d[:-1])
    joined = same[:-1] | same[1:]         # step j is part of a stretch of equal steps
    joined[1:] &= ~(joined[:-1] & ~same[1:-1])  # a new stride after a joined step: cut it
    cut = np.ones(m + 1, dtype=bool)      # cut[i]: a run starts at i
    cut[1:m] = ~joined
    b = np.flatnonzero(cut)
    lo, hi = b[:-1], b[1:]
    stride = np.where(hi - lo > 1, np.append(d, 1)[lo], 1)
    return list(zip(lo.tolist(), hi.tolist(), stride.tolist()))


# --------------------------------------------------------------------------- gathers
def gather_rows(buf: np.ndarray, offs: np.ndarray, width: int,
                 runs: list | None = None) -> np.ndarray:
    """(m, width) uint8: the bytes buf[offs[i]:offs[i] + width] (strided views where regular;
    runs: stride_runs(offs), or of any offsets that differ from offs by a constant)."""
    offs = np.asarray(offs, dtype=np.int64)
    if offs.size and (int(offs.min()) < 0 or int(offs.max()) + width > buf.size):
        raise FastPathError('field outside the message buffer')
    runs = stride_runs(offs) if runs is None else runs
    if len(runs) > offs.size // 4 + 8:
        return buf[offs[:, None] + np.arange(width, dtype=np.int64)]
    out = np.empty((offs.size, width), dtype=_U8)
    for lo, hi, stride in runs:
        out[lo:hi] = np.ndarray((hi - lo, width), dtype=_U8, buffer=buf,
                                offset=int(offs[lo]), strides=(stride, 1))
    return out


def gather_struct(buf: np.ndarray, offs: np.ndarray, dtype: np.dtype,
                  runs: list | None = None) -> np.ndarray:
    """Structured (m,) array: the record of dtype (fields at their offsets, itemsize bytes)
    at each buf[offs[i]:], in one strided copy per run (runs: stride_runs(offs) or of offsets
    differing from offs by a constant)."""
    offs = np.asarray(offs, dtype=np.int64)
    width = dtype.itemsize
    if offs.size and (int(offs.min()) < 0 or int(offs.max()) + width > buf.size):
        raise FastPathError('field outside the message buffer')
    runs = stride_runs(offs) if runs is None else runs
    if len(runs) > offs.size // 4 + 8:
        return gather_rows(buf, offs, width, runs).view(dtype).reshape(-1)
    raw = np.dtype((np.void, width))  # copied as whole records (field by field is slower)
    out = np.empty(offs.size, dtype=raw)
    for lo, hi, stride in runs:
        out[lo:hi] = np.ndarray((hi - lo,), dtype=raw, buffer=buf, offset=int(offs[lo]),
                                strides=(stride,))
    return out.view(dtype)


def row_field(rows: np.ndarray, at: int, dtype: str) -> np.ndarray:
    """Column bytes rows[:, at:at + size] as dtype values."""
    size = np.dtype(dtype).itemsize
    return np.ascontiguousarray(rows[:, at:at + size]).view(dtype).reshape(-1)


def _gather_f64_indexed(buf: np.ndarray, starts: np.ndarray, counts: np.ndarray,
                        out: np.ndarray) -> None:
    """gather_f64 by fancy indexing (any layout)."""
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


def gather_f64(buf: np.ndarray, starts: np.ndarray, counts: np.ndarray,
               runs: list | None = None) -> np.ndarray:
    """Concatenation of counts[i] float64 (LE) at byte offsets starts[i] of buf.

    Messages laid out at a regular stride (the usual case) are copied as strided views
    (runs: stride_runs(starts, counts) when known)."""
    starts = np.asarray(starts, dtype=np.int64)
    counts = np.asarray(counts, dtype=np.int64)
    total = int(counts.sum())
    out = np.empty(total, dtype='<f8')
    if total == 0:
        return out.astype(np.float64)
    if int(starts.min()) < 0 or int((starts + 8 * counts).max()) > buf.size:
        raise FastPathError('values outside the message buffer')
    runs = stride_runs(starts, counts) if runs is None else runs
    if len(runs) > starts.size // 4 + 8:  # irregular layout: per-run views would be slow
        _gather_f64_indexed(buf, starts, counts, out)
        return out.astype(np.float64, copy=False)
    dest = np.cumsum(counts) - counts
    for lo, hi, stride in runs:
        n, k, d0 = int(counts[lo]), hi - lo, int(dest[lo])
        if n:  # each message's values as one record (memcpy; they are rarely 8-aligned)
            row = np.dtype((np.void, 8 * n))
            out[d0:d0 + k * n].view(row)[...] = np.ndarray(
                (k,), dtype=row, buffer=buf, offset=int(starts[lo]), strides=(stride,))
    return out.astype(np.float64, copy=False)


# --------------------------------------------------------------------------- decode
class Blocks:
    """Decoded block messages: per message stamp_ns, rate, seq, and per field counts/values."""

    def __init__(self, stamp_ns, rate_hz, seq, counts, starts, buf, frame_ids, runs=None):
        self.stamp_ns = stamp_ns      # int64 (m,)
        self.rate_hz = rate_hz        # float64 (m,)
        self.seq = seq                # uint64 (m,)
        self.counts = counts          # {field: int64 (m,)}
        self._starts = starts         # {field: int64 (m,) byte offsets of the values}
        self._buf = buf
        self._frame = frame_ids       # (offsets, lengths) of the frame_id bytes
        self._runs = runs             # uniform layout: stride runs of every field's starts
        self._run_lo = None if runs is None else np.array([r[0] for r in runs], np.int64)

    def __len__(self) -> int:
        return int(self.stamp_ns.size)

    def values(self, field: str, sel: np.ndarray | slice | None = None) -> np.ndarray:
        """Concatenated values of field over the messages sel (index array or slice with
        step 1; default all)."""
        starts, counts = self._starts[field], self.counts[field]
        runs = None
        if isinstance(sel, slice):
            lo, hi, step = sel.indices(len(self))
            if step != 1:
                raise ValueError(f'slice step {step}; expected 1')
            if self._runs is not None:  # the runs within [lo, hi), from lo
                first = max(int(np.searchsorted(self._run_lo, lo, 'right')) - 1, 0)
                runs = [(max(a, lo) - lo, min(b, hi) - lo, st) for a, b, st in
                        self._runs[first:int(np.searchsorted(self._run_lo, hi, 'left'))]
                        if b > lo and a < hi]
        if sel is not None:
            starts, counts = starts[sel], counts[sel]
        return gather_f64(self._buf, starts, counts, runs)

    def frame_id(self, i: int) -> str:
        off, ln = int(self._frame[0][i]), int(self._frame[1][i])
        return self._buf[off:off + ln].tobytes().decode('utf-8')


_COUNT = np.dtype([('n', '<u4')])


def _decode_uniform(b: np.ndarray, starts: np.ndarray, lengths: np.ndarray,
                    fields: Sequence[str], runs: list) -> Blocks | None:
    """decode_blocks when every message has the first one's layout (one frame_id, one sample
    count per field: a recording's usual case): all header fields in one strided pass.
    None when the layout differs anywhere (decode_blocks then decodes field by field)."""
    s0, length = int(starts[0]), int(lengths[0])
    if (lengths != length).any() or s0 + length > b.size:
        return None
    first = b[s0:s0 + length].tobytes()
    slen = struct.unpack_from('<I', first, 12)[0]
    cur = (12 + slen + 7) & ~7
    if slen < 1 or 4 + cur + 16 > length:
        return None
    head_fields = {'names': ['enc', 'sec', 'nsec', 'slen', 'rate', 'seq'],
                   'formats': ['<u2', '<i4', '<u4', '<u4', '<f8', '<u8'],
                   'offsets': [0, 4, 8, 12, 4 + cur, 12 + cur]}
    cur += 16
    counts, vstarts, count_at = {}, {}, {}
    for f in fields:
        cur = (cur + 3) & ~3
        if 4 + cur + 4 > length:
            return None
        count_at[f] = 4 + cur
        n = struct.unpack_from('<I', first, 4 + cur)[0]
        cur += 4
        if n:
            cur = (cur + 7) & ~7
        counts[f], vstarts[f] = n, starts + 4 + cur
        cur += 8 * n
    if 4 + cur != length:
        return None
    if fields:  # the first count directly follows seq: read with the head
        head_fields['names'].append(fields[0])
        head_fields['formats'].append('<u4')
        head_fields['offsets'].append(count_at[fields[0]])
    head = gather_struct(b, starts, np.dtype(dict(
        head_fields, itemsize=head_fields['offsets'][-1] + 4)), runs)
    if (head['enc'] != 0x0100).any():
        raise FastPathError('not little-endian CDR')
    if (head['slen'] != slen).any():
        return None
    for i, f in enumerate(fields):
        n = head[f] if i == 0 else gather_struct(b, starts + count_at[f], _COUNT, runs)['n']
        if (n != counts[f]).any():
            return None
    m = starts.size
    return Blocks(head['sec'].astype(np.int64) * NS_PER_S + head['nsec'], head['rate'].copy(),
                  head['seq'].copy(), {f: np.full(m, counts[f], np.int64) for f in fields},
                  vstarts, b, (starts + 16, np.full(m, slen - 1, np.int64)), runs)


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
    runs = stride_runs(starts)
    uniform = _decode_uniform(b, starts, lengths, fields, runs)
    if uniform is not None:
        return uniform

    def at(rel, width):  # rows of width bytes at starts + rel (rel: int or per message)
        if np.ndim(rel) == 0 or (rel == rel[0]).all():
            return gather_rows(b, starts + int(np.ravel(rel)[0]), width, runs)
        return gather_rows(b, starts + rel, width)

    head = at(0, 16)  # encapsulation, stamp, frame_id length
    if (row_field(head, 0, '<u2') != 0x0100).any():  # bytes 00 01: CDR_LE
        raise FastPathError('not little-endian CDR')
    body = starts + 4
    end = starts + lengths
    sec = row_field(head, 4, '<i4').astype(np.int64)
    nsec = row_field(head, 8, '<u4').astype(np.int64)
    slen = row_field(head, 12, '<u4').astype(np.int64)
    if (slen < 1).any() or (body + 12 + slen > end).any():
        raise FastPathError('bad frame_id length')
    cur = (12 + slen + 7) & ~7
    if (body + cur + 16 > end).any():
        raise FastPathError('message too short')
    rs = at(4 + cur, 16)
    rate = row_field(rs, 0, '<f8')
    seq = row_field(rs, 8, '<u8')
    cur = cur + 16
    counts, vstarts = {}, {}
    for f in fields:
        cur = (cur + 3) & ~3
        if (body + cur + 4 > end).any():
            raise FastPathError('message too short')
        n = row_field(at(4 + cur, 4), 0, '<u4').astype(np.int64)
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
def _view(buf: np.ndarray, offset: int, k: int, stride: int, dtype: str,
          width: int | None = None) -> np.ndarray:
    """k values (or k rows of width values) of dtype at buf[offset + i * stride]."""
    size = np.dtype(dtype).itemsize
    shape, strides = ((k,), (stride,)) if width is None else ((k, width), (stride, size))
    return np.ndarray(shape, dtype=dtype, buffer=buf, offset=offset, strides=strides)


def _block_layout(fields: Sequence[str], cnt: dict, head_len: int, m: int) -> tuple:
    """Per message and field the offsets of the count and of the data (relative to the byte
    after the encapsulation header), and the message lengths."""
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
    return pos_c, pos_d, size + 4


def _frame_layout(frame_id: str) -> tuple:
    """(frame_id bytes with NUL, offset of sample_rate_hz, length of the fixed head)."""
    fb = frame_id.encode('utf-8') + b'\x00'
    off = (12 + len(fb) + 7) & ~7
    return fb, off, off + 16


def _counts(fields: Sequence[str], counts: dict, m: int) -> dict:
    return {f: (np.asarray(counts[f], dtype=np.int64) if f in counts
                else np.zeros(m, np.int64)) for f in fields}


def block_lengths(fields: Sequence[str], counts: dict, frame_id: str = '') -> np.ndarray:
    """The CDR byte lengths encode_blocks gives messages with these sample counts."""
    m = len(next(iter(counts.values()))) if counts else 0
    return _block_layout(fields, _counts(fields, counts, m), _frame_layout(frame_id)[2], m)[2]


def encode_blocks(stamps_ns, rate_hz, seqs, fields: Sequence[str], counts: dict,
                  values: dict, frame_id: str = '', gap: int = 0, out: np.ndarray | None = None,
                  starts: np.ndarray | None = None) -> tuple:
    """CDR of m block messages -> (buffer, starts, lengths).

    stamps_ns, seqs: int arrays (m,); rate_hz scalar or (m,); fields: float64[] field names in
    type order; counts[f]: (m,) sample counts (absent: all 0); values[f]: concatenated values.
    The buffer is bytes with the messages back to back, or with gap > 0 a writable uint8 array
    with gap zero bytes before each message (room for a record header). With out and starts,
    message i is written at out[starts[i]:] (room for block_lengths() bytes) and out returned.
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
    fb, off, head_len = _frame_layout(frame_id)
    cnt = _counts(fields, counts, m)
    vals = {}
    for f in fields:
        tot = int(cnt[f].sum())
        if tot:
            vals[f] = np.ascontiguousarray(values[f], dtype='<f8').reshape(-1)
            if vals[f].size != tot:
                raise FastPathError(f'{f}: {vals[f].size} values for {tot} samples')
    pos_c, pos_d, lengths = _block_layout(fields, cnt, head_len, m)
    given = out is not None
    if not given:
        starts = np.cumsum(lengths + gap) - lengths
        out = np.zeros(int((lengths + gap).sum()), dtype=_U8)
    else:
        starts = np.asarray(starts, dtype=np.int64)
        if m and (starts.min() < 0 or int((starts + lengths).max()) > out.size):
            raise FastPathError('messages outside the output buffer')
    fixed = np.zeros(head_len + 4, dtype=_U8)
    fixed[:4] = (0, 1, 0, 0)
    fixed[16:16 + len(fb)] = np.frombuffer(fb, dtype=_U8)
    fixed[12:16] = np.frombuffer(struct.pack('<I', len(fb)), dtype=_U8)
    dest = {f: np.cumsum(cnt[f]) - cnt[f] for f in fields}
    # messages with the same counts have the same layout: one strided view per run; the head
    # up to the first field's values is built contiguous and copied in one pass, each later
    # count with its alignment padding in one more
    for lo, hi, stride in stride_runs(starts, *(cnt[f] for f in fields)):
        k, s0 = hi - lo, int(starts[lo])
        first = fields[0] if fields else None
        width = head_len + 4 if first is None else \
            4 + (int(pos_d[first][lo]) if cnt[first][lo] else int(pos_c[first][lo]) + 4)
        head = np.zeros((k, width), dtype=_U8)
        head[:, :head_len + 4] = fixed
        _view(head, 4, k, width, '<i4')[...] = sec[lo:hi]
        _view(head, 8, k, width, '<u4')[...] = nsec[lo:hi]
        _view(head, 4 + off, k, width, '<f8')[...] = rate[lo:hi]
        _view(head, 12 + off, k, width, '<u8')[...] = seq[lo:hi]
        if first is not None:
            _view(head, 4 + int(pos_c[first][lo]), k, width, '<u4')[...] = cnt[first][lo]
        _view(out, s0, k, stride, 'u1', width)[...] = head
        for f in fields:
            n, p_c = int(cnt[f][lo]), int(pos_c[f][lo])
            p_d = int(pos_d[f][lo]) if n else p_c + 4
            if f != first:  # the count and the padding after it (zero) as one value
                _view(out, s0 + 4 + p_c, k, stride, '<u8' if p_d - p_c == 8 else '<u4')[...] = n
            if n:
                d0 = int(dest[f][lo])
                row = np.dtype((np.void, 8 * n))  # one record per message (memcpy)
                _view(out, s0 + 4 + p_d, k, stride, row)[...] = \
                    vals[f][d0:d0 + k * n].view(row)
    return (out if gap or given else out.tobytes()), starts, lengths


# --------------------------------------------------------------------------- flat messages
#: struct codes of the base types a flat message may hold ('string': length, bytes, NUL).
FLAT_FORMATS = {'bool': '?', 'int8': 'b', 'uint8': 'B', 'int16': 'h', 'uint16': 'H', 'int32': 'i',
                'uint32': 'I', 'int64': 'q', 'uint64': 'Q', 'float32': 'f', 'float64': 'd', 'string': None}
_LE = b'\x00\x01'   # the encapsulation of little-endian plain CDR


def encode_flat(layout: Sequence, values) -> bytes:
    """One message of a flat layout ((field path, base type), ... : nested types spelled out, no arrays) as
    little-endian plain CDR, the bytes rosbags' serialize_cdr gives; values[path] for each field."""
    out = bytearray(_LE + b'\x00\x00')   # the encapsulation, then its two option bytes
    for path, base in layout:
        value = values[path]
        try:
            if base == 'string':
                text = value.encode('utf-8')
                out += bytes(-(len(out) - 4) % 4) + struct.pack('<I', len(text) + 1) + text + b'\x00'
            else:
                code = FLAT_FORMATS[base]
                out += bytes(-(len(out) - 4) % struct.calcsize(code)) + struct.pack('<' + code, value)
        except (struct.error, AttributeError, UnicodeError) as exc:
            raise FastPathError(f'field {path} = {value!r} is not a {base}: {exc}') from None
    return bytes(out)


def decode_flat(layout: Sequence, data) -> dict:
    """{field path: value} of one little-endian plain CDR message of a flat layout (encode_flat's inverse);
    FastPathError for anything else (another encapsulation, a length that does not fit, bad UTF-8)."""
    data = memoryview(data)
    if bytes(data[:2]) != _LE:
        raise FastPathError(f'encapsulation {bytes(data[:2])!r}; expected {_LE!r} (little-endian plain CDR)')
    pos, out = 4, {}
    try:
        for path, base in layout:
            if base == 'string':
                pos += -(pos - 4) % 4
                (n,) = struct.unpack_from('<I', data, pos)
                if n < 1 or pos + 4 + n > len(data) or data[pos + 3 + n] != 0:
                    raise FastPathError(f'string {path} of length {n} does not fit the message')
                out[path] = bytes(data[pos + 4:pos + 3 + n]).decode('utf-8')
                pos += 4 + n
            else:
                code = FLAT_FORMATS[base]
                pos += -(pos - 4) % struct.calcsize(code)
                (out[path],) = struct.unpack_from('<' + code, data, pos)
                pos += struct.calcsize(code)
    except (struct.error, UnicodeError) as exc:
        raise FastPathError(f'message of {len(data)} bytes does not fit its layout: {exc}') from None
    if not 0 <= len(data) - pos <= 3:   # at most the padding to a multiple of 4
        raise FastPathError(f'message of {len(data)} bytes, {len(data) - pos} beyond its fields')
    return out
