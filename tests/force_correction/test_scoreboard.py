"""The live scoreboard's arithmetic (force_correction.core.scoreboard): rows in lbf, per-set running
mean and sample std over the OK pulls, grades against the threshold, counter rates."""
import math
from types import SimpleNamespace

import numpy as np
import pytest

from force_correction.core.scoreboard import FAIR, GOOD, NONE, POOR, CounterRate, Scoreboard, grade
from force_tester_common.core.clock import NS_PER_S
from force_tester_common.core.scores import PULL_INCOMPLETE, PULL_OK, PULL_SCORE_FIELDS
from force_tester_common.core.units import LBF_N


def score(pull_id, test_set, raw, corr, filt, status=PULL_OK, stat_n=1000.0, dropped=0):
    fields = {k: 0.0 for k in PULL_SCORE_FIELDS}
    fields.update(stationary_peak_n=stat_n, raw_peak_n=stat_n * (1 + raw / 100),
                  corrected_peak_n=stat_n * (1 + corr / 100), filtered_peak_n=stat_n * (1 + filt / 100),
                  raw_diff_pct=raw, corrected_diff_pct=corr, filtered_diff_pct=filt)
    return SimpleNamespace(pull_id=pull_id, test_set=test_set, status=status, dropped_blocks=dropped,
                           detail='', **fields)


def test_grade_against_the_threshold():
    assert [grade(v, 5.0) for v in (0.0, 5.0, 5.1, 10.0, 10.1, -12.0, math.nan)] == \
        [GOOD, GOOD, FAIR, FAIR, POOR, POOR, NONE]


def test_rows_in_lbf_and_running_set_statistics_over_ok_pulls():
    board = Scoreboard(threshold_pct=3.0)
    rng = np.random.default_rng(4)
    diffs = {1: rng.uniform(0, 20, (4, 3)), 3: rng.uniform(0, 60, (3, 3))}
    pid = 0
    for s, rows in diffs.items():
        for raw, corr, filt in rows:
            board.add(score(pid, s, raw, corr, filt, stat_n=800.0 + pid), start_ns=pid * NS_PER_S)
            pid += 1
    board.add(score(pid, 3, 99.0, 99.0, 99.0, status=PULL_INCOMPLETE, dropped=4), start_ns=pid * NS_PER_S)
    rows = board.rows()
    assert [r.pull_id for r in rows] == list(range(8))
    assert rows[0].stationary_lbf == pytest.approx(800.0 / LBF_N)
    assert rows[2].raw_lbf == pytest.approx(802.0 * (1 + diffs[1][2, 0] / 100) / LBF_N)
    assert rows[-1].status == 'INCOMPLETE' and rows[-1].dropped_blocks == 4
    assert [r.pull_id for r in board.rows(last=2)] == [6, 7]
    summaries = board.sets()
    assert [(s.set_id, s.pulls) for s in summaries] == [(1, 4), (3, 3)]     # the INCOMPLETE pull is left out
    for s in summaries:
        d = diffs[s.set_id]
        for k, col in (('raw', 0), ('corrected', 1), ('filtered', 2)):
            assert getattr(s, f'{k}_mean_pct') == pytest.approx(d[:, col].mean())
            assert getattr(s, f'{k}_std_pct') == pytest.approx(d[:, col].std(ddof=1))
    g = board.grades(rows[0])
    assert g['raw'] == grade(diffs[1][0, 0], 3.0)


def test_a_score_delivered_again_replaces_its_row():
    board = Scoreboard()
    board.add(score(0, 1, 10.0, 2.0, 1.0), start_ns=7)
    board.add(score(0, 1, 10.0, 2.0, 1.0), start_ns=7)     # latched, or the same bag played again
    board.add(score(0, 1, 12.0, 2.0, 1.0), start_ns=9)     # a new run
    assert len(board) == 2 and board.sets()[0].pulls == 2


def test_counter_rate_and_restart():
    r = CounterRate(min_span_s=1.0)
    assert math.isnan(r.add(0, 0))
    r.add(NS_PER_S // 2, 500)
    assert r.add(NS_PER_S, 1000) == pytest.approx(1000.0)
    assert r.add(2 * NS_PER_S, 3000) == pytest.approx(2000.0)    # the last second only
    assert math.isnan(r.add(3 * NS_PER_S, 10))                    # restarted node
