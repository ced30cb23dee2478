"""Which score field goes where: the correction core's results <-> PullScore / SetSummary messages,
and the PullScore status codes (PullScore.msg defines them; a test checks these against it).

PullScore carries the core's PullScoreResult fields under the same names; SetSummary renames the
core's SetSummary fields (``SET_SUMMARY_FIELDS``: message field -> core attribute).
"""
import math
from typing import NamedTuple

import numpy as np

PULL_SCORE_FIELDS = ('stationary_peak_n', 'raw_peak_n', 'corrected_peak_n', 'filtered_peak_n',
                     'raw_diff_pct', 'corrected_diff_pct', 'filtered_diff_pct',
                     'raw_rms_n', 'corrected_rms_n', 'filtered_rms_n',
                     'corrected_peak_u_n', 'filtered_peak_u_n', 'coverage_factor')

SET_SUMMARY_FIELDS = {
    'pulls': 'pulls',
    'stationary_peak_mean_n': 'mean_stationary_peak_n',
    'raw_diff_mean_pct': 'raw_mean_pct', 'raw_diff_std_pct': 'raw_std_pct',
    'corrected_diff_mean_pct': 'corrected_mean_pct', 'corrected_diff_std_pct': 'corrected_std_pct',
    'filtered_diff_mean_pct': 'filtered_mean_pct', 'filtered_diff_std_pct': 'filtered_std_pct',
}

PULL_OK, PULL_INCOMPLETE, PULL_RECONFIGURED, PULL_ABORTED = 0, 1, 2, 3
PULL_STATUS_NAMES = {PULL_OK: 'OK', PULL_INCOMPLETE: 'INCOMPLETE', PULL_RECONFIGURED: 'RECONFIGURED',
                     PULL_ABORTED: 'ABORTED'}


class PullStatus(NamedTuple):
    """A pull's status code (PULL_*) and its detail ('' when there is none)."""

    code: int
    detail: str


def pull_status(dropped_blocks: int, notes=(), aborted: bool = False) -> PullStatus:
    """The status of a pull: ABORTED over INCOMPLETE over RECONFIGURED over OK.
    notes: (kind, text) pairs with kind 'incomplete' or 'reconfigured'."""
    kinds = {k for k, _ in notes}
    texts = [t for _, t in notes]
    if dropped_blocks:
        texts.insert(0, f'{dropped_blocks} block(s) missing')
    if aborted:
        code = PULL_ABORTED
    elif dropped_blocks or 'incomplete' in kinds:
        code = PULL_INCOMPLETE
    elif 'reconfigured' in kinds:
        code = PULL_RECONFIGURED
    else:
        code = PULL_OK
    return PullStatus(code, '; '.join(texts))


def peak_short(peak_lbf: float, u_lbf: float, k: float) -> str:
    """The same in a table's cell, whose column names the unit: '750.0 ± 6.0 U k=2' ('750.0' while U is not
    known, '-' while the peak is not): the cell says that ± is the expanded uncertainty and its k."""
    if peak_lbf != peak_lbf:
        return '-'
    return f'{peak_lbf:.1f}' if u_lbf != u_lbf else f'{peak_lbf:.1f} ± {u_lbf:.1f} U k={k:g}'


def mean_sd_text(mean: float, sd: float) -> str:
    """A set's mean and sample standard deviation in a table's cell: '2.39 ± 0.29 sd' ('2.39' for one value whose
    sd is not known, '-' for none): the cell says that ± is a standard deviation, not an uncertainty."""
    if mean != mean:
        return '-'
    return f'{mean:.2f}' if sd != sd else f'{mean:.2f} ± {sd:.2f} sd'


def peak_text(peak_lbf: float, u_lbf: float, k: float) -> str:
    """A corrected peak as a test engineer reports it: '750.0 lbf +/- 6.0 lbf (k = 2)' (the peak alone while U
    is not known, '-' while the peak is not)."""
    if peak_lbf != peak_lbf:
        return '-'
    if u_lbf != u_lbf:
        return f'{peak_lbf:.1f} lbf'
    return f'{peak_lbf:.1f} lbf +/- {u_lbf:.1f} lbf (k = {k:g})'


def mean_std(values) -> tuple:
    """(mean, sample standard deviation) of a set's per-pull values, NaN ones left out: (nan, nan) for none, std 0
    for one. The one arithmetic of a set's statistics (the validator's /set_summary; the monitor's rows of the
    sets it has no summary of)."""
    a = np.asarray(values, dtype=np.float64)
    a = a[~np.isnan(a)]
    if a.size == 0:
        return math.nan, math.nan
    return float(a.mean()), float(a.std(ddof=1)) if a.size > 1 else 0.0
