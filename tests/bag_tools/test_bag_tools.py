"""bag_tools: DAQ campaigns, bag <-> campaign conversion, the CLI (ROS-free)."""

from __future__ import annotations

import sys

import numpy as np
import pytest
import yaml
from daq_data import MSG_DIR, RATE, T0, N, make_pulls, no_partials, removed_warning, run_cli

from bag_tools.core import BagWriter, bag_info, make_typestore, open_bag
from bag_tools.core.channel_map import pairs_map
from bag_tools.core.convert import bag_to_campaign, campaign_to_bag
from bag_tools.core.daq import (
    CAMPAIGN_FILE,
    BagError,
    pull_from_file,
    read_campaign,
    read_csv,
    write_campaign,
    write_csv,
)
from force_tester_common.core.channels import OPTIONAL_CHANNELS, REQUIRED_CHANNELS


@pytest.fixture
def camp(tmp_path):
    return write_campaign(tmp_path / 'camp', make_pulls(3, start=T0))


# --------------------------------------------------------------------------- CSV / campaign
def test_csv_is_lossless_including_nan_and_extremes(tmp_path):
    ch = {'time_s': np.arange(6) / RATE,
          'x': np.array([0.1, -0.0, 1e-310, 1.7976931348623157e308, np.nan, 1 / 3])}
    write_csv(tmp_path / 'a.csv', ch)
    back = read_csv(tmp_path / 'a.csv')
    assert back['time_s'].tobytes() == ch['time_s'].tobytes()
    assert back['x'].tobytes() == ch['x'].tobytes()


def test_campaign_round_trip_bit_exact(camp):
    c = read_campaign(camp)
    assert c.sample_rate_hz == RATE and c.warnings == []
    for (m, ch), p in zip(make_pulls(3, start=T0), c.pulls):
        assert p.meta['start_ns'] == m['start_ns'] and p.meta['pull_id'] == m['pull_id']
        for k, v in ch.items():
            assert p.channels[k].tobytes() == v.tobytes(), k
    assert np.array_equal(c.pulls[0].channels['time_s'], np.arange(N) / RATE)
    doc = yaml.safe_load((camp / CAMPAIGN_FILE).read_text())
    assert doc['sample_rate_hz'] == RATE and doc['pulls'][0]['file'] == 'pull_0001.csv'


def _edit_csv(camp, fn, name='pull_0002.csv'):
    p = camp / name
    lines = p.read_text().splitlines()
    p.write_text('\n'.join(fn(lines)) + '\n')
    return p


def test_missing_required_column_is_named(camp):
    def drop(lines):
        head = lines[0].split(',')
        i = head.index('force_stationary_n')
        return [','.join(c for j, c in enumerate(line.split(',')) if j != i) for line in lines]
    _edit_csv(camp, drop)
    with pytest.raises(BagError, match=r"pull_0002.csv: required column 'force_stationary_n' "
                                       r"is missing"):
        read_campaign(camp)


def test_non_monotonic_time_is_an_error(camp):
    def swap(lines):
        lines[11], lines[12] = lines[12], lines[11]
        return lines
    _edit_csv(camp, swap)
    with pytest.raises(BagError, match=r'pull_0002.csv: time_s is not increasing at row 12'):
        read_campaign(camp)


def test_rate_mismatch_names_both(camp):
    doc = yaml.safe_load((camp / CAMPAIGN_FILE).read_text())
    doc['sample_rate_hz'] = 25000.0
    (camp / CAMPAIGN_FILE).write_text(yaml.safe_dump(doc))
    with pytest.raises(BagError) as e:
        read_campaign(camp)
    msg = str(e.value)
    assert 'sample_rate_hz 25000.0' in msg and '50000 Hz' in msg and 'pull_0001.csv' in msg
    assert '\n' not in msg


def test_different_lengths_is_an_error(tmp_path):
    m, ch = make_pulls(1)[0]
    ch['motor_current_a'] = ch['motor_current_a'][:-3]
    with pytest.raises(BagError, match=r"column 'motor_current_a' has 1497 samples but "
                                       r"'time_s' has 1500"):
        write_campaign(tmp_path / 'c', [(m, ch)])
    assert not (tmp_path / 'c').exists() and no_partials(tmp_path) == []


def test_short_row_in_csv_is_an_error(camp):
    _edit_csv(camp, lambda lines: lines[:50] + [lines[50].rsplit(',', 1)[0]] + lines[51:])
    with pytest.raises(BagError, match=r'line 51 has 9 values; expected 10'):
        read_campaign(camp)


