"""Short events: what the moving average does to an event narrower than a few of its windows.

The moving average (thesis eq 25) smooths the m*a-corrected force; on a pull of seconds it costs
nothing, but an impact of a millisecond is narrower than the thesis's 140 points (1.4 ms at 100 kHz)
and the average cuts its peak. For each event of the moving cell (force_tester_common.core.events)
this estimates, from the data, the peak of the m*a-corrected force with and without the moving
average (the loss the window causes on that event), the event's bandwidth (the frequency below which
EVENT_BANDWIDTH_ENERGY of the corrected event's energy lies) and the window that passes that
bandwidth (its half-power frequency, MA_HALF_POWER * rate / W, at the bandwidth). Pure numpy.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from force_tester_common.core.correction import EVENT_BANDWIDTH_ENERGY, MA_HALF_POWER, SHORT_EVENT_WINDOWS
from force_tester_common.core.events import (
    all_finite,
    below_snr,
    deviations,
    event_width_s,
    find_events,
    nanmedian,
)


@dataclass(frozen=True)
class ShortEvent:
    """One event narrower than SHORT_EVENT_WINDOWS moving-average windows."""

    start_s: float             # first sample of the event, s from the record's start
    width_s: float             # full width at half its peak excursion
    window: int                # the moving average in use, samples
    peak_n: float              # peak excursion of the m*a-corrected force (no moving average)
    filtered_peak_n: float     # the same after the moving average
    bandwidth_hz: float        # EVENT_BANDWIDTH_ENERGY of the corrected event's energy lies below this
    bandwidth_window: int      # the window whose half-power frequency is the bandwidth
    bandwidth_peak_n: float    # the peak after that window

    @property
    def loss(self) -> float:
        """Share of the peak the moving average removes."""
        return 1.0 - self.filtered_peak_n / self.peak_n if self.peak_n > 0 else 0.0

    @property
    def bandwidth_loss(self) -> float:
        return 1.0 - self.bandwidth_peak_n / self.peak_n if self.peak_n > 0 else 0.0

    def line(self, rate_hz: float) -> str:
        return (f'a {self.width_s * 1e3:.3g} ms event at {self.start_s:.4g} s (< {SHORT_EVENT_WINDOWS:g} windows of '
                f'{self.window} = {self.window / rate_hz * 1e3:.3g} ms): the moving average cuts its peak by '
                f'{percent(self.loss)} % ({self.peak_n:.4g} -> {self.filtered_peak_n:.4g} N); '
                f'{self.bandwidth_window} samples from its {self.bandwidth_hz:.3g} Hz bandwidth: '
                f'{percent(self.bandwidth_loss)} %')


def percent(loss: float) -> str:
    """A loss as whole per cent; a window that raises a peak a little is a loss of 0, not '-0'."""
    return f'{max(0.0, 100 * loss):.0f}'


def advice(extension: bool) -> str:
    """The one line that follows the short events: what keeps their peaks."""
    return ('short events: --window-from-bandwidth sets the window from their bandwidth; '
            + ('with the extension, m*a needs no moving average: corrected_n keeps the peak' if extension else
               'corrected_n (m*a, no moving average) keeps the peak, as does an extension of ./ft discover'))


def trailing_mean(x: np.ndarray, window: int) -> np.ndarray:
    """The trailing moving average of the correction (eq 25) over the finite samples of each window."""
    ok = np.isfinite(x)
    c = np.concatenate([[0.0], np.cumsum(np.where(ok, x, 0.0))])
    k = np.concatenate([[0], np.cumsum(ok)])
    i = np.arange(1, x.size + 1)
    lo = np.maximum(i - window, 0)
    n = k[i] - k[lo]
    with np.errstate(invalid='ignore', divide='ignore'):
        return np.where(n > 0, (c[i] - c[lo]) / np.maximum(n, 1), np.nan)


def bandwidth_hz(x: np.ndarray, rate_hz: float, energy: float = EVENT_BANDWIDTH_ENERGY) -> float:
    """Frequency below which ``energy`` of the segment's spectral energy lies (the segment: the event less
    its baseline, from rest to rest)."""
    x = np.nan_to_num(np.asarray(x, dtype=np.float64))
    n = max(4 * x.size, 256)
    p = np.abs(np.fft.rfft(x, n)) ** 2
    if not p.sum() > 0:
        return rate_hz / 2
    cum = np.cumsum(p) / p.sum()
    return float(np.fft.rfftfreq(n, 1.0 / rate_hz)[int(np.searchsorted(cum, energy))])


def window_for_bandwidth(bw_hz: float, rate_hz: float) -> int:
    """The moving average whose half-power frequency is ``bw_hz`` (at least 1 sample)."""
    return max(1, int(math.floor(MA_HALF_POWER * rate_hz / bw_hz))) if bw_hz > 0 else 1


def short_events(force_moving_n, corrected_n, rate_hz: float, window: int) -> list:
    """The ShortEvents of one record: events of the moving cell narrower than SHORT_EVENT_WINDOWS windows,
    with the peak loss measured on the m*a-corrected force ``corrected_n``. An event whose corrected peak is within
    EVENT_SNR noise deviations (events.robust_sd of ``corrected_n``; events.below_snr decides it) is noise, or
    inertia the correction removed: not
    reported (a wiggle between pulls was reported, 'cuts its peak by 95 % (0.38 -> 0.02 N)')."""
    f = np.asarray(force_moving_n, dtype=np.float64)
    corr = np.asarray(corrected_n, dtype=np.float64)
    out = []
    dev = None    # corrected_n's deviations, taken once a short event is found (a record has none most of the time)
    spans, median = find_events(f, rate_hz)
    # event_width_s's baseline is the nanmedian, which is find_events' median unless a sample is infinite
    baseline = median if spans and (all_finite(f) or not np.isinf(f).any()) else None
    for span in spans:
        width = event_width_s(f, rate_hz, span, baseline)
        if width * rate_hz >= SHORT_EVENT_WINDOWS * window:
            continue
        a, b = span
        lo, hi = max(0, a - window), min(corr.size, b + 2 * window)   # the averaged event and its tail
        base = nanmedian(corr[max(0, a - 4 * window):a]) if a > 0 else 0.0
        base = 0.0 if not math.isfinite(base) else base
        seg = corr[lo:hi] - base
        sign = 1.0 if np.nanmax(seg) >= -np.nanmin(seg) else -1.0
        peak = float(np.nanmax(sign * seg))
        dev = deviations(corr) if dev is None else dev
        if not peak > 0 if not dev.size else below_snr(dev, peak, or_equal=True):    # peak <= EVENT_SNR robust sd
            continue
        filt = float(np.nanmax(sign * (trailing_mean(corr[max(0, lo - window):hi], window)[lo - max(0, lo - window):]
                                       - base)))
        bw = bandwidth_hz(seg, rate_hz)
        wb = window_for_bandwidth(bw, rate_hz)
        fb = float(np.nanmax(sign * (trailing_mean(corr[max(0, lo - wb):hi], wb)[lo - max(0, lo - wb):] - base)))
        out.append(ShortEvent(a / rate_hz, width, int(window), peak, filt, bw, wb, fb))
    return out


def bandwidth_window(events: list, default: int) -> int:
    """The window to use for a record's short events: the narrowest any of them asks for (``default`` when
    there is none)."""
    return min((e.bandwidth_window for e in events), default=default)


class ShortEventMonitor:
    """Short events of a stream (the live node): the blocks are kept until ``chunk_s`` of them are there,
    then searched; an event is reported once, when it ends more than ``overlap_s`` before the newest sample
    (the last ``overlap_s`` is kept and searched again with the next chunk)."""

    def __init__(self, window: int, rate_hz: float, chunk_s: float = 1.0, overlap_s: float = 0.1) -> None:
        self.window, self.rate = int(window), float(rate_hz)
        self.chunk = max(int(chunk_s * rate_hz), 8 * self.window)
        self.overlap = max(int(overlap_s * rate_hz), 4 * self.window)
        self.reset()

    def reset(self) -> None:
        self.raw: list = []
        self.corr: list = []
        self.size = 0
        self.offset = 0          # samples dropped from the front since the run began
        self.reported = 0        # absolute index before which events have been reported

    def add(self, raw, corrected) -> list:
        """The ShortEvents that ended in the samples seen so far (start_s from the run's first sample)."""
        self.raw.append(np.asarray(raw, dtype=np.float64))
        self.corr.append(np.asarray(corrected, dtype=np.float64))
        self.size += len(self.raw[-1])
        if self.size < self.chunk:
            return []
        raw, corr = np.concatenate(self.raw), np.concatenate(self.corr)
        limit = raw.size - self.overlap
        found = []
        for e in short_events(raw, corr, self.rate, self.window):
            first = int(round(e.start_s * self.rate))
            end = first + int(round(e.width_s * self.rate))
            if end < limit and first + self.offset >= self.reported:
                found.append(ShortEvent((first + self.offset) / self.rate, *dataclass_values(e)[1:]))
                self.reported = first + self.offset + 1
        self.raw, self.corr = [raw[limit:]], [corr[limit:]]
        self.size = raw.size - limit
        self.offset += limit
        return found


def dataclass_values(e: ShortEvent) -> tuple:
    return (e.start_s, e.width_s, e.window, e.peak_n, e.filtered_peak_n, e.bandwidth_hz, e.bandwidth_window,
            e.bandwidth_peak_n)
