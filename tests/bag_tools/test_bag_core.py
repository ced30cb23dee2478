"""Tests of the ROS-free bag_tools core (rosbags-based rosbag2 MCAP bags)."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest
import yaml
from bag_msgs import MSG_DIR, bag_typestore, force, header

from bag_tools.core import BagError, BagWriter, bag_info, find_msg_dirs, format_info, make_typestore, open_bag, schedule

T0 = 1_700_000_000_000_000_000
FORCE = 'force_tester_msgs/msg/ForceBlock'
ACCEL = 'force_tester_msgs/msg/AccelBlock'
PULL = 'force_tester_msgs/msg/PullEvent'


@pytest.fixture(scope='module')
def store():
    return bag_typestore()


def accel(store, ns, seq, n=5):
    msg = store.types[ACCEL](header=header(store, ns), sample_rate_hz=2000.0, seq=seq,
                             axial_m_s2=np.ones(n), lateral_m_s2=np.zeros(n),
                             vertical_m_s2=np.zeros(n))
    return store.serialize_cdr(msg, ACCEL)


def pull(store, ns, event, pull_id, test_set):
    msg = store.types[PULL](header=header(store, ns), event=event, pull_id=pull_id,
                            test_set=test_set, coupon_break_n=5000.0, velocity_m_s=2.0,
                            decel_m_s2=-30.0)
    return store.serialize_cdr(msg, PULL)


def sample_messages(store):
    """(topic, type, stamp, cdr) with a seq gap on /force (seq 3 missing)."""
    out = []
    for seq in [0, 1, 2, 4, 5]:
        out.append(('/force', FORCE, T0 + seq * 5_000_000, force(store, T0, seq)))
    for seq in range(4):
        out.append(('/accel', ACCEL, T0 + seq * 2_500_000 + 1, accel(store, T0, seq)))
    out.append(('/pull_event', PULL, T0 + 3_000_000, pull(store, T0, 0, 7, 2)))
    out.append(('/pull_event', PULL, T0 + 9_000_000, pull(store, T0, 1, 7, 2)))
    out.append(('/pull_event', PULL, T0 + 12_000_000, pull(store, T0, 0, 8, 4)))
    return out


def write_bag(path, store, msgs):
    with BagWriter(path, store) as w:
        for topic, typ, _, _ in msgs:
            w.add_topic(topic, typ)
        for topic, _, stamp, cdr in msgs:
            w.write(topic, stamp, cdr)
    return path


@pytest.fixture()
def bag(tmp_path, store):
    msgs = sample_messages(store)
    return write_bag(tmp_path / 'bag', store, msgs), msgs


def assert_one_line(err, path):
    text = str(err.value)
    assert '\n' not in text
    assert str(path) in text


# -- typestore -----------------------------------------------------------------------------
def test_find_msg_dirs_env_and_fallback(tmp_path):
    prefix = tmp_path / 'install' / 'force_tester_msgs'
    (prefix / 'share' / 'force_tester_msgs' / 'msg').mkdir(parents=True)
    dirs = find_msg_dirs({'AMENT_PREFIX_PATH': f'/nonexistent:{prefix}'})
    assert dirs == [prefix / 'share' / 'force_tester_msgs' / 'msg']
    assert find_msg_dirs({}) == [MSG_DIR]


def test_make_typestore_errors(tmp_path, store):
    assert FORCE in store.types and 'std_msgs/msg/Header' in store.types
    with pytest.raises(BagError) as err:
        make_typestore([tmp_path / 'nope'])
    assert_one_line(err, tmp_path / 'nope')


# -- writer / reader round trip ----------------------------------------------------------------
def test_round_trip_bytes_and_stamps(bag, store):
    path, msgs = bag
    with open_bag(path) as b:
        got = list(b.messages())
        assert b.topics() == {'/force': (FORCE, 5), '/accel': (ACCEL, 4),
                              '/pull_event': (PULL, 3)}
        assert b.start_ns == T0 and b.end_ns == T0 + 25_000_000
        assert b.duration_ns == 25_000_000
        # deserialisation with the definitions embedded in the bag (no msg dirs needed)
        m = b.deserialize(got[0].cdr, got[0].type_name)
        assert m.seq == 0 and m.header.frame_id == 'tester'
        with pytest.raises(BagError):
            b.deserialize(b'\x00\x01\x00\x00', 'nope_msgs/msg/Nope')
        # filters
        only = list(b.messages(['/pull_event'], start_ns=T0 + 4_000_000, end_ns=T0 + 12_000_000))
        assert [x.stamp_ns for x in only] == [T0 + 9_000_000]
        with pytest.raises(BagError) as err:
            list(b.messages(['/missing']))
        assert "'/missing'" in str(err.value) and '\n' not in str(err.value)
    stamps = [x.stamp_ns for x in got]
    assert stamps == sorted(stamps)
    expected = sorted((s, t, typ, c) for t, typ, s, c in msgs)
    assert sorted((x.stamp_ns, x.topic, x.type_name, x.cdr) for x in got) == expected


def test_metadata_yaml(bag):
    path, _ = bag
    meta = yaml.safe_load((path / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert meta['storage_identifier'] == 'mcap'
    assert meta['version'] == 9
    assert meta['message_count'] == 12
    assert isinstance(meta['custom_data'], dict)  # not null: yaml-cpp wants a map
    topics = {t['topic_metadata']['name']: t for t in meta['topics_with_message_count']}
    assert topics['/force']['topic_metadata']['type'] == FORCE
    assert topics['/force']['message_count'] == 5
    assert topics['/force']['topic_metadata']['serialization_format'] == 'cdr'
    assert topics['/force']['topic_metadata']['type_description_hash'].startswith('RIHS01_')
    assert topics['/pull_event']['topic_metadata']['type'] == PULL
    files = meta['relative_file_paths']
    assert len(files) == 1 and files[0].endswith('.mcap') and (path / files[0]).is_file()


def _raw_mcap_schemas(file: Path) -> dict[str, tuple[str, str]]:
    """Independent minimal MCAP parse: footer -> summary section -> Schema (0x03) records."""
    data = file.read_bytes()
    magic = b'\x89MCAP0\r\n'
    assert data[:8] == magic and data[-8:] == magic
    footer = data[-8 - 29:-8]
    assert footer[0] == 0x02
    summary_start, = struct.unpack_from('<Q', footer, 9)
    pos, end = summary_start, len(data) - 8 - 29
    out = {}
    while pos < end:
        op = data[pos]
        length, = struct.unpack_from('<Q', data, pos + 1)
        body = data[pos + 9:pos + 9 + length]
        if op == 0x03:
            off = 2
            fields = []
            for _ in range(3):
                n, = struct.unpack_from('<I', body, off)
                fields.append(body[off + 4:off + 4 + n].decode())
                off += 4 + n
            out[fields[0]] = (fields[1], fields[2])
        pos += 9 + length
    return out


def test_mcap_schemas_embed_full_definitions(bag):
    path, _ = bag
    mcap = next(path.glob('*.mcap'))
    # 1. independent raw parse of the schema records
    schemas = _raw_mcap_schemas(mcap)
    assert set(schemas) == {FORCE, ACCEL, PULL}
    enc, text = schemas[FORCE]
    assert enc == 'ros2msg'
    assert 'float64[] moving_n' in text and 'uint64 seq' in text
    sep = '=' * 80
    assert f'{sep}\nMSG: std_msgs/Header\n' in text
    assert f'{sep}\nMSG: builtin_interfaces/Time\n' in text
    assert 'builtin_interfaces/Time stamp' in text
    assert 'uint8 START=0' in schemas[PULL][1]
    # 2. rosbags' own MCAP reader sees the same, with the ros2 profile
    from rosbags.rosbag2.storage_mcap import McapReader
    r = McapReader(mcap)
    r.open()
    try:
        by_name = {s.name: s for s in r.schemas.values()}
        assert by_name[FORCE].encoding == 'ros2msg' and by_name[FORCE].data == text
        assert {c.topic: c.msgtype for c in r.connections}['/force'] == FORCE
    finally:
        r.close()
    assert mcap.read_bytes()[9 + 8:9 + 8 + 8] == b'\x04\x00\x00\x00ros2'


def test_info_counts_gaps_pulls(bag):
    path, _ = bag
    info = bag_info(path)
    f = info['topics']['/force']
    assert f['count'] == 5 and f['type'] == FORCE
    assert f['sample_rate_hz'] == 1000.0 and f['samples'] == 25
    assert f['seq_gaps'] == 1 and f['seq_first'] == 0 and f['seq_last'] == 5
    a = info['topics']['/accel']
    assert a['seq_gaps'] == 0 and a['sample_rate_hz'] == 2000.0
    assert 'seq_gaps' not in info['topics']['/pull_event']
    assert info['pulls']['count'] == 2 and info['pulls']['ends'] == 1
    assert info['pulls']['test_sets'] == [2, 4] and info['pulls']['pull_ids'] == [7, 8]
    assert info['message_count'] == 12
    assert info['duration_s'] == pytest.approx(0.025)
    text = format_info(info)
    assert '/force' in text and FORCE in text and 'Pulls:     2' in text


# -- bad input -> BagError, one line ------------------------------------------------------------
def test_truncated_mcap(bag):
    path, _ = bag
    mcap = next(path.glob('*.mcap'))
    data = mcap.read_bytes()
    mcap.write_bytes(data[:len(data) // 2])
    with pytest.raises(BagError) as err:
        open_bag(path)
    assert_one_line(err, path)
    with pytest.raises(BagError):
        bag_info(path)


def test_garbage_mcap(bag):
    path, _ = bag
    mcap = next(path.glob('*.mcap'))
    mcap.write_bytes(b'not an mcap file at all' * 3)
    with pytest.raises(BagError) as err:
        open_bag(path)
    assert_one_line(err, path)


def test_missing_metadata(bag):
    path, _ = bag
    (path / 'metadata.yaml').unlink()
    with pytest.raises(BagError) as err:
        open_bag(path)
    assert_one_line(err, path)
    assert 'metadata.yaml' in str(err.value)


def test_missing_dir_and_file(tmp_path):
    with pytest.raises(BagError) as err:
        open_bag(tmp_path / 'absent')
    assert_one_line(err, tmp_path / 'absent')
    f = tmp_path / 'x.mcap'
    f.write_bytes(b'')
    with pytest.raises(BagError) as err:
        open_bag(f)
    assert_one_line(err, f)


def test_empty_bag(tmp_path, store):
    path = tmp_path / 'empty'
    with BagWriter(path, store) as w:
        w.add_topic('/force', FORCE)
    with pytest.raises(BagError) as err:
        open_bag(path)
    assert_one_line(err, path)
    assert 'no messages' in str(err.value)
    info = bag_info(path)  # as `ros2 bag info`: a valid bag with 0 messages (docs/reliability.md)
    assert info['message_count'] == 0 and info['topics']['/force']['count'] == 0


# -- writer failure handling ---------------------------------------------------------------------
def test_failed_write_leaves_no_bag(tmp_path, store):
    path = tmp_path / 'failed'
    with pytest.raises(RuntimeError):
        with BagWriter(path, store) as w:
            w.add_topic('/force', FORCE)
            w.write('/force', T0, force(store, T0, 0))
            raise RuntimeError('recorder crashed')
    assert not path.exists()


def test_writer_rejects_bad_input(tmp_path, store):
    existing = tmp_path / 'exists'
    existing.mkdir()
    with pytest.raises(BagError) as err:
        BagWriter(existing, store)
    assert_one_line(err, existing)
    assert existing.is_dir()  # never deleted

    path = tmp_path / 'bad'
    with pytest.raises(BagError) as err:
        with BagWriter(path, store) as w:
            w.add_topic('/x', 'force_tester_msgs/msg/Nope')
    assert "'force_tester_msgs/msg/Nope'" in str(err.value) and '\n' not in str(err.value)
    assert not path.exists()
    with BagWriter(path, store) as w:
        w.add_topic('/force', FORCE)
        w.add_topic('/force', FORCE)  # idempotent
        for args in [('/other', T0, force(store, T0, 0)), ('/force', -1, force(store, T0, 0)),
                     ('/force', 1.5, force(store, T0, 0)), ('/force', T0, b'\xff\xff'),
                     ('/force', T0, 'text')]:
            with pytest.raises(BagError) as err:
                w.write(*args)
            assert '\n' not in str(err.value)
        with pytest.raises(BagError):
            w.add_topic('/force', ACCEL)
        w.write('/force', np.int64(T0), force(store, T0, 0))
    with open_bag(path) as b:
        assert b.message_count == 1


# -- playback scheduling ---------------------------------------------------------------------------
def test_schedule():
    stamps = [T0, T0 + 10**9, T0 + 2 * 10**9, T0 + 3 * 10**9]
    s = schedule(stamps)
    assert s.offsets_ns == [0, 10**9, 2 * 10**9, 3 * 10**9] and s.start_index == 0
    s = schedule(stamps, rate=2.0, start_offset_s=1, stop_offset_s=2)
    assert (s.start_index, s.stop_index, s.offsets_ns) == (1, 3, [0, 5 * 10**8])
    assert schedule([]).offsets_ns == []
    for kwargs in [dict(rate=0), dict(rate=-1), dict(rate=float('nan')),
                   dict(start_offset_s=-1), dict(start_offset_s=2, stop_offset_s=1),
                   dict(start_offset_s=10)]:
        with pytest.raises(BagError) as err:
            schedule(stamps, **kwargs)
        assert '\n' not in str(err.value)
    with pytest.raises(BagError):
        schedule([T0 + 1, T0])
