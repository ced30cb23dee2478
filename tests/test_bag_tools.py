"""bag_tools: DAQ campaigns, bag <-> campaign conversion, offline correction, plot, CLI (ROS-free)."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

REPO = Path(__file__).resolve().parents[1]
SRC_DIRS = [REPO / 'src' / p for p in ('bag_tools', 'force_tester_common', 'force_correction',
                                       'force_tester_sim')]
for _d in reversed(SRC_DIRS):
    if str(_d) not in sys.path:
        sys.path.insert(0, str(_d))

from bag_tools.core import BagWriter, bag_info, make_typestore, open_bag  # noqa: E402
from bag_tools.core.convert import bag_to_campaign, campaign_to_bag  # noqa: E402
from bag_tools.core.daq import (CAMPAIGN_FILE, BagError, read_campaign, read_csv,  # noqa: E402
                                read_tdms, write_campaign, write_csv)
from bag_tools.core.offline import correct  # noqa: E402
from force_correction.core import (CorrectionParams, SetStatistics, correct_signal,  # noqa: E402
                                   score_pull)
from force_tester_common.core.channels import OPTIONAL_CHANNELS, REQUIRED_CHANNELS  # noqa: E402

MSG_DIR = REPO / 'src' / 'force_tester_msgs' / 'msg'
RATE = 50000.0
T0 = 1_700_000_000_000_000_000
N = 1500  # samples per synthetic pull (30 ms)


def synth(n=N, seed=0, peak=2000.0, optional=True):
    """A pull-like record: a smooth tension pulse with a break, accel ringing, noise."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / RATE
    tc = t[n // 2]
    pulse = peak * np.exp(-((t - tc) / 2e-3) ** 2) * (t < tc + 1e-3)
    accel = 50 * np.sin(2 * np.pi * 900 * t) * np.exp(-t / 0.01) + rng.normal(0, 0.5, n)
    ch = {'time_s': t,
          'encoder_position_m': 1.2 * t + 0.5 * t * t,
          'accel_axial_m_s2': accel,
          'force_moving_n': pulse + 1.152 * accel + rng.normal(0, 0.3, n),
          'force_stationary_n': pulse + rng.normal(0, 0.3, n)}
    if optional:
        ch.update(motor_current_a=rng.normal(3, 0.1, n), motor_voltage_v=rng.normal(40, 1, n),
                  motor_velocity_cmd_m_s=np.full(n, 4.572), accel_lateral_m_s2=rng.normal(0, 1, n),
                  accel_vertical_m_s2=rng.normal(0, 1, n))
    return ch


def meta(s, **kw):
    return {'set': s, 'coupon_lbf': 200.0 * s, 'velocity_fps': 3.0 + s, 'decel_g': -0.5 * (s > 3),
            **kw}


def make_pulls(k=3, start=None, **kw):
    out = []
    for i in range(k):
        m = meta(1 + i % 2)
        if start is not None:
            m['start_ns'] = start + i * (N * 20_000 + 5_000_000)
            m['pull_id'] = 100 + i
        out.append((m, synth(seed=i, peak=1000.0 * (i + 1), **kw)))
    return out


@pytest.fixture
def camp(tmp_path):
    return write_campaign(tmp_path / 'camp', make_pulls(3, start=T0))


def run_cli(*args):
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(map(str, SRC_DIRS)),
               _ROS_WHEELS_BOOTSTRAP_COMPLETE='1')
    return subprocess.run([sys.executable, '-m', 'bag_tools.cli', *map(str, args)],
                          capture_output=True, text=True, env=env, timeout=120)


def no_partials(folder: Path):
    return [p.name for p in folder.iterdir() if p.name.startswith('.')]


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
        return [','.join(c for j, c in enumerate(l.split(',')) if j != i) for l in lines]
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
    res = correct(camp, camp.parent / 'out')  # the correction skips the NaN samples
    assert res['nan_samples'] == 3 and all(np.isfinite(s['filtered_mean_pct']) for s in res['sets'])


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
    warnings = []
    res = correct(tmp_path / 'holey', tmp_path / 'k', warnings=warnings)
    assert [p['dropped_blocks'] for p in res['pulls']] == [0, 2, 0]  # dropped + unmatched
    assert any(w.startswith('dropped block on force') for w in warnings)
    assert res['runs'] == 4  # the filter restarts after the gap, as the live node does


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
    res = correct(bag, tmp_path / 'corr')  # the topic is copied through
    assert bag_info(tmp_path / 'corr')['topics']['/thing']['count'] == 1
    assert len(res['pulls']) == 3


