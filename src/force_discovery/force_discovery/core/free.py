"""Discovery without a reference (issue 26): what a campaign with only the moving cell and the accelerometer says.
ROS-free.

Another lab's rig may have no stationary reference cell, no encoder and no motor channels (campaign.yaml or its
channel map names them ``absent:``). Without the tension T the model of record F_move = T + m2 a2 cannot be
checked during an event, but wherever the cell carries only the mass in front of it -- a FREE PHASE: before
contact, after a break or a rebound, while braking -- it reads

    F_move = g m2 a2(t + d) + offset + hum            (g: the cell's gain, d: the accelerometer's delay)

which identifies the product G = g m2, the delay d, the free structure's ringing modes (in a2 after the event),
the mains hum and the data quality. g and m2 separate only with a reference (the stationary cell) or a known
calibration mass. The method, per pull:

1. Screen (quality.screen_pull, every channel present), repair, low-pass both channels alike (prep.lowpassed: the
   band scaled to the rate).
2. Events, of either sign and any shape (force_tester_common.core.events: |F_move - median| above 20 % of the
   record's largest excursion): a tension pull, a compression impact, a braking load. Free phases: first the
   samples away from the events (FREE_MARGIN_S or a quarter of the event's length); G and d fitted there; then the
   event is where F_move departs from G a2 by more than EVENT_Z robust standard deviations of that residual (the
   part of the force the accelerometer does not explain: a contact, a lanyard), grown by EVENT_PAD_S, and the
   free phases are the rest.
3. Per pull and per delay on a grid (DELAY_MAX_S either way, DELAY_STEP_SHARE of a sample; a2 shifted exactly in
   the frequency domain), the normal equations of F_move on a2 with the pull's own offset and hum (sine and cosine
   at the campaign's hum frequency) projected out: three numbers, so that every fit and held-out residual below
   needs the pull only through them.
4. Ringing: the strongest damped modes (matrix pencil) of a2 in the free decay after the last event.

The campaign: G and d fitted on all pulls pooled; with n >= 2 pulls every pull is held out once (leave-one-out:
the fit on the others scores it), which gives each cause its held-out evidence (significance.significance) and
each estimate a jackknife interval. n >= MIN_NAMED_PULLS (4): a cause is named as with a reference (significant
held out, interval outside its tolerance band). n = 2 or 3: the same numbers, but t >= 4 over so few held-out
pulls is not a standard they can meet; what departs consistently is `indicated`, nothing is named. n = 1:
per-pull estimates, no interval, no cause.
"""
# This module's docstring is the Method section of the reference-free report.md: keep it the method as run.
from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np

from force_tester_common.core.channels import CHANNELS, REQUIRED_CHANNELS
from force_tester_common.core.events import event_spans

from . import quality as Q
from .errors import DiscoveryError
from .hum import HUM_BAND_HZ
from .prep import MASK_GROW_S, lowpassed
from .ringing import MOUNT_MAX_FRACTION, damped_basis, matrix_pencil, ring_sse
from .significance import MIN_REL_REDUCTION, MIN_T, significance

FORCE, ACCEL = 'force_moving_n', 'accel_axial_m_s2'
FREE_CHANNELS = (FORCE, ACCEL)
REFERENCE_CHANNELS = ('force_stationary_n', 'encoder_position_m')
MIN_NAMED_PULLS = 4            # held-out pulls needed before a cause can meet t >= MIN_T
FREE_MIN_SAMPLES = 200         # a record shorter than this is not a full record (40 ms at 5 kHz)
EDGE_S = 1e-3                  # the record's first and last ms are not fitted (the FFT filters' edges)
FREE_MARGIN_S = 2e-3           # first pass: free phases start this far (or a quarter event) from an event
EVENT_Z = 6.0                  # second pass: |F_move - G a2| above this many robust sd is in the event
EVENT_PAD_S = 0.5e-3           # ... grown by this much on each side (the low-pass's spread)
EVENT_GAP_S = 1e-3             # event samples closer than this are one event
MIN_FREE_SHARE = 0.05          # a pull with fewer free samples (of the record) cannot be fitted
DELAY_MAX_S = 200e-6
DELAY_STEP_SHARE = 0.25        # the delay grid's step, in samples ...
DELAY_STEP_MIN_S = 2.5e-6      # ... but not finer than this (a parabola refines the minimum)
DELAY_LOCAL_STEPS = 8          # refits search this many steps either side of the first estimate(s)
RING_S = 0.03                  # the free decay analysed after the last event (at most RING_SAMPLES samples)
RING_SAMPLES = 800
RING_MIN_SAMPLES = 100
MODE_BAND = (20.0, 0.45)       # modes from 20 Hz to 0.45 x the sample rate ...
MODE_MAX_ZETA = 0.3            # ... with damping ratio below this
MODE_MIN_SHARE = 0.05          # ... and at least this share of the segment's energy
MODES_PER_PULL = 3
MODE_CLUSTER_REL = 0.05        # modes of different pulls within 5 % are one mode

# what each quantity needs, and why (report.json identifiable / not_identifiable)
QUANTITIES = (
    ('gain_mass_product', FREE_CHANNELS, 'g m2: the moving cell\'s gain times the mass in front of it, from the '
     'free phases (F_move = g m2 a2)'),
    ('accel_delay', FREE_CHANNELS, 'the accelerometer\'s delay against the moving cell, from the free phases'),
    ('ringing_modes', (ACCEL,), 'the free structure\'s modes in a2 after the event (a mount mode among them)'),
    ('mains_hum', (FORCE,), 'the line frequency and amplitude on the moving cell, from the free phases'),
    ('data_quality', (), 'spikes, overloads, clipping, held values, NaN, time gaps, stuck channels'),
    ('moving_cell_gain', ('force_stationary_n',), 'g and m2 separate only with a reference (the stationary cell) '
     'or a known calibration mass'),
    ('effective_mass', ('force_stationary_n',), 'g and m2 separate only with a reference (the stationary cell) or '
     'a known calibration mass'),
    ('ac_coupling', ('force_stationary_n',), 'the cell\'s slow decay is judged against the reference cell\'s '
     'force during the event'),
    ('corrected_force_error', ('force_stationary_n',), 'how far the corrected force is from the force at the '
     'specimen needs the cell at the specimen'),
    ('cell_damping', ('force_stationary_n',), 'measured on the stationary cell\'s free decay'),
    ('coulomb_friction', ('motor_current_a', 'encoder_position_m'), 'the drive\'s force balance needs the motor '
     'current and the carriage motion'),
    ('simulation_check', ('encoder_position_m', 'force_stationary_n'), 'the re-simulation is driven by the '
     'measured carriage motion and fitted to the tension'),
)
COMPUTED = ('gain_mass_product', 'accel_delay', 'ringing_modes', 'mains_hum', 'data_quality')


