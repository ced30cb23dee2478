"""./ft thesis: the thesis's predictions beside ours, as JSON with the documented keys."""
import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.slow
def test_thesis_json_has_the_documented_keys_and_physics(tmp_path):
    out = tmp_path / 'thesis.json'
    res = subprocess.run([sys.executable, '-m', 'ft_cli', 'thesis', '--json', str(out), '--pulls', '2',
                          '--cache', str(tmp_path / 'cache'), '--plots', str(tmp_path / 'plots')],
                         cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, res.stderr[-2000:]
    data = json.loads(out.read_text())
    top = data['top_speed']
    assert set(top) == {'peak_fps', 'plateau_fps', 'current_limit_hit', 'peak_power_kw', 'distance_to_plateau_ft',
                        'plateau_cause'}
    assert top['plateau_cause'] == 'back_emf'
    assert top['plateau_fps'] == pytest.approx(325.2 * 0.0668 / (0.9185 * 3) / 0.3048, rel=0.01)
    assert top['current_limit_hit'] is True
    assert [m['mass_kg'] for m in data['mass_sweep']] == [1, 16, 31, 46, 61]
    plateaus = [m['plateau_fps'] for m in data['mass_sweep']]
    assert max(plateaus) - min(plateaus) < 0.01 * plateaus[0]          # mass changes the overshoot only
    sets = data['campaign']['sets']
    assert [s['set'] for s in sets] == [1, 2, 3, 4, 5]
    for s in sets:
        assert set(s) == {'set', 'stationary_avg_lbf', 'a2_max_g', 'raw_diff_pct', 'ma_diff_pct', 'ma_filter_diff_pct'}
        assert s['raw_diff_pct'] > s['ma_diff_pct']                      # the moving cell reads high; m*a helps
    assert (tmp_path / 'plots' / 'top_speed.png').is_file()
    assert 'Table 7' in res.stdout and 'Table 9' in res.stdout
