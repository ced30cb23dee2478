"""Per-pull preparation: the data-quality check of one pull's channels and the derived signals and windows the
stages fit (T, the low-passed channels, the carriage motion from the encoder, the analysis window). ROS-free."""
from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Optional

import numpy as np

from force_tester_common.core.channels import REQUIRED_CHANNELS as REQUIRED

from .errors import DiscoveryError
from .quality import repair

LOWPASS_HZ = (7000.0, 9000.0)   # every force/accel channel is low-passed alike (zero phase) before the regressions
# ... scaled to the rate below 25 kHz: the raised cosine runs from 0.28 to 0.36 x the sample rate (7-9 kHz at 25 kHz),
# so a 10 kHz record is low-passed at 2.8-3.6 kHz (below Nyquist), a 5 kHz one at 1.4-1.8 kHz
LOWPASS_RATE_SHARE = (0.28, 0.36)
ENCODER_SPAN_S = 2e-3   # the carriage's motion (x3, v3, a3) is a cubic Savitzky-Golay fit to the encoder over this span


def lowpass_band(dt: float) -> tuple:
    """(start, stop) of the raised-cosine low-pass, Hz, for sample interval dt: LOWPASS_HZ, scaled down to the rate
    where that would reach past LOWPASS_RATE_SHARE of it."""
    return tuple(min(f, share / dt) for f, share in zip(LOWPASS_HZ, LOWPASS_RATE_SHARE))


def _lowpass_w(f: np.ndarray, dt: float) -> np.ndarray:
    lo, hi = lowpass_band(dt)
    w = np.ones_like(f)
    mid = (f > lo) & (f < hi)
    w[mid] = 0.5 * (1 + np.cos(np.pi * (f[mid] - lo) / (hi - lo)))
    w[f >= hi] = 0.0
    return w


# The grids below are cached per (length, dt): the pulls of a campaign are mostly of one length, and one pull's
# channels share a lead. A few entries keep every hit a 100-pull discover has (16 kept 0.8 MB each for nothing:
# docs/speed-discover.md).
GRID_CACHE = 4


@functools.lru_cache(maxsize=GRID_CACHE)
def _lowpass_on_grid(n: int, dt: float) -> tuple:
    """(f, the low-pass's weights) on the rfft grid of n samples at dt: the same for every pull of that length."""
    f = np.fft.rfftfreq(n, dt)
    H = _lowpass_w(f, dt)
    f.flags.writeable = H.flags.writeable = False
    return f, H


def _detrended_spectrum(x: np.ndarray, dt: float) -> tuple:
    """(X, f, H, trend): the spectrum of x less its end-to-end line, the rfft grid's frequencies and the low-pass's
    weights on it, and the line."""
    from scipy import fft as sfft  # numpy.fft's numbers to the bit, and faster on lengths with large prime factors
    n = len(x)
    trend = np.linspace(x[0], x[-1], n)
    f, H = _lowpass_on_grid(n, float(dt))
    return sfft.rfft(x - trend), f, H, trend


def filtered(x: np.ndarray, dt: float, h=None) -> np.ndarray:
    """Zero-phase low-pass of x, optionally times a frequency response h(omega) (end trend removed first)."""
    from scipy import fft as sfft
    X, f, H, trend = _detrended_spectrum(x, dt)
    if h is None:
        return sfft.irfft(H * X, len(x)) + trend
    return sfft.irfft(H * h(2 * np.pi * f) * X, len(x))


def lowpassed(x: np.ndarray, dt: float) -> np.ndarray:
    """The zero-phase low-pass every force and accelerometer channel gets (lowpass_band) of x."""
    return filtered(np.asarray(x, float), dt)


def encoder_window(dt: float) -> int:
    """The samples of the encoder's Savitzky-Golay fit (ENCODER_SPAN_S, odd, at least 5)."""
    return max(5, int(round(ENCODER_SPAN_S / dt)) | 1)


