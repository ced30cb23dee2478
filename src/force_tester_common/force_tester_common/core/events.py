"""Events found from the data: where the moving cell's force stands out of its baseline.

An event is a stretch where |force - baseline| exceeds ``EVENT_LEVEL`` of the record's largest
excursion (baseline: the record's median), of either sign: a tension pull, a compression impact,
a braking load. Stretches closer than ``EVENT_GAP_S`` are one event. Pure numpy.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

#: Fraction of the record's largest excursion above which a sample is in an event.
EVENT_LEVEL = 0.2
#: Stretches closer than this are one event, s.
EVENT_GAP_S = 0.005
#: A normal distribution's standard deviation over its median absolute deviation (MAD): 1.4826 MAD is a robust
#: standard deviation, blind to a few % of events.
MAD_SD = 1.4826
#: An event's peak excursion must exceed this many robust standard deviations (MAD_SD x MAD) of the record:
#: a record of noise alone has no event.
EVENT_SNR = 8.0
#: Level at which an event's duration is measured (full width at half of its peak excursion).
WIDTH_LEVEL = 0.5


def event_spans(force, rate_hz: float, level: float = EVENT_LEVEL, gap_s: float = EVENT_GAP_S) -> list:
    """[(first, end)] sample index ranges of the events in ``force`` (NaN samples are never in one)."""
    return find_events(force, rate_hz, level, gap_s).spans


class Events(NamedTuple):
    """The events of a record: [(first, end)] sample spans, and the record's median of its finite samples (NaN when
    there is none), for a caller that needs both (event_width_s takes it) without a second median of the record."""

    spans: list
    baseline: float


#: records shorter than this are partially sorted whole (np.median's own way)
_SELECT_MIN = 4096
#: the sample's ranks either side of its middle that bracket the median (of about 1024 sampled values)
_BRACKET = 48
#: the narrow bracket's half-width, in the sample's ranks, around where the median is estimated to lie in it
_NEAR = 6


def median(x: np.ndarray, finite: bool = False) -> np.float64:
    """np.median of a 1-D float64 array, the same value bit for bit (of a median of zeros, the sign may differ:
    -0.0 == 0.0), in a sixth of its time on a pull. An evenly spaced sample of about 1024 values of x is sorted; one
    count (the samples of x below the sample's middle value) tells how far that value's rank is from the median's, so
    where the median lies in the sample; the two sample values a few ranks either side of there bracket it, the
    samples of x inside (1-3 % of a pull) are taken out, and their counted rank picks the median from them by a
    partial sort (np.median partially sorts all of x, 2-3 ms on 100,000 samples). When that bracket misses, a wider
    one (+-_BRACKET ranks of the sample's middle: 10 % of the samples); when that misses too (x in an odd order),
    np.median itself. A short record is partially sorted whole and its middle pair averaged as np.median averages
    it, the same bits (zeros' signs included), without np.median's NaN check (which imports numpy.ma, 5-10 ms, on its
    first call). np.median itself for anything else: an empty or other array, or one with a NaN (its median is NaN).
    finite: the caller knows x has no NaN (the check is skipped)."""
    x = np.asarray(x)
    n = x.size
    if not n or x.ndim != 1 or x.dtype != np.float64 or (not finite and np.isnan(x).any()):
        return np.median(x)
    k = n // 2                     # the upper middle rank; the lower one too for odd n
    first = k - 1 if n % 2 == 0 else k
    if n < _SELECT_MIN:
        # np.median's mean of the middle pair (or of the middle sample): a sum from 0.0, divided by the count
        return np.add.reduce(np.partition(x, [first, k])[first:k + 1]) / (k - first + 1)
    s = np.sort(x[::n // 1024])
    m = s.size // 2
    mid = s[m]
    below_mid = int(np.count_nonzero(x < mid))
    j = m + int(round((k - below_mid) * s.size / n))     # where the median's rank falls in the sample
    near = _NEAR + abs(j - m) // 2                          # the further from the middle, the less sure
    for a, b in ((j - near, j + near), (m - _BRACKET, m + _BRACKET)):
        if a < 0 or b >= s.size:
            continue
        lo, hi = s[a], s[b]
        inside = np.compress((x >= lo) & (x <= hi), x)
        below = below_mid - int(np.count_nonzero(inside < mid)) if lo <= mid <= hi else \
            int(np.count_nonzero(x < lo))
        if below <= first and k - below < inside.size:      # both middle ranks inside the bracket
            part = np.partition(inside, [first - below, k - below])
            # np.median's mean of the middle pair
            return (part[first - below] + part[k - below]) / 2 if n % 2 == 0 else part[k - below]
    return np.median(x)


def all_finite(x: np.ndarray) -> bool:
    """Whether every sample of a float array is finite, in one pass and no mask: a NaN or an infinity makes the sum
    NaN or infinite, and a sum of finite samples is finite unless it overflows (then np.isfinite decides)."""
    with np.errstate(over='ignore', invalid='ignore'):     # inf + -inf, an overflow: no warning, just not finite
        total = np.add.reduce(x, axis=None)
    return math.isfinite(total) or bool(np.isfinite(x).all())


def nanmedian(x) -> np.float64:
    """np.nanmedian of a 1-D float64 array, the same value: ``median`` when no sample is NaN, else np.nanmedian."""
    x = np.asarray(x, dtype=np.float64)
    return median(x, finite=True) if x.ndim == 1 and x.size and not np.isnan(x).any() else np.nanmedian(x)


def find_events(force, rate_hz: float, level: float = EVENT_LEVEL, gap_s: float = EVENT_GAP_S) -> Events:
    """The events of ``force`` (``Events``)."""
    x = np.asarray(force, dtype=np.float64)
    whole = all_finite(x)    # the usual record: no mask, no copies of it without its non-finite samples
    ok = None if whole else np.isfinite(x)
    if x.size < 2 or not (whole or ok.any()):
        return Events([], float('nan'))
    base = median(x if whole else x[ok], finite=True)
    dev = np.abs(x - base)
    if not whole:
        dev[~ok] = 0.0
    peak = dev.max()
    if not peak > 0 or below_snr(dev if whole else dev[ok], peak):
        return Events([], float(base))
    idx = np.flatnonzero(dev > level * peak)
    gap = max(1, int(round(gap_s * rate_hz)))
    cut = np.flatnonzero(np.diff(idx) > gap)
    starts = np.concatenate([[idx[0]], idx[cut + 1]])
    ends = np.concatenate([idx[cut], [idx[-1]]]) + 1
    return Events([(int(a), int(b)) for a, b in zip(starts, ends)], float(base))


#: relative margin around the noise threshold within which below_snr takes the exact median
_MARGIN = 1e-6


def below_snr(dev: np.ndarray, peak: float, or_equal: bool = False) -> bool:
    """peak < EVENT_SNR * MAD_SD * median(dev) (<= with ``or_equal``), exactly, without the median's partial sort
    where two counts decide it: the median (the mean of the sorted middle pair) lies clearly above the threshold
    when at most (n - 1) // 2 samples are at or below it, clearly below when more than n // 2 are below it; only a
    median within _MARGIN of the threshold is computed (a record whose peak is ~EVENT_SNR noise deviations).
    dev: absolute deviations from the median, finite, at least one."""
    thr = peak / (EVENT_SNR * MAD_SD)
    n = dev.size
    # the usual record first (most samples quiet): more than half below the threshold is enough
    if np.count_nonzero(dev < thr * (1 - _MARGIN)) > n // 2:
        return False
    if np.count_nonzero(dev <= thr * (1 + _MARGIN)) <= (n - 1) // 2:
        return True
    exact = EVENT_SNR * (MAD_SD * median(dev, finite=True))
    return bool(peak <= exact if or_equal else peak < exact)


def deviations(x) -> np.ndarray:
    """|x - median(x)| over x's finite samples (empty when it has none): what robust_sd and below_snr take."""
    x = np.asarray(x, dtype=np.float64)
    x = x if all_finite(x) else x[np.isfinite(x)]     # the usual record: no copy of it
    return np.abs(x - median(x, finite=True)) if x.size else x


def robust_sd(x) -> float:
    """MAD_SD x the median absolute deviation of x's finite samples (0 when it has none): its noise, robust to
    events."""
    dev = deviations(x)
    return MAD_SD * float(median(dev, finite=True)) if dev.size else 0.0


def event_width_s(force, rate_hz: float, span: tuple, baseline: float | None = None) -> float:
    """Full width of one event at WIDTH_LEVEL of its peak excursion, s. baseline: the record's nanmedian when
    the caller has it (find_events' baseline, for a record with no infinite sample), else computed here."""
    x = np.asarray(force, dtype=np.float64)
    base = np.nanmedian(x) if baseline is None else baseline
    seg = np.abs(np.nan_to_num(x[span[0]:span[1]] - base))
    if not seg.size or not seg.max() > 0:
        return 0.0
    above = np.flatnonzero(seg >= WIDTH_LEVEL * seg.max())
    return float(above[-1] - above[0] + 1) / rate_hz