def test_nan_rows_warn_and_are_kept(camp):
    def nan(lines):
        for i in (100, 101, 102):
            parts = lines[i].split(',')
            parts[3] = 'nan'
            parts[2] = ''  # an empty field reads as NaN too
            lines[i] = ','.join(parts)
        return lines
    _edit_csv(camp, nan)
    c = read_campaign(camp)
    ch = c.pulls[1].channels
    assert np.isnan(ch['force_moving_n'][99:102]).all()
    assert np.isnan(ch['accel_axial_m_s2'][99:102]).all()
    assert any('3 row(s) with NaN' in w and 'pull_0002.csv' in w for w in c.warnings)


def test_missing_optional_columns_are_fine_and_reported(tmp_path):
    src = write_campaign(tmp_path / 'c', make_pulls(2, optional=False))
    c = read_campaign(src)
    assert set(c.missing_optional()) == set(OPTIONAL_CHANNELS)
    assert any('optional column(s)' in w for w in c.warnings)
    warnings = []
    campaign_to_bag(c, tmp_path / 'bag', warnings=warnings)
    assert any('no /motor topic' in w for w in warnings)
    topics = bag_info(tmp_path / 'bag')['topics']
    assert '/motor' not in topics and topics['/accel']['samples'] == 2 * N
    back = read_campaign(bag_to_campaign(tmp_path / 'bag', tmp_path / 'c2'))
    assert set(back.pulls[0].channels) == set(REQUIRED_CHANNELS)


def test_bad_metadata_and_missing_campaign_file(tmp_path, camp):
    with pytest.raises(BagError, match='has no campaign.yaml'):
        read_campaign(tmp_path)
    doc = yaml.safe_load((camp / CAMPAIGN_FILE).read_text())
    doc['pulls'][1]['coupon_lbf'] = 'lots'
    (camp / CAMPAIGN_FILE).write_text(yaml.safe_dump(doc))
    with pytest.raises(BagError, match=r"pull #1 coupon_lbf 'lots' is invalid"):
        read_campaign(camp)


def test_write_campaign_is_atomic(tmp_path):
    pulls = make_pulls(3)
    del pulls[2][1]['force_moving_n']  # the last pull fails after two were written
    with pytest.raises(BagError, match="required column 'force_moving_n'"):
        write_campaign(tmp_path / 'c', pulls)
    assert list(tmp_path.iterdir()) == []
    write_campaign(tmp_path / 'c', make_pulls(1))
    with pytest.raises(BagError, match='exists already'):
        write_campaign(tmp_path / 'c', make_pulls(1))


# --------------------------------------------------------------------------- conversion
def test_campaign_bag_campaign_round_trip(camp, tmp_path):
    bag = campaign_to_bag(camp, tmp_path / 'bag', block_size=64)
    info = bag_info(bag)
    assert info['pulls']['count'] == 3 and info['topics']['/force']['seq_gaps'] == 0
    assert info['start_ns'] == T0
    back = read_campaign(bag_to_campaign(bag, tmp_path / 'back'))
    src = read_campaign(camp)
    for p, q in zip(src.pulls, back.pulls):
        assert q.meta['start_ns'] == p.meta['start_ns'] and q.meta['pull_id'] == p.meta['pull_id']
        assert q.meta['set'] == p.meta['set']
        for k in ('coupon_lbf', 'velocity_fps', 'decel_g'):
            assert q.meta[k] == pytest.approx(p.meta[k], rel=1e-12, abs=1e-12)
        assert set(q.channels) == set(p.channels)
        for k, v in p.channels.items():
            assert q.channels[k].tobytes() == v.tobytes(), k
    # and again into a bag: the block messages are the same bytes
    bag2 = campaign_to_bag(back, tmp_path / 'bag2', block_size=64)
    with open_bag(bag) as a, open_bag(bag2) as b:
        ma, mb = list(a.messages()), list(b.messages())
    assert [(m.topic, m.stamp_ns, m.cdr) for m in ma] == [(m.topic, m.stamp_ns, m.cdr) for m in mb]


def test_block_log_time_is_last_sample(camp, tmp_path):
    bag = campaign_to_bag(camp, tmp_path / 'bag', block_size=50)
    with open_bag(bag) as b:
        msgs = list(b.messages(['/force', '/pull_event']))
        first = [m for m in msgs if m.topic == '/force'][0]
        msg = b.deserialize(first.cdr, first.type_name)
    stamp = msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
    assert stamp == T0 and first.stamp_ns == T0 + 49 * 20_000
    assert msgs[0].topic == '/pull_event' and msgs[0].stamp_ns == T0


