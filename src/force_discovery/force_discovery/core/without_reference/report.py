"""The reference-free path's report: report.json, report.md (its Method section is driver.py's docstring),
extension.yaml, written whole. ROS-free."""
from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path
from typing import Dict, Optional, Sequence

from force_tester_common.core.channels import CHANNELS, REQUIRED_CHANNELS

from .. import quality as Q
from ..extension import correction_uncertainty, extension_yaml
from ..identifiability import COMPUTED, FREE_CHANNELS, identifiability
from ..markdown import rig_line
from ..report import CANDIDATE_KEYS, LISTED_KEYS, NO_RIG, NOT_AVAILABLE, WITH_REFERENCE_ONLY, clean, complete
from ..report import rig_state as state_of
from ..significance import MIN_REL_REDUCTION, MIN_T
from ..uncertainty import INCONCLUSIVE, INDICATED, WITHIN
from .leave_one_out import MIN_NAMED_PULLS, validation_text
from .phases import FreePull

REFERENCE_COMPUTED = ('moving_cell_gain', 'effective_mass')
#: with no reference the correction's mass is g m2 (extension.CORRECTED's form): its u is stated as m2's
PRODUCT_CORRECTED = (('gain_mass_product', 'gain_mass_kg', 'mass_kg', ('effective_mass', 'mass_kg')),
                  ('accel_delay', 'delay_s', 'accel_delay_s', ('accel_delay', 'delay_s')))
SIGNIFICANCE_RULE = (f'every pull is held out once (leave-one-out); a cause is named when, over at least '
                     f'{MIN_NAMED_PULLS} held-out pulls, removing it raises the summed squared residual by >= '
                     f'{100 * MIN_REL_REDUCTION:g} % with t >= {MIN_T:g}, AND its 95 % interval (jackknife) lies '
                     'wholly outside its tolerance band; inside the band it is within_tolerance, across an edge '
                     'inconclusive; with 2-3 pulls what departs on every held-out pull is indicated; one pull: '
                     'per_pull_only (uncertainty.verdict_rule)')
#: a cause's plain-words place in the data (report.json causes[].where, as with a reference)
WHERE = {'gain_mass_product': 'the moving cell against the accelerometer in the free phases (before contact, after '
                              'a break or a rebound): g m2 off the rig\'s m2',
         'accel_delay': 'the moving cell leads the accelerometer in the free phases: a2 lags the force',
         'mains_hum': 'a spectral line on the moving cell in the free phases',
         'mount_resonance': 'accelerometer ringing in the free decay after the last event, below the cell mode',
         'moving_cell_gain': 'the moving cell against the stationary cell over the whole record',
         'effective_mass': 'the moving cell against the stationary cell and the accelerometer over the whole record'}
REFERENCE_WHAT = ('from the stationary cell: F_move = g T + g m2 a2(t + d) - k C over the whole record, T from '
                  'force_stationary_n (no encoder needed)')


