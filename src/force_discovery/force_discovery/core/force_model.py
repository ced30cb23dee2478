"""The force model: F_move - hum = g T + M a2(t + d) - k C on the analysis window, fitted over the pulls' samples
(ForceModel; force_stats.ForceStats answers the same questions from per-pull sufficient statistics), and its
coefficients as catalog parameters with their intervals. ROS-free."""
from __future__ import annotations

import math
from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np

from force_tester_sim.core.departures import fractional_delay

from .prep import Pull
from .uncertainty import jackknife_ci

TERMS = ('moving_cell_gain', 'effective_mass', 'accel_delay', 'ac_coupling')


class ForceModel:
    """F_move - hum = g T + M a2(t + d) - k C on W (C: running integral of F_move - hum over the whole record).

    The accelerometer delay is applied to the force side (F_move, T, C delayed by d with linear interpolation),
    so a linearly interpolated (low-passing) delay in the accelerometer path is matched exactly."""

    def __init__(self, pulls: Sequence[Pull], m2: float, hums: Optional[Sequence] = None):
        """hums: the mains-hum estimate per pull (whole record) to subtract from F_move, or None."""
        self.m2 = m2
        self.pulls = pulls
        self.full = []
        for p, h in zip(pulls, hums if hums is not None else [None] * len(pulls)):
            y = p.fm - (h if h is not None else 0.0)
            self.full.append((y, p.T, np.cumsum(y) * p.dt))
        self.a2 = [p.a2[p.w0:p.w1] for p in pulls]
        self._cache: Dict[float, list] = {}

    def at(self, d: float) -> list:
        key = round(d, 10)
        if key not in self._cache:
            if len(self._cache) > 64:
                self._cache.clear()
            out = []
            for p, arrs in zip(self.pulls, self.full):
                m = min(p.w0, 16)   # d <= 200 us = 10 samples: a short lead-in is enough
                out.append(tuple(fractional_delay(a[p.w0 - m:p.w1], d / p.dt)[m:] for a in arrs))
            self._cache[key] = out
        return self._cache[key]

    def design(self, terms, d, idx, masked=True):
        """(y adjusted for fixed terms, regressor matrix, column names) per pull of idx, on W: the usable samples
        only (masked=True), or all of W."""
        sig = self.at(d if 'accel_delay' in terms else 0.0)
        a2 = self.a2
        ys, Xs = [], []
        for j in idx:
            y0, Tj, Cj = sig[j]
            y = y0.copy()
            cols, names = [], []
            if 'moving_cell_gain' in terms:
                if 'effective_mass' in terms:
                    cols += [Tj, a2[j]]
                    names += ['g', 'M']
                else:
                    cols += [Tj + self.m2 * a2[j]]
                    names += ['g']
            else:
                y = y - Tj
                if 'effective_mass' in terms:
                    cols += [a2[j]]
                    names += ['M']
                else:
                    y = y - self.m2 * a2[j]
            if 'ac_coupling' in terms:
                cols += [-Cj]
                names += ['k']
            ok = self.pulls[j].usable(self.pulls[j].w0, self.pulls[j].w1) if masked else slice(None)
            ys.append(y[ok])
            Xs.append(np.column_stack(cols)[ok] if cols else np.zeros((len(ys[-1]), 0)))
        return ys, Xs, names

    def fit(self, terms, idx, d=0.0):
        ys, Xs, names = self.design(terms, d, idx)
        if not names:
            return {}, float(sum(np.sum(y ** 2) for y in ys))
        X = np.vstack(Xs)
        y = np.concatenate(ys)
        c, *_ = np.linalg.lstsq(X, y, rcond=None)
        r = y - X @ c
        return dict(zip(names, c)), float(r @ r)

    def fit_delay(self, terms, idx):
        grid = self.delay_grid()
        sse = np.array([self.fit(terms, idx, d)[1] for d in grid])
        k = int(np.argmin(sse))
        d = float(grid[k] + _parabolic_offset(sse, k) * (grid[1] - grid[0]))
        coef, s = self.fit(terms, idx, d)
        return coef, s, d

    def delay_grid(self, d_max=200e-6) -> np.ndarray:
        return np.arange(0.0, d_max + 1e-12, self.pulls[0].dt / 2)

    def loo_fits(self, terms, idx) -> List[Tuple[dict, float]]:
        """Leave-one-pull-out refits over idx: [(coef, delay)], the delay refitted on the grid when it is a term.

        Per-pull normal equations (X'X, X'y, y'y) at each grid delay are summed once; dropping pull k subtracts
        its share. The refined delay's coefficients interpolate linearly between the two nearest grid delays."""
        grid = self.delay_grid() if 'accel_delay' in terms else np.zeros(1)
        names, G, b, s = None, [], [], []
        for d in grid:
            ys, Xs, names = self.design(terms, d, idx)
            G.append(np.array([X.T @ X for X in Xs]))
            b.append(np.array([X.T @ y for X, y in zip(Xs, ys)]))
            s.append(np.array([y @ y for y in ys]))
        G, b, s = np.array(G), np.array(b), np.array(s)          # (grid, pulls, p, p), (grid, pulls, p), (grid, pulls)
        Gs, bs, ss = G.sum(1), b.sum(1), s.sum(1)
        out = []
        for k in range(len(idx)):
            c = np.array([_solve(Gs[i] - G[i, k], bs[i] - b[i, k]) for i in range(len(grid))])
            sse = ss - s[:, k] - np.einsum('ip,ip->i', bs - b[:, k], c)
            i = int(np.argmin(sse))
            off = _parabolic_offset(sse, i)
            ci = c[i] if off == 0 else c[i] + abs(off) * (c[i + (1 if off > 0 else -1)] - c[i])
            out.append((dict(zip(names, ci)), float(grid[i] + off * (grid[1] - grid[0]))))
        return out

    def sse_per_pull(self, terms, coef, d, idx) -> np.ndarray:
        ys, Xs, names = self.design(terms, d, idx)
        c = np.array([coef[n] for n in names]) if names else np.zeros(0)
        return np.array([float(np.sum((y - X @ c) ** 2)) for y, X in zip(ys, Xs)])

    def resid(self, terms, coef, d, j) -> np.ndarray:
        """Pull j's residual on all of W (masked samples included: their values are repaired, not measured)."""
        ys, Xs, names = self.design(terms, d, [j], masked=False)
        c = np.array([coef[n] for n in names]) if names else np.zeros(0)
        return ys[0] - Xs[0] @ c

    def t2_reduction(self, coef, d, fit, held) -> float:
        """Relative held-out SSE reduction when T^2 is added to the full model (coef, d: its fit)."""
        fm_ = self
        sig = fm_.at(d)

        def t2(j):   # T^2 on W, on the usable samples as design() takes them
            p = fm_.pulls[j]
            return sig[j][1][p.usable(p.w0, p.w1)] ** 2
        ys, Xs, names = fm_.design(set(TERMS), d, fit)
        X = np.vstack([np.column_stack([Xk, t2(j)]) for Xk, j in zip(Xs, fit)])
        c, *_ = np.linalg.lstsq(X, np.concatenate(ys), rcond=None)
        ys2, Xs2, _ = fm_.design(set(TERMS), d, held)
        c0 = np.array([coef[n] for n in names])
        s0 = sum(float(np.sum((y - Xk @ c0) ** 2)) for y, Xk in zip(ys2, Xs2))
        s1 = sum(float(np.sum((y - np.column_stack([Xk, t2(j)]) @ c) ** 2)) for y, Xk, j in zip(ys2, Xs2, held))
        return float(1 - s1 / s0) if s0 > 0 else 0.0


