"""discover(): the stages in order -- analyse, decide, search beyond the catalog, check what is left, close the loop
through the simulator, report -- with the pulls streamed (stream.Stream: memory flat in the number of pulls,
per-pull work on the campaign engine), or, for a campaign without a reference (no stationary cell or no encoder, or
fewer than MIN_PULLS pulls), the reference-free path. The one pipeline; tests/force_discovery/one_pass.py is its
in-memory oracle. ROS-free."""
from __future__ import annotations

import dataclasses
import shutil
import tempfile
from pathlib import Path
from typing import Callable, Optional

from . import beyond as bey
from .decision import Decision, decide
from .errors import DiscoveryError
from .extension import add_extra_terms, named_extension
from .identifiability import check_core_channels, full_identifiability, needs_reference_free
from .outputs import write_outputs
from .report import (
    WITHOUT_REFERENCE_ONLY,
    add_beyond,
    add_simulation,
    build_report,
    campaign_section,
    complete,
    rig_state,
    unusable_report,
)
from .source import campaign_absent
from .stages import MIN_PULLS, Analysis
from .stream import Stream, pull_refs
from .without_reference.driver import discover_without_reference


def spills_locally(scheduler: Optional[str]) -> bool:
    """Whether the workers share this machine's disk (the embedded cluster or inline), so a spill helps."""
    from force_tester_common.engine import INLINE, resolve_scheduler
    return resolve_scheduler(scheduler) in (None, INLINE)


def discover(campaign, rig, out_dir, *, scheduler: Optional[str] = None,
             progress: Optional[Callable[[str, int, int], None]] = None, mapper=None, rig_file=None,
             plots: bool = True) -> dict:
    """Analyse, decide, re-simulate the held-out pulls, write DIR/report.json, report.md, extension.yaml (+ plots).
    Returns the report dict. campaign: a campaign folder (read pull by pull), [(meta, channels)] or
    [source.PullRef]; scheduler: where the per-pull stages run (force_tester_common.engine: None for the embedded
    cluster or $DASK_SCHEDULER_ADDRESS, 'inline', or tcp://HOST:PORT), or mapper: a force_tester_common.engine.Mapper
    to run them (its scheduler then); progress(stage, done, total) as pulls finish; plots=False writes no PNGs
    (report.md then lists none; nothing decided changes). rig: the rig given (a
    RigParams; rig_file: the file it came from), or None when none was given: the reference-free path then judges
    nothing against a nominal (report.rig_state), the path with a reference takes the packaged nominal rig."""
    from force_tester_common.engine import Mapper
    mapper = Mapper(scheduler) if mapper is None else mapper
    refs = pull_refs(campaign)
    absent = campaign_absent(refs)
    check_core_channels(absent)
    state = rig_state(rig, rig_file)
    if needs_reference_free(absent):   # no stationary cell or no encoder: what the remaining channels support
        return discover_without_reference(refs, absent, rig, out_dir, mapper, progress, rig_state=state)
    if len(refs) < MIN_PULLS:          # too few to fit half and hold half out: the free phases, leave-one-out
        return discover_without_reference(refs, absent, rig, out_dir, mapper, progress, few=MIN_PULLS,
                                          rig_state=state)
    if rig is None:                    # the analysis with a reference needs a model of record: ours
        from force_tester_sim.core.params import load_rig
        rig = load_rig()
        state = rig_state(rig, nominal=True)
    spill = tempfile.mkdtemp(prefix='ft_discover_spill_') if spills_locally(mapper.scheduler) else None
    try:
        st = Stream(refs, rig, mapper, spill, progress)
        analysis = st.analyse()
        decision = decide(analysis, rig)
        out = Path(out_dir)
        if not analysis.pulls:
            report = complete({**unusable_report(analysis, rig), **campaign_section(analysis, absent), 'plots': [],
                               'rig': state},
                              {}, 'the data-quality screen left too few pulls to analyse (data_quality)')
            write_outputs(report, analysis, None, (), rig, out, plots=plots)
            return report
        found = st.beyond(analysis, decision)
        decision = with_beyond(decision, found)
        if set(found.demoted) & set(bey.CAUSE_PARAMS):   # the force residual changes without the cause: again
            again = st.beyond(analysis, decision, tuple(found.demoted))
            found = dataclasses.replace(again, demoted={**found.demoted, **again.demoted},
                                        seconds=found.seconds + again.seconds)
            decision = with_beyond(decision, found)
        ext = named_extension(analysis, decision, rig)
        add_extra_terms(ext, [t.as_dict() for t in found.terms])
        left, errors, check = st.held_out_results(analysis, decision, ext)
        analysis = with_run(analysis, st)
        report = build_report(analysis, decision, errors, left, rig)
        report['identifiable'], report['not_identifiable'] = full_identifiability(tuple(analysis.candidates))
        if isinstance(check, DiscoveryError):
            report['notes'].append(f'no simulation check: {check}')
            check = None
        add_simulation(report, check)
        add_beyond(report, found)
        report = complete({**report, **campaign_section(analysis, absent), 'plots': [], 'rig': state},
                          WITHOUT_REFERENCE_ONLY)
        write_outputs(report, analysis, errors, decision.named, rig, out, check, ext, found.traces, plots=plots)
        return report
    finally:
        if spill is not None:
            shutil.rmtree(spill, ignore_errors=True)


def with_beyond(decision: Decision, found: bey.BeyondResult) -> Decision:
    """The decision with the catalog causes a library term fits better (beyond.selection.search_channel) withheld."""
    new = {n: why for n, why in found.demoted.items() if n not in decision.rejected}
    if not new:
        return decision
    named = tuple(n for n in decision.named if n not in new)
    return dataclasses.replace(decision, named=named, rejected={**decision.rejected, **new},
                               notes=decision.notes + tuple(f'{n} withheld: {why}' for n, why in new.items()))


def with_run(analysis: Analysis, st: Stream) -> Analysis:
    """The analysis with the run's failed and retried pulls and where the passes ran."""
    return dataclasses.replace(analysis, failed=tuple(st.failed), retried=tuple(st.retried), scheduler=st.where)

