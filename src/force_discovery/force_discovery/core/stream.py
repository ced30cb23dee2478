"""The driver: discover() with the pulls streamed (issue 16): memory does not grow with the number of pulls.
ROS-free.

Each pull is read, prepared and reduced to a few small results, one pull at a time per worker, and only those
results meet: the decision needs per-pull
numbers (quality verdicts, free-decay ratios, hum amplitudes, friction offsets, squared residuals), the force
model's sufficient statistics (force_stats.py) and a few arrays of a few pulls (the hum's pre-pull records of
up to 12 fitted pulls, one free-decay segment and one pull's residuals and traces for the plots). The arithmetic
is the stages' (stages.py: hum_candidate, force_stage_from, ring_stage_from, friction_candidate; leftover_part,
error_part, resim_pull); the force model's fits are made from the statistics (force_stats.ForceStats) instead of
the stacked samples (force_model.ForceModel). tests/force_discovery/one_pass.py does the same work with every pull
in memory: the oracle the stream is checked against (to rounding: the order of the additions differs).

The per-pull work is four passes, each a top-level function of (pull, small settings) mapped over the pulls with
the campaign engine (force_tester_common.engine.map_pulls: Dask, or inline); a pass needs what the earlier ones
found over the whole campaign:

1. ``survey`` (every pull): read, check, screen and prepare it; its data-quality verdict and window, its friction
   offsets. The prepared pull is spilled to a scratch folder (one .npz per pull, removed at the end) so the later
   passes need not parse its file again -- not with a scheduler of your own, whose workers may not share this
   machine's disk: they read the pull again.
   -> the usable pulls, fitted/held-out split, the friction force.
   ``cell_record`` (the first usable pulls, 16 at a time until the calibrations have theirs): the cells' damping
   ratio from the pull's free decay.
   -> the cells' calibration (T uses it from here on).
2. ``hum_record`` (up to 12 fitted pulls): the pre-pull residual and the free-decay mode.
   -> the hum frequency, the observed free-decay mode.
3. ``pull_stats`` (every usable pull): the hum amplitude, the force model's statistics; held-out pulls: the free
   decay and the current residual scored.
   -> every candidate, then decide().
4. ``held_out`` (the held-out pulls): the structure check's share and spectrum, the force errors, and the
   re-simulation with and without the extension; added up as they arrive (in pull order), not kept.

A pull whose file cannot be read or analysed in pass 1 is left out and listed by name (report.json
failed_pulls); pulls rerun because their worker died are listed too (retried_pulls). A pull that passed pass 1
and fails later stops the discovery (DiscoveryError naming it).
"""
from __future__ import annotations

import dataclasses
import os
import shutil
import tempfile
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Callable, Optional, Sequence

import numpy as np

from force_tester_sim.core.departures import departures_from_data
from force_tester_sim.core.extra_terms import extra_terms_from_data

from . import beyond as bey
from .budget import (
    clock_relative,
    force_systematics,
    force_variants,
    friction_systematics,
    friction_variants,
    honest_all,
    load_dependence,
    load_groups,
    pull_to_pull_parts,
    rate_stat_u,
    statistical_u,
    variant_pulls,
)
from .cells import (
    CAL_PULLS,
    calibration_note,
    cell_calibration,
    cell_damping_from,
    cell_frequency_from,
    cell_mode,
    with_tension,
)
from .decision import Decision, decide
from .errors import DiscoveryError
from .extension import add_extra_terms, named_extension
from .force_errors import ErrorPart, ForceErrors, error_part
from .force_model import TERMS, ForceModel, fit_terms
from .force_stats import ForceStats, force_blocks
from .free import discover_free
from .friction import (
    friction_row,
    friction_rows,
    friction_sse,
    friction_stat,
    viscous_departure,
    viscous_separable,
    viscous_u,
)
from .hum import few_pulls, hum_frequencies, hum_frequency_from, hum_per_pull, hum_scale, pre_residual
from .identifiability import check_core_channels, full_identifiability, needs_reference_free
from .leftover import LeftoverPart, LeftoverSum, leftover_part
from .outputs import write_outputs
from .prep import Pull, PullQuality, check_quality, prepare
from .quality import PullScreen, screen_pull
from .report import add_beyond, add_simulation, build_report, unusable_report
from .resim import ResimPart, ResimSetup, ResimSum, resim_pull, resim_setup
from .ringing import RingPart, cell_modes, free_decay_mode, observed_mode, ring_part
from .source import PullRef, campaign_absent, campaign_refs, load_channels, memory_refs, rated_ranges
from .stages import (
    MIN_PULLS,
    Analysis,
    HumScales,
    PullInfo,
    candidate_notes,
    force_stage_from,
    friction_candidate,
    hum_candidate,
    ring_stage_from,
    split,
    unusable_analysis,
)

