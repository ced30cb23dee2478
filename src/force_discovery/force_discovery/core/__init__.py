"""ROS-free core of force_discovery: what the model of record gets wrong in measured data.

One module an idea, in the order a discovery runs (pipeline.discover -> stream.py, the one driver):

- source.py       where a campaign's pulls come from (a folder read pull by pull, or channels in memory)
- quality.py      the data-quality screen (defects found, repaired and masked; pulls left out)
- overload.py     ... its overloads: bursts in one channel alone; when two channels disagree, which one is blamed
- prep.py         per-pull preparation: T, the low-passed channels, carriage motion, the analysis window
- cells.py        cell calibration: the stationary cell's frequency and damping from the free decay, T recomputed
- hum.py          mains hum: the line's frequency (from pre-pull records or free-phase residuals), each pull's
                  amplitude and phase
- force_model.py  the force model F_move - hum = g T + M a2(t + d) - k C, fitted on samples (ForceModel)
- force_stats.py  ... the same fits from per-pull sufficient statistics (ForceStats: what the stream uses)
- ringing.py      ringing: the free decay after the break (matrix pencil), the mount mapping, modes across pulls
- friction.py     friction: the motor current against the force balance
- significance.py the held-out significance test
- uncertainty.py  intervals (jackknife, bootstrap, a mean's) and the tolerance verdict
- budget.py       uncertainty budgets: the systematic parts of every parameter's uncertainty, the expanded interval
- candidate.py    Candidate and Evidence: what a stage says about one cause (frozen)
- stages.py       the stages: each turns its channel's per-pull results into Candidates; Analysis; the method
- decision.py     the decision: named, within tolerance, inconclusive, withheld
- beyond/         beyond the catalog: a grammar of candidate terms searched on what the named causes leave, one
                  module a job (its docstring lists them): the grammar, the per-pull series, the spectrum pass,
                  the normal equations, the forward selection, the catalog's priority, the search, the
                  interpretation, the plots' traces
- leftover.py     the leftover structure no catalog entry explains
- force_errors.py the held-out force-channel error, model of record vs extended
- resim.py        closing the loop: the held-out pulls re-simulated with and without the extension
- identifiability.py what a campaign's channels can identify: which path a campaign lacking channels takes,
                  identifiable / not_identifiable (both paths)
- without_reference/ discovery without a reference (no stationary cell or encoder, or 1-3 pulls), one module an
                  idea: driver.py (its docstring is the method: the free phases of the moving cell and the
                  accelerometer give g m2, the accelerometer delay, the ringing modes, the hum), delay_fit.py
                  (F = G a(t + d) + offset on a grid of delays), phases.py (pass 1 of a pull: its events, free phases,
                  own g m2 and delay, free-decay modes), phase_stats.py (pass 2: the normal equations per delay),
                  leave_one_out.py (the campaign: pooled estimates, every pull held out once, its Candidates),
                  stationary_cell.py (with the stationary cell: g and m2 apart), report.py (its report.json,
                  report.md and extension.yaml)
- passes.py       the per-pull passes (read, cells, hum, statistics, held-out, beyond), each a function the campaign
                  engine maps over the pulls, with its settings and its small result
- stream.py       the driver: the passes in order on the campaign engine, memory flat in the number of pulls
- pipeline.py     discover(): the entry point; the path a campaign takes, the stages in order
- report.py       report.json (the one place Candidates become dicts); markdown.py report.md; extension.py
                  extension.yaml; plots.py the figures; outputs.py writes the folder whole
- errors.py       DiscoveryError
"""
