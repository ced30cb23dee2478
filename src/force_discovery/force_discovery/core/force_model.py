"""The force model: F_move - hum = g T + M a2(t + d) - k C on the analysis window, fitted over the pulls' samples
(ForceModel; force_stats.ForceStats answers the same questions from per-pull sufficient statistics), and its
coefficients as catalog parameters with their intervals. ROS-free.

The accelerometer's delay d is a shift of a2 (WindowShift: band-limited, exact), not an interpolation between
samples: a real sensor's or DAQ's delay does not low-pass the channel it delays, and an interpolated one does (by
5 % at a 3 kHz mode sampled at 10 kHz, half a sample off), which the effective mass then takes up. The delay is
searched on a grid (delay_grid) from a lead (d < 0: a DAQ that samples its channels in turn samples the
accelerometer after the moving cell) to a lag; between two grid delays a fit uses the two neighbours' normal
equations, weighted linearly (design(): both neighbours' rows, each scaled by the square root of its weight), so
every fit is one least-squares problem whatever d is, and the statistics of force_stats reproduce it.
"""
from __future__ import annotations

import math
from typing import Dict, List, NamedTuple, Optional, Sequence, Tuple

import numpy as np

from force_tester_sim.core.shift import Shifter

from .errors import DiscoveryError
from .prep import Pull
from .uncertainty import jackknife_ci

TERMS = ('moving_cell_gain', 'effective_mass', 'accel_delay', 'ac_coupling')
DELAY_MAX_S = 200e-6       # the delay search: the accelerometer lags the force by up to this ...
DELAY_LEAD_S = 50e-6       # ... or leads it by up to this (a DAQ's channel skew, a moving cell that lags)
DELAY_STEP_MAX_S = 5e-6    # the grid's step: half a sample, but not coarser than this (the normal equations are
                           # weighted linearly between grid delays: a bias of the order of the step squared; the
                           # reference-free path's delay grid keeps to it too)


#: regressors a model-form variant adds (budget: extra_systematics): the tension's own timing against the moving
#: cell, T's rate in N per us of shift (the model of record has the two cells simultaneous; a DAQ that samples its
#: channels in turn, or a stationary cell that lags, makes them not)
EXTRA = ('tension_timing',)
TIMING_UNIT_S = 1e-6


GRID_BATCH_BYTES = 1 << 20   # grid_sse's designs stacked at most this big at once (at least one): all 51 delays of a
                             # 100-pull campaign's fitted pulls at once made its discover peak at 357 MB, 292 MB so,
                             # 282 before the batching; a 12-pull discover's CPU is the same with 1 MB or no bound
SHIFT_MARGIN = 256   # samples either side of W a shift sees (a delay reaches 20 samples at 100 kHz; the ends' ripple
                     # stays in the margin): a 2 s record is shifted from about a fifth of it


class Fit(NamedTuple):
    """A force model fitted on some pulls: its coefficients by column name, the sum of squared residuals, and the
    accelerometer delay it was fitted at (s)."""

    coefficients: dict
    sse: float
    delay_s: float


class TermsFit(NamedTuple):
    """A force model of the named terms fitted on the fitted pulls (fit_terms): the terms, coefficients, delay (s)."""

    terms: frozenset
    coefficients: dict
    delay_s: float


class LooFit(NamedTuple):
    """One leave-one-pull-out refit: the coefficients and the delay (s)."""

    coefficients: dict
    delay_s: float


