"""The in-memory twin of the stages (every pull's arrays at once). ROS-free."""
from __future__ import annotations

from typing import Optional, Sequence, Tuple

import numpy as np

from .cells import calibration_note, cell_calibration, cell_damping_ratio, with_tension
from .errors import DiscoveryError
from .force_model import TERMS, ForceModel, fit_terms
from .friction import friction_row, friction_rows, friction_sse, friction_stat
from .hum import few_pulls, hum_frequency_from, hum_frequency_near, hum_per_pull, hum_scale, pre_residual
from .leftover import leftover_from, leftover_part
from .prep import Pull, check_quality, prepare
from .quality import screen_pull
from .ringing import cell_modes, free_decay_mode, observed_mode, ring_part
from .stages import (
    MIN_PULLS,
    Analysis,
    candidate_notes,
    force_stage_from,
    friction_candidate,
    hum_candidate,
    ring_stage_from,
    split,
    unusable_analysis,
)


def fit_hum_frequency(pulls: Sequence[Pull], m2: float) -> Tuple[float, dict]:
    """Frequency maximizing the summed (per-pull, free phase) line power of the pre-pull residual, 45-65 Hz."""
    return hum_frequency_from([pre_residual(p, m2) for p in pulls], pulls[0].dt)


def hum_frequency_per_pull(p: Pull, f0: float, m2: float) -> float:
    """One pull's own least-squares hum frequency near f0 (its pre-pull record only)."""
    return hum_frequency_near(*pre_residual(p, m2), f0)


def friction_offsets(pulls, idx, rig) -> Optional[np.ndarray]:
    """Per pull: the median force-balance residual while moving and at rest (None without a current channel)."""
    return friction_rows(friction_row(pulls[j], rig) for j in idx)


def calibrate_cells(pulls: Sequence[Pull], rig) -> Tuple[Sequence[Pull], Optional[dict]]:
    """The cells' damping ratio measured on the pulls' free decay (cell_damping_ratio); when it departs from the
    rig's by more than CAL_MIN_CHANGE (relative), every pull's T is recomputed with it (a1 from F_stat depends on the
    stationary cell's damping: with a wrong one T rings wrongly at the cell mode). Returns (pulls, calibration or
    None when nothing was measured)."""
    c1, out = cell_calibration(cell_damping_ratio(pulls, range(len(pulls)), rig), rig)
    if c1 is None:
        return pulls, out
    return tuple(with_tension(p, rig, c1) for p in pulls), out


def hum_stage(pulls, fit, held, m2) -> Tuple[dict, Optional[tuple]]:
    """The mains-hum candidate and, when it is significant, the hum per pull.

    Frequency from a few fitted pulls' pre-pull records; phase per pull from its own pre-pull record;
    amplitude of the held-out pulls from the fitted pulls. Scored on W (disjoint from the pre-pull
    record the phases came from), inside the full force model."""
    few = few_pulls(fit)
    pres = [pre_residual(pulls[j], m2) for j in few]
    f_hum, _power = hum_frequency_from(pres, pulls[few[0]].dt)
    amps, hums = [], []
    for p in pulls:
        a, h = hum_per_pull(p, f_hum, m2)
        amps.append(a)
        hums.append(h)
    a_fit = float(np.mean([amps[k] for k in fit]))
    hums = [h * hum_scale(amps, a_fit, j) if j in held else h for j, h in enumerate(hums)]
    cand, significant = hum_candidate(f_hum, pres, amps, a_fit, ForceModel(pulls, m2, hums), ForceModel(pulls, m2),
                                      fit, held)
    return cand, (tuple(hums) if significant else None)


def force_stage(pulls, hums, fit, held, m2) -> Tuple[dict, dict]:
    """The force-channel candidates (each tested by dropping it from the full model) and the full model."""
    return force_stage_from(ForceModel(pulls, m2, hums), fit, held, m2)


def ring_stage(pulls, fit, held, fc) -> Tuple[Optional[dict], Optional[dict]]:
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
    return ring_stage_from(modes, parts, [pulls[j].name for j in held], dt, fc)


def current_stage(pulls, fit, held, rig) -> Tuple[Optional[dict], Optional[dict]]:
    """The coulomb-friction candidate from the motor current and the held-out squared residuals without/with it
    (None, None without a current channel)."""
    rows = friction_offsets(pulls, fit, rig)
    if rows is None:
        return None, None
    fcf = friction_stat(rows)
    b = [friction_sse(pulls[j], rig, 0.0) for j in held]
    e = [friction_sse(pulls[j], rig, fcf) for j in held]
    return (friction_candidate(rows, fcf, np.array(b), np.array(e), len(fit)),
            {'sse_base': b, 'sse_ext': e, 'samples': [len(pulls[j].t) for j in held]})


def analyse(campaign_pulls, rig) -> Analysis:
    """All statistics (no files), in one pass with every pull's arrays in memory. campaign_pulls: [(meta, channels)].

    The reference implementation: discover() streams the pulls instead (stream.py), with the same stages."""
    if len(campaign_pulls) < MIN_PULLS:
        raise DiscoveryError(f'campaign has {len(campaign_pulls)} pulls; expected at least {MIN_PULLS} '
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
    if len(pulls) < MIN_PULLS:
        return unusable_analysis(len(pulls), len(prepared), quality, screens, excluded)
    m2 = rig.force_chain.m2
    fit, held = split(pulls)
    notes = []
    pulls, cells = calibrate_cells(pulls, rig)
    if calibration_note(cells):
        notes.append(calibration_note(cells))
    hum, hums = hum_stage(pulls, fit, held, m2)
    cand = {'mains_hum': hum}
    force_cand, force = force_stage(pulls, hums, fit, held, m2)
    cand.update(force_cand)
    mount, ring = ring_stage(pulls, fit, held, rig.force_chain)
    friction, friction_sses = current_stage(pulls, fit, held, rig)
    notes += candidate_notes(cand, mount, friction)
    return Analysis(pulls, quality, tuple(fit), tuple(held), hums, cand, force, ring, tuple(notes), screens, excluded,
                    cells, friction_sses)


def leftover(analysis: Analysis, named, rig) -> Optional[dict]:
    """Structure left in the held-out force residual after the extension (W vs the quiet pre-pull record)."""
    pulls, held, hums = analysis.pulls, analysis.held, analysis.hums
    fm_ = ForceModel(pulls, rig.force_chain.m2, hums)
    terms = set(n for n in named if n in TERMS)
    coef, d = fit_terms(fm_, terms, analysis.fit)
    parts = [leftover_part(pulls[j], hums[j] if hums is not None else None, fm_.resid(terms, coef, d, j), rig)
             for j in held]
    return leftover_from(parts, pulls[0].dt)
