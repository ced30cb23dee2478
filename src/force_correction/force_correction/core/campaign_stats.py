"""Campaign statistics shaped like thesis Tables 7-9: the thesis's own correction, scored per pull and per set.

A campaign is a list of (meta, channels): meta has at least 'set'; channels are DAQ-export columns (SI).
"""
from __future__ import annotations

from typing import Dict, List

import numpy as np

from force_tester_common.core.correction import MASS_KG, WINDOW
from force_tester_common.core.units import G_M_S2, LBF_N

from .params import CorrectionParams
from .scoring import score_pull
from .streaming import correct_signal


def pull_scores(channels: Dict[str, np.ndarray], m2_nominal: float = MASS_KG, window: int = WINDOW) -> dict:
    """Thesis eq 1 peak % differences of one pull (raw, after m*a, after m*a + moving average) and peaks."""
    c = correct_signal(channels['force_moving_n'], channels['accel_axial_m_s2'], CorrectionParams(m2_nominal, window))
    sc = score_pull(channels['force_stationary_n'], c.raw_n, c.corrected_n, c.filtered_n)
    a2 = np.asarray(channels['accel_axial_m_s2'])
    return {'stationary_peak_lbf': sc.stationary_peak_n / LBF_N, 'moving_peak_lbf': sc.raw_peak_n / LBF_N,
            'a2_max_g': float(np.max(np.abs(a2))) / G_M_S2, 'raw_diff_pct': sc.raw_diff_pct,
            'ma_diff_pct': sc.corrected_diff_pct, 'ma_filter_diff_pct': sc.filtered_diff_pct}


def campaign_tables(campaign, m2_nominal: float = MASS_KG, window: int = WINDOW) -> List[dict]:
    """Per-set statistics like thesis Tables 7-9 (means and sample standard deviations over the set's pulls):
    stationary_avg_lbf, moving_avg_lbf, a2_max_g (mean of the per-pull max |a2|), raw_diff_pct, ma_diff_pct
    (after m*a with ``m2_nominal``), ma_filter_diff_pct (then the ``window``-point trailing average)."""
    per_set: Dict[int, List[dict]] = {}
    for meta, ch in campaign:
        per_set.setdefault(int(meta['set']), []).append(pull_scores(ch, m2_nominal, window))
    out = []
    keys = ('stationary_peak_lbf', 'moving_peak_lbf', 'a2_max_g', 'raw_diff_pct', 'ma_diff_pct', 'ma_filter_diff_pct')
    names = {'stationary_peak_lbf': 'stationary_avg_lbf', 'moving_peak_lbf': 'moving_avg_lbf'}
    for s in sorted(per_set):
        rows = per_set[s]
        d = {'set': s, 'pulls': len(rows)}
        for k in keys:
            v = np.array([r[k] for r in rows])
            name = names.get(k, k)
            d[name] = float(v.mean())
            d[name + '_std'] = float(v.std(ddof=1)) if len(v) > 1 else 0.0
        out.append(d)
    return out


# Thesis Tables 8 and 9: average force difference (%) after m*a, and after m*a + moving average, per set.
THESIS_MA_DIFF_PCT = {1: 1.5, 2: 12.8, 3: 5.4, 4: 11.1, 5: 32.0}
THESIS_MA_FILTER_DIFF_PCT = {1: 2.5, 2: 5.3, 3: 3.8, 4: 22.2, 5: 16.3}


def format_tables(tables: List[dict], rig) -> str:
    """Tables 7, 8 and 9 of the campaign beside the thesis's numbers (``rig.test_set(n)`` gives each set's
    measured_stationary_avg_lbf and measured_a2_max_g, thesis Table 7)."""
    lines = ['Table 7 (raw): mean stationary peak and mean a2 max per set',
             f'{"set":>3} {"sim lbf":>9} {"thesis lbf":>10} {"ratio":>6} | {"sim g":>7} {"thesis g":>8} {"ratio":>6}'
             f' | {"moving lbf":>10} {"raw diff %":>10}']
    for r in tables:
        ts = rig.test_set(r['set'])
        lines.append(f'{r["set"]:>3} {r["stationary_avg_lbf"]:9.1f} {ts.measured_stationary_avg_lbf:10.1f} '
                     f'{r["stationary_avg_lbf"] / ts.measured_stationary_avg_lbf:6.3f} | {r["a2_max_g"]:7.1f} '
                     f'{ts.measured_a2_max_g:8.1f} {r["a2_max_g"] / ts.measured_a2_max_g:6.3f} | '
                     f'{r["moving_avg_lbf"]:10.1f} {r["raw_diff_pct"]:10.1f}')
    for title, key, ref in (('Table 8: avg force difference % after m*a (nominal m2)', 'ma_diff_pct',
                             THESIS_MA_DIFF_PCT),
                            ('Table 9: avg force difference % after m*a + moving average', 'ma_filter_diff_pct',
                             THESIS_MA_FILTER_DIFF_PCT)):
        lines += ['', title, f'{"set":>3} {"sim %":>7} {"sim std":>8} {"thesis %":>8} {"ratio":>6}']
        for r in tables:
            th = ref.get(r['set'], float('nan'))
            lines.append(f'{r["set"]:>3} {r[key]:7.2f} {r[key + "_std"]:8.2f} {th:8.1f} {r[key] / th:6.2f}')
    return '\n'.join(lines)
