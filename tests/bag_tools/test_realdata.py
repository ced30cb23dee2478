"""Real recordings of another lab (issue 40): LADISK's two modal-hammer hits (data/ladisk_beam_hammer beside
this file, MIT, its README gives the provenance), LabVIEW files with a decimal comma and units written `g` and
`Newtons`, imported through the real CLI with a channel map that --init-map wrote."""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from daq_data import SRC_DIRS, run_cli

for _d in reversed(SRC_DIRS):
    if str(_d) not in sys.path:
        sys.path.insert(0, str(_d))

from bag_tools.core.convert import bag_to_campaign  # noqa: E402
from bag_tools.core.daq import read_campaign  # noqa: E402
from bag_tools.core.daqfiles import read_records  # noqa: E402
from force_tester_common.core.units import G_M_S2  # noqa: E402

DATA = Path(__file__).resolve().parent / 'data' / 'ladisk_beam_hammer'
#: peak force (N) of each hit, as the files hold it
PEAKS = {'acceleration.lvm': 195.605522, 'camera.lvm': 422.370802}


def test_the_copies_carry_their_licence():
    assert 'MIT License' in (DATA / 'LICENSE.txt').read_text() and 'Ladisk' in (DATA / 'LICENSE.txt').read_text()
    assert 'f5d6fd5d7647a03e58a02b4ad697f7df23e5971a' in (DATA / 'README.md').read_text()


@pytest.mark.slow
@pytest.mark.parametrize('name', sorted(PEAKS))
def test_ladisk_hammer_hits_import_through_a_map_init_map_wrote(name, tmp_path):
    src = DATA / name
    m = tmp_path / 'map.yaml'
    r = run_cli('import', src, '--init-map', m)
    assert r.returncode == 0, r.stderr
    assert 'FILL_IN(s)' not in r.stdout        # the file states its units: only the guesses to check
    text = m.read_text()
    assert '50030 samples at 50000 Hz, 1.0006 s' in text
    assert '"Force (Trigger)" [Newtons]' in text and '"Acceleration (Trigger)" [g]' in text
    doc = yaml.safe_load(text)
    assert doc['channels']['force_moving_n'] == {'source': 'Force (Trigger)', 'unit': 'Newtons', 'sign': 'tension'}
    assert doc['channels']['accel_axial_m_s2']['source'] == 'Acceleration (Trigger)'
    # filled in: the hammer's cell reads its impact positive, as a compression
    m.write_text(text.replace('"Newtons"            # as the file states it: no sensitivity needed\n    sign: tension',
                              '"Newtons"\n    sign: compression'))
    assert yaml.safe_load(m.read_text())['channels']['force_moving_n']['sign'] == 'compression'
    r = run_cli('import', src, tmp_path / 'bag', '--channels', m)
    assert r.returncode == 0, r.stderr
    assert 'imported 1 pull(s) at 50000 Hz' in r.stdout
    rec, = read_records(src)
    pull, = read_campaign(bag_to_campaign(tmp_path / 'bag', tmp_path / 'back')).pulls
    np.testing.assert_array_equal(pull.channels['force_moving_n'], -rec.channels['Force (Trigger)'])
    np.testing.assert_allclose(pull.channels['accel_axial_m_s2'], rec.channels['Acceleration (Trigger)'] * G_M_S2,
                               rtol=1e-15)
    assert -pull.channels['force_moving_n'].min() == PEAKS[name]
    assert len(pull.channels['time_s']) == 50030 and pull.channels['time_s'][1] == 2e-5
