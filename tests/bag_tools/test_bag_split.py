"""Tests of split bags (SplitBagWriter: one rosbag2 directory, several .mcap files). ROS-free."""

from __future__ import annotations

import bag_msgs
import pytest
import yaml
from bag_msgs import bag_typestore, header

from bag_tools.core import BagError, BagWriter, bag_info, open_bag
from bag_tools.core.split_writer import MESSAGE_OVERHEAD_BYTES, SplitBagWriter, open_bag_writer

T0 = 1_700_000_000_000_000_000
FORCE = 'force_tester_msgs/msg/ForceBlock'
PULL = 'force_tester_msgs/msg/PullEvent'
MS = 1_000_000


@pytest.fixture(scope='module')
def store():
    return bag_typestore()


def force(store, ns, seq, n=50):
    return bag_msgs.force(store, ns, seq, n)


def pull(store, ns, event, pull_id):
    msg = store.types[PULL](header=header(store, ns), event=event, pull_id=pull_id,
                            test_set=1, coupon_break_n=5000.0, velocity_m_s=2.0,
                            decel_m_s2=-30.0)
    return store.serialize_cdr(msg, PULL)


def messages(store, n=30):
    """(topic, type, stamp, cdr): /force every 10 ms, a PullEvent START/END pair."""
    out = [('/force', FORCE, T0 + i * 10 * MS, force(store, T0 + i * 10 * MS, i))
           for i in range(n)]
    out.append(('/pull_event', PULL, T0 + 35 * MS, pull(store, T0 + 35 * MS, 0, 1)))
    out.append(('/pull_event', PULL, T0 + 215 * MS, pull(store, T0 + 215 * MS, 1, 1)))
    return sorted(out, key=lambda m: m[2])


def write(writer, msgs):
    with writer as w:
        for topic, typ, _, _ in msgs:
            w.add_topic(topic, typ)
        for topic, _, stamp, cdr in msgs:
            w.write(topic, stamp, cdr)
    return writer.path


def read_all(path):
    with open_bag(path) as b:
        return [tuple(m) for m in b.messages()], b.topics(), b.start_ns, b.end_ns


def meta(path):
    return yaml.safe_load((path / 'metadata.yaml').read_text())['rosbag2_bagfile_information']


def check_split_bag(path, msgs, plain):
    info = meta(path)
    files = info['relative_file_paths']
    assert len(files) > 1
    assert files == [f'{path.name}_{i}.mcap' for i in range(len(files))]
    assert sorted(p.name for p in path.iterdir()) == sorted(files + ['metadata.yaml'])
    assert not list(path.parent.glob(f'.{path.name}*'))          # temp dir gone
    assert info['version'] == 9 and info['storage_identifier'] == 'mcap'
    assert info['custom_data'] == {'writer': 'bag_tools.core'}
    assert [f['path'] for f in info['files']] == files
    assert info['message_count'] == len(msgs) == sum(f['message_count'] for f in info['files'])
    assert all(f['message_count'] > 0 for f in info['files'])
    counts = {t['topic_metadata']['name']: t['message_count']
              for t in info['topics_with_message_count']}
    assert counts == {'/force': sum(m[0] == '/force' for m in msgs),
                      '/pull_event': sum(m[0] == '/pull_event' for m in msgs)}
    assert info['starting_time']['nanoseconds_since_epoch'] == msgs[0][2]
    assert info['duration']['nanoseconds'] == msgs[-1][2] - msgs[0][2]
    # per-file times/counts = those of the messages each file holds, files in time order
    i = 0
    for f in info['files']:
        chunk = msgs[i:i + f['message_count']]
        assert f['starting_time']['nanoseconds_since_epoch'] == chunk[0][2]
        assert f['duration']['nanoseconds'] == chunk[-1][2] - chunk[0][2]
        i += f['message_count']
    # the same QoS/type metadata as an unsplit bag
    plain_topics = {t['topic_metadata']['name']: t['topic_metadata']
                    for t in meta(plain)['topics_with_message_count']}
    assert {t['topic_metadata']['name']: t['topic_metadata']
            for t in info['topics_with_message_count']} == plain_topics
    # reads back identical to the unsplit bag
    got, topics, start, end = read_all(path)
    want, wtopics, wstart, wend = read_all(plain)
    assert got == want and topics == wtopics and (start, end) == (wstart, wend)
    assert [m[2] for m in got] == [m[2] for m in msgs]
    assert [m[3] for m in got] == [m[3] for m in msgs]
    # bag_info works
    bi = bag_info(path)
    assert bi['message_count'] == len(msgs)
    assert sorted(bi['storage_files']) == sorted(files)
    assert bi['topics']['/force']['seq_gaps'] == 0
    assert bi['topics']['/force']['count'] == counts['/force']
    assert bi['pulls']['count'] == 1
    return info


def test_split_by_duration(tmp_path, store):
    msgs = messages(store)
    plain = write(BagWriter(tmp_path / 'plain', store), msgs)
    path = write(SplitBagWriter(tmp_path / 'bag', store, max_duration_ns=100 * MS), msgs)
    info = check_split_bag(path, msgs, plain)
    # 0..290 ms in 100 ms files: [0, 100), [100, 200), [200, 300)
    assert [f['message_count'] for f in info['files']] == [11, 10, 11]
    assert [f['starting_time']['nanoseconds_since_epoch'] - T0 for f in info['files']] == \
        [0, 100 * MS, 200 * MS]
    assert all(f['duration']['nanoseconds'] < 100 * MS for f in info['files'])


