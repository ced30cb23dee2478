"""The discovery's output folder: extension.yaml, report.json, report.md and the plots, written whole or not at
all. ROS-free."""
from __future__ import annotations

import json
from pathlib import Path
from typing import Optional

from .extension import extension, extension_yaml
from .force_errors import ForceErrors
from .identifiability import identifiability_lines
from .markdown import markdown
from .plots import beyond_plots, residual_plots, simulation_plot
from .stages import Analysis


def write_outputs(report, analysis: Analysis, errors: Optional[ForceErrors], named, rig, out: Path, check=None,
                  ext: dict | None = None, traces=(), plots: bool = True) -> None:
    """Write DIR/extension.yaml, report.json, report.md and the plots (adds report['plots']; none when
    plots=False). check: the simulation check (resim.SimulationCheck), whose kept pull is overlaid in
    simulation.png; ext: extension() of the report when the caller has it already; traces: beyond.term_traces
    (beyond_<k>.png).

    Everything is written into a fresh folder beside DIR first and moved in at the end, so a failure never
    leaves a half-written report."""
    from force_tester_common.core.partial import staging

    with staging(out, '.discover-') as mark:   # a staging folder a killed run left here is removed first
        stage = mark.folder
        ext = extension(report, rig) if ext is None else ext
        (stage / 'extension.yaml').write_text(extension_yaml(ext))
        pngs = (residual_plots(analysis, errors, named, rig, stage) + simulation_plot(check, stage)
                + beyond_plots(traces, stage)) if plots else []
        report['plots'] = [str(out / Path(q).name) for q in pngs]
        (stage / 'report.json').write_text(json.dumps(report, indent=1))
        md = markdown(report, report['plots'], analysis.screens, analysis.excluded)
        more = identifiability_lines(report)
        (stage / 'report.md').write_text(md + ('\n' + '\n'.join(more) if more else ''))
        mark.unmark()
        for f in sorted(stage.iterdir(), key=lambda q: q.name == 'report.json'):   # report.json last
            f.replace(out / f.name)