# ------------------------------------------------------------------------------------------ which path
def needs_reference_free(absent: Sequence[str]) -> bool:
    """Whether a campaign lacking these channels takes the reference-free path (no stationary cell or no
    encoder)."""
    return any(c in absent for c in REFERENCE_CHANNELS)


def check_core_channels(absent: Sequence[str], name: str = 'campaign') -> None:
    """One line when the moving cell (or the accelerometer) is absent: nothing to correct."""
    from bag_tools.core.daqfiles import NOTHING_TO_CORRECT
    for c in FREE_CHANNELS:
        if c in absent:
            raise DiscoveryError(f'{name} has no {c!r} channel; {NOTHING_TO_CORRECT}')


def identifiability(absent: Sequence[str], computed: Sequence[str] = COMPUTED, few: int = 0) -> Tuple[list, list]:
    """(identifiable, not_identifiable) for a campaign lacking ``absent``: each {quantity, needs, what} or
    {quantity, needs, missing, reason}; computed: what this analysis computes of the quantities whose channels
    are there (the rest is listed as not identifiable by this path, with the reason); few: the analysis with a
    reference was not run because it needs this many pulls."""
    yes, no = [], []
    for q, needs, what in QUANTITIES:
        missing = [c for c in needs if c in absent]
        if missing:
            no.append({'quantity': q, 'needs': list(needs), 'missing': missing,
                       'reason': f'needs {", ".join(missing)} (absent): {what}'})
        elif q in computed:
            yes.append({'quantity': q, 'needs': list(needs), 'what': what})
        elif few:
            no.append({'quantity': q, 'needs': list(needs), 'missing': [],
                       'reason': f'needs at least {few} pulls (half fitted, half held out) for the analysis with a '
                                 f'reference: {what}'})
        else:
            no.append({'quantity': q, 'needs': list(needs), 'missing': [c for c in REFERENCE_CHANNELS if c in absent],
                       'reason': f'its channels are here, but the analysis with a reference needs '
                                 f'{" and ".join(REFERENCE_CHANNELS)} together: {what}'})
    return yes, no


def full_identifiability(tested: Sequence[str]) -> Tuple[list, list]:
    """(identifiable, not_identifiable) of a campaign with its reference: the catalog causes tested (``tested``)
    and the simulation check; coulomb_friction without a motor current channel is not identifiable."""
    yes = [{'quantity': q, 'needs': list(needs), 'what': what} for q, needs, what in QUANTITIES
           if q in tested or q in ('data_quality', 'simulation_check', 'cell_damping')]
    yes += [{'quantity': q, 'needs': list(REFERENCE_CHANNELS + FREE_CHANNELS), 'what': 'catalog cause'}
            for q in tested if q not in {y['quantity'] for y in yes}]
    no = [] if 'coulomb_friction' in tested else [
        {'quantity': 'coulomb_friction', 'needs': ['motor_current_a', 'encoder_position_m'],
         'missing': ['motor_current_a'], 'reason': 'needs motor_current_a (absent): the drive\'s force balance'}]
    return yes, no


def identifiability_lines(report: dict) -> list:
    """report.md's lines on what the channels identify (both paths)."""
    if 'identifiable' not in report:
        return []
    out = ['## Identifiable from these channels', '',
           ', '.join(q['quantity'] for q in report['identifiable']) or '-', '']
    if report['not_identifiable']:
        out += ['Not identifiable:', ''] + [f'- {q["quantity"]}: {q["reason"]}' for q in report['not_identifiable']]
        out.append('')
    return out


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


@dataclass(frozen=True)
class FreeStats:
    """Pass 2 of one pull: per delay on the grid, the normal equations (ff, fa, aa) of F_move on a2(t + d) with
    the offset (and the hum at the campaign's frequency) projected out; with and without the hum."""

    delays: np.ndarray
    hum: np.ndarray                  # (len(delays), 3): ff, fa, aa with the hum projected out
    nohum: np.ndarray                # ... without
    hum_amp: float                   # the pull's hum amplitude at G, d of its own
    samples: int


HUM_KEEP = 2000


class Shifter:
    """x(t + d) for any d, band-limited (exact in the frequency domain; the end trend removed first and put
    back): the spectrum computed once."""

    def __init__(self, x: np.ndarray, dt: float):
        n = len(x)
        self.n, self.dt = n, dt
        self.trend = np.linspace(x[0], x[-1], n)
        self.slope = (x[-1] - x[0]) / (dt * (n - 1))
        self.X = np.fft.rfft(x - self.trend)
        self.w = 2 * np.pi * np.fft.rfftfreq(n, dt)

    def __call__(self, d: float) -> np.ndarray:
        return np.fft.irfft(self.X * np.exp(1j * self.w * d), self.n) + self.trend + self.slope * d


def _events(fm: np.ndarray, rate: float) -> list:
    return event_spans(fm, rate)


def _runs(mask: np.ndarray) -> list:
    if not mask.any():
        return []
    e = np.flatnonzero(np.diff(np.r_[0, mask.astype(np.int8), 0]))
    return list(zip(e[::2].tolist(), e[1::2].tolist()))


def _grow(mask: np.ndarray, k: int) -> np.ndarray:
    if k <= 0 or not mask.any():
        return mask.copy()
    c = np.convolve(mask.astype(float), np.ones(2 * k + 1), mode='same')
    return c > 0.5


