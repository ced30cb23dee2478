"""Per-pull scoring of the moving cell against the stationary cell (thesis eq 1, Tables 8, 9).

Eq 1 at the peaks: %Fdiff = |Fs_peak - F_peak| / Fs_peak * 100, peaks = max over the pull.
RMS errors are taken over the *loaded window*: the samples where the stationary force exceeds
``loaded_fraction`` times its peak (default 10 %), so the unloaded lead-in and the free ringing
after the break (where F_stat = -m1*a1, eq 21) do not dominate. NaNs are ignored throughout.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass, fields, replace
from typing import Dict, List, Optional

import numpy as np

from force_tester_common.core.clock import record_stamps_ns
from force_tester_common.core.correction import LOADED_FRACTION, LOADED_FRACTION_RANGE
from force_tester_common.core.scores import mean_std

from .errors import CorrectionError
from .peak_uncertainty import PeakInputs, peak_uncertainty


@dataclass(frozen=True)
class PullScoreResult:
    """Score of one pull. Forces in N, differences in %, RMS in N."""

    stationary_peak_n: float
    raw_peak_n: float
    corrected_peak_n: float
    filtered_peak_n: float
    raw_diff_pct: float
    corrected_diff_pct: float
    filtered_diff_pct: float
    raw_rms_n: float
    corrected_rms_n: float
    filtered_rms_n: float
    n_samples: int
    n_loaded: int
    loaded_fraction: float
    dropped_blocks: int = 0
    #: expanded uncertainty of corrected_peak_n / filtered_peak_n (N, k = coverage_factor; core/peak_uncertainty):
    #: NaN where the pull's m*a was not at hand (a score log of an older validator)
    corrected_peak_u_n: float = math.nan
    filtered_peak_u_n: float = math.nan
    coverage_factor: float = math.nan

    def __eq__(self, other):
        """Field by field, NaN equal to NaN (a score equals its round trip through the score log)."""
        if not isinstance(other, PullScoreResult):
            return NotImplemented
        return all(a == b or (a != a and b != b) for a, b in
                   ((getattr(self, f.name), getattr(other, f.name)) for f in fields(self)))

    __hash__ = None


def _arr(x, name: str) -> np.ndarray:
    a = np.asarray(x, dtype=np.float64)
    if a.ndim != 1:
        raise CorrectionError(f"{name} has shape {a.shape}; expected a 1-D array")
    return a


def _nanmax(a: np.ndarray) -> float:
    if not a.size:
        return math.nan
    m = a.max()          # the max of the same values in the same order when there is no NaN: one pass, no copy
    if m == m:
        return float(m)
    fin = a[~np.isnan(a)]
    return float(fin.max()) if fin.size else math.nan


def _rms(err: np.ndarray) -> float:
    if err.size:
        ms = np.mean(err * err)
        if ms == ms:          # no NaN among the errors: their mean square as it is, without a copy of them
            return float(np.sqrt(ms))
    fin = err[~np.isnan(err)]
    return float(np.sqrt(np.mean(fin * fin))) if fin.size else math.nan


def score_pull(stationary, raw, corrected, filtered, loaded_fraction: float = LOADED_FRACTION, *,
               inertial=None, sample_rate_hz: float | None = None, peak_inputs: PeakInputs | None = None
               ) -> PullScoreResult:
    """Score one pull; all inputs are per-sample arrays of equal length (N).

    Peak % difference per eq 1 (``|Fs_peak - F_peak| / Fs_peak * 100``, peaks = nanmax over the
    pull) and RMS of (signal - stationary) over the loaded window, i.e. the samples where the
    stationary force > ``loaded_fraction`` * stationary peak. Raises CorrectionError if the
    stationary peak is <= 0 or the stationary signal is all NaN.
    """
    lf = loaded_fraction
    lo, hi = LOADED_FRACTION_RANGE
    if isinstance(lf, bool) or not isinstance(lf, numbers.Real) or not lo <= float(lf) <= hi:
        raise CorrectionError(
            f"loaded_fraction {lf!r} is out of range; expected a float in [{lo}, {hi}]")
    lf = float(lf)
    s = _arr(stationary, 'stationary')
    sigs = {'raw': _arr(raw, 'raw'), 'corrected': _arr(corrected, 'corrected'),
            'filtered': _arr(filtered, 'filtered')}
    for k, a in sigs.items():
        if a.shape != s.shape:
            raise CorrectionError(
                f"{k} has {a.shape[0]} samples but stationary has {s.shape[0]}; "
                f"expected equal lengths")
    s_peak = _nanmax(s)
    if not s_peak > 0.0:  # also catches NaN (all-NaN or empty)
        raise CorrectionError(
            f"stationary peak {s_peak!r} N is not usable; expected a finite peak > 0 N")
    with np.errstate(invalid='ignore'):
        loaded = np.flatnonzero(s > lf * s_peak)     # the loaded samples (a short stretch): taken by index
    s_loaded = s[loaded]
    out = {}
    for k, a in sigs.items():
        pk = _nanmax(a)
        out[f'{k}_peak_n'] = pk
        out[f'{k}_diff_pct'] = abs(s_peak - pk) / s_peak * 100.0
        out[f'{k}_rms_n'] = _rms(a[loaded] - s_loaded)
    if inertial is not None and sample_rate_hz is not None and (   # a finite nanmax: a finite sample, no scan
            math.isfinite(out['corrected_peak_n']) or np.isfinite(sigs['corrected']).any()):
        ma = _arr(inertial, 'inertial')
        if ma.shape != s.shape:
            raise CorrectionError(f"inertial has {ma.shape[0]} samples but stationary has {s.shape[0]}; "
                                  "expected equal lengths")
        pu = peak_uncertainty(sigs['corrected'], ma, sigs['filtered'], sample_rate_hz,
                              PeakInputs() if peak_inputs is None else peak_inputs,
                              filtered_peak=out['filtered_peak_n'])
        out.update(corrected_peak_u_n=pu.expanded_n, filtered_peak_u_n=pu.filtered_expanded_n,
                   coverage_factor=pu.k)
    return PullScoreResult(stationary_peak_n=s_peak, n_samples=int(s.shape[0]),
                           n_loaded=int(loaded.size), loaded_fraction=lf, **out)


_FIELDS = ('stationary', 'raw', 'corrected', 'filtered', 'inertial')


class PullAccumulator:
    """Collects the samples of one pull, block by block, and scores it at the end.

    The pull covers sample times t with start_ns <= t < end_ns (integer ns; end open until
    :meth:`finish`). A block's samples are stamped by the sample clock (``record_stamps_ns``), so a
    block straddling the start or end contributes exactly its samples inside the pull.
    Blocks may arrive after ``finish`` (late); they are still assigned by their sample times.
    """

    def __init__(self, start_ns: int, end_ns: Optional[int] = None, set_id=None, pull_id=None):
        if not _is_int(start_ns):
            raise CorrectionError(f"start_ns {start_ns!r} is not an int; expected integer ns")
        self.start_ns = int(start_ns)
        self.end_ns: Optional[int] = None
        self.set_id = set_id
        self.pull_id = pull_id
        self.dropped_blocks = 0
        self.lost_peak_n = -math.inf      # the largest stationary force of the blocks lost (note_dropped)
        self.sample_rate_hz: Optional[float] = None
        self._parts: Dict[str, List[np.ndarray]] = {k: [] for k in _FIELDS}
        self._times: List[np.ndarray] = []
        if end_ns is not None:
            self.finish(end_ns)

    @property
    def finished(self) -> bool:
        return self.end_ns is not None

    @property
    def n_samples(self) -> int:
        return int(sum(t.shape[0] for t in self._times))

    def finish(self, end_ns: int) -> None:
        if not _is_int(end_ns) or int(end_ns) <= self.start_ns:
            raise CorrectionError(
                f"end_ns {end_ns!r} is out of range; expected an integer ns > start_ns "
                f"{self.start_ns}")
        self.end_ns = int(end_ns)
        if self._times:  # trim samples already taken beyond the end
            for i, t in enumerate(self._times):
                keep = t < self.end_ns
                if not keep.all():
                    self._times[i] = t[keep]
                    for k in _FIELDS:
                        self._parts[k][i] = self._parts[k][i][keep]

    def note_dropped(self, count: int = 1, lost_peak_n: float = math.nan) -> None:
        """Record blocks lost during the pull (reported in the score), and the largest stationary force they
        carried, when known: a pull whose stationary peak fell in them is not scored (score())."""
        self.dropped_blocks += int(count)
        if lost_peak_n > self.lost_peak_n:   # NaN: not known, never larger
            self.lost_peak_n = float(lost_peak_n)

    def add_block(self, stamp_ns: int, sample_rate_hz: float, stationary, raw, corrected,
                  filtered, inertial=None) -> int:
        """Add one block; returns the number of its samples that fall inside the pull. inertial: the block's
        m*a (N), for the peak's uncertainty (NaN when not given)."""
        if not _is_int(stamp_ns):
            raise CorrectionError(f"stamp_ns {stamp_ns!r} is not an int; expected integer ns")
        rate = float(sample_rate_hz)
        if not math.isfinite(rate) or rate <= 0:
            raise CorrectionError(
                f"sample_rate_hz {sample_rate_hz!r} is out of range; expected a rate > 0 Hz")
        n0 = np.shape(stationary)[0] if np.ndim(stationary) else 1
        if inertial is None:
            inertial = np.full(n0, np.nan)
        arrs = [_arr(x, k) for k, x in zip(_FIELDS, (stationary, raw, corrected, filtered, inertial))]
        n = arrs[0].shape[0]
        for k, a in zip(_FIELDS, arrs):
            if a.shape[0] != n:
                raise CorrectionError(
                    f"{k} has {a.shape[0]} samples but stationary has {n}; expected equal")
        t = record_stamps_ns(int(stamp_ns), n, rate)
        keep = t >= self.start_ns
        if self.end_ns is not None:
            keep &= t < self.end_ns
        cnt = int(np.count_nonzero(keep))
        self.sample_rate_hz = rate
        if cnt:
            self._times.append(t[keep])
            for k, a in zip(_FIELDS, arrs):
                self._parts[k].append(a[keep].copy())
        return cnt

    def arrays(self) -> Dict[str, np.ndarray]:
        """Samples collected so far, sorted by sample time: keys time_ns + the four signals."""
        if not self._times:
            e = np.empty(0)
            return {'time_ns': np.empty(0, dtype=np.int64), **{k: e for k in _FIELDS}}
        t = np.concatenate(self._times)
        order = np.argsort(t, kind='stable')
        out = {'time_ns': t[order]}
        for k in _FIELDS:
            out[k] = np.concatenate(self._parts[k])[order]
        return out

    def score(self, loaded_fraction: float = LOADED_FRACTION, peak_inputs: PeakInputs | None = None
              ) -> PullScoreResult:
        a = self.arrays()
        # m*a known for every sample the corrected force has (not for a pull begun without it)
        fin = np.isfinite(a['inertial'])
        known = bool(fin.any()) and np.array_equal(fin, np.isfinite(a['corrected']))
        res = score_pull(a['stationary'], a['raw'], a['corrected'], a['filtered'], loaded_fraction=loaded_fraction,
                         inertial=a['inertial'] if known else None,
                         sample_rate_hz=self.sample_rate_hz if known else None, peak_inputs=peak_inputs)
        if self.lost_peak_n > res.stationary_peak_n:
            raise CorrectionError(f'the stationary peak fell in the {self.dropped_blocks} lost block(s): '
                                  f'{self.lost_peak_n:.4g} N there, {res.stationary_peak_n:.4g} N in what arrived; '
                                  'expected the peak among the scored samples')
        return replace(res, dropped_blocks=self.dropped_blocks)


