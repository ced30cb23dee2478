"""Friction: the motor current against the force balance of the model of record (the current channel); dry
friction is an offset F_c sign(v3). ROS-free."""
from __future__ import annotations

from typing import Iterable, Optional, Tuple

import numpy as np

from .prep import Pull

STILL_M_S = 1e-4     # |v3| below this: the carriage is at rest (no dry friction)
MOVING_M_S = 0.05    # v3 above this: moving forward (dry friction at its full value)


def drive_force_balance(p: Pull, drive, fm: np.ndarray) -> np.ndarray:
    """The drive force the model of record needs for the pull's measured motion: m_c a3 + b v3 + F_move."""
    return drive.reflected_mass_kg * p.a3 + drive.viscous_damping_n_s_per_m * p.v3 + fm


def current_resid(p: Pull, rig) -> Optional[Tuple[np.ndarray, np.ndarray]]:
    if p.current is None:
        return None
    d = rig.drive
    rho = p.current * d.force_per_amp_n_per_a - drive_force_balance(p, d, p.fm)
    moving = p.v3 > MOVING_M_S
    still = np.abs(p.v3) < STILL_M_S
    return rho, np.where(p.usable(), np.where(moving, 1.0, np.where(still, 0.0, np.nan)), np.nan)


def friction_stat(rows: np.ndarray) -> float:
    """The friction force from the friction_row()s: median residual while moving minus at rest."""
    return float(np.median(rows[:, 0]) - np.median(rows[:, 1]))


def friction_row(p: Pull, rig) -> Optional[tuple]:
    """The pull's median force-balance residual while moving and at rest (None without a current channel)."""
    cr = current_resid(p, rig)
    if cr is None:
        return None
    rho, sg = cr
    return np.median(rho[sg == 1.0]), np.median(rho[sg == 0.0])


def friction_rows(rows: Iterable[Optional[tuple]]) -> Optional[np.ndarray]:
    """The friction_row()s as an array, None when a pull had no current channel."""
    out = []
    for r in rows:
        if r is None:
            return None
        out.append(r)
    return np.array(out)


def friction_sse(p: Pull, rig, fc: float) -> float:
    rho, sg = current_resid(p, rig)
    ok = ~np.isnan(sg)
    r = rho[ok] - fc * sg[ok]
    r = r - np.median(rho[sg == 0.0])
    r = np.clip(r, -np.percentile(np.abs(r), 95) * 3 - 1e-9, np.percentile(np.abs(r), 95) * 3 + 1e-9)
    return float(np.sum((r / rig.drive.force_per_amp_n_per_a) ** 2))   # in A^2
