"""The score history (ROS-free): the pulls scored so far and each test set's running statistics, as the rows
of /monitor/score_history (ScoreRow, SetRow; display units, rounded for reading).

The set statistics are the validator's (its /set_summary, the last one per set). The validator latches only its
newest summary, so a monitor started (or restarted) mid-test hears one set's; each set it has no summary of gets
the same statistics from the OK scores it holds (the latched /pull_score history), with the validator's arithmetic
(``force_tester_common.core.scores.mean_std``). A pull scored again (the validator re-scores a pull it had scored
from partial data) replaces its row.
"""
from __future__ import annotations

from collections import OrderedDict
from types import SimpleNamespace

from force_tester_common.core.scores import PULL_OK, PULL_STATUS_NAMES, mean_sd_text, mean_std, peak_short
from force_tester_common.core.units import n_to_lbf

from .errors import MonitorError
from .live import score_lbf

DIFFS = ('raw', 'corrected', 'filtered')
NO_OK_PULL = 'no OK pull'   # a set's row while none of its pulls is OK (its statistics are over OK pulls)


def _lbf(value_n: float) -> float:
    return round(float(n_to_lbf(float(value_n))), 1)


def _pct(value: float) -> float:
    return round(float(value), 2)


def score_row(score) -> dict:
    """A PullScore (or anything with its fields) as a ScoreRow's fields: MonitorScore's (score_lbf), rounded."""
    s = score_lbf(score)
    return {'pull': s['pull_id'], 'test_set': s['test_set'],
            'status': PULL_STATUS_NAMES.get(s['status'], str(s['status'])),
            'stationary_lbf': round(s['stationary_peak_lbf'], 1),
            'corrected_lbf': peak_short(s['corrected_peak_lbf'], s['corrected_peak_u_lbf'], s['coverage_factor']),
            **{f'{d}_pct': _pct(s[f'{d}_diff_pct']) for d in DIFFS}}


def set_row(summary) -> dict:
    """A SetSummary message (or anything with its fields) as a SetRow's fields."""
    return {'test_set': int(summary.test_set), 'pulls': int(summary.pulls),
            'stationary_mean_lbf': _lbf(summary.stationary_peak_mean_n),
            **{f'{d}_pct': mean_sd_text(getattr(summary, f'{d}_diff_mean_pct'), getattr(summary, f'{d}_diff_std_pct'))
               for d in DIFFS}}


class ScoreHistory:
    """The newest ``rows`` scored pulls and the last summary of each test set."""

    def __init__(self, rows: int):
        if not (isinstance(rows, int) and rows >= 1):
            raise MonitorError(f'history rows {rows!r} is invalid; expected an integer >= 1')
        self.rows = rows
        self._pulls: OrderedDict = OrderedDict()   # (test_set, pull_id, start ns) -> (start ns, ScoreRow fields)
        self._sets: dict = {}                      # test_set -> SetRow fields (the validator's summary)
        self._ok: dict = {}                        # test_set -> {(pull_id, start stamp ns): OK score}
        self.coverage_factor = float('nan')

    def add_score(self, score, stamp_ns: int) -> None:
        # keyed by the pull's start stamp too: a second run of the sim numbers its pulls from 0 again, and its
        # rows must not replace the first run's (a pull scored again has its stamp: its row is replaced)
        key = (int(score.test_set), int(score.pull_id), int(stamp_ns))
        self._pulls.pop(key, None)
        self._pulls[key] = (int(stamp_ns), score_row(score))
        while len(self._pulls) > self.rows:
            self._pulls.popitem(last=False)
        self.coverage_factor = float(score.coverage_factor)
        kept = self._ok.setdefault(key[0], {})
        kept.pop(key[1:], None)
        if int(score.status) == PULL_OK:
            kept[key[1:]] = score

    def add_summary(self, summary) -> None:
        self._sets[int(summary.test_set)] = set_row(summary)

    def newest_stamp_ns(self) -> int:
        return max((s for s, _ in self._pulls.values()), default=0)

    def pulls(self) -> list:
        """ScoreRow fields, newest first."""
        return [row for _, row in reversed(self._pulls.values())]

    def sets(self) -> list:
        """SetRow fields, by test set: the validator's summary, else one computed from the OK scores held, else (a
        set with scores but none OK) a row that says so."""
        rows = dict(self._sets)
        for test_set, kept in self._ok.items():
            if test_set in rows:
                continue
            rows[test_set] = set_row(summary_of(test_set, list(kept.values()))) if kept else {
                'test_set': test_set, 'pulls': 0, 'stationary_mean_lbf': float('nan'),
                **{f'{d}_pct': NO_OK_PULL for d in DIFFS}}
        return [rows[k] for k in sorted(rows)]


def summary_of(test_set: int, scores: list) -> SimpleNamespace:
    """A SetSummary's fields from a set's OK scores, as the validator computes them."""
    out = {'test_set': test_set, 'pulls': len(scores),
           'stationary_peak_mean_n': float(sum(float(s.stationary_peak_n) for s in scores) / len(scores))}
    for d in DIFFS:
        out[f'{d}_diff_mean_pct'], out[f'{d}_diff_std_pct'] = mean_std([getattr(s, f'{d}_diff_pct') for s in scores])
    return SimpleNamespace(**out)