def test_truncated_and_metadata_less_bags(tmp_path, camp):
    bag = campaign_to_bag(camp, tmp_path / 'bag')
    mcap = next(bag.glob('*.mcap'))
    data = mcap.read_bytes()
    mcap.write_bytes(data[:len(data) // 2])
    for fn in (lambda: bag_info(bag), lambda: bag_to_campaign(bag, tmp_path / 'c'),
               lambda: correct(bag, tmp_path / 'k')):
        with pytest.raises(BagError) as e:
            fn()
        assert '\n' not in str(e.value) and 'bag' in str(e.value)
    assert not (tmp_path / 'c').exists() and not (tmp_path / 'k').exists()
    assert no_partials(tmp_path) == []
    (bag / 'metadata.yaml').unlink()
    with pytest.raises(BagError, match='has no metadata.yaml.*unfinished recording'):
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


# --------------------------------------------------------------------------- offline correction
def _reference(pulls, params, joined=False):
    """correct_signal per pull (or on the concatenation) + score_pull + SetStatistics."""
    if joined:
        f = np.concatenate([c['force_moving_n'] for _, c in pulls])
        a = np.concatenate([c['accel_axial_m_s2'] for _, c in pulls])
        whole = correct_signal(f, a, params)
        outs, pos = [], 0
        for _, c in pulls:
            n = len(c['time_s'])
            outs.append({k: getattr(whole, k)[pos:pos + n] for k in
                         ('raw_n', 'inertial_n', 'corrected_n', 'filtered_n')})
            pos += n
    else:
        outs = [{k: getattr(correct_signal(c['force_moving_n'], c['accel_axial_m_s2'], params), k)
                 for k in ('raw_n', 'inertial_n', 'corrected_n', 'filtered_n')}
                for _, c in pulls]
    stats = SetStatistics()
    scores = []
    for (m, c), o in zip(pulls, outs):
        s = score_pull(c['force_stationary_n'], o['raw_n'], o['corrected_n'], o['filtered_n'])
        stats.add(m['set'], s)
        scores.append(s)
    return outs, scores, stats


@pytest.mark.parametrize('mass_kg, window', [(1.152, 140), (0.7, 33)])
def test_correct_campaign_equals_core(tmp_path, mass_kg, window):
    pulls = make_pulls(4)  # no start_ns: each pull is its own run
    src = write_campaign(tmp_path / 'c', pulls)
    res = correct(src, tmp_path / 'out', mass_kg=mass_kg, window=window)
    params = CorrectionParams(mass_kg=mass_kg, window=window)
    outs, scores, stats = _reference(pulls, params)
    out = read_campaign(tmp_path / 'out')
    for p, o in zip(out.pulls, outs):
        for k in ('inertial_n', 'corrected_n', 'filtered_n'):
            np.testing.assert_allclose(p.channels[k], o[k], rtol=0, atol=1e-9)
    for got, s in zip(res['pulls'], scores):
        for k in ('raw_diff_pct', 'corrected_diff_pct', 'filtered_diff_pct', 'filtered_rms_n'):
            assert abs(got[k] - getattr(s, k)) <= 1e-9
    for got in res['sets']:
        ref = stats.summary(got['set_id'])
        assert got['pulls'] == ref.pulls
        assert abs(got['filtered_mean_pct'] - ref.filtered_mean_pct) <= 1e-9
        assert abs(got['corrected_std_pct'] - ref.corrected_std_pct) <= 1e-9
    doc = json.loads((tmp_path / 'out' / 'scores.json').read_text())
    assert doc['params']['window'] == window and len(doc['pulls']) == 4


def test_correct_bag_equals_core_and_live_semantics(tmp_path):
    pulls = make_pulls(3, start=T0)
    # make pulls 0 and 1 contiguous: the live node would not reset its filter between them
    pulls[1][0]['start_ns'] = T0 + N * 20_000
    src = write_campaign(tmp_path / 'c', pulls)
    bag = campaign_to_bag(src, tmp_path / 'bag')
    res = correct(bag, tmp_path / 'out')
    params = CorrectionParams()
    joined, js, _ = _reference(pulls[:2], params, joined=True)
    alone, als, _ = _reference(pulls[2:], params)
    ref_outs, ref_scores = joined + alone, js + als
    assert res['runs'] == 2
    with open_bag(tmp_path / 'out') as b:
        topics = b.topics()
        assert topics['/force_corrected'].count == topics['/force'].count
        assert topics['/pull_score'].count == 3 and topics['/set_summary'].count == 3
        blocks = [b.deserialize(m.cdr, m.type_name) for m in b.messages('/force_corrected')]
        scores = [b.deserialize(m.cdr, m.type_name) for m in b.messages('/pull_score')]
    filt = np.concatenate([np.asarray(m.filtered_n) for m in blocks])
    np.testing.assert_allclose(filt, np.concatenate([o['filtered_n'] for o in ref_outs]),
                               rtol=0, atol=1e-9)
    assert [m.seq for m in blocks] == list(range(len(blocks)))
    for msg, ref, (m, _c) in zip(scores, ref_scores, pulls):
        assert msg.pull_id == m['pull_id']
        assert abs(msg.filtered_diff_pct - ref.filtered_diff_pct) <= 1e-9
        assert abs(msg.corrected_rms_n - ref.corrected_rms_n) <= 1e-9
    # a bag and the campaign it came from give the same summary
    again = correct(src, tmp_path / 'out2')
    assert again['sets'] == res['sets']


def test_correct_bag_to_campaign_and_campaign_to_bag(tmp_path, camp):
    bag = campaign_to_bag(camp, tmp_path / 'bag')
    a = correct(bag, tmp_path / 'as_campaign', to='campaign')
    b = correct(camp, tmp_path / 'as_bag', to='bag')
    assert a['sets'] == b['sets']
    c = read_campaign(tmp_path / 'as_campaign')
    assert 'filtered_n' in c.pulls[0].channels
    assert bag_info(tmp_path / 'as_bag')['topics']['/force_corrected']['count'] > 0
    assert no_partials(tmp_path) == []


def test_correct_rejects_bad_params_and_existing_output(tmp_path, camp):
    with pytest.raises(BagError, match='window 0 is out of range'):
        correct(camp, tmp_path / 'o', window=0)
    with pytest.raises(BagError, match='exists already'):
        correct(camp, camp)
    with pytest.raises(BagError, match='neither a bag'):
        correct(tmp_path, tmp_path / 'o')


# --------------------------------------------------------------------------- optional deps
def test_tdms_without_nptdms_says_so(tmp_path):
    try:
        import nptdms  # noqa: F401
    except ImportError:
        with pytest.raises(BagError, match='reading TDMS needs npTDMS'):
            read_tdms(tmp_path / 'x.tdms')
    else:
        pytest.skip('npTDMS is installed')


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


def test_plot(tmp_path, camp):
    pytest.importorskip('matplotlib')
    from bag_tools.core.plot import load_pull, plot_pull
    pull, rate = load_pull(camp, 2)
    out = plot_pull(pull, rate, tmp_path / 'p.png')
    assert out.read_bytes()[:4] == b'\x89PNG'
    r = run_cli('plot', camp, '--pull', '1', '--si', '--out', tmp_path / 'q.png')
    assert r.returncode == 0, r.stderr


def test_plot_without_matplotlib_says_so(camp):
    try:
        import matplotlib  # noqa: F401
    except ImportError:
        r = run_cli('plot', camp, '--pull', '1')
        assert r.returncode == 2
        assert r.stderr.strip() == ('./ft bag plot: error: plotting needs matplotlib: pip '
                                    'install matplotlib (see requirements.txt)')
    else:
        pytest.skip('matplotlib is installed')


# --------------------------------------------------------------------------- CLI
def test_cli_errors_are_one_line(tmp_path, camp):
    cases = [
        (('export', tmp_path / 'missing', tmp_path / 'c'), 'export', 'does not exist'),
        (('import', tmp_path, tmp_path / 'b'), 'import', 'has no campaign.yaml'),
        (('correct', camp, tmp_path / 'o', '--window', '0'), 'correct', 'window 0'),
        (('correct', camp), 'correct', 'required: dst'),
        (('plot', camp, '--pull', '9'), 'plot', 'pull 9 is out of range'),
    ]
    for args, cmd, text in cases:
        r = run_cli(*args)
        assert r.returncode == 2, (args, r.stderr)
        lines = r.stderr.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith(f'./ft bag {cmd}: error: '), r.stderr
        assert text in lines[0], lines[0]
        assert 'Traceback' not in r.stderr


def test_cli_import_correct_export(tmp_path, camp):
    r = run_cli('import', camp, tmp_path / 'bag')
    assert r.returncode == 0 and 'imported 3 pull(s)' in r.stdout, r.stderr
    r = run_cli('correct', tmp_path / 'bag', tmp_path / 'corr', '--mass-kg', '1.152')
    assert r.returncode == 0, r.stderr
    head, _units, _rule, *rows = r.stdout.splitlines()
    assert head.split()[:4] == ['set', 'pulls', 'stationary', 'diff']
    assert [row.split()[:2] for row in rows[:2]] == [['1', '2'], ['2', '1']]
    r = run_cli('export', tmp_path / 'corr', tmp_path / 'c2')
    assert r.returncode == 0, r.stderr
    assert 'filtered_n' in read_campaign(tmp_path / 'c2').pulls[0].channels
    for cmd in ('export', 'import', 'correct', 'plot', 'info'):
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
    # the usual bag is copied with the results appended (ExtendedBag)
    monkeypatch.setattr(os, 'pwrite', lambda *a: (_ for _ in ()).throw(
        OSError(28, 'No space left on device (simulated)')))
    with pytest.raises(BagError, match='No space left'):
        correct(bag, tmp_path / 'k')
    monkeypatch.undo()
    # a bag that has result topics already is rewritten message by message (BagWriter)
    done = correct(bag, tmp_path / 'done') and tmp_path / 'done'
    real_write, n = writer.BagWriter.write, []

    def write_then_fail(self, *a, **kw):
        n.append(1)
        if len(n) == 200:
            raise BagError('disk full (simulated)')
        return real_write(self, *a, **kw)
    monkeypatch.setattr(writer.BagWriter, 'write', write_then_fail)
    with pytest.raises(BagError, match='disk full'):
        correct(done, tmp_path / 'k')
    n.clear()
    with pytest.raises(BagError, match='disk full'):
        campaign_to_bag(camp, tmp_path / 'b2')
    shutil.rmtree(done)
    assert sorted(p.name for p in tmp_path.iterdir()) == ['bag', 'camp']


def test_tdms_reader_logic_with_a_stand_in_module(tmp_path, monkeypatch):
    """The mapping / time logic of read_tdms, with a minimal stand-in for npTDMS."""
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
    got = read_tdms(tmp_path / 'x.tdms', ['force_moving_n=DAQ/LC moving',
                                          'force_stationary_n=LC stat'])
    assert set(got) == set(REQUIRED_CHANNELS)
    assert got['time_s'].tobytes() == ch['time_s'].tobytes()
    assert got['force_moving_n'].tobytes() == ch['force_moving_n'].tobytes()
    with pytest.raises(BagError, match="has no channel 'Nope' \\(mapped to 'force_moving_n'\\)"):
        read_tdms(tmp_path / 'x.tdms', {'force_moving_n': 'Nope'})
    with pytest.raises(BagError, match="--map column 'bogus' is not a DAQ column"):
        read_tdms(tmp_path / 'x.tdms', {'bogus': 'LC moving'})
    # the same file through the CLI path's validation: a missing required column is named
    from bag_tools.core.daq import check_channels
    with pytest.raises(BagError, match="required column 'force_moving_n' is missing"):
        check_channels(read_tdms(tmp_path / 'x.tdms'), 'x.tdms', None)


def test_plot_logic_with_a_stand_in_matplotlib(tmp_path, camp, monkeypatch):
    """Exercise plot_pull's data path (units, correction, velocity) without matplotlib."""
    from unittest import mock
    plt = mock.MagicMock()
    axes = [mock.MagicMock() for _ in range(3)]
    fig = mock.MagicMock()
    plt.subplots.return_value = (fig, axes)
    mpl = mock.MagicMock(pyplot=plt)
    monkeypatch.setitem(sys.modules, 'matplotlib', mpl)
    monkeypatch.setitem(sys.modules, 'matplotlib.pyplot', plt)
    from bag_tools.core.plot import load_pull, plot_pull
    pull, rate = load_pull(camp, 1)
    plot_pull(pull, rate, tmp_path / 'p.png')
    fig.savefig.assert_called_once()
    stat = axes[0].plot.call_args_list[0].args[1]
    np.testing.assert_allclose(stat, pull.channels['force_stationary_n'] / 4.4482216152605)
    filt = axes[0].plot.call_args_list[3].args[1]
    ref = correct_signal(pull.channels['force_moving_n'], pull.channels['accel_axial_m_s2'],
                         CorrectionParams()).filtered_n / 4.4482216152605
    np.testing.assert_allclose(filt, ref)
    plot_pull(pull, rate, tmp_path / 'q.png', si=True)
    vel = axes[2].twinx.return_value.plot.call_args_list[-1].args[1]
    np.testing.assert_allclose(vel, np.gradient(pull.channels['encoder_position_m'], 1 / RATE))
    with pytest.raises(BagError, match='pull 4 is out of range; expected 1..3'):
        load_pull(camp, 4)
