"""The leftover structure: what the held-out force residual still holds after the extension (variance in the
analysis window against the quiet pre-pull floor, its dominant frequency, the channel it follows). ROS-free."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable, Optional

import numpy as np

from .prep import Pull

UNEXPLAINED_SHARE = 0.3       # residual variance in W above 1/(1-0.3) x the quiet-record floor: structured
LEFTOVER_BAND_HZ = 4000.0   # the structure check looks below this (above it, sampling of the break's step aliases)


def _band(x: np.ndarray, dt: float) -> np.ndarray:
    X = np.fft.rfft(x)
    X[np.fft.rfftfreq(len(x), dt) > LEFTOVER_BAND_HZ] = 0.0
    return np.fft.irfft(X, len(x))


@dataclass(frozen=True)
class LeftoverPart:
    """What one held-out pull adds to the structure check (leftover_part)."""

    var_window: float        # residual variance in W (band-limited, steps left out)
    var_quiet: float         # the quiet pre-pull floor's
    spectrum: np.ndarray     # residual power spectrum (2^16 points)
    corr: dict               # channel -> |correlation| with the residual


def leftover_part(p: Pull, hum: Optional[np.ndarray], r: np.ndarray, rig) -> LeftoverPart:
    """One held-out pull's share of the structure check: r is its force residual on W after the extension
    (ForceModel.resid), hum its hum estimate when the hum is significant (else None)."""
    ok = p.usable(p.w0, p.w1)
    # masked (repaired) samples are zeroed before the band limit: a repaired span's residual would otherwise
    # ring through the brick-wall filter into the samples kept
    r = _band(np.where(ok, r, 0.0), p.dt)
    keep = ok.copy()     # the break's and the elastic rise's fast steps alias: left out
    g = int(3e-3 / p.dt)
    for i in (p.brk - p.w0, p.load0 - p.w0):
        keep[max(0, i - g):max(0, i + g)] = False
    pre = (p.fm - (hum if hum is not None else 0) - p.T - rig.force_chain.m2 * p.a2)
    k = np.arange(len(pre))
    usable = p.usable()
    quiet = (k > int(0.02 / p.dt)) & (k < p.pre1) & usable   # the pre-pull record, defects left out ...
    rest = quiet & (np.abs(p.v3) < 1e-3)                       # ... with the carriage at rest: the floor
    pre = pre[rest] if rest.sum() >= 2000 else pre[quiet]
    pre = _band(pre - np.mean(pre), p.dt)
    P = np.abs(np.fft.rfft((r - r.mean()) * np.hanning(len(r)), 2 ** 16)) ** 2
    corr = {}
    for nm, x in (('tension T', p.T[p.w0:p.w1]), ('T^2', p.T[p.w0:p.w1] ** 2),
                  ('accel_axial', p.a2[p.w0:p.w1]), ('encoder a3', p.a3[p.w0:p.w1])):
        corr[nm] = abs(np.corrcoef(r, x)[0, 1] if np.std(x) > 0 else 0.0)
    return LeftoverPart(float(np.var(r[keep])), float(np.var(pre)), P, corr)


class LeftoverSum:
    """leftover_part()s added up in pull order (only their spectra's sum is kept)."""

    def __init__(self):
        self.vw, self.vq, self.spec, self.corr = [], [], None, {}

    def add(self, part: LeftoverPart) -> None:
        self.vw.append(part.var_window)
        self.vq.append(part.var_quiet)
        self.spec = part.spectrum if self.spec is None else self.spec + part.spectrum
        for nm, c in part.corr.items():
            self.corr.setdefault(nm, []).append(c)

    def result(self, dt: float) -> dict:
        """The structure check (module docstring); dt: the campaign's sample interval."""
        vw, vq, spec, corr = self.vw, self.vq, self.spec, self.corr
        share = 1.0 - float(np.mean(vq)) / float(np.mean(vw)) if np.mean(vw) > 0 else 0.0
        f = np.fft.rfftfreq(2 ** 16, dt)
        ok = f > 5.0
        fdom = float(f[ok][np.argmax(spec[ok])])
        best = max(corr, key=lambda k: np.mean(corr[k]))
        return {'share_of_residual_variance': share, 'dominant_frequency_hz': fdom, 'correlated_channel': best,
                'correlation': float(np.mean(corr[best])), 'structured': bool(share > UNEXPLAINED_SHARE),
                'rule': f'residual variance in the analysis window exceeds the quiet pre-pull floor by a share > '
                        f'{UNEXPLAINED_SHARE}'}


def leftover_from(parts: Iterable[LeftoverPart], dt: float) -> dict:
    """The structure check from the held-out pulls' leftover_part()s, in pull order."""
    acc = LeftoverSum()
    for part in parts:
        acc.add(part)
    return acc.result(dt)
