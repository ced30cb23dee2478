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


@pytest.mark.slow
def test_the_tutorial_runs_on_the_ladisk_recordings(tmp_path):
    """docs/tutorial-your-rig.md, run as written: its shell blocks in order in a fresh folder (./ft the workspace's),
    its filled-in map written where the page shows it, each printed line it quotes found in what the command before
    printed. Then the done-when of issue 40 on the report: no cause named and nothing judged against our rig's
    nominal without --rig (report.json says no rig was given, report.md too); g m2 consistent with zero, reported
    as such with its meaning; camera.lvm's accelerometer clip flagged on the accelerometer, the force not blamed."""
    import json
    import re
    import subprocess
    root = Path(__file__).resolve().parents[2]
    page = (root / 'docs' / 'tutorial-your-rig.md').read_text()
    (tmp_path / 'tests').symlink_to(root / 'tests')       # the page's `cp tests/bag_tools/data/...`
    out = ''
    blocks = re.findall(r'^```(\w*)\n(.*?)^```', page, re.S | re.M)
    assert [k for k, _ in blocks].count('') >= 5
    for kind, body in blocks:
        if kind == 'yaml':                                # the map as filled in
            (tmp_path / 'lab' / 'map.yaml').write_text(body)
        elif kind == 'text':                              # what the command before printed, lines shortened by ...
            for line in body.splitlines():
                said = line.split(' ...')[0]
                assert said in out, f'the tutorial quotes {said!r}; the command printed:\n{out}'
        else:
            for cmd in body.strip().splitlines():
                r = subprocess.run(cmd.replace('./ft ', f'{root / "ft"} ', 1), shell=True, cwd=tmp_path,
                                   capture_output=True, text=True, timeout=900)
                assert r.returncode == 0, f'{cmd}: {r.stderr[-2000:]}'
                out = r.stdout
    rep = json.loads((tmp_path / 'runs' / 'ladisk' / 'report.json').read_text())
    md = (tmp_path / 'runs' / 'ladisk' / 'report.md').read_text()
    # no cause named against our rig's nominal without --rig
    assert rep['rig']['given'] is False and rep['rig']['file'] is None and 'Rig: none; no rig given' in md
    assert rep['cause'] == 'none' and rep['causes'] == [] and rep['indicated'] == []
    assert all(c['tolerance']['verdict'] == 'not_judged' and c['tolerance']['band'] is None
               for c in rep['candidates'].values())
    assert 'g m2 = the rig\'s m2' not in md and 'not_available' in rep['tolerances']
    # g m2 consistent with zero, reported as such, with its meaning
    lo, hi = rep['candidates']['gain_mass_product']['parameters_ci95']['gain_mass_kg']
    assert lo < 0.0 < hi and hi - lo < 0.01
    meaning = [n for n in rep['notes'] if 'consistent with zero' in n]
    assert meaning and 'the accelerometer is not on the cell\'s body' in meaning[0]
    assert '## What the estimates mean' in md and 'consistent with zero' in md
    # the modes the page names
    assert [round(m['frequency_hz']) for m in rep['modes'][:3]] == [1898, 696, 3671]
    # camera.lvm's clip flagged on the accelerometer, nothing on the force, nothing in acceleration.lvm
    dq = {(d['pull'], d['channel'], d['kind']) for d in rep['data_quality']}
    assert dq == {('camera.lvm', 'accel_axial_m_s2', 'clipping')}, rep['data_quality']
