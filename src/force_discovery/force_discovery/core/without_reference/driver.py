"""Discovery without a reference: what a campaign with only the moving cell and the accelerometer says.
ROS-free.

Another lab's rig may have no stationary reference cell, no encoder and no motor channels (campaign.yaml or its
channel map names them ``absent:``). Without the tension T the model of record F_move = T + m2 a2 cannot be
checked during an event, but wherever the cell carries only the mass in front of it -- a FREE PHASE: before
contact, after a break or a rebound, while braking -- it reads

    F_move = g m2 a2(t + d) + offset + hum            (g: the cell's gain, d: the accelerometer's delay)

which identifies the product G = g m2, the delay d, the free structure's ringing modes (in a2 after the event),
the mains hum and the data quality. g and m2 separate only with a reference (the stationary cell: step 5) or a
known calibration mass. The method, per pull:

1. Screen (quality.screen_pull, every channel present), repair, low-pass both channels alike (prep.lowpassed: the
   band scaled to the rate).
2. Events, of either sign and any shape (force_tester_common.core.events: |F_move - median| above 20 % of the
   record's largest excursion): a tension pull, a compression impact, a braking load. Free phases: first the
   samples away from the events (FREE_MARGIN_S or a quarter of the event's length); G and d fitted there; then the
   event is where F_move departs from G a2 by more than EVENT_Z robust standard deviations of that residual (the
   part of the force the accelerometer does not explain: a contact, a lanyard), grown by EVENT_PAD_S, and the
   free phases are the rest.
3. Per pull and per delay on a grid (DELAY_MAX_S either way, DELAY_STEP_SHARE of a sample; a2 shifted exactly in
   the frequency domain), the normal equations of F_move on a2 with the pull's own offset and hum (sine and cosine
   at the campaign's hum frequency) projected out: three numbers, so that every fit and held-out residual below
   needs the pull only through them.
4. Ringing: the strongest damped modes (matrix pencil) of a2 in the free decay after the last event.
5. With the stationary cell (a campaign without the encoder, or with every channel but 1-3 pulls): T from the
   stationary cell (prep.tension_from_stationary) over the whole record, and per delay the Gram matrix of
   F_move, T, a2(t + d) and C (the running integral of F_move) with the offset and hum projected out
   (stationary_cell.py): F_move = g T + g m2 a2(t + d) - k C separates the cell's gain g and the mass m2.

The campaign: G and d fitted on all pulls pooled; with n >= 2 pulls every pull is held out once (leave-one-out:
the fit on the others scores it), which gives each cause its held-out evidence (significance.significance) and
each estimate a jackknife interval. n >= MIN_NAMED_PULLS (4): a cause is named as with a reference (significant
held out, interval outside its tolerance band). n = 2 or 3: the same numbers, but t >= 4 over so few held-out
pulls is not a standard they can meet; what departs consistently is `indicated`, nothing is named. n = 1:
per-pull estimates, no interval, no cause.
"""
# This module's docstring is the Method section of the reference-free report.md: keep it the method as run.
from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import Optional, Sequence

import numpy as np

from .. import quality as Q
from ..errors import DiscoveryError
from ..hum import HUM_BAND_HZ, hum_frequency_free
from ..identifiability import FREE_CHANNELS, check_core_channels
from .delay_fit import delay_grid
from .leave_one_out import campaign_analysis
from .phase_stats import FreeStats, free_stats
from .phases import FreePull, free_pull
from .report import campaign_report, write_report
from .stationary_cell import reference_stats

METHOD = __doc__.split('\n\n', 1)[1]


# ------------------------------------------------------------------------------------------ the driver
@dataclass(frozen=True)
class PhasesRead:
    """Pass 1 of one pull: its screen, and its FreePull, or why it is left out."""

    name: str
    screen: Optional[Q.PullScreen] = None
    pull: Optional[FreePull] = None
    excluded: Optional[str] = None


def read_pass(ref) -> PhasesRead:
    """Pass 1 (mapped over the pulls): read, screen, and analyse one pull's free phases."""
    from ..source import load_channels, rated_ranges
    _meta, ch = load_channels(ref)
    for c in FREE_CHANNELS:
        if c not in ch:
            check_core_channels((c,), f'pull {ref.name!r}')
    sc = Q.screen_pull(ref.name, ch, rated_ranges(ref))
    why = sc.exclusion(0, sc.samples, FREE_CHANNELS)
    if why:
        return PhasesRead(ref.name, sc, excluded=why)
    try:
        return PhasesRead(ref.name, sc, free_pull(ref.name, ch, sc))
    except DiscoveryError as exc:
        return PhasesRead(ref.name, sc, excluded=str(exc))


