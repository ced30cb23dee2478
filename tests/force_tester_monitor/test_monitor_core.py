"""The monitor's ROS-free core: health arithmetic, joining, live-trace scalars, pull traces, and
batches of raw CDR blocks with malformed messages among them."""
import math

import numpy as np
import pytest
from force_tester_monitor.core.batch import decode_batch
from force_tester_monitor.core.errors import MonitorError
from force_tester_monitor.core.health import TopicStats, recorder_counts
from force_tester_monitor.core.live import ForceJoin, JoinedBlock, LiveTrace, PullTraces, loaded_window, score_lbf
from force_tester_monitor.core.params import MonitorParams

from bag_tools.core.fastcdr import encode_blocks
from force_tester_common.core.channels import FORCE_FIELDS
from force_tester_common.core.clock import NS_PER_S
from force_tester_common.core.units import LBF_N

MS = 1_000_000


def test_health_counts_gaps_nan_rate_and_latency_percentiles():
    st = TopicStats('/force', window_s=1.0)
    t0 = 10 * NS_PER_S
    arrivals = t0 + np.arange(100) * 10 * MS               # 100 blocks/s for 1 s
    stamps = arrivals - np.where(np.arange(100) < 98, 2 * MS, 50 * MS)
    seq = np.concatenate((np.arange(50), np.arange(53, 103)))  # 3 skipped
    st.add(arrivals[:60], stamps[:60], seq[:60], nan_samples=2)
    st.add(arrivals[60:], stamps[60:], seq[60:], nan_samples=1)
    snap = st.snapshot(int(arrivals[-1]))
    assert (snap.received, snap.seq_gaps, snap.nan_samples) == (100, 3, 3)
    assert snap.rate_hz == pytest.approx(100, rel=0.02)
    assert snap.latency_p50_ms == pytest.approx(2.0)
    assert snap.latency_p99_ms > 2.0
    # a restart (seq back to 0) is a new run, not a gap; old arrivals leave the window
    st.add([arrivals[-1] + 3 * NS_PER_S], [arrivals[-1] + 3 * NS_PER_S - MS], [0])
    later = st.snapshot(int(arrivals[-1] + 3 * NS_PER_S))
    assert later.seq_gaps == 3 and later.latency_p50_ms == pytest.approx(1.0) and later.rate_hz == pytest.approx(1.0)
    assert math.isnan(TopicStats('/x', 1.0).snapshot(t0).latency_p50_ms)


def test_recorder_counts_come_from_its_progress_report_only():
    assert recorder_counts('recorder: bag recorder', {'messages': '12', '/force': '7', 'held_back': '1'}) == \
        {'messages': 12, '/force': 7}
    assert recorder_counts('correction: inertial correction', {'messages': '3'}) is None
    assert recorder_counts('recorder: bag recorder', {'messages': 'many'}) is None


def block(stamp, values, seq=0, rate=50_000.0):
    v = np.asarray(values, float)
    return JoinedBlock(stamp, seq, rate, v, v + 1, v + 2, v + 3)


def test_join_pairs_by_stamp_and_forgets_force_blocks_whose_partner_is_gone():
    j = ForceJoin()
    for k in range(3):
        j.add_force(k * MS, np.full(5, float(k)))
    assert j.add_corrected(7 * MS, 0, 5e4, np.ones(5), np.ones(5), np.ones(5)) is None
    got = j.add_corrected(2 * MS, 9, 5e4, np.ones(5), np.ones(5), np.ones(5))
    assert got.stationary[0] == 2.0 and got.seq == 9
    assert j.add_corrected(0, 1, 5e4, np.ones(5), np.ones(5), np.ones(5)) is None  # dropped as stale
    with pytest.raises(MonitorError, match='max_pending 0'):
        ForceJoin(0)


