"""Force-chain model of record (rig README, thesis Figure 29 / eqs 17-21), ROS-free.

wall - K_LC1 (stationary cell) - m1 - lanyard K_L (tension only, slack) - m2 - K_LC2 (moving cell) - carriage x3

State x = [w, w', u1, u1'] with w = u2 - x3 (the moving cell's deflection; relative coordinates keep the
stiff cell out of the input and avoid cancellation against metres of carriage travel).
Input u = [x3, v3, a3, beta] (carriage kinematics and the coupon's remaining load fraction).

    F_move = K_LC2 (x3 - u2) + c2 (v3 - v2) = -(K_LC2 w + c2 w')
    F_stat = K_LC1 u1 + c1 v1
    T      = beta * max(0, K_L (u2 - u1 - slack) + c_L (v2 - v1))
    m2 u2'' = F_move - T        m1 u1'' = T - F_stat
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .params import RigParams


@dataclass(frozen=True)
class ChainParams:
    """Everything the right-hand side needs for one pull (nominal chain + the pull's own lanyard/coupon)."""
    m1: float
    m2: float
    k1: float
    k2: float
    c1: float
    c2: float
    kl: float
    cl: float
    slack_m: float
    break_n: float
    break_duration_s: float

    @classmethod
    def from_rig(cls, rig: RigParams, *, slack_m: float, break_n: float, break_duration_s: float,
                 lanyard_stiffness_n_per_m: float | None = None) -> 'ChainParams':
        fc = rig.force_chain
        kl = fc.lanyard_stiffness_n_per_m if lanyard_stiffness_n_per_m is None else lanyard_stiffness_n_per_m
        return cls(m1=fc.m1, m2=fc.m2, k1=fc.load_cell_stiffness_n_per_m, k2=fc.load_cell_stiffness_n_per_m,
                   c1=fc.c1, c2=fc.c2, kl=kl, cl=fc.lanyard_damping(kl), slack_m=slack_m, break_n=break_n,
                   break_duration_s=break_duration_s)

    @property
    def series_stiffness(self) -> float:
        return 1.0 / (1.0 / self.kl + 1.0 / self.k1 + 1.0 / self.k2)


def lanyard_drive(x, u, p: ChainParams):
    """K_L (u2 - u1 - slack) + c_L (v2 - v1): the lanyard force before the tension-only clip and beta."""
    x = np.asarray(x)
    u = np.asarray(u)
    stretch = x[..., 0] + (u[..., 0] - p.slack_m) - x[..., 2]
    rate = x[..., 1] + u[..., 1] - x[..., 3]
    return p.kl * stretch + p.cl * rate


def tension(x, u, p: ChainParams):
    """Lanyard tension (never compressive)."""
    u = np.asarray(u)
    return u[..., 3] * np.maximum(0.0, lanyard_drive(x, u, p))


def force_move(x, p: ChainParams):
    x = np.asarray(x)
    return -(p.k2 * x[..., 0] + p.c2 * x[..., 1])


def force_stat(x, p: ChainParams):
    x = np.asarray(x)
    return p.k1 * x[..., 2] + p.c1 * x[..., 3]


def chain_rhs(t: float, x, u, p: ChainParams) -> np.ndarray:
    """dx/dt of the model of record (general, nonlinear: tension-only clip and coupon beta)."""
    w, wd, u1, v1 = x
    x3, v3, a3, beta = u
    g = p.kl * (w + (x3 - p.slack_m) - u1) + p.cl * (wd + v3 - v1)
    tl = beta * g if g > 0.0 else 0.0
    fm = -(p.k2 * w + p.c2 * wd)
    fs = p.k1 * u1 + p.c1 * v1
    return np.array([wd, (fm - tl) / p.m2 - a3, v1, (tl - fs) / p.m1])


def linear_matrices(p: ChainParams, taut: bool):
    """(A, B) of the linear pieces: taut (beta = 1, unclipped tension) or free (T = 0).

    Input of the linear pieces: [x3 - slack, v3, a3].
    """
    A = np.zeros((4, 4))
    B = np.zeros((4, 3))
    A[0, 1] = 1.0
    A[2, 3] = 1.0
    A[1, 0] = -p.k2 / p.m2
    A[1, 1] = -p.c2 / p.m2
    A[3, 2] = -p.k1 / p.m1
    A[3, 3] = -p.c1 / p.m1
    B[1, 2] = -1.0
    if taut:
        # T = kl (w + p - u1) + cl (w' + v3 - v1)
        A[1, :] += np.array([-p.kl, -p.cl, p.kl, p.cl]) / p.m2
        B[1, :2] += np.array([-p.kl, -p.cl]) / p.m2
        A[3, :] += np.array([p.kl, p.cl, -p.kl, -p.cl]) / p.m1
        B[3, :2] += np.array([p.kl, p.cl]) / p.m1
    return A, B
