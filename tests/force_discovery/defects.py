"""Data-defect injectors for the tests (issue 12): each takes one pull's channels and returns a NEW dict
(the changed arrays are copies; the others are the caller's arrays, never written) plus the list of what
it did, as ``Injected(channel, kind, i0, i1)``: the samples i0 <= i < i1 of ``channel`` it changed, in
the new record's indices ('all' when every channel but time_s was changed).

Positions are drawn with the caller's rng: ``where='mixed'`` (default) puts the first half of the defects
inside the loaded window (from the stationary cell's rise above 10 % of its peak to its maximum, where the
coupon starts to break; away from its first 1 ms and its last 0.5 ms, where the elastic rise, the ringing
it starts and the break are) and the rest elsewhere in the record (the pre-pull record and the
quiet end, away from the pull); 'loaded' or 'elsewhere' puts all of them there.
"""
from __future__ import annotations

from typing import List, NamedTuple, Sequence, Tuple

import numpy as np

from force_discovery.core.quality import (
    ALL,
    CLIPPING,
    HELD,
    NONFINITE,
    SPIKE,
    STUCK,
    TIME_CHANNEL,
    TIME_GAP,
    TIME_NONMONOTONIC,
)

MIN_SPACING_S = 10e-3     # drawn defects are at least this far apart (each is found on its own)


class Injected(NamedTuple):
    channel: str
    kind: str
    i0: int
    i1: int


def loaded_window(ch: dict) -> Tuple[int, int]:
    """(first, last + 1) sample of the loading: from the stationary cell's first sample above 10 % of its peak
    to its maximum before the break (the break: its first fall below half of its maximum so far)."""
    fs = np.asarray(ch['force_stationary_n'], float)
    l0 = int(np.flatnonzero(fs > 0.1 * np.nanmax(fs))[0])
    run = np.maximum.accumulate(fs[l0:])
    brk = int(np.flatnonzero(fs[l0:] < 0.5 * run)[0])
    return l0, l0 + int(np.argmax(fs[l0:l0 + brk])) + 1


def _dt(ch: dict) -> float:
    t = np.asarray(ch[TIME_CHANNEL], float)
    return float(np.median(np.diff(t)))