def _fit(fm: np.ndarray, a: np.ndarray, w: np.ndarray) -> Tuple[float, float]:
    """(G, SSE) of fm = G a + offset on the samples w (least squares, closed form)."""
    f = fm[w] - np.mean(fm[w])
    x = a[w] - np.mean(a[w])
    xx, xf = float(x @ x), float(x @ f)
    g = xf / xx if xx > 0 else 0.0
    return g, float(f @ f) - g * xf


def _delay_grid(dt: float, around: Sequence[float] = ()) -> np.ndarray:
    """The delays tried: +/-DELAY_MAX_S in steps of DELAY_STEP_SHARE samples (at least DELAY_STEP_MIN_S); with
    ``around``, only from DELAY_LOCAL_STEPS steps below the least of them and 0 to as far above the largest."""
    step = max(DELAY_STEP_SHARE * dt, DELAY_STEP_MIN_S)
    k = int(math.floor(DELAY_MAX_S / step))
    grid = np.arange(-k, k + 1) * step
    if len(around):
        lo = min(min(around), 0.0) - DELAY_LOCAL_STEPS * step
        hi = max(max(around), 0.0) + DELAY_LOCAL_STEPS * step
        grid = grid[(grid >= lo) & (grid <= hi)]
    return grid


def _best_on_grid(delays: np.ndarray, sse: np.ndarray) -> float:
    """The minimum of sse over the grid, refined by a parabola through the best point and its neighbours."""
    i = int(np.argmin(sse))
    if 0 < i < len(sse) - 1 and np.isfinite(sse[i - 1:i + 2]).all():
        y0, y1, y2 = sse[i - 1], sse[i], sse[i + 1]
        den = y0 - 2 * y1 + y2
        if den > 0:
            return float(delays[i] + 0.5 * (y0 - y2) / den * (delays[1] - delays[0]))
    return float(delays[i])


def _interp_stats(delays: np.ndarray, tab: np.ndarray, d: float) -> np.ndarray:
    return np.array([np.interp(d, delays, tab[:, k]) for k in range(tab.shape[1])])


def _prepared(name: str, ch: dict, screen: Q.PullScreen):
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
    t, dt, fm, a2, ok, raw = _prepared(name, ch, screen)
    n = len(t)
    rate = 1.0 / dt
    spans = _events(raw, rate)
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
    g, d = _own_fit(fm, A, free, _delay_grid(dt))
    # second pass: the event is where the force departs from what the accelerometer explains
    r = fm - g * A(d)
    base = np.median(r[free])
    sd = 1.4826 * float(np.median(np.abs(r[free] - base)))
    out = np.abs(r - base) > EVENT_Z * max(sd, 1e-12)
    out &= near | _grow(near, int(round(0.05 * n)))     # only around the events found (not a stray noise sample)
    gap = int(round(EVENT_GAP_S / dt))
    ev = np.zeros(n, bool)
    runs = _runs(out)
    if runs:
        merged = [list(runs[0])]
        for a, b in runs[1:]:
            if a - merged[-1][1] <= gap:
                merged[-1][1] = b
            else:
                merged.append([a, b])
        for a, b in merged:
            ev[a:b] = True
    ev |= _spans_mask(spans, n)
    ev = _grow(ev, int(round(EVENT_PAD_S / dt)))
    free = ok & ~ev
    if free.sum() < MIN_FREE_SHARE * n:
        raise DiscoveryError(f'pull {name!r}: {int(free.sum())} free-phase samples; expected at least '
                             f'{MIN_FREE_SHARE:.0%} of the record outside the events')
    g, d = _own_fit(fm, A, free, _delay_grid(dt, [d]))
    r = fm - g * A(d)
    events = []
    for a, b in _runs(ev):
        seg = raw[a:b] - np.median(raw)
        k = int(np.argmax(np.abs(seg)))
        events.append({'sign': 'tension' if seg[k] > 0 else 'compression', 'peak_n': float(raw[a + k]),
                       'start_s': float(t[a]), 'end_s': float(t[b - 1]), 'width_s': float((b - a) * dt)})
    last = max(b for _a, b in _runs(ev))
    ring, modes = _ring(a2, ok, last, dt)
    hum_i = np.flatnonzero(free)
    if len(hum_i) > HUM_KEEP:
        hum_i = hum_i[np.linspace(0, len(hum_i) - 1, HUM_KEEP).astype(int)]
    x = np.asarray(ch[ACCEL], float)
    fin = np.isfinite(x)
    r4 = (x[:-4] + x[4:] - 4.0 * (x[1:-3] + x[3:-1]) + 6.0 * x[2:-2])[fin[2:-2]] / 6.0
    noise = float(1.4826 * np.median(np.abs(r4)) / math.sqrt(70.0) * 6.0) if len(r4) else 0.0
    return FreePull(name, dt, n, tuple(events), float(free.mean()), int(free.sum()), g, d, ring, modes,
                    t[hum_i], r[hum_i] - np.mean(r[hum_i]), noise)


def _spans_mask(spans, n):
    m = np.zeros(n, bool)
    for a, b in spans:
        m[a:b] = True
    return m


def _own_fit(fm, A: Shifter, free, delays) -> Tuple[float, float]:
    """(G, d) of one pull: the delay minimizing the SSE on the grid (parabola refined), G there. G keeps the sign
    it has at d = 0: past half a period of the ringing, a delay with G of the other sign fits as well."""
    fits = [_fit(fm, A(d), free) for d in delays]
    sign = np.sign(fits[int(np.argmin(np.abs(delays)))][0]) or 1.0
    sse = np.array([e if np.sign(g) == sign else np.inf for g, e in fits])
    d = _best_on_grid(delays, sse)
    return _fit(fm, A(d), free)[0], d


def _ring(a2: np.ndarray, ok: np.ndarray, last: int, dt: float):
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


