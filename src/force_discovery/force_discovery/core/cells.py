"""Cell-damping calibration: the load cells' damping ratio measured on the stationary cell's free decay after the
break, and T recomputed with it when it departs from the rig's. ROS-free."""
from __future__ import annotations

import dataclasses
import math
from typing import Iterable, Optional, Sequence, Tuple

import numpy as np

from .prep import Pull, tension_from_stationary
from .ringing import matrix_pencil

CAL_PULLS = 8                    # pulls whose stationary-cell free decay measures the cells' damping ratio
CAL_RING_TO_NOISE = 10.0         # ... when its rms stands this many times above the quiet record's noise
CAL_SAMPLES = 400                # ... over this many samples after the break (8 ms at 50 kHz)
CAL_MIN_CHANGE = 0.25            # T is recomputed with the measured ratio when it departs from the rig's by this


def cell_zeta(p: Pull, rig) -> Optional[float]:
    """One pull's damping ratio of the load cells from the stationary cell's free decay after the break (lanyard
    slack: m1 alone on its cell, one mode near sqrt(K_LC1/m1)), when its ring stands CAL_RING_TO_NOISE x above the
    record's quiet noise; else None."""
    fc = rig.force_chain
    f1 = math.sqrt(fc.load_cell_stiffness_n_per_m / fc.m1) / (2 * np.pi)
    i0 = p.brk + int(round(2e-4 / p.dt))
    seg = p.fs[i0:i0 + CAL_SAMPLES]
    if len(seg) < CAL_SAMPLES // 2:
        return None
    seg = seg - np.mean(seg)
    noise = float(np.std(p.fs[:max(10, p.pre1 // 4)]))
    for f, z, e in matrix_pencil(seg, p.dt):
        if abs(f / f1 - 1.0) < 0.3 and 0.0 < z < 0.5 and math.sqrt(e / len(seg)) > CAL_RING_TO_NOISE * noise:
            return z
    return None


def cell_damping_from(zetas: Iterable[Optional[float]]) -> Optional[Tuple[float, int]]:
    """(median, count) of the first CAL_PULLS measured ratios among the per-pull cell_zeta() values (None: not
    measured on that pull), in pull order; None if none was measured."""
    found = []
    for z in zetas:
        if len(found) >= CAL_PULLS:
            break
        if z is not None:
            found.append(z)
    return (float(np.median(found)), len(found)) if found else None


def cell_damping_ratio(pulls: Sequence[Pull], idx: Sequence[int], rig) -> Optional[Tuple[float, int]]:
    """(damping ratio, pulls used) of the load cells (cell_zeta), the median over up to CAL_PULLS of the pulls idx
    where it could be measured; None if it could not on any."""
    return cell_damping_from(cell_zeta(pulls[j], rig) for j in idx)


def cell_calibration(cal: Optional[Tuple[float, int]], rig) -> Tuple[Optional[float], Optional[dict]]:
    """(the stationary cell's damping coefficient c1 that T must use, or None to keep the rig's; the calibration as
    report.json cell_damping says it, or None when nothing was measured) from cell_damping_ratio()'s result."""
    if cal is None:
        return None, None
    fc = rig.force_chain
    zeta, n = cal
    used = abs(zeta / fc.load_cell_damping_ratio - 1.0) > CAL_MIN_CHANGE
    out = {'rig_damping_ratio': fc.load_cell_damping_ratio, 'measured_damping_ratio': zeta, 'pulls': n,
           'used_for_tension': used}
    return (2.0 * zeta * math.sqrt(fc.load_cell_stiffness_n_per_m * fc.m1) if used else None), out


def with_tension(p: Pull, rig, c1: Optional[float]) -> Pull:
    """The pull with T recomputed from its stationary cell with damping coefficient c1 (None: the pull as is)."""
    if c1 is None:
        return p
    fc = rig.force_chain
    return dataclasses.replace(p, T=tension_from_stationary(p.fs, p.dt, fc.m1, fc.load_cell_stiffness_n_per_m, c1))


def calibration_note(cells: Optional[dict]) -> Optional[str]:
    if not (cells and cells['used_for_tension']):
        return None
    return (f'the cells ring with damping ratio {cells["measured_damping_ratio"]:.4g} (free decay after the '
            f'break, {cells["pulls"]} pulls), not the rig\'s {cells["rig_damping_ratio"]:.4g}: T = F_stat + '
            f'm1 a1 uses the measured one')
