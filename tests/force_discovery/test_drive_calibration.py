"""Issue 38: the drive calibrated on the data (friction.drive_fit, drive_calibration, calibrated_rows). A synthetic
drive record with known constants: the true force per amp 3 % below the rig YAML's, the reflected mass 4 % above,
dry friction 200 N while moving and a load that rises to a few kilonewtons. The uncalibrated friction carries the
force constant's error times the drive force; the calibrated one recovers k_F and the friction, and the datasheet's
force-constant line leaves the budget."""
from __future__ import annotations

import math
from functools import partial

import numpy as np
import pytest
import yaml

from force_discovery.core import budget as B
from force_discovery.core.friction import (
    calibrated_rows,
    drive_calibration,
    drive_line,
    drive_lines,
    friction_row,
    friction_rows,
    friction_stat,
)
from force_discovery.core.prep import Pull
from force_tester_sim.core.params import NOMINAL_YAML, rig_from_dict

DT = 1e-4
K_TRUE, M_TRUE, F_C = 0.97, 1.04, 200.0     # the true k_F and m_c over the rig YAML's; the dry friction (N)


def _rig():
    return rig_from_dict(yaml.safe_load(NOMINAL_YAML.read_text()))


def _pull(speed: float, load: float, seed: int) -> Pull:
    """A pull at this cruise speed (m/s) whose moving cell rises to load (N) and breaks; the current is what the true
    drive needs (module doc) plus a little noise."""
    d = _rig().drive
    n = 8000
    t = np.arange(n) * DT
    v = np.interp(t, [0.0, 0.1, 0.18, 0.6, 0.7, 0.8], [0.0, 0.0, speed, speed, 0.0, 0.0])
    a = np.gradient(v, DT)
    fm = load * np.clip((t - 0.25) / 0.3, 0.0, 1.0) * (t < 0.55)
    drive = M_TRUE * d.reflected_mass_kg * a + d.viscous_damping_n_s_per_m * v + fm + F_C * (v > 0.01)
    current = drive / (K_TRUE * d.force_per_amp_n_per_a)
    current = current + 0.01 * np.random.default_rng(seed).standard_normal(n)
    z = np.zeros(n)
    return Pull('p', t, DT, fm, z, z, z, np.cumsum(v) * DT, v, a, current, 0, n, 900, 2500, 5500, load)


def _rows():
    rig = _rig()
    pulls = [_pull(s, f, k) for k, (s, f) in enumerate([(2.0, 2000.0), (2.5, 3000.0), (3.0, 4000.0),
                                                         (3.5, 2500.0), (2.2, 3500.0), (3.2, 3000.0)])]
    return rig, pulls, friction_rows(friction_row(p, rig) for p in pulls)


def test_the_drive_calibration_recovers_the_force_per_amp_and_the_friction():
    rig, _pulls, rows = _rows()
    kf, u = drive_calibration(rows, rig)
    assert kf == pytest.approx(K_TRUE * rig.drive.force_per_amp_n_per_a, rel=2e-3), kf
    assert u < 0.002 * kf
    raw = calibrated_rows(rows, False)
    assert abs(friction_stat(calibrated_rows(rows, True)) - F_C) < 2.0
    assert abs(friction_stat(raw) - F_C) > 10.0          # the 3 % on the drive force, uncalibrated
    assert np.array_equal(calibrated_rows(raw, True), raw)              # three columns: as they are


def test_with_the_drive_calibrated_the_force_constant_line_leaves_the_budget():
    rig, pulls, rows = _rows()
    rows_v = [B.friction_variants(p, rig) for p in pulls]
    stat = partial(friction_stat, joint=False)
    stated = B.friction_systematics(calibrated_rows(rows, False), rows_v, stat)
    kf, u = drive_calibration(rows, rig)
    lines = drive_lines(rows, (kf, u), calibrated_rows(rows, False), rig)
    calibrated = B.friction_systematics(calibrated_rows(rows, True), rows_v, stat, drive=lines)
    assert stated['torque_constant'] > 5.0 and B.DRIVE_CALIBRATION not in stated, stated
    assert calibrated['torque_constant'] < 0.5 and calibrated['actuator_inertia'] < 0.5, calibrated
    assert 0.0 < calibrated[B.DRIVE_CALIBRATION] < 0.5 and B.KIND[B.DRIVE_CALIBRATION] == 'nominal constant'
    assert calibrated[B.DRIVE_CALIBRATION] == pytest.approx(drive_line(rows, u / kf))
    assert lines[0] == pytest.approx(np.mean(rows[:, 7]) * u / kf)
    # two models of the drive: half the gap between the calibrated friction and the datasheet drive's (its 3 % on D)
    assert calibrated[B.DRIVE_MODEL] == lines[1] > 5.0 and B.KIND[B.DRIVE_MODEL] == 'model form'


def test_pulls_that_do_not_settle_the_drive_keep_its_datasheet():
    """The pulls' own fits scattered, missing, or the reverse regression (the current on the cells' force) parting
    from the forward one (the independent generator's drive: module doc of friction.py): the rig YAML's k_F."""
    rig, _pulls, rows = _rows()
    assert np.allclose(rows[:, 6], rows[:, 3], atol=2e-3)   # the reverse regression agrees where the balance holds
    parted = rows.copy()
    parted[:, 6] = rows[:, 3] + 0.1                     # ... and where it does not, the two part: no calibration
    assert drive_calibration(parted, rig) is None
    spread = rows.copy()
    spread[:, 3] = [0.2, -0.2, 0.3, -0.3, 0.25, -0.1]   # the pulls' drive fits disagree by tens of percent
    assert drive_calibration(spread, rig) is None
    spread[:, 3] = math.nan                            # a pull with no drive fit of its own
    assert drive_calibration(spread, rig) is None
    assert drive_calibration(rows[:2], rig) is None    # two pulls: no spread to judge by