def free_stats(name: str, ch: dict, screen: Q.PullScreen, f_hum: float, fp: FreePull,
               delays: np.ndarray) -> FreeStats:
    """Pass 2 of one pull: the normal equations per delay of the grid ``delays`` (the campaign's: every pull's
    delay and 0 inside it), with and without the hum at f_hum."""
    t, dt, fm, a2, ok, raw = _prepared(name, ch, screen)
    n = len(t)
    # the same free phases as pass 1: outside the events it found
    ev = np.zeros(n, bool)
    for e in fp.events:
        ev[(t >= e['start_s']) & (t <= e['end_s'])] = True
    free = ok & ~ev
    A = Shifter(a2, dt)
    tf = t[free]
    one = np.ones(len(tf))
    hum_cols = np.column_stack([one, np.sin(2 * np.pi * f_hum * tf), np.cos(2 * np.pi * f_hum * tf)])
    out = {}
    for key, N in (('hum', hum_cols), ('nohum', one[:, None])):
        Qn, _ = np.linalg.qr(N)
        f = fm[free] - Qn @ (Qn.T @ fm[free])
        rows = []
        for d in delays:
            a = A(d)[free]
            a = a - Qn @ (Qn.T @ a)
            rows.append((float(f @ f), float(f @ a), float(a @ a)))
        out[key] = np.array(rows)
    r = fm[free] - fp.gain_mass * A(fp.delay_s)[free]
    c, *_ = np.linalg.lstsq(hum_cols, r, rcond=None)
    return FreeStats(delays, out['hum'], out['nohum'], float(math.hypot(c[1], c[2])), int(free.sum()))


# ------------------------------------------------------------------------------------------ the campaign
def _pooled(stats: Sequence[FreeStats], idx: Sequence[int], key: str = 'hum') -> Tuple[float, float]:
    """(G, d) fitted on the pulls idx pooled: the delay minimizing the summed SSE (parabola refined), G there."""
    delays = stats[idx[0]].delays
    tab = sum(getattr(stats[j], key) for j in idx)
    sse = tab[:, 0] - tab[:, 1] ** 2 / np.maximum(tab[:, 2], 1e-300)
    sign = np.sign(tab[int(np.argmin(np.abs(delays))), 1]) or 1.0      # G's sign at d = 0 (see _own_fit)
    sse = np.where(np.sign(tab[:, 1]) == sign, sse, np.inf)
    d = _best_on_grid(delays, sse)
    ff, fa, aa = _interp_stats(delays, tab, d)
    return fa / aa, d


def _sse(st: FreeStats, g: float, d: float, key: str = 'hum') -> float:
    ff, fa, aa = _interp_stats(st.delays, getattr(st, key), d)
    return max(0.0, ff - 2 * g * fa + g * g * aa)


def _t_quantile(n: int) -> float:
    from scipy.stats import norm, t
    return float(t.ppf(0.975, n - 1)) if n >= 2 else float(norm.ppf(0.975))


def _jackknife(est: float, loo: Sequence[float]) -> Optional[List[float]]:
    n = len(loo)
    if n < 2:
        return None
    m = float(np.mean(loo))
    se = math.sqrt((n - 1) / n * float(np.sum((np.asarray(loo) - m) ** 2)))
    h = _t_quantile(n) * se
    return [est - h, est + h]


def _mean_ci(x: Sequence[float]) -> Optional[List[float]]:
    x = np.asarray(x, float)
    if len(x) < 2:
        return None
    h = _t_quantile(len(x)) * float(np.std(x, ddof=1)) / math.sqrt(len(x))
    return [float(x.mean() - h), float(x.mean() + h)]


def _cluster_modes(pulls: Sequence[FreePull]) -> list:
    """Modes seen in at least half the pulls (frequencies within MODE_CLUSTER_REL): [{frequency_hz, damping_ratio,
    pulls, per_pull}], by how many pulls show it, then the energy."""
    allm = sorted((f, z, e, j) for j, p in enumerate(pulls) for f, z, e in p.modes)
    groups: list = []
    for m in allm:
        if groups and m[0] <= groups[-1][-1][0] * (1 + MODE_CLUSTER_REL):
            groups[-1].append(m)
        else:
            groups.append([m])
    out = []
    need = max(1, math.ceil(len(pulls) / 2))
    for g in groups:
        per = {}
        for f, z, e, j in g:
            if j not in per or e > per[j][2]:
                per[j] = (f, z, e)
        if len(per) < need:
            continue
        fs = [v[0] for v in per.values()]
        zs = [v[1] for v in per.values()]
        out.append({'frequency_hz': float(np.median(fs)), 'damping_ratio': float(np.median(zs)),
                    'frequency_ci95': _mean_ci(fs), 'damping_ci95': _mean_ci(zs), 'pulls': len(per),
                    'energy_share': float(np.median([v[2] for v in per.values()])),
                    'per_pull': {pulls[j].name: [v[0], v[1]] for j, v in sorted(per.items())}})
    out.sort(key=lambda m: (-m['pulls'], -m['energy_share']))
    return out


def _verdict(n: int, ev, inside: Optional[bool], outside: Optional[bool], per_pull_better: bool) -> str:
    if n < 2:
        return 'per_pull_only'
    if inside:
        return 'within_tolerance'
    if n < MIN_NAMED_PULLS:
        return 'indicated' if (ev.rel_sse_reduction >= MIN_REL_REDUCTION and per_pull_better and outside) \
            else 'not_indicated'
    if not ev.significant:
        return 'not_significant'
    return 'named' if outside else 'inconclusive'


def _evidence_dict(ev, base, ext) -> dict:
    return {'statistic': 'held-out (leave-one-out) free-phase SSE reduction and t of the per-pull reductions',
            'rel_sse_reduction': ev.rel_sse_reduction, 't': ev.t, 'rms_gain': ev.rms_gain,
            'threshold': f'rel >= {MIN_REL_REDUCTION:g} and t >= {MIN_T:g} over >= {MIN_NAMED_PULLS} held-out pulls',
            'significant': bool(ev.significant), 'per_pull_rel_reduction': [float(1 - e / b) if b > 0 else 0.0
                                                                          for b, e in zip(base, ext)]}


