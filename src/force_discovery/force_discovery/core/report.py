"""report.json: the discovery's findings as one JSON document (build_report; unusable_report when the data-quality
stage leaves too few pulls). The candidates become dicts here, with the decision's verdicts. The other outputs:
markdown.py (report.md), extension.py (extension.yaml), plots.py, outputs.py (writes them all). ROS-free."""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from force_tester_common.core.channels import CHANNELS

from . import quality as Q
from .decision import NONLIN_SHARE, Decision
from .errors import DiscoveryError
from .force_errors import ForceErrors
from .force_model import TERMS
from .leftover import UNEXPLAINED_SHARE
from .ringing import MOUNT_MAX_FRACTION
from .significance import MIN_REL_REDUCTION, MIN_T
from .stages import CATALOG_PARAMS, MIN_PULLS, Analysis
from .uncertainty import INCONCLUSIVE, WITHIN

FORCE_CHANNEL = ('mains_hum',) + TERMS
HELD_OUT = 'held-out'     # validation.method with a reference: half the pulls fitted, half held out
#: report.json's top-level keys, on both paths (a test checks a campaign with a reference and one without). A key a
#: path cannot fill is {NOT_AVAILABLE: why} (complete), never left out
REPORT_KEYS = ('cause', 'causes', 'baseline_error', 'extended_error', 'gain', 'metric', 'rig', 'reference',
               'stationary_cell',
               'absent', 'channels', 'validation', 'identifiable', 'not_identifiable', 'force_channel',
               'within_tolerance', 'inconclusive', 'indicated', 'tolerances', 'pulls', 'fitted_pulls',
               'held_out_pulls', 'excluded_pulls', 'significance_rule', 'uncertainty_budget', 'candidates', 'modes',
               'per_pull', 'cell_mode_hz', 'leftover', 'cell_damping', 'simulation', 'simulation_check',
               'beyond_catalog', 'beyond_search', 'data_quality', 'notes', 'plots', 'failed_pulls', 'retried_pulls',
               'scheduler')
NOT_AVAILABLE = 'not_available'
NO_RIG = ('no rig given (--rig): the estimates are reported with what they mean; nothing is judged against a '
          'nominal or a tolerance band, so no cause is named')


def rig_state(rig, file=None, nominal: bool = False) -> dict:
    """report.json's ``rig``: what the data were judged against. rig None: none given (NO_RIG); nominal: none
    given, and the analysis with a reference took the packaged nominal rig (ours) as its model of record; else the
    rig given, from ``file`` (None: given in memory)."""
    if rig is None:
        return {'given': False, 'file': None, 'what': NO_RIG}
    if nominal:
        from force_tester_sim.core.params import NOMINAL_YAML
        return {'given': False, 'file': str(NOMINAL_YAML),
                'what': 'no rig given (--rig): the analysis with a reference (the stationary cell, the encoder) '
                        'judges the data against the packaged nominal rig, the workspace\'s own'}
    return {'given': True, 'file': None if file is None else str(file),
            'what': 'departures are named against this rig\'s nominal values and tolerance bands'}
#: why the path without a reference cannot fill a key (the keys only the analysis with a reference fills)
WITH_REFERENCE_ONLY = {
    'force_channel': 'the held-out force-channel error needs the tension T and the carriage motion (the stationary '
                     'cell, the encoder, 4 pulls or more): the free phases give the metric instead',
    'leftover': 'the structure check runs on the force model\'s residual, which needs T and the carriage motion',
    'cell_damping': 'the cells\' calibration is the stationary cell\'s free decay with the encoder\'s motion',
    'simulation': 'the re-simulation drives the sim with the encoder\'s carriage motion and checks T',
    'simulation_check': 'the re-simulation drives the sim with the encoder\'s carriage motion and checks T',
    'beyond_catalog': 'the search beyond the catalog runs on the residuals the model of record leaves, which need T '
                      'and the carriage motion',
    'beyond_search': 'the search beyond the catalog runs on the residuals the model of record leaves, which need T '
                     'and the carriage motion'}
#: why the path with a reference does not fill a key (the keys only the free-phase analysis fills)
WITHOUT_REFERENCE_ONLY = {
    'modes': 'with a reference the ringing is the mount_resonance candidate (its evidence: the observed mode)',
    'per_pull': 'with a reference the estimates are pooled over the fitted pulls and tested on the held-out ones; '
                'per-pull estimates are the free-phase analysis\'s',
    'cell_mode_hz': 'with a reference the rig\'s cell mode is the mount_resonance candidate\'s evidence.cell_mode_hz'}


