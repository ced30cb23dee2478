"""The ONE-PASS discovery: every pull's arrays in memory at once, the force model fitted on the stacked samples
(force_model.ForceModel) instead of per-pull sufficient statistics (force_stats.ForceStats). A test oracle, not a
second product: the stages' arithmetic is the product's (stages.py, hum.py, ringing.py, friction.py, cells.py,
leftover.py, report's build_report), only the order of the work differs, so test_stream.py checks that
`force_discovery.core.pipeline.discover` (streamed) gives this report to rounding.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Optional, Sequence, Tuple

import numpy as np

from force_discovery.core import budget as B
from force_discovery.core import stages as S
from force_discovery.core.cells import (
    calibration_note,
    cell_calibration,
    cell_damping_ratio,
    cell_frequency_from,
    cell_mode,
    with_tension,
)
from force_discovery.core.decision import decide
from force_discovery.core.errors import DiscoveryError
from force_discovery.core.extension import extension
from force_discovery.core.force_errors import ForceErrors, error_part
from force_discovery.core.force_model import TERMS, ForceModel, fit_terms
from force_discovery.core.friction import (
    calibrated_rows,
    drive_calibration,
    drive_lines,
    friction_row,
    friction_rows,
    friction_sse,
    friction_stat,
    impulse_form,
    impulse_rows,
    impulse_variants,
    viscous_departure,
    viscous_separable,
    viscous_u,
)
from force_discovery.core.hum import (
    few_pulls,
    hum_form_parts,
    hum_frequencies,
    hum_frequency_from,
    hum_per_pull,
    hum_scale,
    pre_residual,
)
from force_discovery.core.identifiability import full_identifiability
from force_discovery.core.leftover import leftover_from, leftover_part
from force_discovery.core.outputs import write_outputs
from force_discovery.core.prep import Pull, check_quality, prepare
from force_discovery.core.quality import screen_pull
from force_discovery.core.report import (
    WITHOUT_REFERENCE_ONLY,
    add_simulation,
    build_report,
    campaign_section,
    complete,
    rig_state,
    unusable_report,
)
from force_discovery.core.resim import simulation_check
from force_discovery.core.ringing import cell_modes, free_decay_mode, free_decay_variants, observed_mode, ring_part
from force_discovery.core.source import campaign_absent, memory_refs
from force_tester_sim.core.departures import departures_from_data


@dataclass(frozen=True)
class OnePass:
    """analyse()'s result: the Analysis the product's report takes, and the arrays the one pass kept for the later
    stages: the prepared pulls (usable ones, T with the cells' calibration) and the hum per pull when significant."""

    analysis: S.Analysis
    pulls: tuple
    hums: Optional[tuple]


def calibrate_cells(pulls: Sequence[Pull], rig) -> Tuple[Sequence[Pull], Optional[dict], Optional[tuple],
                                                    Optional[tuple]]:
    """The cells' damping ratio measured on the pulls' free decay (cell_damping_ratio); when it departs from the
    rig's by more than CAL_MIN_CHANGE (relative), every pull's T is recomputed with it. Returns (pulls, calibration
    or None when nothing was measured, the (K_LC1, c1) T uses or None for the rig's, the measured cell frequency)."""
    fcal = cell_frequency_from(cell_mode(p, rig) for p in pulls)
    c1, out = cell_calibration(cell_damping_ratio(pulls, range(len(pulls)), rig), rig, fcal)
    if c1 is None:
        return pulls, out, None, fcal
    return tuple(with_tension(p, rig, c1) for p in pulls), out, c1, fcal


def systematic_parts(pulls, fit, cand, hums, rig, c1, fcal, delay) -> dict:
    """The systematic parts of the budgets (force_discovery.core.budget) from the pulls' arrays: the force model
    refitted on the variant pulls' samples (ForceModel), the load groups, the free-decay modes, the friction rows."""
    m2 = rig.force_chain.m2
    out: dict = {}
    vidx = B.variant_pulls(fit)
    sub_h = None if hums is None else [hums[j] for j in vidx]
    variants = [B.force_variants(pulls[j], rig, c1, fcal) for j in vidx]
    fs = B.force_systematics(ForceModel([pulls[j] for j in vidx], m2, sub_h),
                             {n: ForceModel([v[n] for v in variants], m2, sub_h) for n in variants[0]},
                             range(len(vidx)), m2)
    u_stat = {t: {p: (B.rate_stat_u(t, cand[t]) if t == 'ac_coupling' else B.statistical_u(t, cand[t], p))
                  for p in cand[t].parameters} for t in TERMS}
    ld = B.load_dependence(ForceModel(pulls, m2, hums), B.load_groups(fit, [p.peak for p in pulls]), m2, u_stat,
                           delay)
    mf = B.extra_systematics(lambda extra: ForceModel(pulls, m2, hums, extra=extra), fit, m2)
    for t, params in fs.items():
        for p, comps in params.items():
            out.setdefault(t, {})[p] = {**comps, **mf[t][p], **({'load_dependence': ld[t][p]} if t in ld else {})}
    few = few_pulls(fit)
    hum_freqs = hum_frequencies([pre_residual(pulls[j], m2) for j in few], cand['mains_hum'].parameters['frequency_hz'])
    modes = [free_decay_mode(pulls[j]) for j in few]
    variants = [free_decay_variants(pulls[j], m) for j, m in zip(few, modes)]
    out.update(B.pull_to_pull_parts(cand, modes, hum_freqs, variants))
    for par, comps in hum_form_parts([pre_residual(pulls[j], m2) for j in few],
                                     cand['mains_hum'].parameters['frequency_hz']).items():
        out.setdefault('mains_hum', {}).setdefault(par, {}).update(comps)
    if 'coulomb_friction' in cand:
        rows = friction_rows(friction_row(pulls[j], rig) for j in fit)
        impulse = impulse_form(rows, rig)
        rows_v = [B.friction_variants(pulls[j], rig) for j in fit]
        if impulse:
            rows = impulse_rows(rows)
            rows_v = impulse_variants(rows_v)
        drive = drive_calibration(rows, rig)
        line = None if drive is None else drive_lines(rows, drive, calibrated_rows(rows, False), rig, impulse)
        rows = calibrated_rows(rows, drive is not None)
        joint = viscous_separable(rows, viscous_u(rig))
        out['coulomb_friction'] = {'force_n': B.friction_systematics(
            rows, rows_v, partial(friction_stat, joint=joint), joint, line)}
    return out


def hum_stage(pulls, fit, held, m2):
    """(the mains-hum candidate, the hum per pull when it is significant else None, the per-pull scales)."""
    few = few_pulls(fit)
    pres = [pre_residual(pulls[j], m2) for j in few]
    f_hum, _power = hum_frequency_from(pres, pulls[few[0]].dt)
    amps, hums = [], []
    for p in pulls:
        a, h = hum_per_pull(p, f_hum, m2)
        amps.append(a)
        hums.append(h)
    a_fit = float(np.mean([amps[k] for k in fit]))
    scales = [hum_scale(amps, a_fit, j) if j in held else 1.0 for j in range(len(pulls))]
    hums = [h * hum_scale(amps, a_fit, j) if j in held else h for j, h in enumerate(hums)]
    cand, significant = S.hum_candidate(f_hum, hum_frequencies(pres, f_hum), amps, a_fit, ForceModel(pulls, m2, hums),
                                        ForceModel(pulls, m2), fit, held)
    return cand, (tuple(hums) if significant else None), S.HumScales(f_hum, tuple(scales))


def ring_stage(pulls, fit, held, fc):
    """The mount-resonance candidate from the free decay after the break (None, None without one)."""
    modes = [free_decay_mode(pulls[j]) for j in few_pulls(fit)]
    obs = observed_mode(modes)
    dt = pulls[0].dt
    parts = [] if obs is None else [ring_part(pulls[j], dt, cell_modes(fc), obs, keep=k == 0)
                                    for k, j in enumerate(held)]
    if parts and parts[0] is None:   # the plot's segment: the first held-out pull with one
        k = next((k for k, pt in enumerate(parts) if pt is not None), None)
        if k is not None:
            parts[k] = ring_part(pulls[held[k]], dt, cell_modes(fc), obs, keep=True)
    return S.ring_stage_from(modes, parts, [pulls[j].name for j in held], dt, fc)


def current_stage(pulls, fit, held, rig):
    """The coulomb-friction candidate and the held-out squared residuals without/with it (None, None without a
    current channel)."""
    rows = friction_rows(friction_row(pulls[j], rig) for j in fit)
    if rows is None:
        return None, None
    if impulse_form(rows, rig):
        rows = impulse_rows(rows)
    drive = drive_calibration(rows, rig)
    rows = calibrated_rows(rows, drive is not None)
    joint = viscous_separable(rows, viscous_u(rig))
    fcf, db = friction_stat(rows, joint), viscous_departure(rows, joint)
    b = [friction_sse(pulls[j], rig, 0.0, db) for j in held]
    e = [friction_sse(pulls[j], rig, fcf, db) for j in held]
    return (S.friction_candidate(rows, fcf, np.array(b), np.array(e), len(fit), joint,
                                 rig.drive.viscous_damping_n_s_per_m + db if joint else None,
                                 None if drive is None else drive[0]),
            {'sse_base': b, 'sse_ext': e, 'samples': [len(pulls[j].t) for j in held]})


def analyse(campaign_pulls, rig) -> OnePass:
    """All statistics (no files), in one pass with every pull's arrays in memory. campaign_pulls: [(meta, channels)]."""
    if len(campaign_pulls) < S.MIN_PULLS:
        raise DiscoveryError(f'campaign has {len(campaign_pulls)} pulls; expected at least {S.MIN_PULLS} '
                             '(half are fitted, half held out)')
    quality = tuple(check_quality(m, c) for m, c in campaign_pulls)
    dts = {round(q.dt, 12) for q in quality}
    if len(dts) != 1:
        raise DiscoveryError(f'pulls have different sample intervals {sorted(dts)}; expected one rate')
    screens = tuple(screen_pull(q.name, c) for q, (_m, c) in zip(quality, campaign_pulls))
    prepared = [prepare(m, c, rig, q, sc) for (m, c), q, sc in zip(campaign_pulls, quality, screens)]
    why = [sc.exclusion(p.w0, p.w1) for p, sc in zip(prepared, screens)]
    excluded = {p.name: w for p, w in zip(prepared, why) if w}
    pulls = tuple(p for p, w in zip(prepared, why) if not w)
    if len(pulls) < S.MIN_PULLS:
        return OnePass(S.unusable_analysis(len(pulls), len(prepared), quality, screens, excluded), (), None)
    m2 = rig.force_chain.m2
    fit, held = S.split(pulls)
    notes = []
    pulls, cells, c1, fcal = calibrate_cells(pulls, rig)
    if calibration_note(cells):
        notes.append(calibration_note(cells))
    hum, hums, scales = hum_stage(pulls, fit, held, m2)
    force_cand, force = S.force_stage_from(ForceModel(pulls, m2, hums), fit, held, m2)
    mount, ring = ring_stage(pulls, fit, held, rig.force_chain)
    friction, friction_sses = current_stage(pulls, fit, held, rig)
    cand, more = S.candidate_notes({'mains_hum': hum, **force_cand}, mount, friction)
    sys_ = systematic_parts(pulls, fit, cand, hums, rig, c1, fcal, force['delay_s'])
    cand = B.honest_all(cand, sys_, B.clock_relative(rig))
    infos = tuple(S.PullInfo(p.name, p.dt, len(p.t), p.w0, p.w1) for p in pulls)
    analysis = S.Analysis(infos, quality, tuple(fit), tuple(held), scales if hums is not None else None, cand, force,
                        ring, tuple(notes + more), screens, excluded, cells, friction_sses)
    return OnePass(analysis, pulls, hums)


def leftover(one: OnePass, named, rig) -> Optional[dict]:
    """Structure left in the held-out force residual after the extension (W vs the quiet pre-pull record)."""
    pulls, held, hums = one.pulls, one.analysis.held, one.hums
    fm_ = ForceModel(pulls, rig.force_chain.m2, hums)
    terms = set(n for n in named if n in TERMS)
    _terms, coef, d = fit_terms(fm_, terms, one.analysis.fit)
    parts = [leftover_part(pulls[j], hums[j] if hums is not None else None, fm_.resid(terms, coef, d, j), rig)
             for j in held]
    return leftover_from(parts, pulls[0].dt)


def force_errors(one: OnePass, named, rig) -> ForceErrors:
    """Held-out force-channel residual per pull: baseline (model of record) and extended (named causes)."""
    pulls, fit, held = one.pulls, one.analysis.fit, one.analysis.held
    m2 = rig.force_chain.m2
    fm0 = ForceModel(pulls, m2)
    fm1 = ForceModel(pulls, m2, one.hums if 'mains_hum' in named else None)
    terms = set(n for n in named if n in TERMS)
    _terms, coef, d = fit_terms(fm1, terms, fit)
    out = ForceErrors()
    for k, j in enumerate(held):
        out.add(error_part(pulls[j], fm0.resid(set(), {}, 0.0, j), fm1.resid(terms, coef, d, j), keep=k == 0))
    return out


def discover_in_memory(campaign_pulls, rig, out_dir) -> dict:
    """pipeline.discover() in one pass with every pull's arrays in memory: [(meta, channels)]."""
    one = analyse(campaign_pulls, rig)
    analysis = one.analysis
    decision = decide(analysis, rig)
    if not analysis.pulls:   # the data-quality stage left too few pulls: say so, name nothing
        report = complete({**unusable_report(analysis, rig), **campaign_section(analysis, ()), 'plots': [],
                           'rig': rig_state(rig)}, {},
                          'the data-quality screen left too few pulls to analyse (data_quality)')
        write_outputs(report, analysis, None, (), rig, Path(out_dir))
        return report
    # structure no catalog entry explains: what is left after every force-channel entry, named or not
    left = leftover(one, tuple(dict.fromkeys(decision.named + TERMS)), rig)
    errors = force_errors(one, decision.named, rig)
    report = build_report(analysis, decision, errors, left, rig)
    report['identifiable'], report['not_identifiable'] = full_identifiability(tuple(analysis.candidates))
    ext = extension(report, rig)
    check = None
    try:
        check = simulation_check(one.pulls, analysis.held, rig, departures_from_data(ext['departures']))
    except DiscoveryError as exc:
        report['notes'].append(f'no simulation check: {exc}')
    add_simulation(report, check)
    no_search = 'the one-pass oracle has no search beyond the catalog (the stream\'s only: test_stream.BEYOND)'
    absent = campaign_absent(memory_refs(campaign_pulls))
    report = complete({**report, **campaign_section(analysis, absent), 'plots': [], 'rig': rig_state(rig)},
                      {**WITHOUT_REFERENCE_ONLY, 'beyond_catalog': no_search, 'beyond_search': no_search})
    write_outputs(report, analysis, errors, decision.named, rig, Path(out_dir), check, ext)
    return report
