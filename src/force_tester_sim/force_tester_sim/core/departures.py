"""Departures of a rig from the model of record: a catalog of named, parameterised effects.

A rig YAML may carry an optional ``departures:`` section; absent (or empty) means the nominal rig
(ideal sensors, model of record). Two spellings are accepted::

    departures:                                  departures:
      - {name: accel_delay, delay_s: 4.0e-5}       accel_delay: {delay_s: 4.0e-5}
      - {name: moving_cell_gain, gain: 1.02}       moving_cell_gain: {gain: 1.02}

Each entry must be one of ``CATALOG`` with exactly its parameters. Physical departures
(effective_mass, mount_resonance, coulomb_friction) change the simulation; sensor departures
(accel_delay, moving_cell_gain, ac_coupling, mains_hum) are applied to the recorded channels after
the physics (in that order: gain, ac_coupling, hum on the moving cell; delay on the accelerometer).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Dict, Mapping, Optional, Tuple

import numpy as np

from .errors import SimError
from .shift import Shifter

# mount_resonance: the base mass between the mount and the moving cell's sensing element (the bracket: the
# cell's carriage-side half and its adapter plate), by default as a fraction of the true m2 (light next to m2,
# which carries the lanyard clevis, the accelerometer block and the cell's own upper half); the optional
# parameter base_mass_kg sets it. k_mount = (2 pi f)^2 (base + m2).
MOUNT_BASE_MASS_FRACTION = 0.25

# name -> (kind, {parameter: (lower bound, upper bound, inclusive lower)}, meaning)
CATALOG: Dict[str, Tuple[str, Dict[str, tuple], str]] = {
    'effective_mass': ('physical', {'mass_kg': (0.0, 1.0e3, False)},
                       'true moving-side mass m2 differs from nominal (the correction uses nominal)'),
    'accel_delay': ('sensor', {'delay_s': (-0.01, 0.01, True)},
                    'accelerometer channel lags the force channels by delay_s (a shift; < 0: it leads them)'),
    'moving_cell_gain': ('sensor', {'gain': (0.0, 100.0, False)},
                         'moving-cell channel = gain * true F_move'),
    'mount_resonance': ('physical', {'frequency_hz': (0.0, 20000.0, False), 'damping_ratio': (0.0, 1.0, False)},
                        'lightly damped mode between moving cell and carriage: carriage - mount k/c - base mass '
                        '(base_mass_kg, default MOUNT_BASE_MASS_FRACTION * m2) - moving cell - m2; '
                        'k_mount = (2 pi f)^2 (base mass + m2)'),
    'ac_coupling': ('sensor', {'time_constant_s': (0.0, 1.0e6, False)},
                    'moving-cell channel first-order high-pass filtered (piezo discharge)'),
    'mains_hum': ('sensor', {'frequency_hz': (0.0, 25000.0, False), 'amplitude_n': (0.0, 1.0e5, True)},
                  'sinusoid (random phase per pull, seeded) added to the moving-cell channel'),
    'coulomb_friction': ('physical', {'force_n': (0.0, 1.0e5, True)},
                         'dry friction F_c sign(v3) in the drive force balance (shows in motor_current_a)'),
}

# Optional parameters: name -> {parameter: (lower bound, upper bound, inclusive lower)}; absent = the default above.
OPTIONAL_PARAMS: Dict[str, Dict[str, tuple]] = {
    'mount_resonance': {'base_mass_kg': (0.0, 1.0e3, False)},
}


@dataclass(frozen=True)
class Departure:
    name: str
    params: Tuple[Tuple[str, float], ...]   # sorted (parameter, value)

    def __getitem__(self, key: str) -> float:
        return dict(self.params)[key]

    def get(self, key: str, default: Optional[float] = None) -> Optional[float]:
        return dict(self.params).get(key, default)

    @property
    def kind(self) -> str:
        return CATALOG[self.name][0]


@dataclass(frozen=True)
class Departures:
    """The rig's departures (empty: the nominal rig). Frozen, hashable, picklable."""
    entries: Tuple[Departure, ...] = ()

    def __bool__(self) -> bool:
        return bool(self.entries)

    def __str__(self) -> str:
        if not self.entries:
            return 'none'
        return ', '.join(f'{d.name}(' + ', '.join(f'{k}={v:g}' for k, v in d.params) + ')'
                         for d in self.entries)

    def get(self, name: str) -> Optional[Departure]:
        if name not in CATALOG:
            raise SimError(f'departure {name!r} is unknown; expected one of {sorted(CATALOG)}')
        for d in self.entries:
            if d.name == name:
                return d
        return None

    def __contains__(self, name: str) -> bool:
        return self.get(name) is not None

    @property
    def names(self) -> Tuple[str, ...]:
        return tuple(d.name for d in self.entries)

    def without(self, *names: str) -> 'Departures':
        return Departures(tuple(d for d in self.entries if d.name not in names))

    def with_entry(self, name: str, **params) -> 'Departures':
        return Departures(self.without(name).entries + (_entry(name, params, f'departures.{name}'),))

    def as_dict(self) -> Dict[str, Dict[str, float]]:
        return {d.name: dict(d.params) for d in self.entries}


