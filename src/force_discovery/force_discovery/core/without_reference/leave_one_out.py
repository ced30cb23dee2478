"""The reference-free campaign: g m2 and the delay pooled over the pulls, every pull held out once (leave-one-out),
the jackknife intervals, each cause's held-out evidence and its verdict, and what the number of pulls supports.
ROS-free."""
from __future__ import annotations

import math
from typing import List, Optional, Sequence, Tuple

import numpy as np

from force_tester_sim.core.tolerances import Band

from ..budget import COMBINED, HALF_PULLS, OPERATING_RANGE, STATISTICAL, expanded, halves_line
from ..candidate import Candidate, Evidence
from ..ringing import MOUNT_MAX_FRACTION, cluster_modes, damped_basis, ring_sse
from ..significance import MIN_REL_REDUCTION, MIN_T, significance
from ..uncertainty import NAMED, NOT_JUDGED, jackknife_ci, mean_ci, t_quantile, verdict_rule
from .phase_stats import FreeStats, gain_at, pooled, sse_at
from .phases import FreePull
from .stationary_cell import fit, gram_at, models, pooled_gram, reference_fits

MIN_NAMED_PULLS = 4            # held-out pulls needed before a cause can meet t >= MIN_T


def _jackknife(est: float, loo: Sequence[float]) -> Optional[List[float]]:
    return list(jackknife_ci(est, loo)) if len(loo) >= 2 else None


def _budget(est: float, ci: Optional[List[float]], halves: Optional[Tuple[float, float]], n: int) -> tuple:
    """(interval, budget) of one reference-free parameter: the statistical part (the interval's half-width over
    Student's t) and the model-form line OPERATING_RANGE, as a term beyond the catalog has it (budget.operating_range):
    halves, the parameter fitted on the first and on the second half of the pulls (a model whose form is the
    physics' gives both the same), u^2 = (h1 - h2)^2 / 4 less u_stat^2, at least 0; the interval widened to
    estimate +/- budget.expanded (k = 2 on the line). Fewer than 2 HALF_PULLS pulls, or no interval: as it was."""
    if ci is None or halves is None or n < 2 * HALF_PULLS or not all(math.isfinite(v) for v in ci):
        return ci, {}
    q = t_quantile(n)
    u_stat = 0.5 * (ci[1] - ci[0]) / q
    u_op = halves_line(halves[0], halves[1], u_stat)
    U = max(expanded(q, u_stat, u_op), 0.5 * (ci[1] - ci[0]))
    center = 0.5 * (ci[0] + ci[1])     # the jackknife's interval is about the estimate; mean_ci's about the mean
    return [float(center - U), float(center + U)], {STATISTICAL: u_stat, OPERATING_RANGE: u_op,
                                                    COMBINED: math.hypot(u_stat, u_op)}


def _evidence(ev, base, ext, where: str = 'free-phase', **more) -> Evidence:
    return Evidence(ev.rel_sse_reduction, ev.t, bool(ev.significant), ev.rms_gain,
                    statistic=f'held-out (leave-one-out) {where} SSE reduction and t of the per-pull reductions',
                    threshold=f'rel >= {MIN_REL_REDUCTION:g} and t >= {MIN_T:g} over >= {MIN_NAMED_PULLS} held-out '
                              'pulls',
                    per_pull_rel_reduction=tuple(float(1 - e / b) if b > 0 else 0.0 for b, e in zip(base, ext)),
                    **more)


