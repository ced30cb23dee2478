"""Recording that survives: a killed recorder's bag is recovered by `./ft bag reindex` up to its
last written chunk; a full disk stops the recorder with a finished, readable bag.

The first tests are ROS-free (the core on files); the ones marked slow run the real recorder
node as a process over DDS with the real sim publishing.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import subprocess
import time
from pathlib import Path

import pytest
from bag_msgs import FORCE, bag_typestore, force
from daq_data import run_cli

from bag_tools.core.errors import BagError
from bag_tools.core.metadata import METADATA_FILE, load_metadata
from bag_tools.core.reader import open_bag
from bag_tools.core.recording import CHUNK_BYTES, RESERVE_NAME, Recording
from bag_tools.core.reindex import needs_reindex, reindex

T0 = 1_700_000_000_000_000_000
RECORD_OVERHEAD = 31  # bytes of an MCAP message record besides its data


def seqs_by_topic(bag):
    """{topic: [seq, ...]} of a bag, in the order read: a block's seq, a pull event's
    2 * pull_id + event (START 0, END 1), so both count 0, 1, 2, ... as published."""
    out = {}
    with open_bag(bag, allow_empty=True) as b:
        for m in b.messages():
            msg = b.deserialize(m.cdr, m.type_name)
            seq = msg.seq if hasattr(msg, 'seq') else 2 * msg.pull_id + msg.event
            out.setdefault(m.topic, []).append(int(seq))
    return out


def assert_readable_prefix(bag, expected_total=None):
    """Every topic is seq 0, 1, 2, ... with nothing missing, and metadata.yaml agrees with what
    is read (nothing looks more complete than it is)."""
    seqs = seqs_by_topic(bag)
    for topic, s in seqs.items():
        assert s == list(range(len(s))), topic
    info = load_metadata(bag)
    total = sum(len(s) for s in seqs.values())
    assert info['message_count'] == total
    counts = {t['topic_metadata']['name']: t['message_count'] for t in info['topics_with_message_count']}
    assert {t: c for t, c in counts.items() if c} == {t: len(s) for t, s in seqs.items()}
    if expected_total is not None:
        assert total == expected_total
    return total


def test_killed_recording_loses_at_most_the_chunk_in_progress(tmp_path):
    """The file as a killed recorder leaves it (whatever it had handed to the OS) reindexes to
    every message of every written chunk: at most one chunk (CHUNK_BYTES of records) is lost."""
    store = bag_typestore()
    rec = Recording(tmp_path / 'live', store).open()
    rec.add_topic('/force', FORCE)
    written, sizes, snapshots = 0, [], []
    for k in range(3000):
        data = force(store, T0 + k * 1_000_000, k, n=50)
        rec.write('/force', T0 + k * 1_000_000, data)
        written += 1
        sizes.append(len(data))
        if k in (10, 777, 1500, 2999):  # kill here: copy what is in the file now
            snap = tmp_path / f'killed{k}'
            snap.mkdir()
            shutil.copy(tmp_path / 'live' / 'live.mcap', snap / 'killed.mcap')
            snapshots.append((snap, written))
    rec.close()
    assert not (tmp_path / 'live' / RESERVE_NAME).exists()
    bound = CHUNK_BYTES // (min(sizes) + RECORD_OVERHEAD) + 1
    assert rec.chunks >= 3000 * (min(sizes) + RECORD_OVERHEAD) // CHUNK_BYTES  # chunks were cut
    for snap, n in snapshots:
        assert needs_reindex(snap)
        with pytest.raises(BagError, match='needs a reindex'):
            open_bag(snap)
        report = reindex(snap)
        got = assert_readable_prefix(snap)
        assert got == report.message_count
        assert n - bound <= got <= n, (snap.name, n, got, bound)


def test_killed_split_recording_is_reindexed_with_its_file_in_progress(tmp_path):
    """A split recording killed mid-file: its finished files are in the bag, the one in
    progress in the hidden .splits directory beside it; reindex takes it in."""
    store = bag_typestore()
    rec = Recording(tmp_path / 'bag', store, max_bytes=400_000).open()
    rec.add_topic('/force', FORCE)
    for k in range(1200):
        rec.write('/force', T0 + k, force(store, T0 + k, k, n=50))
    # the process is gone here: nothing more is written or closed (the files are as it left them)
    assert len(list((tmp_path / 'bag').glob('*.mcap'))) == 2
    assert needs_reindex(tmp_path / 'bag')
    report = reindex(tmp_path / 'bag')
    assert report.moved == ['bag_2.mcap']
    got = assert_readable_prefix(tmp_path / 'bag')
    bound = CHUNK_BYTES // (len(force(store, T0, 0, n=50)) + RECORD_OVERHEAD) + 1
    assert 1200 - bound <= got < 1200
    assert [p.name for p in tmp_path.iterdir()] == ['bag']  # no .splits directory left
    assert sorted(p.name for p in (tmp_path / 'bag').iterdir()) == [
        'bag_0.mcap', 'bag_1.mcap', 'bag_2.mcap', METADATA_FILE]  # nor the disk reserve
    assert load_metadata(tmp_path / 'bag')['relative_file_paths'] == ['bag_0.mcap', 'bag_1.mcap',
                                                                      'bag_2.mcap']


@pytest.mark.parametrize('cut', [9, 40, 0.37, 0.5, 0.81, -1])
def test_reindex_recovers_the_whole_chunks_of_a_torn_file(tmp_path, cut):
    """A file cut anywhere (in the header, a chunk, a message index, the summary): every
    message record wholly before the cut is read back (the complete records of a torn,
    uncompressed chunk included), and the result reads with rosbags and with mcap."""
    from mcap.reader import make_reader
    store = bag_typestore()
    rec = Recording(tmp_path / 'full', store).open()
    rec.add_topic('/force', FORCE)
    for k in range(2000):
        rec.write('/force', T0 + k, force(store, T0 + k, k, n=50))
    rec.close()
    mcap = tmp_path / 'full' / 'full.mcap'
    data = mcap.read_bytes()
    at = cut if isinstance(cut, int) and cut >= 0 else int(len(data) * cut) if cut > 0 else len(data) - 1
    bag = tmp_path / 'cut'
    bag.mkdir()
    (bag / 'cut.mcap').write_bytes(data[:at])
    report = reindex(bag)
    got = assert_readable_prefix(bag)
    assert got == sum(1 for end in _record_ends(mcap) if end <= at)
    assert 0 < got < 2000 or cut in (9, 40, -1)
    with (bag / 'cut.mcap').open('rb') as fh:
        assert sum(1 for _ in make_reader(fh).iter_messages()) == got
    again = reindex(bag)  # a finished file is only read
    assert not again.files[0].repaired and again.message_count == report.message_count == got


def _record_ends(mcap: Path) -> list:
    """File offsets of the end of each message record of a finished MCAP file (from its
    chunk indexes and message indexes)."""
    import struct

    from bag_tools.core.mcapfile import read_summary, records_start
    data = mcap.read_bytes()
    ends = []
    for c in read_summary(mcap).chunks:
        for moff in c.message_index_offsets.values():
            _cid, blen = struct.unpack_from('<HI', data, moff + 9)
            for i in range(blen // 16):
                _log, rel = struct.unpack_from('<QQ', data, moff + 15 + 16 * i)
                start = records_start(c) + rel
                ends.append(start + 9 + struct.unpack_from('<Q', data, start + 1)[0])
    return ends


def test_info_and_reindex_on_the_command_line(tmp_path):
    store = bag_typestore()
    rec = Recording(tmp_path / 'bag', store).open()
    rec.add_topic('/force', FORCE)
    for k in range(1500):
        rec.write('/force', T0 + k, force(store, T0 + k, k, n=50))
    shutil.copytree(tmp_path / 'bag', tmp_path / 'killed')  # with its disk reserve
    rec.close()
    info = run_cli('info', tmp_path / 'killed')
    assert info.returncode == 2 and 'needs a reindex' in info.stderr, info.stderr
    assert 'needs a reindex: run ./ft bag reindex on it' in info.stderr
    assert len(info.stderr.strip().splitlines()) == 1
    out = run_cli('reindex', tmp_path / 'killed')
    assert out.returncode == 0, out.stderr
    assert 'metadata.yaml written' in out.stdout
    assert sorted(p.name for p in (tmp_path / 'killed').iterdir()) == ['bag.mcap', METADATA_FILE]
    assert run_cli('info', tmp_path / 'killed').returncode == 0
    missing = run_cli('reindex', tmp_path / 'nothing')
    assert missing.returncode == 2 and 'Traceback' not in missing.stderr


# --------------------------------------------------------------------------- a full disk
@contextlib.contextmanager
def small_tmpfs(where: Path, size: str):
    """A tmpfs of the given size mounted at where (root only); always unmounted."""
    where.mkdir()
    r = subprocess.run(['mount', '-t', 'tmpfs', '-o', f'size={size}', 'tmpfs', str(where)],
                       capture_output=True, text=True)
    if r.returncode != 0:
        pytest.skip(f'cannot mount a tmpfs here: {r.stderr.strip()}')
    try:
        yield where
    finally:
        subprocess.run(['umount', '-l', str(where)], check=False)


def test_full_disk_leaves_a_finished_bag_of_what_fit(tmp_path):
    store = bag_typestore()
    with small_tmpfs(tmp_path / 'disk', '3m') as disk:
        rec = Recording(disk / 'bag', store).open()
        rec.add_topic('/force', FORCE)
        written = 0
        with pytest.raises(OSError):
            for k in range(100_000):
                rec.write('/force', T0 + k, force(store, T0 + k, k, n=50))
                written += 1
                if k % 100 == 0:
                    rec.flush()
        report = rec.salvage()
        assert report is not None
        got = assert_readable_prefix(disk / 'bag', report.message_count)
        bound = CHUNK_BYTES // (len(force(store, T0, 0, n=50)) + RECORD_OVERHEAD) + 1
        assert written - bound <= got <= written  # all but the chunk that failed
        assert got > 2000                                     # most of 3 MB
        assert sorted(p.name for p in (disk / 'bag').iterdir()) == ['bag.mcap', METADATA_FILE]
        assert not [p for p in disk.iterdir() if p.name != 'bag']


# --------------------------------------------------------------------------- the live recorder
class RecorderWatch:
    """rclpy in this process: the recorder's /diagnostics statuses (level, message, values)."""

    def __init__(self):
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        from rclpy.executors import SingleThreadedExecutor

        from force_tester_common.core.channels import DIAGNOSTICS_TOPIC
        from force_tester_common.ros import EVENT_QOS
        rclpy.init(args=['watch'])
        self.node = rclpy.create_node('recorder_watch')
        self.statuses = []
        self.node.create_subscription(DiagnosticArray, DIAGNOSTICS_TOPIC, self._on, EVENT_QOS)
        self.executor = SingleThreadedExecutor()
        self.executor.add_node(self.node)

    def _on(self, msg):
        for s in msg.status:
            if s.name.startswith('recorder:'):
                self.statuses.append((int.from_bytes(s.level, 'little') if isinstance(s.level, bytes)
                                      else int(s.level), s.message, {kv.key: kv.value for kv in s.values}))

    def wait(self, cond, timeout, alive=lambda: True):
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline and alive():
            n = len(self.statuses)
            self.executor.spin_once(timeout_sec=0.05)
            for st in self.statuses[n:]:
                if cond(st):
                    return st
        return None

    def close(self):
        import rclpy
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown()


