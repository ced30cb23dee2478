"""The search's residual is formed with the accelerometer's timing fitted (passes.BEYOND_NUISANCE): a DAQ that
samples its channels in turn is no term beyond the catalog. On physics we did not write: the independent generator
(tests/independent/rig.py), whose multiplexed ADC puts each channel a slot after the one before."""
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / 'benchmarks'))

import independent_cases as IG  # noqa: E402

from force_discovery.core.passes import BEYOND_NUISANCE  # noqa: E402
from force_discovery.core.pipeline import discover  # noqa: E402


@pytest.mark.slow
def test_a_multiplexed_daqs_timing_at_a_ringing_cell_is_no_term(tmp_path, monkeypatch):
    # seed 4423 draws 1.6 us per ADC slot (the accelerometer 3.2 us after the moving cell) and a moving cell that
    # rings at 4.0 kHz with 1.6 % damping: nothing is injected. With the catalog's accel_delay inside its tolerance,
    # not named, the moving cell's residual kept 12.3 N rms of the ringing's slope, and the search named F_move*x and
    # T*x there (main at 2b8b8f2): a false alarm. Fitted in the search's residual, the timing leaves nothing to name
    monkeypatch.setenv(IG.CACHE_ENV, str(tmp_path / 'cache'))
    case = IG.case(4423, [], pulls=14, overrides={'daq.sample_rate_hz': 20e3})
    skew = case.truth['daq']['channels']['accel_axial_m_s2']['skew_s']
    assert skew > 3e-6 and case.truth['departures'] == []
    report = discover(case.campaign, case.rig, tmp_path / 'out', scheduler='inline', plots=False)
    assert report['beyond_catalog'] == [], [(t['channel'], t['term']) for t in report['beyond_catalog']]
    # the timing is the search's nuisance, not a catalog cause: it is neither named nor checked against the library
    assert 'accel_delay' in BEYOND_NUISANCE
    assert 'accel_delay' not in [c['name'] for c in report['causes']]
    search = report['beyond_search']
    assert 'accel_delay' not in search['catalog_checked'] and 'accel_delay' not in search['catalog_not_fitting']