def campaign_report(analysis: Optional[dict], pulls: Sequence[FreePull], absent: Sequence[str], screens: Sequence,
                    excluded: Dict[str, str], failed: Sequence, rig, notes: Sequence[str] = (), few: int = 0,
                    rig_state: Optional[dict] = None, retried: Sequence[str] = (),
                    scheduler: Optional[str] = None) -> dict:
    """report.json of the reference-free path (few: run because the campaign has fewer pulls than this): the keys
    of the path with a reference (report.REPORT_KEYS), those it cannot fill saying why. rig None: none given
    (report.rig_state; rig_state: report.json's rig, from the pipeline)."""
    with_ref = bool(analysis and analysis.get('reference'))
    yes, no = identifiability(absent, COMPUTED + (REFERENCE_COMPUTED if with_ref else ()), few=few)
    for q in yes:
        if q['quantity'] in REFERENCE_COMPUTED:
            q['what'] = REFERENCE_WHAT
    n = len(pulls)
    rep = {'rig': rig_state or state_of(rig), 'reference': False, 'stationary_cell': with_ref, 'absent': list(absent),
           'channels': [c for c in CHANNELS if c not in absent and (c in REQUIRED_CHANNELS or c in FREE_CHANNELS)],
           'identifiable': yes, 'not_identifiable': no, 'validation': validation_text(max(n, 1), with_ref),
           'pulls': [p.name for p in pulls], 'fitted_pulls': [p.name for p in pulls],
           'held_out_pulls': [p.name for p in pulls] if n >= 2 else [],
           'data_quality': Q.defect_dicts(screens), 'excluded_pulls': dict(excluded),
           'failed_pulls': [{'pull': p, 'error': e} for p, e in failed], 'notes': list(notes),
           'retried_pulls': list(retried), 'scheduler': scheduler or None, 'plots': [],
           'tolerances': dataclasses.asdict(rig.tolerances) if rig is not None else {NOT_AVAILABLE: NO_RIG},
           'significance_rule': SIGNIFICANCE_RULE}
    rep['notes'].append(f'the stationary cell separates g and m2 ({REFERENCE_WHAT})' if with_ref else
                        'g and m2 separate only with a reference (the stationary cell) or a known calibration '
                        'mass: the free phases give their product g m2')
    why = {**WITH_REFERENCE_ONLY, 'cell_mode_hz': f'{NO_RIG}: the rig\'s cell mode, which a mount mode is told from, '
                                                  'needs its cell stiffness and m2'}
    if analysis is None:
        rep.update(cause='unexplained', causes=[], candidates={}, gain=None, baseline_error=None,
                   extended_error=None, modes=[], per_pull=[])
        return complete(clean(rep), why, 'no usable pulls (excluded_pulls, failed_pulls say why)')
    c = {k: {**cand.as_dict(), 'tolerance': analysis['tolerance'][k]} for k, cand in analysis['causes'].items()}
    c = {k: {f: v[f] for f in CANDIDATE_KEYS} for k, v in c.items()}
    named = analysis['named']
    if n == 1:
        cause = 'none'
        rep['notes'].append('one pull: per-pull estimates only, no cause')
    else:
        cause = named[0] if named else 'none'
        ind = [k for k, v in c.items() if v['tolerance']['verdict'] == INDICATED]
        if ind:
            rep['notes'].append(f'indicated (departs on every held-out pull, too few pulls to name): '
                                f'{", ".join(ind)}')
    samples = max(analysis['samples'], 1)
    rep['notes'] += readings(c)

    def listed(verdict, **more):
        return [{'name': k, **{f: c[k][f] for f in LISTED_KEYS}, **more} for k in c
                if c[k]['tolerance']['verdict'] == verdict]
    rep.update(cause=cause, candidates=c,
               causes=[{'name': k, **{f: c[k][f] for f in LISTED_KEYS}, 'gain': c[k]['evidence']['rms_gain'],
                        'channel': c[k]['channel'], 'where': WHERE[k]} for k in named],
               indicated=listed(INDICATED), within_tolerance=listed(WITHIN),
               inconclusive=listed(INCONCLUSIVE, pulls_to_settle=None),
               metric='RMS moving-cell residual in the free phases, held out (leave-one-out); baseline: '
                      + ('g m2 = the rig\'s m2' if rig is not None else 'g m2 = 0 (no rig given)')
                      + ', no delay, no hum',
               baseline_error=math.sqrt(analysis['baseline_sse'] / samples),
               extended_error=math.sqrt(analysis['extended_sse'] / samples),
               modes=analysis['modes'], per_pull=analysis['per_pull'])
    if analysis['cell_mode_hz'] is not None:
        rep['cell_mode_hz'] = analysis['cell_mode_hz']
    rep['gain'] = rep['baseline_error'] / rep['extended_error'] if rep['extended_error'] else None
    rep['uncertainty_budget'] = {k: v['uncertainty_budget'] for k, v in c.items()}
    return complete(clean(rep), why)


