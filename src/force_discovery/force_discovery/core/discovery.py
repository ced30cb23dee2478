"""Discovery: find what the model of record gets wrong in a measured campaign, name the cause from the
departure catalog, fit its parameters, and measure the gain on held-out pulls (issue 5). ROS-free.

Method (every step is a regression on measured channels; no simulation loop):

1. Per pull, from the measured channels only:
   - T = F_stat + m1 a1 (eq 21/23), a1 from F_stat = K_LC1 u1 + c1 u1' solved in the frequency domain; F_stat,
     F_move and a2 all pass the same zero-phase raised-cosine low-pass (7-9 kHz), so eq 21 holds in the band.
   - carriage motion x3, v3, a3 from the encoder (Savitzky-Golay, 2 ms window).
   - the loaded window (F_stat > 10 % of its peak), the break (last sample with T > 5 % of the peak) and the
     analysis window W = [loaded start - 50 ms, break + 150 ms].
2. Channel "force": the model of record says F_move = T + m2 a2 (ideal sensors). The residual
   r = F_move - T - m2_nom a2 is explained by the linear model
       F_move = g T + (g m) a2(t + d) - (1/tau) C + hum,   C = integral of F_move (AC coupling, exact),
   with d found on a grid (dt/2 steps to 200 us, parabolic refinement; the delay is applied to the force side
   by linear interpolation, i.e. exactly as a DAQ/sim channel delay acts on a2) and hum = A sin(2 pi f t + phase_pull)
   (f searched 45-65 Hz on the pre-pull record, phase per pull from the pre-pull record).
3. Channel "ringing": after the break T = 0 and, in the carriage frame, a2 - a3 is a free decay. The model of
   record's only mode there is the moving cell on m2 (sqrt(K_LC2/m2), about 3.9 kHz). A dominant lightly damped
   pole well below it (< 0.7 x) is a mount resonance; its frequency and damping are fitted (matrix pencil) and
   mapped back to the mount's (f, zeta) through the 2-DOF carriage-mount-base-cell-m2 model.
4. Channel "current": i kf - m_c a3 - b v3 - F_move (force balance) has an offset F_c sign(v3) for dry friction.
Fitting uses the pulls at even list positions (0, 2, ...), scoring the others (held out). A cause is NAMED when on the
held-out pulls (a) its channel's summed squared residual falls by >= MIN_REL_REDUCTION when the cause is added
to (or kept in) the model, and (b) the per-pull reductions have a t statistic >= MIN_T (one-sided, over held-out
pulls). Each force-channel cause is tested by removing it from the full force model (the others stay fitted).
Ranked by the held-out relative reduction of their channel's squared residual -- strongest first. Left-over
structure (force residual variance in W, below 4 kHz, away from the load/break steps, vs the at-rest floor) with
nothing named gives `unexplained`.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Dict, Iterable, List, Optional, Sequence, Tuple

import numpy as np

from force_tester_common.core.channels import REQUIRED_CHANNELS as REQUIRED
from force_tester_sim.core.departures import CATALOG, fractional_delay
from force_tester_sim.core.tolerances import BAND_PARAMETER, band

from .errors import DiscoveryError
from .quality import repair, screen_pull
from .uncertainty import NAMED, bootstrap_ci, jackknife_ci, verdict

MIN_PULLS = 4                 # half are fitted, half held out
MIN_REL_REDUCTION = 0.01      # held-out SSE must fall by at least 1 %
MIN_T = 4.0                   # and consistently over held-out pulls
HUM_BAND_HZ = (45.0, 65.0)
FEW_PULLS = 12               # the hum frequency and the free-decay modes come from this many fitted pulls
MOUNT_MAX_FRACTION = 0.7      # a free-decay mode below 0.7 x the cell mode is not the cell
UNEXPLAINED_SHARE = 0.3       # residual variance in W above 1/(1-0.3) x the quiet-record floor: structured
NONLIN_SHARE = 0.03           # a T^2 term removing > 3 % of the held-out force residual: not a linear sensor
CATALOG_PARAMS = {name: tuple(params) for name, (_kind, params, _meaning) in CATALOG.items()}


# ------------------------------------------------------------------------------------------ per-pull prep
LOWPASS_HZ = (7000.0, 9000.0)   # every force/accel channel is low-passed alike (zero phase) before the regressions


def _lowpass_w(f: np.ndarray) -> np.ndarray:
    lo, hi = LOWPASS_HZ
    w = np.ones_like(f)
    mid = (f > lo) & (f < hi)
    w[mid] = 0.5 * (1 + np.cos(np.pi * (f[mid] - lo) / (hi - lo)))
    w[f >= hi] = 0.0
    return w


def _filtered(x: np.ndarray, dt: float, h=None) -> np.ndarray:
    """Zero-phase low-pass of x, optionally times a frequency response h(omega) (end trend removed first)."""
    n = len(x)
    trend = np.linspace(x[0], x[-1], n)
    X = np.fft.rfft(x - trend)
    f = np.fft.rfftfreq(n, dt)
    H = _lowpass_w(f)
    if h is None:
        return np.fft.irfft(H * X, n) + trend
    return np.fft.irfft(H * h(2 * np.pi * f) * X, n)


def tension_from_stationary(fs: np.ndarray, dt: float, m1: float, k1: float, c1: float) -> np.ndarray:
    """T = F_stat + m1 a1 (eq 21/23) with a1 from F_stat = K u1 + c1 v1 (exact in the frequency domain)."""
    return _filtered(fs, dt) + _filtered(fs, dt, lambda w: -m1 * w ** 2 / (k1 + 1j * c1 * w))


@dataclass(frozen=True)
class Pull:
    """One prepared pull: filtered channels, derived signals and window indices (never changed)."""

    name: str
    t: np.ndarray
    dt: float
    fm: np.ndarray
    fs: np.ndarray
    a2: np.ndarray
    T: np.ndarray
    x3: np.ndarray
    v3: np.ndarray
    a3: np.ndarray
    current: Optional[np.ndarray]
    w0: int
    w1: int
    pre1: int
    load0: int
    brk: int
    peak: float
    ok: Optional[np.ndarray] = None   # usable samples (the data-quality screen's mask, grown by MASK_GROW_S); None: all

    def usable(self, i0: int = 0, i1: Optional[int] = None) -> np.ndarray:
        i1 = len(self.t) if i1 is None else i1
        return np.ones(i1 - i0, bool) if self.ok is None else self.ok[i0:i1]


CAL_PULLS = 8                    # pulls whose stationary-cell free decay measures the cells' damping ratio
CAL_RING_TO_NOISE = 10.0         # ... when its rms stands this many times above the quiet record's noise
CAL_SAMPLES = 400                # ... over this many samples after the break (8 ms at 50 kHz)
CAL_MIN_CHANGE = 0.25            # T is recomputed with the measured ratio when it departs from the rig's by this
MASK_GROW_S = 0.5e-3             # masked spans grow by this much: the low-pass and the 2 ms Savitzky-Golay spread
MIN_SAMPLES = 2000               # a pull record shorter than this is not a full record
QUALITY_CHANNELS = ('force_stationary_n', 'force_moving_n', 'accel_axial_m_s2', 'encoder_position_m')


@dataclass(frozen=True)
class PullQuality:
    """What the data-quality stage found in one pull's channels (before anything is fitted)."""

    name: str
    samples: int
    dt: float
    nonfinite: dict          # channel -> count of NaN/inf samples (the channels the analysis uses)
    peak_n: float            # stationary-cell peak
    noise_n: float           # stationary-cell standard deviation on the first tenth of the record
    has_current: bool

    @property
    def usable(self) -> bool:
        return self.peak_n > max(20.0, 20 * self.noise_n)