@functools.lru_cache(maxsize=16)   # a few kB each: every (rate, derivative) a campaign has
def _encoder_kernels(win: int, dt: float, deriv: int) -> tuple:
    """(the convolution kernel, the left end's and the right end's rows) of the cubic Savitzky-Golay fit's deriv-th
    derivative over win samples at dt: savgol_coeffs, and savgol_filter's 'interp' end fits of the unit impulses
    (its output is linear in its input: row i maps an end window to the fit's value at its i-th sample)."""
    from scipy.signal import savgol_coeffs, savgol_filter
    half = win // 2
    ends = savgol_filter(np.eye(win), win, 3, deriv=deriv, delta=dt, axis=0)
    out = (savgol_coeffs(win, 3, deriv=deriv, delta=dt), ends[:half].copy(), ends[win - half:].copy())
    for a in out:
        a.flags.writeable = False
    return out


def as_encoder(x: np.ndarray, dt: float, deriv: int = 0) -> np.ndarray:
    """x smoothed as the encoder's carriage motion is (its deriv-th derivative): the cubic Savitzky-Golay fit over
    ENCODER_SPAN_S, scipy's savgol_filter (mode 'interp') to rounding.

    The same kernel and end fits as savgol_filter, from savgol_coeffs once per (window, dt, deriv); the interior
    by numpy's convolve, which is about 3x faster than the ndimage filter savgol_filter calls, and the ends as two
    small products instead of two polynomial fits a call (`./ft bench encoder`). A record with a non-finite sample
    or shorter than the window is savgol_filter's directly."""
    from scipy.signal import savgol_filter
    x = np.asarray(x, float)
    win = encoder_window(dt)
    if len(x) < win or not np.isfinite(x).all():
        return savgol_filter(x, win, 3, deriv=deriv, delta=dt)
    c, left, right = _encoder_kernels(win, float(dt), int(deriv))
    half = win // 2
    y = np.convolve(x, c, mode='same')
    # each end relative to its end sample: a derivative's row sums to 0 only to rounding, times the position
    for rows, part, at in ((left, slice(0, half), slice(0, win)), (right, slice(len(x) - half, None),
                                                                   slice(len(x) - win, None))):
        ref = x[at][0]
        y[part] = rows @ (x[at] - ref) + (ref if deriv == 0 else 0.0)
    return y


