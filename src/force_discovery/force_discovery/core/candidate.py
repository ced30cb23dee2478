"""What the stages say about a catalog cause: a Candidate (its parameters, their 95 % intervals, the evidence) and
its Evidence (the held-out significance test and what the cause's channel adds to it). Frozen and built whole by the
stage that finds them (stages.py); decision.py reads them; report.py turns them into report.json's dicts (as_dict)
and adds the decision's verdicts there. ROS-free.

A new kind of cause (a term beyond the catalog, a reference-free check: without_reference.leave_one_out) is a new
stage that returns a Candidate;
a new piece of evidence is a field of Evidence, with its place in EVIDENCE_ORDER (report.json's key order)."""
from __future__ import annotations

from dataclasses import dataclass, field, fields
from typing import Dict, List, Optional

# report.json's order of the evidence keys: the significance test's (significance.significance), then what a
# channel adds; a candidate that could not be tested (too few held-out pulls) has no statistic or threshold
TEST_ORDER = ('statistic', 'rel_sse_reduction', 't', 'threshold', 'significant', 'rms_gain')
UNTESTED_ORDER = ('significant', 'rel_sse_reduction', 't', 'rms_gain')
EVIDENCE_ORDER = ('rms_gain_alone', 't_squared_rel_reduction', 'observed_frequency_hz', 'observed_damping_ratio',
                  'cell_mode_hz', 'frequency_rule', 'ring_to_noise', 'ring_to_noise_ci95', 'viscous_damping_n_s_per_m',
                  'drive_force_per_amp_n_per_a', 'ac_coupling_per_s', 'per_pull_rel_reduction')


@dataclass(frozen=True)
class Evidence:
    """A candidate's held-out evidence. The test (significance.significance): the relative reduction of its
    channel's summed squared residual on the held-out pulls, the t of the per-pull reductions, whether both pass,
    and the RMS gain; then what the channel adds (None: not measured for this candidate)."""

    rel_sse_reduction: float
    t: float
    significant: bool
    rms_gain: float
    statistic: Optional[str] = None               # what was tested (None: not tested)
    threshold: Optional[str] = None               # the rule it was held to
    rms_gain_alone: Optional[float] = None        # hum, force channel: the gain of the cause alone over the record's
    t_squared_rel_reduction: Optional[float] = None   # moving_cell_gain: a T^2 term's held-out reduction (linearity)
    observed_frequency_hz: Optional[float] = None     # mount_resonance: the free-decay mode observed ...
    observed_damping_ratio: Optional[float] = None
    cell_mode_hz: Optional[float] = None              # ... the model of record's cell mode ...
    frequency_rule: Optional[str] = None              # ... and the rule that tells them apart
    ring_to_noise: Optional[float] = None             # mount_resonance: the mode's ring over the noise (its band)
    ring_to_noise_ci95: Optional[tuple] = None
    viscous_damping_n_s_per_m: Optional[float] = None   # coulomb_friction: the drive's b fitted with it (joint)
    drive_force_per_amp_n_per_a: Optional[float] = None   # coulomb_friction: the drive's k_F the pulls calibrated
    ac_coupling_per_s: Optional[float] = None         # effective_mass without a reference: k fitted with g and m2
    per_pull_rel_reduction: Optional[tuple] = None    # leave-one-out: each held-out pull's own relative reduction

    def value(self, name: str):
        """The evidence called name (a tolerance band may apply to one, tolerances.BAND_PARAMETER)."""
        if name not in self._names():
            raise KeyError(name)
        return getattr(self, name)

    @classmethod
    def _names(cls) -> set:
        return {f.name for f in fields(cls)}

    def as_dict(self) -> dict:
        """report.json's evidence: the measured keys, in report.json's order."""
        head = TEST_ORDER if self.statistic is not None else UNTESTED_ORDER
        out = {k: getattr(self, k) for k in head}
        out.update((k, list(v) if isinstance(v, tuple) else v) for k in EVIDENCE_ORDER
                   if (v := getattr(self, k)) is not None)
        return out


@dataclass(frozen=True)
class Candidate:
    """One catalog cause as a stage found it: its parameters (departures.CATALOG's names), their 95 % intervals
    over ci_pulls pulls, the evidence, and the measured channel it was tested on. A stage gives the statistical
    interval; budget.honest() replaces it with the expanded one and fills uncertainty_budget
    ({parameter: {component: standard uncertainty}}, budget.py)."""

    parameters: Dict[str, float]
    parameters_ci95: Dict[str, List[float]]
    ci_pulls: int
    evidence: Evidence
    channel: str
    uncertainty_budget: Dict[str, Dict[str, float]] = field(default_factory=dict)

    def as_dict(self) -> dict:
        """The candidate as report.json lists it before the decision's verdicts are added (a fresh dict)."""
        return {'parameters': dict(self.parameters),
                'parameters_ci95': {k: None if v is None else list(v) for k, v in self.parameters_ci95.items()},
                'ci_pulls': self.ci_pulls, 'evidence': self.evidence.as_dict(), 'channel': self.channel,
                'uncertainty_budget': {k: dict(v) for k, v in self.uncertainty_budget.items()}}


__all__ = ['Candidate', 'Evidence']