def check_quality(meta: dict, ch: dict) -> PullQuality:
    """The data-quality stage for one pull; DiscoveryError (quoting the value) if it is unusable."""
    name = str(meta.get('file', '?'))
    for k in REQUIRED:
        if k not in ch:
            raise DiscoveryError(f'pull {name!r} has no {k!r} channel; expected {", ".join(REQUIRED)}')
    t = np.asarray(ch['time_s'], float)
    n = len(t)
    if n < MIN_SAMPLES:
        raise DiscoveryError(f'pull {name!r} has {n} samples; expected a full record (>= {MIN_SAMPLES})')
    fs = np.asarray(ch['force_stationary_n'], float)
    finite = np.isfinite(fs)
    head = fs[: max(10, n // 10)]
    q = PullQuality(name, n, float(np.nanmedian(np.diff(t))),
                    {k: int(np.count_nonzero(~np.isfinite(np.asarray(ch[k], float)))) for k in QUALITY_CHANNELS},
                    float(np.max(fs[finite])) if finite.any() else float('nan'),
                    float(np.nanstd(head)) if np.isfinite(head).any() else float('nan'), 'motor_current_a' in ch)
    if not q.usable:
        raise DiscoveryError(f'pull {name!r}: stationary peak {q.peak_n:.3g} N is not a pull; '
                             'expected a loaded record')
    return q


def prepare(meta: dict, ch: dict, rig, q: Optional[PullQuality] = None, screen=None) -> Pull:
    """The prepare stage: derived signals and windows of one pull that passed check_quality(); with a data-quality
    screen (quality.screen_pull), its defects are repaired (interpolated) first and masked out of every fit."""
    from scipy.signal import savgol_filter
    q = check_quality(meta, ch) if q is None else q
    ok = None
    if screen is not None and screen.spans:
        ch = repair(ch, screen)
        ok = screen.combined(grow_s=MASK_GROW_S)
    t = np.asarray(ch['time_s'], float)
    n, dt = q.samples, q.dt
    fc = rig.force_chain
    fs = np.asarray(ch['force_stationary_n'], float)
    x = np.asarray(ch['encoder_position_m'], float)
    T = tension_from_stationary(fs, dt, fc.m1, fc.load_cell_stiffness_n_per_m, fc.c1)
    fm = _filtered(np.asarray(ch['force_moving_n'], float), dt)
    a2 = _filtered(np.asarray(ch['accel_axial_m_s2'], float), dt)
    win = max(5, int(round(2e-3 / dt)) | 1)
    x3 = savgol_filter(x, win, 3)
    v3 = savgol_filter(x, win, 3, deriv=1, delta=dt)
    a3 = savgol_filter(x, win, 3, deriv=2, delta=dt)
    cur = ch.get('motor_current_a')
    cur = None if cur is None else np.asarray(cur, float)
    peak = q.peak_n
    load0 = int(np.flatnonzero(fs > 0.1 * peak)[0])
    brk = int(np.flatnonzero(T > 0.05 * peak)[-1])
    w0 = max(0, load0 - int(0.05 / dt))
    w1 = min(n, brk + int(0.15 / dt))
    pre1 = max(0, load0 - int(0.03 / dt))
    return Pull(q.name, t, dt, fm, fs, a2, T, x3, v3, a3, cur, w0, w1, pre1, load0, brk, peak, ok)


# ------------------------------------------------------------------------------------------ mains hum
def _hum_design(t, f):
    return np.column_stack([np.sin(2 * np.pi * f * t), np.cos(2 * np.pi * f * t), np.ones_like(t)])


def _pre_resid(p: Pull, m2: float) -> Tuple[np.ndarray, np.ndarray]:
    i0 = int(0.02 / p.dt)
    ok = p.usable(i0, p.pre1)
    return p.t[i0:p.pre1][ok], (p.fm - p.T - m2 * p.a2)[i0:p.pre1][ok]


pre_residual = _pre_resid   # (t, r): the pull's pre-pull residual F_move - T - m2 a2 (usable samples), the hum's data


def few_pulls(fit: Sequence[int]) -> list:
    """The fitted pulls (list positions) that the hum frequency and the free-decay modes are measured on: up to
    FEW_PULLS, spread evenly over the fitted ones."""
    return list(fit[::max(1, len(fit) // FEW_PULLS)][:FEW_PULLS])


def fit_hum_frequency(pulls: Sequence[Pull], m2: float) -> Tuple[float, dict]:
    """Frequency maximizing the summed (per-pull, free phase) line power of the pre-pull residual, 45-65 Hz."""
    return hum_frequency_from([_pre_resid(p, m2) for p in pulls], pulls[0].dt)


def hum_frequency_from(pres: Sequence[Tuple[np.ndarray, np.ndarray]], dt: float) -> Tuple[float, dict]:
    """fit_hum_frequency() on the pulls' pre-pull residuals pres = [(t, r)] (pre_residual), dt: the first one's."""
    def power(f):
        tot = 0.0
        for t, r in pres:
            A = _hum_design(t, f)
            c, *_ = np.linalg.lstsq(A, r, rcond=None)
            tot += float(np.sum((A[:, :2] @ c[:2]) ** 2))
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


def hum_frequency_per_pull(p: Pull, f0: float, m2: float) -> float:
    """One pull's own least-squares hum frequency near f0 (its pre-pull record only)."""
    return hum_frequency_near(*_pre_resid(p, m2), f0)


def hum_frequency_near(t: np.ndarray, r: np.ndarray, f0: float) -> float:
    """hum_frequency_per_pull() on the pull's pre-pull residual (t, r)."""
    from scipy.optimize import minimize_scalar

    def neg_power(f):
        A = _hum_design(t, f)
        c, *_ = np.linalg.lstsq(A, r, rcond=None)
        return -float(np.sum((A[:, :2] @ c[:2]) ** 2))
    return float(minimize_scalar(neg_power, bounds=(f0 - 0.3, f0 + 0.3), method='bounded',
                                 options={'xatol': 1e-3}).x)


def hum_per_pull(p: Pull, f: float, m2: float) -> Tuple[float, np.ndarray]:
    """(amplitude, hum over the whole record) with the phase/amplitude fitted on the pre-pull record only."""
    t, r = _pre_resid(p, m2)
    c, *_ = np.linalg.lstsq(_hum_design(t, f), r, rcond=None)
    return float(math.hypot(c[0], c[1])), c[0] * np.sin(2 * np.pi * f * p.t) + c[1] * np.cos(2 * np.pi * f * p.t)


# ------------------------------------------------------------------------------------------ force channel
TERMS = ('moving_cell_gain', 'effective_mass', 'accel_delay', 'ac_coupling')


class ForceModel:
    """F_move - hum = g T + M a2(t + d) - k C on W (C: running integral of F_move - hum over the whole record).

    The accelerometer delay is applied to the force side (F_move, T, C delayed by d with linear interpolation),
    so a linearly interpolated (low-passing) delay in the accelerometer path is matched exactly."""

    def __init__(self, pulls: Sequence[Pull], m2: float, hums: Optional[Sequence] = None):
        """hums: the mains-hum estimate per pull (whole record) to subtract from F_move, or None."""
        self.m2 = m2
        self.pulls = pulls
        self.full = []
        for p, h in zip(pulls, hums if hums is not None else [None] * len(pulls)):
            y = p.fm - (h if h is not None else 0.0)
            self.full.append((y, p.T, np.cumsum(y) * p.dt))
        self.a2 = [p.a2[p.w0:p.w1] for p in pulls]
        self._cache: Dict[float, list] = {}

    def at(self, d: float) -> list:
        key = round(d, 10)
        if key not in self._cache:
            if len(self._cache) > 64:
                self._cache.clear()
            out = []
            for p, arrs in zip(self.pulls, self.full):
                m = min(p.w0, 16)   # d <= 200 us = 10 samples: a short lead-in is enough
                out.append(tuple(fractional_delay(a[p.w0 - m:p.w1], d / p.dt)[m:] for a in arrs))
            self._cache[key] = out
        return self._cache[key]

    def design(self, terms, d, idx, masked=True):
        """(y adjusted for fixed terms, regressor matrix, column names) per pull of idx, on W: the usable samples
        only (masked=True), or all of W."""
        sig = self.at(d if 'accel_delay' in terms else 0.0)
        a2 = self.a2
        ys, Xs = [], []
        for j in idx:
            y0, Tj, Cj = sig[j]
            y = y0.copy()
            cols, names = [], []
            if 'moving_cell_gain' in terms:
                if 'effective_mass' in terms:
                    cols += [Tj, a2[j]]
                    names += ['g', 'M']
                else:
                    cols += [Tj + self.m2 * a2[j]]
                    names += ['g']
            else:
                y = y - Tj
                if 'effective_mass' in terms:
                    cols += [a2[j]]
                    names += ['M']
                else:
                    y = y - self.m2 * a2[j]
            if 'ac_coupling' in terms:
                cols += [-Cj]
                names += ['k']
            ok = self.pulls[j].usable(self.pulls[j].w0, self.pulls[j].w1) if masked else slice(None)
            ys.append(y[ok])
            Xs.append(np.column_stack(cols)[ok] if cols else np.zeros((len(ys[-1]), 0)))
        return ys, Xs, names

    def fit(self, terms, idx, d=0.0):
        ys, Xs, names = self.design(terms, d, idx)
        if not names:
            return {}, float(sum(np.sum(y ** 2) for y in ys))
        X = np.vstack(Xs)
        y = np.concatenate(ys)
        c, *_ = np.linalg.lstsq(X, y, rcond=None)
        r = y - X @ c
        return dict(zip(names, c)), float(r @ r)

    def fit_delay(self, terms, idx):
        grid = self.delay_grid()
        sse = np.array([self.fit(terms, idx, d)[1] for d in grid])
        k = int(np.argmin(sse))
        d = float(grid[k] + _parabolic_offset(sse, k) * (grid[1] - grid[0]))
        coef, s = self.fit(terms, idx, d)
        return coef, s, d

    def delay_grid(self, d_max=200e-6) -> np.ndarray:
        return np.arange(0.0, d_max + 1e-12, self.pulls[0].dt / 2)

    def loo_fits(self, terms, idx) -> List[Tuple[dict, float]]:
        """Leave-one-pull-out refits over idx: [(coef, delay)], the delay refitted on the grid when it is a term.

        Per-pull normal equations (X'X, X'y, y'y) at each grid delay are summed once; dropping pull k subtracts
        its share. The refined delay's coefficients interpolate linearly between the two nearest grid delays."""
        grid = self.delay_grid() if 'accel_delay' in terms else np.zeros(1)
        names, G, b, s = None, [], [], []
        for d in grid:
            ys, Xs, names = self.design(terms, d, idx)
            G.append(np.array([X.T @ X for X in Xs]))
            b.append(np.array([X.T @ y for X, y in zip(Xs, ys)]))
            s.append(np.array([y @ y for y in ys]))
        G, b, s = np.array(G), np.array(b), np.array(s)          # (grid, pulls, p, p), (grid, pulls, p), (grid, pulls)
        Gs, bs, ss = G.sum(1), b.sum(1), s.sum(1)
        out = []
        for k in range(len(idx)):
            c = np.array([_solve(Gs[i] - G[i, k], bs[i] - b[i, k]) for i in range(len(grid))])
            sse = ss - s[:, k] - np.einsum('ip,ip->i', bs - b[:, k], c)
            i = int(np.argmin(sse))
            off = _parabolic_offset(sse, i)
            ci = c[i] if off == 0 else c[i] + abs(off) * (c[i + (1 if off > 0 else -1)] - c[i])
            out.append((dict(zip(names, ci)), float(grid[i] + off * (grid[1] - grid[0]))))
        return out

    def sse_per_pull(self, terms, coef, d, idx) -> np.ndarray:
        ys, Xs, names = self.design(terms, d, idx)
        c = np.array([coef[n] for n in names]) if names else np.zeros(0)
        return np.array([float(np.sum((y - X @ c) ** 2)) for y, X in zip(ys, Xs)])

    def resid(self, terms, coef, d, j) -> np.ndarray:
        """Pull j's residual on all of W (masked samples included: their values are repaired, not measured)."""
        ys, Xs, names = self.design(terms, d, [j], masked=False)
        c = np.array([coef[n] for n in names]) if names else np.zeros(0)
        return ys[0] - Xs[0] @ c

    def t2_reduction(self, coef, d, fit, held) -> float:
        """Relative held-out SSE reduction when T^2 is added to the full model (coef, d: its fit)."""
        fm_ = self
        sig = fm_.at(d)

        def t2(j):   # T^2 on W, on the usable samples as design() takes them
            p = fm_.pulls[j]
            return sig[j][1][p.usable(p.w0, p.w1)] ** 2
        ys, Xs, names = fm_.design(set(TERMS), d, fit)
        X = np.vstack([np.column_stack([Xk, t2(j)]) for Xk, j in zip(Xs, fit)])
        c, *_ = np.linalg.lstsq(X, np.concatenate(ys), rcond=None)
        ys2, Xs2, _ = fm_.design(set(TERMS), d, held)
        c0 = np.array([coef[n] for n in names])
        s0 = sum(float(np.sum((y - Xk @ c0) ** 2)) for y, Xk in zip(ys2, Xs2))
        s1 = sum(float(np.sum((y - np.column_stack([Xk, t2(j)]) @ c) ** 2)) for y, Xk, j in zip(ys2, Xs2, held))
        return float(1 - s1 / s0) if s0 > 0 else 0.0


def _parabolic_offset(y: np.ndarray, k: int) -> float:
    """Offset (in grid steps, within (-1, 1)) of the vertex of the parabola through y[k-1:k+2]; 0 at an end."""
    if not 0 < k < len(y) - 1:
        return 0.0
    den = y[k - 1] - 2 * y[k] + y[k + 1]
    return float(0.5 * (y[k - 1] - y[k + 1]) / den) if den > 0 else 0.0


def _solve(G: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Normal equations G c = b, columns scaled to unit diagonal first."""
    if len(b) == 0:
        return np.zeros(0)
    D = np.sqrt(np.diag(G))
    D[D == 0] = 1.0
    return np.linalg.solve(G / np.outer(D, D), b / D) / D


def force_params_ci(loo: Sequence[Tuple[dict, float]], coef: dict, d: float, m2: float) -> dict:
    """name -> {parameter: [lo, hi]} from leave-one-pull-out refits (jackknife). The AC coupling's interval
    comes from the rate k = 1/tau that the regression fits, inverted (k <= 0 is tau = inf: DC)."""
    full = force_params(coef, d, m2)
    per = [force_params(c, dk, m2) for c, dk in loo]
    out = {}
    for name, params in full.items():
        if name == 'ac_coupling':
            lo, hi = jackknife_ci(coef['k'], [c['k'] for c, _ in loo])
            out[name] = {'time_constant_s': [1.0 / hi if hi > 0 else math.inf, 1.0 / lo if lo > 0 else math.inf]}
        else:
            out[name] = {k: list(jackknife_ci(v, [p[name][k] for p in per])) for k, v in params.items()}
    return out


def force_params(coef: dict, d: float, m2: float) -> dict:
    g = coef.get('g', 1.0)
    out = {}
    if 'g' in coef:
        out['moving_cell_gain'] = {'gain': float(g)}
    if 'M' in coef:
        out['effective_mass'] = {'mass_kg': float(coef['M'] / g)}
    out['accel_delay'] = {'delay_s': float(d)}
    if 'k' in coef:
        out['ac_coupling'] = {'time_constant_s': float(1.0 / coef['k']) if coef['k'] > 0 else float('inf')}
    return out


# ------------------------------------------------------------------------------------------ ringing channel
def matrix_pencil(y: np.ndarray, dt: float, order: int = 8) -> List[Tuple[float, float, float]]:
    """Damped modes of y: [(frequency Hz, damping ratio, rms amplitude share)], strongest first."""
    n = len(y)
    L = n // 2
    Y = np.lib.stride_tricks.sliding_window_view(y, L + 1)
    U, s, Vh = np.linalg.svd(Y, full_matrices=False)
    V = Vh[:order].conj().T
    V1, V2 = V[:-1], V[1:]
    z = np.linalg.eigvals(np.linalg.pinv(V1) @ V2)
    z = z[np.abs(z) > 1e-6]
    Z = np.vander(z, n, increasing=True).T
    amp, *_ = np.linalg.lstsq(Z, y.astype(complex), rcond=None)
    out = []
    for zi, ai in zip(z, amp):
        lam = np.log(zi) / dt
        w = abs(lam)
        f = abs(lam.imag) / (2 * np.pi)
        if f < 1.0:
            continue
        zeta = -lam.real / w
        e = float(np.sum(np.abs(ai * zi ** np.arange(n)) ** 2))
        out.append((float(f), float(zeta), e))
    # merge conjugate pairs: keep positive-frequency energies summed by frequency
    out.sort(key=lambda m: -m[2])
    merged = []
    for f, zt, e in out:
        for m in merged:
            if abs(m[0] - f) < 1e-6 * max(1.0, f):
                m[2] += e
                break
        else:
            merged.append([f, zt, e])
    merged.sort(key=lambda m: -m[2])
    return [tuple(m) for m in merged]


def ring_segment(p: Pull, length_s: float = 0.03) -> Optional[np.ndarray]:
    i0 = p.brk + int(2e-4 / p.dt)
    i1 = min(len(p.t), i0 + int(length_s / p.dt))
    if i1 - i0 < 200 or not p.usable(i0, i1).all():
        return None
    y = (p.a2 - p.a3)[i0:i1]
    return y - np.mean(y)


def damped_basis(n: int, dt: float, f: float, zeta: float) -> np.ndarray:
    t = np.arange(n) * dt
    w = 2 * np.pi * f
    e = np.exp(-zeta * w * t)
    wd = w * math.sqrt(max(1e-12, 1 - zeta ** 2))
    return np.column_stack([e * np.sin(wd * t), e * np.cos(wd * t)])


def ring_sse(seg: np.ndarray, dt: float, modes: Sequence[Tuple[float, float]]) -> float:
    """Squared residual of seg after a per-pull amplitude/phase fit of the given (f, zeta) modes."""
    if not modes:
        return float(seg @ seg)
    X = np.hstack([damped_basis(len(seg), dt, f, z) for f, z in modes] + [np.ones((len(seg), 1))])
    c, *_ = np.linalg.lstsq(X, seg, rcond=None)
    r = seg - X @ c
    return float(r @ r)


def ring_to_noise(p: Pull, seg: np.ndarray, cell: Sequence[Tuple[float, float]], mode: Tuple[float, float]) -> float:
    """RMS of the fitted mode's ringing in seg over the noise rms of a2 - a3 on the quiet pre-pull record."""
    X = np.hstack([damped_basis(len(seg), p.dt, f, z) for f, z in cell] + [np.ones((len(seg), 1)),
                                                                          damped_basis(len(seg), p.dt, *mode)])
    c, *_ = np.linalg.lstsq(X, seg, rcond=None)
    ring = X[:, -2:] @ c[-2:]
    q = (p.a2 - p.a3)[int(0.02 / p.dt):p.pre1]
    noise = float(np.std(q - np.polyval(np.polyfit(np.arange(len(q)), q, 1), np.arange(len(q))))) if len(q) > 100 \
        else 0.0
    return float(np.sqrt(np.mean(ring ** 2)) / max(noise, 1e-12))


def mount_from_observed(f_obs: float, zeta_obs: float, m2: float, k_cell: float, zeta_cell: float, mb: float):
    """Mount (frequency_hz, damping_ratio) whose carriage-mount-base(mb)-cell-m2 chain has the observed lowest pole
    (the sim's mount_resonance parameters, departures.py)."""
    from scipy.optimize import fsolve
    c2 = 2 * zeta_cell * math.sqrt(k_cell * m2)
    M = np.diag([mb, m2])

    def pole(fm, zm):
        km = (2 * np.pi * fm) ** 2 * (mb + m2)
        cm = 2 * zm * math.sqrt(km * (mb + m2))
        K = np.array([[km + k_cell, -k_cell], [-k_cell, k_cell]])
        C = np.array([[cm + c2, -c2], [-c2, c2]])
        A = np.block([[np.zeros((2, 2)), np.eye(2)], [-np.linalg.solve(M, K), -np.linalg.solve(M, C)]])
        ev = np.linalg.eigvals(A)
        ev = ev[ev.imag > 0]
        lam = ev[np.argmin(np.abs(ev))]
        return abs(lam.imag) / (2 * np.pi), -lam.real / abs(lam)

    def eq(v):
        f, z = pole(v[0], v[1])
        return [f / f_obs - 1.0, z / max(zeta_obs, 1e-6) - 1.0]
    sol = fsolve(eq, [f_obs / 0.95, max(zeta_obs, 1e-4)], full_output=True)
    return float(sol[0][0]), float(sol[0][1])


# ------------------------------------------------------------------------------------------ current channel
STILL_M_S = 1e-4     # |v3| below this: the carriage is at rest (no dry friction)
MOVING_M_S = 0.05    # v3 above this: moving forward (dry friction at its full value)


def drive_force_balance(p: Pull, drive, fm: np.ndarray) -> np.ndarray:
    """The drive force the model of record needs for the pull's measured motion: m_c a3 + b v3 + F_move."""
    return drive.reflected_mass_kg * p.a3 + drive.viscous_damping_n_s_per_m * p.v3 + fm


def current_resid(p: Pull, rig) -> Optional[Tuple[np.ndarray, np.ndarray]]:
    if p.current is None:
        return None
    d = rig.drive
    rho = p.current * d.force_per_amp_n_per_a - drive_force_balance(p, d, p.fm)
    moving = p.v3 > MOVING_M_S
    still = np.abs(p.v3) < STILL_M_S
    return rho, np.where(p.usable(), np.where(moving, 1.0, np.where(still, 0.0, np.nan)), np.nan)


def _friction_stat(rows: np.ndarray) -> float:
    return float(np.median(rows[:, 0]) - np.median(rows[:, 1]))


def friction_row(p: Pull, rig) -> Optional[tuple]:
    """The pull's median force-balance residual while moving and at rest (None without a current channel)."""
    cr = current_resid(p, rig)
    if cr is None:
        return None
    rho, sg = cr
    return np.median(rho[sg == 1.0]), np.median(rho[sg == 0.0])


def friction_offsets(pulls, idx, rig) -> Optional[np.ndarray]:
    """Per pull: the median force-balance residual while moving and at rest (None without a current channel)."""
    return friction_rows(friction_row(pulls[j], rig) for j in idx)


def friction_rows(rows: Iterable[Optional[tuple]]) -> Optional[np.ndarray]:
    """The friction_row()s as an array, None when a pull had no current channel."""
    out = []
    for r in rows:
        if r is None:
            return None
        out.append(r)
    return np.array(out)


def friction_sse(p: Pull, rig, fc: float) -> float:
    rho, sg = current_resid(p, rig)
    ok = ~np.isnan(sg)
    r = rho[ok] - fc * sg[ok]
    r = r - np.median(rho[sg == 0.0])
    r = np.clip(r, -np.percentile(np.abs(r), 95) * 3 - 1e-9, np.percentile(np.abs(r), 95) * 3 + 1e-9)
    return float(np.sum((r / rig.drive.force_per_amp_n_per_a) ** 2))   # in A^2


# ------------------------------------------------------------------------------------------ significance
def significance(base: np.ndarray, ext: np.ndarray) -> dict:
    """Held-out per-pull SSE without (base) and with (ext) a cause."""
    d = 1.0 - ext / np.maximum(base, 1e-300)   # per-pull relative reductions
    rel = float(1.0 - ext.sum() / base.sum()) if base.sum() > 0 else 0.0
    sd = float(np.std(d, ddof=1)) if len(d) > 1 else 0.0
    tstat = float(np.mean(d) / (sd / math.sqrt(len(d)))) if sd > 0 else (math.inf if np.mean(d) > 0 else 0.0)
    return {'statistic': 'held-out SSE reduction and t of the per-pull relative reductions',
            'rel_sse_reduction': rel, 't': tstat, 'threshold': f'rel >= {MIN_REL_REDUCTION:g} and t >= {MIN_T:g}',
            'significant': bool(rel >= MIN_REL_REDUCTION and tstat >= MIN_T),
            'rms_gain': float(math.sqrt(base.sum() / ext.sum())) if ext.sum() > 0 else math.inf}


# ------------------------------------------------------------------------------------------ main entry
def _split(pulls: Sequence[Pull]):
    fit = list(range(0, len(pulls), 2))
    held = list(range(1, len(pulls), 2))
    return fit, held


def cell_zeta(p: Pull, rig) -> Optional[float]:
    """One pull's damping ratio of the load cells from the stationary cell's free decay after the break (lanyard
    slack: m1 alone on its cell, one mode near sqrt(K_LC1/m1)), when its ring stands CAL_RING_TO_NOISE x above the
    record's quiet noise; else None."""
    fc = rig.force_chain
    f1 = math.sqrt(fc.load_cell_stiffness_n_per_m / fc.m1) / (2 * np.pi)
    i0 = p.brk + int(round(2e-4 / p.dt))
    seg = p.fs[i0:i0 + CAL_SAMPLES]
    if len(seg) < CAL_SAMPLES // 2:
        return None
    seg = seg - np.mean(seg)
    noise = float(np.std(p.fs[:max(10, p.pre1 // 4)]))
    for f, z, e in matrix_pencil(seg, p.dt):
        if abs(f / f1 - 1.0) < 0.3 and 0.0 < z < 0.5 and math.sqrt(e / len(seg)) > CAL_RING_TO_NOISE * noise:
            return z
    return None


def cell_damping_from(zetas: Iterable[Optional[float]]) -> Optional[Tuple[float, int]]:
    """(median, count) of the first CAL_PULLS measured ratios among the per-pull cell_zeta() values (None: not
    measured on that pull), in pull order; None if none was measured."""
    found = []
    for z in zetas:
        if len(found) >= CAL_PULLS:
            break
        if z is not None:
            found.append(z)
    return (float(np.median(found)), len(found)) if found else None


def cell_damping_ratio(pulls: Sequence[Pull], idx: Sequence[int], rig) -> Optional[Tuple[float, int]]:
    """(damping ratio, pulls used) of the load cells (cell_zeta), the median over up to CAL_PULLS of the pulls idx
    where it could be measured; None if it could not on any."""
    return cell_damping_from(cell_zeta(pulls[j], rig) for j in idx)


def cell_calibration(cal: Optional[Tuple[float, int]], rig) -> Tuple[Optional[float], Optional[dict]]:
    """(the stationary cell's damping coefficient c1 that T must use, or None to keep the rig's; the calibration as
    report.json cell_damping says it, or None when nothing was measured) from cell_damping_ratio()'s result."""
    if cal is None:
        return None, None
    fc = rig.force_chain
    zeta, n = cal
    used = abs(zeta / fc.load_cell_damping_ratio - 1.0) > CAL_MIN_CHANGE
    out = {'rig_damping_ratio': fc.load_cell_damping_ratio, 'measured_damping_ratio': zeta, 'pulls': n,
           'used_for_tension': used}
    return (2.0 * zeta * math.sqrt(fc.load_cell_stiffness_n_per_m * fc.m1) if used else None), out


def with_tension(p: Pull, rig, c1: Optional[float]) -> Pull:
    """The pull with T recomputed from its stationary cell with damping coefficient c1 (None: the pull as is)."""
    if c1 is None:
        return p
    fc = rig.force_chain
    return dataclasses.replace(p, T=tension_from_stationary(p.fs, p.dt, fc.m1, fc.load_cell_stiffness_n_per_m, c1))


def calibrate_cells(pulls: Sequence[Pull], rig) -> Tuple[Sequence[Pull], Optional[dict]]:
    """The cells' damping ratio measured on the pulls' free decay (cell_damping_ratio); when it departs from the
    rig's by more than CAL_MIN_CHANGE (relative), every pull's T is recomputed with it (a1 from F_stat depends on the
    stationary cell's damping: with a wrong one T rings wrongly at the cell mode). Returns (pulls, calibration or
    None when nothing was measured)."""
    c1, out = cell_calibration(cell_damping_ratio(pulls, range(len(pulls)), rig), rig)
    if c1 is None:
        return pulls, out
    return tuple(with_tension(p, rig, c1) for p in pulls), out


def calibration_note(cells: Optional[dict]) -> Optional[str]:
    if not (cells and cells['used_for_tension']):
        return None
    return (f'the cells ring with damping ratio {cells["measured_damping_ratio"]:.4g} (free decay after the '
            f'break, {cells["pulls"]} pulls), not the rig\'s {cells["rig_damping_ratio"]:.4g}: T = F_stat + '
            f'm1 a1 uses the measured one')


@dataclass(frozen=True)
class Analysis:
    """Everything the stages measured (no files, nothing decided yet)."""

    pulls: tuple                 # per usable pull: its Pull (analyse) or PullInfo (stream.analyse_stream)
    quality: tuple               # PullQuality per campaign pull
    fit: tuple                   # list positions of the fitted pulls
    held: tuple                  # list positions of the held-out pulls
    hums: Optional[tuple]        # the mains hum per pull when it is significant (analyse: the arrays; the stream:
    #                              HumScales), else None
    candidates: dict             # catalog name -> {'parameters', 'evidence', 'channel', ...}
    force: dict                  # the full force model: coef, delay_s, held-out SSE
    ring: Optional[dict]         # the observed free-decay mode, its held-out scores and one segment, if any
    notes: tuple = ()
    screens: tuple = ()          # quality.PullScreen per campaign pull (the data-quality stage)
    excluded: dict = field(default_factory=dict)   # pull name -> why the data-quality stage left it out
    cells: Optional[dict] = None  # calibrate_cells(): the cells' damping ratio measured, and whether T used it
    friction: Optional[dict] = None   # current_stage(): held-out squared current residuals without/with friction
    failed: tuple = ()           # (pull name, one line) per pull whose file could not be read or analysed
    retried: tuple = ()          # names of the pulls rerun because a worker died under them
    scheduler: str = ''          # where the per-pull stages ran ('' for analyse(): in this process, one pass)

    @property
    def fitted_pulls(self) -> list:
        return [self.pulls[j].name for j in self.fit]

    @property
    def held_out_pulls(self) -> list:
        return [self.pulls[j].name for j in self.held]


FORCE_CHANNEL_TEXT = 'force_moving_n - (T + m2 a2), analysis window'


def hum_candidate(f_hum: float, pres: Sequence[Tuple[np.ndarray, np.ndarray]], amps: Sequence[float], a_fit: float,
                  fm_h, fm_0, fit, held) -> Tuple[dict, bool]:
    """(the mains-hum candidate, whether it is significant) from the hum frequency f_hum, the few pulls' pre-pull
    residuals pres (for its interval), every pull's hum amplitude, and the full force model with (fm_h) and without
    (fm_0) the hum: a ForceModel or a ForceStats."""
    c_h, _, d_h = fm_h.fit_delay(set(TERMS), fit)
    c_0, _ = fm_0.fit(set(TERMS), fit, d_h)
    sig = significance(fm_0.sse_per_pull(set(TERMS), c_0, d_h, held), fm_h.sse_per_pull(set(TERMS), c_h, d_h, held))
    sig['rms_gain_alone'] = significance(fm_0.sse_per_pull(set(), {}, 0.0, held),
                                         fm_h.sse_per_pull(set(), {}, 0.0, held))['rms_gain']
    ci = {'frequency_hz': list(bootstrap_ci([hum_frequency_near(t, r, f_hum) for t, r in pres], np.mean)),
          'amplitude_n': list(bootstrap_ci([amps[k] for k in fit], np.mean))}
    cand = {'parameters': {'frequency_hz': f_hum, 'amplitude_n': a_fit}, 'parameters_ci95': ci, 'ci_pulls': len(fit),
            'evidence': sig,
            'channel': FORCE_CHANNEL_TEXT, 'where': f'whole record; line at {f_hum:.2f} Hz'}
    return cand, bool(sig['significant'])


def hum_scale(amps: Sequence[float], a_fit: float, j: int) -> float:
    """The factor on held-out pull j's own hum estimate: its amplitude comes from the fitted pulls (a_fit)."""
    return a_fit / max(amps[j], 1e-12)


def hum_stage(pulls, fit, held, m2) -> Tuple[dict, Optional[tuple]]:
    """The mains-hum candidate and, when it is significant, the hum per pull.

    Frequency from a few fitted pulls' pre-pull records; phase per pull from its own pre-pull record;
    amplitude of the held-out pulls from the fitted pulls. Scored on W (disjoint from the pre-pull
    record the phases came from), inside the full force model."""
    few = few_pulls(fit)
    pres = [_pre_resid(pulls[j], m2) for j in few]
    f_hum, _power = hum_frequency_from(pres, pulls[few[0]].dt)
    amps, hums = [], []
    for p in pulls:
        a, h = hum_per_pull(p, f_hum, m2)
        amps.append(a)
        hums.append(h)
    a_fit = float(np.mean([amps[k] for k in fit]))
    hums = [h * hum_scale(amps, a_fit, j) if j in held else h for j, h in enumerate(hums)]
    cand, significant = hum_candidate(f_hum, pres, amps, a_fit, ForceModel(pulls, m2, hums), ForceModel(pulls, m2),
                                      fit, held)
    return cand, (tuple(hums) if significant else None)


def force_stage(pulls, hums, fit, held, m2) -> Tuple[dict, dict]:
    """The force-channel candidates (each tested by dropping it from the full model) and the full model."""
    return force_stage_from(ForceModel(pulls, m2, hums), fit, held, m2)


def force_stage_from(fm_, fit, held, m2) -> Tuple[dict, dict]:
    """force_stage() on a force model: a ForceModel (the pulls' arrays) or a ForceStats (their sufficient
    statistics)."""
    full = set(TERMS)
    coef_full, _, d_full = fm_.fit_delay(full, fit)
    sse_full = fm_.sse_per_pull(full, coef_full, d_full, held)
    base_sse = fm_.sse_per_pull(set(), {}, 0.0, held)
    params_full = force_params(coef_full, d_full, m2)
    ci = force_params_ci(fm_.loo_fits(full, fit), coef_full, d_full, m2)
    cand = {}
    for term in TERMS:
        d = 0.0 if term == 'accel_delay' else d_full
        c, _ = fm_.fit(full - {term}, fit, d)
        sig = significance(fm_.sse_per_pull(full - {term}, c, d, held), sse_full)
        c1, _, d1 = (fm_.fit_delay({term}, fit) if term == 'accel_delay' else (*fm_.fit({term}, fit), 0.0))
        sig['rms_gain_alone'] = significance(base_sse, fm_.sse_per_pull({term}, c1, d1, held))['rms_gain']
        cand[term] = {'parameters': params_full[term], 'parameters_ci95': ci[term], 'ci_pulls': len(fit),
                      'evidence': sig, 'channel': FORCE_CHANNEL_TEXT}
    # non-linearity check for the gain: would T^2 explain more than a linear gain?
    cand['moving_cell_gain']['evidence']['t_squared_rel_reduction'] = fm_.t2_reduction(coef_full, d_full, fit, held)
    force = {'coef': coef_full, 'delay_s': d_full, 'sse_base_held': base_sse.tolist(),
             'sse_full_held': sse_full.tolist()}
    return cand, force


def free_decay_mode(p: Pull) -> Optional[Tuple[float, float, float]]:
    """The strongest mode (frequency, damping ratio, energy) of the pull's free decay after the break, or None."""
    seg = ring_segment(p)
    if seg is None:
        return None
    mm = [m for m in matrix_pencil(seg[:800], p.dt) if 100.0 < m[0] < 10000.0 and 0 < m[1] < 0.5]
    return mm[0] if mm else None


def cell_modes(fc) -> list:
    """The model of record's only mode after the break: the moving cell on m2, [(frequency, damping ratio)]."""
    return [(math.sqrt(fc.load_cell_stiffness_n_per_m / fc.m2) / (2 * np.pi), fc.load_cell_damping_ratio)]


def observed_mode(modes: Sequence[Optional[tuple]]) -> Optional[Tuple[float, float]]:
    """(frequency, damping ratio): the medians of the few fitted pulls' free_decay_mode() (None: none had one)."""
    modes = [m for m in modes if m is not None]
    if not modes:
        return None
    return float(np.median([m[0] for m in modes])), float(np.median([m[1] for m in modes]))


@dataclass(frozen=True)
class RingPart:
    """One held-out pull's free decay scored with the cell mode alone (base) and with the observed mode (ext)."""

    sse_base: float          # with the campaign's sample interval (the ring stage's)
    sse_ext: float
    ring_to_noise: float
    samples: int
    own_base: float          # with the pull's own sample interval (the report's RMS)
    own_ext: float
    segment: Optional[np.ndarray] = None


def ring_part(p: Pull, dt: float, cell: list, mode: Tuple[float, float], keep: bool = False) -> Optional[RingPart]:
    """RingPart of the held-out pull p (None: no clean free decay); dt: the campaign's sample interval; keep: keep
    the segment (for the plot)."""
    seg = ring_segment(p)
    if seg is None:
        return None
    b, e = ring_sse(seg, dt, cell), ring_sse(seg, dt, cell + [mode])
    ob, oe = (b, e) if p.dt == dt else (ring_sse(seg, p.dt, cell), ring_sse(seg, p.dt, cell + [mode]))
    return RingPart(b, e, ring_to_noise(p, seg, cell, mode), len(seg), ob, oe, seg if keep else None)


def ring_stage_from(modes: Sequence[Optional[tuple]], parts: Sequence[Optional[RingPart]], names: Sequence[str],
                    dt: float, fc) -> Tuple[Optional[dict], Optional[dict]]:
    """The mount-resonance candidate (None, None without a free-decay mode) from the few fitted pulls'
    free_decay_mode() and the held-out pulls' ring_part() (with the observed_mode() of those modes); names: the
    held-out pulls' names."""
    obs = observed_mode(modes)
    if obs is None:
        return None, None
    modes = [m for m in modes if m is not None]
    fo, zo = obs
    f_cell = cell_modes(fc)[0][0]
    ok = [(n, pt) for n, pt in zip(names, parts) if pt is not None]
    b = np.array([pt.sse_base for _, pt in ok])
    e = np.array([pt.sse_ext for _, pt in ok])
    r2n = np.array([pt.ring_to_noise for _, pt in ok])
    sig = significance(b, e) if len(ok) >= 2 else {'significant': False, 'rel_sse_reduction': 0.0, 't': 0.0,
                                                   'rms_gain': 1.0}
    sig.update(observed_frequency_hz=fo, observed_damping_ratio=zo, cell_mode_hz=f_cell,
               frequency_rule=f'observed < {MOUNT_MAX_FRACTION} x cell mode ({MOUNT_MAX_FRACTION * f_cell:.0f} Hz)')
    if fo >= MOUNT_MAX_FRACTION * f_cell:
        sig['significant'] = False
    ci = {'frequency_hz': list(bootstrap_ci([m[0] for m in modes])),
          'damping_ratio': list(bootstrap_ci([m[1] for m in modes]))}
    sig['ring_to_noise'] = float(np.median(r2n)) if len(r2n) else 0.0
    sig['ring_to_noise_ci95'] = list(bootstrap_ci(r2n)) if len(r2n) else [0.0, math.inf]
    cand = {'parameters': {'frequency_hz': fo, 'damping_ratio': zo}, 'parameters_ci95': ci, 'ci_pulls': len(ok),
            'evidence': sig,
            'channel': 'accel_axial - a3(encoder), 0.2-30 ms after the break',
            'identified': 'the mode as it appears in the measured channels (extension.yaml maps it to the mount)'}
    first = next(((n, pt) for n, pt in ok if pt.segment is not None), (None, None))
    ring = {'fo': fo, 'zo': zo, 'segment': first[1].segment if first[1] else None, 'segment_pull': first[0],
            'segment_dt': dt, 'sse_base': [pt.own_base for _, pt in ok], 'sse_ext': [pt.own_ext for _, pt in ok],
            'samples': [pt.samples for _, pt in ok]}
    return cand, ring


def ring_stage(pulls, fit, held, fc) -> Tuple[Optional[dict], Optional[dict]]:
    """The mount-resonance candidate from the free decay after the break (None, None without one)."""
    modes = [free_decay_mode(pulls[j]) for j in few_pulls(fit)]
    obs = observed_mode(modes)
    dt = pulls[0].dt
    parts = [] if obs is None else [ring_part(pulls[j], dt, cell_modes(fc), obs, keep=k == 0)
                                    for k, j in enumerate(held)]
    if parts and parts[0] is None:   # the plot's segment: the first held-out pull with one
        k = next((k for k, pt in enumerate(parts) if pt is not None), None)
        if k is not None:
            parts[k] = ring_part(pulls[held[k]], dt, cell_modes(fc), obs, keep=True)
    return ring_stage_from(modes, parts, [pulls[j].name for j in held], dt, fc)


def friction_candidate(rows: np.ndarray, fcf: float, b: np.ndarray, e: np.ndarray, n_fit: int) -> dict:
    """The coulomb-friction candidate from the fitted pulls' friction_row()s, their statistic fcf, and the held-out
    pulls' friction_sse() without (b) and with (e) it."""
    return {'parameters': {'force_n': fcf}, 'parameters_ci95': {'force_n': list(bootstrap_ci(rows, _friction_stat))},
            'ci_pulls': n_fit, 'evidence': significance(b, e),
            'channel': 'motor_current_a - force balance (i kf = m_c a3 + b v3 + F_move)'}


def current_stage(pulls, fit, held, rig) -> Tuple[Optional[dict], Optional[dict]]:
    """The coulomb-friction candidate from the motor current and the held-out squared residuals without/with it
    (None, None without a current channel)."""
    rows = friction_offsets(pulls, fit, rig)
    if rows is None:
        return None, None
    fcf = _friction_stat(rows)
    b = [friction_sse(pulls[j], rig, 0.0) for j in held]
    e = [friction_sse(pulls[j], rig, fcf) for j in held]
    return (friction_candidate(rows, fcf, np.array(b), np.array(e), len(fit)),
            {'sse_base': b, 'sse_ext': e, 'samples': [len(pulls[j].t) for j in held]})


def analyse(campaign_pulls, rig) -> Analysis:
    """All statistics (no files), in one pass with every pull's arrays in memory. campaign_pulls: [(meta, channels)].

    The reference implementation: discover() streams the pulls instead (stream.py), with the same stages."""
    if len(campaign_pulls) < MIN_PULLS:
        raise DiscoveryError(f'campaign has {len(campaign_pulls)} pulls; expected at least {MIN_PULLS} '
                             '(half are fitted, half held out)')
    quality = tuple(check_quality(m, c) for m, c in campaign_pulls)
    dts = {round(q.dt, 12) for q in quality}
    if len(dts) != 1:
        raise DiscoveryError(f'pulls have different sample intervals {sorted(dts)}; expected one rate')
    screens = tuple(screen_pull(q.name, c) for q, (_m, c) in zip(quality, campaign_pulls))
    prepared = [prepare(m, c, rig, q, sc) for (m, c), q, sc in zip(campaign_pulls, quality, screens)]
    why = [sc.exclusion(p.w0, p.w1) for p, sc in zip(prepared, screens)]
    excluded = {p.name: w for p, w in zip(prepared, why) if w}
    pulls = tuple(p for p, w in zip(prepared, why) if not w)
    if len(pulls) < MIN_PULLS:
        return unusable_analysis(len(pulls), len(prepared), quality, screens, excluded)
    m2 = rig.force_chain.m2
    fit, held = _split(pulls)
    notes = []
    pulls, cells = calibrate_cells(pulls, rig)
    if calibration_note(cells):
        notes.append(calibration_note(cells))
    hum, hums = hum_stage(pulls, fit, held, m2)
    cand = {'mains_hum': hum}
    force_cand, force = force_stage(pulls, hums, fit, held, m2)
    cand.update(force_cand)
    mount, ring = ring_stage(pulls, fit, held, rig.force_chain)
    friction, friction_sses = current_stage(pulls, fit, held, rig)
    notes += candidate_notes(cand, mount, friction)
    return Analysis(pulls, quality, tuple(fit), tuple(held), hums, cand, force, ring, tuple(notes), screens, excluded,
                    cells, friction_sses)


def unusable_analysis(usable: int, total: int, quality: tuple, screens: tuple, excluded: dict, **run) -> Analysis:
    """The analysis when the data-quality stage leaves fewer than MIN_PULLS pulls: nothing fitted, a note why."""
    return Analysis((), quality, (), (), None, {}, {}, None,
                    (f'{usable} of {total} pulls are usable after the data-quality screen; '
                     f'at least {MIN_PULLS} are needed',), screens, excluded, **run)


def candidate_notes(cand: dict, mount: Optional[dict], friction: Optional[dict]) -> list:
    """Adds the mount and friction candidates to cand; the notes on the ones that could not be tested."""
    notes = []
    if mount is None:
        notes.append('no free decay after the break to analyse for a mount resonance')
    else:
        cand['mount_resonance'] = mount
    if friction is None:
        notes.append('coulomb_friction not tested: the data has no motor_current_a channel')
    else:
        cand['coulomb_friction'] = friction
    return notes


@dataclass(frozen=True)
class Decision:
    """The causes named (strongest first), every candidate's practical-significance verdict, and those withheld."""

    named: tuple
    verdicts: dict = field(default_factory=dict)          # name -> uncertainty.verdict() of each candidate
    rejected: dict = field(default_factory=dict)          # name -> why it was withheld
    notes: tuple = ()

    def with_verdict(self, kind: str) -> list:
        return [n for n, v in self.verdicts.items() if v['verdict'] == kind]


CAUSE_ORDER = ('mains_hum', 'moving_cell_gain', 'effective_mass', 'accel_delay', 'ac_coupling',
               'mount_resonance', 'coulomb_friction')


def _admissible(name: str, c: dict) -> bool:
    if not c['evidence'].get('significant'):
        return False
    if name == 'coulomb_friction':
        return c['parameters']['force_n'] > 0   # the catalog's dry friction opposes the motion
    if name == 'ac_coupling':
        tau = c['parameters']['time_constant_s']
        return tau > 0 and math.isfinite(tau)
    return True


def tolerance_input(name: str, c: dict) -> Tuple[float, Tuple[float, float]]:
    """(estimate, 95 % interval) of the quantity the cause's tolerance band applies to."""
    par = BAND_PARAMETER[name][0]
    if par in c['parameters']:
        return c['parameters'][par], tuple(c['parameters_ci95'][par])
    return c['evidence'][par], tuple(c['evidence'][par + '_ci95'])


def decide(analysis: Analysis, rig) -> Decision:
    """Named causes (strongest first): significant on held-out pulls AND outside their tolerance band."""
    cand = analysis.candidates
    if not analysis.pulls:
        return Decision((), notes=('no decision: too few usable pulls',))
    verdicts = {}
    for n in CAUSE_ORDER:
        if n in cand:
            est, ci = tolerance_input(n, cand[n])
            verdicts[n] = verdict(est, ci, band(n, rig.tolerances, rig.force_chain.m2), _admissible(n, cand[n]),
                                  cand[n]['ci_pulls'])
    named = [n for n, v in verdicts.items() if v['verdict'] == NAMED]
    rejected, notes = {}, []
    nl = cand['moving_cell_gain']['evidence']['t_squared_rel_reduction']
    if nl > NONLIN_SHARE:
        for n in named:
            if n in TERMS:
                rejected[n] = ('withheld: the moving cell departs from T non-linearly (a T^2 term '
                               f'removes {100 * nl:.0f} % of the held-out residual left by the linear force model)')
        named = [n for n in named if n not in TERMS]
        notes.append('the moving cell departs from T non-linearly (T^2 term significant); the force-channel '
                     'catalog entries do not explain it')
    named.sort(key=lambda n: -cand[n]['evidence']['rel_sse_reduction'])
    return Decision(tuple(named), verdicts, rejected, tuple(notes))


LEFTOVER_BAND_HZ = 4000.0   # the structure check looks below this (above it, sampling of the break's step aliases)


def _band(x: np.ndarray, dt: float) -> np.ndarray:
    X = np.fft.rfft(x)
    X[np.fft.rfftfreq(len(x), dt) > LEFTOVER_BAND_HZ] = 0.0
    return np.fft.irfft(X, len(x))


def leftover(analysis: Analysis, named, rig) -> Optional[dict]:
    """Structure left in the held-out force residual after the extension (W vs the quiet pre-pull record)."""
    pulls, held, hums = analysis.pulls, analysis.held, analysis.hums
    fm_ = ForceModel(pulls, rig.force_chain.m2, hums)
    terms = set(n for n in named if n in TERMS)
    coef, d = fit_terms(fm_, terms, analysis.fit)
    parts = [leftover_part(pulls[j], hums[j] if hums is not None else None, fm_.resid(terms, coef, d, j), rig)
             for j in held]
    return leftover_from(parts, pulls[0].dt)


def fit_terms(fm_, terms, fit) -> Tuple[dict, float]:
    """(coefficients, delay) of the force model with the given terms on the fitted pulls (the delay fitted when it
    is a term, else 0)."""
    coef, _, d = (fm_.fit_delay(terms, fit) if 'accel_delay' in terms else (*fm_.fit(terms, fit), 0.0))
    return coef, d


@dataclass(frozen=True)
class LeftoverPart:
    """What one held-out pull adds to the structure check (leftover_part)."""

    var_window: float        # residual variance in W (band-limited, steps left out)
    var_quiet: float         # the quiet pre-pull floor's
    spectrum: np.ndarray     # residual power spectrum (2^16 points)
    corr: dict               # channel -> |correlation| with the residual


def leftover_part(p: Pull, hum: Optional[np.ndarray], r: np.ndarray, rig) -> LeftoverPart:
    """One held-out pull's share of leftover(): r is its force residual on W after the extension (ForceModel.resid),
    hum its hum estimate when the hum is significant (else None)."""
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
        """The structure check (see leftover()); dt: the campaign's sample interval."""
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
    """leftover() from the held-out pulls' leftover_part()s, in pull order."""
    acc = LeftoverSum()
    for part in parts:
        acc.add(part)
    return acc.result(dt)