def campaign_analysis(pulls: Sequence[FreePull], stats: Sequence[FreeStats], f_hum: float, rig) -> dict:
    """The campaign's estimates, their intervals, the held-out evidence and the verdicts (report.json's core)."""
    n = len(pulls)
    fc = rig.force_chain
    tol = rig.tolerances
    g0 = fc.m2                        # the model of record: g = 1, the rig's m2, no delay
    allj = list(range(n))
    G, d = _pooled(stats, allj)
    loo = [_pooled(stats, [k for k in allj if k != j]) for j in allj] if n >= 2 else []
    hum_amps = [s.hum_amp for s in stats]
    # held-out SSE of each pull under the nested models
    if n >= 2:
        base = np.array([_sse(stats[j], g0, 0.0, 'nohum') for j in allj])
        lo = [_pooled(stats, [k for k in allj if k != j], 'nohum') for j in allj]
        full_nohum = np.array([_sse(stats[j], *lo[j], 'nohum') for j in allj])
        full = np.array([_sse(stats[j], *loo[j], 'hum') for j in allj])
        no_delay = np.array([_sse(stats[j], _gain_at(stats, [k for k in allj if k != j], 0.0), 0.0, 'hum')
                             for j in allj])
    else:
        base = np.array([_sse(stats[0], g0, 0.0, 'nohum')])
        full_nohum = np.array([_sse(stats[0], G, d, 'nohum')])
        full = np.array([_sse(stats[0], G, d, 'hum')])
        no_delay = np.array([_sse(stats[0], _gain_at(stats, [0], 0.0), 0.0, 'hum')])
    # the G cause: nominal g m2 vs fitted G (delay fitted in both); the delay: G alone vs G and d; hum: without/with
    g_nom_d = np.array([_sse(stats[j], g0, loo[j][1] if n >= 2 else d, 'hum') for j in allj])
    causes = {}
    band_g = (tol.moving_cell_gain_rel + tol.effective_mass_rel) * g0
    ci_g = _jackknife(G, [x[0] for x in loo])
    ci_d = _jackknife(d, [x[1] for x in loo])
    amp = float(np.mean(hum_amps))
    ci_h = _mean_ci(hum_amps)

    def entry(name, params, ci, ev_base, ev_ext, inside, outside, channel, extra=None):
        ev = significance(ev_base, ev_ext)
        better = bool(np.all(ev_ext < ev_base))
        v = _verdict(n, ev, inside, outside, better)
        causes[name] = {'name': name, 'parameters': params, 'parameters_ci95': ci, 'verdict': v,
                        'evidence': _evidence_dict(ev, ev_base, ev_ext), 'channel': channel, **(extra or {})}

    def band_test(ci, est, lo_, hi_):
        lo_ci, hi_ci = (ci if ci is not None else (est, est))
        return lo_ <= lo_ci and hi_ci <= hi_, hi_ci < lo_ or lo_ci > hi_

    ins, outs = band_test(ci_g, G, g0 - band_g, g0 + band_g)
    entry('gain_mass_product', {'gain_mass_kg': G}, {'gain_mass_kg': ci_g}, g_nom_d, full, ins if n >= 2 else None,
          outs, 'force_moving_n = g m2 a2(t + d), free phases',
          {'model_of_record': {'gain_mass_kg': g0, 'band_kg': [g0 - band_g, g0 + band_g]}})
    ins, outs = band_test(ci_d, d, -tol.accel_delay_s, tol.accel_delay_s)
    entry('accel_delay', {'delay_s': d}, {'delay_s': ci_d}, no_delay, full, ins if n >= 2 else None, outs,
          'force_moving_n = g m2 a2(t + d), free phases', {'band_s': [-tol.accel_delay_s, tol.accel_delay_s]})
    ins, outs = band_test(ci_h, amp, 0.0, tol.mains_hum_amplitude_n)
    entry('mains_hum', {'frequency_hz': f_hum, 'amplitude_n': amp}, {'amplitude_n': ci_h}, full_nohum, full,
          ins if n >= 2 else None, outs, 'force_moving_n - g m2 a2(t + d), free phases',
          {'band_n': [0.0, tol.mains_hum_amplitude_n]})
    modes = _cluster_modes(pulls)
    f_cell = math.sqrt(fc.load_cell_stiffness_n_per_m / fc.m2) / (2 * np.pi)
    noise = float(np.median([p.accel_noise for p in pulls]))
    mount = next((m for m in modes if m['frequency_hz'] < MOUNT_MAX_FRACTION * f_cell), None)
    if mount is not None:
        cell = [(f_cell, fc.load_cell_damping_ratio)]
        b, e, r2n = [], [], []
        for p in pulls:
            if p.ring is None:
                continue
            others = [v for k, v in mount['per_pull'].items() if k != p.name] if n >= 2 else \
                list(mount['per_pull'].values())
            if not others:
                continue
            mode = (float(np.median([o[0] for o in others])), float(np.median([o[1] for o in others])))
            b.append(ring_sse(p.ring, p.dt, cell))
            e.append(ring_sse(p.ring, p.dt, cell + [mode]))
            X = np.column_stack([damped_basis(len(p.ring), p.dt, *mode), np.ones(len(p.ring))])
            c, *_ = np.linalg.lstsq(X, p.ring, rcond=None)
            r2n.append(float(np.sqrt(np.mean((X[:, :2] @ c[:2]) ** 2)) / max(p.accel_noise, 1e-12)))
        if b:
            rn = float(np.median(r2n))
            entry('mount_resonance', {'frequency_hz': mount['frequency_hz'], 'damping_ratio': mount['damping_ratio']},
                  {'frequency_hz': mount['frequency_ci95'], 'damping_ratio': mount['damping_ci95']}, np.array(b),
                  np.array(e), rn < tol.mount_ring_to_noise if n >= 2 else None, rn >= tol.mount_ring_to_noise,
                  'accel_axial_m_s2, free decay after the last event',
                  {'cell_mode_hz': f_cell, 'ring_to_noise': rn,
                   'frequency_rule': f'observed < {MOUNT_MAX_FRACTION} x the rig\'s cell mode '
                                     f'({MOUNT_MAX_FRACTION * f_cell:.0f} Hz)'})
    order = ('mount_resonance', 'accel_delay', 'gain_mass_product', 'mains_hum')
    named = sorted((k for k in order if k in causes and causes[k]['verdict'] == 'named'),
                   key=lambda k: -causes[k]['evidence']['rel_sse_reduction'])
    per_pull = [{'pull': p.name, 'gain_mass_kg': p.gain_mass, 'delay_s': p.delay_s, 'hum_amplitude_n': s.hum_amp,
                 'free_share': p.free_share, 'events': list(p.events),
                 'modes': [{'frequency_hz': f, 'damping_ratio': z, 'energy_share': e} for f, z, e in p.modes]}
                for p, s in zip(pulls, stats)]
    return {'G': G, 'd': d, 'causes': causes, 'named': named, 'modes': modes, 'per_pull': per_pull,
            'baseline_sse': float(base.sum()), 'extended_sse': float(full.sum()),
            'samples': int(sum(s.samples for s in stats)), 'accel_noise': noise, 'cell_mode_hz': f_cell}