def stats_pass(item) -> FreeStats:
    """Pass 2 (mapped over the usable pulls): item = (PullRef, PhasesRead, hum frequency, the delay grid,
    the rig's force chain)."""
    from ..source import load_channels
    ref, sv, f_hum, delays, fc = item
    _meta, ch = load_channels(ref)
    st = free_stats(ref.name, ch, sv.screen, f_hum, sv.pull, delays)
    return replace(st, ref=reference_stats(ref.name, ch, sv.screen, f_hum, delays, fc))


def discover_without_reference(refs: Sequence, absent: Sequence[str], rig, out_dir, mapper, progress=None,
                               few: int = 0, rig_state: Optional[dict] = None) -> dict:
    """The reference-free discovery of a campaign lacking ``absent`` (module docstring), or of one with every
    channel but fewer pulls than ``few`` (the analysis with a reference needs that many); writes DIR/report.json,
    report.md and extension.yaml and returns the report. rig None: no rig was given (nothing is judged against a
    nominal: leave_one_out.campaign_analysis); rig_state: report.json's ``rig`` (pipeline.rig_state)."""
    def run(stage, fn, items, names):
        prog = (lambda done, total: progress(stage, done, total)) if progress else None
        return mapper(fn, items, names=list(names), keep=True, on_result=None, progress=prog)
    res = run('read', read_pass, list(refs), [r.name for r in refs])
    failed = list(res.failed)
    run_info = {'retried': list(res.retried), 'scheduler': res.scheduler}
    reads = [s for s in res.results if s is not None]
    screens = tuple(s.screen for s in reads if s.screen is not None)
    excluded = {s.name: s.excluded for s in reads if s.excluded}
    usable = [(r, s) for r, s in zip(refs, res.results) if s is not None and s.pull is not None]
    notes = [f'no {", ".join(absent)}: the reference-free analysis (free phases of the moving cell and the '
             'accelerometer)'] if absent else [
        f'{len(refs)} pulls: the analysis with a reference needs at least {few} (half fitted, half held out); '
        'the free phases of the moving cell and the accelerometer are analysed instead, leave-one-out']
    dts = {round(s.pull.dt, 12) for _r, s in usable}
    if len(dts) > 1:
        raise DiscoveryError(f'pulls have different sample intervals {sorted(dts)}; expected one rate')
    from bag_tools.core.daqfiles import NOTHING_TO_CORRECT
    if not usable and failed and all(NOTHING_TO_CORRECT in why for _n, why in failed):
        raise DiscoveryError(failed[0][1].split(': ', 1)[-1])       # no moving cell in any pull: one line
    if not usable:
        notes.append(f'0 of {len(refs)} pulls are usable (excluded_pulls, failed_pulls say why)')
        rep = campaign_report(None, [], absent, screens, excluded, failed, rig, notes, few, rig_state, **run_info)
        write_report(rep, screens, rig, Path(out_dir), METHOD)
        return rep
    pulls = [s.pull for _r, s in usable]
    pres = [(p.hum_t, p.hum_r) for p in pulls if len(p.hum_t) > 100]
    f_hum = hum_frequency_free(pres) if pres else float(np.mean(HUM_BAND_HZ))
    grid = delay_grid(pulls[0].dt, [p.delay_s for p in pulls])
    fc = rig.force_chain if rig is not None else None
    res2 = run('statistics', stats_pass, [(r, s, f_hum, grid, fc) for r, s in usable],
               [p.name for p in pulls])
    if res2.failed:
        name, why = res2.failed[0]
        raise DiscoveryError(f'pull {name!r} failed in the statistics stage ({why}); expected every usable pull '
                             'to finish it')
    analysis = campaign_analysis(pulls, res2.results, f_hum, rig)
    run_info['retried'] += [n for n in res2.retried if n not in run_info['retried']]
    rep = campaign_report(analysis, pulls, absent, screens, excluded, failed, rig, notes, few, rig_state, **run_info)
    write_report(rep, screens, rig, Path(out_dir), METHOD)
    return rep


__all__ = ['PhasesRead', 'discover_without_reference', 'stats_pass', 'read_pass']
