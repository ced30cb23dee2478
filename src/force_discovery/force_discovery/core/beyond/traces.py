"""What the plots show of each named term: its channel's residual on one held-out pull before and after the term
is taken out (TermTrace). ROS-free."""
from __future__ import annotations

import math
from typing import Dict, NamedTuple, Sequence, Tuple

import numpy as np

from force_tester_sim.core.extra_terms import term_values

from .selection import Term
from .series import ChannelSeries, term_column


class TermTrace(NamedTuple):
    """One named term on one pull."""

    pull: str
    channel: str
    term: str
    t: np.ndarray               # s
    before: np.ndarray          # the channel's residual with the other named terms removed
    after: np.ndarray           # ... and with this term removed too


def term_traces(series: Dict[str, ChannelSeries], terms: Sequence[Term], pull: str) -> Tuple[TermTrace, ...]:
    """The TermTrace of each named term on one pull (series.channel_series). A sinusoid's phase is fitted on the
    pull (its amplitude is the term's)."""
    contrib = {}
    for ch in {t.channel for t in terms}:
        if ch not in series:
            continue
        y, sig = series[ch].residual, series[ch].signals
        prods = [t for t in terms if t.channel == ch and t.frequency_hz is None]
        rest = y - sum((t.coefficient * term_column(series[ch], t.term) for t in prods), np.zeros_like(y))
        for t in terms:
            if t.channel != ch:
                continue
            # a product term as its column is made (through the current's filter); a sinusoid's factor as it is
            fac = t.coefficient * (term_values(t.term, sig) if t.frequency_hz is not None
                                   else term_column(series[ch], t.term))
            if t.frequency_hz is not None:
                ph = 2 * np.pi * t.frequency_hz * sig['t']
                X = np.column_stack([fac * np.sin(ph), fac * np.cos(ph)])
                bs, bc = np.linalg.lstsq(X, rest, rcond=None)[0]
                fac = fac * np.sin(ph + math.atan2(bc, bs))
            contrib[(ch, t.term)] = (sig['t'], y, fac)
    out = []
    for t in terms:
        if (t.channel, t.term) not in contrib:
            continue
        tt, y, c = contrib[(t.channel, t.term)]
        others = sum((v[2] for k, v in contrib.items() if k[0] == t.channel and k != (t.channel, t.term)),
                     np.zeros_like(y))
        out.append(TermTrace(pull, t.channel, t.term, tt, y - others, y - others - c))
    return tuple(out)