NO_DEPARTURES = Departures()


def _entry(name: Any, params: Mapping, where: str) -> Departure:
    if name not in CATALOG:
        raise SimError(f'{where}: departure {name!r} is unknown; expected one of {sorted(CATALOG)}')
    spec = CATALOG[name][1]
    optional = OPTIONAL_PARAMS.get(name, {})
    if not isinstance(params, Mapping):
        raise SimError(f'{where} is {params!r}; expected a mapping of {sorted(spec)}')
    if not set(spec) <= set(params) <= set(spec) | set(optional):
        extra = f' (optional: {sorted(optional)})' if optional else ''
        raise SimError(f'{where} has parameters {sorted(params)}; expected exactly {sorted(spec)}{extra}')
    spec = {**spec, **optional}
    out = []
    for k in sorted(set(params)):
        v = params[k]
        lo, hi, incl = spec[k]
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise SimError(f'{where}.{k} is {v!r}; expected a finite number')
        v = float(v)
        if not ((v >= lo if incl else v > lo) and v <= hi):
            raise SimError(f'{where}.{k} is {v!r}; expected a number in {"[" if incl else "("}{lo:g}, {hi:g}]')
        out.append((k, v))
    return Departure(str(name), tuple(out))


def departures_from_data(data: Any) -> Departures:
    """Parse the YAML ``departures:`` section (None or empty: nominal)."""
    if data is None:
        return NO_DEPARTURES
    entries = []
    if isinstance(data, Mapping):
        for name, params in data.items():
            entries.append(_entry(name, params if params is not None else {}, f'departures.{name}'))
    elif isinstance(data, list):
        for i, item in enumerate(data):
            if not isinstance(item, Mapping) or 'name' not in item:
                raise SimError(f'departures[{i}] is {item!r}; expected a mapping with a "name" key')
            params = {k: v for k, v in item.items() if k != 'name'}
            entries.append(_entry(item['name'], params, f'departures[{i}]'))
    else:
        raise SimError(f'departures is {data!r}; expected a list of entries or a mapping name -> parameters')
    names = [d.name for d in entries]
    if len(set(names)) != len(names):
        raise SimError(f'departures {names} repeat; expected each catalog entry at most once')
    return Departures(tuple(entries))


# ---------------------------------------------------------------- sensor-side departures
def high_pass(x: np.ndarray, time_constant_s: float, dt_s: float) -> np.ndarray:
    """First-order high-pass (piezo discharge), exact for a piecewise-constant-in-steps input:
    y[k] = a (y[k-1] + x[k] - x[k-1]), a = exp(-dt/tau); starts settled at 0 with x[0] as the baseline."""
    from scipy.signal import lfilter
    x = np.asarray(x, dtype=float)
    a = math.exp(-dt_s / time_constant_s)
    y = lfilter([a, -a], [1.0, -a], x - x[0])
    return y + 0.0


def hum_phase(seed: int) -> float:
    """Random (seeded, per pull) phase of the mains hum."""
    return float(np.random.default_rng([int(seed), 0x4D41494E]).uniform(0.0, 2.0 * math.pi))


def apply_sensor_departures(deps: Departures, t: np.ndarray, force_moving: np.ndarray, accel_axial: np.ndarray,
                            seed: int) -> Tuple[np.ndarray, np.ndarray]:
    """(moving-cell channel, axial accel channel) as recorded: the clean truth through the sensor departures."""
    fm = np.asarray(force_moving, dtype=float)
    a2 = np.asarray(accel_axial, dtype=float)
    dt = float(t[1] - t[0])
    d = deps.get('moving_cell_gain')
    if d is not None:
        fm = d['gain'] * fm
    d = deps.get('ac_coupling')
    if d is not None:
        fm = high_pass(fm, d['time_constant_s'], dt)
    d = deps.get('mains_hum')
    if d is not None:
        fm = fm + d['amplitude_n'] * np.sin(2.0 * math.pi * d['frequency_hz'] * t + hum_phase(seed))
    d = deps.get('accel_delay')
    if d is not None:
        a2 = Shifter(a2, dt)(-d['delay_s'])   # a delay, not an interpolation: it does not low-pass a2
    return fm, a2
