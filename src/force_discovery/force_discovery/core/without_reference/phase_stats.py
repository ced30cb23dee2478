"""Pass 2 of the reference-free path on one pull: the normal equations of F_move on a2(t + d) per delay of the
campaign's grid (offset and hum projected out), and the fits and held-out residuals that need a pull only through
them (pooled over any pulls: leave-one-out). ROS-free."""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional, Sequence, Tuple

import numpy as np

from .. import quality as Q
from .delay_fit import Shifter, best_on_grid, interp_stats
from .phases import FreePull, prepared


@dataclass(frozen=True)
class FreeStats:
    """Pass 2 of one pull: per delay on the grid, the normal equations (ff, fa, aa) of F_move on a2(t + d) with
    the offset (and the hum at the campaign's frequency) projected out; with and without the hum."""

    delays: np.ndarray
    hum: np.ndarray                  # (len(delays), 3): ff, fa, aa with the hum projected out
    nohum: np.ndarray                # ... without
    hum_amp: float                   # the pull's hum amplitude at G, d of its own
    samples: int
    ref: Optional[object] = None     # stationary_cell.RefStats: with the stationary cell, else None


def free_stats(name: str, ch: dict, screen: Q.PullScreen, f_hum: float, fp: FreePull,
               delays: np.ndarray) -> FreeStats:
    """Pass 2 of one pull: the normal equations per delay of the grid ``delays`` (the campaign's: every pull's
    delay and 0 inside it), with and without the hum at f_hum."""
    t, dt, fm, a2, ok, raw = prepared(name, ch, screen)
    n = len(t)
    # the same free phases as pass 1: outside the events it found
    ev = np.zeros(n, bool)
    for e in fp.events:
        ev[(t >= e['start_s']) & (t <= e['end_s'])] = True
    free = ok & ~ev
    A = Shifter(a2, dt)
    tf = t[free]
    one = np.ones(len(tf))
    hum_cols = np.column_stack([one, np.sin(2 * np.pi * f_hum * tf), np.cos(2 * np.pi * f_hum * tf)])
    out = {}
    for key, N in (('hum', hum_cols), ('nohum', one[:, None])):
        Qn, _ = np.linalg.qr(N)
        f = fm[free] - Qn @ (Qn.T @ fm[free])
        rows = []
        for d in delays:
            a = A(d)[free]
            a = a - Qn @ (Qn.T @ a)
            rows.append((float(f @ f), float(f @ a), float(a @ a)))
        out[key] = np.array(rows)
    r = fm[free] - fp.gain_mass * A(fp.delay_s)[free]
    c, *_ = np.linalg.lstsq(hum_cols, r, rcond=None)
    return FreeStats(delays, out['hum'], out['nohum'], float(math.hypot(c[1], c[2])), int(free.sum()))


def pooled(stats: Sequence[FreeStats], idx: Sequence[int], key: str = 'hum') -> Tuple[float, float]:
    """(G, d) fitted on the pulls idx pooled: the delay minimizing the summed SSE (parabola refined), G there."""
    delays = stats[idx[0]].delays
    tab = sum(getattr(stats[j], key) for j in idx)
    sse = tab[:, 0] - tab[:, 1] ** 2 / np.maximum(tab[:, 2], 1e-300)
    sign = np.sign(tab[int(np.argmin(np.abs(delays))), 1]) or 1.0      # G's sign at d = 0 (see _own_fit)
    sse = np.where(np.sign(tab[:, 1]) == sign, sse, np.inf)
    d = best_on_grid(delays, sse)
    ff, fa, aa = interp_stats(delays, tab, d)
    return fa / aa, d


def sse_at(st: FreeStats, g: float, d: float, key: str = 'hum') -> float:
    ff, fa, aa = interp_stats(st.delays, getattr(st, key), d)
    return max(0.0, ff - 2 * g * fa + g * g * aa)


def gain_at(stats: Sequence[FreeStats], idx: Sequence[int], d: float) -> float:
    tab = sum(interp_stats(stats[j].delays, stats[j].hum, d) for j in idx)
    return float(tab[1] / tab[2])


