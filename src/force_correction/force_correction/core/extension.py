"""The correctable part of a discovered model extension, as streaming filters on the moving-cell channel.

`./ft discover` writes extension.yaml; its ``correction:`` section says how the measured moving-cell
force departs from the force the m*a correction assumes, and this module undoes it, block by block:

- ``mass_kg``: the mass that belongs in m*a (replaces m2);
- ``moving_cell_gain``: measured = gain x true, so the force is divided by it;
- ``moving_cell_quadratic_per_n``, ``moving_cell_cubic_per_n2`` (the terms F_move^2 and F_move^3 on
  force_moving that discover found beyond the catalog): measured = F + c2 F^2 + c3 F^3, so each sample is
  linearised (Newton's method, pointwise: no state) after the hum and before the gain;
- ``accel_delay_s``: the accelerometer lags the force channel, so the force is delayed by the same
  amount (a fractional-delay FIR) and the two line up again: corrected(t) = F(t - d) - m a2_meas(t);
- ``ac_coupling_time_constant_s``: the channel is first-order high-passed (piezo discharge); the
  exact inverse of that discrete high-pass restores the slow part;
- ``mains_hum_hz``: the interference line is estimated on the unloaded signal (recursive least
  squares of a sine and cosine at that frequency, exponentially forgotten over ``hum_memory_s``,
  updated only while |F| < ``hum_unloaded_n``) and subtracted everywhere; during a pull the
  estimate is held. (A notch would also remove the pull's own content near that frequency.)

Every stage is an IIR/FIR filter with explicit state like scipy's ``zi``, so a signal cut into any
blocks gives the one-pass result. A NaN sample enters the filters as the last finite value (so it
cannot poison their state) and leaves as NaN at its own index.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import Optional, Tuple

import numpy as np
import yaml

from .errors import CorrectionError


def _lfilter():
    """scipy.signal.lfilter, imported on first use (scipy.signal takes ~1 s to import, which
    every command importing this module would otherwise pay)."""
    from scipy.signal import lfilter
    return lfilter


# the terms beyond the catalog (extension.yaml extra_terms:, force_discovery's beyond_catalog) that the correction
# undoes: on the moving cell, a polynomial linearised live -> the correction key that carries its coefficient
CORRECTION_TERMS = {'F_move^2': 'moving_cell_quadratic_per_n', 'F_move^3': 'moving_cell_cubic_per_n2'}
# the channels a term changes the corrected force through: F_move itself, and a2 in m*a2
CORRECTED_CHANNELS = ('force_moving', 'accel_axial')


@dataclass(frozen=True)
class Extension:
    mass_kg: Optional[float] = None
    moving_cell_gain: float = 1.0
    moving_cell_quadratic_per_n: float = 0.0
    moving_cell_cubic_per_n2: float = 0.0
    accel_delay_s: float = 0.0
    ac_coupling_time_constant_s: Optional[float] = None
    mains_hum_hz: Optional[float] = None
    hum_memory_s: float = 0.5
    hum_unloaded_n: float = 50.0
    # extra_terms on CORRECTED_CHANNELS that the correction cannot undo ('force_moving: v'): said, not ignored
    not_applied: Tuple[str, ...] = ()

    def __post_init__(self):
        def bad(name, value, expected):
            raise CorrectionError(f'extension {name} {value!r} is invalid; expected {expected}')
        if self.mass_kg is not None and not (math.isfinite(self.mass_kg) and 0 < self.mass_kg <= 1e4):
            bad('mass_kg', self.mass_kg, 'a mass in (0, 1e4] kg')
        if not (math.isfinite(self.moving_cell_gain) and 0.1 <= self.moving_cell_gain <= 10):
            bad('moving_cell_gain', self.moving_cell_gain, 'a gain in [0.1, 10]')
        for name, lim in (('moving_cell_quadratic_per_n', 1e-2), ('moving_cell_cubic_per_n2', 1e-4)):
            v = getattr(self, name)
            if not (math.isfinite(v) and abs(v) <= lim):
                bad(name, v, f'a coefficient in [-{lim:g}, {lim:g}]')
        if not (math.isfinite(self.accel_delay_s) and 0 <= self.accel_delay_s <= 0.01):
            bad('accel_delay_s', self.accel_delay_s, 'a delay in [0, 0.01] s')
        tau = self.ac_coupling_time_constant_s
        if tau is not None and not (math.isfinite(tau) and 1e-4 <= tau <= 1e4):
            bad('ac_coupling_time_constant_s', tau, 'a time constant in [1e-4, 1e4] s')
        if self.mains_hum_hz is not None and not (math.isfinite(self.mains_hum_hz) and 1 <= self.mains_hum_hz <= 1e4):
            bad('mains_hum_hz', self.mains_hum_hz, 'a frequency in [1, 1e4] Hz')

    @classmethod
    def from_dict(cls, data: dict) -> 'Extension':
        known = {f.name for f in fields(cls)} - {'not_applied'}
        unknown = sorted(set(data) - known)
        if unknown:
            raise CorrectionError(f'extension key {unknown[0]!r} is unknown; expected some of {sorted(known)}')
        try:
            return cls(**{k: (None if v is None else float(v)) for k, v in data.items()})
        except (TypeError, ValueError) as exc:
            raise CorrectionError(f'extension {data!r} is invalid: {exc}') from None

    def describe(self) -> str:
        """What the extension changes, briefly: 'none', or 'moving_cell_gain 1.02, accel_delay_s 2.1e-05'."""
        default = type(self)()
        changed = [f'{f.name} {v:.6g}' if isinstance(v, float) else f'{f.name} {v}' for f in fields(self)
                   if f.name != 'not_applied' and (v := getattr(self, f.name)) != getattr(default, f.name)]
        if self.not_applied:
            changed.append(f'not undone: {", ".join(self.not_applied)}')
        return ', '.join(changed) or 'none'

    @classmethod
    def from_yaml(cls, path) -> 'Extension':
        """The ``correction:`` section of an extension.yaml written by `./ft discover`."""
        try:
            doc = yaml.safe_load(Path(path).read_text())
        except (OSError, yaml.YAMLError) as exc:
            raise CorrectionError(f'extension file {str(path)!r} cannot be read: {exc}') from None
        if not isinstance(doc, dict) or not isinstance(doc.get('correction', {}), dict):
            raise CorrectionError(f'extension file {str(path)!r} has no correction: mapping; '
                                  'expected the extension.yaml of ./ft discover')
        ext = cls.from_dict(doc.get('correction') or {})
        return replace(ext, not_applied=not_undone(doc.get('extra_terms') or []))

    def not_applied_warning(self) -> str:
        """The one line that names the terms the correction cannot undo ('' when there are none)."""
        return (f'the extension\'s {", ".join(self.not_applied)} cannot be undone by the correction: the corrected '
                'force is off by them') if self.not_applied else ''

    @property
    def nonlinear(self) -> bool:
        return self.moving_cell_quadratic_per_n != 0.0 or self.moving_cell_cubic_per_n2 != 0.0

    def linearise(self, x: np.ndarray) -> np.ndarray:
        """F with F + c2 F^2 + c3 F^3 = x, sample by sample (Newton's method from F = x; the slope is kept
        >= 0.1 so a sample beyond the polynomial's fold stays finite)."""
        c2, c3 = self.moving_cell_quadratic_per_n, self.moving_cell_cubic_per_n2
        f = np.array(x, dtype=float)
        for _ in range(8):
            g = f + c2 * f ** 2 + c3 * f ** 3 - x
            f = f - g / np.maximum(1.0 + 2 * c2 * f + 3 * c3 * f ** 2, 0.1)
        return f

    def stages(self, sample_rate_hz: float) -> Tuple[Tuple[np.ndarray, np.ndarray], ...]:
        """(b, a) of each linear filter stage on the moving-cell force, in order (the hum canceller
        comes first, separately)."""
        out = []
        if self.moving_cell_gain != 1.0:
            out.append((np.array([1.0 / self.moving_cell_gain]), np.array([1.0])))
        if self.ac_coupling_time_constant_s is not None:
            # forward model y[n] = p (y[n-1] + x[n] - x[n-1]), p = tau / (tau + T): inverse below
            p = self.ac_coupling_time_constant_s / (self.ac_coupling_time_constant_s + 1.0 / sample_rate_hz)
            out.append((np.array([1.0 / p, -1.0]), np.array([1.0, -1.0])))
        if self.accel_delay_s > 0:
            d = self.accel_delay_s * sample_rate_hz
            k, f = int(math.floor(d)), d - math.floor(d)
            h = np.zeros(k + 2)
            h[k], h[k + 1] = 1.0 - f, f
            out.append((h, np.array([1.0])))
        return tuple(out)


def load_filters(extension: Extension) -> None:
    """Import what the extension's filters run on (scipy.signal) now, not on the first block: a node calls this when
    it (re)starts. On a busy machine the import took longer than a validator's 5 s without a block, and the
    extension pair of `./ft demo` lost its first pull."""
    if extension.stages(1.0) or extension.mains_hum_hz is not None:
        _lfilter()


def not_undone(extra_terms) -> Tuple[str, ...]:
    """'channel: term' of each of an extension's extra_terms that changes the corrected force (CORRECTED_CHANNELS)
    and that the correction does not undo (not in CORRECTION_TERMS): a cable's drag on the moving cell, a drifting
    accelerometer zero, a frame mode. The correction cannot see the signals they need (v, t) or their phase."""
    if not isinstance(extra_terms, list) or not all(isinstance(e, dict) for e in extra_terms):
        raise CorrectionError(f'extension extra_terms {extra_terms!r} is invalid; expected a list of '
                              '{channel, term, coefficient} mappings')
    return tuple(f'{e.get("channel")}: {e.get("term")}' for e in extra_terms
                 if e.get('channel') in CORRECTED_CHANNELS
                 and not (e.get('channel') == 'force_moving' and e.get('term') in CORRECTION_TERMS))


class ForcePrefilter:
    """The extension's stages on the moving-cell force, streaming, with explicit copyable state."""

    def __init__(self, extension: Extension, sample_rate_hz: float):
        self.extension = extension
        self.stages = extension.stages(sample_rate_hz)
        self.hum = HumCanceller(extension, sample_rate_hz) if extension.mains_hum_hz is not None else None
        self.state = self.initial_state()

    def initial_state(self):
        """(zi of each stage, last finite input, hum canceller state)."""
        zis = tuple(np.zeros(max(len(a), len(b)) - 1) for b, a in self.stages)
        return zis, 0.0, (self.hum.initial_state() if self.hum else None)

    def reset(self):
        self.state = self.initial_state()

    def process(self, force: np.ndarray) -> np.ndarray:
        x = np.asarray(force, dtype=float)
        if (not self.stages and self.hum is None and not self.extension.nonlinear) or not len(x):
            return x
        zis, last, hum_state = self.state
        bad = ~np.isfinite(x)
        if bad.any():  # hold the last finite value through bad samples
            x = x.copy()
            idx = np.where(bad, 0, np.arange(len(x)))
            np.maximum.accumulate(idx, out=idx)
            held = x[idx]
            held[bad & (np.cumsum(~bad) == 0)] = last
            x = held
        y, new = x, []
        if self.hum is not None:
            y, hum_state = self.hum.process(y, hum_state)
        if self.extension.nonlinear:
            y = self.extension.linearise(y)
        for (b, a), zi in zip(self.stages, zis):
            if len(zi):
                y, zf = _lfilter()(b, a, y, zi=zi)
            else:
                y, zf = _lfilter()(b, a, y), zi
            new.append(zf)
        self.state = (tuple(new), float(x[-1]), hum_state)
        if bad.any():
            y = y.copy()
            y[bad] = np.nan
        return y


class HumCanceller:
    """Causal estimate of a known-frequency line, learnt on unloaded samples, subtracted from all.

    For each sample n the estimate uses samples before n only: exponentially weighted sums of
    the sine/cosine products and of the signal times them, over the unloaded samples, give a
    2x2 least-squares fit. The sums are first-order recursions run by lfilter with explicit
    state, so any block split gives the one-pass result.
    """

    def __init__(self, extension: Extension, sample_rate_hz: float):
        self.w = 2 * math.pi * extension.mains_hum_hz / sample_rate_hz
        self.lam = math.exp(-1.0 / (extension.hum_memory_s * sample_rate_hz))
        self.unloaded = extension.hum_unloaded_n

    @staticmethod
    def initial_state():
        return 0, np.zeros((5, 1))  # samples seen, recursion states of the 5 sums

    def process(self, x: np.ndarray, state) -> tuple:
        n0, zi = state
        n = np.arange(n0, n0 + len(x))
        c, s = np.cos(self.w * n), np.sin(self.w * n)
        m = (np.abs(x) < self.unloaded).astype(float)
        terms = np.stack([m * c * c, m * c * s, m * s * s, m * x * c, m * x * s])
        sums, zf = _lfilter()([1.0], [1.0, -self.lam], terms, axis=1, zi=self.lam * zi)
        # the sums before each sample: shift by one (the first uses the carried state)
        prev = np.concatenate([zi, sums[:, :-1]], axis=1)
        cc, cs, ss, xc, xs = prev
        det = cc * ss - cs * cs
        ok = det > 1e-6 * np.maximum(cc + ss, 1e-300) ** 2
        safe = np.where(ok, det, 1.0)
        a = np.where(ok, (xc * ss - xs * cs) / safe, 0.0)
        b = np.where(ok, (xs * cc - xc * cs) / safe, 0.0)
        return x - (a * c + b * s), (n0 + len(x), sums[:, -1:])