def _gain_at(stats: Sequence[FreeStats], idx: Sequence[int], d: float) -> float:
    tab = sum(_interp_stats(stats[j].delays, stats[j].hum, d) for j in idx)
    return float(tab[1] / tab[2])


def validation_text(n: int) -> dict:
    """What the number of pulls supports (report.json validation)."""
    if n == 1:
        return {'method': 'per-pull', 'pulls': 1,
                'supports': 'the pull\'s own estimates (g m2, delay, modes, hum, data quality)',
                'cannot_support': 'an interval, a held-out check, or a cause: one pull cannot tell an effect '
                                  'from that pull\'s own scatter'}
    if n < MIN_NAMED_PULLS:
        return {'method': 'leave-one-out', 'pulls': n,
                'supports': f'each estimate fitted on {n - 1} pull(s) and checked on the one left out; the '
                            'per-pull agreement; a jackknife interval (wide: Student t with '
                            f'{n - 1} degree(s) of freedom)',
                'cannot_support': f'a named cause: the held-out test needs t >= {MIN_T:g} over at least '
                                  f'{MIN_NAMED_PULLS} held-out pulls; what departs on every held-out pull is '
                                  '`indicated`, not named'}
    return {'method': 'leave-one-out', 'pulls': n,
            'supports': f'each estimate fitted on {n - 1} pulls and checked on the one left out, every pull held '
                        f'out once; named causes (t >= {MIN_T:g} over the {n} held-out pulls, interval outside '
                        'the tolerance band)',
            'cannot_support': 'g and m2 separately (no reference), anything needing an absent channel'}


# ------------------------------------------------------------------------------------------ report
def free_report(analysis: Optional[dict], pulls: Sequence[FreePull], absent: Sequence[str], screens: Sequence,
                excluded: Dict[str, str], failed: Sequence, rig, notes: Sequence[str] = (), few: int = 0) -> dict:
    """report.json of the reference-free path (few: run because the campaign has fewer pulls than this)."""
    from .report import clean
    yes, no = identifiability(absent, few=few)
    n = len(pulls)
    rep = {'reference': False, 'absent': list(absent),
           'channels': [c for c in CHANNELS if c not in absent and (c in REQUIRED_CHANNELS or c in FREE_CHANNELS)],
           'identifiable': yes, 'not_identifiable': no, 'validation': validation_text(max(n, 1)),
           'pulls': [p.name for p in pulls], 'fitted_pulls': [p.name for p in pulls],
           'held_out_pulls': [p.name for p in pulls] if n >= 2 else [],
           'data_quality': Q.defect_dicts(screens), 'excluded_pulls': dict(excluded),
           'failed_pulls': [{'pull': p, 'error': e} for p, e in failed], 'notes': list(notes)}
    rep['notes'].append('g and m2 separate only with a reference (the stationary cell) or a known calibration '
                        'mass: the free phases give their product g m2')
    if analysis is None:
        rep.update(cause='unexplained', causes=[], candidates={}, gain=None, baseline_error=None,
                   extended_error=None, modes=[], per_pull=[])
        return clean(rep)
    c = analysis['causes']
    named = analysis['named']
    if n == 1:
        cause = 'none'
        rep['notes'].append('one pull: per-pull estimates only, no cause')
    else:
        cause = named[0] if named else 'none'
        ind = [k for k, v in c.items() if v['verdict'] == 'indicated']
        if ind:
            rep['notes'].append(f'indicated (departs on every held-out pull, too few pulls to name): '
                                f'{", ".join(ind)}')
    samples = max(analysis['samples'], 1)
    rep.update(cause=cause, causes=[c[k] for k in named], candidates=c,
               indicated=[c[k] for k in c if c[k]['verdict'] == 'indicated'],
               within_tolerance=[c[k] for k in c if c[k]['verdict'] == 'within_tolerance'],
               inconclusive=[c[k] for k in c if c[k]['verdict'] == 'inconclusive'],
               metric='RMS moving-cell residual in the free phases, held out (leave-one-out); baseline: '
                      'g m2 = the rig\'s m2, no delay, no hum',
               baseline_error=math.sqrt(analysis['baseline_sse'] / samples),
               extended_error=math.sqrt(analysis['extended_sse'] / samples),
               modes=analysis['modes'], per_pull=analysis['per_pull'], cell_mode_hz=analysis['cell_mode_hz'])
    rep['gain'] = rep['baseline_error'] / rep['extended_error'] if rep['extended_error'] else None
    return clean(rep)


def _fmt_ci(ci, scale=1.0, fmt='.4g') -> str:
    if not ci or ci[0] is None:
        return '-'
    return f'[{ci[0] * scale:{fmt}}, {ci[1] * scale:{fmt}}]'