def _live(tmp_path, bag, pulls):
    from ft_cli.graph import Graph
    graph = Graph(tmp_path / 'logs')
    watch = RecorderWatch()
    graph.start('bag_tools', 'recorder_node', {'bag_path': str(bag)})
    graph.start('force_tester_sim', 'sim_node', {
        'test_sets': '[1]', 'pulls_per_set': pulls, 'rate': 1.0, 'wait_for_subscribers': 1,
        'exit_when_done': True, 'block_size': 50})   # 1 ms blocks: many messages in flight when it is killed
    return graph, watch


@pytest.mark.slow
def test_sigkilled_recorder_is_recovered_by_reindex(tmp_path, ros_domain):
    """The real recorder, recording the real sim, SIGKILLed mid-run: reindex recovers every
    message it had written but the chunk in progress, each topic without a gap."""
    bag = tmp_path / 'bag'
    graph, watch = _live(tmp_path, bag, pulls=3)
    rec = graph.procs['recorder_node']
    try:
        st = watch.wait(lambda s: int(s[2].get('messages', 0)) >= 6000, 60,
                        alive=lambda: rec.poll() is None)
        assert st is not None, graph.tail('recorder_node')
        # kill right after a progress report: it counts what was written up to then
        st = watch.wait(lambda s: 'messages' in s[2], 5)
        rec.send_signal(signal.SIGKILL)
        reported = int(st[2]['messages'])
        rec.wait(10)
    finally:
        graph.stop()
        watch.close()
    assert not (bag / METADATA_FILE).exists()
    out = run_cli('info', bag)
    assert out.returncode == 2 and 'needs a reindex' in out.stderr
    out = run_cli('reindex', bag)
    assert out.returncode == 0, out.stderr
    seqs = seqs_by_topic(bag)
    got = assert_readable_prefix(bag)
    with open_bag(bag) as b:  # the bound in messages: a chunk of the smallest blocks
        smallest = min(len(m.cdr) for m in b.messages(['/force', '/accel', '/motor', '/encoder']))
    bound = CHUNK_BYTES // (smallest + RECORD_OVERHEAD) + 1 + 2  # + a pull's START and END
    print(f"recovered {got}, reported before the kill {reported}, bound {bound}")
    assert got >= reported - bound, (got, reported, bound)
    assert set(seqs) >= {'/force', '/accel', '/motor', '/encoder'}
    assert sorted(p.name for p in bag.iterdir()) == ['bag.mcap', METADATA_FILE]


