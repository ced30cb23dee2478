"""discover(): the stages in order -- analyse, decide, check what is left, close the loop through the simulator,
report."""
from __future__ import annotations

from pathlib import Path

from force_tester_sim.core.departures import departures_from_data

from . import report as R
from .discovery import TERMS, analyse, decide, leftover
from .errors import DiscoveryError
from .resim import simulation_check


def discover(campaign_pulls, rig, out_dir) -> dict:
    """Analyse, decide, re-simulate the held-out pulls, write DIR/report.json, report.md, extension.yaml (+ plots).
    Returns the report dict."""
    analysis = analyse(campaign_pulls, rig)
    decision = decide(analysis, rig)
    if not analysis.pulls:   # the data-quality stage left too few pulls: say so, name nothing
        report = R.unusable_report(analysis, rig)
        R.write_outputs(report, analysis, ([], []), (), rig, Path(out_dir))
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
