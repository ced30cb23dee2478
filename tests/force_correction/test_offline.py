"""Offline correction (force_correction.offline): bags and campaigns through the live core,
its typed result, the plot, and the ./ft bag correct / plot commands."""
from __future__ import annotations

import json
import os
import shutil
import sys

import numpy as np
import pytest
from daq_data import MSG_DIR, RATE, T0, N, make_pulls, no_partials, run_cli

from bag_tools.core import BagWriter, bag_info, make_typestore, open_bag
from bag_tools.core.convert import campaign_to_bag
from bag_tools.core.daq import read_campaign, write_campaign
from bag_tools.core.errors import BagError
from force_correction.core import CorrectionError, CorrectionParams, SetStatistics, correct_signal, score_pull
from force_correction.offline import CorrectionResult, CorrectionSetup, correct
from force_tester_common.core.units import LBF_N


@pytest.fixture
def camp(tmp_path):
    return write_campaign(tmp_path / 'camp', make_pulls(3, start=T0))


def offline_cli(*args):
    return run_cli(*args, module='force_correction.offline.cli')


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
    res = correct(src, tmp_path / 'out', CorrectionSetup.build(mass_kg, window))
    assert isinstance(res, CorrectionResult) and res.path == 'campaign'
    params = CorrectionParams(mass_kg=mass_kg, window=window)
    outs, scores, stats = _reference(pulls, params)
    out = read_campaign(tmp_path / 'out')
    for p, o in zip(out.pulls, outs):
        for k in ('inertial_n', 'corrected_n', 'filtered_n'):
            np.testing.assert_allclose(p.channels[k], o[k], rtol=0, atol=1e-9)
    for got, s in zip(res.pulls, scores):
        for k in ('raw_diff_pct', 'corrected_diff_pct', 'filtered_diff_pct', 'filtered_rms_n'):
            assert abs(getattr(got.score, k) - getattr(s, k)) <= 1e-9
    for got in res.sets:
        ref = stats.summary(got.set_id)
        assert got.pulls == ref.pulls
        assert abs(got.filtered_mean_pct - ref.filtered_mean_pct) <= 1e-9
        assert abs(got.corrected_std_pct - ref.corrected_std_pct) <= 1e-9
    doc = json.loads((tmp_path / 'out' / 'scores.json').read_text())
    assert doc['params']['window'] == window and len(doc['pulls']) == 4
    assert doc['pulls'] == json.loads(json.dumps(res.as_dict()['pulls']))


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
    assert res.runs == 2 and res.path == 'fast'
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
    assert again.sets == res.sets


def test_correct_bag_to_campaign_and_campaign_to_bag(tmp_path, camp):
    bag = campaign_to_bag(camp, tmp_path / 'bag')
    a = correct(bag, tmp_path / 'as_campaign', to='campaign')
    b = correct(camp, tmp_path / 'as_bag', to='bag')
    assert a.sets == b.sets
    c = read_campaign(tmp_path / 'as_campaign')
    assert 'filtered_n' in c.pulls[0].channels
    assert bag_info(tmp_path / 'as_bag')['topics']['/force_corrected']['count'] > 0
    assert no_partials(tmp_path) == []


def test_correct_rejects_bad_params_and_existing_output(tmp_path, camp):
    with pytest.raises(CorrectionError, match='window 0 is out of range'):
        CorrectionSetup.build(window=0)
    with pytest.raises(CorrectionError, match='loaded_fraction 1.5 is out of range'):
        CorrectionSetup(loaded_fraction=1.5)
    with pytest.raises(CorrectionError, match='max_pending 0 is out of range'):
        CorrectionSetup(max_pending=0)
    with pytest.raises(CorrectionError, match='exists already'):
        correct(camp, camp)
    with pytest.raises(CorrectionError, match="path 'quick' is invalid"):
        correct(camp, tmp_path / 'o', path='quick')
    with pytest.raises(BagError, match='neither a bag'):
        correct(tmp_path, tmp_path / 'o')


