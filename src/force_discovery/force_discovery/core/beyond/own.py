"""A sensor's own terms seen on the moving cell (own_reading). The stationary cell's reading enters the moving cell's
model as the tension T (F_move = g (T + m2 a2)), the accelerometer's as m2 a2. So a sensor's own non-linearity
(F_stat^2, a2^3) leaves a term in those signals alone on the moving cell's residual, times -g (the stationary cell)
or -g m2 (the accelerometer): the moving side's tension is the quantity the stationary cell should read, and the
cell's own non-linearity is seen only under load, where its free phases (T = 0) see nothing. Such a term is read as
the sensor's own, written in its own signal and unit. A product with another signal (T*v) stays the moving cell's:
two cells that read one tension cannot tell whose it is (grammar.FREE_PHASE_BLIND says so in the report).
A named term's near-tie group (selection.tie_group) is listed in the report as read so (near_ties). ROS-free."""
from __future__ import annotations

import dataclasses
from typing import Dict, List, Optional

from force_tester_sim.core.extra_terms import parse_term, term_name

from .grammar import CARRIED, channel_band, read_as
from .selection import Term


def carrier(term: str) -> Optional[str]:
    """The sensor whose own non-linearity a moving-cell term is (grammar.CARRIED: degree >= 2 in its signals
    alone), or None."""
    sensor = read_as('force_moving', term)[0]
    return None if sensor == 'force_moving' else sensor


def near_ties(t: Term) -> List[dict]:
    """beyond_search.identifiability's entries of a named term's tie group (selection.tie_group): each member the
    held-out pulls cannot tell from it, as the report reads it (read_as), with the whole group (near_tie: the named
    term first, as channel:term)."""
    named = (t.channel, t.term)
    members = []
    for ch, term, left, margin in t.ties:
        pair = read_as(ch, term)
        if pair != named and pair not in [m[0] for m in members]:
            members.append((pair, term, ch, left, margin))
    group = [f'{c}:{m}' for c, m in (named, *(m[0] for m in members))]
    return [{'channel': c, 'term': m,
             'reason': (f'a near-tie with {t.term} on {t.channel}, named: on {ch} its column ({term}) differs from '
                        f"the named term's by a part inside the channel's band at the size found (1 - r^2 = "
                        f'{left:.1e} on the held-out pulls), and the named term beats it there by {100 * margin:.2f} '
                        '% of the SSE, short of the held-out test (SSE -1 %, t >= 4): the data cannot tell which '
                        'it is'),
             'near_tie': group} for (c, m), term, ch, left, margin in members]


def reading_factors(coefficients: dict, m2: float) -> Dict[str, float]:
    """How much of each sensor's reading the moving cell's model carries, from the force model's fitted
    coefficients (force_model.TermsFit: g, M = g m2 when fitted): the stationary cell's g, the accelerometer's g m2."""
    g = float(coefficients.get('g', 1.0))
    return {'force_stationary': g, 'accel_axial': float(coefficients.get('M', g * m2))}


def own_reading(t: Term, factors: Dict[str, float], rig) -> Term:
    """The term as its sensor's own (carrier), on the sensor's channel, in the sensor's signal: coefficient, interval,
    contribution and budget divided by -factor; the sensor's band; the near-tied terms said on the moving cell.
    Any other term as it was."""
    sensor = None if t.channel != 'force_moving' else carrier(t.term)
    if sensor is None:
        return t
    k = -1.0 / factors[sensor]
    lo, hi = sorted((t.ci95[0] * k, t.ci95[1] * k))
    rms_lo, rms_hi = (v * abs(k) for v in t.rms_ci95)
    band = channel_band(sensor, rig)
    return dataclasses.replace(
        t, channel=sensor, term=term_name({CARRIED[sensor][0]: sum(parse_term(t.term).values())}),
        coefficient=t.coefficient * k, ci95=(lo, hi), rms=t.rms * abs(k), rms_ci95=(rms_lo, rms_hi), band=band,
        named=bool(rms_lo > band), budget={n: v * abs(k) for n, v in t.budget.items()},
        alternatives=tuple(f'{a} on force_moving' for a in (t.term, *t.alternatives)),
        beat=() if not t.beat else (f'{t.beat[0]} on force_moving', t.beat[1]))