def _is_int(x) -> bool:
    return isinstance(x, numbers.Integral) and not isinstance(x, bool)


@dataclass(frozen=True)
class SetSummary:
    """Per-set statistics like thesis Tables 8 and 9 (std is the sample std, ddof=1)."""

    set_id: object
    pulls: int
    mean_stationary_peak_n: float
    raw_mean_pct: float
    raw_std_pct: float
    corrected_mean_pct: float
    corrected_std_pct: float
    filtered_mean_pct: float
    filtered_std_pct: float


class SetStatistics:
    """Running per-set list of pull scores."""

    def __init__(self):
        self._scores: Dict[object, List[PullScoreResult]] = {}

    def add(self, set_id, result: PullScoreResult) -> None:
        if not isinstance(result, PullScoreResult):
            raise CorrectionError(f"result {result!r} is not a PullScoreResult")
        self._scores.setdefault(set_id, []).append(result)

    def sets(self) -> list:
        return list(self._scores)

    def scores(self, set_id) -> List[PullScoreResult]:
        return list(self._scores.get(set_id, []))

    def summary(self, set_id) -> SetSummary:
        res = self._scores.get(set_id)
        if not res:
            raise CorrectionError(
                f"set {set_id!r} has no scored pulls; expected one of {self.sets()}")
        out = {}
        for k in ('raw', 'corrected', 'filtered'):
            out[f'{k}_mean_pct'], out[f'{k}_std_pct'] = mean_std(
                [getattr(r, f'{k}_diff_pct') for r in res])
        return SetSummary(set_id=set_id, pulls=len(res),
                          mean_stationary_peak_n=float(np.mean(
                              [r.stationary_peak_n for r in res])), **out)
