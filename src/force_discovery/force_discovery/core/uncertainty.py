"""Uncertainty of fitted parameters from the pull-to-pull spread (the statistical part of each budget: budget.py adds
the systematic parts and expands the interval), and the practical-significance verdict.

- Pooled fits (the force model's gain, mass, delay, AC coupling) get a delete-one-pull jackknife over the
  fitted pulls: se^2 = (n - 1)/n sum (theta_(-k) - mean)^2, interval theta +/- t(0.975, n - 1) se.
- Statistics of per-pull estimates (a median mode frequency, a median friction offset, a mean hum amplitude)
  get a seeded percentile bootstrap over pulls (BOOTSTRAP_RESAMPLES resamples).

A cause is acted on only when it is statistically significant on held-out pulls AND its 95 % interval lies
wholly outside its tolerance band (force_tester_sim.core.tolerances). Otherwise it is reported as
`within_tolerance` (interval inside the band, significant or not), `inconclusive` (significant, interval
straddles a band edge; with the number of pulls that would settle it, from the interval's statistical part
shrinking as 1/sqrt(n), its systematic part not at all) or `not_significant`.
"""
from __future__ import annotations

import math
from typing import Callable, List, Optional, Sequence, Tuple

import numpy as np

from force_tester_sim.core.tolerances import Band

CONFIDENCE = 0.95
BOOTSTRAP_RESAMPLES = 2000
BOOTSTRAP_SEED = 20130           # fixed: the same data give the same report

NAMED, WITHIN, INCONCLUSIVE, NOT_SIGNIFICANT = 'named', 'within_tolerance', 'inconclusive', 'not_significant'
# the verdicts a campaign of 1-3 pulls can give (the reference-free path's leave-one-out): one pull has no interval;
# 2-3 held-out pulls cannot meet t >= MIN_T, so what departs on every one of them is indicated, not named
PER_PULL_ONLY, INDICATED, NOT_INDICATED = 'per_pull_only', 'indicated', 'not_indicated'
# no rig given (the reference-free path without --rig): no nominal and no tolerance band to judge an estimate
# against; it is reported with what it means, never named
NOT_JUDGED = 'not_judged'


def t_quantile(n: int) -> float:
    """Two-sided CONFIDENCE quantile of Student's t with n - 1 degrees of freedom (normal for n < 2)."""
    from scipy.stats import norm, t
    q = 0.5 + CONFIDENCE / 2
    return float(t.ppf(q, n - 1)) if n >= 2 else float(norm.ppf(q))


def jackknife_se(leave_one_out: np.ndarray) -> np.ndarray:
    """The jackknife standard error of an estimate (or, column by column, of several) from its delete-one-pull
    refits (one row per pull left out): sqrt((n - 1)/n sum (theta_(-k) - mean)^2)."""
    loo = np.asarray(leave_one_out, float)
    n = len(loo)
    return np.sqrt((n - 1) / n * np.sum((loo - loo.mean(0)) ** 2, axis=0))


def jackknife_ci(estimate: float, leave_one_out: Sequence[float]) -> Tuple[float, float]:
    """CONFIDENCE interval of a pooled estimate from its delete-one-pull refits."""
    loo = np.asarray(leave_one_out, float)
    n = len(loo)
    if n < 2 or not np.all(np.isfinite(loo)):
        return -math.inf, math.inf
    h = t_quantile(n) * float(jackknife_se(loo))
    return float(estimate - h), float(estimate + h)


def bootstrap_ci(values: Sequence, statistic: Callable[[np.ndarray], float] = np.median) -> Tuple[float, float]:
    """CONFIDENCE percentile-bootstrap interval of statistic(values) over pulls (values: one row per pull)."""
    v = np.asarray(values, float)
    n = len(v)
    if n < 2:
        return -math.inf, math.inf
    rng = np.random.default_rng(BOOTSTRAP_SEED)
    idx = rng.integers(0, n, size=(BOOTSTRAP_RESAMPLES, n))
    if v.ndim == 1 and statistic in (np.median, np.mean):   # the same statistic of every resample, in one call
        stats = statistic(v[idx], axis=1)
    else:
        stats = np.array([statistic(v[i]) for i in idx])
    a = (1 - CONFIDENCE) / 2
    return float(np.quantile(stats, a)), float(np.quantile(stats, 1 - a))


def pulls_to_settle(estimate: float, ci: Tuple[float, float], band: Band, n: int,
                    fixed_half: float = 0.0) -> Optional[int]:
    """Pulls needed for the interval to clear the nearer band edge; None if never. Of its half-width h, the part
    fixed_half (the expanded systematic part, budget.py) does not shrink with more pulls; the statistical rest,
    sqrt(h^2 - fixed_half^2), shrinks as 1/sqrt(n)."""
    lo, hi = ci
    if not (math.isfinite(lo) and math.isfinite(hi)):
        return None
    half = 0.5 * (hi - lo)
    dist = band.distance(estimate)
    stat = math.sqrt(max(0.0, half * half - fixed_half * fixed_half))
    room = dist * dist - fixed_half * fixed_half
    if dist <= 0 or stat <= 0 or room <= 0:
        return None
    return int(math.ceil(n * stat * stat / room))


def verdict_rule(inside: bool, outside: bool, significant: bool, can_name: bool = True, departs: bool = False,
                 one_pull: bool = False) -> str:
    """The one verdict rule of both paths (the module doc): inside/outside, the 95 % interval lies wholly inside /
    wholly outside the tolerance band; significant, the held-out test passed. can_name: enough held-out pulls for
    the test to name a cause (the reference-free path's MIN_NAMED_PULLS; always with a reference); below it,
    departs says whether the cause departs consistently (every held-out pull better with it). one_pull: a single
    pull, per-pull estimates only."""
    if one_pull:
        return PER_PULL_ONLY
    if inside:
        return WITHIN            # significant or not: whatever it is, it does not matter
    if not can_name:
        return INDICATED if departs else NOT_INDICATED
    if not significant:
        return NOT_SIGNIFICANT
    return NAMED if outside else INCONCLUSIVE


def verdict(estimate: float, ci: Tuple[float, float], band: Band, significant: bool, n: int,
            fixed_half: float = 0.0) -> dict:
    """The practical-significance verdict of one candidate (verdict_rule) with its band, estimate, interval and
    pulls (report.json's `tolerance`); fixed_half: the part of the interval's half-width that more pulls do not
    shrink (pulls_to_settle)."""
    lo, hi = ci
    out = {'band': band.as_dict(), 'estimate': float(estimate), 'ci95': [float(lo), float(hi)], 'pulls': int(n)}
    out['verdict'] = verdict_rule(band.contains(lo, hi), band.excludes(lo, hi), significant)
    if out['verdict'] == INCONCLUSIVE:
        out['pulls_to_settle'] = pulls_to_settle(estimate, ci, band, n, fixed_half)
    return out


def mean_ci(x: Sequence[float]) -> Optional[List[float]]:
    """CONFIDENCE interval of the mean of x (Student t; None for fewer than 2 values)."""
    x = np.asarray(x, float)
    if len(x) < 2:
        return None
    h = t_quantile(len(x)) * float(np.std(x, ddof=1)) / math.sqrt(len(x))
    return [float(x.mean() - h), float(x.mean() + h)]
