"""Discovery: find what the model of record gets wrong in a measured campaign, name the cause from the
departure catalog, fit its parameters, and measure the gain on held-out pulls. ROS-free.

Method (every step is a regression on measured channels; no simulation loop):

1. Per pull, from the measured channels only:
   - T = F_stat + m1 a1 (eq 21/23), a1 from F_stat = K_LC1 u1 + c1 u1' solved in the frequency domain; F_stat,
     F_move and a2 all pass the same zero-phase raised-cosine low-pass (7-9 kHz), so eq 21 holds in the band.
   - carriage motion x3, v3, a3 from the encoder (Savitzky-Golay, 2 ms window).
   - the loaded window (F_stat > 10 % of its peak), the break (last sample with T > 5 % of the peak) and the
     analysis window W = [loaded start - 50 ms, break + 150 ms].
2. Channel "force": the model of record says F_move = T + m2 a2 (ideal sensors). The residual
   r = F_move - T - m2_nom a2 is explained by the linear model
       F_move = g T + (g m) a2(t + d) - (1/tau) C + hum,   C = integral of F_move (AC coupling, exact),
   with d found on a grid (-50 to 200 us, a lead to a lag, in steps of half a sample up to 5 us, parabolic
   refinement; a2 shifted band-limited, as a real delay acts: force_model) and hum = A sin(2 pi f t + phase_pull)
   (f searched 45-65 Hz on the pre-pull record, phase per pull from the pre-pull record).
3. Channel "ringing": after the break T = 0 and, in the carriage frame, a2 - a3 is a free decay. The model of
   record's only mode there is the moving cell on m2 (sqrt(K_LC2/m2), about 3.9 kHz). A dominant lightly damped
   pole well below it (< 0.7 x) is a mount resonance; its frequency and damping are fitted (matrix pencil) and
   mapped back to the mount's (f, zeta) through the 2-DOF carriage-mount-base-cell-m2 model.
4. Channel "current": i kf - m_c a3 - b v3 - F_move (force balance) has an offset F_c sign(v3) for dry friction.
Fitting uses the pulls at even list positions (0, 2, ...), scoring the others (held out). A cause is NAMED when on the
held-out pulls (a) its channel's summed squared residual falls by >= MIN_REL_REDUCTION when the cause is added
to (or kept in) the model, and (b) the per-pull reductions have a t statistic >= MIN_T (one-sided, over held-out
pulls). Each force-channel cause is tested by removing it from the full force model (the others stay fitted).
Ranked by the held-out relative reduction of their channel's squared residual -- strongest first. Left-over
structure (force residual variance in W, below 4 kHz, away from the load/break steps, vs the at-rest floor) with
nothing named gives `unexplained`.
"""
# This module's docstring is the Method section of report.md (markdown.py): keep it the method as run.
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Dict, Optional, Sequence, Tuple

import numpy as np

from force_tester_sim.core.departures import CATALOG

from .candidate import Candidate, Evidence
from .force_model import TERMS, fit_once, force_params, force_params_ci
from .friction import friction_stat, joint_ci
from .ringing import MOUNT_MAX_FRACTION, RingPart, cell_modes, observed_mode
from .significance import significance
from .uncertainty import CONFIDENCE, bootstrap_ci

MIN_PULLS = 4                 # half are fitted, half held out
CATALOG_PARAMS = {name: tuple(params) for name, (_kind, params, _meaning) in CATALOG.items()}


def split(pulls: Sequence):
    """(fitted, held-out) list positions: every other pull."""
    fit = list(range(0, len(pulls), 2))
    held = list(range(1, len(pulls), 2))
    return fit, held


@dataclass(frozen=True)
class PullInfo:
    """A usable pull as the Analysis keeps it (no arrays)."""

    name: str
    dt: float
    samples: int
    w0: int
    w1: int


@dataclass(frozen=True)
class HumScales:
    """Analysis.hums: the hum frequency and the factor on each pull's own hum estimate (hum.hum_per_pull; 1 on a
    fitted pull, the fitted pulls' mean amplitude over the pull's own on a held-out one)."""

    frequency_hz: float
    scales: tuple


