"""The decision: which candidates are named (significant on held-out pulls and outside their tolerance band),
within tolerance or inconclusive, and which are withheld. ROS-free."""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Tuple

from force_correction.core.peak_uncertainty import COVERAGE_FACTOR
from force_tester_sim.core.tolerances import BAND_PARAMETER, band

from .budget import COMBINED, STATISTICAL
from .candidate import Candidate
from .force_model import TERMS
from .stages import Analysis
from .uncertainty import NAMED, verdict

NONLIN_SHARE = 0.03           # a T^2 term removing > 3 % of the held-out force residual: not a linear sensor


@dataclass(frozen=True)
class Decision:
    """The causes named (strongest first), every candidate's practical-significance verdict, and those withheld."""

    named: tuple
    verdicts: dict = field(default_factory=dict)          # name -> uncertainty.verdict() of each candidate
    rejected: dict = field(default_factory=dict)          # name -> why it was withheld
    notes: tuple = ()

    def with_verdict(self, kind: str) -> list:
        return [n for n, v in self.verdicts.items() if v['verdict'] == kind]


CAUSE_ORDER = ('mains_hum', 'moving_cell_gain', 'effective_mass', 'accel_delay', 'ac_coupling',
               'mount_resonance', 'coulomb_friction')


def _admissible(name: str, c: Candidate) -> bool:
    if not c.evidence.significant:
        return False
    if name == 'coulomb_friction':
        return c.parameters['force_n'] > 0   # the catalog's dry friction opposes the motion
    if name == 'ac_coupling':
        tau = c.parameters['time_constant_s']
        return tau > 0 and math.isfinite(tau)
    return True


def tolerance_input(name: str, c: Candidate) -> Tuple[float, Tuple[float, float]]:
    """(estimate, 95 % interval) of the quantity the cause's tolerance band applies to: the expanded interval
    (budget.py) when it is a parameter."""
    par = BAND_PARAMETER[name][0]
    if par in c.parameters:
        return c.parameters[par], tuple(c.parameters_ci95[par])
    return c.evidence.value(par), tuple(c.evidence.value(par + '_ci95'))


def fixed_half(name: str, c: Candidate) -> float:
    """The half-width that more pulls would not shrink: COVERAGE_FACTOR x the systematic part of the band
    parameter's budget (0 without one)."""
    b = c.uncertainty_budget.get(BAND_PARAMETER[name][0])
    if not b or name == 'ac_coupling':   # the AC coupling's interval is made in its rate 1/tau: taken as shrinking
        return 0.0
    return COVERAGE_FACTOR * math.sqrt(sum(v * v for k, v in b.items() if k not in (STATISTICAL, COMBINED)))


def decide(analysis: Analysis, rig) -> Decision:
    """Named causes (strongest first): significant on held-out pulls AND outside their tolerance band."""
    cand = analysis.candidates
    if not analysis.pulls:
        return Decision((), notes=('no decision: too few usable pulls',))
    verdicts = {}
    for n in CAUSE_ORDER:
        if n in cand:
            est, ci = tolerance_input(n, cand[n])
            verdicts[n] = verdict(est, ci, band(n, rig.tolerances, rig.force_chain.m2), _admissible(n, cand[n]),
                                  cand[n].ci_pulls, fixed_half(n, cand[n]))
    named = [n for n, v in verdicts.items() if v['verdict'] == NAMED]
    rejected, notes = {}, []
    nl = cand['moving_cell_gain'].evidence.t_squared_rel_reduction
    if nl > NONLIN_SHARE:
        for n in named:
            if n in TERMS:
                rejected[n] = ('withheld: the moving cell departs from T non-linearly (a T^2 term '
                               f'removes {100 * nl:.0f} % of the held-out residual left by the linear force model)')
        named = [n for n in named if n not in TERMS]
        notes.append('the moving cell departs from T non-linearly (T^2 term significant); the force-channel '
                     'catalog entries do not explain it')
    named.sort(key=lambda n: -cand[n].evidence.rel_sse_reduction)
    return Decision(tuple(named), verdicts, rejected, tuple(notes))
