"""Force-chain model of record (rig README, thesis Figure 29 / eqs 17-21), ROS-free.

wall - K_LC1 (stationary cell) - m1 - lanyard K_L (tension only, slack) - m2 - K_LC2 (moving cell) - carriage x3

State x = [w, w', u1, u1'] with w = u2 - x3 (the moving cell's deflection; relative coordinates keep the
stiff cell out of the input and avoid cancellation against metres of carriage travel).
Input u = [x3, v3, a3, beta] (carriage kinematics and the coupon's remaining load fraction).

    F_move = K_LC2 (x3 - u2) + c2 (v3 - v2) = -(K_LC2 w + c2 w')
    F_stat = K_LC1 u1 + c1 v1
    T      = beta * max(0, K_L (u2 - u1 - slack) + c_L (v2 - v1))
    m2 u2'' = F_move - T        m1 u1'' = T - F_stat

Extensions used only by rigs with departures / pulls that ask for them (the nominal path is unchanged):
- mount_resonance (``mb > 0``): two more states, x = [w, w', u1, u1', wb, wb'], wb = ub - x3, the deflection of
  a mount (km, cm) carrying a base mass mb between the carriage and the moving cell:
      F_move = K_LC2 (ub - u2) + c2 (vb - v2)        mb ub'' = -km wb - cm wb' - F_move
- a yielding coupon (``yield_n`` finite): once the lanyard force reaches yield_n the coupon flows with linear
  hardening H; the taut piece then has k_p = K_L H/(K_L + H), c_p = c_L H/(K_L + H) and slack - yield_n/H
  (``flow_params``). Loading is assumed monotonic while flowing.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import numpy as np

from .departures import MOUNT_BASE_MASS_FRACTION
from .errors import SimError
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
    mb: float = 0.0     # mount_resonance departure: base mass between mount and moving cell (0: no mount)
    km: float = 0.0     # mount stiffness
    cm: float = 0.0     # mount damping
    yield_n: float = math.inf        # coupon yield force (inf: elastic to the break, the model of record)
    hardening_n_per_m: float = 0.0   # coupon plastic hardening stiffness H (> 0 when yield_n is finite)

    @property
    def yields(self) -> bool:
        return math.isfinite(self.yield_n)

    def flow_params(self) -> 'ChainParams':
        """The taut piece while the coupon flows plastically (rigid-plastic coupon with linear hardening in series
        with the lanyard; loading assumed monotonic while flowing):
        T = F_y + H s_p = K_L (s - s_p) + c_L s'  =>  T = k_p (u2 - u1 - slack') + c_p s', with
        k_p = K_L H / (K_L + H), c_p = c_L H / (K_L + H), slack' = slack - F_y / H."""
        f = self.hardening_n_per_m / (self.kl + self.hardening_n_per_m)
        return dataclasses.replace(self, kl=self.kl * f, cl=self.cl * f,
                                   slack_m=self.slack_m - self.yield_n / self.hardening_n_per_m,
                                   yield_n=math.inf)

    @property
    def has_mount(self) -> bool:
        return self.mb > 0.0

    @property
    def n_states(self) -> int:
        return 6 if self.mb > 0.0 else 4

    @classmethod
    def from_rig(cls, rig: RigParams, *, slack_m: float, break_n: float, break_duration_s: float,
                 lanyard_stiffness_n_per_m: float | None = None, yield_n: float | None = None,
                 hardening_n_per_m: float | None = None) -> 'ChainParams':
        p = cls._from_rig(rig, slack_m=slack_m, break_n=break_n, break_duration_s=break_duration_s,
                          lanyard_stiffness_n_per_m=lanyard_stiffness_n_per_m)
        if yield_n is None:
            return p
        if not (hardening_n_per_m is not None and hardening_n_per_m > 0 and yield_n > 0):
            raise SimError(f'coupon yield {yield_n!r} N / hardening {hardening_n_per_m!r} N/m; expected both > 0')
        return dataclasses.replace(p, yield_n=float(yield_n), hardening_n_per_m=float(hardening_n_per_m))

    @classmethod
    def _from_rig(cls, rig: RigParams, *, slack_m: float, break_n: float, break_duration_s: float,
                  lanyard_stiffness_n_per_m: float | None = None) -> 'ChainParams':
        fc = rig.force_chain
        kl = fc.lanyard_stiffness_n_per_m if lanyard_stiffness_n_per_m is None else lanyard_stiffness_n_per_m
        deps = getattr(rig, 'departures', None)
        if not deps:
            return cls(m1=fc.m1, m2=fc.m2, k1=fc.load_cell_stiffness_n_per_m, k2=fc.load_cell_stiffness_n_per_m,
                       c1=fc.c1, c2=fc.c2, kl=kl, cl=fc.lanyard_damping(kl), slack_m=slack_m, break_n=break_n,
                       break_duration_s=break_duration_s)
        # physical departures: the true m2 (effective_mass) and the mount (mount_resonance)
        em = deps.get('effective_mass')
        fc = dataclasses.replace(fc, moving_side_mass_kg=em['mass_kg']) if em is not None else fc
        mb = km = cm = 0.0
        mr = deps.get('mount_resonance')
        if mr is not None:
            mb = mr.get('base_mass_kg', MOUNT_BASE_MASS_FRACTION * fc.m2)   # the bracket (departures.py)
            carried = mb + fc.m2                         # the stiff cell makes base + m2 move as one on the mount
            km = (2.0 * math.pi * mr['frequency_hz']) ** 2 * carried
            cm = 2.0 * mr['damping_ratio'] * math.sqrt(km * carried)
        return cls(m1=fc.m1, m2=fc.m2, k1=fc.load_cell_stiffness_n_per_m, k2=fc.load_cell_stiffness_n_per_m,
                   c1=fc.c1, c2=fc.c2, kl=kl, cl=fc.lanyard_damping(kl), slack_m=slack_m, break_n=break_n,
                   break_duration_s=break_duration_s, mb=mb, km=km, cm=cm)

    @property
    def series_stiffness(self) -> float:
        if self.mb > 0.0:
            return 1.0 / (1.0 / self.kl + 1.0 / self.k1 + 1.0 / self.k2 + 1.0 / self.km)
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
    if p.mb > 0.0:
        return -(p.k2 * (x[..., 0] - x[..., 4]) + p.c2 * (x[..., 1] - x[..., 5]))
    return -(p.k2 * x[..., 0] + p.c2 * x[..., 1])


