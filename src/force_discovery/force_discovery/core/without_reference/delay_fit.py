"""F = G a(t + d) + offset fitted on a grid of delays d (the reference-free path's gain and delay): a band-limited
shift of a channel, the grid, its parabola-refined minimum. ROS-free."""
from __future__ import annotations

import math
from typing import Sequence, Tuple

import numpy as np

from force_tester_sim.core.shift import Shifter

from ..force_model import DELAY_MAX_S, DELAY_STEP_MAX_S

DELAY_STEP_SHARE = 0.25        # the delay grid's step, in samples ...
DELAY_STEP_MIN_S = 2.5e-6      # ... but not finer than this (a parabola refines the minimum), nor coarser than
                               # DELAY_STEP_MAX_S: the pooled fits interpolate each pull's normal equations linearly
                               # between grid delays, which biases G = fa / aa by O(step^2) (1.7 % low at a 50 us
                               # step, 5 kHz with a 60 us delay; 0.03 % at 5 us)
ALIAS_SHARE = 0.01             # local SSE minima this close (share of its range) to the least are equal fits
DELAY_LOCAL_STEPS = 8          # refits search this many steps either side of the first estimate(s)


def fit_at(fm: np.ndarray, a: np.ndarray, w: np.ndarray) -> Tuple[float, float]:
    """(G, SSE) of fm = G a + offset on the samples w (least squares, closed form)."""
    f = fm[w] - np.mean(fm[w])
    x = a[w] - np.mean(a[w])
    xx, xf = float(x @ x), float(x @ f)
    g = xf / xx if xx > 0 else 0.0
    return g, float(f @ f) - g * xf


def delay_grid(dt: float, around: Sequence[float] = ()) -> np.ndarray:
    """The delays tried: +/-DELAY_MAX_S in steps of DELAY_STEP_SHARE samples (DELAY_STEP_MIN_S to
    DELAY_STEP_MAX_S); with ``around``, only from DELAY_LOCAL_STEPS steps below the least of them and 0 to as far
    above the largest."""
    step = min(max(DELAY_STEP_SHARE * dt, DELAY_STEP_MIN_S), DELAY_STEP_MAX_S)
    k = int(math.floor(DELAY_MAX_S / step))
    grid = np.arange(-k, k + 1) * step
    if len(around):
        lo = min(min(around), 0.0) - DELAY_LOCAL_STEPS * step
        hi = max(max(around), 0.0) + DELAY_LOCAL_STEPS * step
        grid = grid[(grid >= lo) & (grid <= hi)]
    return grid


def best_on_grid(delays: np.ndarray, sse: np.ndarray) -> float:
    """The minimum of sse over the grid, refined by a parabola through the best point and its neighbours. Local
    minima within ALIAS_SHARE of the SSE's range of the least are equally good fits, and the one nearest d = 0 is
    taken: when one mode dominates the free phases (our rig's 3.9 kHz cell mode after the break), a delay a whole
    period away fits as well, and which of the two has the lower SSE is chance (the 25 kHz rig's 60 us delay came
    out at -195 us)."""
    i = int(np.argmin(sse))
    fin = np.isfinite(sse)
    if fin.sum() >= 3:
        tol = sse[i] + ALIAS_SHARE * (np.max(sse[fin]) - sse[i])
        up = np.r_[np.inf, sse[:-1]]
        down = np.r_[sse[1:], np.inf]
        cand = np.flatnonzero(fin & (sse <= tol) & (sse <= np.where(np.isfinite(up), up, np.inf))
                              & (sse <= np.where(np.isfinite(down), down, np.inf)))
        if len(cand):
            i = int(cand[np.argmin(np.abs(delays[cand]))])
    if 0 < i < len(sse) - 1 and np.isfinite(sse[i - 1:i + 2]).all():
        y0, y1, y2 = sse[i - 1], sse[i], sse[i + 1]
        den = y0 - 2 * y1 + y2
        if den > 0:
            return float(delays[i] + 0.5 * (y0 - y2) / den * (delays[1] - delays[0]))
    return float(delays[i])


def interp_stats(delays: np.ndarray, tab: np.ndarray, d: float) -> np.ndarray:
    return np.array([np.interp(d, delays, tab[:, k]) for k in range(tab.shape[1])])


def own_fit(fm, A: Shifter, free, delays) -> Tuple[float, float]:
    """(G, d) of one pull: the delay minimizing the SSE on the grid (parabola refined), G there. G keeps the sign
    it has at d = 0: past half a period of the ringing, a delay with G of the other sign fits as well."""
    fits = [fit_at(fm, A(d), free) for d in delays]
    sign = np.sign(fits[int(np.argmin(np.abs(delays)))][0]) or 1.0
    sse = np.array([e if np.sign(g) == sign else np.inf for g, e in fits])
    d = best_on_grid(delays, sse)
    return fit_at(fm, A(d), free)[0], d

