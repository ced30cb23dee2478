"""The search's settings from a few fitted pulls (the spectrum pass): the signals' scales and, on each channel, the
frequency of its residual spectrum's line (a sinusoid's frequency is the campaign's; its phase each pull's own).
ROS-free."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Dict, NamedTuple, Optional, Sequence, Tuple

import numpy as np

from ..leftover import LEFTOVER_BAND_HZ
from .series import ChannelSeries

MIN_HZ = 20.0                  # a sinusoid's frequency lies above this (and below LEFTOVER_BAND_HZ)
SPECTRUM_POINTS = 2 ** 15
PEAK_PROMINENCE = 10.0        # a sinusoid's line stands this far above the median spectrum around it ...
PEAK_SPAN = 64                # ... over this many bins either side
REFINE_BINS = 2               # the line's frequency is refined this many bins either side of the peak ...
REFINE_PULLS = 4              # ... on the samples of at most this many pulls (memory flat in the pulls)


class ChannelSpectrum(NamedTuple):
    """One channel of one pull in the spectrum pass."""

    power: np.ndarray                                   # the residual's power spectrum (SPECTRUM_POINTS)
    rms: Dict[str, float]                               # each signal's rms
    record: Optional[Tuple[np.ndarray, np.ndarray]]     # (times s, residual), kept on REFINE_PULLS pulls only


@dataclass(frozen=True)
class SearchSettings:
    """The search's settings from a few fitted pulls (settings_from): the signals' scales and each channel's
    residual-spectrum line."""

    scales: Dict[str, float]
    freq: Dict[str, float]      # channel -> Hz


def _peak(P: np.ndarray, band: np.ndarray) -> Optional[int]:
    """The strongest local maximum of P inside band that stands PEAK_PROMINENCE above the median of the
    PEAK_SPAN bins around it (a line, not a broadband residual), or None."""
    idx = np.flatnonzero(band)
    idx = idx[(idx > 0) & (idx < len(P) - 1)]
    local = idx[(P[idx] > P[idx - 1]) & (P[idx] >= P[idx + 1])]
    for k in local[np.argsort(-P[local])][:8]:
        near = P[max(0, k - PEAK_SPAN):k + PEAK_SPAN + 1]
        if P[k] > PEAK_PROMINENCE * np.median(near):
            return int(k)
    return None


def spectrum_part(series: Dict[str, ChannelSeries], dt_dec: float, records: bool = True
                  ) -> Dict[str, ChannelSpectrum]:
    """{channel: ChannelSpectrum} of one pull. The spectrum treats the samples as evenly spaced; the sensors' free
    phases are two stretches with the pull between them, so the line's frequency is refined on the samples' own
    times (refine_frequency), kept where ``records`` (the first REFINE_PULLS pulls of the spectrum pass)."""
    out = {}
    for ch, cs in series.items():
        y, sig = cs.residual, cs.signals
        yy = (y - y.mean()) * np.hanning(len(y))
        P = np.abs(np.fft.rfft(yy, SPECTRUM_POINTS)) ** 2
        out[ch] = ChannelSpectrum(P, {k: float(np.sqrt(np.mean(v ** 2))) for k, v in sig.items()},
                                  (np.asarray(sig['t'], float), np.asarray(y, float)) if records else None)
    return out


def refine_frequency(f0: float, step: float, records: Sequence[Tuple[np.ndarray, np.ndarray]]) -> float:
    """The frequency within f0 +/- REFINE_BINS step that maximizes the summed power of the pulls' least-squares
    sinusoids on their samples' own times (records: [(t, residual)], each pull its own phase and amplitude): the
    spectrum's peak is off by up to a bin, and by more where the record has a gap (the free phases either side of
    the pull); one phase across such a gap needs the frequency to a small share of a bin."""
    def power(f):
        tot = 0.0
        for t, y in records:
            ph = 2 * np.pi * f * t
            X = np.column_stack([np.cos(ph), np.sin(ph), np.ones_like(t)])
            c = np.linalg.lstsq(X, y, rcond=None)[0]
            tot += float(np.sum((X[:, :2] @ c[:2]) ** 2))
        return tot
    grid = f0 + step * np.linspace(-REFINE_BINS, REFINE_BINS, 8 * REFINE_BINS + 1)
    for _ in range(3):   # a coarse grid, then finer ones around its best
        pw = np.array([power(f) for f in grid])
        k = int(np.argmax(pw))
        h = grid[1] - grid[0]
        grid = grid[k] + h * np.linspace(-1.0, 1.0, 9)
    return float(grid[4])


def settings_from(parts: Sequence[Dict[str, ChannelSpectrum]], dt_dec: float) -> SearchSettings:
    """The search's SearchSettings from spectrum_part()s of a few fitted pulls."""
    f = np.fft.rfftfreq(SPECTRUM_POINTS, dt_dec)
    ok = (f > MIN_HZ) & (f < LEFTOVER_BAND_HZ)
    freq, scales = {}, {}
    for ch in {c for part in parts for c in part}:
        P = sum(part[ch].power for part in parts if ch in part)
        k = _peak(P, ok)
        records = [part[ch].record for part in parts if ch in part and part[ch].record is not None]
        if k is not None:
            freq[ch] = refine_frequency(float(f[k]), float(f[1] - f[0]), records) if records else float(f[k])
        for part in parts:
            if ch in part:
                for s, r in part[ch].rms.items():
                    scales[s] = max(scales.get(s, 0.0), r)
    return SearchSettings({s: (v if v > 0 else 1.0) for s, v in scales.items()}, freq)