def test_while_the_correction_is_down_the_live_trace_keeps_the_stationary_force():
    """Issue 41, Low: with the correction down, no force block found its corrected block and the live trace
    vanished entirely. A force block whose corrected block has not come 5 s (ALONE_AFTER_S, of stamps) after it
    comes back alone: the stationary and raw forces, corrected and filtered NaN; with the correction up, none."""
    from force_tester_monitor.core.live import ALONE_AFTER_S
    rate, n, step = 50_000.0, 500, 10 * MS          # 10 ms blocks
    up, down = ForceJoin(), ForceJoin()
    alone = []
    for k in range(800):                               # 8 s of blocks
        stamp, values = k * step, np.full(n, 100.0 + k)
        assert up.add_force(stamp, values, rate, values + 1) == []
        assert up.add_corrected(stamp, k, rate, values + 1, values, values) is not None
        alone += down.add_force(stamp, values, rate, values + 1)
    assert len(alone) == 800 - 1 - int(ALONE_AFTER_S * NS_PER_S // step)   # all but the last 5 s
    assert [b.stamp_ns for b in alone] == [k * step for k in range(len(alone))]
    lt = LiveTrace(every=1)
    out = lt.add(alone[-1])
    assert out.max['stationary'] == pytest.approx((100.0 + len(alone) - 1) / LBF_N, abs=0.005)
    assert out.max['raw'] == pytest.approx((101.0 + len(alone) - 1) / LBF_N, abs=0.005)
    assert np.isnan(out.max['corrected']) and np.isnan(out.max['filtered'])


def test_live_trace_gives_last_and_max_in_lbf_per_group():
    lt = LiveTrace(every=2)
    assert lt.add(block(0, [1.0, 9.0, 2.0])) is None
    out = lt.add(block(60_000, [3.0, np.nan, 4.0], seq=1))
    assert out.blocks == 2 and out.seq == 1
    assert out.last['stationary'] == pytest.approx(4.0 / LBF_N, abs=0.005)
    assert out.max['stationary'] == pytest.approx(9.0 / LBF_N, abs=0.005)
    assert out.max['filtered'] == pytest.approx(12.0 / LBF_N, abs=0.005)
    # rounded to 0.01 lbf: the viewer's legend showed 17 digits (issue 41, Low)
    assert all(repr(v) == repr(round(v, 2)) and len(repr(v).split('.')[1]) <= 2
               for d in (out.last, out.max) for v in d.values()), (out.last, out.max)
    assert out.stamp_ns == 60_000 + 2 * 20_000          # the last sample at 50 kHz
    assert lt.flush() is None
    lt.add(block(120_000, [5.0]))
    assert lt.flush().blocks == 1


def test_pull_trace_is_the_loaded_window_with_margin_at_full_rate():
    rate = 1000.0
    s = np.zeros(100)
    s[40:60] = np.hanning(22)[1:-1] * 100.0
    window = loaded_window(s)
    assert s[window.start] > 10.0 and s[window.start - 1] <= 10.0 and s[window.stop - 1] > 10.0
    traces = PullTraces(margin_s=0.005, max_s=10.0, timeout_s=1.0)
    traces.start(4, 2, 0)
    traces.end(4, 100 * MS, now_ns=0)
    out = []
    for k in range(10):
        out += traces.add(block(k * 10 * MS, s[10 * k:10 * k + 10], rate=rate), now_ns=0)
    assert len(out) == 1
    t = out[0]
    assert (t.pull_id, t.test_set) == (4, 2)
    n = window.stop - window.start + 10
    assert t.time_s.size == n and t.time_s[0] == pytest.approx((window.start - 5) / rate)
    assert np.allclose(np.diff(t.time_s), 1 / rate)
    assert max(t.signals['stationary']) == pytest.approx(s.max() / LBF_N)


def test_a_lost_block_is_a_gap_of_nan_on_a_uniform_time_axis():
    # the monitor subscribes best effort: a block it lost must not close up the trace's time axis
    rate = 1000.0
    traces = PullTraces(margin_s=0.0, max_s=10.0, timeout_s=1.0)
    traces.start(1, 1, 0)
    traces.end(1, 40 * MS, now_ns=0)
    out = []
    for k in (0, 1, 3):  # block 2 lost
        out += traces.add(block(k * 10 * MS, np.full(10, 5.0 + k), rate=rate), now_ns=0)
    (t,) = out
    assert t.time_s.size == 40 and np.allclose(np.diff(t.time_s), 1 / rate)
    st = t.signals['stationary']
    assert np.isnan(st[20:30]).all() and np.isfinite(np.delete(st, np.s_[20:30])).all()
    assert st[30] == pytest.approx(8.0 / LBF_N)


def test_pull_trace_goes_out_after_the_timeout_when_data_stops_short():
    traces = PullTraces(margin_s=0.0, max_s=10.0, timeout_s=1.0)
    traces.start(1, 1, 0)
    assert traces.add(block(0, [0.1, 5.0, 0.1], rate=1000.0), now_ns=0) == []
    traces.end(1, 10 * MS, now_ns=0)
    assert traces.expire(NS_PER_S // 2) == []
    # a lagging stream that is still coming keeps the pull open past the timeout
    assert traces.add(block(3 * MS, [0.1, 0.1], rate=1000.0), now_ns=NS_PER_S // 2) == []
    assert traces.expire(NS_PER_S) == []
    (t,) = traces.expire(3 * NS_PER_S // 2)
    assert t.time_s.size == 1 and t.signals['stationary'][0] == pytest.approx(5.0 / LBF_N)


def test_a_batch_with_malformed_messages_keeps_the_good_ones():
    counts = {f: np.full(3, 50) for f in FORCE_FIELDS}
    buf, starts, lengths = encode_blocks(np.array([NS_PER_S, NS_PER_S + MS, NS_PER_S + 2 * MS]), 5e4,
                                         np.arange(3), FORCE_FIELDS, counts,
                                         {f: np.arange(150.0) for f in FORCE_FIELDS})
    msgs = [bytes(buf[a:a + n]) for a, n in zip(starts, lengths)]
    bad_rate = bytearray(msgs[1])
    bad_rate[4 + 16:4 + 24] = np.float64(0.0).tobytes()  # sample_rate_hz = 0 (frame_id '' -> offset 16)
    items = [(1, msgs[0]), (2, b'\x00\x01\x00\x00garbage'), (3, bytes(bad_rate)), (4, msgs[2])]
    b = decode_batch(items, FORCE_FIELDS)
    assert list(b.arrival_ns) == [1, 4] and list(b.seq) == [0, 2] and len(b.problems) == 2
    assert 'sample_rate_hz 0.0' in b.problems[1]
    assert np.array_equal(b.values['stationary_n'][1], np.arange(100.0, 150.0))
    nan_msg = bytearray(msgs[0])
    nan_msg[-8:] = np.float64(np.nan).tobytes()
    assert decode_batch([(1, bytes(nan_msg))], FORCE_FIELDS).nan_samples == 1


def test_params_name_the_value_and_the_range():
    with pytest.raises(MonitorError, match=r'port 70000 is out of range; expected a value in \[0, 65535\]'):
        MonitorParams(port=70000)
    with pytest.raises(MonitorError, match="force_every 'x' is invalid"):
        MonitorParams(force_every='x')
    with pytest.raises(MonitorError, match="host 'lab-pc' is invalid; expected an IP address"):
        MonitorParams(host='lab-pc')
    assert MonitorParams(host='0.0.0.0').host == '0.0.0.0'


def test_a_score_in_lbf_states_the_corrected_peak_with_its_uncertainty():
    from types import SimpleNamespace
    score = SimpleNamespace(pull_id=3, test_set=2, status=0, stationary_peak_n=760 * LBF_N,
                            corrected_peak_n=750 * LBF_N, corrected_peak_u_n=6 * LBF_N, filtered_peak_n=700 * LBF_N,
                            filtered_peak_u_n=56 * LBF_N, coverage_factor=2.0, raw_diff_pct=31.5,
                            corrected_diff_pct=-1.25, filtered_diff_pct=4.0)
    out = score_lbf(score)
    assert (out['raw_diff_pct'], out['corrected_diff_pct'], out['filtered_diff_pct']) == (31.5, -1.25, 4.0)
    assert out['corrected_peak'] == '750.0 lbf +/- 6.0 lbf (k = 2)'
    assert out['corrected_peak_u_lbf'] == pytest.approx(6.0) and out['filtered_peak_u_lbf'] == pytest.approx(56.0)
    unknown = score_lbf(SimpleNamespace(**{**vars(score), 'corrected_peak_u_n': math.nan}))
    assert unknown['corrected_peak'] == '750.0 lbf'   # no U claimed where none is known


def test_score_history_lists_the_newest_pulls_first_and_the_validators_set_statistics():
    from types import SimpleNamespace

    from force_tester_monitor.core.history import ScoreHistory

    from force_tester_common.core.units import LBF_N

    def score(pull, test_set=1, u_n=26.7, status=0):
        return SimpleNamespace(pull_id=pull, test_set=test_set, status=status, stationary_peak_n=1000.0 + pull,
                               corrected_peak_n=1010.0, corrected_peak_u_n=u_n, filtered_peak_n=990.0,
                               filtered_peak_u_n=30.0, raw_diff_pct=30.123456,
                               corrected_diff_pct=1.006, filtered_diff_pct=-0.5, coverage_factor=2.0)
    history = ScoreHistory(rows=3)
    for pull in range(5):
        history.add_score(score(pull, status=pull % 2), stamp_ns=pull * 1_000_000_000)
    rows = history.pulls()
    assert [r['pull'] for r in rows] == [4, 3, 2]          # the newest three, newest first
    assert rows[0]['status'] == 'OK' and rows[1]['status'] == 'INCOMPLETE'
    assert rows[0]['stationary_lbf'] == round(1004.0 / LBF_N, 1)
    # each cell says what its ± is: the expanded uncertainty and its k (issue 41, Low: no table said so)
    assert rows[0]['corrected_lbf'] == f'{1010.0 / LBF_N:.1f} ± {26.7 / LBF_N:.1f} U k=2'
    assert (rows[0]['raw_pct'], rows[0]['corrected_pct']) == (30.12, 1.01)
    assert history.newest_stamp_ns() == 4_000_000_000 and history.coverage_factor == 2.0
    history.add_score(score(3, u_n=float('nan')), stamp_ns=3_000_000_000)   # pull 3 scored again: one row, moved up
    assert [r['pull'] for r in history.pulls()] == [3, 4, 2]
    assert history.pulls()[0]['corrected_lbf'] == f'{1010.0 / LBF_N:.1f}'
    nan = float('nan')
    summary = SimpleNamespace(test_set=2, pulls=4, stationary_peak_mean_n=3000.0, raw_diff_mean_pct=30.0,
                              raw_diff_std_pct=1.234, corrected_diff_mean_pct=2.0, corrected_diff_std_pct=nan,
                              filtered_diff_mean_pct=nan, filtered_diff_std_pct=nan)
    history.add_summary(summary)
    history.add_summary(SimpleNamespace(**{**vars(summary), 'test_set': 1}))
    assert [s['test_set'] for s in history.sets()] == [1, 2]
    assert history.sets()[1] == {'test_set': 2, 'pulls': 4, 'stationary_mean_lbf': round(3000.0 / LBF_N, 1),
                                 'raw_pct': '30.00 ± 1.23 sd', 'corrected_pct': '2.00', 'filtered_pct': '-'}
    with pytest.raises(MonitorError, match="history rows 0 is invalid"):
        ScoreHistory(rows=0)


def test_the_nodes_panel_rows_are_one_short_line_stale_when_silent_and_hold_the_worst():
    """/monitor/nodes (issue 41): a long message is cut to one line (the whole text in values 'detail'); a node
    silent for STALE_S is STALE with how long it has been silent; a newer OK does not hide an ERROR of the
    last HOLD_S seconds, which goes once HOLD_S has passed."""
    from force_tester_monitor.core.nodes import DETAIL_KEY, SHORT_MESSAGE_CHARS, node_rows, short_message

    from force_tester_common.core.health import HOLD_S, LEVEL_ERROR, LEVEL_OK, LEVEL_STALE, STALE_S, NodeStates
    long = ('(re)started: m = 1.152 kg, N = 140 (the moving average lags the peak by 70 samples, 1.4 ms at 50 kHz;'
            ' see docs/thesis.md), extension: none')
    short, detail = short_message(long)
    assert len(short) <= SHORT_MESSAGE_CHARS and short.endswith('\u2026') and '\n' not in short and detail == long
    assert short_message('running') == ('running', '')
    states = NodeStates(hold_s=HOLD_S)
    states.add('correction: m*a correction', '', LEVEL_OK, long, [('blocks', '10')], 0)
    states.add('validator: pull scoring', '', LEVEL_ERROR, 'pull 3 not scored', [], 0)
    states.add('validator: pull scoring', '', LEVEL_OK, 'scoring', [('scores', '4')], NS_PER_S)
    rows = {r.name.split(':')[0]: r for r in node_rows(states.states(2 * NS_PER_S))}
    assert (rows['correction'].level, rows['correction'].message) == (LEVEL_OK, short)
    assert rows['correction'].values == ((DETAIL_KEY, long), ('blocks', '10'))
    assert (rows['validator'].level, rows['validator'].message) == (LEVEL_ERROR, 'pull 3 not scored')
    assert rows['validator'].values == (('scores', '4'),)
    later = int((HOLD_S + 0.5) * NS_PER_S)
    states.add('validator: pull scoring', '', LEVEL_OK, 'scoring', [('scores', '5')], later)
    rows = {r.name.split(':')[0]: r for r in node_rows(states.states(later))}
    assert (rows['validator'].level, rows['validator'].message) == (LEVEL_OK, 'scoring')
    assert rows['correction'].level == LEVEL_STALE and later / NS_PER_S > STALE_S
    assert rows['correction'].message == f'STALE: no report for {later / NS_PER_S:.0f} s'
    assert dict(rows['correction'].values)[DETAIL_KEY] == long


def test_a_monitor_that_missed_the_summaries_computes_each_sets_statistics_as_the_validator_does():
    """Issue 41: a monitor started (or restarted) mid-test hears only the validator's newest /set_summary (latched,
    depth 1) but every score (/pull_score keeps 1000): the sets it has no summary of get the validator's arithmetic
    over their OK scores; a set whose pulls are none OK gets a row that says so."""
    from types import SimpleNamespace

    from force_tester_monitor.core.history import NO_OK_PULL, ScoreHistory, set_row

    from force_correction.core.scoring import PullScoreResult, SetStatistics
    from force_tester_common.core.scores import PULL_INCOMPLETE, PULL_OK, SET_SUMMARY_FIELDS
    rng = np.random.default_rng(4)
    history, stats = ScoreHistory(rows=50), SetStatistics()
    for pull in range(9):
        test_set, status = 1 + pull % 3, PULL_INCOMPLETE if pull % 3 == 2 else PULL_OK
        values = dict(stationary_peak_n=float(rng.uniform(900, 1100)), raw_diff_pct=float(rng.normal(30, 3)),
                      corrected_diff_pct=float(rng.normal(2, 1)), filtered_diff_pct=float(rng.normal(-1, 1)))
        result = PullScoreResult(raw_peak_n=1.0, corrected_peak_n=1.0, filtered_peak_n=1.0, raw_rms_n=0.0,
                                 corrected_rms_n=0.0, filtered_rms_n=0.0, n_samples=10, n_loaded=5,
                                 loaded_fraction=0.5, **values)
        history.add_score(SimpleNamespace(pull_id=pull, test_set=test_set, status=status, corrected_peak_n=1.0,
                                          corrected_peak_u_n=1.0, filtered_peak_n=1.0, filtered_peak_u_n=1.0,
                                          coverage_factor=2.0, **values), stamp_ns=pull)
        if status == PULL_OK:
            stats.add(test_set, result)

    def validator_row(test_set):
        s = stats.summary(test_set)
        return set_row(SimpleNamespace(test_set=test_set, **{f: getattr(s, k) for f, k in SET_SUMMARY_FIELDS.items()}))
    history.add_summary(SimpleNamespace(test_set=2, **{f: getattr(stats.summary(2), k)
                                                       for f, k in SET_SUMMARY_FIELDS.items()}))
    assert history.sets() == [validator_row(1), validator_row(2),
                              {'test_set': 3, 'pulls': 0,
                               'stationary_mean_lbf': pytest.approx(float('nan'), nan_ok=True),
                               'raw_pct': NO_OK_PULL, 'corrected_pct': NO_OK_PULL, 'filtered_pct': NO_OK_PULL}]
    assert history.sets()[0]['pulls'] == 3 and '±' in history.sets()[0]['raw_pct']


def test_a_second_run_of_the_sim_keeps_the_first_runs_rows():
    """Issue 41: pull ids restart at 0 when the sim runs again with the graph up; rows are keyed by the pull's
    start stamp too, so the first run's rows stay (and its OK scores stay in the set's statistics)."""
    from types import SimpleNamespace

    from force_tester_monitor.core.history import ScoreHistory

    def score(pull):
        return SimpleNamespace(pull_id=pull, test_set=3, status=0, stationary_peak_n=1000.0 + pull,
                               corrected_peak_n=1010.0, corrected_peak_u_n=1.0, filtered_peak_n=990.0,
                               filtered_peak_u_n=1.0, raw_diff_pct=30.0, corrected_diff_pct=1.0,
                               filtered_diff_pct=-0.5, coverage_factor=2.0)
    history = ScoreHistory(rows=10)
    for run in range(2):
        for pull in range(2):
            history.add_score(score(pull), stamp_ns=(100 * run + pull) * NS_PER_S)
    assert [r['pull'] for r in history.pulls()] == [1, 0, 1, 0]
    assert history.sets()[0]['pulls'] == 4
    history.add_score(score(1), stamp_ns=101 * NS_PER_S)   # the second run's pull 1 scored again: replaced
    assert [r['pull'] for r in history.pulls()] == [1, 0, 1, 0] and history.sets()[0]['pulls'] == 4