def readings(c: dict) -> list:
    """What g m2 means, in words (report.json notes, report.md, the CLI): consistent with zero, a mass the cell
    carries, or a sign to check; the meaning needs no rig."""
    g = c.get('gain_mass_product')
    if not g:
        return []
    est, ci = g['parameters']['gain_mass_kg'], g['parameters_ci95']['gain_mass_kg']
    if not ci or ci[0] is None:
        return [f'g m2 = {est:.3g} kg (one pull: no interval, no reading)']
    said = f'g m2 = {est:.3g} kg, 95 % interval [{ci[0]:.3g}, {ci[1]:.3g}] kg'
    if ci[0] <= 0.0 <= ci[1]:
        return [f'{said}: consistent with zero. In the free phases the cell carries no mass that moves with the '
                'accelerometer: the accelerometer is not on the cell\'s body (on the struck structure, say), so '
                'the m a correction has nothing to subtract, and the accelerometer delay is not defined']
    if ci[0] > 0.0:
        return [f'{said}: the cell carries a mass moving with the accelerometer (its gain g times that mass m2; '
                'they separate only with a reference or a known calibration mass)']
    return [f'{said}: negative: the cell and the accelerometer count opposite directions positive; check the '
            'signs in the channel map']


def _fmt_ci(ci, scale=1.0, fmt='.4g') -> str:
    if not ci or ci[0] is None:
        return '-'
    return f'[{ci[0] * scale:{fmt}}, {ci[1] * scale:{fmt}}]'


def report_markdown(rep: dict, screens: Sequence, method: str) -> str:
    """report.md of the reference-free path."""
    lines = ['# Discovery without a reference', '',
             f'Channels: {", ".join(rep["channels"])}; absent: {", ".join(rep["absent"]) or "-"}. '
             f'{len(rep["pulls"])} usable pulls ({rep["validation"]["method"]}).', '',
             rig_line(rep), '',
             f'**Cause: {rep["cause"]}**' + (f' (named: {", ".join(c["name"] for c in rep["causes"])})'
                                             if rep['causes'] else ''), '']
    if rep.get('gain'):
        lines += [f'{rep["metric"]}: {rep["baseline_error"]:.4g} N -> {rep["extended_error"]:.4g} N '
                  f'(x{rep["gain"]:.3g}).', '']
    said = readings(rep.get('candidates') or {})
    if said:
        lines += ['## What the estimates mean', ''] + [f'- {x}' for x in said] + ['']
    lines += ['## Identifiable from these channels', '', '| quantity | from | what |', '|---|---|---|']
    lines += [f'| {q["quantity"]} | {", ".join(q["needs"]) or "every channel"} | {q["what"]} |'
              for q in rep['identifiable']]
    lines += ['', '## Not identifiable', '', '| quantity | needs | why |', '|---|---|---|']
    lines += [f'| {q["quantity"]} | {", ".join(q["needs"])} | {q["reason"]} |' for q in rep['not_identifiable']]
    v = rep['validation']
    lines += ['', '## What the number of pulls supports', '', f'- method: {v["method"]} over {v["pulls"]} pull(s)',
              f'- supports: {v["supports"]}', f'- cannot support: {v["cannot_support"]}', '']
    if rep.get('candidates'):
        lines += ['## Estimates', '', '| quantity | estimate | 95 % interval | held-out rel. reduction | t | verdict |',
                  '|---|---|---|---|---|---|']
        for name, c in rep['candidates'].items():
            p = ', '.join(f'{k} {val:.6g}' for k, val in c['parameters'].items())
            ci = '; '.join(f'{k} {_fmt_ci(val, fmt=".6g")}' for k, val in c['parameters_ci95'].items() if val)
            ev = c['evidence']
            t = 'inf' if ev['t'] is None else f'{ev["t"]:.3g}'
            lines.append(f'| {name} | {p} | {ci or "-"} | {ev["rel_sse_reduction"]:.3g} | {t} | '
                         f'{c["tolerance"]["verdict"]} |')
        lines.append('')
    if rep.get('modes'):
        lines += ['## Ringing modes (a2, free decay after the last event)', '',
                  (f'The rig\'s cell mode: {rep["cell_mode_hz"]:.0f} Hz.' if isinstance(rep['cell_mode_hz'], float)
                   else 'No rig given: no cell mode, so no mode is told a mount\'s.'), '',
                  '| frequency (Hz) | damping ratio | pulls | 95 % interval (Hz) |', '|---|---|---|---|']
        lines += [f'| {m["frequency_hz"]:.1f} | {m["damping_ratio"]:.4f} | {m["pulls"]} | '
                  f'{_fmt_ci(m["frequency_ci95"], fmt=".1f")} |' for m in rep['modes']]
        lines.append('')
    if rep.get('per_pull'):
        lines += ['## Per pull', '', '| pull | events | g m2 (kg) | delay (us) | hum (N) | free share |',
                  '|---|---|---|---|---|---|']
        for p in rep['per_pull']:
            evs = '; '.join(f'{e["sign"]} {e["peak_n"]:.4g} N at {e["start_s"]:.4f} s, {1e3 * e["width_s"]:.3g} ms'
                            for e in p['events'])
            lines.append(f'| {p["pull"]} | {evs} | {p["gain_mass_kg"]:.5g} | {1e6 * p["delay_s"]:.3g} | '
                         f'{p["hum_amplitude_n"]:.3g} | {p["free_share"]:.2f} |')
        lines.append('')
    if rep['notes']:
        lines += ['## Notes', ''] + [f'- {x}' for x in rep['notes']] + ['']
    if rep.get('failed_pulls'):
        lines += ['Pulls that could not be read or analysed:', ''] + \
                 [f'- {f["pull"]}: {f["error"]}' for f in rep['failed_pulls']] + ['']
    lines += Q.markdown_lines(screens, rep.get('excluded_pulls'))
    lines += ['## Method', '', method]
    return '\n'.join(lines) + '\n'


