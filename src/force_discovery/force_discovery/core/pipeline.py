"""discover(): the stages in order -- analyse, decide, check what is left, close the loop through the simulator,
report -- with the pulls streamed (stream.py: memory flat in the number of pulls, per-pull work on the campaign
engine). The one pipeline; tests/force_discovery/one_pass.py is its in-memory oracle."""
from __future__ import annotations

from typing import Callable, Optional

from .stream import discover_stream


def discover(campaign, rig, out_dir, *, scheduler: Optional[str] = None,
             progress: Optional[Callable[[str, int, int], None]] = None, mapper=None) -> dict:
    """Analyse, decide, re-simulate the held-out pulls, write DIR/report.json, report.md, extension.yaml (+ plots).
    Returns the report dict. campaign: a campaign folder (read pull by pull), [(meta, channels)] or
    [source.PullRef]; scheduler: where the per-pull stages run (force_tester_common.engine; None: the embedded
    cluster, or $DASK_SCHEDULER_ADDRESS), or mapper: a force_tester_common.engine.Mapper to run them;
    progress(stage, done, total) as pulls finish."""
    return discover_stream(campaign, rig, out_dir, scheduler, progress, mapper)