def free_markdown(rep: dict, screens: Sequence) -> str:
    """report.md of the reference-free path."""
    lines = ['# Discovery without a reference', '',
             f'Channels: {", ".join(rep["channels"])}; absent: {", ".join(rep["absent"]) or "-"}. '
             f'{len(rep["pulls"])} usable pulls ({rep["validation"]["method"]}).', '',
             f'**Cause: {rep["cause"]}**' + (f' (named: {", ".join(c["name"] for c in rep["causes"])})'
                                             if rep['causes'] else ''), '']
    if rep.get('gain'):
        lines += [f'{rep["metric"]}: {rep["baseline_error"]:.4g} N -> {rep["extended_error"]:.4g} N '
                  f'(x{rep["gain"]:.3g}).', '']
    lines += ['## Identifiable from these channels', '', '| quantity | from | what |', '|---|---|---|']
    lines += [f'| {q["quantity"]} | {", ".join(q["needs"]) or "every channel"} | {q["what"]} |'
              for q in rep['identifiable']]
    lines += ['', '## Not identifiable', '', '| quantity | needs | why |', '|---|---|---|']
    lines += [f'| {q["quantity"]} | {", ".join(q["needs"])} | {q["reason"]} |' for q in rep['not_identifiable']]
    v = rep['validation']
    lines += ['', '## What the number of pulls supports', '', f'- method: {v["method"]} over {v["pulls"]} pull(s)',
              f'- supports: {v["supports"]}', f'- cannot support: {v["cannot_support"]}', '']
    if rep.get('candidates'):
        lines += ['## Estimates', '', '| quantity | estimate | 95 % interval | held-out rel. reduction | t | verdict |',
                  '|---|---|---|---|---|---|']
        for name, c in rep['candidates'].items():
            p = ', '.join(f'{k} {val:.6g}' for k, val in c['parameters'].items())
            ci = '; '.join(f'{k} {_fmt_ci(val, fmt=".6g")}' for k, val in c['parameters_ci95'].items() if val)
            ev = c['evidence']
            t = 'inf' if ev['t'] is None else f'{ev["t"]:.3g}'
            lines.append(f'| {name} | {p} | {ci or "-"} | {ev["rel_sse_reduction"]:.3g} | {t} | {c["verdict"]} |')
        lines.append('')
    if rep.get('modes'):
        lines += ['## Ringing modes (a2, free decay after the last event)', '',
                  f'The rig\'s cell mode: {rep["cell_mode_hz"]:.0f} Hz.', '',
                  '| frequency (Hz) | damping ratio | pulls | 95 % interval (Hz) |', '|---|---|---|---|']
        lines += [f'| {m["frequency_hz"]:.1f} | {m["damping_ratio"]:.4f} | {m["pulls"]} | '
                  f'{_fmt_ci(m["frequency_ci95"], fmt=".1f")} |' for m in rep['modes']]
        lines.append('')
    if rep.get('per_pull'):
        lines += ['## Per pull', '', '| pull | events | g m2 (kg) | delay (us) | hum (N) | free share |',
                  '|---|---|---|---|---|---|']
        for p in rep['per_pull']:
            evs = '; '.join(f'{e["sign"]} {e["peak_n"]:.4g} N at {e["start_s"]:.4f} s, {1e3 * e["width_s"]:.3g} ms'
                            for e in p['events'])
            lines.append(f'| {p["pull"]} | {evs} | {p["gain_mass_kg"]:.5g} | {1e6 * p["delay_s"]:.3g} | '
                         f'{p["hum_amplitude_n"]:.3g} | {p["free_share"]:.2f} |')
        lines.append('')
    if rep['notes']:
        lines += ['## Notes', ''] + [f'- {x}' for x in rep['notes']] + ['']
    if rep.get('failed_pulls'):
        lines += ['Pulls that could not be read or analysed:', ''] + \
                 [f'- {f["pull"]}: {f["error"]}' for f in rep['failed_pulls']] + ['']
    lines += Q.markdown_lines(screens, rep.get('excluded_pulls'))
    doc = __doc__.split('\n\n', 1)[1]
    lines += ['## Method', '', doc]
    return '\n'.join(lines) + '\n'


def free_extension(rep: dict, rig) -> dict:
    """extension.yaml: what the correction can undo from these channels. The correction subtracts mass_kg a2 from
    F_move / moving_cell_gain; with g unknown, mass_kg is g m2 and the gain 1, so the corrected force is g times
    the force at the contact (stated under assumptions)."""
    c = rep.get('candidates') or {}
    corr = {'mass_kg': rig.force_chain.m2, 'accel_delay_s': 0.0, 'moving_cell_gain': 1.0}
    named = {x['name'] for x in rep.get('causes', [])}
    if 'gain_mass_product' in named:
        corr['mass_kg'] = c['gain_mass_product']['parameters']['gain_mass_kg']
    if 'accel_delay' in named:
        corr['accel_delay_s'] = c['accel_delay']['parameters']['delay_s']
    if 'mains_hum' in named:
        corr['mains_hum_hz'] = c['mains_hum']['parameters']['frequency_hz']
    return {'departures': {}, 'correction': corr,
            'assumptions': {'moving_cell_gain': 'not identifiable without a reference or a calibration mass: '
                            'mass_kg is g m2 and the gain 1, so the corrected force is g times the contact force'}}


def write_free_outputs(rep: dict, screens: Sequence, rig, out: Path) -> None:
    """DIR/report.json, report.md and extension.yaml, written whole (into a fresh folder, moved in at the end)."""
    import shutil
    import tempfile

    from .extension import extension_yaml
    out.mkdir(parents=True, exist_ok=True)
    stage = Path(tempfile.mkdtemp(prefix='.discover-', dir=out))
    try:
        (stage / 'extension.yaml').write_text(extension_yaml(free_extension(rep, rig)))
        (stage / 'report.md').write_text(free_markdown(rep, screens))
        (stage / 'report.json').write_text(json.dumps(rep, indent=1))
        for f in sorted(stage.iterdir(), key=lambda q: q.name == 'report.json'):
            f.replace(out / f.name)
    finally:
        shutil.rmtree(stage, ignore_errors=True)


HUM_STEP_HZ = 0.05
HUM_PULLS = 6


