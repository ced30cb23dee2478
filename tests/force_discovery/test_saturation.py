"""Defects before physics (issue 39): a load cell clipped by the independent generator's DAQ (its `clipping`
departure, tests/independent/rig.py) is a saturation that the data-quality screen names with its channel and
level, and `discover` fits no term to it; a clean independent campaign has no saturation (its peaks are rounded)."""
from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pytest

from force_discovery.core import quality as Q
from force_discovery.core.pipeline import discover
from force_tester_sim.core.params import rig_from_dict

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / 'independent'))
import rig as R  # noqa: E402  the independent generator

pytestmark = pytest.mark.slow
SEED = 2700


def campaign(departures, sets, pulls):
    camp, truth = R.generate_campaign(SEED, n_pulls=pulls, sets=list(sets), departures=departures,
                                      rig={'daq.absent': []})
    import yaml
    return camp, truth, rig_from_dict(yaml.safe_load(R.rig_yaml(truth)))


@pytest.mark.parametrize('channel', ['force_moving_n', 'force_stationary_n'])
def test_a_clipped_cell_is_a_saturation_with_its_level_and_no_term(tmp_path, channel):
    camp, truth, rig = campaign([{'name': 'clipping', 'channel': channel}], (2, 3, 4, 2), 4)
    (dep,) = truth['departures']
    level = dep['params']['clip_level_si']
    assert all(p['clipped'][channel] > 0 for p in truth['pulls'])        # the generator clipped every pull
    report = discover(camp, rig, tmp_path, scheduler='inline', plots=False)
    sat = [d for d in report['data_quality'] if d['kind'] == Q.SATURATION]
    assert {d['channel'] for d in sat} == {channel}, report['data_quality']
    assert {d['pull'] for d in sat} == {m['file'] for m, _ in camp}
    for d in sat:
        assert d['level'] == pytest.approx(level, rel=1e-3)
    terms = report['beyond_catalog']
    assert not isinstance(terms, list) or terms == [], terms
    md = (tmp_path / 'report.md').read_text()
    assert f'{channel} saturates at {sat[0]["level"]:+.6g}' in md
    assert json.loads((tmp_path / 'report.json').read_text())['data_quality'] == report['data_quality']


def test_a_clean_independent_campaign_has_no_saturation():
    camp, _truth, _rig = campaign([], (1, 2, 3, 4, 5), 5)
    for meta, ch in camp:
        screen = Q.screen_pull(meta['file'], ch)
        sat = [d.as_dict() for d in screen.defects if d.kind in (Q.SATURATION, Q.CLIPPING)]
        assert sat == [], sat
        assert np.isfinite(ch['force_moving_n']).all()