def report_extension(rep: dict, rig) -> dict:
    """extension.yaml: what the correction can undo from these channels. The correction subtracts mass_kg a2 from
    F_move / moving_cell_gain; with g unknown, mass_kg is g m2 and the gain 1, so the corrected force is g times
    the force at the contact (stated under assumptions)."""
    c = rep.get('candidates') or {}
    measured = c['gain_mass_product']['parameters']['gain_mass_kg'] if 'gain_mass_product' in c else 0.0
    corr = {'mass_kg': rig.force_chain.m2 if rig is not None else measured, 'accel_delay_s': 0.0,
            'moving_cell_gain': 1.0}
    named = {x['name'] for x in rep.get('causes', [])}
    if 'gain_mass_product' in named:
        corr['mass_kg'] = c['gain_mass_product']['parameters']['gain_mass_kg']
    if 'accel_delay' in named:
        corr['accel_delay_s'] = c['accel_delay']['parameters']['delay_s']
    if 'mains_hum' in named:
        corr['mains_hum_hz'] = c['mains_hum']['parameters']['frequency_hz']
    if named & set(REFERENCE_COMPUTED):     # the stationary cell: g and m2 apart
        corr['moving_cell_gain'] = c['moving_cell_gain']['parameters']['gain']
        corr['mass_kg'] = c['effective_mass']['parameters']['mass_kg']
        return {'departures': {}, 'correction': corr, **_stated(correction_uncertainty(c, corr)),
                'assumptions': {}}
    return {'departures': {}, 'correction': corr, **_stated(correction_uncertainty(c, corr, PRODUCT_CORRECTED)),
            'assumptions': {'moving_cell_gain': 'not identifiable without a reference or a calibration mass: '
                            'mass_kg is g m2 and the gain 1, so the corrected force is g times the contact force; '
                            'the corrected peak\'s uncertainty keeps the rig\'s u of the gain for it',
                            **({} if rig is not None else {'mass_kg': f'{NO_RIG}: mass_kg is the g m2 measured in '
                                                           'the free phases'})}}


def _stated(unc: dict) -> dict:
    return {'uncertainty': unc} if unc else {}


def write_report(rep: dict, screens: Sequence, rig, out: Path, method: str) -> None:
    """DIR/report.json, report.md and extension.yaml, written whole (into a fresh folder, moved in at the end)."""
    from force_tester_common.core.partial import staging

    with staging(out, '.discover-') as mark:   # a staging folder a killed run left here is removed first
        stage = mark.folder
        (stage / 'extension.yaml').write_text(extension_yaml(report_extension(rep, rig)))
        (stage / 'report.md').write_text(report_markdown(rep, screens, method))
        (stage / 'report.json').write_text(json.dumps(rep, indent=1))
        mark.unmark()
        for f in sorted(stage.iterdir(), key=lambda q: q.name == 'report.json'):
            f.replace(out / f.name)