def campaign_analysis(pulls: Sequence[FreePull], stats: Sequence[FreeStats], f_hum: float, rig) -> dict:
    """The campaign's estimates, their intervals, the held-out evidence and the verdicts (report.json's core):
    causes {name: Candidate}, tolerance {name: its verdict with the band (uncertainty.verdict's form)}. rig None:
    no rig was given, so there is no nominal to depart from: g m2's held-out evidence is against g m2 = 0 (no mass
    moving with the accelerometer), every verdict is NOT_JUDGED, and no mode is told a mount's (no cell mode)."""
    n = len(pulls)
    fc = rig.force_chain if rig is not None else None
    tol = rig.tolerances if rig is not None else None
    g0 = fc.m2 if fc is not None else 0.0     # the model of record: g = 1, the rig's m2, no delay
    allj = list(range(n))
    G, d = pooled(stats, allj)
    loo = [pooled(stats, [k for k in allj if k != j]) for j in allj] if n >= 2 else []
    hum_amps = [s.hum_amp for s in stats]
    # held-out SSE of each pull under the nested models
    if n >= 2:
        base = np.array([sse_at(stats[j], g0, 0.0, 'nohum') for j in allj])
        lo = [pooled(stats, [k for k in allj if k != j], 'nohum') for j in allj]
        full_nohum = np.array([sse_at(stats[j], *lo[j], 'nohum') for j in allj])
        full = np.array([sse_at(stats[j], *loo[j], 'hum') for j in allj])
        no_delay = np.array([sse_at(stats[j], gain_at(stats, [k for k in allj if k != j], 0.0), 0.0, 'hum')
                             for j in allj])
    else:
        base = np.array([sse_at(stats[0], g0, 0.0, 'nohum')])
        full_nohum = np.array([sse_at(stats[0], G, d, 'nohum')])
        full = np.array([sse_at(stats[0], G, d, 'hum')])
        no_delay = np.array([sse_at(stats[0], gain_at(stats, [0], 0.0), 0.0, 'hum')])
    # the G cause: nominal g m2 vs fitted G (delay fitted in both); the delay: G alone vs G and d; hum: without/with
    g_nom_d = np.array([sse_at(stats[j], g0, loo[j][1] if n >= 2 else d, 'hum') for j in allj])
    causes, tolerance = {}, {}
    band_g = (tol.moving_cell_gain_rel + tol.effective_mass_rel) * g0 if tol is not None else 0.0
    h = n // 2
    halves = [pooled(stats, allj[:h]), pooled(stats, allj[h:])] if h >= HALF_PULLS else None
    ci_g, b_g = _budget(G, _jackknife(G, [x[0] for x in loo]), halves and (halves[0][0], halves[1][0]), n)
    ci_d, b_d = _budget(d, _jackknife(d, [x[1] for x in loo]), halves and (halves[0][1], halves[1][1]), n)
    amp = float(np.mean(hum_amps))
    ci_h, b_h = _budget(amp, mean_ci(hum_amps), (float(np.mean(hum_amps[:h])), float(np.mean(hum_amps[h:]))) if h
                        else None, n)

    def entry(name, params, ci, ev_base, ev_ext, inside, outside, channel, band, where='free-phase', budget=None,
              **more):
        """The cause as a Candidate (its interval the jackknife's, widened by its model-form line: _budget) and its
        tolerance verdict (uncertainty.verdict_rule, as with a reference); band: (parameter, lo, hi, estimate)."""
        ev = significance(ev_base, ev_ext)
        departs = ev.rel_sse_reduction >= MIN_REL_REDUCTION and bool(np.all(ev_ext < ev_base)) and bool(outside)
        v = verdict_rule(bool(inside), bool(outside), ev.significant, can_name=n >= MIN_NAMED_PULLS,
                         departs=departs, one_pull=n < 2) if rig is not None else NOT_JUDGED
        causes[name] = Candidate(params, ci, n, _evidence(ev, ev_base, ev_ext, where, **more), channel,
                                 uncertainty_budget=budget or {})
        par, lo_, hi_, est = band
        pci = ci.get(par)
        tolerance[name] = {'band': Band(name, par, lo_, hi_).as_dict() if rig is not None else None,
                           'estimate': est, 'ci95': None if pci is None else list(pci), 'pulls': n, 'verdict': v}

    def band_test(ci, est, lo_, hi_):
        lo_ci, hi_ci = (ci if ci is not None else (est, est))
        return lo_ <= lo_ci and hi_ci <= hi_, hi_ci < lo_ or lo_ci > hi_

    ins, outs = band_test(ci_g, G, g0 - band_g, g0 + band_g)
    entry('gain_mass_product', {'gain_mass_kg': G}, {'gain_mass_kg': ci_g}, g_nom_d, full, ins if n >= 2 else None,
          outs, 'force_moving_n = g m2 a2(t + d), free phases', ('gain_mass_kg', g0 - band_g, g0 + band_g, G),
          budget={'gain_mass_kg': b_g} if b_g else None)
    tol_d, tol_h = (tol.accel_delay_s, tol.mains_hum_amplitude_n) if tol is not None else (0.0, 0.0)
    ins, outs = band_test(ci_d, d, -tol_d, tol_d)
    entry('accel_delay', {'delay_s': d}, {'delay_s': ci_d}, no_delay, full, ins if n >= 2 else None, outs,
          'force_moving_n = g m2 a2(t + d), free phases', ('delay_s', -tol_d, tol_d, d),
          budget={'delay_s': b_d} if b_d else None)
    ins, outs = band_test(ci_h, amp, 0.0, tol_h)
    entry('mains_hum', {'frequency_hz': f_hum, 'amplitude_n': amp}, {'amplitude_n': ci_h}, full_nohum, full,
          ins if n >= 2 else None, outs, 'force_moving_n - g m2 a2(t + d), free phases',
          ('amplitude_n', 0.0, tol_h, amp), budget={'amplitude_n': b_h} if b_h else None)
    ref = [s.ref for s in stats]
    reference = None
    if all(r is not None for r in ref):      # the stationary cell: g and m2 apart (stationary_cell.py)
        reference = reference_fits(ref, d, [x[1] for x in loo] if n >= 2 else [d], g0)
        held = reference['held']
        where = 'whole-record (F_move = g T + M a2(t + d) - k C)'
        chan = 'force_moving_n = g T + g m2 a2(t + d) - k C, T from force_stationary_n, the whole record'
        rg, rm = reference['g'], reference['m2']
        rh = None
        if h >= HALF_PULLS:
            rh = [fit(pooled_gram(ref, idx, d), models(g0)['full']) for idx in (allj[:h], allj[h:])]
        ci_rg, b_rg = _budget(rg, _jackknife(rg, [x[0] for x in reference['loo']]),
                              rh and (float(rh[0][0]), float(rh[1][0])), n)
        ci_rm, b_rm = _budget(rm, _jackknife(rm, [x[1] for x in reference['loo']]),
                              rh and (float(rh[0][1] / rh[0][0]), float(rh[1][1] / rh[1][0])), n)
        bg = tol.moving_cell_gain_rel if tol is not None else 0.0
        ins, outs = band_test(ci_rg, rg, 1.0 - bg, 1.0 + bg)
        entry('moving_cell_gain', {'gain': rg}, {'gain': ci_rg}, held['unit_gain'], held['full'],
              ins if n >= 2 else None, outs, chan, ('gain', 1.0 - bg, 1.0 + bg, rg), where,
              budget={'gain': b_rg} if b_rg else None)
        bm = tol.effective_mass_rel * g0 if tol is not None else 0.0
        ins, outs = band_test(ci_rm, rm, g0 - bm, g0 + bm)
        entry('effective_mass', {'mass_kg': rm}, {'mass_kg': ci_rm}, held['record_mass'], held['full'],
              ins if n >= 2 else None, outs, chan, ('mass_kg', g0 - bm, g0 + bm, rm), where,
              budget={'mass_kg': b_rm} if b_rm else None, ac_coupling_per_s=reference['k'])
    modes = cluster_modes(pulls)
    f_cell = math.sqrt(fc.load_cell_stiffness_n_per_m / fc.m2) / (2 * np.pi) if fc is not None else None
    noise = float(np.median([p.accel_noise for p in pulls]))
    mount = next((m for m in modes if f_cell and m['frequency_hz'] < MOUNT_MAX_FRACTION * f_cell), None)
    if mount is not None:
        cell = [(f_cell, fc.load_cell_damping_ratio)]
        b, e, r2n = [], [], []
        for p in pulls:
            if p.ring is None:
                continue
            others = [v for k, v in mount['per_pull'].items() if k != p.name] if n >= 2 else \
                list(mount['per_pull'].values())
            if not others:
                continue
            mode = (float(np.median([o[0] for o in others])), float(np.median([o[1] for o in others])))
            b.append(ring_sse(p.ring, p.dt, cell))
            e.append(ring_sse(p.ring, p.dt, cell + [mode]))
            X = np.column_stack([damped_basis(len(p.ring), p.dt, *mode), np.ones(len(p.ring))])
            c, *_ = np.linalg.lstsq(X, p.ring, rcond=None)
            r2n.append(float(np.sqrt(np.mean((X[:, :2] @ c[:2]) ** 2)) / max(p.accel_noise, 1e-12)))
        if b:
            rn = float(np.median(r2n))
            entry('mount_resonance', {'frequency_hz': mount['frequency_hz'], 'damping_ratio': mount['damping_ratio']},
                  {'frequency_hz': mount['frequency_ci95'], 'damping_ratio': mount['damping_ci95']}, np.array(b),
                  np.array(e), rn < tol.mount_ring_to_noise if n >= 2 else None, rn >= tol.mount_ring_to_noise,
                  'accel_axial_m_s2, free decay after the last event',
                  ('ring_to_noise', 0.0, tol.mount_ring_to_noise, rn), cell_mode_hz=f_cell, ring_to_noise=rn,
                  frequency_rule=f'observed < {MOUNT_MAX_FRACTION} x the rig\'s cell mode '
                                 f'({MOUNT_MAX_FRACTION * f_cell:.0f} Hz)')
    order = ('mount_resonance', 'accel_delay', 'moving_cell_gain', 'effective_mass', 'gain_mass_product',
             'mains_hum')
    named = sorted((k for k in order if k in causes and tolerance[k]['verdict'] == NAMED),
                   key=lambda k: -causes[k].evidence.rel_sse_reduction)
    per_pull = [{'pull': p.name, 'gain_mass_kg': p.gain_mass, 'delay_s': p.delay_s, 'hum_amplitude_n': s.hum_amp,
                 'free_share': p.free_share, 'events': list(p.events),
                 'modes': [{'frequency_hz': f, 'damping_ratio': z, 'energy_share': e} for f, z, e in p.modes]}
                for p, s in zip(pulls, stats)]
    if reference is not None:      # each pull's own g and m2 (at its own delay)
        for row, p, r in zip(per_pull, pulls, ref):
            b = fit(gram_at(r, p.delay_s), models(g0)['full'])
            row.update(moving_cell_gain=float(b[0]), effective_mass_kg=float(b[1] / b[0]))
    return {'G': G, 'd': d, 'causes': causes, 'tolerance': tolerance, 'named': named, 'modes': modes,
            'per_pull': per_pull,
            'baseline_sse': float(base.sum()), 'extended_sse': float(full.sum()),
            'samples': int(sum(s.samples for s in stats)), 'accel_noise': noise, 'cell_mode_hz': f_cell,
            'reference': reference is not None}



