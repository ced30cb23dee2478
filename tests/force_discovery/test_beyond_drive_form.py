"""Issue 39, section 2 on the motor current: a term there is fitted with the drive's force per amp k_F and its
reflected mass beside it (their forms, the drive force the model of record needs and a3, each over k_F: the current's
catalog columns after the Coulomb step), so the data measure them, and it is named only when it beats each in its
place.

Before, k_F and the reflected mass stayed at the rig YAML's values, and their stated uncertainties (the torque
constant's and the pulley's 2.24 % on k_F, the inertias' 5 %) entered every term's budget as the coefficient's shift
with each one standard uncertainty off. On this campaign (0cc011a) an injected aerodynamic drag `v^2` of 3x the
current's band came out at 0.0489 A/(m/s)^2 (true 0.0510) with a statistical u of 0.0004 and the drive's lines
0.0017 (the actuator's inertia), 0.0007 and 0.0005 (k_F): its contribution's interval, [0.188, 0.226] A, reached
into the band (0.191 A), and it went to `within_tolerance`.

The campaign is bench_sweep's nominal one (the independent generator, tests/independent/rig.py, seed 3900, twelve
pulls on sets 2-4 at 20 kHz), with the term added to the recorded current as bench_sweep adds it: sized from the
generator's clean signals to 3x the band over the loaded windows, put back on the channel's ADC steps. discover sees
the data and the generator's datasheet rig only."""
from __future__ import annotations

import numpy as np
import pytest
from sweep_case import base_case, with_term

from force_discovery.core.beyond.normal_equations import ChannelStats, Column
from force_discovery.core.beyond.selection import separable
from force_discovery.core.pipeline import discover

STATED = ('torque_constant', 'pulley_radius', 'actuator_inertia', 'motor_inertia')   # the drive's stated lines


@pytest.fixture(scope='module')
def base():
    return base_case()


@pytest.mark.slow
def test_a_drag_on_the_current_is_named_beside_the_fitted_drive_constants(base, tmp_path):
    # one sign: a discover of this campaign is ~25 CPU-s; both signs are in the sweep (docs/discovery-sweep-drive.md)
    camp, coef = with_term(base, 'motor_current', 'v^2', -1.0)
    report = discover(camp, base.rig, tmp_path, scheduler='inline', plots=False)
    mine = [t for t in report['beyond_catalog'] if t['channel'] == 'motor_current']
    assert mine and mine[0]['term'] == 'v^2', (coef, report['beyond_catalog'], report['beyond_search'])
    first = mine[0]
    assert abs(first['coefficient'] - coef) <= 0.3 * abs(coef), (coef, first['coefficient'])
    assert min(first['ci95']) <= coef <= max(first['ci95']), (coef, first['ci95'])
    budget = first['uncertainty_budget']
    # the data measure k_F and the reflected mass beside the term: their stated uncertainties move it no more, and
    # what measuring them costs is its own line
    assert all(budget[k] < 0.01 * budget['statistical'] for k in STATED), budget
    assert 0 < budget['drive_fitted'] < 3 * budget['statistical'], budget
    alt = first['best_catalog_alternative']   # it beat the drive's causes in its place, and says by how much
    assert alt['held_out_margin'] > 0, alt


def stats(X: np.ndarray) -> ChannelStats:
    """One pull's statistics of columns X (the last column the catalog's), against a zero residual."""
    lib, cat = X[:, :-1], X[:, -1:]
    return ChannelStats(tuple(f'c{k}' for k in range(lib.shape[1])), lib.T @ lib, np.zeros(lib.shape[1]), 0.0,
                        len(X), Column(cat.T @ cat, lib.T @ cat, np.zeros(1)), {}, {})


def test_a_term_in_the_span_of_the_drive_forms_is_not_separable():
    # an F_move term on the current is exactly k_F's form less the mass's and the damping's: with them fitted beside
    # it, its coefficient is not measured at all, and its budget keeps the stated lines (selection.search_channel)
    rng = np.random.default_rng(0)
    a, b, c = rng.normal(size=(3, 500))
    in_span = stats(np.column_stack([a, b, 2.0 * a - 0.5 * b]))
    apart = stats(np.column_stack([a, b, c]))
    assert not separable([in_span], (0, 1), (0,), 0)
    assert separable([apart], (0, 1), (0,), 0)
