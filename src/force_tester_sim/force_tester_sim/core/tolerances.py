"""Practical significance: how far a rig may depart from its model of record before it matters.

A rig YAML may carry a ``tolerances:`` section (defaults: the packaged nominal.yaml, equal to ``Tolerances()``).
Each catalog departure gets a band of its parameter around the model of record (``band()``): a departure
whose 95 % confidence interval lies inside its band is within tolerance (not worth acting on), one whose
interval lies wholly outside is worth acting on. The sim README justifies the defaults.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Any, Mapping

from .departures import CATALOG
from .errors import SimError


@dataclass(frozen=True)
class Tolerances:
    moving_cell_gain_rel: float = 0.005           # |gain - 1|: calibration uncertainty of a quartz force cell
    effective_mass_rel: float = 0.02              # |m2_true - m2| / m2: weighing the fixtures and half-cells
    accel_delay_s: float = 5.0e-6                 # a quarter sample at 50 kHz: below what the DAQ can resolve
    ac_coupling_dc_time_constant_s: float = 100.0  # tau at or above this counts as DC (50x a 2 s record)
    mains_hum_amplitude_n: float = 1.0            # about 3x the cells' 0.3 N noise, 0.1 % of a 1000 N pull
    coulomb_friction_n: float = 20.0              # 0.5 % of the drive's 4.7 kN peak force (about 0.3 A)
    mount_ring_to_noise: float = 3.0              # a mount mode counts if its ringing rms exceeds 3x the noise rms


#: catalog name -> (parameter the band applies to, Tolerances field that sets it)
BAND_PARAMETER = {
    'moving_cell_gain': ('gain', 'moving_cell_gain_rel'),
    'effective_mass': ('mass_kg', 'effective_mass_rel'),
    'accel_delay': ('delay_s', 'accel_delay_s'),
    'ac_coupling': ('time_constant_s', 'ac_coupling_dc_time_constant_s'),
    'mains_hum': ('amplitude_n', 'mains_hum_amplitude_n'),
    'coulomb_friction': ('force_n', 'coulomb_friction_n'),
    'mount_resonance': ('ring_to_noise', 'mount_ring_to_noise'),
}
assert set(BAND_PARAMETER) == set(CATALOG)


@dataclass(frozen=True)
class Band:
    """The values of ``parameter`` that count as the model of record for ``cause``: [lo, hi]."""

    cause: str
    parameter: str
    lo: float
    hi: float

    def contains(self, lo: float, hi: float) -> bool:
        """The interval [lo, hi] lies wholly inside the band."""
        return self.lo <= lo and hi <= self.hi

    def excludes(self, lo: float, hi: float) -> bool:
        """The interval [lo, hi] lies wholly outside the band."""
        return hi < self.lo or lo > self.hi

    def distance(self, x: float) -> float:
        """How far x is from the nearer band edge (0 at an edge)."""
        return min(abs(x - self.lo), abs(x - self.hi))

    def as_dict(self) -> dict:
        return {'parameter': self.parameter, 'lo': self.lo, 'hi': self.hi}


def band(cause: str, tol: Tolerances, nominal_m2_kg: float) -> Band:
    """The tolerance band of a catalog cause, in the units of its parameter."""
    if cause not in BAND_PARAMETER:
        raise SimError(f'departure {cause!r} is unknown; expected one of {sorted(BAND_PARAMETER)}')
    par, key = BAND_PARAMETER[cause]
    v = getattr(tol, key)
    if cause == 'moving_cell_gain':
        return Band(cause, par, 1.0 - v, 1.0 + v)
    if cause == 'effective_mass':
        return Band(cause, par, nominal_m2_kg * (1.0 - v), nominal_m2_kg * (1.0 + v))
    if cause == 'ac_coupling':
        return Band(cause, par, v, math.inf)
    if cause == 'accel_delay':
        return Band(cause, par, -v, v)   # a lead as well as a lag (a DAQ that samples its channels in turn)
    return Band(cause, par, 0.0, v)   # hum amplitude, friction, ring-to-noise: from zero up to v


def tolerances_from_data(data: Any) -> Tolerances:
    """Parse the YAML ``tolerances:`` section (None: the defaults); every value a finite positive number."""
    if data is None:
        return Tolerances()
    names = [f.name for f in fields(Tolerances)]
    if not isinstance(data, Mapping):
        raise SimError(f'tolerances is {data!r}; expected a mapping of {names}')
    unknown = sorted(set(data) - set(names))
    if unknown:
        raise SimError(f'tolerances has unknown key(s) {unknown}; expected only {names}')
    out = {}
    for k, v in data.items():
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not (math.isfinite(v) and v > 0):
            raise SimError(f'tolerances.{k} is {v!r}; expected a finite positive number')
        if k.endswith('_rel') and v >= 1:
            raise SimError(f'tolerances.{k} is {v!r}; expected a relative tolerance in (0, 1)')
        out[k] = float(v)
    return Tolerances(**out)
