"""Issue 27: beyond the catalog. A departure no catalog entry describes, hidden at a random strength by the
generator (its own model of the physics, applied to the recorded channels; generator.BEYOND), is found as the right
term on the right channel with its coefficient, and a clean campaign gives an empty beyond_catalog. The code under
test sees only the data and the nominal rig; the truth is used only to score."""
from __future__ import annotations

import pytest
from generator import BEYOND, beyond_campaign, check_beyond, draw_nuisance, make_campaign

from force_discovery.core.beyond import interpretation, library
from force_discovery.core.pipeline import discover
from force_tester_sim.core.errors import SimError
from force_tester_sim.core.extra_terms import parse_term, term_name
from force_tester_sim.core.params import load_rig


def run(camp, tmp):
    return discover(camp, load_rig(), tmp, scheduler='inline')


# each kind once, at a seed of its own; every other one through the model-form nuisances
CASES = [(kind, 11 + i, i % 2 == 1) for i, kind in enumerate(sorted(BEYOND))]


@pytest.mark.parametrize('kind,seed,nuisance', CASES)
def test_a_departure_outside_the_catalog_is_found_as_its_term(kind, seed, nuisance, tmp_path):
    camp, truth = beyond_campaign(kind, seed, nuisance)
    report = run(camp, tmp_path)
    got = check_beyond(report, truth)
    assert got['right_term'], (truth['channel'], truth['term'], got['found'])
    assert got['coefficient_30pct'], (truth['coefficient'], got['found'])
    assert report['cause'] == 'beyond_catalog', (report['cause'], got['catalog_named'])
    first = next(t for t in report['beyond_catalog'] if t['channel'] == truth['channel'])
    lo, hi = first['ci95']
    assert lo < first['coefficient'] < hi and first['gain'] > 1.0
    assert first['interpretation'] == interpretation(truth['channel'], truth['term'], first['frequency_hz'])
    md = (tmp_path / 'report.md').read_text()
    assert '## Beyond the catalog' in md and truth['term'] in md
    ext = (tmp_path / 'extension.yaml').read_text()
    assert 'extra_terms:' in ext and truth['term'] in ext


@pytest.mark.parametrize('nuisance', [False, True])
def test_a_clean_campaign_has_nothing_beyond_the_catalog(nuisance, tmp_path):
    report = run(make_campaign(None, seed=31, nuisance=draw_nuisance(31) if nuisance else None), tmp_path)
    assert report['beyond_catalog'] == [], report['beyond_catalog']
    assert report['cause'] == 'none'
    assert 'extra_terms' not in (tmp_path / 'extension.yaml').read_text()


def test_the_grammar_writes_and_reads_its_terms():
    lib = library()
    assert len(lib) == len(set(lib))
    for t in lib + ['v*sin', 'F_move*sin', 'sin']:
        assert term_name(parse_term(t)) == t
    assert {'F_move^2', 'v^2', 't', 'F_move*v', 'v^3'} <= set(lib)
    for bad in ('v*F_move', 'v^4', 'w', 'sin^2', 'v*v'):
        with pytest.raises(SimError, match='term'):
            parse_term(bad)