def validation_text(n: int, reference: bool = False) -> dict:
    """What the number of pulls supports (report.json validation); reference: the stationary cell is there (g and
    m2 apart)."""
    if n == 1:
        return {'method': 'per-pull', 'pulls': 1,
                'supports': f'the pull\'s own estimates ({"g, m2, " if reference else ""}g m2, delay, modes, hum, '
                            'data quality)',
                'cannot_support': 'an interval, a held-out check, or a cause: one pull cannot tell an effect '
                                  'from that pull\'s own scatter'}
    if n < MIN_NAMED_PULLS:
        return {'method': 'leave-one-out', 'pulls': n,
                'supports': f'each estimate fitted on {n - 1} pull(s) and checked on the one left out; the '
                            'per-pull agreement; a jackknife interval (wide: Student t with '
                            f'{n - 1} degree(s) of freedom)',
                'cannot_support': f'a named cause: the held-out test needs t >= {MIN_T:g} over at least '
                                  f'{MIN_NAMED_PULLS} held-out pulls; what departs on every held-out pull is '
                                  '`indicated`, not named'}
    return {'method': 'leave-one-out', 'pulls': n,
            'supports': f'each estimate fitted on {n - 1} pulls and checked on the one left out, every pull held '
                        f'out once; named causes (t >= {MIN_T:g} over the {n} held-out pulls, interval outside '
                        'the tolerance band)',
            'cannot_support': ('' if reference else 'g and m2 separately (no reference), ') +
                              'anything needing an absent channel'}