def test_split_by_size(tmp_path, store):
    msgs = messages(store)
    plain = write(BagWriter(tmp_path / 'plain', store), msgs)
    size = len(msgs[0][3]) + MESSAGE_OVERHEAD_BYTES
    path = write(SplitBagWriter(tmp_path / 'bag', store, max_bytes=size * 8), msgs)
    info = check_split_bag(path, msgs, plain)
    assert len(info['files']) >= 4
    assert all(f['message_count'] <= 9 for f in info['files'])  # 8 blocks (+ a small PullEvent)


def test_size_and_duration(tmp_path, store):
    msgs = messages(store)
    plain = write(BagWriter(tmp_path / 'plain', store), msgs)
    w = SplitBagWriter(tmp_path / 'bag', store, max_bytes=10**9, max_duration_ns=50 * MS)
    with w:
        w.add_topic('/force', FORCE)
        w.add_topic('/pull_event', PULL)
        for topic, _, stamp, cdr in msgs:
            w.write(topic, stamp, cdr)
    info = check_split_bag(w.path, msgs, plain)
    assert len(info['files']) == 6


def test_topic_added_late_and_in_all_files(tmp_path, store):
    """A topic first seen in a later file is in the metadata; each file has all topics known."""
    msgs = [m for m in messages(store) if m[0] == '/force']
    with SplitBagWriter(tmp_path / 'bag', store, max_duration_ns=100 * MS) as w:
        w.add_topic('/force', FORCE)
        for topic, _, stamp, cdr in msgs[:15]:
            w.write(topic, stamp, cdr)
        w.add_topic('/pull_event', PULL)
        w.write('/pull_event', T0 + 155 * MS, pull(store, T0 + 155 * MS, 0, 3))
        for topic, _, stamp, cdr in msgs[15:]:
            w.write(topic, stamp, cdr)
    info = meta(w.path)
    assert len(info['files']) == 3
    counts = {t['topic_metadata']['name']: t['message_count']
              for t in info['topics_with_message_count']}
    assert counts == {'/force': 30, '/pull_event': 1}
    with open_bag(w.path) as b:
        assert [m.topic for m in b.messages(['/pull_event'])] == ['/pull_event']
        assert b.message_count == 31


def test_nothing_complete_before_close_and_failure_leaves_nothing(tmp_path, store):
    msgs = messages(store)
    path = tmp_path / 'bag'
    with pytest.raises(RuntimeError):
        with SplitBagWriter(path, store, max_duration_ns=50 * MS) as w:
            w.add_topic('/force', FORCE)
            w.add_topic('/pull_event', PULL)
            for topic, _, stamp, cdr in msgs[:20]:
                w.write(topic, stamp, cdr)
            assert w.file_count >= 3
            assert len(list(path.glob('*.mcap'))) >= 2        # finished files moved in
            assert not (path / 'metadata.yaml').exists()
            with pytest.raises(BagError):
                open_bag(path)
            raise RuntimeError('recording failed')
    assert list(tmp_path.iterdir()) == []


def test_bad_write_does_not_leave_empty_file(tmp_path, store):
    msgs = [m for m in messages(store) if m[0] == '/force'][:12]
    with SplitBagWriter(tmp_path / 'bag', store, max_duration_ns=100 * MS) as w:
        w.add_topic('/force', FORCE)
        for topic, _, stamp, cdr in msgs[:10]:
            w.write(topic, stamp, cdr)
        with pytest.raises(BagError):   # rolls to a new file, then the data is rejected
            w.write('/force', msgs[10][2], b'not cdr')
        with pytest.raises(BagError):
            w.write('/nope', msgs[10][2], msgs[10][3])
    info = meta(w.path)
    assert info['relative_file_paths'] == ['bag_0.mcap']
    assert sorted(p.name for p in w.path.iterdir()) == ['bag_0.mcap', 'metadata.yaml']
    assert open_bag(w.path).message_count == 10


def test_failed_close_leaves_nothing(tmp_path, store, monkeypatch):
    msgs = messages(store)
    w = SplitBagWriter(tmp_path / 'bag', store, max_duration_ns=100 * MS).open()
    w.add_topic('/force', FORCE)
    w.add_topic('/pull_event', PULL)
    for topic, _, stamp, cdr in msgs:
        w.write(topic, stamp, cdr)
    monkeypatch.setattr(SplitBagWriter, '_metadata',
                        lambda self: (_ for _ in ()).throw(OSError('disk full')))
    with pytest.raises(BagError) as err:
        w.close()
    assert 'disk full' in str(err.value) and '\n' not in str(err.value)
    assert list(tmp_path.iterdir()) == []


def test_empty_split_bag(tmp_path, store):
    with SplitBagWriter(tmp_path / 'bag', store, max_bytes=1000) as w:
        w.add_topic('/force', FORCE)
    info = meta(w.path)
    assert info['relative_file_paths'] == ['bag_0.mcap'] and info['message_count'] == 0
    with open_bag(w.path, allow_empty=True) as b:
        assert b.message_count == 0 and list(b.messages()) == []


def test_errors_and_factory(tmp_path, store):
    (tmp_path / 'exists').mkdir()
    with pytest.raises(BagError):
        SplitBagWriter(tmp_path / 'exists', store, max_bytes=10)
    with pytest.raises(BagError):
        SplitBagWriter(tmp_path / 'x', store, max_bytes=-1)
    with pytest.raises(BagError):
        SplitBagWriter(tmp_path / 'no' / 'x', store, max_bytes=10)
    w = SplitBagWriter(tmp_path / 'x', store, max_bytes=10)
    with pytest.raises(BagError):
        w.write('/force', T0, b'\x00\x01\x00\x00')            # not opened
    assert type(open_bag_writer(tmp_path / 'a', store)) is BagWriter
    assert type(open_bag_writer(tmp_path / 'a', store, max_duration_ns=1)) is SplitBagWriter
