"""extension.yaml: the named causes as the sim's departures catalog takes them and what the correction node can
undo (extension), from the report or, before the report exists, from the decision (named_extension). ROS-free."""
from __future__ import annotations

import math

from force_correction.core.extension import CORRECTION_TERMS
from force_correction.core.peak_uncertainty import COVERAGE_FACTOR
from force_tester_sim.core.departures import MOUNT_BASE_MASS_FRACTION
from force_tester_sim.core.uncertainty import DEPARTURES

from .decision import Decision
from .report import available, candidates, clean, entry
from .ringing import mount_from_observed
from .stages import CATALOG_PARAMS, Analysis

#: the corrected values whose uncertainty extension.yaml states: (the candidate, its parameter, the correction's
#: key, the (cause, parameter) of the rig YAML's uncertainty: form it is stated as)
CORRECTED = (('effective_mass', 'mass_kg', 'mass_kg', ('effective_mass', 'mass_kg')),
             ('moving_cell_gain', 'gain', 'moving_cell_gain', ('moving_cell_gain', 'gain')),
             ('accel_delay', 'delay_s', 'accel_delay_s', ('accel_delay', 'delay_s')))

HEAD = ('# Extension found by `./ft discover`: the departures section below, appended to the nominal rig '
        'YAML,\n# reproduces the behaviour with load_rig; the correction section is what the correction node '
        'can undo\n# (the correction node and `./ft bag correct --extension` divide F_move by '
        'moving_cell_gain, undo the\n# AC coupling, notch the hum, delay F_move by accel_delay_s to line it '
        'up with a2, then subtract\n# mass_kg * a2). assumptions: what a mapping to the sim needed that the '
        'data do not identify. uncertainty: the\n# standard uncertainties (k = 1) of the corrected values the '
        'campaign estimated, in the rig YAML\'s form\n# (the corrected peak\'s uncertainty takes them). extra_terms: '
        'terms beyond the catalog (the rig YAML\n# takes them too); the correction linearises the moving cell by '
        'their F_move^2 and F_move^3\n# (moving_cell_quadratic_per_n, moving_cell_cubic_per_n2); it names any other '
        'term on the moving cell\n# or the accelerometer, which it cannot undo, in a warning.\n')


def named_extension(analysis: Analysis, decision: Decision, rig) -> dict:
    """extension() of the report build_report() will write, from the named causes alone (it needs nothing else
    of the report): the stream re-simulates with it before the report exists."""
    cand = candidates(analysis, decision)
    return extension(clean({'causes': [entry(n, cand[n]) for n in decision.named], 'candidates': cand}), rig)


def extension(report, rig) -> dict:
    """departures: the named causes as the sim's catalog takes them; correction: what correction_node undoes.

    The mount is identified as the mode seen in the measured channels; the sim's mount_resonance parameters
    are the mount's own, mapped from it through the carriage-mount-bracket-cell-m2 chain with an assumed
    bracket mass (stated in extension.yaml, key assumptions)."""
    deps = {c['name']: dict(c['parameters']) for c in report['causes'] if c['name'] in CATALOG_PARAMS}
    fc = rig.force_chain
    m2 = float(deps.get('effective_mass', {}).get('mass_kg', fc.m2))
    assumptions = {}
    if 'mount_resonance' in deps:
        obs = deps['mount_resonance']
        mb = MOUNT_BASE_MASS_FRACTION * m2
        f, z = mount_from_observed(obs['frequency_hz'], obs['damping_ratio'], m2, fc.load_cell_stiffness_n_per_m,
                                     fc.load_cell_damping_ratio, mb)
        deps['mount_resonance'] = {'frequency_hz': f, 'damping_ratio': z, 'base_mass_kg': mb}
        assumptions['mount_resonance'] = (
            f'observed mode {obs["frequency_hz"]:.2f} Hz, zeta {obs["damping_ratio"]:.4f} (the identified '
            f'quantities) mapped to the mount through the carriage-mount-bracket-cell-m2 chain with an assumed '
            f'bracket mass base_mass_kg = {MOUNT_BASE_MASS_FRACTION} x m2 = {mb:.4f} kg (not identifiable from '
            f'these channels); another bracket mass gives other mount parameters and the same observed mode')
    delay = float(deps.get('accel_delay', {}).get('delay_s', 0.0))
    if delay < 0:
        assumptions['accel_delay'] = (
            f'the accelerometer leads the moving cell by {-delay * 1e6:.3g} us (a DAQ that samples its channels in '
            f'turn); the correction delays F_move only, so it keeps accel_delay_s 0 and the lead is in the '
            f'uncertainty it states for the delay')
    corr = {'mass_kg': m2,
            'accel_delay_s': max(delay, 0.0),
            'moving_cell_gain': float(deps.get('moving_cell_gain', {}).get('gain', 1.0))}
    if 'ac_coupling' in deps:
        corr['ac_coupling_time_constant_s'] = deps['ac_coupling']['time_constant_s']
    if 'mains_hum' in deps:
        corr['mains_hum_hz'] = deps['mains_hum']['frequency_hz']
    out = {'departures': deps, 'correction': corr}
    unc = correction_uncertainty(report.get('candidates') or {}, corr)
    if unc:
        out['uncertainty'] = unc
    add_extra_terms(out, available(report, 'beyond_catalog') or ())
    if assumptions:
        out['assumptions'] = assumptions
    return out


def correction_uncertainty(cands: dict, corr: dict, corrected=CORRECTED) -> dict:
    """The extension's ``uncertainty:`` section (the rig YAML's form, force_tester_sim.core.uncertainty:
    ``departures: {cause: {parameter: u}}``): the standard uncertainty (k = 1) of each value the correction uses
    that the campaign estimated (m2, the gain, the delay: ``corrected``), from the candidate's expanded interval
    (half-width / COVERAGE_FACTOR) and, where the correction keeps the model of record's value because the cause is
    not named, the difference between the estimate and that value: u = sqrt((U / k)^2 + (estimate - used)^2).
    A candidate with no interval (one pull: per-pull estimates only) states nothing."""
    out: dict = {}
    for cause, par, key, (as_cause, as_par) in corrected:
        c = cands.get(cause) or {}
        ci = (c.get('parameters_ci95') or {}).get(par)
        est = (c.get('parameters') or {}).get(par)
        if not ci or est is None or not all(v is not None and math.isfinite(v) for v in ci):
            continue
        lo, hi = ci
        u = math.hypot(0.5 * (hi - lo) / COVERAGE_FACTOR, est - corr[key])
        out.setdefault(as_cause, {})[as_par] = float(u)
    return {DEPARTURES: out} if out else {}


def add_extra_terms(ext: dict, terms) -> None:
    """ext's extra_terms: (the sim's rig YAML takes them: force_tester_sim.core.extra_terms) from report.json
    beyond_catalog entries, and the correction's polynomial of the moving cell from its F_move^2, F_move^3."""
    if not terms:
        return
    ext['extra_terms'] = [{'channel': t['channel'], 'term': t['term'], 'coefficient': t['coefficient'],
                           **({'frequency_hz': t['frequency_hz']} if t.get('frequency_hz') else {})} for t in terms]
    for t in terms:
        if t['channel'] == 'force_moving' and t['term'] in CORRECTION_TERMS:
            ext['correction'][CORRECTION_TERMS[t['term']]] = t['coefficient']


def extension_yaml(ext: dict) -> str:
    """The text of extension.yaml: HEAD, then ext."""
    import yaml
    return HEAD + yaml.safe_dump(clean(ext), sort_keys=False)
