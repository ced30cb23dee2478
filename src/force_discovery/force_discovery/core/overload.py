"""The data-quality screen's overloads found in the record itself (quality.screen_pull calls it): bursts that
one channel shows and the others do not, and, when two channels disagree, which one is blamed. ROS-free.

A burst is a channel's largest excursion when it is short and stands far above the rest of its record (bursts).
The rig's events (the break, an impact) are in every channel at once; a sensor or amplifier driven past its
range is in one. So a burst is an overload when no other coincidence channel has an event within
OVERLOAD_CONTEXT_S of it: an excursion reaching OVERLOAD_COINCIDENCE of that channel's largest one.

"Its largest one" is taken over the part of the record where the channel kept to its physics: what went beyond
its rated range or clipped (quality.py found those) is left out, and so is each burst already blamed, the burst
with the weakest counterpart blamed first (overloads). Without that, one channel's overload makes the other
channel's real event look lonely: a drop test's accelerometer that reads 500 m/s^2 during a 700 N impact and
bursts to 9000 m/s^2 8 ms later, with no force, made the impact a force-channel overload (issue 40). With it, the
accelerometer's burst (the force at its noise there) is blamed first; the impact is then the accelerometer's
largest excursion, and the force's impact has its counterpart.
"""
from __future__ import annotations

from typing import Dict, List, NamedTuple, Sequence, Tuple

import numpy as np

from force_tester_common.core.events import median

# A burst: <= 5 ms, > 1.5 x above everything else of its channel, > 50 x its noise; no other coincidence channel
# has an event within 2 ms of it (above 30 % of that channel's largest excursion): a sensor or amplifier driven
# past its range (an accelerometer's +/-9000 m/s^2 burst in a free phase).
OVERLOAD_MAX_S = 5e-3
OVERLOAD_RATIO = 1.5
OVERLOAD_SNR = 50.0
OVERLOAD_CONTEXT_S = 2e-3
OVERLOAD_COINCIDENCE = 0.3
OVERLOAD_EDGE = 0.25             # the burst's samples: above this share of its peak excursion
OVERLOAD_MAX_COUNT = 3           # bursts looked for per channel


class Burst(NamedTuple):
    """A channel's burst: its samples [i0, i1), its peak's sample and how many times the rest of the record it is."""

    i0: int
    i1: int
    at: int
    ratio: float


class Overload(NamedTuple):
    """A burst blamed on its channel: samples [i0, i1), its signed peak (from the record's median), its ratio."""

    channel: str
    i0: int
    i1: int
    peak: float
    ratio: float


def bursts(dev: np.ndarray, sigma: float, dt: float) -> List[Burst]:
    """A channel's bursts, largest first (dev: |x - median|; sigma: its noise). The largest excursion is one when it
    lasts <= OVERLOAD_MAX_S and stands OVERLOAD_RATIO x above the rest of the record and OVERLOAD_SNR x above the
    noise; then the next, on the rest, up to OVERLOAD_MAX_COUNT."""
    n = len(dev)
    w = max(1, int(round(OVERLOAD_MAX_S / dt)))
    g = max(1, int(round(OVERLOAD_CONTEXT_S / dt)))
    d = dev.copy()
    out = []
    for _ in range(OVERLOAD_MAX_COUNT):
        k = int(np.argmax(d))
        peak = float(d[k])
        if not peak > OVERLOAD_SNR * max(sigma, 1e-12):
            break
        big = np.flatnonzero(d[max(0, k - w):k + w + 1] > OVERLOAD_EDGE * peak) + max(0, k - w)
        i0, i1 = int(big[0]), int(big[-1]) + 1
        rest = np.concatenate((d[:max(0, i0 - g)], d[min(n, i1 + g):]))
        top_rest = float(np.max(rest)) if len(rest) else 0.0
        if i1 - i0 > w or peak < OVERLOAD_RATIO * top_rest:
            break
        out.append(Burst(i0, i1, k, peak / max(top_rest, 1e-12)))
        d[max(0, i0 - g):min(n, i1 + g)] = 0.0
    return out


def overloads(channels: Dict[str, Tuple[np.ndarray, float]], left: Dict[str, list], dt: float,
              coincidence: Sequence[str]) -> List[Overload]:
    """The overloads of one record (the module docstring).
    channels: channel -> (its samples, finite; its noise); left: channel -> the spans (i0, i1) where it already
    left its physics (beyond its rated range, clipped); coincidence: the channels that all see the rig's events.
    A channel with no other coincidence channel to compare is not judged. Of the bursts that have no
    counterpart, the one with the weakest is blamed, and the others are judged again without it; a burst with
    a counterpart is an event, and so are its channel's smaller ones."""
    g = max(1, int(round(OVERLOAD_CONTEXT_S / dt)))
    devs = {c: np.abs(x - median(x)) for c, (x, _s) in channels.items()}
    others = {c: [o for o in coincidence if o != c and o in devs] for c in devs}
    left = {c: list(left.get(c, ())) for c in devs}
    todo = {c: [b for b in bursts(devs[c], s, dt) if not any(b.i0 < e and s0 < b.i1 for s0, e in left[c])]
            for c, (_x, s) in channels.items() if others[c]}
    out = []

    def counterpart(c: str, i0: int, i1: int) -> float:
        """The largest share of its own largest excursion (where it kept to its physics) another channel
        reaches within OVERLOAD_CONTEXT_S of the burst."""
        best = 0.0
        for o in others[c]:
            d = devs[o].copy()
            for s0, e in left[o]:
                d[max(0, s0 - g):e + g] = 0.0
            top = float(np.max(d))
            if top > 0:
                best = max(best, float(np.max(devs[o][max(0, i0 - g):i1 + g])) / top)
        return best

    while True:
        now = sorted((counterpart(c, bs[0].i0, bs[0].i1), c) for c, bs in todo.items() if bs)
        for r, c in now:
            if r >= OVERLOAD_COINCIDENCE:
                todo[c] = []
        if not now or now[0][0] >= OVERLOAD_COINCIDENCE:
            return out
        c = now[0][1]
        b = todo[c].pop(0)
        x = channels[c][0]
        out.append(Overload(c, b.i0, b.i1, float(x[b.at] - median(x)), b.ratio))
        left[c].append((b.i0, b.i1))