@pytest.mark.slow
def test_full_disk_stops_the_recorder_cleanly(tmp_path, ros_domain):
    """The recorder on a 4 MB tmpfs with the sim publishing about 5 MB/s: an ERROR on
    /diagnostics and in its log, a finished bag of what fit, and a clean stop on SIGINT."""
    with small_tmpfs(tmp_path / 'disk', '4m') as disk:
        bag = disk / 'bag'
        graph, watch = _live(tmp_path, bag, pulls=1)
        rec = graph.procs['recorder_node']
        try:
            st = watch.wait(lambda s: s[0] == 2 and 'disk full' in s[1], 60,
                            alive=lambda: rec.poll() is None)
            assert st is not None, graph.tail('recorder_node')
            assert 'recording stopped' in st[1] and 'metadata.yaml written' in st[1]
            assert rec.poll() is None  # still up, reporting
        finally:
            codes = graph.stop()
            watch.close()
        assert codes['recorder_node'] in (0, -signal.SIGINT), graph.tail('recorder_node')
        log = (tmp_path / 'logs' / 'recorder_node.log').read_text()
        assert 'disk full' in log and 'Traceback' not in log
        got = assert_readable_prefix(bag)
        print(f'disk full: {st[1]}; bag holds {got}')
        assert got > 1000
        assert sorted(p.name for p in bag.iterdir()) == ['bag.mcap', METADATA_FILE]
        assert os.listdir(disk) == ['bag']