TRACE_PULLS = 2    # held-out pulls (the first ones) that keep their residuals and traces for the plots
SPILL_ARRAYS = ('t', 'fm', 'fs', 'a2', 'T', 'x3', 'v3', 'a3', 'current', 'ok')
SPILL_SCALARS = ('dt', 'w0', 'w1', 'pre1', 'load0', 'brk', 'peak')


# ------------------------------------------------------------------------------------------ per-pull results
@dataclass(frozen=True)
class Survey:
    """What pass 1 found in one pull."""

    name: str
    quality: Optional[PullQuality] = None
    screen: Optional[PullScreen] = None
    rejected: Optional[str] = None     # the pull is not analysable (DiscoveryError): the campaign stops
    excluded: Optional[str] = None     # why the data-quality screen leaves it out
    info: Optional[PullInfo] = None
    friction: Optional[tuple] = None   # friction.friction_row
    spill: Optional[str] = None        # where the prepared pull was spilled
    friction_variants: Optional[dict] = None   # budget.friction_variants: the row with each drive constant off


@dataclass(frozen=True)
class HumRecord:
    """Pass 2, one of the few fitted pulls: its pre-pull residual (t, r) and its free-decay mode."""

    t: np.ndarray
    r: np.ndarray
    mode: Optional[tuple]


@dataclass(frozen=True)
class StatsJob:
    """Pass 3's settings for one pull."""

    f_hum: float
    held: bool
    dt: float                           # the campaign's sample interval (the first usable pull's)
    fcf: Optional[float] = None         # the friction force (held-out pulls with a current channel)
    db: float = 0.0                     # ... and the viscous damping's departure fitted with it (friction.py)
    mode: Optional[tuple] = None        # the observed free-decay mode (held-out pulls, when there is one)
    variants: bool = False              # also the force statistics under budget.force_variants (a few fitted pulls)
    fcal: Optional[tuple] = None        # ... with the measured cell frequency (cells.cell_frequency_from)


@dataclass(frozen=True)
class PullStats:
    """Pass 3, one pull: hum amplitude, force statistics; held-out pulls: current and free decay scored."""

    amp: float
    dt: float
    blocks: np.ndarray
    friction: Optional[tuple] = None    # (squared current residual without, with the friction)
    ring: Optional[RingPart] = None
    variants: Optional[dict] = None     # budget variant name -> its force_blocks


@dataclass(frozen=True)
class HeldJob:
    """Pass 4's settings for one held-out pull: the hum, the two force fits to take residuals of, the re-simulation."""

    f_hum: float
    left_scale: Optional[float]         # hum factor for the structure check (None: no hum)
    err_scale: Optional[float]          # ... for the extended force error
    left_fit: tuple                     # (terms, coefficients, delay) for the structure check
    err_fit: tuple                      # ... for the extended force error
    keep: bool                          # keep residuals and traces (plots)
    setup: Optional[ResimSetup]


@dataclass(frozen=True)
class BeyondJob:
    """The search beyond the catalog (core/beyond/), one pull: the residuals after the named causes."""

    f_hum: float
    hum_scale: Optional[float]          # the hum estimate's factor (None: the hum is not named)
    err_fit: tuple                      # (terms, coefficients, delay) of the named force-channel causes
    coulomb: Optional[float]            # the named Coulomb friction (N), or None
    survey: Optional[bey.Survey]        # None: the spectrum pass (a few fitted pulls); else the statistics
    sensors: tuple = ()                 # terms found on the sensors on their own (beyond.sensor_corrected)
    records: bool = False               # the spectrum pass keeps the residual's samples (beyond.REFINE_PULLS pulls)


@dataclass(frozen=True)
class HeldOut:
    """Pass 4, one held-out pull."""

    leftover: LeftoverPart
    errors: ErrorPart
    resim: Optional[ResimPart]


@dataclass(frozen=True)
class Source:
    """Where a pass gets a pull: the survey's spill, else the pull's data again."""

    ref: PullRef
    spill: Optional[str] = None


