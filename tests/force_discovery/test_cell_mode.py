"""Issue 38: the stationary cell's free decay after the break (cells.cell_mode) beside the DAQ anti-alias filter's own
ringing. An 8-pole filter's least-damped pole pair rings at its corner after the break (a Butterworth's damping
0.195); when that corner lies within the window around the rig's cell frequency, the stronger ring is the filter's,
not the cell's (independent seed 5103: 3515 Hz, damping 0.20, taken for the cell's 4606 Hz; m2 came out 1.017 kg
for 0.791). Of the modes in the window, the one nearest the rig's frequency is the cell's."""
from __future__ import annotations

import math

import numpy as np
import pytest
import yaml

from force_discovery.core.cells import cell_mode, rig_cell_frequency
from force_discovery.core.prep import Pull
from force_tester_sim.core.params import NOMINAL_YAML, rig_from_dict

DT = 2e-5            # 50 kHz


def _ring(t: np.ndarray, f: float, zeta: float, amp: float) -> np.ndarray:
    w = 2 * math.pi * f
    return amp * np.exp(-zeta * w * t) * np.cos(w * math.sqrt(1 - zeta * zeta) * t)


def _pull(modes) -> Pull:
    """A record whose stationary cell rings, from the break at 0.1 s, with these (frequency, damping, amplitude)s
    over a little noise."""
    n, brk = 10000, 5000
    t = np.arange(n) * DT
    after = np.clip(t - brk * DT, 0.0, None)
    fs = 0.01 * np.random.default_rng(3).standard_normal(n)
    for f, z, a in modes:
        fs = fs + np.where(t >= brk * DT, _ring(after, f, z, a), 0.0)
    z0 = np.zeros(n)
    return Pull('p', t, DT, z0, fs, z0, z0, z0, z0, z0, None, 0, n, 2000, 4000, brk, 1000.0)


def test_the_cell_mode_is_the_one_nearest_the_rigs_frequency_not_the_filters_ring():
    rig = rig_from_dict(yaml.safe_load(NOMINAL_YAML.read_text()))
    f1 = rig_cell_frequency(rig)
    cell = (0.996 * f1, 0.043, 3.0)
    filt = (0.76 * f1, 0.2, 40.0)            # within the +/- 30 % window, far stronger, far more damped
    f, z = cell_mode(_pull([filt, cell]), rig)
    assert f == pytest.approx(cell[0], rel=1e-3), (f, z)
    assert z == pytest.approx(cell[1], rel=0.05)
    f, z = cell_mode(_pull([filt]), rig)     # the filter's ring alone: nothing nearer to take
    assert f == pytest.approx(filt[0], rel=5e-3) and z == pytest.approx(0.2, rel=0.05)
