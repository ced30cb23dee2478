"""Validated, immutable parameters of the inertial correction (thesis eq 24, 25)."""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass

from .errors import CorrectionError

#: Largest accepted moving-average window (1 s at 50 kHz).
MAX_WINDOW = 50000
#: Largest accepted moving-side mass, kg (sanity bound).
MAX_MASS_KG = 1.0e4


@dataclass(frozen=True)
class CorrectionParams:
    """Parameters of ``corrected = F_move - m*a`` and the trailing moving average.

    mass_kg: moving-side mass m2 in kg; finite, in (0, MAX_MASS_KG].
        Default 1.152 kg (thesis Table 7: 2.54 lbf/g, i.e. 0.079 slug).
    window: trailing moving-average length in samples; integer in [1, MAX_WINDOW].
        Default 140 (thesis eq 25; 2.8 ms at 50 kHz).
    """

    mass_kg: float = 1.152
    window: int = 140

    def __post_init__(self) -> None:
        m = self.mass_kg
        if isinstance(m, bool) or not isinstance(m, numbers.Real):
            raise CorrectionError(
                f"mass_kg {m!r} is not a real number; expected a finite float in "
                f"(0, {MAX_MASS_KG:g}] kg")
        m = float(m)
        if not math.isfinite(m) or m <= 0.0 or m > MAX_MASS_KG:
            raise CorrectionError(
                f"mass_kg {m!r} is out of range; expected a finite float in "
                f"(0, {MAX_MASS_KG:g}] kg")
        w = self.window
        if isinstance(w, bool) or not isinstance(w, numbers.Integral):
            if isinstance(w, numbers.Real) and not isinstance(w, bool) \
                    and math.isfinite(float(w)) and float(w).is_integer():
                w = int(w)
            else:
                raise CorrectionError(
                    f"window {w!r} is not an integer; expected an integer in [1, {MAX_WINDOW}]")
        w = int(w)
        if w < 1 or w > MAX_WINDOW:
            raise CorrectionError(
                f"window {w} is out of range; expected an integer in [1, {MAX_WINDOW}]")
        object.__setattr__(self, 'mass_kg', m)
        object.__setattr__(self, 'window', w)
