"""The motor current's force balance in the search beyond the catalog (issue 39), on the independent generator
(tests/independent/rig.py): its carriage answers the moving cell's fast ringing (m2 a2 at the cells' and lanyard's
modes) with its own acceleration, which the encoder's smoothed a3 does not carry, so a balance with F_move as it is
left -m2 a2 in the current's residual, and three of five clean campaigns were given an `a2` term on the current.
The balance is now formed as a3 sees the motion (prep.like_a3), at the analog channels' fitted lead
(beyond.series.balance_lead)."""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from force_discovery.core.beyond import channel_series
from force_discovery.core.beyond.series import term_column
from force_discovery.core.prep import prepare
from force_tester_sim.core.params import rig_from_dict

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / 'independent'))
import rig as R  # noqa: E402  the independent generator
from generator import make_campaign, rig_with  # noqa: E402  the own generator

pytestmark = pytest.mark.slow
SEED = 4401          # a clean campaign of bench_sweep's (nominal rig, 20 kHz) that was given the false alarm


def clean_pulls():
    camp, truth = R.generate_campaign(SEED, n_pulls=2, sets=[3, 4], departures=[],
                                      rig={'daq.absent': [], 'daq.sample_rate_hz': 20e3})
    return camp, rig_from_dict(yaml.safe_load(R.rig_yaml(truth)))


def current_on_a2(camp, rig, c_added: float = 0.0):
    """(the a2 coefficient of the current's residual, A per m/s^2; the share of its squared residual a2 explains),
    over the pulls, c_added x the recorded a2 added to the recorded current first. a2's column is the search's own
    (series.term_column): on the current the balance is formed through like_a3, so its columns are the terms through
    it (series.Through), while ChannelSeries.signals holds the signals as read at the lead, unfiltered. Regressed on
    that unfiltered a2 (mostly the cells' ringing, which the filter takes out of the residual), an a2 of -0.02 A per
    m/s^2 added to the current read -0.0007 (both generators alike); on its column, -0.0200."""
    xx = xy = yy = 0.0
    for meta, ch in camp:
        ch = {**ch, 'motor_current_a': ch['motor_current_a'] + c_added * ch['accel_axial_m_s2']}
        p = prepare(meta, ch, rig)
        cs = channel_series(p, rig, np.zeros(p.w1 - p.w0), None, {})['motor_current']
        a, y = term_column(cs, 'a2'), cs.residual
        xx, xy, yy = xx + a @ a, xy + a @ y, yy + y @ y
    return xy / xx, (xy * xy / xx) / yy


@pytest.fixture(scope='module')
def campaign():
    return clean_pulls()


def test_a_clean_independent_current_has_no_a2_in_its_balance(campaign):
    camp, rig = campaign
    coef, share = current_on_a2(camp, rig)
    m2_in_a = rig.force_chain.m2 / rig.drive.force_per_amp_n_per_a
    # before: the fast ringing of m2 a2 stayed in the residual, coefficient about -m2 / k_F, half or more of it
    assert share < 0.05, (coef, share)
    assert abs(coef) < 0.2 * m2_in_a, (coef, m2_in_a)


@pytest.fixture(scope='module')
def own_campaign():
    """Two pulls of the own generator (tests/force_discovery/generator.py), nominal rig."""
    return make_campaign(None, SEED, sets=[3, 4], pulls=1), rig_with(None)


@pytest.mark.parametrize('which', ['campaign', 'own_campaign'])
def test_an_a2_term_on_the_current_is_still_measured(which, request):
    camp, rig = request.getfixturevalue(which)
    c = -0.02                                        # A per m/s^2: about -0.9 kg through this rig's k_F
    coef, _ = current_on_a2(camp, rig, c)
    base, _ = current_on_a2(camp, rig)
    assert coef - base == pytest.approx(c, rel=0.05)     # the term itself, through the smoothing unchanged
    assert coef == pytest.approx(c, rel=0.2)             # before: c - m2 / k_F, about -0.045
