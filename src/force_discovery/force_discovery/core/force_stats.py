"""The force model's sufficient statistics, one pull at a time (discovery in bounded memory). ROS-free.

force_model.ForceModel fits F_move - hum = g T + M a2(t + d) - k C over every fitted pull's analysis window W at
once, with the accelerometer delay d applied to the force side by linear interpolation. Everything it computes --
least-squares fits over any set of pulls, held-out squared residuals, leave-one-pull-out refits, the delay search,
the T^2 check -- depends on a pull's samples only through inner products of its columns. So each pull is reduced
to small matrices once (``force_blocks``) and ``ForceStats`` answers every question ForceModel answers from them.

Why this is exact (up to rounding): a delay of d = (k + f) dt is linear interpolation between the integer shifts
k and k + 1,
    x_d = (1 - f) x_k + f x_(k+1)        (departures.fractional_delay, and the first sample held before W),
so every column of every design at any delay in [k dt, (k + 1) dt] is a fixed linear combination of BASE columns
on W (the usable samples): F_move, T, C_F = integral of F_move, the pull's own hum estimate H and its integral
C_H, each at shifts k and k + 1; a2 (never delayed); and T_k^2, T_k T_(k+1), T_(k+1)^2 (for the T^2 check at
that delay). The hum a model subtracts is s H (s: 0 without the hum, 1 on a fitted pull, the fitted pulls' mean
amplitude over the pull's own on a held-out one), so C = C_F - s C_H. For each pair (k, k + 1) a pull keeps
R_k, the triangular factor of a QR decomposition of its BASE columns (B = Q R_k): 14 x 14 numbers. A design
[X | y] = B M (M: the combination) has the same inner products as R_k M, since B^T B = R_k^T R_k. Least squares
on the stacked R_k M of the fitted pulls is the least-squares fit on their samples; |R_k M v|^2 is a pull's
squared residual for coefficients v. Householder QR keeps each column's error at rounding relative to that
column, so nothing is lost by forming normal equations (no squared condition number).

What changes against ForceModel: the order of the additions (sums per pull, then over pulls; C = C_F - s C_H
instead of the integral of F_move - s H), so the numbers agree to rounding, not bit for bit
(tests/force_discovery/test_stream.py compares the two). Size: 14 x 14 x (d_max/dt) floats, 16 KB a pull.
"""
from __future__ import annotations

import math
from typing import Optional, Sequence

import numpy as np

from .errors import DiscoveryError
from .force_model import TERMS, ForceModel
from .prep import Pull

DELAY_MAX_S = 200e-6   # the delay search's range (ForceModel.delay_grid's default)
LEAD = 16              # samples before W that a delay may reach (ForceModel.at's lead-in)
BASE = ('fm_a', 'fm_b', 'T_a', 'T_b', 'CF_a', 'CF_b', 'H_a', 'H_b', 'CH_a', 'CH_b', 'a2', 'TT_aa', 'TT_ab', 'TT_bb')
_I = {n: i for i, n in enumerate(BASE)}


def delay_pairs(dt: float, d_max: float = DELAY_MAX_S) -> int:
    """How many shift pairs (k, k + 1) cover the delays 0..d_max at sample interval dt."""
    return max(1, int(math.ceil(d_max / dt - 1e-9)))


def force_blocks(p: Pull, hum: np.ndarray, d_max: float = DELAY_MAX_S) -> np.ndarray:
    """The pull's sufficient statistics: R_k for k = 0 .. delay_pairs - 1 (shape (pairs, 14, 14)), see the module
    docstring. hum: the pull's own hum estimate over the whole record (hum.hum_per_pull), unscaled."""
    n = p.w1 - p.w0
    m = min(p.w0, LEAD)
    ok = p.usable(p.w0, p.w1)
    if int(np.count_nonzero(ok)) < len(BASE):
        raise DiscoveryError(f'pull {p.name!r} has {int(np.count_nonzero(ok))} usable samples in its analysis '
                             f'window; expected at least {len(BASE)}')
    pos = np.arange(m, m + n)
    leads = {key: x[p.w0 - m:p.w1] for key, x in (('fm', p.fm), ('T', p.T), ('CF', np.cumsum(p.fm) * p.dt),
                                                 ('H', hum), ('CH', np.cumsum(hum) * p.dt))}

    def shifted(key, k):
        return leads[key][np.maximum(pos - k, 0)][ok]
    a2 = p.a2[p.w0:p.w1][ok]
    pairs = delay_pairs(p.dt, d_max)
    out = np.empty((pairs, len(BASE), len(BASE)))
    nxt = {key: shifted(key, 0) for key in leads}
    for k in range(pairs):
        cur, nxt = nxt, {key: shifted(key, k + 1) for key in leads}
        Ta, Tb = cur['T'], nxt['T']
        B = np.column_stack([cur['fm'], nxt['fm'], Ta, Tb, cur['CF'], nxt['CF'], cur['H'], nxt['H'], cur['CH'],
                             nxt['CH'], a2, Ta * Ta, Ta * Tb, Tb * Tb])
        out[k] = np.linalg.qr(B, mode='r')
    return out