def test_dropped_block_becomes_nan_rows(camp, tmp_path):
    bag = campaign_to_bag(camp, tmp_path / 'bag')
    store = make_typestore([MSG_DIR])
    k = 0
    with open_bag(bag) as src, BagWriter(tmp_path / 'holey', store) as w:
        for t, ti in src.topics().items():
            w.add_topic(t, ti.type_name)
        for m in src.messages():
            if m.topic == '/force':
                k += 1
                if k == 35:  # pull 2 (30 blocks of 50 per pull), its 5th block
                    continue
            w.write(m.topic, m.stamp_ns, m.cdr)
    assert bag_info(tmp_path / 'holey')['topics']['/force']['seq_gaps'] == 1
    warnings = []
    c = read_campaign(bag_to_campaign(tmp_path / 'holey', tmp_path / 'c', warnings=warnings))
    ch = c.pulls[1].channels
    assert np.isnan(ch['force_moving_n'][200:250]).all()
    assert int(np.isnan(ch['force_moving_n']).sum()) == 50
    assert not np.isnan(ch['accel_axial_m_s2']).any()
    assert any('pull 101: 50 of 1500 samples of force_moving_n missing' in w for w in warnings)


def _bag_with_unknown_type(tmp_path, camp):
    pkg = tmp_path / 'other_pkg' / 'msg'
    pkg.mkdir(parents=True)
    (pkg / 'Thing.msg').write_text('float64 value\nstring note\n')
    store = make_typestore([MSG_DIR, pkg])
    bag = campaign_to_bag(camp, tmp_path / 'bag0')
    with open_bag(bag) as src, BagWriter(tmp_path / 'bag', store) as w:
        for t, ti in src.topics().items():
            w.add_topic(t, ti.type_name)
        w.add_topic('/thing', 'other_pkg/msg/Thing')
        for m in src.messages():
            w.write(m.topic, m.stamp_ns, m.cdr)
        thing = store.types['other_pkg/msg/Thing'](value=1.5, note='hi')
        w.write('/thing', T0 + 5, store.serialize_cdr(thing, 'other_pkg/msg/Thing'))
    return tmp_path / 'bag'


def test_unknown_type_listed_by_info_and_skipped_by_export(tmp_path, camp):
    bag = _bag_with_unknown_type(tmp_path, camp)
    info = bag_info(bag)
    assert info['topics']['/thing'] == {'type': 'other_pkg/msg/Thing', 'count': 1}
    warnings = []
    c = read_campaign(bag_to_campaign(bag, tmp_path / 'c', warnings=warnings))
    assert len(c.pulls) == 3
    assert any('/thing (other_pkg/msg/Thing) skipped' in w for w in warnings)