@dataclass(frozen=True)
class Analysis:
    """Everything the stages measured (no files, nothing decided yet)."""

    pulls: Tuple[PullInfo, ...]  # per usable pull, in campaign order
    quality: tuple               # PullQuality per campaign pull
    fit: tuple                   # list positions of the fitted pulls
    held: tuple                  # list positions of the held-out pulls
    hums: Optional[HumScales]    # the mains hum when it is significant, else None
    candidates: Dict[str, Candidate]   # catalog name -> what its stage found
    force: dict                  # the full force model: coef, delay_s, held-out SSE
    ring: Optional[dict]         # the observed free-decay mode, its held-out scores and one segment, if any
    notes: tuple = ()
    screens: tuple = ()          # quality.PullScreen per campaign pull (the data-quality stage)
    excluded: dict = field(default_factory=dict)   # pull name -> why the data-quality stage left it out
    cells: Optional[dict] = None  # cells.cell_calibration(): the cells' damping ratio measured, and whether T used it
    friction: Optional[dict] = None   # held-out squared current residuals without/with friction, and their samples
    failed: tuple = ()           # (pull name, one line) per pull whose file could not be read or analysed
    retried: tuple = ()          # names of the pulls rerun because a worker died under them
    scheduler: str = ''          # where the per-pull stages ran

    @property
    def fitted_pulls(self) -> list:
        return [self.pulls[j].name for j in self.fit]

    @property
    def held_out_pulls(self) -> list:
        return [self.pulls[j].name for j in self.held]


FORCE_CHANNEL_TEXT = 'force_moving_n - (T + m2 a2), analysis window'


def hum_candidate(f_hum: float, freqs: Sequence[float], amps: Sequence[float], a_fit: float,
                  fm_h, fm_0, fit, held) -> Tuple[Candidate, bool]:
    """(the mains-hum candidate, whether it is significant) from the hum frequency f_hum, the few pulls' own
    frequencies freqs (hum.hum_frequencies, for its interval), every pull's hum amplitude, and the full force model
    with (fm_h) and without (fm_0) the hum: a ForceModel or a ForceStats."""
    c_h, _, d_h = fm_h.fit_delay(set(TERMS), fit)
    c_0 = fm_0.fit(set(TERMS), fit, d_h).coefficients
    sig = significance(fm_0.sse_per_pull(set(TERMS), c_0, d_h, held), fm_h.sse_per_pull(set(TERMS), c_h, d_h, held))
    alone = significance(fm_0.sse_per_pull(set(), {}, 0.0, held), fm_h.sse_per_pull(set(), {}, 0.0, held)).rms_gain
    ci = {'frequency_hz': list(bootstrap_ci(freqs, np.mean)),
          'amplitude_n': list(bootstrap_ci([amps[k] for k in fit], np.mean))}
    cand = Candidate({'frequency_hz': f_hum, 'amplitude_n': a_fit}, ci, len(fit),
                     dataclasses.replace(sig, rms_gain_alone=alone), FORCE_CHANNEL_TEXT)
    return cand, bool(sig.significant)


def force_stage_from(fm_, fit, held, m2) -> Tuple[Dict[str, Candidate], dict]:
    """The force-channel candidates (each tested by dropping it from the full model) and the full model, from a
    force model: a ForceStats (the pulls' sufficient statistics) or a ForceModel (their arrays)."""
    full = set(TERMS)
    coef_full, _, d_full = fm_.fit_delay(full, fit)
    sse_full = fm_.sse_per_pull(full, coef_full, d_full, held)
    base_sse = fm_.sse_per_pull(set(), {}, 0.0, held)
    params_full = force_params(coef_full, d_full, m2)
    ci = force_params_ci(fm_.loo_fits(full, fit), coef_full, d_full, m2)
    evidence = {}
    for term in TERMS:
        d = 0.0 if term == 'accel_delay' else d_full
        c = fm_.fit(full - {term}, fit, d).coefficients
        sig = significance(fm_.sse_per_pull(full - {term}, c, d, held), sse_full)
        c1, _, d1 = fit_once(fm_, {term}, fit)
        alone = significance(base_sse, fm_.sse_per_pull({term}, c1, d1, held)).rms_gain
        evidence[term] = dataclasses.replace(sig, rms_gain_alone=alone)
    # non-linearity check for the gain: would T^2 explain more than a linear gain?
    t2 = fm_.t2_reduction(coef_full, d_full, fit, held)
    evidence['moving_cell_gain'] = dataclasses.replace(evidence['moving_cell_gain'], t_squared_rel_reduction=t2)
    cand = {term: Candidate(params_full[term], ci[term], len(fit), evidence[term], FORCE_CHANNEL_TEXT)
            for term in TERMS}
    force = {'coef': coef_full, 'delay_s': d_full, 'sse_base_held': base_sse.tolist(),
             'sse_full_held': sse_full.tolist()}
    return cand, force


