"""The expanded uncertainty (k = 2) of one pull's corrected peak force, from the signals of that pull.

The corrected force is c(t) = F(t - d) / g - m a(t) (thesis eq 24 after an extension's stages): F the moving
cell, g its gain, d the accelerometer's lag, m = m2, a = V / S the accelerometer (S its sensitivity). Its peak
P = max_t c(t) is what a test engineer reports. What P inherits (``PeakInputs``, standard uncertainties, k = 1):

- m2 (``mass_rel``), the moving cell's gain (``gain_rel``) and the accelerometer's sensitivity
  (``accel_sensitivity_rel``): c is linear in each at every t, so P moves by the sensitivity coefficient at the
  peak (-m a(t_pk), F(t_pk) / g, m a(t_pk)) times u: **linear propagation (GUM, JCGM 100)** is exact to first
  order while the peak stays on its sample, and relative u of 1-2 % do not move it;
- the accelerometer's lag (``accel_delay_s``): P moves by -F'(t_pk) d. At a coupon's break the force falls off a
  cliff right after its peak, so F' is not the same on both sides of t_pk and a max() of a shifted signal is not
  a smooth function of d: the first-order term is not defined there. **Monte Carlo (JCGM 101)** is used for it:
  M draws of (m, g, S, d) and white noise of the measured sigma, the peak of each drawn c(t) near t_pk, and u
  the draws' standard deviation (the linear terms come out the same in it, so one MC gives the total);
- the noise: sigma of c over the pull's quiet lead-in (differences of neighbouring samples, so a slow drift does
  not count), added to each draw's samples; and since the max of a noisy plateau picks its highest noise sample
  (a one-sided bias the draws' spread does not show), sigma sqrt(2 ln n) is added to k u, n the samples within
  3 sigma of the peak.

The moving average (eq 25) cuts a short peak: the filtered peak sits below the corrected one by
``ma_cut_n = P - max(filtered)``, measured on the pull itself. The filtered peak's expanded uncertainty is
U + |ma_cut| (the cut is a one-sided bias of known size that the average adds).

The stationary cell reads T - m1 a1, not the lanyard tension T (m1 on its cell rings at ~4 kHz): U here is the
uncertainty of the corrected peak as an estimate of the lanyard tension's peak, which is what eq 24 measures.
The validation (benchmarks/bench_peak_coverage.py) compares against both.

Everything runs once per pull on arrays the validator already holds; no state crosses pulls.
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from force_tester_common.core.cache import cached_array

from .errors import CorrectionError

#: coverage factor of the stated expanded uncertainty (a calibration certificate's k = 2)
COVERAGE_FACTOR = 2.0
#: Monte Carlo draws per pull (JCGM 101 asks for enough that the std settles to 1-2 digits: 400 gives ~3.5 %)
MC_DRAWS = 400
#: half-width of the window around the peak the draws search (s): far wider than any delay drawn
PEAK_WINDOW_S = 1.0e-3
#: the quiet lead-in: the last QUIET_MAX_S of samples before |c| first exceeds this share of the peak
QUIET_FRACTION = 0.05
QUIET_MAX_S = 0.1

#: the draws' seed: the same signals around the peak give the same U, wherever the pull's samples begin
MC_SEED = 0x0E
INPUT_NAMES = ('mass_rel', 'gain_rel', 'accel_sensitivity_rel', 'accel_delay_s')


@dataclass(frozen=True)
class PeakInputs:
    """Standard uncertainties (k = 1) of what the correction uses: relative for m2, the cell's gain and the
    accelerometer's sensitivity; in seconds for the accelerometer's lag. All 0: only the noise counts."""

    mass_rel: float = 0.0
    gain_rel: float = 0.0
    accel_sensitivity_rel: float = 0.0
    accel_delay_s: float = 0.0

    def __post_init__(self):
        for name in INPUT_NAMES:
            v = getattr(self, name)
            hi = 1e-2 if name == 'accel_delay_s' else 1.0
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or not 0 <= v < hi:
                raise CorrectionError(f'peak uncertainty input {name} is {v!r}; expected a standard uncertainty, '
                                      f'a finite number in [0, {hi:g})')
            object.__setattr__(self, name, float(v))


@dataclass(frozen=True)
class PeakUncertainty:
    """One pull's corrected peak and its uncertainty (N). components: (name, standard uncertainty in N) of the
    linear budget at the peak (delay: its first-order value, max of the two sides); u_n: the Monte Carlo's
    combined standard uncertainty; expanded_n = k u_n."""

    peak_n: float
    u_n: float
    expanded_n: float
    k: float
    components: tuple
    ma_cut_n: float
    filtered_expanded_n: float
    noise_n: float
    method: str = 'monte_carlo'

    def as_dict(self) -> dict:
        return {'peak_n': self.peak_n, 'u_n': self.u_n, 'expanded_n': self.expanded_n, 'k': self.k,
                'components': dict(self.components), 'ma_cut_n': self.ma_cut_n,
                'filtered_expanded_n': self.filtered_expanded_n, 'noise_n': self.noise_n, 'method': self.method}


def quiet_noise(corrected: np.ndarray, sample_rate_hz: float) -> float:
    """sigma of the corrected signal over the quiet lead-in (NaN if there is none): the std of the differences of
    neighbouring samples over sqrt(2), so a slow drift does not count as noise."""
    c = np.asarray(corrected, dtype=float)
    top, bottom = (int(np.argmax(c)), int(np.argmin(c))) if c.size else (0, 0)
    if c.size and math.isfinite(c[top]) and math.isfinite(c[bottom]):
        # the usual pull, every sample finite (the largest and the smallest are; a NaN would be both): the largest
        # |c| from them, and the first loud sample searched for only up to the loudest one (which is loud)
        loudest = top if c[top] >= -c[bottom] else bottom
        pk = float(abs(c[loudest]))
        end = int(np.argmax(np.abs(c[:loudest + 1]) > QUIET_FRACTION * pk)) if pk > 0 else len(c)
    else:
        fin = np.isfinite(c)
        if not fin.any():
            return math.nan
        mag = np.abs(c)
        loud = fin & (mag > QUIET_FRACTION * float(np.max(mag[fin])))
        end = int(np.argmax(loud)) if loud.any() else len(c)     # the first loud sample
    q = c[max(0, end - int(QUIET_MAX_S * sample_rate_hz)):end]   # just before the load: not where the pull began
    d = np.diff(q[np.isfinite(q)])
    return float(np.std(d) / math.sqrt(2.0)) if len(d) >= 8 else math.nan


@functools.lru_cache(maxsize=8)
def mc_normals(draws: int, width: int) -> tuple:
    """The Monte Carlo's standard normals for ``draws`` draws over a window of ``width`` samples: (4 x draws) for
    m2, the gain, the sensitivity and the lag, then (draws x width) for the noise, from one generator seeded with
    MC_SEED, in that order. The same for every pull of that window (the seed is fixed), so drawn once a process
    (read-only arrays), and kept in the user's cache (force_tester_common.core.cache): a command then starts
    without importing numpy.random (~13 ms of `./ft bag correct`'s start)."""
    def draw():
        import numpy.random  # noqa: F401 - here: only when the cache has no copy
        return np.random.default_rng(MC_SEED).standard_normal(4 * draws + draws * width)

    both = cached_array(f'mc_normals-seed{MC_SEED}-numpy{np.__version__}-{draws}x{width}',
                        (4 * draws + draws * width,), draw)
    z, noise = both[:4 * draws].reshape(4, draws), both[4 * draws:].reshape(draws, width)
    z.flags.writeable = noise.flags.writeable = False
    return z, noise


@functools.lru_cache(maxsize=8)
def noise_extremes(draws: int, width: int) -> tuple:
    """The least and the largest of each column of mc_normals' noise (draws x width): kept once a process."""
    noise = mc_normals(draws, width)[1]
    least, most = noise.min(axis=0), noise.max(axis=0)
    least.flags.writeable = most.flags.writeable = False
    return least, most


def noise_peaks(row: np.ndarray, sigma: float, z_noise: np.ndarray) -> np.ndarray | None:
    """max over j of row[j] + sigma z_noise[r, j] for each draw r, the same doubles as computing every column (None
    where a value is not finite: the caller takes its general path). With the inputs all 0 every draw is the
    window's one row plus its own noise (the general path's products with 1 + 0 z are exact). Rounding keeps order,
    so each draw's peak is at least the largest row[j] + sigma least[j] (least: the column's smallest normal), and a
    column whose row[j] + sigma most[j] lies below that bound never holds a draw's peak: only the span of columns
    that can is computed (a few samples beside a sharp peak, instead of 2 ms of them)."""
    if not np.isfinite(row).all():
        return None
    least, most = noise_extremes(*z_noise.shape)
    bound = np.max(row + sigma * least)
    can = np.flatnonzero(row + sigma * most >= bound)
    a, b = int(can[0]), int(can[-1]) + 1
    peaks = (row[a:b] + sigma * z_noise[:, a:b]).max(axis=1)
    return peaks if math.isfinite(bound) and np.isfinite(peaks).all() else None


def peak_uncertainty(corrected, inertial, filtered, sample_rate_hz: float, inputs: PeakInputs,
                     k: float = COVERAGE_FACTOR, draws: int = MC_DRAWS, filtered_peak: float | None = None
                     ) -> PeakUncertainty:
    """The corrected peak of one pull and its expanded uncertainty (module docstring).

    corrected, inertial, filtered: the pull's c = F - m a, m a, and the moving average of c (N, equal lengths,
    NaN allowed); the force the correction used is c + m a. Deterministic (MC_SEED), and independent of where
    the pull's samples begin: the same pull scored live, replayed or offline gives the same U. filtered_peak: the
    largest filtered sample, NaN ignored (scoring.score_pull's), when the caller has it.
    """
    if not isinstance(inputs, PeakInputs):
        raise CorrectionError(f'inputs {inputs!r} is not a PeakInputs; expected PeakInputs(...)')
    rate = float(sample_rate_hz)
    if not math.isfinite(rate) or rate <= 0:
        raise CorrectionError(f'sample_rate_hz {sample_rate_hz!r} is out of range; expected a rate > 0 Hz')
    c = np.asarray(corrected, dtype=float)
    ma = np.asarray(inertial, dtype=float)
    fl = np.asarray(filtered, dtype=float)
    if c.ndim != 1 or ma.shape != c.shape or fl.shape != c.shape:
        raise CorrectionError(f'corrected, inertial and filtered have shapes {c.shape}, {ma.shape}, {fl.shape}; '
                              'expected 1-D arrays of equal length')
    i = int(np.argmax(c)) if c.size else 0
    # the usual pull: a finite largest corrected sample (so no NaN, argmax would give it) whose m a is finite is the
    # first largest of those where both are: no masks or index arrays of the whole pull
    if not (c.size and math.isfinite(c[i]) and math.isfinite(ma[i])):
        fin = np.isfinite(c) & np.isfinite(ma)
        if not fin.any():
            raise CorrectionError('the pull has no finite corrected sample; expected at least one')
        i = int(np.flatnonzero(fin)[np.argmax(c[fin])])
    peak = float(c[i])
    noise = quiet_noise(c, rate)
    sigma = 0.0 if math.isnan(noise) else noise
    n = len(c)
    h = max(2, int(round(PEAK_WINDOW_S * rate)))
    lo, hi = max(i - h, 0), min(i + h + 1, n)
    force = c[lo:hi] + ma[lo:hi]        # the force the correction used, where it is read: around the peak

    # the linear budget at the peak (sensitivity coefficient x standard uncertainty)
    def slope(j0, j1):
        j0, j1 = j0 - lo, j1 - lo
        return (force[j1] - force[j0]) * rate / (j1 - j0) if j1 > j0 and np.isfinite(force[[j0, j1]]).all() else 0.0
    dfdt = max(abs(slope(max(i - 1, 0), i)), abs(slope(i, min(i + 1, n - 1))))
    components = (('mass', abs(ma[i]) * inputs.mass_rel), ('gain', abs(force[i - lo]) * inputs.gain_rel),
                  ('accel_sensitivity', abs(ma[i]) * inputs.accel_sensitivity_rel),
                  ('accel_delay', dfdt * inputs.accel_delay_s), ('noise', sigma))

    # Monte Carlo over the window around the peak
    idx = np.arange(lo, hi)
    f_w, ma_w = force, ma[lo:hi]
    ok = np.isfinite(f_w) & np.isfinite(ma_w)
    z, z_noise = mc_normals(draws, hi - lo)
    em, eg, es = inputs.mass_rel * z[0], inputs.gain_rel * z[1], inputs.accel_sensitivity_rel * z[2]
    fv = np.where(ok, f_w, np.nan)
    if inputs.accel_delay_s == 0.0:
        # no lag drawn: every draw reads F at its own sample. The interpolation below would give 1 * F[j] +
        # 0 * F[j + 1], so F[j + 1]'s NaN still makes the sample NaN: kept, on one row instead of every draw's.
        f_shift = (fv + 0.0 * fv[np.minimum(np.arange(1, len(idx) + 1), len(idx) - 1)])[None, :]
    else:
        shift = inputs.accel_delay_s * rate * z[3]                 # samples; F(t - delta) by linear interpolation
        pos = np.clip(idx[None, :] - shift[:, None], lo, hi - 1) - lo
        j = np.floor(pos).astype(int)
        j1 = np.minimum(j + 1, len(idx) - 1)
        w = pos - j
        f_shift = (1 - w) * fv[j] + w * fv[j1]
    noise_only = not (inputs.mass_rel or inputs.gain_rel or inputs.accel_sensitivity_rel or inputs.accel_delay_s)
    peaks = noise_peaks(f_shift[0] - ma_w, sigma, z_noise) if noise_only and sigma > 0 and ok.all() else None
    if peaks is None:
        drawn = f_shift * (1 + eg)[:, None] - ma_w[None, :] * ((1 + em) * (1 + es))[:, None]
        if sigma > 0:
            drawn = drawn + sigma * z_noise
        peaks = np.nanmax(np.where(ok[None, :], drawn, np.nan), axis=1)
    u = float(np.std(peaks, ddof=1)) if draws > 1 else 0.0
    # the max of a noisy plateau is its highest noise sample: a one-sided bias the draws' spread does not show.
    # Its size: sigma times the expected max of n standard normals (~ sqrt(2 ln n)), n the samples within 3 sigma
    # of the peak; added to k u linearly (JCGM 100 F.2.4.5: an uncorrected known bias widens the interval)
    near = int(np.count_nonzero(ok & (c[lo:hi] >= peak - 3.0 * sigma))) if sigma > 0 else 1
    bias = sigma * math.sqrt(2.0 * math.log(near)) if near > 1 else 0.0
    big = k * u + bias
    top = filtered_peak if filtered_peak is not None else fl.max() if fl.size else math.nan
    # a finite max is the nanmax (fl.max() propagates a NaN; the caller's ignores them): one pass, or none
    fpk = float(top) if math.isfinite(top) else float(np.nanmax(fl)) if np.isfinite(fl).any() else math.nan
    cut = peak - fpk
    return PeakUncertainty(peak_n=peak, u_n=u, expanded_n=big, k=float(k), components=components, ma_cut_n=cut,
                           filtered_expanded_n=big + abs(cut) if math.isfinite(cut) else math.nan, noise_n=noise)
