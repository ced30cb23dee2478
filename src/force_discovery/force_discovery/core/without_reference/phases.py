"""Pass 1 of the reference-free path on one pull: its events (either sign, any shape), its free phases, a first
g m2 and delay of its own, the ringing modes of its free decay and its free-phase residual (the hum's data).
The method is driver.py's docstring, steps 1, 2 and 4. ROS-free."""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional

import numpy as np

from force_tester_common.core.events import MAD_SD, event_spans

from .. import quality as Q
from ..errors import DiscoveryError
from ..identifiability import ACCEL, FORCE, FREE_CHANNELS
from ..prep import MASK_GROW_S, lowpassed
from ..ringing import matrix_pencil
from .delay_fit import Shifter, delay_grid, own_fit

FREE_MIN_SAMPLES = 200         # a record shorter than this is not a full record (40 ms at 5 kHz)
EDGE_S = 1e-3                  # the record's first and last ms are not fitted (the FFT filters' edges)
FREE_MARGIN_S = 2e-3           # first pass: free phases start this far (or a quarter event) from an event
EVENT_Z = 6.0                  # second pass: |F_move - G a2| above this many robust sd is in the event
EVENT_PAD_S = 0.5e-3           # ... grown by this much on each side (the low-pass's spread)
EVENT_GAP_S = 1e-3             # event samples closer than this are one event
MIN_FREE_SHARE = 0.05          # a pull with fewer free samples (of the record) cannot be fitted
RING_S = 0.03                  # the free decay analysed after the last event (at most RING_SAMPLES samples)
RING_SAMPLES = 800
RING_MIN_SAMPLES = 100
MODE_BAND = (20.0, 0.45)       # modes from 20 Hz to 0.45 x the sample rate ...
MODE_MAX_ZETA = 0.3            # ... with damping ratio below this
MODE_MIN_SHARE = 0.05          # ... and at least this share of the segment's energy
MODES_PER_PULL = 3
HUM_KEEP = 2000


# ------------------------------------------------------------------------------------------ per pull
@dataclass(frozen=True)
class FreePull:
    """What one pull's free phases hold (small: no record-length arrays but the ring and hum stretches)."""

    name: str
    dt: float
    samples: int
    events: tuple                    # ({sign, peak_n, start_s, end_s, width_s}, ...)
    free_share: float                # share of the record in free phases
    free_samples: int
    gain_mass: float                 # the pull's own G (own delay)
    delay_s: float                   # the pull's own d
    ring: Optional[np.ndarray]       # a2 in the free decay after the last event (None: too short)
    modes: tuple                     # ((frequency, damping ratio, energy share), ...) of ring, strongest first
    hum_t: np.ndarray                # free-phase residual F_move - G a2 (the hum's data): times ...
    hum_r: np.ndarray                # ... and values (at most HUM_KEEP samples, evenly thinned)
    accel_noise: float               # robust sd of a2's fourth difference scaled to white noise (quality)


def runs(mask: np.ndarray) -> list:
    if not mask.any():
        return []
    e = np.flatnonzero(np.diff(np.r_[0, mask.astype(np.int8), 0]))
    return list(zip(e[::2].tolist(), e[1::2].tolist()))


def grow(mask: np.ndarray, k: int) -> np.ndarray:
    if k <= 0 or not mask.any():
        return mask.copy()
    c = np.convolve(mask.astype(float), np.ones(2 * k + 1), mode='same')
    return c > 0.5



def prepared(name: str, ch: dict, screen: Q.PullScreen):
    """(t, dt, low-passed F_move, low-passed a2, usable mask) of one pull's channels."""
    t = np.asarray(ch['time_s'], float)
    n = len(t)
    if n < FREE_MIN_SAMPLES:
        raise DiscoveryError(f'pull {name!r} has {n} samples; expected a full record (>= {FREE_MIN_SAMPLES})')
    if screen.spans:
        ch = Q.repair(ch, screen)
        t = np.asarray(ch['time_s'], float)
    dt = float(np.median(np.diff(t)))
    ok = screen.combined(FREE_CHANNELS, grow_s=MASK_GROW_S)
    edge = max(3, int(round(EDGE_S / dt)))
    ok[:edge] = False
    ok[-edge:] = False
    return t, dt, lowpassed(ch[FORCE], dt), lowpassed(ch[ACCEL], dt), ok, np.asarray(ch[FORCE], float)