def test_truncated_and_metadata_less_bags(tmp_path, camp):
    bag = campaign_to_bag(camp, tmp_path / 'bag')
    mcap = next(bag.glob('*.mcap'))
    data = mcap.read_bytes()
    mcap.write_bytes(data[:len(data) // 2])
    for fn in (lambda: bag_info(bag), lambda: bag_to_campaign(bag, tmp_path / 'c')):
        with pytest.raises(BagError) as e:
            fn()
        assert '\n' not in str(e.value) and 'bag' in str(e.value)
    assert not (tmp_path / 'c').exists()
    assert no_partials(tmp_path) == []
    (bag / 'metadata.yaml').unlink()
    with pytest.raises(BagError, match='needs a reindex: run ./ft bag reindex.*no metadata.yaml'):
        bag_to_campaign(bag, tmp_path / 'c')


def test_export_needs_pull_events(tmp_path):
    store = make_typestore([MSG_DIR])
    with BagWriter(tmp_path / 'b', store) as w:
        w.add_topic('/force', 'force_tester_msgs/msg/ForceBlock')
        from bag_tools.core.convert import block_cdr
        w.write('/force', T0, block_cdr(store, 'force_tester_msgs/msg/ForceBlock', T0, RATE, 0,
                                        {'moving_n': np.ones(5), 'stationary_n': np.ones(5)}))
    with pytest.raises(BagError, match='no force_tester_msgs/msg/PullEvent topic'):
        bag_to_campaign(tmp_path / 'b', tmp_path / 'c')


# --------------------------------------------------------------------------- optional deps
def test_tdms_without_nptdms_says_so(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, 'nptdms', None)   # as on a machine without it: `import nptdms` fails
    (tmp_path / 'x.tdms').write_bytes(b'TDSm')
    with pytest.raises(BagError, match='reading this format needs npTDMS'):
        pull_from_file(tmp_path / 'x.tdms', None)


def test_tdms_import(tmp_path):
    nptdms = pytest.importorskip('nptdms')
    _m, ch = make_pulls(1)[0]
    names = {'encoder_position_m': 'Enc', 'accel_axial_m_s2': 'Acc X',
             'force_moving_n': 'LC moving', 'force_stationary_n': 'LC stat'}
    chans = [nptdms.ChannelObject('DAQ', names.get(k, k), v,
                                  properties={'wf_increment': 1 / RATE})
             for k, v in ch.items() if k != 'time_s']
    with nptdms.TdmsWriter(str(tmp_path / 'p.tdms')) as w:
        w.write_segment([nptdms.GroupObject('DAQ'), *chans])
    mapping = [f'{k}=DAQ/{v}' for k, v in names.items()]
    r = run_cli('import', tmp_path / 'p.tdms', tmp_path / 'bag', '--set', '3',
                '--coupon-lbf', '600', *[x for m in mapping for x in ('--map', m)])
    assert r.returncode == 0, r.stderr
    c = read_campaign(bag_to_campaign(tmp_path / 'bag', tmp_path / 'c'))
    assert c.pulls[0].channels['force_moving_n'].tobytes() == ch['force_moving_n'].tobytes()


# --------------------------------------------------------------------------- CLI
def test_cli_errors_are_one_line(tmp_path, camp):
    cases = [
        (('export', tmp_path / 'missing', tmp_path / 'c'), 'export', 'does not exist'),
        (('import', tmp_path, tmp_path / 'b'), 'import', 'has no campaign.yaml'),
        (('info', tmp_path / 'nothing'), 'info', 'does not exist'),
    ]
    for args, cmd, text in cases:
        r = run_cli(*args)
        assert r.returncode == 2, (args, r.stderr)
        lines = r.stderr.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith(f'./ft bag {cmd}: error: '), r.stderr
        assert text in lines[0], lines[0]
        assert 'Traceback' not in r.stderr


@pytest.mark.slow
def test_cli_import_export(tmp_path, camp):
    r = run_cli('import', camp, tmp_path / 'bag')
    assert r.returncode == 0 and 'imported 3 pull(s)' in r.stdout, r.stderr
    r = run_cli('export', tmp_path / 'bag', tmp_path / 'c2')
    assert r.returncode == 0, r.stderr
    assert len(read_campaign(tmp_path / 'c2').pulls) == 3
    for cmd in ('export', 'import', 'info'):
        r = run_cli(cmd, '--help')
        assert r.returncode == 0 and 'usage: ./ft bag ' + cmd in r.stdout


def test_interrupted_outputs_leave_nothing(tmp_path, camp, monkeypatch):
    """Ctrl-C or a failure half-way through writing leaves no output and no temp folder."""
    import bag_tools.core.daq as daq
    import bag_tools.core.writer as writer
    bag = campaign_to_bag(camp, tmp_path / 'bag')
    real_csv, calls = daq.write_csv, []

    def csv_then_interrupt(*a, **kw):
        calls.append(1)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return real_csv(*a, **kw)
    monkeypatch.setattr(daq, 'write_csv', csv_then_interrupt)
    with pytest.raises(KeyboardInterrupt):
        bag_to_campaign(bag, tmp_path / 'c')
    monkeypatch.setattr(daq, 'write_csv', real_csv)
    real_write, n = writer.BagWriter.write, []

    def write_then_fail(self, *a, **kw):
        n.append(1)
        if len(n) == 200:
            raise OSError(28, 'No space left on device (simulated)')
        return real_write(self, *a, **kw)
    monkeypatch.setattr(writer.BagWriter, 'write', write_then_fail)
    with pytest.raises(OSError, match='No space left'):
        campaign_to_bag(camp, tmp_path / 'b2')
    assert sorted(p.name for p in tmp_path.iterdir()) == ['bag', 'camp']


KILLED_WRITER = {   # a writer of OUT that is SIGKILLed midway (as when its host is lost): it prints 'ready' and waits
    'export': """
import sys, time
from daq_data import make_pulls
from bag_tools.core.daq import write_campaign
def pulls():
    yield from make_pulls(1)
    print('ready', flush=True)
    time.sleep(600)
write_campaign(sys.argv[1], pulls())
""",
    'import': """
import sys, time
from daq_data import MSG_DIR
from bag_tools.core import BagWriter, make_typestore
with BagWriter(sys.argv[1], make_typestore([MSG_DIR]), rewritable=sys.argv[2] == 'import'):
    print('ready', flush=True)
    time.sleep(600)
""",
}


@pytest.mark.slow
@pytest.mark.parametrize('command', ['export', 'import'])
def test_a_killed_commands_leftover_is_removed_by_the_next_run(tmp_path, camp, command):
    """A command killed midway (SIGKILL: no cleanup) leaves its unfinished output: export's hidden
    .OUT.partial-* folder, import's bag folder without metadata.yaml. Both are marked as being written;
    the next run of the command removes the leftover with a warning naming it, and writes the output whole."""
    import os
    import signal
    import subprocess
    from pathlib import Path

    from daq_data import SRC_DIRS
    src = campaign_to_bag(camp, tmp_path / 'bag') if command == 'export' else camp
    out = tmp_path / 'out'
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(map(str, [Path(__file__).parents[1], *SRC_DIRS])))
    proc = subprocess.Popen([sys.executable, '-c', KILLED_WRITER[command], str(out), command],
                            stdout=subprocess.PIPE, text=True, env=env)
    assert proc.stdout.readline().strip() == 'ready'
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    left = out if command == 'import' else next(tmp_path.glob('.out.partial-*'))
    assert left.is_dir() and not (left / 'metadata.yaml').exists() and not (left / CAMPAIGN_FILE).exists()
    r = run_cli(command, src, out)
    assert r.returncode == 0, r.stderr
    assert removed_warning(command, left).search(r.stderr), r.stderr
    assert no_partials(tmp_path) == [] and no_partials(out) == []
    if command == 'export':
        assert len(read_campaign(out).pulls) == 3
    else:
        assert bag_info(out)['topics'] and (out / 'metadata.yaml').is_file()


def test_a_killed_recording_is_never_removed_by_an_import(tmp_path, camp):
    """A recording's BagWriter is not marked: cut off (SIGKILL), its folder needs a reindex, and an import into
    that path says it exists instead of removing it."""
    import os
    import signal
    import subprocess
    from pathlib import Path

    from daq_data import SRC_DIRS
    out = tmp_path / 'rec'
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(map(str, [Path(__file__).parents[1], *SRC_DIRS])))
    proc = subprocess.Popen([sys.executable, '-c', KILLED_WRITER['import'], str(out), 'record'],
                            stdout=subprocess.PIPE, text=True, env=env)
    assert proc.stdout.readline().strip() == 'ready'
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    mcap = sorted(p.name for p in out.iterdir())
    r = run_cli('import', camp, out)
    assert r.returncode == 2 and 'exists already' in r.stderr and 'removed' not in r.stderr, r.stderr
    assert sorted(p.name for p in out.iterdir()) == mcap and mcap and '.ft-writing' not in mcap


