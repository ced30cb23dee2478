"""Validated, immutable parameters of the inertial correction (thesis eq 24, 25)."""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass

from force_tester_common.core.correction import MASS_KG, MASS_RANGE_KG, WINDOW, WINDOW_RANGE

from .errors import CorrectionError

MIN_MASS_KG, MAX_MASS_KG = MASS_RANGE_KG
MIN_WINDOW, MAX_WINDOW = WINDOW_RANGE


@dataclass(frozen=True)
class CorrectionParams:
    """Parameters of ``corrected = F_move - m*a`` and the trailing moving average.

    mass_kg: moving-side mass m2 in kg; finite, in MASS_RANGE_KG (default MASS_KG, thesis Table 7).
    window: trailing moving-average length in samples; integer in WINDOW_RANGE (default WINDOW,
        thesis eq 25).
    """

    mass_kg: float = MASS_KG
    window: int = WINDOW

    def __post_init__(self) -> None:
        m = self.mass_kg
        if isinstance(m, bool) or not isinstance(m, numbers.Real):
            raise CorrectionError(
                f"mass_kg {m!r} is not a real number; expected a finite float in "
                f"[{MIN_MASS_KG:g}, {MAX_MASS_KG:g}] kg")
        m = float(m)
        if not math.isfinite(m) or not MIN_MASS_KG <= m <= MAX_MASS_KG:
            raise CorrectionError(
                f"mass_kg {m!r} is out of range; expected a finite float in "
                f"[{MIN_MASS_KG:g}, {MAX_MASS_KG:g}] kg")
        w = self.window
        if isinstance(w, bool) or not isinstance(w, numbers.Integral):
            if isinstance(w, numbers.Real) and not isinstance(w, bool) \
                    and math.isfinite(float(w)) and float(w).is_integer():
                w = int(w)
            else:
                raise CorrectionError(
                    f"window {w!r} is not an integer; expected an integer in "
                    f"[{MIN_WINDOW}, {MAX_WINDOW}]")
        w = int(w)
        if not MIN_WINDOW <= w <= MAX_WINDOW:
            raise CorrectionError(
                f"window {w} is out of range; expected an integer in [{MIN_WINDOW}, {MAX_WINDOW}]")
        object.__setattr__(self, 'mass_kg', m)
        object.__setattr__(self, 'window', w)