class WindowShift:
    """A channel on W (p.w0:p.w1) shifted band-limited by any d (Shifter on W and SHIFT_MARGIN samples either
    side: ForceModel and force_blocks shift alike)."""

    def __init__(self, x: np.ndarray, p: Pull):
        m = min(p.w0, SHIFT_MARGIN)
        self.x, self.m, self.n = x[p.w0:p.w1], m, p.w1 - p.w0
        self.shifter = Shifter(x[p.w0 - m:p.w1 + SHIFT_MARGIN], p.dt)

    def __call__(self, d: float) -> np.ndarray:
        return self.x if d == 0.0 else self.shifter(d)[self.m:self.m + self.n]

    def many(self, ds: np.ndarray) -> np.ndarray:
        """(len(ds), W): the channel shifted by each d of ds, as __call__ one d at a time to rounding (d = 0: the
        channel itself). A shift by d = k dt + f is the shift by f, rotated circularly by k samples (the spectrum's
        factor exp(i w d) = exp(i w f) exp(i w k dt), the DFT's shift theorem: exact, the Nyquist bin included), so a
        grid of delays needs one inverse transform per fraction f of a sample it holds (a grid of half samples:
        one), not one per delay."""
        ds = np.asarray(ds, float)
        sh = self.shifter
        k = np.floor(ds / sh.dt + 1e-6).astype(int)          # whole samples of each d
        frac = ds - k * sh.dt                                 # and the rest, in [0, dt) to rounding
        key = np.round(frac / sh.dt, 6)
        trend = sh.trend[self.m:self.m + self.n]
        at = np.arange(self.m, self.m + self.n)
        out = np.empty((len(ds), self.n))
        for f in np.unique(key):
            rows = np.flatnonzero(key == f)
            base = np.fft.irfft(sh.X * np.exp(1j * sh.w * frac[rows[0]]), sh.n)
            out[rows] = np.take(base, at + k[rows, None], mode='wrap') + trend + (sh.slope * ds[rows])[:, None]
        out[ds == 0.0] = self.x
        return out

    def rate(self) -> np.ndarray:
        return self.shifter.rate()[self.m:self.m + self.n]


def tension_rate(p: Pull) -> np.ndarray:
    """The tension_timing column on W: dT/dt (band-limited) times TIMING_UNIT_S."""
    return WindowShift(p.T, p).rate() * TIMING_UNIT_S


def delay_grid(dt: float) -> np.ndarray:
    """The delays the force model tries: -DELAY_LEAD_S .. DELAY_MAX_S (to whole steps), 0 included."""
    step = min(dt / 2, DELAY_STEP_MAX_S)
    return np.arange(-int(math.ceil(DELAY_LEAD_S / step - 1e-9)), int(math.floor(DELAY_MAX_S / step + 1e-9)) + 1) * step


def grid_parts(grid: np.ndarray, d: float) -> List[Tuple[int, float]]:
    """[(index into grid, weight)]: the grid delays a fit at d uses, its two neighbours weighted linearly (clipped
    to the grid), or the grid's 0 alone for d = 0 (ForceModel.design and ForceStats.design alike)."""
    if d == 0.0:
        return [(int(np.argmin(np.abs(grid))), 1.0)]
    x = (d - grid[0]) / (grid[1] - grid[0])
    i = min(max(int(math.floor(x)), 0), len(grid) - 2)
    f = min(max(x - i, 0.0), 1.0)
    return [(k, w) for k, w in ((i, 1.0 - f), (i + 1, f)) if w > 0]


def checked_extra(extra: Sequence[str]) -> tuple:
    bad = [e for e in extra if e not in EXTRA]
    if bad:
        raise DiscoveryError(f'extra regressor(s) {bad} unknown; expected some of {list(EXTRA)}')
    return tuple(extra)