def complete(report: dict, why: dict, default: str = '') -> dict:
    """The report with every REPORT_KEYS key in that order: a key the path did not fill is {NOT_AVAILABLE: why}
    (why[key], else default). A key outside REPORT_KEYS, or missing with no reason, is a DiscoveryError."""
    extra = sorted(set(report) - set(REPORT_KEYS))
    missing = [k for k in REPORT_KEYS if k not in report and not (why.get(k) or default)]
    if extra or missing:
        raise DiscoveryError(f'report.json keys {extra} are not in REPORT_KEYS and {missing} have no value and no '
                             'reason; expected every REPORT_KEYS key, filled or said why not')
    return {k: report[k] if k in report else {NOT_AVAILABLE: why.get(k) or default} for k in REPORT_KEYS}


def available(report: dict, key: str):
    """report[key], or None where the path said why it could not fill it (complete)."""
    v = report.get(key)
    return None if isinstance(v, dict) and set(v) == {NOT_AVAILABLE} else v


def campaign_section(analysis: Analysis, absent) -> dict:
    """report.json: the campaign as the path with a reference saw it (the keys the reference-free path fills too)."""
    n_fit, n_held = len(analysis.fit), len(analysis.held)
    return {'reference': True, 'stationary_cell': True, 'absent': list(absent),
            'channels': [c for c in CHANNELS if c not in absent], 'pulls': [p.name for p in analysis.pulls],
            'excluded_pulls': dict(analysis.excluded), 'indicated': [],
            'validation': {'method': HELD_OUT, 'pulls': n_held,
                           'supports': f'each cause fitted on the {n_fit} fitted pulls and tested on the {n_held} '
                                       f'held-out ones; named causes (t >= {MIN_T:g} over the held-out pulls, '
                                       'interval outside the tolerance band)',
                           'cannot_support': ('anything needing an absent channel' if absent else '')}}


#: report.json: a candidate's keys (candidates.<name>), on both paths; a listed cause (causes[], within_tolerance[],
#: inconclusive[], indicated[]) has its name and LISTED_KEYS, a named one also its gain, channel and where
CANDIDATE_KEYS = ('parameters', 'parameters_ci95', 'uncertainty_budget', 'tolerance', 'evidence', 'channel')
LISTED_KEYS = ('parameters', 'parameters_ci95', 'uncertainty_budget', 'tolerance', 'evidence')


