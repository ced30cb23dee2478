"""The force model's sufficient statistics, one pull at a time (discovery in bounded memory). ROS-free.

force_model.ForceModel fits F_move - hum = g T + M a2(t + d) - k C over every fitted pull's analysis window W at
once, a2 shifted by the accelerometer delay d (band-limited) on a grid of delays, the normal equations weighted
linearly between two grid delays. Everything it computes -- least-squares fits over any set of pulls, held-out
squared residuals, leave-one-pull-out refits, the delay search, the T^2 check -- depends on a pull's samples only
through inner products of its columns. So each pull is reduced to small matrices once (``force_blocks``) and
``ForceStats`` answers every question ForceModel answers from them.

Why this is exact (up to rounding): at a grid delay g every column of every design is a fixed linear combination
of BASE columns on W (the usable samples): F_move, T, C_F = integral of F_move, the pull's own hum estimate H and
its integral C_H, T^2 (for the T^2 check), T's rate (the tension_timing variant's regressor) and a2 shifted by g.
The hum a model subtracts is s H (s: 0 without the hum, 1 on a fitted pull, the fitted pulls' mean amplitude over
the pull's own on a held-out one), so C = C_F - s C_H.
For each grid delay a pull keeps R_g, the triangular factor of a QR decomposition of its BASE columns (B = Q R_g):
8 x 8 numbers. A design [X | y] = B M (M: the combination) has the same inner products as R_g M, since
B^T B = R_g^T R_g; between two grid delays the rows of both, each scaled by the square root of its weight, as
ForceModel.design stacks its samples. Least squares on the stacked rows of the fitted pulls is the least-squares fit
on their samples; |R_g M v|^2 is a pull's squared residual for coefficients v. Householder QR keeps each column's
error at rounding relative to that column, so nothing is lost by forming normal equations (no squared condition
number). The first seven columns do not depend on the delay: their QR is made once, and a2's column at each grid
delay is added to it (its projection and the norm of what is left).

What changes against ForceModel: the order of the additions (sums per pull, then over pulls; C = C_F - s C_H
instead of the integral of F_move - s H), so the numbers agree to rounding, not bit for bit
(tests/force_discovery/test_stream.py compares the two). Size: 8 x 8 floats per grid delay, 26 KB a pull.
"""
from __future__ import annotations

import math
from typing import Optional, Sequence

import numpy as np

from .errors import DiscoveryError
from .force_model import ForceModel, WindowShift, checked_extra, delay_grid, grid_parts, tension_rate
from .prep import Pull

BASE = ('fm', 'T', 'CF', 'H', 'CH', 'TT', 'dT', 'a2')
_I = {n: i for i, n in enumerate(BASE)}


def force_blocks(p: Pull, hum: np.ndarray) -> np.ndarray:
    """The pull's sufficient statistics: R_g for each delay g of delay_grid(p.dt), in order (shape (grid, 8, 8)),
    see the module docstring. hum: the pull's own hum estimate over the whole record (hum.hum_per_pull), unscaled."""
    ok = p.usable(p.w0, p.w1)
    if int(np.count_nonzero(ok)) < len(BASE):
        raise DiscoveryError(f'pull {p.name!r} has {int(np.count_nonzero(ok))} usable samples in its analysis '
                             f'window; expected at least {len(BASE)}')
    T = p.T[p.w0:p.w1][ok]
    fixed = np.column_stack([p.fm[p.w0:p.w1][ok], T, (np.cumsum(p.fm) * p.dt)[p.w0:p.w1][ok], hum[p.w0:p.w1][ok],
                             (np.cumsum(hum) * p.dt)[p.w0:p.w1][ok], T * T, tension_rate(p)[ok]])
    Q, R0 = np.linalg.qr(fixed)
    grid = delay_grid(p.dt)
    A = WindowShift(p.a2, p).many(grid)[:, ok]              # a2 shifted by every grid delay, (grid, usable samples)
    r = A @ Q                                               # each shift's projection on the fixed columns
    out = np.zeros((len(grid), len(BASE), len(BASE)))
    out[:, :-1, :-1] = R0
    out[:, :-1, -1] = r
    out[:, -1, -1] = np.linalg.norm(A - r @ Q.T, axis=1)   # what the fixed columns leave of a2 (no cancellation)
    return out