def test_tdms_reader_logic_with_a_stand_in_module(tmp_path, monkeypatch):
    """TDMS through the one channel-map path (--map pairs, the time from wf_increment), with a stand-in npTDMS."""
    import types
    _m, ch = make_pulls(1, optional=False)[0]
    names = {'force_moving_n': 'LC moving', 'force_stationary_n': 'LC stat'}

    class Chan:
        def __init__(self, name, data):
            self.name, self._d = name, data
            self.properties = {'wf_increment': 1 / RATE}

        def __getitem__(self, sl):
            return self._d[sl]

    group = types.SimpleNamespace(
        name='DAQ', channels=lambda: [Chan(names.get(k, k), v) for k, v in ch.items()
                                      if k != 'time_s'])
    fake = types.SimpleNamespace(TdmsFile=types.SimpleNamespace(
        read=lambda p: types.SimpleNamespace(groups=lambda: [group])))
    monkeypatch.setitem(sys.modules, 'nptdms', fake)
    (tmp_path / 'x.tdms').write_bytes(b'TDSm')       # read_records wants a file; the stand-in reads none
    got = pull_from_file(tmp_path / 'x.tdms', pairs_map(['force_moving_n=DAQ/LC moving',
                                                         'force_stationary_n=LC stat'])).channels
    assert set(got) == set(REQUIRED_CHANNELS)
    assert got['time_s'].tobytes() == ch['time_s'].tobytes()
    assert got['force_moving_n'].tobytes() == ch['force_moving_n'].tobytes()
    with pytest.raises(BagError, match="source 'Nope' is not a channel of the file"):
        pull_from_file(tmp_path / 'x.tdms', pairs_map({'force_moving_n': 'Nope'}))
    with pytest.raises(BagError, match="--map column 'bogus' is not a DAQ column"):
        pairs_map({'bogus': 'LC moving'})
    with pytest.raises(BagError, match="expected COLUMN=CHANNEL"):
        pairs_map(['force_moving_n'])
    # unmapped, the channels keep the file's names, and the moving cell's is not ours: named in one line
    with pytest.raises(BagError, match='no force_moving_n channel'):
        pull_from_file(tmp_path / 'x.tdms', None)