def test_correct_skips_nan_samples(tmp_path):
    pulls = make_pulls(3)
    pulls[1][1]['force_moving_n'][99:102] = np.nan
    res = correct(write_campaign(tmp_path / 'c', pulls), tmp_path / 'out')
    assert res.nan_samples == 3 and all(np.isfinite(s.filtered_mean_pct) for s in res.sets)


def _drop_force_block(bag, dst, which):
    store = make_typestore([MSG_DIR])
    k = 0
    with open_bag(bag) as src, BagWriter(dst, store) as w:
        for t, ti in src.topics().items():
            w.add_topic(t, ti.type_name)
        for m in src.messages():
            if m.topic == '/force':
                k += 1
                if k == which:
                    continue
            w.write(m.topic, m.stamp_ns, m.cdr)
    return dst


def test_dropped_block_is_counted_and_restarts_the_filter(camp, tmp_path):
    bag = campaign_to_bag(camp, tmp_path / 'bag')
    holey = _drop_force_block(bag, tmp_path / 'holey', 35)  # pull 2's 5th block
    res = correct(holey, tmp_path / 'k')
    assert res.path == 'generic'  # the fast path declines a dropped block
    assert [p.score.dropped_blocks for p in res.pulls] == [0, 2, 0]  # dropped + unmatched
    assert any(w.startswith('dropped block on force') for w in res.warnings)
    assert res.runs == 4  # the filter restarts after the gap, as the live node does
    with pytest.raises(CorrectionError, match='fast path does not apply'):
        correct(holey, tmp_path / 'k2', path='fast')


def test_unknown_type_is_copied_through(tmp_path, camp):
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
    res = correct(tmp_path / 'bag', tmp_path / 'corr')
    assert bag_info(tmp_path / 'corr')['topics']['/thing']['count'] == 1
    assert len(res.pulls) == 3