# ------------------------------------------------------------------------------------------ loading
def _write_spill(p: Pull, path: str) -> None:
    arrays = {k: getattr(p, k) for k in SPILL_ARRAYS if getattr(p, k) is not None}
    with open(path, 'wb') as fh:
        np.savez(fh, name=np.array(p.name), scalars=np.array([float(getattr(p, k)) for k in SPILL_SCALARS]),
                 **arrays)


def _read_spill(path: str) -> Pull:
    with np.load(path) as z:
        sc = dict(zip(SPILL_SCALARS, z['scalars'].tolist()))
        arrays = {k: (z[k] if k in z.files else None) for k in SPILL_ARRAYS}
        name = str(z['name'])
    ints = {k: int(sc[k]) for k in ('w0', 'w1', 'pre1', 'load0', 'brk')}
    return Pull(name, arrays['t'], sc['dt'], arrays['fm'], arrays['fs'], arrays['a2'], arrays['T'], arrays['x3'],
                  arrays['v3'], arrays['a3'], arrays['current'], peak=sc['peak'], ok=arrays['ok'], **ints)


def prepare_ref(ref: PullRef, rig):
    """(PullQuality, PullScreen, Pull) of one pull from its data (DiscoveryError when it cannot be analysed)."""
    meta, ch = load_channels(ref)
    q = check_quality(meta, ch)
    sc = screen_pull(q.name, ch, rated_ranges(ref))
    return q, sc, prepare(meta, ch, rig, q, sc)


def load_pull(src: Source, rig, c1: Optional[tuple]) -> Pull:
    """The prepared pull (from the spill when there is one), T with the cells' calibration c1 (cells.with_tension's
    (K_LC1, c1); None: the rig's)."""
    p = _read_spill(src.spill) if src.spill is not None and os.path.exists(src.spill) else prepare_ref(src.ref, rig)[2]
    return with_tension(p, rig, c1)


# ------------------------------------------------------------------------------------------ the passes
def survey(item) -> Survey:
    """Pass 1: item = (PullRef, rig, spill path or None)."""
    ref, rig, spill = item
    try:
        q, sc, p = prepare_ref(ref, rig)
    except DiscoveryError as exc:
        return Survey(ref.name, rejected=str(exc))
    why = sc.exclusion(p.w0, p.w1)
    info = PullInfo(p.name, p.dt, len(p.t), p.w0, p.w1)
    if why:
        return Survey(p.name, q, sc, excluded=why, info=info)
    if spill is not None:
        _write_spill(p, spill)
    return Survey(p.name, q, sc, None, None, info, friction_row(p, rig), spill, friction_variants(p, rig))


def cell_record(item) -> Optional[tuple]:
    """Pass 1b: item = (Source, rig); cells.cell_mode of the pull (its T does not matter)."""
    src, rig = item
    return cell_mode(load_pull(src, rig, None), rig)


def hum_record(item) -> HumRecord:
    """Pass 2: item = (Source, rig, c1)."""
    src, rig, c1 = item
    p = load_pull(src, rig, c1)
    t, r = pre_residual(p, rig.force_chain.m2)
    return HumRecord(t, r, free_decay_mode(p))


def pull_stats(item) -> PullStats:
    """Pass 3: item = (Source, rig, c1, StatsJob)."""
    src, rig, c1, job = item
    p = load_pull(src, rig, c1)
    amp, hum = hum_per_pull(p, job.f_hum, rig.force_chain.m2)
    friction = ring = None
    if job.held and job.fcf is not None and p.current is not None:
        friction = (friction_sse(p, rig, 0.0, job.db), friction_sse(p, rig, job.fcf, job.db))
    if job.held and job.mode is not None:
        ring = ring_part(p, job.dt, cell_modes(rig.force_chain), job.mode, keep=True)
    variants = None
    if job.variants:
        variants = {name: force_blocks(v, hum) for name, v in force_variants(p, rig, c1, job.fcal).items()}
    return PullStats(amp, p.dt, force_blocks(p, hum), friction, ring, variants)