def _parabolic_offset(y: np.ndarray, k: int) -> float:
    """Offset (in grid steps, within (-1, 1)) of the vertex of the parabola through y[k-1:k+2]; 0 at an end."""
    if not 0 < k < len(y) - 1:
        return 0.0
    den = y[k - 1] - 2 * y[k] + y[k + 1]
    return float(0.5 * (y[k - 1] - y[k + 1]) / den) if den > 0 else 0.0


def _solve(G: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Normal equations G c = b, columns scaled to unit diagonal first."""
    if len(b) == 0:
        return np.zeros(0)
    D = np.sqrt(np.diag(G))
    D[D == 0] = 1.0
    return np.linalg.solve(G / np.outer(D, D), b / D) / D


def force_params_ci(loo: Sequence[Tuple[dict, float]], coef: dict, d: float, m2: float) -> dict:
    """name -> {parameter: [lo, hi]} from leave-one-pull-out refits (jackknife). The AC coupling's interval
    comes from the rate k = 1/tau that the regression fits, inverted (k <= 0 is tau = inf: DC)."""
    full = force_params(coef, d, m2)
    per = [force_params(c, dk, m2) for c, dk in loo]
    out = {}
    for name, params in full.items():
        if name == 'ac_coupling':
            lo, hi = jackknife_ci(coef['k'], [c['k'] for c, _ in loo])
            out[name] = {'time_constant_s': [1.0 / hi if hi > 0 else math.inf, 1.0 / lo if lo > 0 else math.inf]}
        else:
            out[name] = {k: list(jackknife_ci(v, [p[name][k] for p in per])) for k, v in params.items()}
    return out


def force_params(coef: dict, d: float, m2: float) -> dict:
    g = coef.get('g', 1.0)
    out = {}
    if 'g' in coef:
        out['moving_cell_gain'] = {'gain': float(g)}
    if 'M' in coef:
        out['effective_mass'] = {'mass_kg': float(coef['M'] / g)}
    out['accel_delay'] = {'delay_s': float(d)}
    if 'k' in coef:
        out['ac_coupling'] = {'time_constant_s': float(1.0 / coef['k']) if coef['k'] > 0 else float('inf')}
    return out


def fit_terms(fm_, terms, fit) -> Tuple[dict, float]:
    """(coefficients, delay) of the force model with the given terms on the fitted pulls (the delay fitted when it
    is a term, else 0)."""
    coef, _, d = (fm_.fit_delay(terms, fit) if 'accel_delay' in terms else (*fm_.fit(terms, fit), 0.0))
    return coef, d
