"""Events found from the data: where the moving cell's force stands out of its baseline.

An event is a stretch where |force - baseline| exceeds ``EVENT_LEVEL`` of the record's largest
excursion (baseline: the record's median), of either sign: a tension pull, a compression impact,
a braking load. Stretches closer than ``EVENT_GAP_S`` are one event. Pure numpy.
"""

import numpy as np

#: Fraction of the record's largest excursion above which a sample is in an event.
EVENT_LEVEL = 0.2
#: Stretches closer than this are one event, s.
EVENT_GAP_S = 0.005
#: An event's peak excursion must exceed this many robust standard deviations (1.4826 MAD) of the record:
#: a record of noise alone has no event.
EVENT_SNR = 8.0
#: Level at which an event's duration is measured (full width at half of its peak excursion).
WIDTH_LEVEL = 0.5


def event_spans(force, rate_hz: float, level: float = EVENT_LEVEL, gap_s: float = EVENT_GAP_S) -> list:
    """[(first, end)] sample index ranges of the events in ``force`` (NaN samples are never in one)."""
    x = np.asarray(force, dtype=np.float64)
    ok = np.isfinite(x)
    if x.size < 2 or not ok.any():
        return []
    dev = np.abs(x - np.median(x[ok]))
    dev[~ok] = 0.0
    peak = dev.max()
    noise = 1.4826 * np.median(dev[ok])
    if not peak > 0 or peak < EVENT_SNR * noise:
        return []
    idx = np.flatnonzero(dev > level * peak)
    gap = max(1, int(round(gap_s * rate_hz)))
    cut = np.flatnonzero(np.diff(idx) > gap)
    starts = np.concatenate([[idx[0]], idx[cut + 1]])
    ends = np.concatenate([idx[cut], [idx[-1]]]) + 1
    return [(int(a), int(b)) for a, b in zip(starts, ends)]


def event_width_s(force, rate_hz: float, span: tuple) -> float:
    """Full width of one event at WIDTH_LEVEL of its peak excursion, s."""
    x = np.asarray(force, dtype=np.float64)
    base = np.nanmedian(x)
    seg = np.abs(np.nan_to_num(x[span[0]:span[1]] - base))
    if not seg.size or not seg.max() > 0:
        return 0.0
    above = np.flatnonzero(seg >= WIDTH_LEVEL * seg.max())
    return float(above[-1] - above[0] + 1) / rate_hz