def held_out(item) -> HeldOut:
    """Pass 4: item = (Source, rig, c1, HeldJob)."""
    src, rig, c1, job = item
    p = load_pull(src, rig, c1)
    m2 = rig.force_chain.m2
    hum = None
    if job.left_scale is not None or job.err_scale is not None:
        hum = hum_per_pull(p, job.f_hum, m2)[1]
    h_left = None if job.left_scale is None else hum * job.left_scale
    h_err = None if job.err_scale is None else hum * job.err_scale
    terms, coef, d = job.left_fit
    left = leftover_part(p, h_left, ForceModel([p], m2, [h_left]).resid(set(terms), coef, d, 0), rig)
    terms, coef, d = job.err_fit
    err = error_part(p, ForceModel([p], m2).resid(set(), {}, 0.0, 0),
                       ForceModel([p], m2, [h_err]).resid(set(terms), coef, d, 0), keep=job.keep)
    sim = resim_pull(p, job.setup, trace=job.keep) if job.setup is not None else None
    return HeldOut(left, err, sim)


def beyond_pass(item, series: bool = False):
    """Pass 5 (core/beyond/): item = (Source, rig, c1, BeyondJob); the pull's residual spectra (job.survey None) or
    its library statistics (series=True: its beyond.channel_series)."""
    src, rig, c1, job = item
    p = load_pull(src, rig, c1)
    if job.sensors:
        p = bey.sensor_corrected(p, job.sensors, rig, c1)
    m2 = rig.force_chain.m2
    h = None if job.hum_scale is None else hum_per_pull(p, job.f_hum, m2)[1] * job.hum_scale
    terms, coef, d = job.err_fit
    fm_ = ForceModel([p], m2, [h])
    r = fm_.resid(set(terms), coef, d, 0)
    causes = {k: fm_.resid(set(terms) - {k}, coef, d, 0) - r for k in terms}   # each cause undone (cause_check)
    if h is not None:
        causes['mains_hum'] = h[p.w0:p.w1]
    out = bey.channel_series(p, rig, r, h, job.coulomb, causes)
    if series:
        return out
    series = out
    if job.survey is None:
        return bey.spectrum_part(series, p.dt * bey.decimation(p.dt), job.records)
    return bey.beyond_part(series, job.survey)


# ------------------------------------------------------------------------------------------ the driver
def map_stage(mapper, fn: Callable, items: Sequence, names: Sequence[str], on_result: Optional[Callable] = None,
              progress: Optional[Callable] = None):
    """The one place discovery maps a per-pull stage over pulls: mapper is force_tester_common.engine's Mapper (or
    map_pulls): results in item order, failures by name; with on_result(index, result), called in item order,
    the results are not kept."""
    return mapper(fn, items, names=list(names), keep=on_result is None, on_result=on_result, progress=progress)


def spills_locally(scheduler: Optional[str]) -> bool:
    """Whether the workers share this machine's disk (the embedded cluster or inline), so a spill helps."""
    from force_tester_common.engine import INLINE, resolve_scheduler
    return resolve_scheduler(scheduler) in (None, INLINE)


def pull_refs(campaign) -> list:
    """PullRefs of a campaign given as a folder (str or Path), [(meta, channels)] or [PullRef]."""
    if isinstance(campaign, (str, os.PathLike)):
        return campaign_refs(campaign)
    campaign = list(campaign)
    if campaign and all(isinstance(r, PullRef) for r in campaign):
        return campaign
    return memory_refs(campaign)