def a3_response(omega: np.ndarray, dt: float) -> np.ndarray:
    """How a3 answers the carriage's true acceleration at omega (rad/s): the encoder's second-derivative
    Savitzky-Golay kernel over -omega^2 (1 at 0; the kernel is symmetric, so its response is real, written with
    -2 sin^2 so low frequencies keep their digits)."""
    from scipy.signal import savgol_coeffs
    win = encoder_window(dt)
    c = savgol_coeffs(win, 3, deriv=2, delta=dt, use='dot')
    omega = np.asarray(omega, float)
    d = np.zeros_like(omega)
    for k in range(1, win // 2 + 1):   # taps +k and -k alike; the centre tap adds nothing (sin 0)
        d -= 2.0 * (c[win // 2 + k] + c[win // 2 - k]) * np.sin(0.5 * omega * k * dt) ** 2
    out = np.ones_like(omega)
    nz = omega > 0
    out[nz] = d[nz] / -(omega[nz] ** 2)
    return out


@functools.lru_cache(maxsize=GRID_CACHE)
def a3_filter(n: int, dt: float) -> tuple:
    """(omega, a3_response) on the rfft grid of n samples at dt: the same for every pull of that length."""
    w = 2 * np.pi * np.fft.rfftfreq(n, dt)
    return w, a3_response(w, dt)


@functools.lru_cache(maxsize=GRID_CACHE)
def _a3_read_later(m: int, dt: float, lead: float) -> np.ndarray:
    """a3_filter's response on the rfft grid of m samples at dt, read lead s later (times exp(i omega lead)): a
    campaign's pulls share m and dt, and a drive's lead is used on several channels."""
    w, h = a3_filter(m, dt)
    out = h * np.exp(1j * w * lead) if lead else h
    out.flags.writeable = False
    return out


def like_a3(x: np.ndarray, dt: float, lead: float = 0.0) -> np.ndarray:
    """x through the filter that makes the encoder's a3 of the carriage's acceleration (a3_response), read lead s
    later (x(t + lead): an analog channel lags the encoder by its anti-alias filter's delay; the encoder's latched
    counter has none). A force balance with a3 in it holds only so: what rings faster than a3 follows (m2 a2 in
    F_move, at the cells' and the lanyard's modes) the carriage's own acceleration answers, not the current."""
    return _on_padded_grid(x, dt, lead, True)


def read_later(x: np.ndarray, dt: float, lead: float) -> np.ndarray:
    """x read lead s later (x(t + lead)), as like_a3 reads it but unfiltered: like_a3(x, dt, lead) is
    like_a3(read_later(x, dt, lead), dt) to the padding's rounding."""
    return _on_padded_grid(x, dt, lead, False) if lead else np.asarray(x, float)


def _on_padded_grid(x: np.ndarray, dt: float, lead: float, a3: bool) -> np.ndarray:
    """like_a3 (a3) or read_later: x less its end-to-end line, zero-padded, times the response, plus the line read
    lead s later."""
    from scipy import fft as sfft
    x = np.asarray(x, float)
    n = len(x)
    trend = np.linspace(x[0], x[-1], n)
    m = sfft.next_fast_len(n, real=True)   # zero-padded (x - trend ends at 0) to a length the FFT factors fast
    h = _a3_read_later(m, float(dt), float(lead)) if a3 else _read_later(m, float(dt), float(lead))
    y = sfft.irfft(sfft.rfft(x - trend, m) * h, m)[:n]
    return y + trend + lead * (x[-1] - x[0]) / max((n - 1) * dt, dt)


@functools.lru_cache(maxsize=GRID_CACHE)
def _read_later(m: int, dt: float, lead: float) -> np.ndarray:
    """exp(i omega lead) on the rfft grid of m samples at dt (read_later's response)."""
    out = np.exp(1j * 2 * np.pi * np.fft.rfftfreq(m, dt) * lead)
    out.flags.writeable = False
    return out


def tension_from_stationary(fs: np.ndarray, dt: float, m1: float, k1: float, c1: float) -> np.ndarray:
    """T = F_stat + m1 a1 (eq 21/23) with a1 from F_stat = K u1 + c1 v1 (exact in the frequency domain): filtered(fs)
    plus filtered(fs) times a1's response, from one spectrum of fs."""
    from scipy import fft as sfft
    X, f, H, trend = _detrended_spectrum(fs, dt)
    w = 2 * np.pi * f
    return (sfft.irfft(H * X, len(fs)) + trend) + sfft.irfft(H * (-m1 * w ** 2 / (k1 + 1j * c1 * w)) * X, len(fs))


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
    fm = filtered(np.asarray(ch['force_moving_n'], float), dt)
    a2 = filtered(np.asarray(ch['accel_axial_m_s2'], float), dt)
    x3, v3, a3 = (as_encoder(x, dt, k) for k in range(3))
    cur = ch.get('motor_current_a')
    cur = None if cur is None else np.asarray(cur, float)
    peak = q.peak_n
    load0 = int(np.flatnonzero(fs > 0.1 * peak)[0])
    brk = int(np.flatnonzero(T > 0.05 * peak)[-1])
    w0 = max(0, load0 - int(0.05 / dt))
    w1 = min(n, brk + int(0.15 / dt))
    pre1 = max(0, load0 - int(0.03 / dt))
    return Pull(q.name, t, dt, fm, fs, a2, T, x3, v3, a3, cur, w0, w1, pre1, load0, brk, peak, ok)