def clean(x):
    if isinstance(x, dict):
        return {str(k): clean(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [clean(v) for v in x]
    if isinstance(x, (np.floating, float)):
        v = float(x)
        return v if math.isfinite(v) else None
    if isinstance(x, (np.integer,)):
        return int(x)
    if isinstance(x, np.bool_):
        return bool(x)
    return x


def _where(n, c):
    p = c['parameters']
    if n == 'mains_hum':
        return (f'a spectral line at {p["frequency_hz"]:.2f} Hz on the moving cell, '
                'on the whole record (also with no load)')
    if n == 'mount_resonance':
        ev = c['evidence']
        return (f'accelerometer ringing at {ev["observed_frequency_hz"]:.0f} Hz '
                f'(zeta {ev["observed_damping_ratio"]:.3f}) '
                'after the taut instant and the break; '
                f'the model of record only has the {ev["cell_mode_hz"]:.0f} Hz cell mode')
    if n == 'coulomb_friction':
        return 'motor current offset while the carriage moves (sign of v3)'
    if n == 'ac_coupling':
        return ('moving cell undershoots after the load and decays with the time constant '
                '(correlates with the running integral of F_move)')
    if n == 'moving_cell_gain':
        return 'moving cell off by a fixed fraction of the tension during the quasi-static load (coupon flow)'
    if n == 'effective_mass':
        return 'residual proportional to a2 (the ringing at the elastic rise and the break)'
    if n == 'accel_delay':
        return 'residual proportional to da2/dt: a2 lags the forces (visible on the ringing at the rise and break)'
    return ''


def candidates(analysis: Analysis, decision: Decision) -> dict:
    """The analysis's candidates with the decision's verdicts filled in."""
    out = {}
    for n, cand in analysis.candidates.items():
        c = cand.as_dict()
        if n in decision.rejected:
            c['evidence']['rejected'] = decision.rejected[n]
        c['tolerance'] = decision.verdicts.get(n)
        out[n] = c
    return out


def entry(n: str, c: dict) -> dict:
    """A candidate as listed in report.json: parameters, their 95 % intervals (expanded: budget.py), the
    uncertainty budget {parameter: {component: u}}, the tolerance verdict."""
    return {'name': n, 'parameters': {k: float(c['parameters'][k]) for k in CATALOG_PARAMS[n]},
            'parameters_ci95': {k: [float(v) for v in c['parameters_ci95'][k]] for k in CATALOG_PARAMS[n]},
            'uncertainty_budget': {k: c['uncertainty_budget'][k] for k in CATALOG_PARAMS[n]
                                   if k in c['uncertainty_budget']},
            'tolerance': c['tolerance']}


def build_report(analysis: Analysis, decision: Decision, errors: ForceErrors, left, rig) -> dict:
    """The report (JSON-ready). errors: the held-out force errors with the named causes (force_errors.py, added
    up by the stream's last pass); left: the structure check (leftover.py)."""
    named = decision.named
    cand = candidates(analysis, decision)
    causes = []
    for n in named:
        c = cand[n]
        ev = dict(c['evidence'])
        causes.append({**entry(n, c), 'evidence': ev, 'gain': ev.get('rms_gain'), 'channel': c['channel'],
                       'where': _where(n, c)})
    primary = named[0] if named else ('unexplained' if left and left['structured'] else 'none')
    if primary == 'unexplained':
        causes.append({'name': 'unexplained', 'parameters': {
            'dominant_frequency_hz': left['dominant_frequency_hz'], 'correlated_channel': left['correlated_channel'],
            'share_of_residual_variance': left['share_of_residual_variance']},
            'evidence': {'statistic': 'residual variance share above the quiet-record floor',
                         'value': left['share_of_residual_variance'], 'threshold': UNEXPLAINED_SHARE,
                         'rule': left['rule']}, 'gain': 1.0})
    if primary in ('mount_resonance', 'coulomb_friction') and not any(n in FORCE_CHANNEL for n in named):
        # RMS on the cause's own channel (held-out); no other channel changes
        metric = ('RMS on held-out pulls of ' + cand[primary]['channel'] + ' (per-pull amplitude/phase of the '
                  'modes fitted)' if primary == 'mount_resonance' else 'RMS on held-out pulls of the motor-current '
                  'residual (force balance), A')
        if primary == 'mount_resonance':
            baseline_error, extended_error = _ring_rms(analysis, rig)
        else:
            baseline_error, extended_error = _current_rms(analysis, rig, cand[primary]['parameters']['force_n'])
    else:
        baseline_error, extended_error = errors.rms()
        metric = ('RMS (N) on the held-out pulls of the moving-cell prediction residual F_move - F_pred over the '
                  'analysis window (50 ms before the load to 150 ms after the break); baseline F_pred = T + m2 a2 '
                  '(eq 21, T = F_stat + m1 a1, nominal m2, ideal sensors), extended: all named force-channel causes')
    report = {
        'cause': primary,
        'causes': causes,
        'baseline_error': baseline_error,
        'extended_error': extended_error,
        'gain': baseline_error / extended_error if extended_error > 0 else None,
        'metric': metric,
        'force_channel': dict(zip(('baseline_rms_n', 'extended_rms_n'), errors.rms())),
        'within_tolerance': [{**entry(n, cand[n]), 'evidence': cand[n]['evidence']}
                             for n in decision.with_verdict(WITHIN)],
        'inconclusive': [{**entry(n, cand[n]), 'evidence': cand[n]['evidence'],
                          'pulls_to_settle': cand[n]['tolerance'].get('pulls_to_settle')}
                         for n in decision.with_verdict(INCONCLUSIVE)],
        'tolerances': dataclasses.asdict(rig.tolerances),
        'fitted_pulls': analysis.fitted_pulls,
        'held_out_pulls': analysis.held_out_pulls,
        'significance_rule': (f'a candidate is named when, on the held-out pulls, removing it from the extended '
                              f'model raises the summed squared residual of its channel by >= '
                              f'{100 * MIN_REL_REDUCTION:g} % and the per-pull increases have t >= {MIN_T:g}, '
                              f'AND its 95 % interval (the pull-to-pull spread and the systematic parts of '
                              f'its uncertainty_budget, expanded) lies wholly outside '
                              f'its tolerance band (rig tolerances:); inside the band it is within_tolerance, '
                              f'across an edge inconclusive; '
                              f'a mount mode must also lie below {MOUNT_MAX_FRACTION} x the cell mode; '
                              f'force-channel causes are withheld when a T^2 term removes > '
                              f'{100 * NONLIN_SHARE:g} % of the held-out force residual left by them'),
        'uncertainty_budget': {n: c['uncertainty_budget'] for n, c in cand.items()},
        'candidates': {n: {k: c[k] for k in CANDIDATE_KEYS} for n, c in cand.items()},
        'leftover': left,
        'cell_damping': analysis.cells,
        'data_quality': quality_section(analysis),
        'notes': [*analysis.notes, *decision.notes],
        **run_section(analysis),
    }
    return clean(report)


def run_section(analysis: Analysis) -> dict:
    """report.json: the pulls that could not be analysed (failed_pulls: name and why), those rerun after a worker
    died (retried_pulls), and where the per-pull stages ran (scheduler)."""
    return {'failed_pulls': [{'pull': n, 'error': e} for n, e in analysis.failed],
            'retried_pulls': list(analysis.retried), 'scheduler': analysis.scheduler or None}


def quality_section(analysis: Analysis) -> list:
    """report.json data_quality: every defect found, {pull, channel, kind, t_start_s, t_end_s, detail}, and one
    entry (kind 'excluded') per pull the screen left out."""
    rows = Q.defect_dicts(analysis.screens)
    for name, why in analysis.excluded.items():
        q = next(q for q in analysis.quality if q.name == name)
        rows.append({'pull': name, 'channel': Q.ALL, 'kind': 'excluded', 't_start_s': 0.0,
                     't_end_s': q.samples * q.dt, 'detail': why})
    return rows


def add_simulation(report: dict, check) -> None:
    """report.json simulation: {channel: {baseline_rms, extended_rms, gain}} from the re-simulation of the held-out
    pulls (None when no pull could be re-simulated), and simulation_check: how (pulls, ring frequency, damping, the
    extra terms re-simulated and how)."""
    report['simulation'] = None if check is None else clean(check.as_dict())
    report['simulation_check'] = None if check is None else clean(check.details())


def add_beyond(report: dict, found) -> None:
    """report.json beyond_catalog (the beyond package's named terms, best first) and beyond_search (how the search
    ran, the terms inside their band, the catalog causes a term fits better); with no catalog cause named, a term
    found makes the cause 'beyond_catalog' instead of 'unexplained' or 'none'."""
    from force_tester_sim.core.extra_terms import CHANNEL_UNITS

    from .beyond.grammar import SEARCHED, library
    from .beyond.own import near_ties
    report['beyond_catalog'] = clean([t.as_dict() for t in found.terms])
    report['beyond_search'] = clean({
        'channels': list(SEARCHED), 'library_terms': len(library()), 'frequencies_hz': found.frequencies,
        'within_tolerance': [t.as_dict() for t in found.within_tolerance],
        'catalog_not_fitting': found.demoted, 'channel_units': {c: CHANNEL_UNITS[c] for c in SEARCHED},
        'identifiability': list(found.identifiability) + [
            {'channel': t.channel, 'term': t.term, 'reason': t.unidentifiable}
            for t in found.within_tolerance if t.unidentifiable] + [e for t in found.terms for e in near_ties(t)],
        'catalog_checked': found.checked,
        'rule': 'forward selection over the library on the fitted pulls; a term joins when it passes the held-out '
                'test of the catalog (SSE -1 %, t >= 4) and is named when its contribution rms, over its 95 % '
                'interval, lies above the channel band (evidence.band)'})
    if found.terms and report['cause'] in ('unexplained', 'none'):
        report['cause'] = 'beyond_catalog'
        report['causes'] = [c for c in report['causes'] if c['name'] != 'unexplained']


def unusable_report(analysis: Analysis, rig) -> dict:
    """The report when the data-quality stage leaves too few pulls: unexplained, data_quality says why."""
    return clean({
        'cause': 'unexplained',
        'causes': [{'name': 'unexplained', 'parameters': {}, 'gain': None,
                    'evidence': {'statistic': 'pulls usable after the data-quality screen',
                                 'value': len(analysis.quality) - len(analysis.excluded), 'threshold': MIN_PULLS,
                                 'rule': 'defects leave too few pulls to fit and hold out; see data_quality'}}],
        'baseline_error': None, 'extended_error': None, 'gain': None, 'metric': 'none: no pulls to score',
        'within_tolerance': [], 'inconclusive': [], 'candidates': {}, 'leftover': None,
        'simulation': None, 'simulation_check': None,
        'tolerances': dataclasses.asdict(rig.tolerances), 'fitted_pulls': [], 'held_out_pulls': [],
        'data_quality': quality_section(analysis), 'notes': list(analysis.notes), **run_section(analysis)})


def _ring_rms(analysis: Analysis, rig):
    ring = analysis.ring
    b = e = n = 0.0
    for sb, se, ns in zip(ring['sse_base'], ring['sse_ext'], ring['samples']):
        b += sb
        e += se
        n += ns
    return math.sqrt(b / n), math.sqrt(e / n)


def _current_rms(analysis: Analysis, rig, fcf):
    fr = analysis.friction
    return math.sqrt(sum(fr['sse_base']) / sum(fr['samples'])), math.sqrt(sum(fr['sse_ext']) / sum(fr['samples']))
