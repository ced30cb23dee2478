"""A sensor's term confirmed where it acts (moving_sse). A term on the stationary cell or the accelerometer is found in
the sensor's free phases, where its signals are small, and judged by its size over the analysis window, where the
sensor reads the force (selection.search_channel). That size is an extrapolation from the free phases, and there two
columns can be near-tied that part ways under the load: on the stationary cell, F_move is g m2 a2 with the lanyard
slack and hundreds of newtons more under the load. The moving cell reads the same force over the window: the
sensor's reading enters its model through T (the stationary cell) or m2 a2 (the accelerometer). So a sensor's term is
named only when, taken out of the sensor, it lowers the moving cell's held-out squared residual, with the cell's gain
and m2 refitted beside (their forms, the moving cell's catalog columns): the same held-out criterion, on the channel
that reads the force. ROS-free."""
from __future__ import annotations

from typing import Optional, Sequence

import numpy as np

from force_tester_sim.core.extra_terms import SIN

from .grammar import FORCE_FORMS
from .normal_equations import BeyondPart
from .selection import fit_model, sse

MOVING = 'force_moving'


def moving_sse(parts: Sequence[BeyondPart], fit: Sequence[int], held: Sequence[int]) -> Optional[np.ndarray]:
    """The moving cell's squared residual on each held-out pull, with its gain's and m2's forms fitted on the fitted
    pulls (no library term), or None when a pull lacks the moving cell."""
    if not fit or not held or not all(MOVING in parts[j].stats for j in (*fit, *held)):
        return None
    fs, hs = [parts[j].stats[MOVING] for j in fit], [parts[j].stats[MOVING] for j in held]
    n_prod = sum(1 for nm in fs[0].names if not nm.endswith(SIN))
    cat = tuple(range(len(FORCE_FORMS))) if fs[0].catalog is not None else ()
    model = fit_model(fs, (), None, cat, n_prod)
    return np.array([sse(st, model, n_prod) for st in hs])
