"""Data quality before physics: screen each pull's channels for data defects, say where they
are, and give the masks that keep them out of every fit. ROS-free (numpy only).

A data defect is something the DAQ or a sensor did to the record, not something the rig did: a spike,
clipping, a held (repeated) stretch, NaN/inf, a broken time axis, a channel stuck at a constant. The rig's
own sharp events -- the elastic rise in a quarter of a millisecond, a break dropping the force by thousands
of newtons within one sample, the cell ringing at ~4 kHz after it, the carriage's deceleration -- are
physics and must not be flagged; every detector below is built so that they are not (checked on clean
simulated pulls of every test set in tests/force_discovery/test_quality.py).

The detectors, per channel class (sensor channels: the load cells and accelerometers, which always carry
analog noise; the encoder: quantised, constant while the carriage is at rest; the drive's channels:
noise-free in the simulation and legitimately constant or at the voltage limit, so only the NaN and stuck
checks apply to them):

- ``nonfinite``: NaN or inf samples, any channel (``time_s`` included).
- ``time_gap`` / ``time_nonmonotonic``: a step of ``time_s`` above ``TIME_GAP_FACTOR`` x the median
  step, or a step <= 0. Every channel is masked there (the samples no longer sit on the sample grid).
- ``stuck``: a channel constant over the whole record (sensor channels: standard deviation below
  ``STUCK_NOISE_FRACTION`` of the rig's nominal sensor noise; others: exactly constant). The whole channel
  is masked.
- ``clipping``: sensor channels; a run of >= ``CLIP_MIN_RUN`` consecutive samples exactly at the record's
  maximum or minimum (the value at which the sensor or the ADC saturates), with the samples at that value
  less than ``MERGE_GAP_S`` before or after it (noise dithers in and out of the clip at its edges), that cuts the
  signal (``CLIP_FLANK_STEPS``: not a smooth extremum on one ADC code); or shorter runs that come back to that
  value (``CLIP_MIN_VISITS``: a sensor ringing past its limit).
- ``held``: sensor channels; a run of >= ``HELD_MIN_SAMPLES`` samples each exactly equal to the one before
  (noise never repeats a value). When every sensor channel holds over the same span it is one defect on
  channel ``ALL`` (a DAQ buffer under-run: the DAQ repeated its last sample on every channel) and every
  channel is masked there. The encoder alone may stay constant for seconds while the carriage is at rest;
  it is held (a defect) only when it moved by more than ``ENCODER_JUMP_QUANTA`` counts in the one sample
  before or after the constant run, i.e. it was moving while it reported no motion.
- ``saturation``: the load cells; see ``saturation.py``: a flat top (within a few noise sigma of the record's
  extreme for >= 0.3 ms, equal samples or not) while the other cell keeps rising: the cell stopped at a level
  (the ADC's, a conditioner's, its rated range) and the load there is lost. It replaces the ``clipping`` record
  of the same span, and a pull with one inside its analysis window is excluded (a flat top cannot be masked
  away: the filters carry it into the samples around it, and the load's peak is in it).
- ``overload``: sensor channels; samples beyond the rated range a channel map gives; and, see ``overload.py``, a
  burst of up to 5 ms far above the rest of the channel's record (1.5 x its largest other excursion, 50 x its
  noise) that no other channel shows (a sensor or amplifier driven past its range, e.g. +/-9000 m/s^2 on an
  accelerometer in a free phase); when two channels disagree, the one that left its physics is blamed.
- ``spike``: sensor channels; see ``_spikes``: a short (<= ``SPIKE_MAX_SAMPLES``) excursion that stands out
  of the fourth difference (which all but removes the rig's ringing and trends), is explained by a compact
  excursion alone, returns to the trend it left, and shows in one channel only (the rig's sharp events --
  the elastic rise, the break -- show in both cells and the accelerometer at once). Limitation: a spike
  within ~0.3 ms of such an event, or inside the big ringing right after a break, is not told apart from
  it and is not reported.

Every defect's samples are masked, padded by ``MASK_PAD_S`` on both sides. ``PullScreen`` holds the
defects and the masked spans; ``PullScreen.usable(channel)`` is the per-channel mask (True = usable),
``PullScreen.combined()`` the AND over the analysis channels, ``PullScreen.window_share(i0, i1)`` the masked
share of an index window and ``PullScreen.exclusion(i0, i1)`` the reason to exclude the pull (masked share
above ``EXCLUDE_SHARE``, a stuck analysis channel, or a broken time axis inside the window), or None.
``repair`` replaces the defect samples for the FFT filters downstream (see its docstring);
``defect_dicts`` and ``markdown_lines`` give report.json's ``data_quality`` and report.md's section.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Dict, Iterable, List, Optional, Sequence, Tuple

import numpy as np

from force_tester_common.core.channels import (
    ACCEL_TYPE,
    BLOCK_TYPES,
    ENCODER_TYPE,
    FORCE_TYPE,
    REQUIRED_CHANNELS,
)
from force_tester_common.core.events import MAD_SD
from force_tester_sim.core.pull import ACCEL_NOISE_M_S2, LOAD_CELL_NOISE_N

from .overload import OVERLOAD_MAX_S, overloads
from .saturation import saturations

# ------------------------------------------------------------------------------------------ names
SPIKE = 'spike'
CLIPPING = 'clipping'
HELD = 'held'
NONFINITE = 'nonfinite'
TIME_GAP = 'time_gap'
TIME_NONMONOTONIC = 'time_nonmonotonic'
STUCK = 'stuck'
OVERLOAD = 'overload'
SATURATION = 'saturation'
KINDS = (SPIKE, OVERLOAD, SATURATION, CLIPPING, HELD, NONFINITE, TIME_GAP, TIME_NONMONOTONIC, STUCK)
TIME_KINDS = (TIME_GAP, TIME_NONMONOTONIC)

ALL = 'all'                      # the channel of a defect that masks every channel (under-run, time axis)
TIME_CHANNEL = 'time_s'
FORCE_CHANNELS = tuple(BLOCK_TYPES[FORCE_TYPE][1].values())
#: the two cells read the same load: one that stops while the other keeps rising saturated (saturation.py)
CELL_PAIRS = tuple((c, o) for c in FORCE_CHANNELS for o in FORCE_CHANNELS if c != o)
ACCEL_CHANNELS = tuple(BLOCK_TYPES[ACCEL_TYPE][1].values())
SENSOR_CHANNELS = FORCE_CHANNELS + ACCEL_CHANNELS
(ENCODER_CHANNEL,) = BLOCK_TYPES[ENCODER_TYPE][1].values()
#: the channels that all see the rig's sharp events (the spike test's coincidence check)
COINCIDENCE_CHANNELS = FORCE_CHANNELS + (BLOCK_TYPES[ACCEL_TYPE][1]['axial_m_s2'],)
#: the channels the analysis fits (combined mask and exclusion default to these)
ANALYSIS_CHANNELS = tuple(c for c in REQUIRED_CHANNELS if c != TIME_CHANNEL)
#: the rig's nominal white noise per sensor channel (the simulation's, one home: force_tester_sim)
NOMINAL_NOISE = {**{c: LOAD_CELL_NOISE_N for c in FORCE_CHANNELS}, **{c: ACCEL_NOISE_M_S2 for c in ACCEL_CHANNELS}}

# ------------------------------------------------------------------------------------------ thresholds
# Padding of every masked span, each side. The detectors place a defect's core to a sample or two; its edges
# (a spike's shoulders below threshold, the first sample after an under-run, clip edges dithered by noise) can
# be a few samples wider. 0.2 ms = 10 samples at 50 kHz: as long as the longest spike, and 3 x 0.2 ms per
# spike is < 0.3 % of the shortest analysis window (~200 ms).
MASK_PAD_S = 0.2e-3
# Defect runs of one kind on one channel closer than this are one defect (noise dithering at a clip's edge,
# NaNs a few samples apart): 2 x the padding, since their padded masks touch anyway.
MERGE_GAP_S = 2 * MASK_PAD_S
# A pull is excluded when defects mask more than this share of its analysis window: with <= 10 % masked,
# each regression still has >= 90 % of its samples, and three 5 ms under-runs plus three spikes inside the
# shortest analysis window (200 ms; more defects than seen on the rig) mask ~9 % and keep the pull.
EXCLUDE_SHARE = 0.10
# Time: a step of time_s above 1.5 x the median step has dropped at least one sample (the next possible step
# is 2 dt; clock jitter of a DAQ is far below 0.5 dt).
TIME_GAP_FACTOR = 1.5
# Stuck: a sensor channel whose standard deviation over the whole record is below 1 % of its nominal noise
# carries no sensor at all (noise alone gives 100 %; a pull gives far more). Other channels: exactly constant.
STUCK_NOISE_FRACTION = 0.01
# Clipping: samples exactly at the record's extreme for >= 5 consecutive samples (0.1 ms). A noisy channel's
# maximum is one sample; even a quantised channel with ~1 LSB of noise does not sit on its extreme code for
# five samples in a row unless it is saturated.
CLIP_MIN_RUN = 5
# ... or fewer at a time, but back on the extreme in >= 2 runs of >= 2 samples (>= CLIP_MIN_RUN in all): a sensor
# ringing far past its limit sits on it 2-4 samples a period (LADISK's camera.lvm, 50 kHz: 26 samples at +/-54.7 g
# in 8 ms). A continuous-valued signal does not return to exactly its record's extreme; such visits less than 5 ms
# apart (a burst's length) are one clipping defect.
CLIP_MIN_VISITS = 2
CLIP_VISIT_GAP_S = OVERLOAD_MAX_S
# ... and cut: a channel whose noise is below its ADC's step sits on its extreme code for many samples at a smooth
# extremum too (the independent generator's moving cell, step 0.22 N, noise 0.05 N: 55 samples of 83 on the lowest
# code at a trough 0.1 s after the break, dithering with the next one; flagged on every campaign of seed 3900). A clip
# cuts the signal while it still moves: over as many samples as the run on either side, one flank leaves the level
# by more than CLIP_FLANK_STEPS steps on average, where an extremum flat to within one step over the run (a
# parabola) leaves it by 4.3 (the trough: 2.1). A float channel's step is tiny: every run there is cut
CLIP_FLANK_STEPS = 8.0
# Held: >= 25 samples (0.5 ms, half the shortest under-run seen, 1 ms) each exactly equal to the one before.
# Float noise never repeats; a quantised channel with ~1 LSB of noise repeats with p < 0.5 per sample, so a
# run of 25 has p < 3e-8 per sample (< 0.003 per 100,000-sample record).
HELD_MIN_SAMPLES = 25
# A sensor channel repeating more than half of its samples is too coarsely quantised for the held test
# (the test assumes noise changes the value almost every sample); it is skipped on that channel.
HELD_MAX_REPEAT_SHARE = 0.5
# Encoder: at rest the count stays constant, and the first change after rest (or the last before it) is one
# count (measured on the simulated sets 1-5: always exactly 1). A change of more than 3 counts in one sample
# next to a constant run means the carriage was moving while the encoder reported no motion.
ENCODER_JUMP_QUANTA = 3.0
# Spikes (see _spikes). r = the fourth difference / 6 = x[i] minus its cubic prediction from x[i-2..i+2]:
# white noise gives std sigma_r = 1.39 sigma; the cell's 3.9 kHz ringing (13 samples a period) is attenuated to
# 0.9 %, the mount's 0.6-2 kHz to < 0.1 %; a spike of height A gives A at its sample and 4A/6, A/6 beside it.
SPIKE_MAX_SAMPLES = 10           # a spike or glitch lasts <= 0.2 ms (10 samples); anything longer is not one
SPIKE_Z = 12.0                   # candidates: |r| > 12 sigma_r (Gaussian noise: never in 1e5 samples); a
#                                  spike must also depart > 12 sigma from the signal interpolated across it
SPIKE_CONTEXT_SAMPLES = 25       # 0.5 ms each side of a candidate group: its context
SPIKE_CONTEXT_RATIO = 8.0        # the group's peak |r| >= 8 x the context's robust |r| (on each side)
SPIKE_RESIDUAL_SHARE = 0.025     # removing the excursion leaves < 2.5 % of the group's peak |r|: a compact
#                                  excursion explains it (a 200-500 N spike: < 0.015; the rig's sharp events
#                                  forming a short group on 155 clean pulls: >= 0.038, and < 0.1 only for
#                                  steps, which the return test rejects)
SPIKE_RETURN_RATIO = 1.0         # the excursion's peak > the level change across it beyond the local slopes:
#                                  it returns to the trend (the excursion smoothing a step is < 0.97 of the
#                                  step for up to 8 samples; a step's group has 4)
SPIKE_COINCIDENCE_S = 0.3e-3     # a glitch is in ONE channel; the pull's sharp events (elastic rise, break,
SPIKE_COINCIDENCE_Z = 6.0        # ringing onset) are in both cells and the accelerometer within ~0.1 ms (the
#                                  accelerometer's delay <= 0.1 ms): a group with |r| > 6 sigma_r in another of
#                                  those channels within 0.3 ms is not a spike
RATED_FLANK = 0.5                # beyond a rated range: the excursion down to this share of it is masked
# repair(): gaps up to a spike's length get a cubic bridge, longer ones (held, NaN runs) a straight line
REPAIR_CUBIC_MAX = SPIKE_MAX_SAMPLES
# At most this many defects of one kind on one channel are listed one by one; the rest are summed up in one
# more record (the masks keep every one of them). Keeps report.json readable for a channel full of NaNs.
MAX_LISTED = 20


# ------------------------------------------------------------------------------------------ results
@dataclass(frozen=True)
class Defect:
    """One data defect: where (pull, channel, first and last affected sample's time) and what; a saturation's
    level (the channel's unit) too."""

    pull: str
    channel: str
    kind: str
    t_start_s: float
    t_end_s: float
    detail: str
    level: Optional[float] = None

    def as_dict(self) -> dict:
        out = {'pull': self.pull, 'channel': self.channel, 'kind': self.kind, 't_start_s': self.t_start_s,
               't_end_s': self.t_end_s, 'detail': self.detail}
        return out if self.level is None else {**out, 'level': self.level}


@dataclass(frozen=True)
class PullScreen:
    """What screen_pull() found in one pull: the defects and the masked sample spans.

    spans: (channel or ALL, kind, i0, i1) -- the defect's own samples i0 <= i < i1 of that channel (every
    channel for ALL); ``pad`` more samples on each side (MASK_PAD_S) are not usable either. Masks are made
    from the spans on demand (a screen stays small)."""

    name: str
    samples: int
    dt: float
    channels: tuple                  # the channels screened (time_s excluded)
    defects: tuple                   # Defect, in time order
    spans: tuple
    pad: int = 0

    def usable(self, channel: str, grow_s: float = 0.0) -> np.ndarray:
        """True where ``channel``'s samples are usable; masked spans grown by ``grow_s`` more on each side
        (e.g. the half-length of a filter run over the repaired channel)."""
        ok = np.ones(self.samples, bool)
        g = self.pad + (int(round(grow_s / self.dt)) if grow_s > 0 else 0)
        for c, _kind, i0, i1 in self.spans:
            if c == ALL or c == channel:
                ok[max(0, i0 - g):min(self.samples, i1 + g)] = False
        return ok

    def combined(self, channels: Sequence[str] = ANALYSIS_CHANNELS, grow_s: float = 0.0) -> np.ndarray:
        """True where every one of ``channels`` is usable (the samples a fit on those channels may use)."""
        ok = np.ones(self.samples, bool)
        for c in channels:
            ok &= self.usable(c, grow_s)
        return ok

    @property
    def masked_share(self) -> float:
        """Share of the record masked on any analysis channel."""
        return 1.0 - float(np.mean(self.combined())) if self.samples else 0.0

    def window_share(self, i0: int, i1: int, channels: Sequence[str] = ANALYSIS_CHANNELS) -> float:
        """Share of samples i0 <= i < i1 masked on any of ``channels``."""
        i0, i1 = max(0, int(i0)), min(self.samples, int(i1))
        if i1 <= i0:
            return 0.0
        return 1.0 - float(np.mean(self.combined(channels)[i0:i1]))

    def exclusion(self, i0: int, i1: int, channels: Sequence[str] = ANALYSIS_CHANNELS) -> Optional[str]:
        """Why the pull must be left out of fits on the window i0 <= i < i1, or None to keep it: a stuck
        channel among ``channels``, a broken time axis inside the window (the regressions assume the
        uniform sample grid), a saturated cell among ``channels`` inside the window, or defects masking more than
        EXCLUDE_SHARE of the window."""
        for c, kind, j0, j1 in self.spans:
            j0, j1 = j0 - self.pad, j1 + self.pad
            if kind == STUCK and c in channels:
                return f'channel {c!r} is stuck at a constant over the whole record'
            if kind in TIME_KINDS and j0 < i1 and j1 > i0:
                return f'the time axis is broken ({kind}) inside the analysis window'
            if kind == SATURATION and c in channels and j0 < i1 and j1 > i0:
                return (f'channel {c!r} saturates inside the analysis window (a flat top while the other cell '
                        'kept rising: the load there is unknown); expected no saturation')
        share = self.window_share(i0, i1, channels)
        if share > EXCLUDE_SHARE:
            return (f'defects mask {100 * share:.1f} % of the analysis window; '
                    f'at most {100 * EXCLUDE_SHARE:.0f} % is allowed')
        return None


# ------------------------------------------------------------------------------------------ helpers
def _runs(b: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
    """Starts and (exclusive) ends of the runs of True in the boolean array b."""
    if not b.any():
        return np.zeros(0, int), np.zeros(0, int)
    edges = np.flatnonzero(b[1:] != b[:-1]) + 1
    edges = np.concatenate(([0] if b[0] else [], edges, [len(b)] if b[-1] else [])).astype(int)
    return edges[::2], edges[1::2]


def _merge(starts: np.ndarray, ends: np.ndarray, gap: int) -> List[Tuple[int, int]]:
    """Runs [start, end) with at most ``gap`` samples between them joined into one."""
    if len(starts) == 0:
        return []
    new = np.flatnonzero(starts[1:] - ends[:-1] > gap) + 1
    first = np.concatenate(([0], new))
    last = np.concatenate((new - 1, [len(starts) - 1]))
    return list(zip(starts[first].tolist(), ends[last].tolist()))


def _fourth_difference(x: np.ndarray) -> np.ndarray:
    """r[i - 2] = (x[i-2] - 4 x[i-1] + 6 x[i] - 4 x[i+1] + x[i+2]) / 6: x[i] minus its cubic prediction from
    its four neighbours (length n - 4)."""
    return (x[:-4] + x[4:] - 4.0 * (x[1:-3] + x[3:-1]) + 6.0 * x[2:-2]) / 6.0


R_PER_SIGMA = float(np.sqrt(70.0) / 6.0)   # std of r for white noise of std 1
# every 7th sample of r is enough for the noise level (14,000 of a 100,000-sample record: ~1 % error)
NOISE_STRIDE = 7


def _quantum(x: np.ndarray) -> float:
    """The smallest step between two samples of x: its ADC's step when the noise is below it (a quantised channel
    with no noise to dither it repeats values, its fourth difference is mostly 0 and each one-step change would
    stand out of a noise of 0: 252 'spikes' a channel on a 20 kHz independent campaign). Its noise is then taken
    as at least the step's, quantum / sqrt(12). On a noisy float channel the step is tiny and changes nothing."""
    d = np.abs(np.diff(x))
    d = d[d > 0]
    return float(np.min(d)) if len(d) else 0.0


def _cut(x: np.ndarray, i0: int, i1: int, level: float, step: float) -> bool:
    """Whether the run [i0, i1) at ``level`` is a cut (a clip), not a smooth extremum the ADC's step flattens:
    CLIP_FLANK_STEPS above. With no flank to tell by (the run at an end of the record), a cut."""
    n = i1 - i0
    rise = [np.nanmean(np.abs(f - level)) for f in (x[max(0, i0 - n):i0], x[i1:i1 + n]) if np.isfinite(f).any()]
    return not rise or max(rise) > CLIP_FLANK_STEPS * step


def _robust_sd(r: np.ndarray) -> float:
    """MAD_SD x median |r|: the standard deviation of zero-mean noise, blind to a few % of events."""
    return float(MAD_SD * np.median(np.abs(r))) if len(r) else 0.0


_STENCIL = np.array([1.0, -4.0, 6.0, -4.0, 1.0]) / 6.0


def _excursion(x: np.ndarray, s0: int, s1: int) -> Tuple[np.ndarray, np.ndarray]:
    """The excursion p on samples s0 <= i < s1 whose removal makes x smoothest there (least squares on the
    fourth difference of x - p over every stencil touching those samples), and the residual r left."""
    k = s1 - s0
    rows = np.arange(s0 - 2, s1 + 2)                  # stencil centres touching [s0, s1)
    D = np.zeros((len(rows), k))
    for j in range(k):
        D[j:j + 5, j] = _STENCIL                      # sample s0 + j sits at stencil position m of centre s0+j+2-m
    r = np.array([_STENCIL @ x[c - 2:c + 3] for c in rows])
    p, *_ = np.linalg.lstsq(D, r, rcond=None)
    return p, r - D @ p


def _filled(x: np.ndarray, finite: np.ndarray) -> np.ndarray:
    """x with its non-finite samples replaced by linear interpolation (x itself when all are finite)."""
    if finite.all():
        return x
    idx = np.arange(len(x))
    y = x.copy()
    y[~finite] = np.interp(idx[~finite], idx[finite], x[finite])
    return y


def _level_change(x: np.ndarray, s0: int, s1: int) -> float:
    """How far x moves from just before [s0, s1) to just after it beyond what the slopes just outside
    predict (trapezoid rule): a step's height; for a spike, the trend's, a few % of a smooth oscillation."""
    predicted = 0.5 * ((x[s0 - 1] - x[s0 - 2]) + (x[s1 + 1] - x[s1])) * (s1 - s0 + 1)
    return float(abs(x[s1] - x[s0 - 1] - predicted))


class _Events:
    """Where a channel has sharp content (|r| > SPIKE_COINCIDENCE_Z sigma_r), queryable per window."""

    def __init__(self, r: np.ndarray, sigma_r: float):
        hit = np.abs(r) > SPIKE_COINCIDENCE_Z * sigma_r
        self.cum = np.concatenate(([0], np.cumsum(hit)))   # cum[j] = hits among r[:j] (sample j + 2)

    def any(self, i0: int, i1: int) -> bool:
        j0, j1 = max(0, i0 - 2), max(0, min(len(self.cum) - 1, i1 - 2))
        return j1 > j0 and self.cum[j1] > self.cum[j0]


def _spikes(x: np.ndarray, r: np.ndarray, sigma_r: float, others: Sequence[_Events], dt: float):
    """Spikes in x (finite; r its fourth difference, sigma_r its noise): (i0, i1, signed peak, detail).

    1. Candidates |r| > SPIKE_Z sigma_r, grouped when closer than SPIKE_MAX_SAMPLES; a group longer than a
       spike's response (SPIKE_MAX_SAMPLES + 4) is not one (the ringing after a break, a fast rise).
    2. Its peak |r| >= SPIKE_CONTEXT_RATIO x the robust |r| of the SPIKE_CONTEXT_SAMPLES before AND after it
       (an isolated event, not a burst of ringing).
    3. A compact excursion p on the group's inner samples explains it: removing p (least squares, see
       _excursion) leaves < SPIKE_RESIDUAL_SHARE of the peak |r| (a kink or a short step leaves more), and
       the excursion returns to the trend: its peak exceeds SPIKE_RETURN_RATIO x the level change across it
       beyond the local slopes (_level_change; a step keeps its height there, p only smooths it).
    4. No other of the pull's channels (both cells, the axial accelerometer) has sharp content within
       SPIKE_COINCIDENCE_S: the rig's events show in all of them, a glitch in one.
    The spike's samples are those of p above SPIKE_Z sigma and a quarter of its peak; they must span
    <= SPIKE_MAX_SAMPLES. Groups within 0.5 ms of the record's ends are not tested."""
    n = len(x)
    L = SPIKE_CONTEXT_SAMPLES
    sigma = sigma_r / R_PER_SIGMA
    coinc = int(round(SPIKE_COINCIDENCE_S / dt))
    cand = np.flatnonzero(np.abs(r) > SPIKE_Z * sigma_r) + 2          # sample indices
    out = []
    for a, b in _merge(cand, cand + 1, SPIKE_MAX_SAMPLES):
        if b - a > SPIKE_MAX_SAMPLES + 4 or a < L + 4 or b > n - L - 4:
            continue
        peak_r = float(np.max(np.abs(r[a - 2:b - 2])))
        ctx = max(_robust_sd(r[a - 2 - L:a - 2]), _robust_sd(r[b - 2:b - 2 + L]), sigma_r)
        if peak_r < SPIKE_CONTEXT_RATIO * ctx:
            continue
        s0, s1 = (a + 1, b - 1) if b - a > 2 else (a, b)
        p, res = _excursion(x, s0, s1)
        if np.max(np.abs(res)) > SPIKE_RESIDUAL_SHARE * peak_r:
            continue
        k = int(np.argmax(np.abs(p)))
        big = np.flatnonzero(np.abs(p) > max(SPIKE_Z * sigma, 0.25 * abs(p[k])))
        if len(big) == 0 or big[-1] + 1 - big[0] > SPIKE_MAX_SAMPLES:
            continue
        if abs(p[k]) <= SPIKE_RETURN_RATIO * _level_change(x, s0, s1):
            continue
        if any(o.any(a - coinc, b + coinc) for o in others):
            continue
        out.append((s0 + int(big[0]), s0 + int(big[-1]) + 1, float(p[k]),
                    f'(noise {sigma:.3g}, context |r| {ctx:.3g})'))
    return out


def _ms(samples: int, dt: float) -> str:
    return f'{1e3 * samples * dt:.3g} ms'


# ------------------------------------------------------------------------------------------ the screen
def screen_pull(name: str, ch: Dict[str, np.ndarray], rated: Optional[Dict[str, float]] = None) -> PullScreen:
    """Screen one pull's channels (dict channel -> array, time_s required) for data defects. rated: a sensor's
    rated range (+/-, SI) per channel, where a channel map gives it: samples beyond it are an overload.

    DiscoveryError when the record cannot be screened at all (no time_s, channels of different lengths, fewer
    than 3 samples, no two finite increasing time stamps)."""
    from .errors import DiscoveryError
    if TIME_CHANNEL not in ch:
        raise DiscoveryError(f'pull {name!r} has no {TIME_CHANNEL!r} channel; expected one to screen')
    t = np.asarray(ch[TIME_CHANNEL], float)
    n = len(t)
    lengths = {k: len(v) for k, v in ch.items() if len(v) != n}
    if lengths or n < 3:
        raise DiscoveryError(f'pull {name!r}: channel lengths {lengths or n} differ from {TIME_CHANNEL!r} '
                             f'({n}); expected equal lengths of at least 3 samples')
    steps = np.diff(t)
    good = np.isfinite(steps) & (steps > 0)
    if not good.any():
        raise DiscoveryError(f'pull {name!r}: {TIME_CHANNEL!r} has no two finite increasing stamps; '
                             'expected a time axis')
    dt = float(np.median(steps[good]))
    found: list = []       # (reported channel, masked channel or ALL, kind, i0, i1, detail)
    gap = int(round(MERGE_GAP_S / dt))

    # the time axis: non-finite stamps, gaps, steps back (every channel is masked there)
    tfin = np.isfinite(t)
    for i0, i1 in _merge(*_runs(~tfin), gap):
        found.append((TIME_CHANNEL, ALL, NONFINITE, i0, i1, f'{i1 - i0} non-finite time stamps'))
    fin_steps = np.isfinite(steps)
    for kind, bad, what in ((TIME_GAP, fin_steps & (steps > TIME_GAP_FACTOR * dt), 'jumps forward'),
                            (TIME_NONMONOTONIC, fin_steps & (steps <= 0), 'steps back or repeats')):
        s, e = _runs(bad)
        for i0, i1 in _merge(s, e, gap):
            worst = float(steps[i0:i1][np.argmax(np.abs(steps[i0:i1] - dt))])
            found.append((TIME_CHANNEL, ALL, kind, i0, i1 + 1,
                          f'time {what} ({int(np.count_nonzero(bad[i0:i1]))} steps, worst {1e3 * worst:.4g} ms); '
                          f'expected steps of {1e6 * dt:.4g} us'))

    held: Dict[str, List[Tuple[int, int]]] = {}
    pending: list = []                # clipping and encoder records, checked against under-runs at the end
    rough: Dict[str, tuple] = {}      # sensor channel -> (finite x, fourth difference, its noise)
    channels = tuple(k for k in ch if k != TIME_CHANNEL)
    for c in channels:
        x = np.asarray(ch[c], float)
        fin = np.isfinite(x)
        for i0, i1 in _merge(*_runs(~fin), gap):
            found.append((c, c, NONFINITE, i0, i1, f'{int(np.count_nonzero(~fin[i0:i1]))} NaN/inf samples'))
        if not fin.any():
            continue
        xf = x[fin]
        spread = float(np.std(xf)) if c in NOMINAL_NOISE else float(np.ptp(xf))
        limit = STUCK_NOISE_FRACTION * NOMINAL_NOISE[c] if c in NOMINAL_NOISE else 0.0
        if spread <= limit:
            found.append((c, c, STUCK, 0, n, f'constant at {float(np.median(xf)):.6g} over the whole record '
                          f'(spread {spread:.3g}; expected > {limit:.3g})'))
            continue
        if rated and c in rated:
            ax = np.abs(np.where(fin, x, 0.0))
            beyond = ax > rated[c]
            s0, e0 = _runs(ax > RATED_FLANK * rated[c])          # each excursion beyond, with its flanks
            keep = [k for k, (a, b) in enumerate(zip(s0, e0)) if beyond[a:b].any()]
            for i0, i1 in _merge(s0[keep], e0[keep], gap):
                seg = x[i0:i1][np.isfinite(x[i0:i1])]
                peak = float(seg[np.argmax(np.abs(seg))])
                found.append((c, c, OVERLOAD, i0, i1, f'{peak:+.6g} beyond the sensor\'s rated range +/-{rated[c]:.6g} '
                              f'(the channel map), over {_ms(i1 - i0, dt)} (sensor overload)'))
        if c == ENCODER_CHANNEL:
            pending += _encoder_held(x, dt)
        if c not in SENSOR_CHANNELS:
            continue
        lo, hi = float(np.min(xf)), float(np.max(xf))
        step = _quantum(xf)
        for level, side in ((hi, 'maximum'), (lo, 'minimum')):
            at = x == level
            if np.count_nonzero(at) < CLIP_MIN_RUN:
                continue
            s, e = _runs(at)
            ceiling = np.count_nonzero(e - s > 1) >= CLIP_MIN_VISITS     # back on the one value, again and again
            g = int(round(CLIP_VISIT_GAP_S / dt)) if ceiling else gap
            longest = np.maximum.reduceat(e - s, np.r_[0, np.flatnonzero(s[1:] - e[:-1] > g) + 1])
            for (i0, i1), run in zip(_merge(s, e, g), longest):
                if (run < CLIP_MIN_RUN and not ceiling) or not _cut(x, i0, i1, level, step):
                    continue
                pending.append((c, c, CLIPPING, i0, i1, f'{int(np.count_nonzero(at[i0:i1]))} samples at the '
                              f'record {side} {level:.6g} (saturated sensor or ADC)'))
        same = np.zeros(n, bool)
        same[1:] = x[1:] == x[:-1]
        if np.mean(same) <= HELD_MAX_REPEAT_SHARE:
            s, e = _runs(same)
            k = (e - s) >= HELD_MIN_SAMPLES
            held[c] = list(zip(s[k].tolist(), e[k].tolist()))
        xw = _filled(x, fin)
        r = _fourth_difference(xw)
        rough[c] = (xw, r, max(_robust_sd(r[::NOISE_STRIDE]), R_PER_SIGMA * _quantum(xw) / np.sqrt(12.0)))
    events = {c: _Events(r, sr) for c, (_x, r, sr) in rough.items() if c in COINCIDENCE_CHANNELS}
    for c, (xw, r, sigma_r) in rough.items():
        others = [e for o, e in events.items() if o != c]
        for i0, i1, peak, detail in _spikes(xw, r, max(sigma_r, 1e-12), others, dt):
            found.append((c, c, SPIKE, i0, i1, f'{peak:+.4g} from the signal interpolated across it, over '
                          f'{_ms(i1 - i0, dt)} {detail}'))
    cells = {c: (xw, sigma_r / R_PER_SIGMA) for c, (xw, _r, sigma_r) in rough.items() if c in FORCE_CHANNELS}
    for s in saturations(cells, dt, CELL_PAIRS):
        pending = [r for r in pending if not (r[0] == s.channel and r[2] == CLIPPING and r[3] < s.i1 and r[4] > s.i0)]
        where = (f'its rated range +/-{rated[s.channel]:.6g}' if rated and s.channel in rated
                 else 'no rated range given')
        pending.append((s.channel, s.channel, SATURATION, s.i0, s.i1,
                      f'saturated at {s.level:+.6g} for {_ms(s.i1 - s.i0, dt)} while {s.other} moved {s.rise:+.4g} '
                      f'({where}): a flat top, the load there lost', s.level))
    left = {c: [(f[3], f[4]) for f in found + pending if f[0] == c and f[2] in (OVERLOAD, CLIPPING, SATURATION)]
            for c in rough}
    sensed = {c: (xw, sigma_r / R_PER_SIGMA) for c, (xw, _r, sigma_r) in rough.items()}
    for c, i0, i1, peak, ratio in overloads(sensed, left, dt, COINCIDENCE_CHANNELS):
        found.append((c, c, OVERLOAD, i0, i1, f'a burst of {peak:+.4g} over {_ms(i1 - i0, dt)}, {ratio:.3g} x the '
                      'rest of the record, in this channel alone (sensor overload)'))
    found += _held_records(held, pending, n, dt)
    return _build(name, t, dt, channels, found)


def _held_records(held: Dict[str, List[Tuple[int, int]]], pending: list, n: int, dt: float) -> list:
    """Held records: one on ALL where every checked sensor channel holds at once (a DAQ buffer under-run;
    the clipping and encoder records inside it are part of it: an under-run that hides the peak holds the
    record's maximum), else one per channel, unless the run is at the channel's extreme (then it is clipping or
    saturation).
    ``pending``: the clipping and encoder-held records found before."""
    out = []
    count = np.zeros(n + 1, int)
    for runs in held.values():
        for i0, i1 in runs:
            count[i0] += 1
            count[i1] -= 1
    every = np.cumsum(count[:n]) == len(held) if len(held) >= 2 else np.zeros(n, bool)
    s, e = _runs(every)
    spans = []
    for a, b in zip(s.tolist(), e.tolist()):
        members = [(i0, i1) for runs in held.values() for i0, i1 in runs if i0 < b and i1 > a]
        spans.append((min(i0 for i0, _ in members), max(i1 for _, i1 in members)))

    def overlaps(i0, i1, among):
        return any(i0 < b and i1 > a for a, b in among)

    for i0, i1 in spans:
        out.append((ALL, ALL, HELD, i0, i1, f'every sensor channel ({", ".join(sorted(held))}) repeats its last '
                    f'value for {_ms(i1 - i0, dt)} ({i1 - i0} samples): DAQ buffer under-run'))
    kept = [r for r in pending if not overlaps(r[3], r[4], spans)]
    out += kept
    for c, runs in held.items():
        clips = [(r[3], r[4]) for r in kept if r[0] == c and r[2] in (CLIPPING, SATURATION)]
        for i0, i1 in runs:
            if not overlaps(i0, i1, spans) and not overlaps(i0, i1, clips):
                out.append((c, c, HELD, i0, i1, f'repeats its last value for {_ms(i1 - i0, dt)} ({i1 - i0} '
                            'samples); a noisy sensor never does'))
    return out


def _encoder_held(x: np.ndarray, dt: float) -> list:
    """The encoder constant for >= HELD_MIN_SAMPLES while moving (a jump > ENCODER_JUMP_QUANTA counts
    in the sample before or after the constant run); constant at rest is not a defect."""
    d = np.abs(np.diff(x))
    pos = d[np.isfinite(d) & (d > 0)]
    if not len(pos):
        return []
    quantum = float(np.min(pos))
    same = np.zeros(len(x), bool)
    same[1:] = d == 0
    s, e = _runs(same)
    k = (e - s) >= HELD_MIN_SAMPLES
    out = []
    for i0, i1 in zip(s[k].tolist(), e[k].tolist()):
        before = d[i0 - 2] if i0 >= 2 else 0.0
        after = d[i1 - 1] if i1 < len(x) else 0.0
        jump = max(before, after) / quantum
        if jump > ENCODER_JUMP_QUANTA:
            out.append((ENCODER_CHANNEL, ENCODER_CHANNEL, HELD, i0, i1,
                        f'constant for {_ms(i1 - i0, dt)} ({i1 - i0} samples) next to a step of {jump:.0f} '
                        f'counts: the carriage moved while the encoder reported no motion'))
    return out


def _build(name: str, t: np.ndarray, dt: float, channels: tuple, found: list) -> PullScreen:
    """Defects (at most MAX_LISTED per channel and kind, the rest summed up) and their spans."""
    n = len(t)
    fin = np.isfinite(t)
    k0 = int(np.argmax(fin))
    tg = np.where(fin, t, t[k0] + (np.arange(n) - k0) * dt)   # the nominal grid where a stamp is missing
    pad = int(round(MASK_PAD_S / dt))
    found.sort(key=lambda r: (r[3], r[0], r[2]))
    spans = tuple((m, kind, 0, n) if kind == STUCK else (m, kind, i0, i1) for _c, m, kind, i0, i1, *_d in found)
    defects, listed, rest = [], {}, {}
    for c, _m, kind, i0, i1, detail, *level in found:      # a saturation's record carries its level last
        key = (c, kind)
        listed[key] = listed.get(key, 0) + 1
        if listed[key] <= MAX_LISTED:
            defects.append(Defect(name, c, kind, float(tg[i0]), float(tg[i1 - 1]), detail, *level))
        else:
            r = rest.setdefault(key, [i0, i1, 0])
            r[1] = i1
            r[2] += 1
    for (c, kind), (i0, i1, count) in rest.items():
        defects.append(Defect(name, c, kind, float(tg[i0]), float(tg[i1 - 1]),
                              f'{count} more {kind} defects in this span (each masked; not listed one by one)'))
    defects.sort(key=lambda d: (d.t_start_s, d.channel, d.kind))
    return PullScreen(name, n, dt, channels, tuple(defects), spans, pad)


def screen_campaign(campaign_pulls: Iterable) -> tuple:
    """PullScreen per (meta, channels) pull; the pull's name is meta['file']."""
    return tuple(screen_pull(str(meta.get('file', '?')), ch) for meta, ch in campaign_pulls)


def _cubic_bridge(x: np.ndarray, s0: int, s1: int) -> np.ndarray:
    """Values for samples s0 <= i < s1 on the cubic through the two good samples on either side: it follows
    the trend and (across a 1-3 sample spike) the cell's 4 kHz ringing."""
    at = np.array([s0 - 2, s0 - 1, s1, s1 + 1])
    return np.polyval(np.polyfit(at - s0, x[at], 3), np.arange(s1 - s0))


def repair(ch: Dict[str, np.ndarray], screen: PullScreen) -> Dict[str, np.ndarray]:
    """A copy of the channel dict with each channel's defect samples (its own and ALL spans, unpadded) and
    non-finite samples replaced: gaps up to REPAIR_CUBIC_MAX samples by the cubic through the two good samples
    on either side, longer ones by linear interpolation between the nearest good samples (the end values
    held beyond the first/last one).

    Why: discovery low-passes every force and accelerometer channel with FFTs over the whole record. A
    500 N one-sample spike has a flat spectrum; the 7-9 kHz raised-cosine low-pass turns it into a sinc
    ringing of 10-20 N over about a millisecond either side (measured on simulated pulls), and a held
    stretch ends in a step that rings alike; one NaN makes the whole filtered channel NaN. Masking the
    samples out of the fits does not stop that smear from reaching the neighbouring, unmasked samples
    through the filter; repairing first does (the cubic bridge leaves < 0.5 N there, even on the ringing of
    the loaded window; a straight line over the padded span would leave up to ~25 N). The padding
    (MASK_PAD_S) is real data and is kept. The replaced samples are invented, so they stay masked: fit with
    ``screen.combined(...)`` (grown by the filter's effective half-length, ``grow_s``, where a filter mixes
    samples). A stuck channel has no good sample and is returned unchanged; ``time_s`` gets only its
    non-finite stamps filled (a gap or a step back is not repaired: ``PullScreen.exclusion`` leaves such a
    window out). Arrays of channels without defect samples are the input arrays themselves (not copied);
    nothing is changed in place."""
    out = dict(ch)
    n = screen.samples
    idx = np.arange(n)
    t = np.asarray(ch[TIME_CHANNEL], float)
    tfin = np.isfinite(t)
    if not tfin.all():
        lo, hi = np.flatnonzero(tfin)[[0, -1]]
        out[TIME_CHANNEL] = np.interp(idx, idx[tfin], t[tfin])
        out[TIME_CHANNEL][:lo] = t[lo] - (lo - idx[:lo]) * screen.dt
        out[TIME_CHANNEL][hi + 1:] = t[hi] + (idx[hi + 1:] - hi) * screen.dt
    for c in screen.channels:
        x = np.asarray(ch[c], float)
        bad = ~np.isfinite(x)
        for m, kind, i0, i1 in screen.spans:
            if m in (c, ALL) and kind not in TIME_KINDS:
                bad[i0:i1] = True
        if not bad.any() or bad.all():
            continue
        y = x.copy()
        y[bad] = np.interp(idx[bad], idx[~bad], x[~bad])
        for s0, s1 in zip(*_runs(bad)):
            if s1 - s0 <= REPAIR_CUBIC_MAX and s0 >= 2 and s1 <= n - 2 and not bad[s0 - 2:s0].any() \
                    and not bad[s1:s1 + 2].any():
                y[s0:s1] = _cubic_bridge(y, s0, s1)
        out[c] = y
    return out


# ------------------------------------------------------------------------------------------ reporting
def defect_dicts(screens: Iterable[PullScreen]) -> List[dict]:
    """report.json's ``data_quality``: every defect as a dict, pull by pull."""
    return [d.as_dict() for s in screens for d in s.defects]


def markdown_lines(screens: Sequence[PullScreen], excluded: Optional[Dict[str, str]] = None) -> List[str]:
    """report.md's data-quality section: a summary, a table of the defects, the excluded pulls and why."""
    excluded = excluded or {}
    defects = [d for s in screens for d in s.defects]
    bad = sorted({d.pull for d in defects})
    lines = ['## Data quality', '',
             f'{len(screens)} pulls screened for {", ".join(KINDS)}: {len(defects)} defects in {len(bad)} pulls; '
             f'defect samples (padded by {1e3 * MASK_PAD_S:.2g} ms each side) are masked out of every fit; a pull '
             f'whose analysis window is more than {100 * EXCLUDE_SHARE:.0f} % masked is excluded.', '']
    if defects:
        lines += ['| pull | channel | kind | start (s) | end (s) | detail |', '|---|---|---|---|---|---|']
        lines += [f'| {d.pull} | {d.channel} | {d.kind} | {d.t_start_s:.5f} | {d.t_end_s:.5f} | {d.detail} |'
                  for d in defects]
        lines.append('')
    saturated: Dict[Tuple[str, float], set] = {}
    for d in defects:
        if d.kind == SATURATION:
            saturated.setdefault((d.channel, round(d.level, 6)), set()).add(d.pull)
    for (c, level), pulls in sorted(saturated.items()):
        lines += [f'**{c} saturates at {level:+.6g}** in {len(pulls)} pull(s): a flat top while the other cell kept '
                  'rising. The load there is unknown: no term is fitted to it, and a pull with it inside its analysis '
                  'window is excluded.', '']
    if excluded:
        lines += ['Excluded pulls:', ''] + [f'- {p}: {why}' for p, why in sorted(excluded.items())] + ['']
    return lines