def free_pull(name: str, ch: dict, screen: Q.PullScreen) -> FreePull:
    """Pass 1 of the reference-free path on one pull (the module docstring's steps 1, 2 and 4, a first G and d)."""
    t, dt, fm, a2, ok, raw = prepared(name, ch, screen)
    n = len(t)
    rate = 1.0 / dt
    spans = event_spans(raw, rate)
    if not spans:
        raise DiscoveryError(f'pull {name!r}: no event in {FORCE!r} (its largest excursion is within '
                             'the noise); expected a pull, an impact or a braking load')
    near = np.zeros(n, bool)
    for a, b in spans:
        m = max(int(round(FREE_MARGIN_S / dt)), (b - a) // 4)
        near[max(0, a - m):min(n, b + m)] = True
    free = ok & ~near
    if free.sum() < MIN_FREE_SHARE * n:
        raise DiscoveryError(f'pull {name!r}: {int(free.sum())} free-phase samples; expected at least '
                             f'{MIN_FREE_SHARE:.0%} of the record outside the events')
    A = Shifter(a2, dt)
    g, d = own_fit(fm, A, free, delay_grid(dt))
    # second pass: the event is where the force departs from what the accelerometer explains
    r = fm - g * A(d)
    base = np.median(r[free])
    sd = MAD_SD * float(np.median(np.abs(r[free] - base)))
    out = np.abs(r - base) > EVENT_Z * max(sd, 1e-12)
    out &= near | grow(near, int(round(0.05 * n)))     # only around the events found (not a stray noise sample)
    gap = int(round(EVENT_GAP_S / dt))
    ev = np.zeros(n, bool)
    found = runs(out)
    if found:
        merged = [list(found[0])]
        for a, b in found[1:]:
            if a - merged[-1][1] <= gap:
                merged[-1][1] = b
            else:
                merged.append([a, b])
        for a, b in merged:
            ev[a:b] = True
    ev |= spans_mask(spans, n)
    ev = grow(ev, int(round(EVENT_PAD_S / dt)))
    free = ok & ~ev
    if free.sum() < MIN_FREE_SHARE * n:
        raise DiscoveryError(f'pull {name!r}: {int(free.sum())} free-phase samples; expected at least '
                             f'{MIN_FREE_SHARE:.0%} of the record outside the events')
    g, d = own_fit(fm, A, free, delay_grid(dt, [d]))
    r = fm - g * A(d)
    events = []
    for a, b in runs(ev):
        seg = raw[a:b] - np.median(raw)
        k = int(np.argmax(np.abs(seg)))
        events.append({'sign': 'tension' if seg[k] > 0 else 'compression', 'peak_n': float(raw[a + k]),
                       'start_s': float(t[a]), 'end_s': float(t[b - 1]), 'width_s': float((b - a) * dt)})
    last = max(b for _a, b in runs(ev))
    ring, modes = free_ring(a2, ok, last, dt)
    hum_i = np.flatnonzero(free)
    if len(hum_i) > HUM_KEEP:
        hum_i = hum_i[np.linspace(0, len(hum_i) - 1, HUM_KEEP).astype(int)]
    x = np.asarray(ch[ACCEL], float)
    fin = np.isfinite(x)
    r4 = (x[:-4] + x[4:] - 4.0 * (x[1:-3] + x[3:-1]) + 6.0 * x[2:-2])[fin[2:-2]] / 6.0
    noise = float(MAD_SD * np.median(np.abs(r4)) / math.sqrt(70.0) * 6.0) if len(r4) else 0.0
    return FreePull(name, dt, n, tuple(events), float(free.mean()), int(free.sum()), g, d, ring, modes,
                    t[hum_i], r[hum_i] - np.mean(r[hum_i]), noise)


def spans_mask(spans, n):
    m = np.zeros(n, bool)
    for a, b in spans:
        m[a:b] = True
    return m



def free_ring(a2: np.ndarray, ok: np.ndarray, last: int, dt: float):
    i0 = last
    i1 = min(len(a2), i0 + min(RING_SAMPLES, int(round(RING_S / dt))))
    if i1 - i0 < RING_MIN_SAMPLES or not ok[i0:i1].all():
        return None, ()
    y = a2[i0:i1] - np.mean(a2[i0:i1])
    total = float(y @ y)
    if total <= 0:
        return None, ()
    lo, hi = MODE_BAND[0], MODE_BAND[1] / dt
    mm = [(f, z, e / total) for f, z, e in matrix_pencil(y, dt, order=12)
          if lo < f < hi and 0 < z < MODE_MAX_ZETA and e / total > MODE_MIN_SHARE]
    return y, tuple(mm[:MODES_PER_PULL])


