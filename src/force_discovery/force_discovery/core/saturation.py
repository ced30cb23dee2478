"""The data-quality screen's saturations (quality.screen_pull calls it): a load cell that stops at a level while the
other cell keeps rising. ROS-free (numpy only).

A saturated cell is a defect, not physics: whatever stops it (the ADC's range, a conditioner or amplifier that
clips at its supply, a cell past its rated range) the load it should have read there is lost, and a fit that
sees the flat top takes it for a non-linearity (`F_stat^3` on the moving cell, when the stationary cell of an
independent campaign was clipped). A rig's real peak is rounded: on clean pulls of every set (our simulator, its
truth rig and the independent generator) a cell stays within SATURATION_Z of its noise of its record's extreme
for at most 0.12 ms, while the other cell moves by at most 0.2 % of the peak in that time. A clipped cell stays
there for 1.4-1.9 ms while the other rises by 50-120 % of the level. So a saturation is a stretch of at least
SATURATION_MIN_S within SATURATION_Z noise of the cell's extreme, during which the other cell rises (or falls, at
the minimum) by at least SATURATION_RISE of the level and SATURATION_RISE_Z of its own noise. Equal samples are
not needed: a conditioner that clips before the DAQ's noise and filter leaves a noisy, rounded flat top, which
the `clipping` test (exactly equal samples) does not see.
"""
from __future__ import annotations

from typing import Dict, List, NamedTuple, Sequence, Tuple

import numpy as np

SATURATION_Z = 4.0            # the flat top: within 4 noise sigma of the cell's record extreme
SATURATION_MIN_S = 0.3e-3     # ... for at least 0.3 ms (clean peaks: <= 0.12 ms; clipped: >= 1.4 ms)
SATURATION_MIN_SAMPLES = 5    # ... and at least 5 samples (a slow DAQ)
SATURATION_GAP_S = 0.05e-3    # noise dips out of the band for a sample or two: runs this close are one
SATURATION_JOIN_S = 5e-3      # the cell's other visits to that level within 5 ms (ringing at the limit) join it
SATURATION_RISE = 0.05        # the other cell rises by >= 5 % of the level over the flat top (clean: <= 0.2 %)
SATURATION_RISE_Z = 20.0      # ... and by >= 20 x its own noise


class Saturation(NamedTuple):
    """A cell's flat top: samples [i0, i1), the level it sat at, the other cell and how far it rose meanwhile."""

    channel: str
    i0: int
    i1: int
    level: float
    other: str
    rise: float


def _runs(b: np.ndarray, gap: int) -> List[Tuple[int, int]]:
    """[start, end) of the runs of True in b, runs at most ``gap`` samples apart joined."""
    idx = np.flatnonzero(b)
    if not len(idx):
        return []
    cut = np.flatnonzero(np.diff(idx) > gap + 1)
    return list(zip(np.r_[idx[0], idx[cut + 1]].tolist(), (np.r_[idx[cut], idx[-1]] + 1).tolist()))


def saturations(cells: Dict[str, Tuple[np.ndarray, float]], dt: float,
                pairs: Sequence[Tuple[str, str]]) -> List[Saturation]:
    """The saturations of one record (the module docstring). cells: channel -> (its samples, finite; its noise
    sigma); pairs: (cell, the other cell that reads the same load)."""
    out = []
    min_run = max(SATURATION_MIN_SAMPLES, int(np.ceil(SATURATION_MIN_S / dt)))
    gap = max(1, int(round(SATURATION_GAP_S / dt)))
    join = max(gap, int(round(SATURATION_JOIN_S / dt)))
    for c, o in pairs:
        if c not in cells or o not in cells:
            continue
        (x, sigma), (y, sigma_o) = cells[c], cells[o]
        for sign in (1.0, -1.0):
            xs, ys = sign * x, sign * y
            top = float(np.max(xs))
            if top <= 0:
                continue
            near = xs >= top - SATURATION_Z * sigma
            for g0, g1 in _runs(near, join):
                flat = [(g0 + a, g0 + b) for a, b in _runs(near[g0:g1], gap) if b - a >= min_run]
                rises = [float(np.max(ys[a:b]) - ys[a]) for a, b in flat]
                if rises and max(rises) >= max(SATURATION_RISE * top, SATURATION_RISE_Z * sigma_o):
                    level = sign * float(np.median(xs[g0:g1][near[g0:g1]]))
                    out.append(Saturation(c, g0, g1, level, o, sign * max(rises)))
    return out