def _positions(ch: dict, rng, n: int, length: int, where: str, avoid: Sequence[Injected] = ()) -> List[int]:
    """n start indices for defects of up to ``length`` samples (see the module doc), clear of each other and
    of ``avoid`` by MIN_SPACING_S (0.5 ms inside the loaded window; there only the start is placed, a defect
    may run past its end). With where='mixed', a defect that finds no room inside goes elsewhere."""
    dt = _dt(ch)
    size = len(ch[TIME_CHANNEL])
    l0, l1 = loaded_window(ch)
    inside = (l0 + int(1e-3 / dt), l1 - int(0.5e-3 / dt))
    away = int(50e-3 / dt)      # 'elsewhere' stays this far from the pull's events (taut, ringing, deceleration)
    outside = [(int(5e-3 / dt), l0 - away - length), (l1 + away, size - int(5e-3 / dt) - length)]
    n_in = {'mixed': (n + 1) // 2, 'loaded': n, 'elsewhere': 0}[where]
    taken = [(a.i0, a.i1) for a in avoid]

    def draw(spans, spacing):
        for _ in range(2000):
            lo, hi = spans[int(rng.integers(len(spans)))]
            if hi <= lo:
                continue
            i = int(rng.integers(lo, hi))
            if all(i + length + spacing <= a or i >= b + spacing for a, b in taken):
                return i
        return None

    out: List[int] = []
    for k in range(n):
        i = draw([inside], int(0.5e-3 / dt)) if k < n_in else None
        if i is None and (k >= n_in or where == 'mixed'):
            i = draw(outside, int(MIN_SPACING_S / dt))
        if i is None:
            raise ValueError(f'no room for defect {k + 1} of {n} ({length} samples, {where!r})')
        taken.append((i, i + length))
        out.append(i)
    return out


def add_spikes(ch: dict, rng, n: int = 3, amplitude: Tuple[float, float] = (200.0, 500.0),
               channel: str = 'force_moving_n', width: Tuple[int, int] = (1, 3), where: str = 'mixed',
               avoid: Sequence[Injected] = ()):
    """n spikes of random sign, height drawn in ``amplitude`` and width (samples) in ``width``, added to
    ``channel`` (clear of the defects in ``avoid``)."""
    out = dict(ch)
    x = np.array(ch[channel], float)
    inj = []
    for i in _positions(ch, rng, n, width[1], where, avoid):
        w = int(rng.integers(width[0], width[1] + 1))
        x[i:i + w] += rng.choice((-1.0, 1.0)) * rng.uniform(*amplitude)
        inj.append(Injected(channel, SPIKE, i, i + w))
    out[channel] = x
    return out, inj


def add_dropouts(ch: dict, rng, n: int = 3, duration_s: Tuple[float, float] = (1e-3, 5e-3),
                 channels: Sequence[str] | None = None, where: str = 'mixed', avoid: Sequence[Injected] = ()):
    """n DAQ buffer under-runs: every channel (or ``channels``) but time_s repeats its last value for a
    duration drawn in ``duration_s`` (time_s goes on: the DAQ stamps by sample count); clear of ``avoid``."""
    dt = _dt(ch)
    names = [c for c in ch if c != TIME_CHANNEL] if channels is None else list(channels)
    out = dict(ch)
    for c in names:
        out[c] = np.array(ch[c], float)
    inj = []
    longest = int(round(duration_s[1] / dt))
    for i in _positions(ch, rng, n, longest, where, avoid):
        m = int(round(rng.uniform(*duration_s) / dt))
        for c in names:
            out[c][i:i + m] = out[c][i - 1]
        label = ALL if channels is None else names[0] if len(names) == 1 else ','.join(names)
        inj.append(Injected(label, HELD, i, i + m))
    return out, inj


def add_clipping(ch: dict, level: float, channel: str = 'force_moving_n'):
    """``channel`` saturated at +-level (the sensor or ADC range). Injected: each run of clipped samples."""
    out = dict(ch)
    x = np.asarray(ch[channel], float)
    out[channel] = np.clip(x, -level, level)
    inj = []
    for sign in (1.0, -1.0):
        over = sign * x >= level
        edges = np.flatnonzero(np.diff(np.concatenate(([0], over.astype(np.int8), [0]))))
        inj += [Injected(channel, CLIPPING, int(a), int(b)) for a, b in zip(edges[::2], edges[1::2])]
    return out, sorted(inj, key=lambda r: r.i0)


def add_nonfinite(ch: dict, rng, n: int = 3, channel: str = 'accel_axial_m_s2', length: Tuple[int, int] = (1, 5),
                  value: float = np.nan, where: str = 'mixed'):
    """n runs of ``value`` (NaN or inf), each ``length`` samples long (drawn), in ``channel``."""
    out = dict(ch)
    x = np.array(ch[channel], float)
    inj = []
    for i in _positions(ch, rng, n, length[1], where):
        m = int(rng.integers(length[0], length[1] + 1))
        x[i:i + m] = value
        inj.append(Injected(channel, NONFINITE, i, i + m))
    out[channel] = x
    return out, inj


def add_time_gap(ch: dict, rng, missing: Tuple[int, int] = (1, 20), where: str = 'elsewhere'):
    """Samples dropped from every channel at one place (the record gets shorter; time_s jumps forward).
    Injected: the two samples on either side of the jump."""
    m = int(rng.integers(missing[0], missing[1] + 1))
    (i,) = _positions(ch, rng, 1, m, where)
    keep = np.ones(len(ch[TIME_CHANNEL]), bool)
    keep[i:i + m] = False
    out = {c: np.asarray(v)[keep] for c, v in ch.items()}
    return out, [Injected(TIME_CHANNEL, TIME_GAP, i - 1, i + 1)]


def add_time_step_back(ch: dict, rng, back: Tuple[int, int] = (1, 20), where: str = 'elsewhere'):
    """time_s steps back by a drawn number of sample intervals at one place and runs on from there (a clock
    reset). Injected: the two samples on either side of the step."""
    dt = _dt(ch)
    m = int(rng.integers(back[0], back[1] + 1))
    (i,) = _positions(ch, rng, 1, 1, where)
    out = dict(ch)
    t = np.array(ch[TIME_CHANNEL], float)
    t[i:] -= (m + 1) * dt
    out[TIME_CHANNEL] = t
    return out, [Injected(TIME_CHANNEL, TIME_NONMONOTONIC, i - 1, i + 1)]


def add_stuck(ch: dict, channel: str, value: float | None = None):
    """``channel`` constant over the whole record (its first sample unless ``value`` is given)."""
    out = dict(ch)
    x = np.asarray(ch[channel], float)
    out[channel] = np.full(len(x), x[0] if value is None else value)
    return out, [Injected(channel, STUCK, 0, len(x))]


def real_world_defects(campaign, seed: int, spikes: int = 3, dropouts: int = 3):
    """The defects seen on the rig, on every pull of a campaign (a new campaign list; metas shared): a few
    DAQ buffer under-runs (every channel holds its last value for 1-5 ms) and a few 200-500 N spikes on
    the moving cell, inside the loaded window and elsewhere. Returns (campaign, {pull file: [Injected]})."""
    out, truth = [], {}
    for k, (meta, ch) in enumerate(campaign):
        rng = np.random.default_rng([seed, k])
        ch, a = add_spikes(ch, rng, n=spikes)
        ch, b = add_dropouts(ch, rng, n=dropouts, avoid=a)
        out.append((meta, ch))
        truth[meta['file']] = a + b
    return out, truth
