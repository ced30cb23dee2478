"""Issue 39, section 2 on the moving cell: when the force model names the cell's gain and the one selection withholds
it for a library term (priority.cause_check: the term explains the moving cell as well held out), the term is measured
with the gain and the effective mass m2 beside it (their forms, F_move and a2, the moving cell's catalog columns),
and it is named only when it beats each of them in its place.

Before, the gain and m2 stayed at the rig YAML's values, and their stated uncertainties entered the term's budget as
the coefficient's shift with each one standard uncertainty off. A load term is nearly collinear with F_move over the
loaded window, so that shift swamped it: on this campaign (df4bff0) an injected `T*t` of 3x the moving cell's band
came out at 0.0126 (true 0.0128) with the interval [-0.0042, 0.0294], twice the gain's 0.0084 each side, holding 0,
and went to `within_tolerance`.

The campaign is bench_sweep's nominal one (the independent generator, tests/independent/rig.py, seed 3900, twelve
pulls on sets 2-4 at 20 kHz), with one term added to the recorded moving cell as bench_sweep adds it: sized from the
generator's clean signals to 3x the band over the loaded windows, put back on the channel's ADC steps. discover sees
the data and the generator's datasheet rig only."""
from __future__ import annotations

import pytest
from sweep_case import base_case, with_term

from force_discovery.core.pipeline import discover

pytestmark = pytest.mark.slow


@pytest.fixture(scope='module')
def base():
    return base_case()


@pytest.mark.parametrize('sign', [1.0, -1.0])
def test_a_load_term_on_the_moving_cell_is_named_beside_the_fitted_gain_and_mass(base, sign, tmp_path):
    camp, coef = with_term(base, 'force_moving', 'T*t', sign)
    report = discover(camp, base.rig, tmp_path, scheduler='inline', plots=False)
    mine = [t for t in report['beyond_catalog'] if t['channel'] == 'force_moving']
    assert mine and mine[0]['term'] == 'T*t', (coef, report['beyond_catalog'], report['beyond_search'])
    first = mine[0]
    assert 'moving_cell_gain' in report['beyond_search']['catalog_not_fitting'], report['beyond_search']
    assert abs(first['coefficient'] - coef) <= 0.3 * abs(coef), (coef, first['coefficient'])
    budget = first['uncertainty_budget']
    # the data measure the gain and m2 beside the term: their stated uncertainties move it no more
    assert budget['gain'] < 0.01 * budget['statistical'] and budget['m2'] < 0.01 * budget['statistical'], budget
    alt = first['best_catalog_alternative']   # it beat the gain and the mass in its place, and says by how much
    assert alt['cause'] in ('moving_cell_gain', 'effective_mass') and alt['held_out_margin'] > 0, alt


@pytest.mark.parametrize('term', ['T*v', 'T*x'])
def test_a_load_term_the_force_model_left_alone_is_measured_beside_the_gain_and_mass(base, term, tmp_path):
    # the force model names neither the gain nor m2 here (both within their tolerances), so the one selection
    # withholds nothing; before, the term's budget then kept their stated uncertainties: on 1f70f8d a T*v of 3x the
    # band came out 0.00218 (true 0.00222), statistical u 9e-6, the gain's line 0.0013, its interval holding 0, and
    # went to within_tolerance. The data separate it from their forms (F_move, a2), and measure them better
    camp, coef = with_term(base, 'force_moving', term, 1.0)
    report = discover(camp, base.rig, tmp_path, scheduler='inline', plots=False)
    assert report['beyond_search']['catalog_not_fitting'] == {}, report['beyond_search']['catalog_not_fitting']
    mine = [t for t in report['beyond_catalog'] if t['channel'] == 'force_moving']
    assert mine and mine[0]['term'] == term, (coef, report['beyond_catalog'], report['beyond_search'])
    first = mine[0]
    assert abs(first['coefficient'] - coef) <= 0.3 * abs(coef), (coef, first['coefficient'])
    assert min(first['ci95']) <= coef <= max(first['ci95']), (coef, first['ci95'])
    budget = first['uncertainty_budget']
    assert 'gain_mass_fitted' in budget and budget['gain'] < 0.01 * budget['statistical'], budget
    assert first['best_catalog_alternative']['held_out_margin'] > 0, first['best_catalog_alternative']


def test_a_term_the_gain_and_mass_take_nearly_whole_is_said_not_identifiable_at_this_strength(base, tmp_path):
    # a2*t over the loaded window is nearly a2, m2's form: of its 2.37 N rms found on the moving cell, 0.30 N is
    # beside F_move and a2, inside the 1 N band. Not named, and no longer silent: beyond_search.identifiability says
    # why (issue 39, section 1)
    camp, coef = with_term(base, 'force_moving', 'a2*t', 1.0)
    report = discover(camp, base.rig, tmp_path, scheduler='inline', plots=False)
    assert not [t for t in report['beyond_catalog'] if t['channel'] == 'force_moving'], report['beyond_catalog']
    said = [e for e in report['beyond_search']['identifiability']
            if e['channel'] == 'force_moving' and e['term'] == 'a2*t']
    assert said and said[0]['reason'].startswith('not identifiable at this strength'), said


def test_the_campaign_with_nothing_added_names_nothing_beyond_the_catalog(base, tmp_path):
    report = discover(base.campaign, base.rig, tmp_path, scheduler='inline', plots=False)
    assert report['beyond_catalog'] == [], report['beyond_catalog']