def test_truncated_bag_is_one_line_and_leaves_nothing(tmp_path, camp):
    bag = campaign_to_bag(camp, tmp_path / 'bag')
    mcap = next(bag.glob('*.mcap'))
    mcap.write_bytes(mcap.read_bytes()[:mcap.stat().st_size // 2])
    with pytest.raises(BagError) as e:
        correct(bag, tmp_path / 'k')
    assert '\n' not in str(e.value) and 'bag' in str(e.value)
    assert not (tmp_path / 'k').exists() and no_partials(tmp_path) == []


def test_write_failures_leave_nothing(tmp_path, camp, monkeypatch):
    """A full disk half-way through writing is an I/O error (OSError, not bad input) and leaves
    no output and no temp folder, for both writers."""
    import bag_tools.core.writer as writer
    bag = campaign_to_bag(camp, tmp_path / 'bag')
    with monkeypatch.context() as mp:  # the usual bag is copied with the results appended
        mp.setattr(os, 'pwrite', lambda *a: (_ for _ in ()).throw(
            OSError(28, 'No space left on device (simulated)')))
        with pytest.raises(OSError, match='No space left'):
            correct(bag, tmp_path / 'k')
    # a bag that has result topics already is rewritten message by message (BagWriter)
    correct(bag, tmp_path / 'done')
    real_write, n = writer.BagWriter.write, []

    def write_then_fail(self, *a, **kw):
        n.append(1)
        if len(n) == 200:
            raise OSError(28, 'No space left on device (simulated)')
        return real_write(self, *a, **kw)
    monkeypatch.setattr(writer.BagWriter, 'write', write_then_fail)
    with pytest.raises(OSError, match='No space left'):
        correct(tmp_path / 'done', tmp_path / 'k')
    shutil.rmtree(tmp_path / 'done')
    assert sorted(p.name for p in tmp_path.iterdir()) == ['bag', 'camp']


# --------------------------------------------------------------------------- plot
def test_plot(tmp_path, camp):
    pytest.importorskip('matplotlib')
    from force_correction.offline.plot import load_pull, plot_pull
    pull, rate = load_pull(camp, 2)
    out = plot_pull(pull, rate, tmp_path / 'p.png')
    assert out.read_bytes()[:4] == b'\x89PNG'
    r = offline_cli('plot', camp, '--pull', '1', '--si', '--out', tmp_path / 'q.png')
    assert r.returncode == 0, r.stderr


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
    from force_correction.offline.plot import load_pull, plot_pull
    pull, rate = load_pull(camp, 1)
    plot_pull(pull, rate, tmp_path / 'p.png')
    fig.savefig.assert_called_once()
    stat = axes[0].plot.call_args_list[0].args[1]
    np.testing.assert_allclose(stat, pull.channels['force_stationary_n'] / LBF_N)
    filt = axes[0].plot.call_args_list[3].args[1]
    ref = correct_signal(pull.channels['force_moving_n'], pull.channels['accel_axial_m_s2'],
                         CorrectionParams()).filtered_n / LBF_N
    np.testing.assert_allclose(filt, ref)
    plot_pull(pull, rate, tmp_path / 'q.png', si=True)
    vel = axes[2].twinx.return_value.plot.call_args_list[-1].args[1]
    np.testing.assert_allclose(vel, np.gradient(pull.channels['encoder_position_m'], 1 / RATE))
    with pytest.raises(CorrectionError, match='pull 4 is out of range; expected 1..3'):
        load_pull(camp, 4)


# --------------------------------------------------------------------------- CLI
def test_cli_errors_are_one_line(tmp_path, camp):
    cases = [
        (('correct', camp, tmp_path / 'o', '--window', '0'), 'correct', 'window 0'),
        (('correct', camp), 'correct', 'required: dst'),
        (('correct', camp, camp), 'correct', 'exists already'),
        (('plot', camp, '--pull', '9'), 'plot', 'pull 9 is out of range'),
        (('export', tmp_path / 'missing', tmp_path / 'c'), 'export', 'does not exist'),
    ]
    for args, cmd, text in cases:
        r = offline_cli(*args)
        assert r.returncode == 2, (args, r.stderr)
        lines = r.stderr.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith(f'./ft bag {cmd}: error: '), r.stderr
        assert text in lines[0], lines[0]
        assert 'Traceback' not in r.stderr


def test_cli_correct_prints_the_set_table(tmp_path, camp):
    bag = campaign_to_bag(camp, tmp_path / 'bag')
    r = offline_cli('correct', bag, tmp_path / 'corr', '--mass-kg', '1.152')
    assert r.returncode == 0, r.stderr
    head, _units, _rule, *rows = r.stdout.splitlines()
    assert head.split()[:4] == ['set', 'pulls', 'stationary', 'diff']
    assert [row.split()[:2] for row in rows[:2]] == [['1', '2'], ['2', '1']]
    assert 'cannot be undone' not in r.stderr
    ext = tmp_path / 'ext.yaml'    # an extension with a term the correction cannot undo: said in one warning
    ext.write_text('correction: {}\nextra_terms: [{channel: force_moving, term: v, coefficient: 9.0}]\n')
    r = offline_cli('correct', bag, tmp_path / 'corr2', '--extension', ext)
    assert r.returncode == 0, r.stderr
    assert "warning: the extension's force_moving: v cannot be undone" in r.stderr, r.stderr
    for cmd in ('correct', 'plot', 'info', 'export'):
        r = offline_cli(cmd, '--help')
        assert r.returncode == 0 and 'usage: ./ft bag ' + cmd in r.stdout


def test_cli_full_disk_is_an_io_error_not_bad_input(tmp_path, camp, monkeypatch, capsys):
    """Bad input exits 2; an I/O failure (a full disk) exits 1; each with one line."""
    from force_correction.offline.cli import main
    bag = campaign_to_bag(camp, tmp_path / 'bag')
    monkeypatch.setattr(os, 'pwrite', lambda *a: (_ for _ in ()).throw(
        OSError(28, 'No space left on device (simulated)')))
    assert main(['correct', str(bag), str(tmp_path / 'out')]) == 1
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and 'I/O failure' in lines[0] and 'No space left' in lines[0], lines
    assert main(['correct', str(bag), str(bag)]) == 2
