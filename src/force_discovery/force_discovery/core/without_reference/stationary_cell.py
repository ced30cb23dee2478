"""The stationary cell in the reference-free path (a campaign with the reference cell but no encoder, or with
every channel but 1-3 pulls): g and m2 apart. ROS-free.

The free phases give only the product g m2. With the stationary cell, T (the tension at the moving cell: the
stationary cell's reading plus its own mass's inertia, prep.tension_from_stationary) is known over the whole
record, the event included, so the model of record's force balance with its departures

    F_move = g T + M a2(t + d) - k C + offset + hum          (M = g m2, C: the running integral of F_move)

separates the cell's gain g and the effective mass m2 = M / g; k (the AC coupling's 1 / time constant) is
fitted too, so that a cell's slow discharge does not bias g. The carriage motion (the encoder) is not needed.
Per pull and per delay of the campaign's grid: the Gram matrix of [F_move, T, a2(t + d), C] on the usable
samples with the offset and the hum projected out (RefStats); every fit below, pooled over any pulls and scored
on the one left out, needs a pull only through it.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Optional, Sequence, Tuple

import numpy as np

from .. import quality as Q
from ..prep import MASK_GROW_S, tension_from_stationary
from .delay_fit import Shifter
from .phases import prepared

REFERENCE = 'force_stationary_n'


@dataclass(frozen=True)
class RefStats:
    """One pull: per delay, the Gram matrix of [F_move, T, a2(t + d), C] (offset and hum projected out)."""

    delays: np.ndarray
    gram: np.ndarray                 # (len(delays), 4, 4)
    samples: int


def reference_stats(name: str, ch: dict, screen: Q.PullScreen, f_hum: float, delays: np.ndarray,
                    fc) -> Optional[RefStats]:
    """RefStats of one pull (None without a stationary cell channel); fc: the rig's force chain (m1, k1, c1;
    None, no rig given: T is the stationary cell's reading, its own mass's inertia unknown)."""
    if REFERENCE not in ch:
        return None
    t, dt, fm, a2, ok, _raw = prepared(name, ch, screen)
    fixed = Q.repair(ch, screen) if screen.spans else ch
    ok = ok & screen.usable(REFERENCE, grow_s=MASK_GROW_S)
    m1, k1, c1 = (fc.m1, fc.load_cell_stiffness_n_per_m, fc.c1) if fc is not None else (0.0, 1.0, 0.0)
    T = tension_from_stationary(np.asarray(fixed[REFERENCE], float), dt, m1, k1, c1)
    C = np.cumsum(fm) * dt
    tk = t[ok]
    N = np.column_stack([np.ones(len(tk)), np.sin(2 * np.pi * f_hum * tk), np.cos(2 * np.pi * f_hum * tk)])
    Qn, _ = np.linalg.qr(N)

    def proj(x):
        x = x[ok]
        return x - Qn @ (Qn.T @ x)
    f, tt, cc = proj(fm), proj(T), proj(C)
    A = Shifter(a2, dt)
    grams = []
    for d in delays:
        X = np.column_stack([f, tt, proj(A(d)), cc])
        grams.append(X.T @ X)
    return RefStats(np.asarray(delays), np.array(grams), int(ok.sum()))


def gram_at(st: RefStats, d: float) -> np.ndarray:
    """The pull's Gram matrix at delay d (linear between the grid's delays)."""
    i = int(np.clip(np.searchsorted(st.delays, d) - 1, 0, len(st.delays) - 2))
    w = float(np.clip((d - st.delays[i]) / (st.delays[i + 1] - st.delays[i]), 0.0, 1.0))
    return (1 - w) * st.gram[i] + w * st.gram[i + 1]


def models(m2: float) -> dict:
    """The nested models as beta = beta0 + L theta over [g, M, k]: full; g = 1 (the cell's calibration); M = g m2
    with the rig YAML's m2."""
    return {'full': (np.zeros(3), np.eye(3)),
            'unit_gain': (np.array([1.0, 0.0, 0.0]), np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])),
            'record_mass': (np.zeros(3), np.array([[1.0, 0.0], [m2, 0.0], [0.0, 1.0]]))}


def fit(G: np.ndarray, model: Tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """beta = [g, M, k] minimizing the SSE whose Gram matrix (over [F, T, a2, C]) is G, within the model."""
    b0, L = model
    Xy, XX = G[1:, 0], G[1:, 1:]
    theta = np.linalg.solve(L.T @ XX @ L, L.T @ (Xy - XX @ b0))
    return b0 + L @ theta


def sse(G: np.ndarray, beta: np.ndarray) -> float:
    return max(0.0, float(G[0, 0] - 2 * beta @ G[1:, 0] + beta @ G[1:, 1:] @ beta))


def pooled_gram(stats: Sequence[RefStats], idx: Sequence[int], d: float) -> np.ndarray:
    return sum(gram_at(stats[j], d) for j in idx)


def reference_fits(stats: Sequence[RefStats], d: float, loo_d: Sequence[float], m2: float) -> dict:
    """The campaign's g and m2: pooled at delay d ({'g', 'm2', 'k'}); with n >= 2 pulls, each pull left out
    (fitted on the others at its left-out delay loo_d[j]): 'loo' [(g, m2)], and the held-out SSE of each pull under
    each model ('held': model -> array)."""
    n = len(stats)
    ms = models(m2)
    b = fit(pooled_gram(stats, range(n), d), ms['full'])
    out = {'g': float(b[0]), 'm2': float(b[1] / b[0]), 'k': float(b[2]), 'loo': [],
           'held': {k: np.zeros(n) for k in ms}}
    for j in range(n):
        others = [k for k in range(n) if k != j] if n >= 2 else [j]
        dj = loo_d[j] if n >= 2 else d
        Go, Gj = pooled_gram(stats, others, dj), gram_at(stats[j], dj)
        for key, m in ms.items():
            out['held'][key][j] = sse(Gj, fit(Go, m))
        if n >= 2:
            bj = fit(Go, ms['full'])
            out['loo'].append((float(bj[0]), float(bj[1] / bj[0])))
    return out


__all__ = ['REFERENCE', 'RefStats', 'fit', 'gram_at', 'models', 'reference_fits', 'reference_stats', 'sse']