class ForceStats(ForceModel):
    """ForceModel's fits from the pulls' force_blocks() instead of their arrays (same methods, same answers to
    rounding). scales: per pull, the factor s on its own hum estimate (None: the model without the hum)."""

    def __init__(self, blocks: Sequence[np.ndarray], dts: Sequence[float], m2: float,
                 scales: Optional[Sequence[float]] = None, extra: Sequence[str] = ()):
        """extra: EXTRA regressors every fit adds (ForceModel's)."""
        self.extra = checked_extra(extra)
        self.m2 = m2
        self.blocks = blocks
        self.dts = dts
        self.scales = scales
        self.pulls = ()
        self._all = None

    def delay_grid(self) -> np.ndarray:
        return delay_grid(self.dts[0])

    def _combination(self, terms, s: float, t2: bool):
        """(M, names): the design [X | y] of ForceModel.design as BASE columns times M."""
        def vec(**w):
            v = np.zeros(len(BASE))
            for key, x in w.items():
                v[_I[key]] += x
            return v
        y = vec(fm=1.0, H=-s)
        T = vec(T=1.0)
        C = vec(CF=1.0, CH=-s)
        a2 = vec(a2=1.0)
        cols, names = [], []
        if 'moving_cell_gain' in terms:
            if 'effective_mass' in terms:
                cols += [T, a2]
                names += ['g', 'M']
            else:
                cols += [T + self.m2 * a2]
                names += ['g']
        else:
            y = y - T
            if 'effective_mass' in terms:
                cols += [a2]
                names += ['M']
            else:
                y = y - self.m2 * a2
        if 'ac_coupling' in terms:
            cols += [-C]
            names += ['k']
        for e in self.extra:
            cols += [vec(dT=1.0)]
            names += [e]
        if t2:
            cols += [vec(TT=1.0)]
        return np.column_stack(cols + [y]), names

    def design(self, terms, d, idx, masked=True, t2=False):
        """(ys, Xs, names) as ForceModel.design, each pull's rows being R_g M (8 rows a grid delay), not its
        samples; t2: T^2 appended as the last column of X. All pulls of idx at once: M is linear in the hum's
        factor s (M(s) = M(0) + s (M(1) - M(0)), exactly: its entries are 0, +-1, +-m2 and +-s)."""
        if not masked:
            raise DiscoveryError('the force statistics hold no samples; expected a ForceModel for residual arrays')
        d = d if 'accel_delay' in terms else 0.0
        idx = [int(j) for j in idx]
        M0, names = self._combination(terms, 0.0, t2)
        M1 = self._combination(terms, 1.0, t2)[0] - M0
        s = np.zeros(len(idx)) if self.scales is None else np.array([self.scales[j] for j in idx], float)
        Ms = M0 + s[:, None, None] * M1                    # (pulls, 8, columns + 1)
        ys, Xs = [None] * len(idx), [None] * len(idx)
        for dt, rows in self._by_rate(idx).items():        # one grid per sample interval (one, in practice)
            parts = grid_parts(delay_grid(dt), d)
            B = self._stacked()
            A = np.concatenate([math.sqrt(w) * (B[[idx[i] for i in rows], k] @ Ms[rows]) for k, w in parts], axis=1)
            for a, i in zip(A, rows):
                ys[i], Xs[i] = a[:, -1], a[:, :-1]
        return ys, Xs, names

    def _stacked(self) -> np.ndarray:
        """The pulls' force_blocks as one array (pulls, grid, 8, 8), made on first use."""
        if self._all is None:
            self._all = np.stack(self.blocks)
        return self._all

    def _by_rate(self, idx) -> dict:
        """{sample interval: positions in idx of the pulls with it}."""
        out: dict = {}
        for i, j in enumerate(idx):
            out.setdefault(self.dts[j], []).append(i)
        return out

    def resid(self, terms, coef, d, j):
        raise DiscoveryError('the force statistics hold no samples; expected a ForceModel for residual arrays')


__all__ = ['BASE', 'ForceStats', 'force_blocks']