def force_stat(x, p: ChainParams):
    x = np.asarray(x)
    return p.k1 * x[..., 2] + p.c1 * x[..., 3]


def chain_rhs(t: float, x, u, p: ChainParams) -> np.ndarray:
    """dx/dt of the model of record (general, nonlinear: tension-only clip and coupon beta)."""
    if p.mb > 0.0:
        return _mount_rhs(x, u, p, clip=True)
    w, wd, u1, v1 = x
    x3, v3, a3, beta = u
    g = p.kl * (w + (x3 - p.slack_m) - u1) + p.cl * (wd + v3 - v1)
    tl = beta * g if g > 0.0 else 0.0
    fm = -(p.k2 * w + p.c2 * wd)
    fs = p.k1 * u1 + p.c1 * v1
    return np.array([wd, (fm - tl) / p.m2 - a3, v1, (tl - fs) / p.m1])


def _mount_rhs(x, u, p: ChainParams, clip: bool) -> np.ndarray:
    """dx/dt with the mount (6 states). ``clip=False``: the taut linear piece (tension unclipped, beta = 1)."""
    w, wd, u1, v1, wb, wbd = x
    x3, v3, a3, beta = u
    g = p.kl * (w + (x3 - p.slack_m) - u1) + p.cl * (wd + v3 - v1)
    if clip:
        tl = beta * g if g > 0.0 else 0.0
    else:
        tl = g
    fm = -(p.k2 * (w - wb) + p.c2 * (wd - wbd))
    fs = p.k1 * u1 + p.c1 * v1
    return np.array([wd, (fm - tl) / p.m2 - a3, v1, (tl - fs) / p.m1,
                     wbd, (-p.km * wb - p.cm * wbd - fm) / p.mb - a3])


def chain_rhs_taut(t: float, x, u, p: ChainParams) -> np.ndarray:
    """dx/dt of the taut linear piece (tension unclipped, beta = 1), any number of states."""
    if p.mb > 0.0:
        return _mount_rhs(x, u, p, clip=False)
    x3, v3, a3, _ = u
    g = p.kl * (x[0] + x3 - p.slack_m - x[2]) + p.cl * (x[1] + v3 - x[3])
    fm = -(p.k2 * x[0] + p.c2 * x[1])
    fs = p.k1 * x[2] + p.c1 * x[3]
    return np.array([x[1], (fm - g) / p.m2 - a3, x[3], (g - fs) / p.m1])


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
    if p.mb > 0.0:
        A = np.pad(A, ((0, 2), (0, 2)))
        B = np.pad(B, ((0, 2), (0, 0)))
        # moving cell between base (wb) and m2 (w): F_move = -(k2 (w - wb) + c2 (w' - wb'))
        A[1, 4] = p.k2 / p.m2
        A[1, 5] = p.c2 / p.m2
        A[4, 5] = 1.0
        A[5, :] = np.array([p.k2, p.c2, 0.0, 0.0, -p.km - p.k2, -p.cm - p.c2]) / p.mb
        B[5, 2] = -1.0
    if taut:
        # T = kl (w + p - u1) + cl (w' + v3 - v1)
        A[1, :4] += np.array([-p.kl, -p.cl, p.kl, p.cl]) / p.m2
        B[1, :2] += np.array([-p.kl, -p.cl]) / p.m2
        A[3, :4] += np.array([p.kl, p.cl, -p.kl, -p.cl]) / p.m1
        B[3, :2] += np.array([p.kl, p.cl]) / p.m1
    return A, B
