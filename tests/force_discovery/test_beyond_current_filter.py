"""Issue 39 on the motor current: its residual is formed through the filter that makes the encoder's a3 (like_a3),
so a term's column is the term through that filter (a filtered product, not a product of filtered factors), and the
analog channels' lead, fitted on the pull's balance alone, is fitted beside every term on each pull instead of being
held at a value that took part of the term up.

Before (main at 2b8b8f2), at 3x the current's band on the independent generator's nominal campaign: `F_move*a2` named
nothing (its column as a product of filtered factors was 0.028 A rms over the analysis window, the term 0.38 A), and
an `F_move^2` moved the pulls' leads from 63-76 us to -11 to -106 us and was left inside the band.

The campaign is bench_sweep's nominal one (sweep_case: seed 3900, twelve pulls on sets 2-4 at 20 kHz), the term
added to the recorded current as bench_sweep adds it. discover sees the data and the generator's datasheet rig only.
The first test is made-up data: the profile of a pull's own nuisance column."""
from __future__ import annotations

import numpy as np
import pytest
from sweep_case import base_case, with_term

from force_discovery.core.beyond import ChannelSeries, beyond_part
from force_discovery.core.beyond.grammar import channel_library
from force_discovery.core.beyond.spectrum import SearchSettings
from force_discovery.core.pipeline import discover

CHANNEL = 'motor_current'


def test_a_pulls_nuisance_column_is_fitted_beside_every_term():
    # one pull whose residual is 2 x its x column plus a large multiple of a column of its own (the lead's, say),
    # correlated with x: with that column profiled out, the library's least squares give x its 2, whatever the
    # nuisance's size
    rng = np.random.default_rng(3)
    n = 4000
    t = np.linspace(0.0, 1.0, n)
    sig = {'F_move': rng.normal(size=n), 'F_stat': rng.normal(size=n), 'T': rng.normal(size=n),
           'a2': rng.normal(size=n), 'v': np.sin(7 * t), 'x': t ** 2, 't': t}
    own = np.sin(40 * t) + 0.5 * t ** 2
    y = 2.0 * sig['x'] + 30.0 * own + 0.01 * rng.normal(size=n)
    scales = {s: 1.0 for s in sig}
    part = beyond_part({CHANNEL: ChannelSeries(y, sig, None, {}, {}, nuisance=own)}, SearchSettings(scales, {}))
    st = part.stats[CHANNEL]
    k = list(channel_library(CHANNEL)).index('x')
    assert st.xy[k] / st.gram[k, k] == pytest.approx(2.0, rel=0.01), st.xy[k] / st.gram[k, k]


@pytest.fixture(scope='module')
def base():
    return base_case()


@pytest.mark.slow
@pytest.mark.parametrize('term,sign,share', [('F_move*a2', 1.0, None), ('F_move^2', 1.0, 0.3)])
def test_a_ringing_or_a_load_product_on_the_current_is_named(base, term, sign, share, tmp_path):
    # F_move*a2: a2 is mostly the cells' ringing, above what a3 follows, so only the filtered product carries it
    # (its coefficient comes out 37 % high: the recorded a2 against the generator's clean one, not checked here);
    # F_move^2: the lead took it up while held
    camp, coef = with_term(base, CHANNEL, term, sign)
    report = discover(camp, base.rig, tmp_path, scheduler='inline', plots=False)
    mine = [t for t in report['beyond_catalog'] if t['channel'] == CHANNEL]
    assert mine and mine[0]['term'] == term, (coef, report['beyond_catalog'], report['beyond_search'])
    assert mine[0]['coefficient'] * coef > 0, (coef, mine[0]['coefficient'])
    if share is not None:
        assert abs(mine[0]['coefficient'] - coef) <= share * abs(coef), (coef, mine[0]['coefficient'])


@pytest.mark.slow
def test_a_term_the_current_keeps_only_inside_the_band_is_listed(base, tmp_path):
    # F_stat*a2 rings with the cells: of 3x the band in the current, about a tenth passes the filter the balance is
    # formed through. Measured, but inside the band there: listed with both sizes, nothing named
    camp, coef = with_term(base, CHANNEL, 'F_stat*a2', 1.0)
    report = discover(camp, base.rig, tmp_path, scheduler='inline', plots=False)
    assert not [t for t in report['beyond_catalog'] if t['channel'] == CHANNEL], (coef, report['beyond_catalog'])
    listed = {(r['channel'], r['term']): r['reason'] for r in report['beyond_search']['identifiability']}
    assert 'the filter that makes' in listed.get((CHANNEL, 'F_stat*a2'), ''), listed