class Stream:
    """One streamed discovery: the passes in order (analyse, then held_out_results) and what they keep between
    them (the pulls' small results and where to find each pull again)."""

    def __init__(self, campaign, rig, mapper=None, spill_dir: Optional[str] = None,
                 progress: Optional[Callable[[str, int, int], None]] = None):
        from force_tester_common.engine import Mapper
        self.refs = pull_refs(campaign)
        self.rig = rig
        self.mapper = Mapper() if mapper is None else mapper
        self.spill_dir = spill_dir
        self.progress = progress
        self.failed, self.retried, self.where = [], [], ''

    def _map(self, stage: str, fn, items, names, on_result=None):
        prog = (lambda done, total: self.progress(stage, done, total)) if self.progress else None
        out = map_stage(self.mapper, fn, items, names, on_result, prog)
        self.where = out.scheduler
        self.retried += [n for n in out.retried if n not in self.retried]
        return out

    def _strict(self, stage: str, out):
        if out.failed:
            name, why = out.failed[0]
            raise DiscoveryError(f'pull {name!r} failed in the {stage} stage after passing the data-quality screen '
                                 f'({why}); expected every usable pull to finish it')
        return out.results

    def analyse(self) -> Analysis:
        """Passes 1-3: every stage's candidates (stages.py), nothing decided yet."""
        refs, rig = self.refs, self.rig
        if len(refs) < MIN_PULLS:
            raise DiscoveryError(f'campaign has {len(refs)} pulls; expected at least {MIN_PULLS} '
                                 '(half are fitted, half held out)')
        spills = [None if self.spill_dir is None else str(Path(self.spill_dir) / f'{i:06d}.npz')
                  for i in range(len(refs))]
        out = self._map('survey', survey, [(r, rig, s) for r, s in zip(refs, spills)], [r.name for r in refs])
        self.failed = list(out.failed)
        surveys = [s for s in out.results if s is not None]
        where = {id(s): i for i, s in enumerate(out.results) if s is not None}
        rejected = next((s for s in surveys if s.rejected), None)
        if rejected is not None:
            raise DiscoveryError(rejected.rejected)
        quality = tuple(s.quality for s in surveys)
        dts = {round(q.dt, 12) for q in quality}
        if len(dts) > 1:
            raise DiscoveryError(f'pulls have different sample intervals {sorted(dts)}; expected one rate')
        screens = tuple(s.screen for s in surveys)
        excluded = {s.name: s.excluded for s in surveys if s.excluded}
        usable = [s for s in surveys if not s.excluded]
        run = {'failed': tuple(self.failed), 'retried': tuple(self.retried), 'scheduler': self.where}
        if len(usable) < MIN_PULLS:
            out = unusable_analysis(len(usable), len(refs), quality, screens, excluded, **run)
            if self.failed:
                out = dataclasses.replace(out, notes=out.notes + (f'{len(self.failed)} pulls could not be read or '
                                                                  'analysed (failed_pulls)',))
            return out
        self.sources = [Source(refs[where[id(s)]], s.spill) for s in usable]
        self.usable = usable
        names = [s.name for s in usable]
        m2 = rig.force_chain.m2
        fit, held = split(usable)
        held_set = set(held)
        notes = []
        modes_cell = self._cell_zetas(names, held)
        self.zetas = [None if m is None else m[1] for m in modes_cell]
        fcal = cell_frequency_from(modes_cell)
        self.c1, cells = cell_calibration(cell_damping_from(self.zetas), rig, fcal)
        if calibration_note(cells):
            notes.append(calibration_note(cells))
        dt = usable[0].info.dt
        self.dt = dt
        rows = friction_rows(usable[j].friction for j in fit)
        joint = viscous_separable(rows, viscous_u(rig))
        fcf = None if rows is None else friction_stat(rows, joint)
        db = viscous_departure(rows, joint)
        # pass 2: the few fitted pulls' pre-pull records and free-decay modes
        few = few_pulls(fit)
        recs = self._strict('hum', self._map('hum', hum_record, [(self.sources[j], rig, self.c1) for j in few],
                                             [names[j] for j in few]))
        pres = [(r.t, r.r) for r in recs]
        f_hum, _power = hum_frequency_from(pres, usable[few[0]].info.dt)
        hum_freqs = hum_frequencies(pres, f_hum)
        modes = [r.mode for r in recs]
        mode = observed_mode(modes)
        del recs
        # pass 3: every usable pull's statistics
        stats, kept = [None] * len(usable), []

        def keep(i, st):   # one free-decay segment is kept (the plot's), the others dropped as they arrive
            if st.ring is not None and st.ring.segment is not None:
                if kept:
                    st = dataclasses.replace(st, ring=dataclasses.replace(st.ring, segment=None))
                kept.append(i)
            stats[i] = st
        vpulls = set(variant_pulls(fit))
        jobs = [StatsJob(f_hum, j in held_set, dt, fcf if j in held_set else None, db,
                         mode if j in held_set else None, j in vpulls, fcal) for j in range(len(usable))]
        self._strict('statistics', self._map('statistics', pull_stats,
                                             [(src, rig, self.c1, job) for src, job in zip(self.sources, jobs)], names,
                                             on_result=keep))
        amps = [st.amp for st in stats]
        a_fit = float(np.mean([amps[k] for k in fit]))
        scales = [hum_scale(amps, a_fit, j) if j in held_set else 1.0 for j in range(len(usable))]
        blocks, dts_ = [st.blocks for st in stats], [st.dt for st in stats]
        fm_h, fm_0 = ForceStats(blocks, dts_, m2, scales), ForceStats(blocks, dts_, m2)
        hum, significant = hum_candidate(f_hum, hum_freqs, amps, a_fit, fm_h, fm_0, fit, held)
        self.f_hum, self.scales = f_hum, scales
        self.fm_h, self.fm_0 = fm_h, fm_0
        force_cand, force = force_stage_from(fm_h if significant else fm_0, fit, held, m2)
        mount, ring = ring_stage_from(modes, [stats[j].ring for j in held], [names[j] for j in held], dt,
                                        rig.force_chain) if mode is not None else (None, None)
        friction = friction_sses = None
        if fcf is not None and all(stats[j].friction is not None for j in held):
            b = [stats[j].friction[0] for j in held]
            e = [stats[j].friction[1] for j in held]
            friction = friction_candidate(rows, fcf, np.array(b), np.array(e), len(fit), joint,
                                          rig.drive.viscous_damping_n_s_per_m + db if joint else None)
            friction_sses = {'sse_base': b, 'sse_ext': e, 'samples': [usable[j].info.samples for j in held]}
        cand, more = candidate_notes({'mains_hum': hum, **force_cand}, mount, friction)
        notes += more
        sys_ = systematics(cand, stats, fit, [s.quality.peak_n for s in usable], scales if significant else None, m2,
                           modes, rows, [usable[j].friction_variants for j in fit], force['delay_s'], joint,
                           hum_freqs)
        cand = honest_all(cand, sys_, clock_relative(rig))
        infos = tuple(s.info for s in usable)
        hums = HumScales(f_hum, tuple(scales)) if significant else None
        run = {'failed': tuple(self.failed), 'retried': tuple(self.retried), 'scheduler': self.where}
        return Analysis(infos, quality, tuple(fit), tuple(held), hums, cand, force, ring, tuple(notes), screens,
                          excluded, cells, friction_sses, **run)

    def _cell_zetas(self, names, held) -> list:
        """cells.cell_mode of the usable pulls in order, as far as the calibrations need them: until CAL_PULLS
        were measured over all pulls and over the held-out ones (cell_damping_from takes the first CAL_PULLS), in
        batches of 2 CAL_PULLS pulls."""
        zetas, held = [], list(held)
        while len(zetas) < len(self.sources):
            found = [z for z in zetas if z is not None]
            held_found = [zetas[j] for j in held if j < len(zetas) and zetas[j] is not None]
            if len(found) >= CAL_PULLS and (len(held_found) >= CAL_PULLS or held[-1] < len(zetas)):
                break
            todo = range(len(zetas), min(len(self.sources), len(zetas) + 2 * CAL_PULLS))
            zetas += self._strict('cells', self._map('cells', cell_record, [(self.sources[j], self.rig) for j in todo],
                                                     [names[j] for j in todo]))
        return zetas

    def err_fit(self, analysis: Analysis, decision: Decision) -> tuple:
        """(hum on for the extended force error, (terms, coefficients, delay)) of the named force-channel causes."""
        terms = set(n for n in decision.named if n in TERMS)
        err_hum = analysis.hums is not None and 'mains_hum' in decision.named
        return err_hum, (frozenset(terms), *fit_terms(self.fm_h if err_hum else self.fm_0, terms, analysis.fit))

    def beyond(self, analysis: Analysis, decision: Decision) -> bey.BeyondResult:
        """Pass 5: the search beyond the catalog (core/beyond/) on the residuals the named causes leave: the residual
        spectra of a few fitted pulls, then every usable pull's library statistics."""
        import time
        t0 = time.perf_counter()
        err_hum, fit_ = self.err_fit(analysis, decision)
        fcf = None
        if 'coulomb_friction' in decision.named:
            fcf = analysis.candidates['coulomb_friction'].parameters['force_n']
        names = [p.name for p in analysis.pulls]

        def job(j, survey, sensors=(), records=False):
            return (self.sources[j], self.rig, self.c1,
                    BeyondJob(self.f_hum, self.scales[j] if err_hum else None, fit_, fcf, survey, sensors, records))
        few = few_pulls(analysis.fit)
        jobs = [job(j, None, records=i < bey.REFINE_PULLS) for i, j in enumerate(few)]
        specs = self._strict('beyond', self._map('beyond', beyond_pass, jobs, [names[j] for j in few]))
        dt = analysis.pulls[0].dt
        survey = bey.survey_from(specs, dt * bey.decimation(dt))
        parts = self._strict('beyond', self._map('beyond', beyond_pass,
                                                 [job(j, survey) for j in range(len(names))], names))
        res = bey.search(parts, analysis.fit, analysis.held, survey, self.rig, decision.named)
        sensors = tuple(t for t in res.terms if t.channel in bey.SENSORS)
        if sensors:   # the moving cell and the current again, against what the sensors read without their terms
            parts = self._strict('beyond', self._map('beyond', beyond_pass,
                                                     [job(j, survey, sensors) for j in range(len(names))], names))
            rest = bey.search(parts, analysis.fit, analysis.held, survey, self.rig, decision.named,
                              channels=tuple(c for c in bey.SEARCHED if c not in bey.SENSORS), sensors=True)
            keep = [t for t in res.terms if t.channel in bey.SENSORS]
            res = dataclasses.replace(
                res, terms=tuple(sorted(keep + list(rest.terms), key=lambda t: -t.rel_sse_reduction)),
                within_tolerance=tuple(t for t in res.within_tolerance if t.channel in bey.SENSORS)
                + rest.within_tolerance, demoted=rest.demoted)
        traces = ()
        if res.terms:   # one held-out pull's residuals before and after each term (the plots)
            j = analysis.held[0]
            series = beyond_pass(job(j, survey), series=True)
            if sensors:   # the sensors' residuals as they were, the others' against the corrected sensors
                series = {**beyond_pass(job(j, survey, sensors), series=True),
                          **{c: series[c] for c in bey.SENSORS if c in series}}
            traces = bey.term_traces(series, res.terms, names[j])
        return dataclasses.replace(res, seconds=time.perf_counter() - t0, traces=traces)

    def held_out_results(self, analysis: Analysis, decision: Decision, ext: dict):
        """Pass 4: (structure check, ForceErrors, SimulationCheck or the DiscoveryError that stopped it)."""
        rig, held, fit = self.rig, analysis.held, analysis.fit
        hum_on = analysis.hums is not None
        left_fit = (frozenset(TERMS), *fit_terms(self.fm_h if hum_on else self.fm_0, set(TERMS), fit))
        err_hum, err_fit = self.err_fit(analysis, decision)
        cal = cell_damping_from(self.zetas[j] for j in held if j < len(self.zetas))
        setup = resim_setup(rig, departures_from_data(ext['departures']), cal,
                            extra_terms_from_data(ext.get('extra_terms')))
        jobs = [HeldJob(self.f_hum, self.scales[j] if hum_on else None, self.scales[j] if err_hum else None,
                        left_fit, err_fit, k < TRACE_PULLS, setup) for k, j in enumerate(held)]
        lsum, errors, sims = LeftoverSum(), ForceErrors(), ResimSum(setup)

        def add(k, res):
            lsum.add(res.leftover)
            errors.add(res.errors)
            sims.add(k, res.resim)
        self._strict('held-out', self._map('held-out', held_out,
                                           [(self.sources[j], rig, self.c1, job) for j, job in zip(held, jobs)],
                                           [analysis.pulls[j].name for j in held], on_result=add))
        if sims.keep is not None and not sims.trace:   # the first pull re-simulated came after the traced ones
            j = held[sims.keep]
            sims.trace = resim_pull(load_pull(self.sources[j], rig, self.c1), setup, trace=True).trace
        try:
            check = sims.result()
        except DiscoveryError as exc:
            check = exc
        return lsum.result(self.dt), errors, check


