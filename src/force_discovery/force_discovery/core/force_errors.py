"""The held-out force-channel error, model of record (base) and extended: each held-out pull's residuals reduced
to their sums of squares and spectra (error_part), added up in pull order (ForceErrors). The report's metric and
residuals.png come from it. ROS-free."""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple, Optional

import numpy as np

from .prep import Pull

PLOT_FFT = 2 ** 15   # points of the residual spectra in residuals.png


@dataclass(frozen=True)
class ErrorPart:
    """One held-out pull's force-channel residual, model of record (base) and extended (ext): what the report
    and the plots take from it (error_part)."""

    base_sse: float
    ext_sse: float
    samples: int                       # usable samples in W (masked ones count as zero residual and are left out)
    base_spectrum: np.ndarray          # |FFT|^2 of the residual (2^15 points), for the plot
    ext_spectrum: np.ndarray
    plot: Optional[dict] = None        # the residuals themselves ('pull', 't', 'dt', 'base', 'ext'), when kept


def error_part(p: Pull, base: np.ndarray, ext: np.ndarray, keep: bool = False) -> ErrorPart:
    """ErrorPart of held-out pull p from its residuals on W (ForceModel.resid), which it zeroes where masked;
    keep: keep the residuals for the plot."""
    bad = ~p.usable(p.w0, p.w1)    # masked (repaired) samples are no evidence: zero residual
    base[bad] = ext[bad] = 0.0
    spec = [np.abs(np.fft.rfft(r - r.mean(), PLOT_FFT)) ** 2 for r in (base, ext)]
    plot = {'pull': p.name, 't': p.t[p.w0:p.w1], 'dt': p.dt, 'base': base, 'ext': ext} if keep else None
    return ErrorPart(float(base @ base), float(ext @ ext), int((~bad).sum()), spec[0], spec[1], plot)


class ErrorRms(NamedTuple):
    """The held-out force error's RMS (N): with the model of record, and with the named causes."""

    baseline: float
    extended: float


class ForceErrors:
    """The held-out force-channel errors, model of record and extended: error_part()s added up in pull order."""

    def __init__(self):
        self.base_sse, self.ext_sse, self.samples = [], [], 0
        self.base_spectrum = self.ext_spectrum = 0
        self.pulls = 0
        self.plot = None

    def add(self, part: ErrorPart) -> None:
        self.base_sse.append(part.base_sse)
        self.ext_sse.append(part.ext_sse)
        self.samples += part.samples
        self.base_spectrum = self.base_spectrum + part.base_spectrum
        self.ext_spectrum = self.ext_spectrum + part.ext_spectrum
        self.pulls += 1
        if self.plot is None and part.plot is not None:
            self.plot = part.plot

    def rms(self) -> ErrorRms:
        """The baseline and extended RMS over the usable samples."""
        return ErrorRms(_rms(self.base_sse, self.samples), _rms(self.ext_sse, self.samples))


def _rms(sses, n: int) -> float:
    """RMS from the per-pull sums of squares over the n samples they stand for."""
    return float(math.sqrt(sum(sses) / n))
