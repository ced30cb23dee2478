"""The search beyond the catalog over the channels (search): each channel's forward selection (selection.py), the
catalog's priority (priority.py), and what it found (BeyondResult). ROS-free."""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Dict, Optional, Sequence, Tuple

from .grammar import COULOMB, FORCE_FORMS, SEARCHED
from .identify import identifiability
from .normal_equations import BeyondPart
from .own import own_reading, reading_factors
from .priority import cause_check
from .selection import Term, search_channel
from .spectrum import SearchSettings
from .traces import TermTrace


@dataclass(frozen=True)
class BeyondResult:
    terms: Tuple[Term, ...] = ()                    # named, best first
    traces: Tuple[TermTrace, ...] = ()              # traces.term_traces of one held-out pull (the plots)
    within_tolerance: Tuple[Term, ...] = ()         # significant, inside the band
    demoted: Dict[str, str] = field(default_factory=dict)   # catalog cause -> why it does not fit
    frequencies: Dict[str, float] = field(default_factory=dict)
    seconds: float = 0.0
    identifiability: Tuple[dict, ...] = ()          # identify.identifiability: the pairs not identified, and why
    checked: Dict[str, dict] = field(default_factory=dict)   # named cause -> the library's best in its place


def search(parts: Sequence[BeyondPart], fit: Sequence[int], held: Sequence[int], settings: SearchSettings, rig,
           named: Sequence[str], channels: Sequence[str] = SEARCHED, sensors: bool = False,
           factors: Optional[Dict[str, float]] = None, withheld: Sequence[str] = ()) -> BeyondResult:
    """The search over the channels (the package docstring; default every searched one): parts in the usable pulls'
    order; sensors: terms were found on the sensors on their own (the force model's causes are checked then, and the
    moving cell's terms stay its own); factors: own.reading_factors (default: the rig's m2, gain 1); withheld: the
    catalog causes a first search withheld for library terms (the moving cell's gain or m2 among them: its terms
    are measured beside both, selection.search_channel)."""
    t0 = time.perf_counter()
    terms, within, demoted, checked = [], [], {}, {}
    factors = factors or reading_factors({}, rig.force_chain.m2)
    for ch in channels:
        if not all(ch in parts[j].stats for j in (*fit, *held)):
            continue
        fit_st, held_st = [parts[j].stats[ch] for j in fit], [parts[j].stats[ch] for j in held]
        found, why, model, kept = search_channel(ch, fit_st, held_st, settings, rig,
                                                 COULOMB in named and ch == 'motor_current',
                                                 bool(set(FORCE_FORMS) & set(withheld)))
        if why is not None:
            demoted[COULOMB] = why
        if kept is not None:   # the Coulomb step kept its priority on the current: what the library did in its place
            checked[COULOMB] = kept
        if ch == 'force_moving' and not sensors:   # a sensor's own non-linearity, carried by T or m2 a2 (own.py)
            have = {(t.channel, t.term) for t in terms + within}
            found = [t for t in (own_reading(t, factors, rig) for t in found) if t.channel == ch
                     or (t.channel, t.term) not in have]
        if ch == 'force_moving':
            # one selection: each named force-model cause is named only when it explains more, held out, than the
            # library would with as many parameters in its place (priority.cause_check)
            for cause in fit_st[0].causes:
                check = cause_check(fit_st, held_st, model, settings, rig, cause)
                if check.demoted is not None:
                    demoted[cause] = check.demoted
                else:
                    checked[cause] = check.beat
        terms += [t for t in found if t.named]
        within += [t for t in found if not t.named]
    terms.sort(key=lambda t: -t.rel_sse_reduction)
    return BeyondResult(terms=tuple(terms), within_tolerance=tuple(within), demoted=demoted, checked=checked,
                        frequencies=dict(settings.freq), seconds=time.perf_counter() - t0,
                        identifiability=tuple(identifiability(parts, fit, settings.freq)) if not sensors else ())