def discover_stream(campaign, rig, out_dir, scheduler: Optional[str] = None,
                    progress: Optional[Callable[[str, int, int], None]] = None, mapper=None) -> dict:
    """discover() with the pulls streamed (module docstring): campaign is a folder, [(meta, channels)] or
    [PullRef]; scheduler: where the per-pull stages run (force_tester_common.engine: None for $DASK_SCHEDULER_ADDRESS
    or the embedded cluster, 'inline', or tcp://HOST:PORT), or mapper: an engine Mapper to run them (its
    scheduler then); progress(stage, done, total)."""
    from force_tester_common.engine import Mapper
    mapper = Mapper(scheduler) if mapper is None else mapper
    refs = pull_refs(campaign)
    absent = campaign_absent(refs)
    check_core_channels(absent)
    if needs_reference_free(absent):   # no stationary cell or no encoder: what the remaining channels support
        return discover_free(refs, absent, rig, out_dir, mapper, progress)
    if len(refs) < MIN_PULLS:          # too few to fit half and hold half out: the free phases, leave-one-out
        return discover_free(refs, absent, rig, out_dir, mapper, progress, few=MIN_PULLS)
    spill = tempfile.mkdtemp(prefix='ft_discover_spill_') if spills_locally(mapper.scheduler) else None
    try:
        st = Stream(refs, rig, mapper, spill, progress)
        analysis = st.analyse()
        decision = decide(analysis, rig)
        out = Path(out_dir)
        if not analysis.pulls:
            report = unusable_report(analysis, rig)
            write_outputs(report, analysis, None, (), rig, out)
            return report
        found = st.beyond(analysis, decision)
        decision = with_beyond(decision, found)
        if set(found.demoted) & set(bey.CAUSE_PARAMS):   # the force residual changes without the cause: again
            again = st.beyond(analysis, decision)
            found = dataclasses.replace(again, demoted={**found.demoted, **again.demoted},
                                        seconds=found.seconds + again.seconds)
            decision = with_beyond(decision, found)
        ext = named_extension(analysis, decision, rig)
        add_extra_terms(ext, [t.as_dict() for t in found.terms])
        left, errors, check = st.held_out_results(analysis, decision, ext)
        analysis = _with_run(analysis, st)
        report = build_report(analysis, decision, errors, left, rig)
        report['identifiable'], report['not_identifiable'] = full_identifiability(tuple(analysis.candidates))
        if isinstance(check, DiscoveryError):
            report['notes'].append(f'no simulation check: {check}')
            check = None
        add_simulation(report, check)
        add_beyond(report, found)
        write_outputs(report, analysis, errors, decision.named, rig, out, check, ext, found.traces)
        return report
    finally:
        if spill is not None:
            shutil.rmtree(spill, ignore_errors=True)


