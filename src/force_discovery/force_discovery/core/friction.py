"""Friction: the motor current against the force balance of the model of record (the current channel); dry
friction is an offset F_c sign(v3). ROS-free.

Dry and viscous friction are fitted together when the campaign's pulls run at different speeds: each pull's
median force-balance residual while moving (minus at rest) is F_c + db v, v its median speed while moving, db the
viscous damping's departure from the rig YAML's b. A straight line through the pulls' (v, residual) gives F_c as
its intercept and db as its slope, so the drive's viscous damping is measured rather than taken from the rig YAML
with its wide stated uncertainty (viscous_separable says when the speeds allow it; otherwise F_c is the median
residual with the YAML's b).

The current's zero is the residual at rest BEFORE the carriage first moves (rest_level): after a stop a dry
contact holds whatever force the drive still applies, anywhere within +/- F_c (the velocity loop's integrator
keeps a current against it), so the rest after the pull is not the current's zero. On the independent generator's
tanh friction (seed 5102, F_c 218 N) the rest after the stop read -25 to -35 N and the friction came out 252 N;
the rest before the launch reads 0.01 N."""
from __future__ import annotations

import math
from typing import Iterable, Optional, Tuple

import numpy as np

from force_tester_common.core.events import median

from .prep import Pull

STILL_M_S = 1e-4     # |v3| below this: the carriage is at rest (no dry friction)
MOVING_M_S = 0.05    # v3 above this: moving forward (dry friction at its full value)
MIN_SPEED_SPREAD = 0.2   # the pulls' speeds must span this fraction of their mean to separate dry from viscous
MIN_REST_SAMPLES = 100   # rest samples before the first motion for the current's zero (else every rest sample)


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


def rest_level(rho: np.ndarray, sg: np.ndarray) -> float:
    """The current residual's zero (current_resid's (rho, sg)): its median at rest before the carriage first moves
    (module doc: after a stop, dry friction holds the drive's leftover force), or over every rest sample when the
    record has fewer than MIN_REST_SAMPLES of those."""
    still = sg == 0.0
    moving = np.flatnonzero(sg == 1.0)
    before = still[:moving[0]] if len(moving) else still
    if np.count_nonzero(before) >= MIN_REST_SAMPLES:
        return float(median(rho[:len(before)][before]))
    return float(median(rho[still]))


def viscous_fit(rows: np.ndarray) -> Optional[Tuple[float, float, float, float]]:
    """(F_c, db, the standard error of db, the standard error of F_c) of the least-squares line through the pulls'
    (speed, moving minus still residual) (rows: friction_row()s); None when the speeds do not span
    MIN_SPEED_SPREAD of their mean or there are fewer than 3 pulls."""
    rows = np.asarray(rows, float)
    if rows.ndim != 2 or rows.shape[1] < 3 or len(rows) < 3:
        return None
    v, y = rows[:, 2], rows[:, 0] - rows[:, 1]
    vbar = float(np.mean(v))
    sxx = float(np.sum((v - vbar) ** 2))
    if not (np.ptp(v) >= MIN_SPEED_SPREAD * abs(vbar) and sxx > 0):
        return None
    db = float(np.sum((v - vbar) * (y - y.mean())) / sxx)
    fc = float(y.mean() - db * vbar)
    s2 = float(np.sum((y - fc - db * v) ** 2)) / (len(v) - 2)
    return fc, db, math.sqrt(s2 / sxx), math.sqrt(s2 * (1.0 / len(v) + vbar * vbar / sxx))


def joint_ci(rows: np.ndarray, confidence: float) -> Tuple[float, float]:
    """The confidence interval of viscous_fit's F_c: Student's t with n - 2 degrees of freedom on its standard
    error (the textbook interval of a line's intercept; a bootstrap over so few pulls is too narrow)."""
    from scipy.stats import t
    fc, _db, _se_db, se = viscous_fit(rows)
    h = float(t.ppf(0.5 + confidence / 2, len(rows) - 2)) * se
    return fc - h, fc + h


def viscous_separable(rows: Optional[np.ndarray], u_b: float) -> bool:
    """Whether the pulls' speeds measure the viscous damping better than the rig YAML states it (u_b: its
    standard uncertainty): then friction_stat(rows, joint=True)."""
    if rows is None:
        return False
    fit = viscous_fit(rows)
    return fit is not None and fit[2] < u_b


def viscous_u(rig) -> float:
    """The standard uncertainty of the drive's viscous damping b (motor + actuator) the rig YAML states."""
    u = rig.uncertainty
    return math.hypot(u.u('drive.viscous_damping_motor_n_s_per_m'), u.u('drive.viscous_damping_actuator_n_s_per_m'))


def friction_stat(rows: np.ndarray, joint: bool = False) -> float:
    """The friction force from the friction_row()s: joint, the intercept of viscous_fit (when the rows allow one,
    as a bootstrap resample may not); else the median residual while moving minus at rest."""
    if joint:
        fit = viscous_fit(rows)
        if fit is not None:
            return fit[0]
    return float(np.median(rows[:, 0]) - np.median(rows[:, 1]))


def viscous_departure(rows: Optional[np.ndarray], joint: bool) -> float:
    """db, the viscous damping's departure from the rig YAML's the rows measure (0 when not joint)."""
    fit = viscous_fit(rows) if (joint and rows is not None) else None
    return 0.0 if fit is None else fit[1]


def friction_row(p: Pull, rig) -> Optional[tuple]:
    """The pull's median force-balance residual while moving and at rest (rest_level), and its median speed while
    moving (None without a current channel)."""
    cr = current_resid(p, rig)
    if cr is None:
        return None
    rho, sg = cr
    return median(rho[sg == 1.0]), rest_level(rho, sg), median(p.v3[sg == 1.0])


def friction_rows(rows: Iterable[Optional[tuple]]) -> Optional[np.ndarray]:
    """The friction_row()s as an array, None when a pull had no current channel."""
    out = []
    for r in rows:
        if r is None:
            return None
        out.append(r)
    return np.array(out)


def friction_sse(p: Pull, rig, fc: float, db: float = 0.0) -> float:
    """The pull's squared current residual (A^2, clipped at 3 x its 95th percentile) with dry friction fc and the
    viscous damping db off the rig YAML's."""
    rho, sg = current_resid(p, rig)
    rho = rho - db * p.v3
    ok = ~np.isnan(sg)
    r = rho[ok] - fc * sg[ok]
    r = r - rest_level(rho, sg)
    r = np.clip(r, -np.percentile(np.abs(r), 95) * 3 - 1e-9, np.percentile(np.abs(r), 95) * 3 + 1e-9)
    return float(np.sum((r / rig.drive.force_per_amp_n_per_a) ** 2))   # in A^2