class ForceModel:
    """F_move - hum = g T + M a2(t + d) - k C on W (C: running integral of F_move - hum over the whole record)."""

    def __init__(self, pulls: Sequence[Pull], m2: float, hums: Optional[Sequence] = None, extra: Sequence[str] = ()):
        """hums: the mains-hum estimate per pull (whole record) to subtract from F_move, or None; extra: EXTRA
        regressors every fit adds."""
        self.m2 = m2
        self.pulls = pulls
        self.extra = checked_extra(extra)
        self.rates = [tension_rate(p) for p in pulls] if self.extra else []
        self.full = []
        for p, h in zip(pulls, hums if hums is not None else [None] * len(pulls)):
            y = p.fm - (h if h is not None else 0.0)
            self.full.append((y[p.w0:p.w1], p.T[p.w0:p.w1], (np.cumsum(y) * p.dt)[p.w0:p.w1]))
        self._shifters: Dict[int, WindowShift] = {}
        self._cache: Dict[float, list] = {}

    def a2_at(self, j: int, d: float, made: Optional[np.ndarray] = None) -> np.ndarray:
        """Pull j's a2(t + d) on W (made: it, already shifted, to keep)."""
        key = round(d, 12)
        if key not in self._cache:
            if len(self._cache) > 128:
                self._cache.clear()
            self._cache[key] = [None] * len(self.pulls)
        row = self._cache[key]
        if row[j] is None and made is not None:
            row[j] = made
        if row[j] is None:
            if j not in self._shifters:
                self._shifters[j] = WindowShift(self.pulls[j].a2, self.pulls[j])
            row[j] = self._shifters[j](d)
        return row[j]

    def delay_grid(self) -> np.ndarray:
        return delay_grid(self.pulls[0].dt)

    def _columns(self, terms, j: int, a2: np.ndarray, m2: float):
        """(y, columns, names) of pull j's design on W given its a2 there (ForceStats._combination's, in samples)."""
        y0, Tj, Cj = self.full[j]
        y = y0.copy()
        cols, names = [], []
        if 'moving_cell_gain' in terms:
            if 'effective_mass' in terms:
                cols += [Tj, a2]
                names += ['g', 'M']
            else:
                cols += [Tj + m2 * a2]
                names += ['g']
        else:
            y = y - Tj
            if 'effective_mass' in terms:
                cols += [a2]
                names += ['M']
            else:
                y = y - m2 * a2
        if 'ac_coupling' in terms:
            cols += [-Cj]
            names += ['k']
        for e in self.extra:
            cols += [self.rates[j]]
            names += [e]
        return y, cols, names

    def design(self, terms, d, idx, masked=True, t2=False):
        """(ys, Xs, names) per pull of idx, on W: y adjusted for the fixed terms and the regressors (t2: T^2
        appended as the last column). masked=True: the usable samples, and between two grid delays both
        neighbours' rows, scaled by the square roots of their weights (module doc); masked=False: all of W with
        a2 shifted by d itself (a residual to look at, not to fit)."""
        d = d if 'accel_delay' in terms else 0.0
        grid = self.delay_grid()
        ys, Xs, names = [], [], []
        for j in idx:
            p = self.pulls[j]
            if not masked:
                y, cols, names = self._columns(terms, j, self.a2_at(j, d), self.m2)
                ys.append(y)
                Xs.append(np.column_stack(cols) if cols else np.zeros((len(y), 0)))
                continue
            ok = p.usable(p.w0, p.w1)
            yy, XX = [], []
            for k, w in grid_parts(grid, d):
                y, cols, names = self._columns(terms, j, self.a2_at(j, grid[k]), self.m2)
                if t2:
                    cols = cols + [self.full[j][1] ** 2]
                r = math.sqrt(w)
                yy.append(r * y[ok])
                XX.append(r * np.column_stack(cols)[ok] if cols else np.zeros((int(np.count_nonzero(ok)), 0)))
            ys.append(np.concatenate(yy))
            Xs.append(np.vstack(XX))
        return ys, Xs, names

    def fit(self, terms, idx, d=0.0) -> Fit:
        """The model of ``terms`` fitted on pulls idx at delay d."""
        ys, Xs, names = self.design(terms, d, idx)
        if not names:
            return Fit({}, float(sum(np.sum(y ** 2) for y in ys)), d)
        X = np.vstack(Xs)
        y = np.concatenate(ys)
        c, *_ = np.linalg.lstsq(X, y, rcond=None)
        r = y - X @ c
        return Fit(dict(zip(names, c)), float(r @ r), d)

    def fit_delay(self, terms, idx) -> Fit:
        """The model of ``terms`` fitted on pulls idx, the delay too (the grid's best, refined by a parabola)."""
        grid = self.delay_grid()
        sse = self.grid_sse(terms, idx, grid)
        k = int(np.argmin(sse))
        d = float(grid[k] + _parabolic_offset(sse, k) * (grid[1] - grid[0]))
        return self.fit(terms, idx, d)

    def grid_sse(self, terms, idx, grid: np.ndarray) -> np.ndarray:
        """fit(terms, idx, d).sse at each d of grid: the designs of GRID_BATCH_BYTES at a time stacked (zero rows pad
        the shorter ones: they add nothing to a fit), their coefficients from one batched QR, the residuals y - X c
        summed as fit() sums them. Each design's QR is its own: the batch changes a number only by rounding (its zero
        rows)."""
        if self.pulls:
            self.prefill(idx, grid)
        out = np.empty(len(grid))
        a = 0
        while a < len(grid):
            first = self.design(terms, grid[a], idx)
            if not first[2]:
                return np.array([float(sum(np.sum(y ** 2) for y in ys)) for ys, _, _ in
                                 (self.design(terms, d, idx) for d in grid)])
            rows, cols = sum(len(y) for y in first[0]), len(first[2])
            b = min(len(grid), a + max(1, GRID_BATCH_BYTES // (8 * rows * (cols + 1))))
            designs = [first, *(self.design(terms, d, idx) for d in grid[a + 1:b])]
            Xs = [np.vstack(X) for _, X, _ in designs]
            ys = [np.concatenate(y) for y, _, _ in designs]
            n = max(len(y) for y in ys)
            X = np.zeros((b - a, n, cols))
            y = np.zeros((b - a, n))
            for k, (Xk, yk) in enumerate(zip(Xs, ys)):
                X[k, :len(yk)], y[k, :len(yk)] = Xk, yk
            del Xs, ys, designs
            Q, R = np.linalg.qr(X)
            try:
                c = np.linalg.solve(R, np.einsum('kni,kn->ki', Q, y)[..., None])[..., 0]
            except np.linalg.LinAlgError:   # a design without full rank: fit()'s least squares, one delay at a time
                return np.array([self.fit(terms, idx, d).sse for d in grid])
            del Q
            r = y - np.einsum('kni,ki->kn', X, c)
            out[a:b] = np.einsum('kn,kn->k', r, r)
            a = b
        return out

    def prefill(self, idx, grid: np.ndarray) -> None:
        """a2_at(j, d) for every pull j of idx and every d of grid made at once (WindowShift.many)."""
        if len(grid) > 128:
            return
        for j in idx:
            missing = [d for d in grid if self._cache.get(round(d, 12), [None] * len(self.pulls))[j] is None]
            if len(missing) < 2:
                continue
            if j not in self._shifters:
                self._shifters[j] = WindowShift(self.pulls[j].a2, self.pulls[j])
            for d, a in zip(missing, self._shifters[j].many(np.array(missing))):
                self.a2_at(j, d, a)

    def loo_fits(self, terms, idx) -> List[LooFit]:
        """Leave-one-pull-out refits over idx, the delay refitted on the grid when it is a term.

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
            out.append(LooFit(dict(zip(names, ci)), float(grid[i] + off * (grid[1] - grid[0]))))
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
        ys, Xs, names = self.design(set(TERMS), d, fit, t2=True)
        c, *_ = np.linalg.lstsq(np.vstack(Xs), np.concatenate(ys), rcond=None)
        ys2, Xs2, _ = self.design(set(TERMS), d, held, t2=True)
        c0 = np.array([coef[n] for n in names])
        s0 = sum(float(np.sum((y - Xk[:, :-1] @ c0) ** 2)) for y, Xk in zip(ys2, Xs2))
        s1 = sum(float(np.sum((y - Xk @ c) ** 2)) for y, Xk in zip(ys2, Xs2))
        return float(1 - s1 / s0) if s0 > 0 else 0.0


def resid_at(p: Pull, m2: float, hum: Optional[np.ndarray], terms, coef: dict, d: float,
             sel: np.ndarray) -> np.ndarray:
    """The force model's residual at the samples sel of the whole record (outside W: the moving cell's free phase
    before the load, where T is about 0 and the model the catalog's g m2 a2), with the coefficients fitted on W:
    F_move - hum - (g T + M a2(t + d) - k C), C the running integral over the whole record as on W; a2 is shifted by
    linear interpolation (the carriage's motion before the load is slow beside the delay)."""
    y = p.fm - (0.0 if hum is None else hum)
    a2 = np.interp(p.t[sel] + d, p.t, p.a2) if ('accel_delay' in terms and d) else p.a2[sel]
    T = p.T[sel]
    if 'moving_cell_gain' in terms and 'effective_mass' not in terms:
        pred = coef['g'] * (T + m2 * a2)
    else:
        pred = (coef['g'] if 'moving_cell_gain' in terms else 1.0) * T \
            + (coef['M'] if 'effective_mass' in terms else m2) * a2
    if 'ac_coupling' in terms:
        pred = pred - coef['k'] * (np.cumsum(y) * p.dt)[sel]
    return y[sel] - pred


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


def force_params_ci(loo: Sequence[LooFit], coef: dict, d: float, m2: float) -> dict:
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


def fit_once(fm_, terms, fit) -> Fit:
    """The force model of ``terms`` on the fitted pulls, the delay fitted when it is a term (else 0)."""
    return fm_.fit_delay(terms, fit) if 'accel_delay' in terms else fm_.fit(terms, fit)


def fit_terms(fm_, terms, fit) -> TermsFit:
    """The force model with the given terms on the fitted pulls (fit_once), with its terms."""
    f = fit_once(fm_, terms, fit)
    return TermsFit(frozenset(terms), f.coefficients, f.delay_s)
