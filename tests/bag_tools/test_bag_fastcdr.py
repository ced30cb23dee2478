"""The numpy fast path (bag_tools.core.fastcdr) against the generic rosbags path.

decode_blocks / encode_blocks vs typestore deserialize_cdr / serialize_cdr (bit exact),
read_topics_raw vs open_bag().messages(), ExtendedBag vs rosbags and the mcap library, and
offline.correct with the fast path vs with it disabled.
"""

from __future__ import annotations

import contextlib
import zlib
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bag_tools.core import BagWriter, make_typestore, open_bag
from bag_tools.core.convert import campaign_to_bag
from bag_tools.core.daq import write_campaign
from bag_tools.core.errors import BagError
from bag_tools.core.fastcdr import FastPathError, decode_blocks, encode_blocks
from bag_tools.core.mcapfile import ExtendedBag, McapBag, read_topics_raw
from force_correction.offline import CorrectionSetup, correct
from force_correction.offline.scorer import BlockStamps, PullScorer, block_sample_stamps
from force_correction.offline.stream import segments
from force_tester_common.core.clock import sample_stamps_ns

REPO = Path(__file__).resolve().parents[2]

MSG_DIR = REPO / 'src' / 'force_tester_msgs' / 'msg'
BLOCK_TYPES = sorted(f'force_tester_msgs/msg/{p.stem}' for p in MSG_DIR.glob('*Block.msg'))
FORCE = 'force_tester_msgs/msg/ForceBlock'
ACCEL = 'force_tester_msgs/msg/AccelBlock'
PULL = 'force_tester_msgs/msg/PullEvent'
NS = 1_000_000_000
T0 = 1_700_000_000_000_000_000


@pytest.fixture(scope='module')
def store():
    return make_typestore([MSG_DIR])


def fields_of(store, type_name):
    names = [f for f in store.types[type_name].__dataclass_fields__ if not f.startswith('_')]
    assert names[:3] == ['header', 'sample_rate_hz', 'seq'], names
    return names[3:]


def bits(a):
    return np.ascontiguousarray(np.asarray(a, dtype=np.float64)).view(np.uint64)


SPECIAL = np.array([0.0, -0.0, np.inf, -np.inf, np.nan, 5e-324, -5e-324, 1.7976931348623157e308,
                    np.frombuffer(b'\x01\x00\x00\x00\x00\x00\xf8\x7f', '<f8')[0]])  # nan payload


def rand_values(rng, n):
    v = rng.normal(0, 1e3, n)
    if n:
        k = rng.integers(0, n + 1)
        v[rng.integers(0, n, k)] = rng.choice(SPECIAL, k)
    return v


FRAME_CHARS = 'abcXYZ_/0123456789é€'


def rand_frame(rng, length):
    # length in characters; some multi-byte so the byte length is not the char count
    return ''.join(rng.choice(list(FRAME_CHARS), length).tolist())


def rand_block(store, rng, type_name, frame_id=None, stamp_ns=None, counts=None):
    T = store.types
    flds = fields_of(store, type_name)
    if frame_id is None:
        frame_id = rand_frame(rng, int(rng.integers(0, 20)))
    if stamp_ns is None:
        sec = int(rng.integers(-2**31, 2**31))
        nsec = int(rng.integers(0, NS))
    else:
        sec, nsec = stamp_ns // NS, stamp_ns % NS
    if counts is None:
        counts = [int(rng.choice([0, 0, 1, 2, 3, 7, int(rng.integers(0, 40))]))
                  for _ in flds]
    rates = [50000.0, 1000.0, 0.0, -0.0, np.nan, np.inf, 1e-300, float(rng.uniform(0, 1e6))]
    rate = rates[int(rng.integers(0, len(rates)))]
    seqs = [0, 1, 2**63 - 1, 2**63, 2**64 - 1, int(rng.integers(0, 2**62))]
    seq = seqs[int(rng.integers(0, len(seqs)))]
    arrays = {f: rand_values(rng, c) for f, c in zip(flds, counts)}
    hdr = T['std_msgs/msg/Header'](stamp=T['builtin_interfaces/msg/Time'](sec=sec,
                                                                           nanosec=nsec),
                                   frame_id=frame_id)
    return T[type_name](header=hdr, sample_rate_hz=rate, seq=seq, **arrays)


def pack(rng, cdrs, with_gaps=True):
    """One buffer holding the messages at random (unaligned) offsets."""
    parts, starts, pos = [], [], 0
    for c in cdrs:
        gap = int(rng.integers(0, 9)) if with_gaps else 0
        parts.append(bytes(rng.integers(0, 256, gap, dtype=np.uint8)))
        pos += gap
        starts.append(pos)
        parts.append(c)
        pos += len(c)
    parts.append(bytes(rng.integers(0, 256, 5, dtype=np.uint8)))
    return b''.join(parts), np.array(starts), np.array([len(c) for c in cdrs])


