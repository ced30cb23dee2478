"""Mains hum: the line's frequency (a few fitted pulls' pre-pull records), and each pull's amplitude and phase
(its own pre-pull record). ROS-free."""
from __future__ import annotations

import math
from typing import Sequence, Tuple

import numpy as np

from .prep import Pull

HUM_BAND_HZ = (45.0, 65.0)
FEW_PULLS = 12               # the hum frequency and the free-decay modes come from this many fitted pulls


def _hum_fit(t: np.ndarray, r: np.ndarray, f: float) -> Tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(c, sin, cos): the least-squares fit r ~ c0 sin(2 pi f t) + c1 cos(2 pi f t) + c2 and its two columns. The
    3 x 3 normal equations, columns scaled to a unit diagonal (the columns are near orthogonal over a few line
    cycles: a least-squares solver's answer to rounding, without building the n x 3 design)."""
    ph = 2 * np.pi * f * t
    sn, cs = np.sin(ph), np.cos(ph)
    ss, sc, s1, cc, c1 = sn @ sn, sn @ cs, sn.sum(), cs @ cs, cs.sum()
    G = np.array([[ss, sc, s1], [sc, cc, c1], [s1, c1, float(len(t))]])
    b = np.array([sn @ r, cs @ r, r.sum()])
    D = np.sqrt(np.diag(G))
    D[D == 0] = 1.0
    try:
        c = np.linalg.solve(G / np.outer(D, D), b / D) / D
    except np.linalg.LinAlgError:   # too few samples for three columns: the least-squares solver's answer
        c = np.linalg.lstsq(np.column_stack([sn, cs, np.ones_like(t)]), r, rcond=None)[0]
    return c, sn, cs


def _line_power(t: np.ndarray, r: np.ndarray, f: float) -> float:
    """The power of the fitted sinusoid at f (_hum_fit) over the samples t."""
    c, sn, cs = _hum_fit(t, r, f)
    return float(np.sum((c[0] * sn + c[1] * cs) ** 2))


def pre_residual(p: Pull, m2: float) -> Tuple[np.ndarray, np.ndarray]:
    """(t, r): the pull's pre-pull residual F_move - T - m2 a2 (usable samples), the hum's data."""
    i0 = int(0.02 / p.dt)
    ok = p.usable(i0, p.pre1)
    return p.t[i0:p.pre1][ok], (p.fm - p.T - m2 * p.a2)[i0:p.pre1][ok]


def few_pulls(fit: Sequence[int]) -> list:
    """The fitted pulls (list positions) that the hum frequency and the free-decay modes are measured on: up to
    FEW_PULLS, spread evenly over the fitted ones."""
    return list(fit[::max(1, len(fit) // FEW_PULLS)][:FEW_PULLS])


def hum_frequency_from(pres: Sequence[Tuple[np.ndarray, np.ndarray]], dt: float) -> Tuple[float, dict]:
    """The hum frequency: the one maximizing the summed (per-pull, free phase) line power of the pre-pull residuals
    pres = [(t, r)] (pre_residual), 45-65 Hz; dt: the first one's sample interval."""
    def power(f):
        tot = 0.0
        for t, r in pres:
            tot += _line_power(t, r, f)
        return tot
    nfft = 2 ** 19   # zero-padded periodogram (about 0.1 Hz bins) summed over pulls, then a local LS refinement
    spec = 0.0
    for _t, r in pres:
        spec = spec + np.abs(np.fft.rfft((r - r.mean()) * np.hanning(len(r)), nfft)) ** 2
    fgrid = np.fft.rfftfreq(nfft, dt)
    band = (fgrid >= HUM_BAND_HZ[0]) & (fgrid <= HUM_BAND_HZ[1])
    pw = spec[band]
    f0 = float(fgrid[band][int(np.argmax(pw))])
    from scipy.optimize import minimize_scalar
    res = minimize_scalar(lambda f: -power(f), bounds=(f0 - 0.15, f0 + 0.15), method='bounded',
                          options={'xatol': 1e-3})
    f = float(res.x)
    # spectral contrast: peak power vs the median over the band
    return f, {'peak_power': float(-res.fun), 'median_power': float(np.median(pw))}


def hum_frequency_near(t: np.ndarray, r: np.ndarray, f0: float) -> float:
    """One pull's own least-squares hum frequency near f0, from its pre-pull residual (t, r) (pre_residual)."""
    from scipy.optimize import minimize_scalar

    def neg_power(f):
        return -_line_power(t, r, f)
    return float(minimize_scalar(neg_power, bounds=(f0 - 0.3, f0 + 0.3), method='bounded',
                                 options={'xatol': 1e-3}).x)


def hum_frequencies(pres: Sequence[Tuple[np.ndarray, np.ndarray]], f0: float) -> list:
    """hum_frequency_near() of each pre-pull residual (t, r) in pres: the pulls' own hum frequencies."""
    return [hum_frequency_near(t, r, f0) for t, r in pres]


def hum_per_pull(p: Pull, f: float, m2: float) -> Tuple[float, np.ndarray]:
    """(amplitude, hum over the whole record) with the phase/amplitude fitted on the pre-pull record only."""
    t, r = pre_residual(p, m2)
    c = _hum_fit(t, r, f)[0]
    return float(math.hypot(c[0], c[1])), c[0] * np.sin(2 * np.pi * f * p.t) + c[1] * np.cos(2 * np.pi * f * p.t)


def hum_scale(amps: Sequence[float], a_fit: float, j: int) -> float:
    """The factor on held-out pull j's own hum estimate: its amplitude comes from the fitted pulls (a_fit)."""
    return a_fit / max(amps[j], 1e-12)


HUM_STEP_HZ = 0.05
HUM_PULLS = 6


def hum_frequency_free(pres: Sequence[Tuple[np.ndarray, np.ndarray]]) -> float:
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


HUM_WINDOWS = ('first half', 'second half')   # the pre-pull record's halves: hum_form_parts' analysis variants


def _amplitude(t: np.ndarray, r: np.ndarray, f: float) -> float:
    c = _hum_fit(t, r, f)[0]
    return float(math.hypot(c[0], c[1]))


def hum_form_parts(pres: Sequence[Tuple[np.ndarray, np.ndarray]], f: float) -> dict:
    """{parameter: {'pre_pull_window': u}}: the model-form line of the hum's frequency and amplitude. The hum is
    fitted as one steady sinusoid over each pull's whole pre-pull record (pres = [(t, r)], pre_residual of the few
    pulls; f the campaign's frequency); each half of the record (HUM_WINDOWS) is a defensible window too, and a hum
    that is not one steady line (a drifting amplitude or frequency, a second line near it, a trend the constant
    does not take) gives each half another answer. u is the RMS over the halves of their median's departure (over
    the pulls) from the whole records' median (empty with fewer than 2 records)."""
    pres = [(t, r) for t, r in pres if len(t) >= 8]
    if len(pres) < 2:
        return {}
    amp0 = float(np.median([_amplitude(t, r, f) for t, r in pres]))
    f0 = float(np.median(hum_frequencies(pres, f)))
    da, df = [], []
    for k in range(len(HUM_WINDOWS)):
        halves = [(t[:len(t) // 2], r[:len(r) // 2]) if k == 0 else (t[len(t) // 2:], r[len(r) // 2:])
                  for t, r in pres]
        da.append(float(np.median([_amplitude(t, r, f) for t, r in halves])) - amp0)
        df.append(float(np.median(hum_frequencies(halves, f))) - f0)
    return {'frequency_hz': {'pre_pull_window': math.sqrt(float(np.mean(np.square(df))))},
            'amplitude_n': {'pre_pull_window': math.sqrt(float(np.mean(np.square(da))))}}
