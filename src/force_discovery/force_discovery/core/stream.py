"""The driver: the passes of a discovery with the pulls streamed: memory does not grow with the number of pulls.
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

The per-pull work is four passes (passes.py), each a top-level function of (pull, small settings) mapped over the
pulls with the campaign engine (force_tester_common.engine.map_pulls: Dask, or inline); a pass needs what the
earlier ones found over the whole campaign:

1. ``read_pass`` (every pull): read, check, screen and prepare it; its data-quality verdict and window, its friction
   offsets. The prepared pull is spilled to a scratch folder (one pickle per pull, removed at the end) so the later
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
from pathlib import Path
from typing import Callable, Optional, Sequence

import numpy as np

from force_tester_sim.core.departures import departures_from_data
from force_tester_sim.core.extra_terms import extra_terms_from_data

from . import beyond as bey
from .budget import (
    campaign_systematics,
    clock_relative,
    filter_form_parts,
    filter_form_preferred,
    honest_all,
    variant_pulls,
)
from .cells import (
    CAL_PULLS,
    calibration_note,
    cell_calibration,
    cell_damping_from,
    cell_frequency_from,
)
from .decision import Decision
from .errors import DiscoveryError
from .force_errors import ForceErrors
from .force_model import TERMS, fit_terms
from .force_stats import ForceStats
from .friction import (
    calibrated_rows,
    drive_calibration,
    drive_lines,
    friction_rows,
    friction_stat,
    impulse_form,
    impulse_rows,
    impulse_variants,
    viscous_departure,
    viscous_separable,
    viscous_u,
)
from .hum import few_pulls, hum_form_parts, hum_frequencies, hum_frequency_from, hum_scale
from .leftover import LeftoverSum
from .passes import (
    BEYOND_NUISANCE,
    BeyondJob,
    HeldJob,
    Source,
    StatsJob,
    beyond_pass,
    cell_record,
    form_stats,
    held_out,
    hum_record,
    load_pull,
    pull_stats,
    read_pass,
)
from .resim import ResimSum, resim_pull, resim_setup
from .ringing import observed_mode
from .source import PullRef, campaign_refs, memory_refs
from .stages import (
    MIN_PULLS,
    Analysis,
    HumScales,
    candidate_notes,
    force_stage_from,
    friction_candidate,
    hum_candidate,
    ring_stage_from,
    split,
    unusable_analysis,
)

TRACE_PULLS = 2    # held-out pulls (the first ones) that keep their residuals and traces for the plots


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
        spills = [None if self.spill_dir is None else str(Path(self.spill_dir) / f'{i:06d}.pkl')
                  for i in range(len(refs))]
        out = self._map('read', read_pass, [(r, rig, s) for r, s in zip(refs, spills)], [r.name for r in refs])
        self.failed = list(out.failed)
        reads = [s for s in out.results if s is not None]
        where = {id(s): i for i, s in enumerate(out.results) if s is not None}
        rejected = next((s for s in reads if s.rejected), None)
        if rejected is not None:
            raise DiscoveryError(rejected.rejected)
        quality = tuple(s.quality for s in reads)
        dts = {round(q.dt, 12) for q in quality}
        if len(dts) > 1:
            raise DiscoveryError(f'pulls have different sample intervals {sorted(dts)}; expected one rate')
        screens = tuple(s.screen for s in reads)
        excluded = {s.name: s.excluded for s in reads if s.excluded}
        usable = [s for s in reads if not s.excluded]
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
        impulse = impulse_form(rows, rig)   # the drive's balance over windows, where the data support only it
        rows_v = [usable[j].friction_variants for j in fit]
        if impulse:
            rows = impulse_rows(rows)
            rows_v = impulse_variants(rows_v)
        drive = drive_calibration(rows, rig)   # the drive's force per amp the data settle (friction.py), or None
        raw = None if rows is None else calibrated_rows(rows, False)
        drive_u = None if drive is None else drive_lines(rows, drive, raw, rig, impulse)   # the friction's lines
        rows = None if rows is None else calibrated_rows(rows, drive is not None)
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
        hum_form = hum_form_parts(pres, f_hum)
        modes = [r.mode for r in recs]
        mode_variants = [r.mode_variants for r in recs]
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
        fit_scales = scales if significant else None   # the hum's per-pull scales where the hum is fitted
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
                                          rig.drive.viscous_damping_n_s_per_m + db if joint else None,
                                          None if drive is None else drive[0])
            friction_sses = {'sse_base': b, 'sse_ext': e, 'samples': [usable[j].info.samples for j in held]}
        cand, more = candidate_notes({'mains_hum': hum, **force_cand}, mount, friction)
        notes += more
        # the accelerometer's delay filter-shaped (the data prefer it to a shift): the filter form's fit is the estimate
        form = filter_form_preferred(stats, fit, m2, fit_scales)
        if form:
            fstats = self._strict('statistics', self._map('statistics', form_stats,
                                                          [(src, rig, self.c1, job) for src, job in zip(self.sources,
                                                                                                        jobs)], names))
            form_cand, _ = force_stage_from(ForceStats([s.blocks for s in fstats], dts_, m2,
                                                       fit_scales), fit, held, m2)
            form_line = filter_form_parts(stats, fstats, fit, m2, fit_scales)
            # the budget's force-model lines from the filter form's statistics too
            stats = [dataclasses.replace(st, blocks=f.blocks, variants=f.variants) for st, f in zip(stats, fstats)]
            cand = {**cand, **{t: dataclasses.replace(cand[t], parameters=form_cand[t].parameters,
                                                      parameters_ci95=form_cand[t].parameters_ci95) for t in TERMS}}
            notes.append('the accelerometer\'s delay is fitted as a 2-pole Bessel filter, not a shift: the data prefer '
                         'it (its squared residual below half a shift\'s seen through the same filter); the gain, m2, '
                         'delay and AC coupling are that fit\'s')
        sys_ = campaign_systematics(cand, stats, fit, [s.quality.peak_n for s in usable],
                                    fit_scales, m2, modes, rows,
                                    rows_v, force['delay_s'], joint, hum_freqs,
                                    mode_variants, hum_form, drive_u)
        if form:   # the shift is the alternative the data rejected; the line is the filter's own (filter_form_parts)
            for t in TERMS:
                for par, comps in sys_.get(t, {}).items():
                    comps['delay_form'] = form_line.get(t, {}).get(par, 0.0)
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

    def err_fit(self, analysis: Analysis, decision: Decision, nuisance: Sequence[str] = ()) -> tuple:
        """(hum on for the extended force error, (terms, coefficients, delay)) of the named force-channel causes (and
        the nuisance terms fitted beside them, named or not: beyond)."""
        terms = set(n for n in decision.named if n in TERMS) | set(nuisance)
        err_hum = analysis.hums is not None and 'mains_hum' in decision.named
        return err_hum, fit_terms(self.fm_h if err_hum else self.fm_0, terms, analysis.fit)

    def beyond(self, analysis: Analysis, decision: Decision, withheld: Sequence[str] = ()) -> bey.BeyondResult:
        """Pass 5: the search beyond the catalog (core/beyond/) on the residuals the named causes leave: the residual
        spectra of a few fitted pulls, then every usable pull's library statistics (withheld: the causes a first
        search withheld for library terms, beyond.search)."""
        import time
        t0 = time.perf_counter()
        # the residual the search forms has the nuisance terms fitted, named or not (passes.BEYOND_NUISANCE)
        nuisance = tuple(t for t in BEYOND_NUISANCE if t not in decision.named)
        err_hum, fit_ = self.err_fit(analysis, decision, nuisance)
        names = [p.name for p in analysis.pulls]

        def job(j, settings, sensors=(), records=False):
            return (self.sources[j], self.rig, self.c1,
                    BeyondJob(self.f_hum, self.scales[j] if err_hum else None, fit_, settings, sensors, records,
                              nuisance))
        few = few_pulls(analysis.fit)
        jobs = [job(j, None, records=i < bey.REFINE_PULLS) for i, j in enumerate(few)]
        specs = self._strict('beyond', self._map('beyond', beyond_pass, jobs, [names[j] for j in few]))
        dt = analysis.pulls[0].dt
        settings = bey.settings_from(specs, dt * bey.decimation(dt))
        parts = self._strict('beyond', self._map('beyond', beyond_pass,
                                                 [job(j, settings) for j in range(len(names))], names))
        factors = bey.reading_factors(fit_.coefficients, self.rig.force_chain.m2)
        res = bey.search(parts, analysis.fit, analysis.held, settings, self.rig, decision.named, factors=factors,
                         withheld=withheld)
        sensors = tuple(t for t in res.terms if t.channel in bey.SENSORS)
        if sensors:   # the moving cell and the current again, against what the sensors read without their terms
            parts = self._strict('beyond', self._map('beyond', beyond_pass,
                                                     [job(j, settings, sensors) for j in range(len(names))], names))
            rest = bey.search(parts, analysis.fit, analysis.held, settings, self.rig, decision.named,
                              withheld=withheld,
                              channels=tuple(c for c in bey.SEARCHED if c not in bey.SENSORS), sensors=True)
            keep = [t for t in res.terms if t.channel in bey.SENSORS]
            res = dataclasses.replace(
                res, terms=tuple(sorted(keep + list(rest.terms), key=lambda t: -t.rel_sse_reduction)),
                within_tolerance=tuple(t for t in res.within_tolerance if t.channel in bey.SENSORS)
                + rest.within_tolerance, demoted=rest.demoted, checked=rest.checked)
        traces = ()
        if res.terms:   # one held-out pull's residuals before and after each term (the plots)
            j = analysis.held[0]
            series = beyond_pass(job(j, settings), series=True)
            if sensors:   # the sensors' residuals as they were, the others' against the corrected sensors
                series = {**beyond_pass(job(j, settings, sensors), series=True),
                          **{c: series[c] for c in bey.SENSORS if c in series}}
            traces = bey.term_traces(series, res.terms, names[j])
        return dataclasses.replace(res, seconds=time.perf_counter() - t0, traces=traces)

    def held_out_results(self, analysis: Analysis, decision: Decision, ext: dict):
        """Pass 4: (structure check, ForceErrors, SimulationCheck or the DiscoveryError that stopped it)."""
        rig, held, fit = self.rig, analysis.held, analysis.fit
        hum_on = analysis.hums is not None
        left_fit = fit_terms(self.fm_h if hum_on else self.fm_0, set(TERMS), fit)
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


__all__ = ['Stream', 'map_stage', 'pull_refs']
