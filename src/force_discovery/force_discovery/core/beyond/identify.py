"""Which (channel, term) pairs of the grammar the search could not identify on a campaign, and why
(report.json beyond_search.identifiability): none is dropped in silence. A pair is listed when its channel is absent,
when the grammar keeps it off its channel (a catalog form, a signal the channel's free phases cannot use:
grammar.structural_reason), when no line stands out for a sinusoid, or when the campaign's own columns make it
collinear with a term before it in the library's order (collinear). ROS-free."""
from __future__ import annotations

from typing import Dict, List, Sequence

import numpy as np

from force_tester_sim.core.extra_terms import CHANNEL_COLUMNS, SIN

from .grammar import SEARCHED, catalog_reading, pairs, structural_reason, structural_tie, via_moving
from .normal_equations import BeyondPart, ChannelStats

COLLINEAR = 1e-6      # two columns whose 1 - r^2 (fitted pulls, pooled) is below this: forward selection, one term at
                      # a time, cannot tell them apart


def collinear(stats: Sequence[ChannelStats]) -> Dict[str, str]:
    """{term: reason} of the product columns the fitted pulls cannot tell from an earlier one in the library's order
    (pairwise: forward selection adds one term at a time, and a tie goes to the earlier term), and of the columns
    that are zero on the samples searched."""
    names = [n for n in stats[0].names if not n.endswith(SIN)]
    n = len(names)
    G = sum(st.gram[:n, :n] for st in stats)
    d = np.sqrt(np.maximum(np.diag(G), 0.0))
    scale = max(float(d.max()), 1e-300)
    zero = d <= 1e-12 * scale
    r = G / np.outer(np.where(zero, 1.0, d), np.where(zero, 1.0, d))
    out = {}
    for k in range(n):
        if zero[k]:
            out[names[k]] = 'its column is zero on the samples searched'
            continue
        for i in range(k):
            left = 1.0 - r[i, k] ** 2
            if not zero[i] and names[i] not in out and left < COLLINEAR:
                out[names[k]] = (f'collinear with {names[i]} on this campaign (1 - r^2 = {max(left, 0.0):.1e} < '
                                 f'{COLLINEAR:g}): the data cannot tell it from {names[i]}, which is searched')
                break
    return out


def identifiability(parts: Sequence[BeyondPart], fit: Sequence[int], frequencies: Dict[str, float]) -> List[dict]:
    """[{channel, term, reason}] of every pair of the grammar (grammar.pairs) the search could not identify, with
    read_as (the pair named in its place) or read_as_cause (the catalog cause named in its place) where the grammar
    says which."""
    out = []
    seen: Dict[str, Dict[str, str]] = {}
    for ch in SEARCHED:
        if fit and all(ch in parts[j].stats for j in fit):
            seen[ch] = collinear([parts[j].stats[ch] for j in fit])
    for ch, term in pairs():
        why = structural_reason(ch, term)
        if why is None and ch not in seen and not (via_moving(ch, term) and 'force_moving' in seen):
            why = f'needs the {CHANNEL_COLUMNS[ch]} channel, absent or unusable in these pulls'
        if why is None and term.endswith(SIN) and ch not in frequencies:
            why = "no line stands out in the channel's residual spectrum: no frequency to search a sinusoid at"
        if why is None:
            why = seen.get(ch, {}).get(term)
        if why is not None:
            tie = structural_tie(ch, term)   # the pair the search names in its place, when a term
            cause = catalog_reading(ch, term)   # or the catalog cause, when a linear force or the moving cell's a2
            out.append({'channel': ch, 'term': term, 'reason': why, **({'read_as': tie} if tie else {}),
                        **({'read_as_cause': cause} if cause else {})})
    return out