def check_decoded(store, blocks, msgs, flds, sel_check=True, rng=None):
    assert len(blocks) == len(msgs)
    for i, msg in enumerate(msgs):
        st = msg.header.stamp
        assert int(blocks.stamp_ns[i]) == st.sec * NS + st.nanosec, i
        assert bits([blocks.rate_hz[i]])[0] == bits([msg.sample_rate_hz])[0], i
        assert int(blocks.seq[i]) == msg.seq, i
        assert blocks.frame_id(i) == msg.header.frame_id, i
        for f in flds:
            assert int(blocks.counts[f][i]) == len(getattr(msg, f)), (i, f)
    for f in flds:
        whole = blocks.values(f)
        ref = np.concatenate([np.asarray(getattr(m, f), dtype=np.float64) for m in msgs])
        assert whole.dtype == np.float64 and whole.shape == ref.shape
        np.testing.assert_array_equal(bits(whole), bits(ref))
        if sel_check and rng is not None and len(msgs):
            sel = np.sort(rng.choice(len(msgs), size=max(1, len(msgs) // 3), replace=False))
            part = blocks.values(f, sel)
            refp = np.concatenate([np.asarray(getattr(msgs[k], f), dtype=np.float64)
                                   for k in sel.tolist()])
            np.testing.assert_array_equal(bits(part), bits(refp))
            lo = int(rng.integers(0, len(msgs)))
            hi = int(rng.integers(lo, len(msgs) + 1))
            np.testing.assert_array_equal(bits(blocks.values(f, slice(lo, hi))),
                                          bits(blocks.values(f, np.arange(lo, hi))))


# --------------------------------------------------------------------------- 1. decode
@pytest.mark.parametrize('type_name', BLOCK_TYPES)
def test_decode_blocks_equals_rosbags(store, type_name):
    rng = np.random.default_rng(zlib.crc32(type_name.encode()))
    flds = fields_of(store, type_name)
    msgs = []
    for k in range(400):
        frame = rand_frame(rng, k % 17) if k < 34 else None  # every frame length 0..16 early
        msgs.append(rand_block(store, rng, type_name, frame_id=frame))
    # all fields empty, and unequal lengths across fields
    msgs.append(rand_block(store, rng, type_name, frame_id='', counts=[0] * len(flds)))
    msgs.append(rand_block(store, rng, type_name, frame_id='x',
                           counts=[3 + 5 * i for i in range(len(flds))]))
    msgs.append(rand_block(store, rng, type_name, frame_id='abcdefg',
                           counts=[0 if i % 2 else 9 for i in range(len(flds))]))
    cdrs = [store.serialize_cdr(m, type_name) for m in msgs]
    back = [store.deserialize_cdr(c, type_name) for c in cdrs]  # rosbags' own view
    # frame id byte lengths hit every alignment residue mod 8
    assert {len(m.header.frame_id.encode()) % 8 for m in msgs} == set(range(8))
    buf, starts, lengths = pack(rng, cdrs)
    assert set((starts % 8).tolist()) == set(range(8))
    for src in (buf, np.frombuffer(buf, np.uint8), bytearray(buf)):
        blocks = decode_blocks(src, starts, lengths, flds)
        check_decoded(store, blocks, back, flds, rng=rng)
    # also: back-to-back without gaps, and in a shuffled order
    buf2, st2, ln2 = pack(rng, cdrs, with_gaps=False)
    perm = rng.permutation(len(cdrs))
    blocks = decode_blocks(buf2, st2[perm], ln2[perm], flds)
    check_decoded(store, blocks, [back[i] for i in perm.tolist()], flds, rng=rng)
    # one message at a time (single-message batches)
    for i in range(0, len(cdrs), 37):
        b = decode_blocks(cdrs[i], [0], [len(cdrs[i])], flds)
        check_decoded(store, b, [back[i]], flds, sel_check=False)


@pytest.mark.parametrize('odd', [None, 'counts', 'frame', 'frame_text'])
def test_decode_blocks_uniform_layout(store, odd):
    """Messages of one layout (a recording's usual case) are decoded in one strided pass per
    field, also when chunk-like gaps break the stride; one message whose later counts differ
    at the same length (or whose frame_id length differs) sends the batch down the general path
    with the same result; a frame_id of the same length keeps the one pass."""
    rng = np.random.default_rng(11)
    flds = fields_of(store, ACCEL)
    msgs = [rand_block(store, rng, ACCEL, frame_id='accel', counts=[6, 6, 6])
            for _ in range(60)]
    if odd == 'counts':
        msgs[41] = rand_block(store, rng, ACCEL, frame_id='accel', counts=[6, 5, 7])
    elif odd:  # same message length either way (the frame_id is padded to 8 bytes)
        msgs[41] = rand_block(store, rng, ACCEL, frame_id='accelxy' if odd == 'frame'
                              else 'accek', counts=[6, 6, 6])
    cdrs = [store.serialize_cdr(m, ACCEL) for m in msgs]
    assert len({len(c) for c in cdrs}) == 1
    back = [store.deserialize_cdr(c, ACCEL) for c in cdrs]
    stride = len(cdrs[0]) + 31
    starts = np.arange(60) * stride + 3 + 977 * (np.arange(60) // 13)  # a gap every 13
    buf = np.zeros(int(starts[-1]) + stride, np.uint8)
    for a, c in zip(starts.tolist(), cdrs):
        buf[a:a + len(c)] = np.frombuffer(c, np.uint8)
    blocks = decode_blocks(buf, starts, np.full(60, len(cdrs[0])), flds)
    assert (blocks._runs is not None) == (odd in (None, 'frame_text'))
    check_decoded(store, blocks, back, flds, rng=rng)
    for lo, hi in ((0, 60), (12, 14), (13, 13), (5, 59), (26, 27)):
        for f in flds:
            np.testing.assert_array_equal(bits(blocks.values(f, slice(lo, hi))),
                                          bits(blocks.values(f, np.arange(lo, hi))))


def test_decode_blocks_empty_and_rejects(store):
    flds = fields_of(store, FORCE)
    b = decode_blocks(b'', np.zeros(0, np.int64), np.zeros(0, np.int64), flds)
    assert len(b) == 0 and b.values('moving_n').size == 0
    rng = np.random.default_rng(5)
    msg = rand_block(store, rng, FORCE, frame_id='abc', counts=[4, 2])
    cdr = bytes(store.serialize_cdr(msg, FORCE))
    with pytest.raises(FastPathError):  # wrong field list: length does not match
        decode_blocks(cdr, [0], [len(cdr)], ['moving_n'])
    with pytest.raises(FastPathError):  # truncated
        decode_blocks(cdr, [0], [len(cdr) - 8], flds)
    with pytest.raises(FastPathError):  # trailing bytes
        decode_blocks(cdr + b'\0' * 8, [0], [len(cdr) + 8], flds)
    be = store.serialize_cdr(msg, FORCE, little_endian=False) \
        if 'little_endian' in store.serialize_cdr.__code__.co_varnames else None
    if be is not None:
        with pytest.raises(FastPathError):
            decode_blocks(be, [0], [len(be)], flds)
    with pytest.raises(FastPathError):  # a count pointing past the end
        bad = bytearray(cdr)
        ok = decode_blocks(cdr, [0], [len(cdr)], flds)
        off = int(ok._starts['moving_n'][0]) + 4 * 8  # stationary_n count after 4 moving_n
        assert int.from_bytes(cdr[off:off + 4], 'little') == 2
        bad[off:off + 4] = (10**6).to_bytes(4, 'little')
        decode_blocks(bytes(bad), [0], [len(bad)], flds)


# --------------------------------------------------------------------------- 2. encode
@pytest.mark.parametrize('type_name', BLOCK_TYPES)
def test_encode_blocks_equals_serialize_cdr(store, type_name):
    rng = np.random.default_rng(1 + zlib.crc32(type_name.encode()))
    flds = fields_of(store, type_name)
    for flen in range(0, 18):
        frame = rand_frame(rng, flen) if flen % 3 else 'f' * flen
        m = int(rng.integers(1, 30))
        stamps = rng.integers(-2**31 * NS, 2**31 * NS - 1, m)
        stamps[0] = 0
        if m > 1:
            stamps[1] = -1  # sec -1, nanosec 999999999
        rates = rng.choice([50000.0, -0.0, np.nan, np.inf, 1e-300, 3.5], m)
        seqs = rng.integers(0, 2**63 - 1, m)
        counts = {f: rng.choice([0, 0, 1, 2, 5, 50], m) for f in flds}
        values = {f: rand_values(rng, int(counts[f].sum())) for f in flds}
        for scalar_rate in (False, True):
            rate_arg = float(rates[0]) if scalar_rate else rates
            buf, starts, lengths = encode_blocks(stamps, rate_arg, seqs, flds, counts, values,
                                                 frame)
            assert isinstance(buf, bytes) and len(buf) == int(lengths.sum())
            np.testing.assert_array_equal(starts, np.cumsum(lengths) - lengths)
            pos = {f: 0 for f in flds}
            for i in range(m):
                arrays = {}
                for f in flds:
                    c = int(counts[f][i])
                    arrays[f] = values[f][pos[f]:pos[f] + c]
                    pos[f] += c
                T = store.types
                s = int(stamps[i])
                hdr = T['std_msgs/msg/Header'](
                    stamp=T['builtin_interfaces/msg/Time'](sec=s // NS, nanosec=s % NS),
                    frame_id=frame)
                msg = T[type_name](header=hdr,
                                   sample_rate_hz=float(rate_arg if scalar_rate else rates[i]),
                                   seq=int(seqs[i]), **arrays)
                ref = store.serialize_cdr(msg, type_name)
                got = buf[int(starts[i]):int(starts[i] + lengths[i])]
                assert got == bytes(ref), (type_name, flen, i, scalar_rate)
            # and the round trip through decode_blocks
            blocks = decode_blocks(buf, starts, lengths, flds)
            np.testing.assert_array_equal(blocks.stamp_ns, stamps)
            for f in flds:
                np.testing.assert_array_equal(bits(blocks.values(f)), bits(values[f]))


@pytest.mark.parametrize('regular', [True, False])
def test_encode_blocks_into_a_given_buffer(store, regular):
    """out/starts (messages anywhere, in any order, in a buffer full of junk) and gap give
    the same message bytes as the plain call; block_lengths predicts the lengths."""
    from bag_tools.core.fastcdr import block_lengths
    rng = np.random.default_rng(21 + regular)
    flds = fields_of(store, FORCE)
    m = 300
    counts = {f: (np.full(m, 50) if regular else rng.choice([0, 1, 50], m)) for f in flds}
    values = {f: rand_values(rng, int(counts[f].sum())) for f in flds}
    args = (T0 + np.arange(m) * 1_000_000, 50000.0, np.arange(m), flds, counts, values, 'lc')
    ref, rst, rln = encode_blocks(*args)
    np.testing.assert_array_equal(block_lengths(flds, counts, 'lc'), rln)
    gapped, gst, gln = encode_blocks(*args, gap=31)
    assert [bytes(gapped[a:a + n]) for a, n in zip(gst, gln)] == \
        [ref[a:a + n] for a, n in zip(rst, rln)]
    order = rng.permutation(m) if not regular else np.arange(m)
    room = rln[order] + rng.integers(0, 9, m) * (not regular)
    pos = np.empty(m, np.int64)
    pos[order] = np.cumsum(room) - room + 5
    out = rng.integers(0, 256, int(room.sum()) + 5, dtype=np.uint8)
    buf, st, ln = encode_blocks(*args, out=out, starts=pos)
    assert buf is out
    assert [bytes(out[a:a + n]) for a, n in zip(pos, ln)] == [ref[a:a + n] for a, n in
                                                             zip(rst, rln)]
    with pytest.raises(FastPathError):
        encode_blocks(*args, out=out[:-9], starts=pos + 4)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.sampled_from([8, 8, 8, 16, 1700, -24, 0, 3]), max_size=60),
       st.lists(st.integers(0, 3), min_size=60, max_size=60), st.integers(0, 2))
def test_stride_runs_and_gathers_match_indexing(steps, counts, kind):
    """Runs cover every message once, each one stride and one count; gathers through them
    equal plain indexing for regular, irregular and overlapping layouts."""
    from bag_tools.core.fastcdr import gather_f64, gather_rows, gather_struct, row_field, stride_runs
    offs = 64 + np.cumsum([0] + steps[:-1]).astype(np.int64) if steps else np.zeros(0, np.int64)
    offs = offs - min(0, int(offs.min(initial=0))) + 64
    m = offs.size
    cnt = np.array(counts[:m], dtype=np.int64) if kind else np.full(m, 2, np.int64)
    runs = stride_runs(offs, cnt)
    covered = []
    for lo, hi, stride in runs:
        assert hi > lo and stride > 0
        assert (np.diff(offs[lo:hi]) == stride).all() and (cnt[lo:hi] == cnt[lo]).all()
        covered += range(lo, hi)
    assert covered == list(range(m))
    buf = np.random.default_rng(m).integers(0, 256, int(offs.max(initial=0)) + 64,
                                            dtype=np.uint8)
    want = [buf[o:o + 8].view('<f8')[0] for o in offs.tolist()]
    np.testing.assert_array_equal(bits(row_field(gather_rows(buf, offs, 8), 0, '<f8')),
                                  bits(want))
    vals = [buf[o:o + 8 * c].view('<f8') for o, c in zip(offs.tolist(), cnt.tolist())]
    ref = np.concatenate(vals) if vals else np.zeros(0)
    np.testing.assert_array_equal(bits(gather_f64(buf, offs, cnt)), bits(ref))
    rec = gather_struct(buf, offs, np.dtype({'names': ['a', 'b'], 'formats': ['<u2', '<f8'],
                                             'offsets': [1, 5], 'itemsize': 13}))
    assert rec['a'].tolist() == [int(buf[o + 1]) | int(buf[o + 2]) << 8 for o in offs.tolist()]
    np.testing.assert_array_equal(bits(rec['b']),
                                  bits([buf[o + 5:o + 13].view('<f8')[0] for o in offs.tolist()]))


def test_stride_runs_one_run_per_chunk():
    """Messages at one stride broken by a lone odd step (a chunk boundary) give one run per
    chunk, not an extra one-message run at each boundary."""
    from bag_tools.core.fastcdr import stride_runs
    offs = np.concatenate([5000 * c + 100 * np.arange(40) for c in range(6)])
    assert stride_runs(offs) == [(40 * c, 40 * c + 40, 100) for c in range(6)]
    assert stride_runs(np.array([0, 10, 20, 35, 50, 65])) == [(0, 3, 10), (3, 6, 15)]


@settings(max_examples=200, deadline=None)
@given(st.lists(st.integers(1, 900), min_size=1, max_size=40), st.integers(1, 400),
       st.lists(st.integers(0, 45), max_size=8))
def test_segments_cover_the_run_and_cut_at_pull_starts(sizes, seg, wanted):
    """Segments cover the blocks once, in order; each is at most 2 * SEGMENT_SAMPLES unless
    it is a single block; a wanted boundary is a cut unless it would leave a segment shorter
    than SEGMENT_SAMPLES (and it is never cut past)."""
    n = np.array(sizes, dtype=np.int64)
    ends = np.cumsum(n)
    m = n.size
    want = np.array(wanted, dtype=np.int64)
    cuts = segments(ends, 0, m, want, size=seg)
    assert cuts[0] == 0 and cuts[-1] == m and all(b > a for a, b in zip(cuts, cuts[1:]))
    size = [int(ends[b - 1] - (ends[a - 1] if a else 0)) for a, b in zip(cuts, cuts[1:])]
    assert all(s <= 2 * seg or b - a == 1 for s, a, b in zip(size, cuts, cuts[1:]))
    for c in set(wanted) & set(range(1, m)):
        if c not in cuts:  # skipped: too close to the cut before it
            before = max(x for x in cuts if x < c)
            assert ends[c - 1] - (ends[before - 1] if before else 0) < seg


def test_encode_blocks_absent_fields_and_errors(store):
    flds = fields_of(store, ACCEL)
    buf, st, ln = encode_blocks([T0, T0 + 1], 1000.0, [4, 5], flds,
                                {'axial_m_s2': np.array([2, 0])},
                                {'axial_m_s2': np.array([1.5, 2.5])}, 'acc')
    for i, (_n, vals) in enumerate(((2, [1.5, 2.5]), (0, []))):
        msg = store.deserialize_cdr(buf[st[i]:st[i] + ln[i]], ACCEL)
        assert list(msg.axial_m_s2) == vals and len(msg.lateral_m_s2) == 0
        assert msg.seq == 4 + i and msg.header.frame_id == 'acc'
    with pytest.raises(FastPathError):  # value count disagrees with counts
        encode_blocks([T0], 1000.0, [0], flds, {'axial_m_s2': [3]},
                      {'axial_m_s2': np.ones(2)})
    with pytest.raises(FastPathError):
        encode_blocks([T0], 1000.0, [-1], flds, {}, {})
    with pytest.raises(FastPathError):
        encode_blocks([2**31 * NS], 1000.0, [0], flds, {}, {})
    empty = encode_blocks(np.zeros(0, np.int64), 1000.0, np.zeros(0, np.int64), flds, {}, {})
    assert empty[0] == b'' and empty[1].size == 0


def _refuses_seq(store, seqs):
    """The fast path's seq is int64: a seq the int64 cannot hold raises FastPathError (the caller then
    takes the generic path, which writes the uint64), never a wrong number."""
    with pytest.raises(FastPathError):
        encode_blocks([T0], 1.0, seqs, fields_of(store, FORCE), {}, {})


def test_encode_blocks_large_seq_uint64_array(store):
    """seq is uint64 in the message: seq >= 2**63 from a uint64 array is refused, not wrapped negative."""
    _refuses_seq(store, np.array([2**63 + 5], dtype=np.uint64))


def test_encode_blocks_large_seq_python_int(store):
    _refuses_seq(store, [2**63])


def test_encode_blocks_largest_int64_seq(store):
    """The largest seq the fast path takes encodes right."""
    buf, _st, _ln = encode_blocks([T0], 1.0, [2**63 - 1], fields_of(store, FORCE), {}, {})
    assert store.deserialize_cdr(buf, FORCE).seq == 2**63 - 1


# --------------------------------------------------------------------------- bags
def block_bytes(store, rng, type_name, stamp, seq, n):
    flds = fields_of(store, type_name)
    msg = rand_block(store, rng, type_name, frame_id=rand_frame(rng, int(rng.integers(0, 9))),
                     stamp_ns=stamp, counts=[n] * len(flds))
    msg.seq = seq
    return store.serialize_cdr(msg, type_name)


def mixed_messages(store, rng, big=True):
    """(topic, type, log_ns, cdr): several topics, ties in log time, log time going back,
    some large messages so the bag has several chunks."""
    topics = [('/force', FORCE), ('/accel', ACCEL), ('/enc', 'force_tester_msgs/msg/EncoderBlock'),
              ('/motor', 'force_tester_msgs/msg/MotorBlock')]
    out = []
    log = T0
    for k in range(600):
        topic, typ = topics[int(rng.integers(0, len(topics)))]
        r = rng.random()
        if r < 0.3:
            pass  # same log time as the previous message (tie)
        elif r < 0.4:
            log -= int(rng.integers(1, 5_000_000))  # written out of log order
        else:
            log += int(rng.integers(1, 5_000_000))
        n = int(rng.integers(0, 60))
        if big and k % 40 == 7:
            n = 40_000  # ~ 0.3-1 MB per message
        out.append((topic, typ, log, block_bytes(store, rng, typ, log, k, n)))
    return out


def write_plain(path, store, msgs, topics_order=None):
    with BagWriter(path, store) as w:
        for topic, typ, _, _ in (topics_order or msgs):
            w.add_topic(topic, typ)
        for topic, _, log, cdr in msgs:
            w.write(topic, log, cdr)
    return path


def generic(path, topics=None):
    with open_bag(path) as b:
        return [(m.topic, m.type_name, m.stamp_ns, m.cdr) for m in b.messages(topics)]


def single_mcap(path):
    with open_bag(path) as b:
        p = b.single_mcap_path()
    assert p is not None and p.suffix == '.mcap'
    return p


# --------------------------------------------------------------------------- 3. read_topics_raw
def test_read_topics_raw_equals_generic_reader(store, tmp_path):
    rng = np.random.default_rng(3)
    msgs = mixed_messages(store, rng)
    bag = write_plain(tmp_path / 'bag', store, msgs)
    mcap = single_mcap(bag)
    with open_bag(bag) as b:
        n_chunks = len(b._reader.storage.storages[0].chunks) \
            if hasattr(getattr(b._reader, 'storage', None), 'storages') else None
    if n_chunks is not None:
        assert n_chunks > 2
    for wanted in (['/force'], ['/accel', '/force'], ['/motor', '/enc', '/force', '/accel'],
                   ['/nope', '/enc']):
        raw, names = read_topics_raw(mcap, wanted)
        assert names == wanted
        got = [(wanted[int(raw.channel[i])], int(raw.log_ns[i]), raw.data(i))
               for i in range(raw.log_ns.size)]
        present = [t for t in wanted if t != '/nope']
        ref = [(t, s, c) for t, _ty, s, c in generic(bag, present)]
        assert got == ref, wanted
        # per topic as well
        for _j, t in enumerate(present):
            sel = np.flatnonzero(raw.channel == wanted.index(t))
            assert [(int(raw.log_ns[i]), raw.data(i)) for i in sel.tolist()] == \
                [(s, c) for _t, _ty, s, c in generic(bag, [t])]
    raw, _ = read_topics_raw(mcap, ['/nope'])
    assert raw.log_ns.size == 0


def test_read_topics_raw_small_bag_and_decode(store, tmp_path):
    rng = np.random.default_rng(4)
    msgs = [('/force', FORCE, T0 + k // 2, block_bytes(store, rng, FORCE, T0 + k, k, k % 5))
            for k in range(50)]
    bag = write_plain(tmp_path / 'bag', store, msgs)
    raw, _ = read_topics_raw(single_mcap(bag), ['/force'])
    blocks = decode_blocks(raw.buf, raw.starts, raw.lengths, fields_of(store, FORCE))
    ref = [store.deserialize_cdr(c, FORCE) for _t, _ty, _s, c in generic(bag, ['/force'])]
    check_decoded(store, blocks, ref, fields_of(store, FORCE), rng=rng)


# --------------------------------------------------------------------------- 4. ExtendedBag
def _meta_counts(path):
    with open_bag(path) as b:
        return b.topics(), b.start_ns, b.end_ns, b.message_count


def _mcap_lib_messages(path):
    """(topic, log, data) in log-time order by Foxglove's reader (an independent MCAP
    implementation), and its summary."""
    from mcap.reader import make_reader
    with open(path, 'rb') as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        msgs = [(ch.topic, m.log_time, bytes(m.data))
                for _s, ch, m in reader.iter_messages(log_time_order=True)]
    return msgs, summary


def test_extended_bag_is_input_plus_new_topics(store, tmp_path):
    """ExtendedBag(src) + new messages (some out of log order, spanning many chunks) reads
    back, with rosbags and with the mcap library, as the input's messages merged in log order
    with the new ones; metadata.yaml and the MCAP statistics agree."""
    rng = np.random.default_rng(11)
    msgs = mixed_messages(store, rng)
    src = write_plain(tmp_path / 'src', store, msgs)
    src_bytes = single_mcap(src).read_bytes()
    new = []
    for k in range(400):
        lg = T0 + int(rng.integers(-10_000_000, 600 * 5_000_000))
        n = 20_000 if k % 50 == 3 else int(rng.integers(0, 40))
        new.append(('/corr' if k % 3 else '/score', FORCE if k % 3 else ACCEL, lg,
                    block_bytes(store, rng, FORCE if k % 3 else ACCEL, lg, k, n)))
    target = ExtendedBag(McapBag(src), tmp_path / 'out')
    with target as out:
        cids = {t: out.add_topic(t, ty, store.generate_msgdef(ty, ros_version=2)[0],
                                 store.hash_rihs01(ty)) for t, ty in (('/corr', FORCE),
                                                                      ('/score', ACCEL))}
        half = len(new) // 2
        for part in (sorted(new[:half], key=lambda m: m[2]), new[half:]):  # 2nd: unsorted
            out.write_messages([cids[t] for t, *_ in part], [m[2] for m in part],
                               [m[3] for m in part])
    mcap_out = single_mcap(tmp_path / 'out')
    assert mcap_out.read_bytes()[:target.copy_end] == src_bytes[:target.copy_end]
    got = generic(tmp_path / 'out')
    want = generic(src) + [(t, ty, lg, c) for t, ty, lg, c in new]
    assert sorted(got, key=lambda m: (m[0], m[2], m[3])) == \
        sorted(want, key=lambda m: (m[0], m[2], m[3]))
    assert [m[2] for m in got] == sorted(m[2] for m in got)  # merged in log order
    lib, summary = _mcap_lib_messages(mcap_out)
    # the same messages (ties in log time may come in another order) ...
    assert sorted(lib) == sorted((t, lg, c) for t, _ty, lg, c in got)
    assert [m[1] for m in lib] == sorted(m[1] for m in lib)  # ... in log order
    assert summary.statistics.message_count == len(want)
    assert len(summary.chunk_indexes) > len(McapBag(src).summary.chunks) + 2
    topics, start, end, count = _meta_counts(tmp_path / 'out')
    assert count == len(want) and start == min(m[2] for m in want) \
        and end == max(m[2] for m in want)
    for t in ('/corr', '/score', '/force', '/motor'):
        assert topics[t].count == sum(m[0] == t for m in want)
    again = McapBag(tmp_path / 'out')  # the output suits the fast paths itself
    assert again.hashes['/corr'] == store.hash_rihs01(FORCE)
    # metadata.yaml holds the MCAP's rosbag2 metadata record under its root key
    import yaml
    from mcap.reader import make_reader
    with open(mcap_out, 'rb') as f:
        (record,) = [m for m in make_reader(f).iter_metadata() if m.name == 'rosbag2']
    info = yaml.safe_load(record.metadata['serialized_metadata'])
    assert info['message_count'] == count
    assert yaml.safe_load((tmp_path / 'out' / 'metadata.yaml').read_text()) == {
        'rosbag2_bagfile_information': info}


def test_extended_bag_leaves_nothing_on_error(store, tmp_path):
    rng = np.random.default_rng(12)
    src = write_plain(tmp_path / 'src', store, mixed_messages(store, rng, big=False)[:50])
    with pytest.raises(RuntimeError):
        with ExtendedBag(McapBag(src), tmp_path / 'out') as out:
            out.add_topic('/x', FORCE, store.generate_msgdef(FORCE, ros_version=2)[0], 'h')
            raise RuntimeError('stop')
    assert not (tmp_path / 'out').exists()
    with pytest.raises(BagError, match='log times >= 0'):
        with ExtendedBag(McapBag(src), tmp_path / 'out') as out:
            cid = out.add_topic('/x', FORCE, store.generate_msgdef(FORCE, ros_version=2)[0],
                                'h')
            out.write_messages([cid, cid], [T0, -1], [b'\0\1\0\0', b'\0\1\0\0'])
    assert not (tmp_path / 'out').exists()
    with pytest.raises(BagError, match='exists already'):
        ExtendedBag(McapBag(src), src)


@pytest.mark.parametrize('fails', [False, True])
def test_a_commit_fill_runs_before_the_write_and_its_error_removes_the_bag(store, tmp_path, fails):
    rng = np.random.default_rng(14)
    src = write_plain(tmp_path / 'src', store, mixed_messages(store, rng, big=False)[:50])
    cdr = block_bytes(store, rng, FORCE, T0, 1, 8)
    out = tmp_path / 'out'
    with pytest.raises(BagError, match='encoding failed') if fails else contextlib.nullcontext():
        with ExtendedBag(McapBag(src), out) as bag:
            cid = bag.add_topic('/corr', FORCE, store.generate_msgdef(FORCE, ros_version=2)[0],
                                store.hash_rihs01(FORCE))
            buf, starts = bag.reserve([cid], [len(cdr)], [T0 + 5])
            buf[starts[0]:starts[0] + len(cdr)] = 0

            def fill():   # the data, filled in by the writer thread
                if fails:
                    raise BagError('encoding failed')
                buf[starts[0]:starts[0] + len(cdr)] = np.frombuffer(cdr, np.uint8)
            bag.commit(fill)
    if fails:
        assert not out.exists()
    else:
        assert [(t, c) for t, _ty, _lg, c in generic(out) if t == '/corr'] == [('/corr', cdr)]


def test_a_bag_mapped_ahead_is_the_file_and_a_failed_map_is_a_fast_path_error(store, tmp_path):
    rng = np.random.default_rng(13)
    src = write_plain(tmp_path / 'src', store, mixed_messages(store, rng, big=False)[:50])
    bag = McapBag(src)
    bag.map_ahead()
    bag.map_ahead()   # a second call while the first maps: one mapping
    assert bag.mm[:] == bag.mcap.read_bytes()
    assert bag.mm is bag.mm
    for ahead in (True, False):   # the file gone after the summary was read: the fast path does not apply
        gone = McapBag(src)
        gone.mcap = tmp_path / 'gone.mcap'
        if ahead:
            gone.map_ahead()
        with pytest.raises(FastPathError, match='cannot map .*gone.mcap'):
            assert gone.mm is None   # not reached: mm raises


@pytest.mark.parametrize('damage', ['no_metadata', 'version_8', 'two_files', 'no_summary'])
def test_mcap_bag_refuses_what_it_cannot_copy(store, tmp_path, damage):
    rng = np.random.default_rng(13)
    src = write_plain(tmp_path / 'src', store, mixed_messages(store, rng, big=False)[:50])
    meta = src / 'metadata.yaml'
    if damage == 'no_metadata':
        meta.unlink()
    elif damage in ('version_8', 'two_files'):
        text = meta.read_text()
        text = text.replace('version: 9', 'version: 8') if damage == 'version_8' else \
            text.replace('relative_file_paths:\n', 'relative_file_paths:\n  - other.mcap\n')
        meta.write_text(text)
    else:  # footer without a summary offset, as an unindexed recording
        mcap = single_mcap(src)
        data = bytearray(mcap.read_bytes())
        data[-37 + 9:-37 + 17] = bytes(8)
        mcap.write_bytes(bytes(data))
    with pytest.raises(FastPathError):
        McapBag(src)


# --------------------------------------------------------------------------- 5. offline correct
RATE = 50000.0
N = 600
BLOCK = 10  # 60 blocks per pull, 120 contiguous (pulls 0 and 1): more than max_pending


def synth(seed, peak):
    rng = np.random.default_rng(seed)
    t = np.arange(N) / RATE
    tc = t[N // 2]
    pulse = peak * np.exp(-((t - tc) / 2e-3) ** 2) * (t < tc + 1e-3)
    accel = 50 * np.sin(2 * np.pi * 900 * t) * np.exp(-t / 0.01) + rng.normal(0, 0.5, N)
    return {'time_s': t, 'encoder_position_m': 1.2 * t,
            'accel_axial_m_s2': accel,
            'force_moving_n': pulse + 1.152 * accel + rng.normal(0, 0.3, N),
            'force_stationary_n': pulse + rng.normal(0, 0.3, N),
            'accel_lateral_m_s2': rng.normal(0, 1, N), 'accel_vertical_m_s2': rng.normal(0, 1, N)}


@pytest.fixture(scope='module')
def base_bag(tmp_path_factory):
    d = tmp_path_factory.mktemp('campaign')
    pulls = []
    for i in range(4):
        m = {'set': 1 + i % 2, 'coupon_lbf': 200.0, 'velocity_fps': 3.0, 'decel_g': 0.0,
             'pull_id': 100 + i, 'start_ns': T0 + i * (N * 20_000 + 5_000_000)}
        pulls.append((m, synth(i, 1000.0 * (i + 1))))
    pulls[1][0]['start_ns'] = T0 + N * 20_000  # pulls 0 and 1 contiguous
    camp = write_campaign(d / 'camp', pulls)
    return campaign_to_bag(camp, d / 'bag', block_size=BLOCK)


def rewrite(src, dst, edit):
    """Copy a bag through edit([(topic, type, log, cdr)]) -> new list."""
    with open_bag(src) as b:
        topics = b.topics()
        msgs = [(m.topic, m.type_name, m.stamp_ns, m.cdr) for m in b.messages()]
    msgs = edit(msgs)
    with BagWriter(dst, make_typestore([MSG_DIR])) as w:
        for t, info in topics.items():
            w.add_topic(t, info.type_name)
        for topic, _ty, log, cdr in msgs:
            w.write(topic, log, cdr)
    return dst


def idx_of(msgs, topic, k):
    return [i for i, m in enumerate(msgs) if m[0] == topic][k]


def drop(topic, k):
    def edit(msgs):
        i = idx_of(msgs, topic, k)
        return msgs[:i] + msgs[i + 1:]
    return edit


def swap_log(topic, k):
    """Blocks k and k+1 of topic exchange log times: k+1 is read first (out of order)."""
    def edit(msgs):
        i, j = idx_of(msgs, topic, k), idx_of(msgs, topic, k + 1)
        msgs = list(msgs)
        a, b = msgs[i], msgs[j]
        msgs[i] = (a[0], a[1], b[2] + 1, a[3])
        msgs[j] = (b[0], b[1], a[2], b[3])
        return msgs
    return edit


def delay(topic, blocks, dt_ns=BLOCK * 20_000):
    """Log every block of topic `blocks` block periods later (partners wait in the aligner)."""
    def edit(msgs):
        return [(t, ty, log + blocks * dt_ns if t == topic else log, c)
                for t, ty, log, c in msgs]
    return edit


def renumber_after_drop_both(k):
    """Remove /force and /accel block k and renumber later seqs: a stamp gap without a seq gap
    (a discontinuity the fast path handles itself)."""
    store = make_typestore([MSG_DIR])

    def edit(msgs):
        out = []
        seen = {'/force': 0, '/accel': 0}
        for t, ty, log, c in msgs:
            if t in seen:
                j = seen[t]
                seen[t] += 1
                if j == k:
                    continue
                if j > k:
                    m = store.deserialize_cdr(c, ty)
                    m.seq = m.seq - 1
                    c = bytes(store.serialize_cdr(m, ty))
            out.append((t, ty, log, c))
        return out
    return edit


def bag_dump(path):
    out = {}
    with open_bag(path) as b:
        store = b.typestore
        for m in b.messages():
            out.setdefault(m.topic, []).append((m.stamp_ns, store.deserialize_cdr(m.cdr,
                                                                                  m.type_name)))
    return out


def _msg_close(a, b, tol):
    fa = [f for f in a.__dataclass_fields__ if not f.startswith('_')]
    for f in fa:
        x, y = getattr(a, f), getattr(b, f)
        if hasattr(x, '__dataclass_fields__'):
            _msg_close(x, y, tol)
        elif isinstance(x, np.ndarray) or isinstance(x, float):
            np.testing.assert_allclose(np.asarray(x, float), np.asarray(y, float), rtol=0,
                                       atol=tol, equal_nan=True, err_msg=f)
        else:
            assert x == y, f


PENDING = 50  # a small max_pending, so a late block in a short bag can exceed it


def _run(src, dst, mode):
    """correct() by one path ('auto': fast where it applies; 'fast_read': the fast reader and the
    generic writer; 'generic'); returns (result as a dict, 1 if the fast reader was used)."""
    res = correct(src, dst, CorrectionSetup(max_pending=PENDING), path=mode)
    return res.as_dict(), int(res.path == 'fast')


CASES = {
    'clean': (None, True),
    'drop_force': (drop('/force', 15), False),
    'drop_accel': (drop('/accel', 20), False),   # the /force block 20 is unmatched
    'drop_force_first': (drop('/force', 0), False),
    'drop_last_accel': (drop('/accel', -1), False),
    'out_of_order_force': (swap_log('/force', 30), False),
    'out_of_order_accel': (swap_log('/accel', 3), False),
    'accel_late_40': (delay('/accel', PENDING - 10), True),   # < max_pending: still paired
    'accel_late_50': (delay('/accel', PENDING), True),   # = max_pending: still paired
    'accel_late_51': (delay('/accel', PENDING + 1), False),  # > max_pending: unmatched
    'force_late_55': (delay('/force', 55), False),
    'gap_without_seq_gap': (renumber_after_drop_both(17), True),
}


@pytest.mark.parametrize('case', sorted(CASES))
def test_correct_fast_equals_generic(base_bag, tmp_path, case):
    edit, fast_expected = CASES[case]
    src = base_bag if edit is None else rewrite(base_bag, tmp_path / 'src', edit)
    fast, used = _run(src, tmp_path / 'fast', 'auto')
    gen, gused = _run(src, tmp_path / 'gen', 'generic')
    assert gused == 0
    assert fast['runs'] == gen['runs'] and fast['nan_samples'] == gen['nan_samples']
    assert len(fast['pulls']) == len(gen['pulls']) > 0
    for p, q in zip(fast['pulls'], gen['pulls']):
        assert p.keys() == q.keys()
        for k in p:
            if isinstance(p[k], float):
                assert abs(p[k] - q[k]) <= 1e-9 or (np.isnan(p[k]) and np.isnan(q[k])), (k, p, q)
            else:
                assert p[k] == q[k], (k, p, q)
    assert len(fast['sets']) == len(gen['sets'])
    for s, t in zip(fast['sets'], gen['sets']):
        for k in s:
            if isinstance(s[k], float):
                assert abs(s[k] - t[k]) <= 1e-9 or (np.isnan(s[k]) and np.isnan(t[k])), k
            else:
                assert s[k] == t[k], k
    assert fast['warnings'] == gen['warnings']
    # the output bags: same topics, log times and messages
    a, b = bag_dump(tmp_path / 'fast'), bag_dump(tmp_path / 'gen')
    assert sorted(a) == sorted(b)
    for t in a:
        assert [s for s, _ in a[t]] == [s for s, _ in b[t]], t
        for (_, x), (_, y) in zip(a[t], b[t]):
            _msg_close(x, y, 1e-9)
    # last, so a wrong result is reported before a wrong choice of path
    assert used == int(fast_expected), f'fast path taken: {used}'


@pytest.mark.parametrize('case', ['clean', 'gap_without_seq_gap'])
def test_correct_write_fast_equals_encode_path(base_bag, tmp_path, case):
    """The extended copy (ExtendedBag) vs the generic writer (both after the fast read):
    identical output messages and log times."""
    edit, _ = CASES[case]
    src = base_bag if edit is None else rewrite(base_bag, tmp_path / 'src', edit)
    r1, u1 = _run(src, tmp_path / 'a', 'fast')
    r2, u2 = _run(src, tmp_path / 'b', 'fast_read')
    assert u1 == u2 == 1
    assert r1 == r2
    assert generic(tmp_path / 'a') == generic(tmp_path / 'b')


def test_correct_fast_path_segments_and_extension(base_bag, tmp_path):
    """The fast path cuts runs into segments (prefilter and correction state carried across):
    tiny segments that split blocks' runs anywhere give the generic path's numbers, with and
    without an extension, and the same output bag."""
    ext = tmp_path / 'extension.yaml'
    ext.write_text('correction:\n  mass_kg: 1.2\n  moving_cell_gain: 1.01\n'
                   '  accel_delay_s: 3.0e-5\n  ac_coupling_time_constant_s: 2.0\n'
                   '  mains_hum_hz: 60.0\n')
    for extension in (None, ext):
        out = {}
        for mode, seg in (('generic', None), ('fast', 37), ('fast', 10**9)):
            setup = CorrectionSetup.build(extension_file=extension)
            if seg is not None:
                setup = replace(setup, segment_samples=seg)
            dst = tmp_path / f'{mode}-{seg}-{extension is not None}'
            res = correct(base_bag, dst, setup, path=mode)
            out[(mode, seg)] = (res.as_dict(), generic(dst))
        (ref, ref_bag), *others = out.values()
        assert ref['pulls'] and ref['runs'] >= 2
        for res, bag in others:
            assert res['runs'] == ref['runs'] and res['warnings'] == ref['warnings']
            for p, q in zip(res['pulls'], ref['pulls']):
                for k in p:
                    assert p[k] == q[k] or abs(p[k] - q[k]) <= 1e-9, (k, p[k], q[k])
            assert [(t, lg) for t, _ty, lg, _c in bag] == [(t, lg) for t, _ty, lg, _c in ref_bag]
            assert bag == ref_bag  # bit for bit, incl. the corrected blocks


@settings(max_examples=200, deadline=None)
@given(st.lists(st.integers(0, 5_000_000), min_size=1, max_size=30), st.integers(1, 60),
       st.sampled_from([50_000.0, 1000.0, 48_000.0, 3.0, 44_100.0, 12_345.6]),
       st.lists(st.integers(-2_000_000, 200_000_000), max_size=20))
def test_block_stamps_equal_the_sample_array(gaps, n, rate, probes):
    """BlockStamps (what the fast path hands the scorer) answers size, t[i], max() and
    searchsorted exactly as the per-sample stamp array would, for any rate."""
    span = int(np.ceil(n * 1e9 / rate))
    stamps = T0 + np.cumsum(np.array(gaps, dtype=np.int64) + span)
    m = stamps.size
    t = block_sample_stamps(stamps, np.full(m, n), np.full(m, rate))
    ref = np.concatenate([sample_stamps_ns(np.full(n, s), np.arange(n), np.full(n, rate))
                          for s in stamps.tolist()])
    assert isinstance(t, BlockStamps)
    np.testing.assert_array_equal(t.array(), ref)
    assert t.size == ref.size and t[-1] == ref[-1] == t.max() and t[0] == ref[0]
    v = np.concatenate([T0 + np.array(probes, dtype=np.int64), ref[::7], ref[::11] + 1])
    np.testing.assert_array_equal(t.searchsorted(v), np.searchsorted(ref, v))


@settings(max_examples=60, deadline=None)
@given(st.lists(st.integers(1, 400), min_size=1, max_size=12), st.integers(0, 2**31))
def test_scorer_fed_in_pieces_equals_one_pass(cuts, seed):
    """PullScorer fed a recording in arbitrary pieces scores every window (overlapping, empty,
    beyond the data, unscorable) exactly as when fed the whole recording at once."""
    rng = np.random.default_rng(seed)
    n = 1500
    t = T0 + np.arange(n, dtype=np.int64) * 20_000
    stat = np.abs(rng.normal(0, 1, n)) * (rng.random() < 0.9)  # sometimes all zero: unscorable
    seg = {'t': t, 'stationary': stat, 'raw': rng.normal(0, 1, n),
           'corrected': rng.normal(0, 1, n), 'filtered': rng.normal(0, 1, n)}
    windows = []
    for k in range(8):
        a = int(rng.integers(-100, n + 100))
        b = a + int(rng.integers(0, 700))
        windows.append((T0 + a * 20_000, T0 + b * 20_000, 1 + k % 3, k))
    windows.sort()
    drops = [int(T0 + rng.integers(0, n) * 20_000) for _ in range(5)]
    whole = PullScorer(windows, drops, 0.1)
    whole.add(seg)
    ref = whole.finish()
    pieces = PullScorer(windows, drops, 0.1)
    bounds = sorted({0, n, *[c % n for c in np.cumsum(cuts).tolist()]})
    for a, b in zip(bounds[:-1], bounds[1:]):
        pieces.add({k: v[a:b] for k, v in seg.items()})
    got = pieces.finish()
    assert [p.as_dict() for p in got[0]] == [p.as_dict() for p in ref[0]] and got[2] == ref[2]
    assert got[1].sets() == ref[1].sets()
