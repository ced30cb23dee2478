"""discover(): the stages in order -- analyse, decide, check what is left, close the loop through the simulator,
report -- with the pulls streamed (stream.py: memory flat in the number of pulls, per-pull work on the campaign
engine). discover_in_memory(): the same with every pull's arrays in memory at once (discovery.analyse), the
reference the stream is checked against."""
from __future__ import annotations

from pathlib import Path
from typing import Callable, Optional

from force_tester_sim.core.departures import departures_from_data

from . import report as R
from .decision import decide
from .errors import DiscoveryError
from .force_model import TERMS
from .in_memory import analyse, leftover
from .resim import simulation_check
from .stream import discover_stream


def discover(campaign, rig, out_dir, *, scheduler: Optional[str] = None,
             progress: Optional[Callable[[str, int, int], None]] = None, mapper=None) -> dict:
    """Analyse, decide, re-simulate the held-out pulls, write DIR/report.json, report.md, extension.yaml (+ plots).
    Returns the report dict. campaign: a campaign folder (read pull by pull), [(meta, channels)] or
    [source.PullRef]; scheduler: where the per-pull stages run (force_tester_common.engine; None: the embedded
    cluster, or $DASK_SCHEDULER_ADDRESS), or mapper: a force_tester_common.engine.Mapper to run them;
    progress(stage, done, total) as pulls finish."""
    return discover_stream(campaign, rig, out_dir, scheduler, progress, mapper)


def discover_in_memory(campaign_pulls, rig, out_dir) -> dict:
    """discover() in one pass with every pull's arrays in memory (discovery.analyse): [(meta, channels)]."""
    analysis = analyse(campaign_pulls, rig)
    decision = decide(analysis, rig)
    if not analysis.pulls:   # the data-quality stage left too few pulls: say so, name nothing
        report = R.unusable_report(analysis, rig)
        R.write_outputs(report, analysis, None, (), rig, Path(out_dir))
        return report
    # structure no catalog entry explains: what is left after every force-channel entry, named or not (a departure
    # too small to name, or within tolerance, is still explained by the catalog)
    left = leftover(analysis, tuple(dict.fromkeys(decision.named + TERMS)), rig)
    errors = R.force_errors(analysis, decision.named, rig)
    report = R.build_report(analysis, decision, errors, left, rig)
    # the loop closed: the held-out pulls re-simulated with the model of record and with the extension
    ext = R.extension(report, rig)
    check = None
    try:
        check = simulation_check(analysis.pulls, analysis.held, rig, departures_from_data(ext['departures']))
    except DiscoveryError as exc:
        report['notes'].append(f'no simulation check: {exc}')
    R.add_simulation(report, check)
    R.write_outputs(report, analysis, errors, decision.named, rig, Path(out_dir), check, ext)
    return report