def systematics(cand: dict, stats: list, fit, peaks, scales, m2: float, modes, rows, rows_v, delay: float,
                joint: bool = False, hum_freqs: Sequence[float] = ()) -> dict:
    """{cause: {parameter: {component: u}}}: the systematic parts of the budgets (budget.py) from pass 3's variant
    statistics and load groups (the force model, at the campaign's delay), the free-decay modes (the mount), the few
    pulls' own hum frequencies and the friction rows (joint: friction_stat's, with the viscous damping fitted)."""
    out: dict = {}
    vidx = [j for j in fit if stats[j].variants is not None]
    if vidx:
        def sub(get):
            return ForceStats([get(stats[j]) for j in vidx], [stats[j].dt for j in vidx], m2,
                              None if scales is None else [scales[j] for j in vidx])
        names = list(stats[vidx[0]].variants)
        fs = force_systematics(sub(lambda st: st.blocks), {n: sub(lambda st, n=n: st.variants[n]) for n in names},
                               range(len(vidx)), m2)
        u_stat = {t: {p: (rate_stat_u(t, cand[t]) if t == 'ac_coupling' else statistical_u(t, cand[t], p))
                      for p in cand[t].parameters} for t in TERMS}
        all_blocks = ForceStats([st.blocks for st in stats], [st.dt for st in stats], m2, scales)
        ld = load_dependence(all_blocks, load_groups(fit, peaks), m2, u_stat, delay)
        for t, params in fs.items():
            for p, comps in params.items():
                out.setdefault(t, {})[p] = {**comps, **({'load_dependence': ld[t][p]} if t in ld else {})}
    out.update(pull_to_pull_parts(cand, modes, hum_freqs))
    if 'coulomb_friction' in cand and rows is not None and all(r is not None for r in rows_v):
        out['coulomb_friction'] = {'force_n': friction_systematics(rows, rows_v, partial(friction_stat, joint=joint))}
    return out


def with_beyond(decision: Decision, found: bey.BeyondResult) -> Decision:
    """The decision with the catalog causes a library term fits better (beyond.selection.search_channel) withheld."""
    new = {n: why for n, why in found.demoted.items() if n not in decision.rejected}
    if not new:
        return decision
    named = tuple(n for n in decision.named if n not in new)
    return dataclasses.replace(decision, named=named, rejected={**decision.rejected, **new},
                               notes=decision.notes + tuple(f'{n} withheld: {why}' for n, why in new.items()))


def _with_run(analysis: Analysis, st: Stream) -> Analysis:
    return dataclasses.replace(analysis, failed=tuple(st.failed), retried=tuple(st.retried), scheduler=st.where)


__all__ = ['Stream', 'beyond_pass', 'discover_stream', 'held_out', 'hum_record', 'load_pull',
           'map_stage', 'pull_stats', 'survey']