def hum_frequency(pres: Sequence[Tuple[np.ndarray, np.ndarray]]) -> float:
    """The line frequency (HUM_BAND_HZ) maximizing the summed least-squares sinusoid power of the free-phase
    residuals pres = [(t, r)] of up to HUM_PULLS pulls: a scan in HUM_STEP_HZ steps, refined. Least squares on the
    free samples alone: an impact record may hold only a few line cycles, with the event cut out of them."""
    from scipy.optimize import minimize_scalar
    pres = list(pres)[:HUM_PULLS]

    def power_many(fs):
        tot = np.zeros(len(fs))
        for t, r in pres:
            ph = 2 * np.pi * np.outer(fs, t)
            X = np.stack([np.sin(ph), np.cos(ph), np.ones_like(ph)], axis=2)      # (f, n, 3)
            XtX = np.einsum('fni,fnj->fij', X, X)
            c = np.linalg.solve(XtX, np.einsum('fni,n->fi', X, r)[..., None])[..., 0]
            tot += np.einsum('fi,fij,fj->f', c[:, :2], XtX[:, :2, :2], c[:, :2])
        return tot

    def power(f):
        return float(power_many(np.array([f]))[0])
    grid = np.arange(HUM_BAND_HZ[0], HUM_BAND_HZ[1] + HUM_STEP_HZ / 2, HUM_STEP_HZ)
    f0 = float(grid[int(np.argmax(np.concatenate([power_many(grid[k:k + 50]) for k in range(0, len(grid), 50)])))])
    return float(minimize_scalar(lambda f: -power(f), bounds=(f0 - HUM_STEP_HZ, f0 + HUM_STEP_HZ), method='bounded',
                                 options={'xatol': 1e-3}).x)


# ------------------------------------------------------------------------------------------ the driver
@dataclass(frozen=True)
class FreeSurvey:
    """Pass 1 of one pull: its screen, and its FreePull, or why it is left out."""

    name: str
    screen: Optional[Q.PullScreen] = None
    pull: Optional[FreePull] = None
    excluded: Optional[str] = None


def free_survey(ref) -> FreeSurvey:
    """Pass 1 (mapped over the pulls): read, screen, and analyse one pull's free phases."""
    from .source import load_channels
    _meta, ch = load_channels(ref)
    for c in FREE_CHANNELS:
        if c not in ch:
            check_core_channels((c,), f'pull {ref.name!r}')
    sc = Q.screen_pull(ref.name, ch)
    why = sc.exclusion(0, sc.samples, FREE_CHANNELS)
    if why:
        return FreeSurvey(ref.name, sc, excluded=why)
    try:
        return FreeSurvey(ref.name, sc, free_pull(ref.name, ch, sc))
    except DiscoveryError as exc:
        return FreeSurvey(ref.name, sc, excluded=str(exc))


def free_pass2(item) -> FreeStats:
    """Pass 2 (mapped over the usable pulls): item = (PullRef, FreeSurvey, hum frequency, the delay grid)."""
    from .source import load_channels
    ref, sv, f_hum, delays = item
    _meta, ch = load_channels(ref)
    return free_stats(ref.name, ch, sv.screen, f_hum, sv.pull, delays)


def discover_free(refs: Sequence, absent: Sequence[str], rig, out_dir, mapper, progress=None, few: int = 0) -> dict:
    """The reference-free discovery of a campaign lacking ``absent`` (module docstring), or of one with every
    channel but fewer pulls than ``few`` (the analysis with a reference needs that many); writes DIR/report.json,
    report.md and extension.yaml and returns the report."""
    def run(stage, fn, items, names):
        prog = (lambda done, total: progress(stage, done, total)) if progress else None
        return mapper(fn, items, names=list(names), keep=True, on_result=None, progress=prog)
    res = run('survey', free_survey, list(refs), [r.name for r in refs])
    failed = list(res.failed)
    surveys = [s for s in res.results if s is not None]
    screens = tuple(s.screen for s in surveys if s.screen is not None)
    excluded = {s.name: s.excluded for s in surveys if s.excluded}
    usable = [(r, s) for r, s in zip(refs, res.results) if s is not None and s.pull is not None]
    notes = [f'no {", ".join(absent)}: the reference-free analysis (free phases of the moving cell and the '
             'accelerometer)'] if absent else [
        f'{len(refs)} pulls: the analysis with a reference needs at least {few} (half fitted, half held out); '
        'the free phases of the moving cell and the accelerometer are analysed instead, leave-one-out']
    dts = {round(s.pull.dt, 12) for _r, s in usable}
    if len(dts) > 1:
        raise DiscoveryError(f'pulls have different sample intervals {sorted(dts)}; expected one rate')
    from bag_tools.core.daqfiles import NOTHING_TO_CORRECT
    if not usable and failed and all(NOTHING_TO_CORRECT in why for _n, why in failed):
        raise DiscoveryError(failed[0][1].split(': ', 1)[-1])       # no moving cell in any pull: one line
    if not usable:
        notes.append(f'0 of {len(refs)} pulls are usable (excluded_pulls, failed_pulls say why)')
        rep = free_report(None, [], absent, screens, excluded, failed, rig, notes, few)
        write_free_outputs(rep, screens, rig, Path(out_dir))
        return rep
    pulls = [s.pull for _r, s in usable]
    pres = [(p.hum_t, p.hum_r) for p in pulls if len(p.hum_t) > 100]
    f_hum = hum_frequency(pres) if pres else float(np.mean(HUM_BAND_HZ))
    grid = _delay_grid(pulls[0].dt, [p.delay_s for p in pulls])
    res2 = run('statistics', free_pass2, [(r, s, f_hum, grid) for r, s in usable], [p.name for p in pulls])
    if res2.failed:
        name, why = res2.failed[0]
        raise DiscoveryError(f'pull {name!r} failed in the statistics stage ({why}); expected every usable pull '
                             'to finish it')
    analysis = campaign_analysis(pulls, res2.results, f_hum, rig)
    rep = free_report(analysis, pulls, absent, screens, excluded, failed, rig, notes, few)
    write_free_outputs(rep, screens, rig, Path(out_dir))
    return rep


__all__ = ['FreePull', 'FreeStats', 'campaign_analysis', 'check_core_channels', 'discover_free', 'free_pull',
           'free_report', 'free_stats', 'identifiability', 'needs_reference_free', 'write_free_outputs']
