"""Cell calibration: the stationary cell's natural frequency on m1 and the cells' damping ratio, measured on its free
decay after the break, and T recomputed with them when they depart from the rig's. ROS-free."""
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
CAL_MIN_FREQ_CHANGE = 0.01       # ... with the measured natural frequency when it departs from the rig's by this


def cell_mode(p: Pull, rig) -> Optional[Tuple[float, float]]:
    """One pull's (undamped natural frequency Hz, damping ratio) of the stationary cell on m1 from its free decay
    after the break (lanyard slack: m1 alone on its cell, one mode near sqrt(K_LC1/m1)), when its ring stands
    CAL_RING_TO_NOISE x above the record's quiet noise; else None. Of several such modes, the one nearest the rig's
    frequency: the DAQ's anti-alias filter rings at its own corner after the break, on every channel, and an 8-pole
    filter's least-damped pair (a Butterworth's damping 0.195) can be the stronger ring in the window (independent
    seed 5103: 3515 Hz, damping 0.20, beside the cell's 4587 Hz; the rig states 4605 Hz)."""
    fc = rig.force_chain
    f1 = math.sqrt(fc.load_cell_stiffness_n_per_m / fc.m1) / (2 * np.pi)
    i0 = p.brk + int(round(2e-4 / p.dt))
    seg = p.fs[i0:i0 + CAL_SAMPLES]
    if len(seg) < CAL_SAMPLES // 2:
        return None
    seg = seg - np.mean(seg)
    noise = float(np.std(p.fs[:max(10, p.pre1 // 4)]))
    found = [(f, z) for f, z, e in matrix_pencil(seg, p.dt)
             if abs(f / f1 - 1.0) < 0.3 and 0.0 < z < 0.5 and math.sqrt(e / len(seg)) > CAL_RING_TO_NOISE * noise]
    if not found:
        return None
    f, z = min(found, key=lambda m: abs(m[0] / f1 - 1.0))
    return f / math.sqrt(1.0 - z * z), z


def cell_zeta(p: Pull, rig) -> Optional[float]:
    """The damping ratio of cell_mode() (None: not measured)."""
    m = cell_mode(p, rig)
    return None if m is None else m[1]


def cell_frequency_from(modes: Iterable[Optional[Tuple[float, float]]]) -> Optional[tuple]:
    """(median natural frequency, its standard deviation, count, median damping ratio, its standard deviation) over
    the first CAL_PULLS measured cell_mode()s (None: not measured on that pull), in pull order; None if fewer than 2
    were measured."""
    found = first_measured(modes)
    if len(found) < 2:
        return None
    f, z = np.array(found).T
    return float(np.median(f)), float(np.std(f, ddof=1)), len(found), float(np.median(z)), float(np.std(z, ddof=1))


def rig_cell_frequency(rig) -> float:
    """The stationary cell's natural frequency on m1 by the rig's constants, sqrt(K_LC1 / m1) / 2 pi (Hz)."""
    fc = rig.force_chain
    return math.sqrt(fc.load_cell_stiffness_n_per_m / fc.m1) / (2 * np.pi)

def cell_damping_from(zetas: Iterable[Optional[float]]) -> Optional[Tuple[float, int]]:
    """(median, count) of the first CAL_PULLS measured ratios among the per-pull cell_zeta() values (None: not
    measured on that pull), in pull order; None if none was measured."""
    found = first_measured(zetas)
    return (float(np.median(found)), len(found)) if found else None


def first_measured(values: Iterable) -> list:
    """The first CAL_PULLS values that were measured (not None), in pull order."""
    found = []
    for v in values:
        if len(found) >= CAL_PULLS:
            break
        if v is not None:
            found.append(v)
    return found


def cell_damping_ratio(pulls: Sequence[Pull], idx: Sequence[int], rig) -> Optional[Tuple[float, int]]:
    """(damping ratio, pulls used) of the load cells (cell_zeta), the median over up to CAL_PULLS of the pulls idx
    where it could be measured; None if it could not on any."""
    return cell_damping_from(cell_zeta(pulls[j], rig) for j in idx)


def cell_calibration(cal: Optional[Tuple[float, int]], rig, fcal: Optional[Tuple[float, float, int]] = None
                     ) -> Tuple[Optional[Tuple[float, float]], Optional[dict]]:
    """(the stationary cell's (stiffness K_LC1, damping coefficient c1) that T must use, or None to keep the rig's;
    the calibration as report.json cell_damping says it, or None when nothing was measured) from
    cell_damping_ratio()'s result and cell_frequency_from()'s. T = F_stat + m1 a1 depends on the cell only through
    its natural frequency on m1 and its damping ratio, so a measured frequency that departs from the rig's by more
    than CAL_MIN_FREQ_CHANGE replaces K_LC1 / m1 (m1 kept), and a measured damping ratio that departs by more than
    CAL_MIN_CHANGE replaces the rig's."""
    if cal is None and fcal is None:
        return None, None
    fc = rig.force_chain
    zeta, k1 = fc.load_cell_damping_ratio, fc.load_cell_stiffness_n_per_m
    out = {'rig_damping_ratio': fc.load_cell_damping_ratio, 'measured_damping_ratio': None, 'pulls': 0,
           'used_for_tension': False}
    if cal is not None:
        z, n = cal
        used = abs(z / fc.load_cell_damping_ratio - 1.0) > CAL_MIN_CHANGE
        out.update(measured_damping_ratio=z, pulls=n, used_for_tension=used)
        zeta = z if used else zeta
    if fcal is not None:
        f, _sd, n = fcal[:3]
        f_rig = rig_cell_frequency(rig)
        used_f = abs(f / f_rig - 1.0) > CAL_MIN_FREQ_CHANGE
        out.update(rig_frequency_hz=f_rig, measured_frequency_hz=f, frequency_pulls=n,
                   frequency_used_for_tension=used_f)
        k1 = fc.m1 * (2 * np.pi * f) ** 2 if used_f else k1
    if not (out['used_for_tension'] or out.get('frequency_used_for_tension')):
        return None, out
    return (float(k1), 2.0 * zeta * math.sqrt(k1 * fc.m1)), out


def with_tension(p: Pull, rig, cal: Optional[Tuple[float, float]]) -> Pull:
    """The pull with T recomputed from its stationary cell with cell_calibration()'s (K_LC1, c1) (None: the pull as
    is)."""
    if cal is None:
        return p
    k1, c1 = cal
    return dataclasses.replace(p, T=tension_from_stationary(p.fs, p.dt, rig.force_chain.m1, k1, c1))


def calibration_note(cells: Optional[dict]) -> Optional[str]:
    if cells and cells.get('frequency_used_for_tension'):
        out = (f'the stationary cell rings on m1 at {cells["measured_frequency_hz"]:.5g} Hz (free decay after the '
               f'break, {cells["frequency_pulls"]} pulls), not the rig\'s {cells["rig_frequency_hz"]:.5g} Hz: T = '
               f'F_stat + m1 a1 uses the measured one')
        return out + ('' if not cells['used_for_tension'] else
                      f', and the measured damping ratio {cells["measured_damping_ratio"]:.4g}')
    if not (cells and cells['used_for_tension']):
        return None
    return (f'the cells ring with damping ratio {cells["measured_damping_ratio"]:.4g} (free decay after the '
            f'break, {cells["pulls"]} pulls), not the rig\'s {cells["rig_damping_ratio"]:.4g}: T = F_stat + '
            f'm1 a1 uses the measured one')
