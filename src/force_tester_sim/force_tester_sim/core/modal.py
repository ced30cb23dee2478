"""Exact first-order-hold propagation of an LTI system on a uniform grid, in modal form (ROS-free).

One home for the propagator of the force chain (core/integrate.py) and of the drive (core/drive_grid.py).
x' = A x + B u with u linear over each step h: each mode z' = lam z + b u gives

    z1 = e^{lam h} z0 + g0 b u0 + g1 b (u1 - u0),  g0 = (e^{lam h} - 1) / lam,  g1 = (e^{lam h} - 1 - lam h) / (lam^2 h)

(for |lam h| < 1e-6, their series: lam = 0, a pure integrator, gives g0 = h, g1 = h / 2), one complex
first-order recursion per mode run by scipy.signal.lfilter.
"""
from __future__ import annotations

import numpy as np
from scipy.signal import lfilter

MODAL_ERROR_MAX = 1e-9    # |V diag(lam) V^-1 - A| / |A| at most (relative)
MODAL_COND_MAX = 1e8      # cond(V) at most: a nearly defective matrix has no usable modal form
SMALL_LAM_H = 1e-6        # |lam h| below this: g0 and g1 from their series


class ModalFOH:
    """The exact FOH discretisation of x' = A x + B u on step ``h``.

    ``blocks``: index lists of A's uncoupled diagonal blocks, each decomposed on its own (None: A whole).
    ``modal``: False when A has no usable modal form (``error`` or ``cond`` too large, or eigenvalues that are
    not in conjugate pairs); then ``propagate`` is not available and the caller integrates otherwise or refuses.
    A real system: one mode of each conjugate pair is propagated, weight 2 (real modes weight 1).
    """

    def __init__(self, A, B, h: float, blocks=None):
        n = A.shape[0]
        if blocks is None:
            evs, V = np.linalg.eig(A)
        else:
            evs = np.zeros(n, dtype=complex)
            V = np.zeros((n, n), dtype=complex)
            for idx in blocks:
                ev, vec = np.linalg.eig(A[np.ix_(idx, idx)])
                evs[idx] = ev
                V[np.ix_(idx, idx)] = vec
        Vinv = np.linalg.inv(V)
        self.n = n
        self.eigenvalues = evs
        self.error = float(np.abs((V * evs) @ Vinv - A).max() / max(np.abs(A).max(), 1e-300))
        self.cond = float(np.linalg.cond(V))
        self.paired = 2 * int(np.sum(evs.imag > 0)) + int(np.sum(evs.imag == 0)) == n
        self.decomposed = bool(np.isfinite(self.error) and self.error <= MODAL_ERROR_MAX
                               and self.cond <= MODAL_COND_MAX)
        self.modal = self.decomposed and self.paired
        if not self.modal:
            return
        keep = np.flatnonzero(evs.imag >= 0)
        lam = evs[keep].astype(complex)
        lh = lam * h
        e = np.exp(lh)
        small = np.abs(lh) < SMALL_LAM_H
        safe = np.where(small, 1.0, lam)
        g0 = np.where(small, h * (1.0 + lh / 2.0 + lh * lh / 6.0), (e - 1.0) / safe)
        g1 = np.where(small, h * (0.5 + lh / 6.0 + lh * lh / 24.0), (e - 1.0 - lh) / (safe * safe * h))
        b = Vinv[keep] @ B
        self.lam = e                                            # the per-step factors e^{lam h}
        self.V = V[:, keep] * np.where(lam.imag > 0, 2.0, 1.0)
        self.Vinv = Vinv[keep]
        self.q0 = (g0 - g1)[:, None] * b                        # multiplies u0
        self.q1 = g1[:, None] * b                               # multiplies u1

    def propagate(self, x0, U) -> np.ndarray:
        """States at every row of U (the inputs sampled on the grid), starting with x0 at U[0].

        The (N x few) products are written column by column: as matrix products they go to a
        multi-threaded BLAS, which on tall, thin arrays is many times slower than this.
        """
        z0 = self.Vinv @ x0
        Z = np.empty((U.shape[0], len(z0)), dtype=complex)
        Z[0] = z0
        for i, lam in enumerate(self.lam):
            q = sum(U[:-1, j] * self.q0[i, j] + U[1:, j] * self.q1[i, j] for j in range(U.shape[1]))
            Z[1:, i] = lfilter([1.0], [1.0, -lam], q, zi=[lam * z0[i]])[0]
        X = np.empty((U.shape[0], self.n))
        for k in range(self.n):
            X[:, k] = sum((Z[:, i] * self.V[k, i]).real for i in range(Z.shape[1]))
        return X


def columns(M, w):
    """M @ w as a sum of columns (M tall and narrow, w small): no BLAS call."""
    out = 0.0
    for c, wc in enumerate(w):
        if wc:
            out = out + M[:, c] * wc
    return out if np.ndim(out) else np.full(M.shape[0], out)


__all__ = ['ModalFOH', 'columns', 'MODAL_ERROR_MAX', 'MODAL_COND_MAX', 'SMALL_LAM_H']
