"""Significance: does a cause lower its channel's squared residual on the held-out pulls, by enough and
consistently over them? ROS-free."""
from __future__ import annotations

import math

import numpy as np

from .candidate import Evidence

MIN_REL_REDUCTION = 0.01      # held-out SSE must fall by at least 1 %
MIN_T = 4.0                   # and consistently over held-out pulls
MIN_UNANIMOUS = 5             # held-out pulls that must all agree before one model is preferred to another of as many
                              # parameters by their signs alone (lower_on_every_pull: by chance 1 in 2^5 = 3 %)


def significance(base: np.ndarray, ext: np.ndarray) -> Evidence:
    """The test on the held-out per-pull SSE without (base) and with (ext) a cause."""
    d = 1.0 - ext / np.maximum(base, 1e-300)   # per-pull relative reductions
    rel = float(1.0 - ext.sum() / base.sum()) if base.sum() > 0 else 0.0
    sd = float(np.std(d, ddof=1)) if len(d) > 1 else 0.0
    tstat = float(np.mean(d) / (sd / math.sqrt(len(d)))) if sd > 0 else (math.inf if np.mean(d) > 0 else 0.0)
    return Evidence(statistic='held-out SSE reduction and t of the per-pull relative reductions',
                    rel_sse_reduction=rel, t=tstat, threshold=f'rel >= {MIN_REL_REDUCTION:g} and t >= {MIN_T:g}',
                    significant=bool(rel >= MIN_REL_REDUCTION and tstat >= MIN_T),
                    rms_gain=float(math.sqrt(base.sum() / ext.sum())) if ext.sum() > 0 else math.inf)


def lower_on_every_pull(base: np.ndarray, ext: np.ndarray) -> bool:
    """Whether ext (held-out per-pull SSE) is below base on every one of at least MIN_UNANIMOUS held-out pulls, and
    by MIN_REL_REDUCTION of the summed SSE: between two models with as many parameters, which one the held-out pulls
    prefer. Not a test for adding a cause (significance is): a term whose size differs from pull to pull lowers every
    pull by a different share, and the t of those shares can stay under MIN_T though no pull disagrees."""
    return bool(len(base) >= MIN_UNANIMOUS and np.all(ext < base)
                and base.sum() > 0 and 1.0 - ext.sum() / base.sum() >= MIN_REL_REDUCTION)