def ring_stage_from(modes: Sequence[Optional[tuple]], parts: Sequence[Optional[RingPart]], names: Sequence[str],
                    dt: float, fc) -> Tuple[Optional[Candidate], Optional[dict]]:
    """The mount-resonance candidate (None, None without a free-decay mode) from the few fitted pulls'
    free_decay_mode() and the held-out pulls' ring_part() (with the observed_mode() of those modes); names: the
    held-out pulls' names. The mode is identified as it appears in the measured channels (extension.yaml maps it
    to the mount: report's extension())."""
    obs = observed_mode(modes)
    if obs is None:
        return None, None
    modes = [m for m in modes if m is not None]
    fo, zo = obs
    f_cell = cell_modes(fc)[0][0]
    ok = [(n, pt) for n, pt in zip(names, parts) if pt is not None]
    b = np.array([pt.sse_base for _, pt in ok])
    e = np.array([pt.sse_ext for _, pt in ok])
    r2n = np.array([pt.ring_to_noise for _, pt in ok])
    sig = significance(b, e) if len(ok) >= 2 else Evidence(rel_sse_reduction=0.0, t=0.0, significant=False,
                                                           rms_gain=1.0)
    ci = {'frequency_hz': list(bootstrap_ci([m[0] for m in modes])),
          'damping_ratio': list(bootstrap_ci([m[1] for m in modes]))}
    sig = dataclasses.replace(
        sig, significant=sig.significant and fo < MOUNT_MAX_FRACTION * f_cell,
        observed_frequency_hz=fo, observed_damping_ratio=zo, cell_mode_hz=f_cell,
        frequency_rule=f'observed < {MOUNT_MAX_FRACTION} x cell mode ({MOUNT_MAX_FRACTION * f_cell:.0f} Hz)',
        ring_to_noise=float(np.median(r2n)) if len(r2n) else 0.0,
        ring_to_noise_ci95=tuple(bootstrap_ci(r2n)) if len(r2n) else (0.0, math.inf))
    cand = Candidate({'frequency_hz': fo, 'damping_ratio': zo}, ci, len(ok), sig,
                     'accel_axial - a3(encoder), 0.2-30 ms after the break')
    first = next(((n, pt) for n, pt in ok if pt.segment is not None), (None, None))
    ring = {'fo': fo, 'zo': zo, 'segment': first[1].segment if first[1] else None, 'segment_pull': first[0],
            'segment_dt': dt, 'sse_base': [pt.own_base for _, pt in ok], 'sse_ext': [pt.own_ext for _, pt in ok],
            'samples': [pt.samples for _, pt in ok]}
    return cand, ring


def friction_candidate(rows: np.ndarray, fcf: float, b: np.ndarray, e: np.ndarray, n_fit: int,
                       joint: bool = False, viscous: Optional[float] = None,
                       force_per_amp: Optional[float] = None) -> Candidate:
    """The coulomb-friction candidate from the fitted pulls' friction_row()s, their statistic fcf (friction_stat;
    joint: fitted with the viscous damping, its interval the line's, else a bootstrap over pulls), and the held-out
    pulls' friction_sse() without (b) and with (e) it; viscous: the drive's viscous damping the joint fit measured
    (evidence; None: the rig YAML's was used); force_per_amp: the drive's force per amp the pulls calibrated
    (friction.drive_calibration; evidence, None: the rig YAML's)."""
    ev = dataclasses.replace(significance(b, e), viscous_damping_n_s_per_m=viscous,
                             drive_force_per_amp_n_per_a=force_per_amp)
    ci = joint_ci(rows, CONFIDENCE) if joint else bootstrap_ci(rows, friction_stat)
    return Candidate({'force_n': fcf}, {'force_n': list(ci)}, n_fit, ev,
                     'motor_current_a - force balance (i kf = m_c a3 + b v3 + F_move)')


def unusable_analysis(usable: int, total: int, quality: tuple, screens: tuple, excluded: dict, **run) -> Analysis:
    """The analysis when the data-quality stage leaves fewer than MIN_PULLS pulls: nothing fitted, a note why."""
    return Analysis((), quality, (), (), None, {}, {}, None,
                    (f'{usable} of {total} pulls are usable after the data-quality screen; '
                     f'at least {MIN_PULLS} are needed',), screens, excluded, **run)


def candidate_notes(cand: Dict[str, Candidate], mount: Optional[Candidate],
                    friction: Optional[Candidate]) -> Tuple[Dict[str, Candidate], list]:
    """(cand with the mount and friction candidates added when there are, the notes on the ones that could not be
    tested)."""
    notes, more = [], {}
    if mount is None:
        notes.append('no free decay after the break to analyse for a mount resonance')
    else:
        more['mount_resonance'] = mount
    if friction is None:
        notes.append('coulomb_friction not tested: the data has no motor_current_a channel')
    else:
        more['coulomb_friction'] = friction
    return {**cand, **more}, notes