class ForceStats(ForceModel):
    """ForceModel's fits from the pulls' force_blocks() instead of their arrays (same methods, same answers to
    rounding). scales: per pull, the factor s on its own hum estimate (None: the model without the hum)."""

    def __init__(self, blocks: Sequence[np.ndarray], dts: Sequence[float], m2: float,
                 scales: Optional[Sequence[float]] = None):
        self.m2 = m2
        self.blocks = blocks
        self.dts = dts
        self.scales = scales
        self.pulls = ()

    def delay_grid(self, d_max=DELAY_MAX_S) -> np.ndarray:
        return np.arange(0.0, d_max + 1e-12, self.dts[0] / 2)

    def _combination(self, terms, wa: float, wb: float, s: float, t2: bool):
        """(M, names): the design [X | y] of ForceModel.design as BASE columns times M."""
        def vec(**w):
            v = np.zeros(len(BASE))
            for key, x in w.items():
                v[_I[key]] += x
            return v
        y = vec(fm_a=wa, fm_b=wb, H_a=-s * wa, H_b=-s * wb)
        T = vec(T_a=wa, T_b=wb)
        C = vec(CF_a=wa, CF_b=wb, CH_a=-s * wa, CH_b=-s * wb)
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
        if t2:
            cols += [vec(TT_aa=wa * wa, TT_ab=2 * wa * wb, TT_bb=wb * wb)]
        return np.column_stack(cols + [y]), names

    def design(self, terms, d, idx, masked=True, t2=False):
        """(ys, Xs, names) as ForceModel.design, each pull's rows being R_k M (14 rows), not its samples; t2: T^2 at
        the delay appended as the last column of X."""
        if not masked:
            raise DiscoveryError('the force statistics hold no samples; expected a ForceModel for residual arrays')
        d = d if 'accel_delay' in terms else 0.0
        ys, Xs, names = [], [], []
        for j in idx:
            blocks, dt = self.blocks[j], self.dts[j]
            ds = d / dt
            k = min(int(math.floor(ds)), len(blocks) - 1)
            f = ds - k
            s = 0.0 if self.scales is None else self.scales[j]
            M, names = self._combination(terms, 1.0 - f, f, s, t2)
            A = blocks[k] @ M
            ys.append(A[:, -1])
            Xs.append(A[:, :-1])
        return ys, Xs, names

    def resid(self, terms, coef, d, j):
        raise DiscoveryError('the force statistics hold no samples; expected a ForceModel for residual arrays')

    def t2_reduction(self, coef, d, fit, held) -> float:
        """ForceModel.t2_reduction from the statistics."""
        ys, Xs, names = self.design(set(TERMS), d, fit, t2=True)
        c, *_ = np.linalg.lstsq(np.vstack(Xs), np.concatenate(ys), rcond=None)
        ys2, Xs2, _ = self.design(set(TERMS), d, held, t2=True)
        c0 = np.array([coef[n] for n in names])
        s0 = sum(float(np.sum((y - Xk[:, :-1] @ c0) ** 2)) for y, Xk in zip(ys2, Xs2))
        s1 = sum(float(np.sum((y - Xk @ c) ** 2)) for y, Xk in zip(ys2, Xs2))
        return float(1 - s1 / s0) if s0 > 0 else 0.0


__all__ = ['BASE', 'DELAY_MAX_S', 'ForceStats', 'delay_pairs', 'force_blocks']
