"""Standard uncertainties (k = 1) of the rig's nominal constants: the ``uncertainty:`` section of a rig YAML.

Every number in the daq, drive, force_chain and sensors sections has one, in that number's own unit, keyed
``section.key`` (``rig.uncertainty.u('force_chain.moving_side_mass_kg')``). A rig YAML may restate any of them;
the others get a default fraction of their own value (``DEFAULTS_REL``; on the nominal rig these equal the
packaged nominal.yaml's section, and the sim README justifies them), so a heavier or stiffer rig scales with them.
A value of 0 states the constant as exact (a gear ratio, a set limit). Anything negative, missing, not finite or
larger than the constant itself is refused with one line naming the key and the value.

The section may also state the standard uncertainty of a departure's parameter (departures.CATALOG), keyed
``departures.<cause>.<parameter>`` (``uncertainty: {departures: {accel_delay: {delay_s: 2.0e-7}}}``): an
extension.yaml written by ``./ft discover`` states so the parameters it estimated, and the correction's peak
uncertainty takes them (tools/ft_cli/peak_inputs.py). A departure's u may not exceed its value (where that is not
0; an absent delay is 0 with an uncertainty).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Iterator, Mapping

from .departures import CATALOG, OPTIONAL_PARAMS
from .errors import SimError

DEPARTURES = 'departures'   # the section of departure parameters' uncertainties

#: section -> key -> default standard uncertainty RELATIVE to the constant (k = 1); a rig without an
#: ``uncertainty:`` entry for a constant gets this fraction of its own value. The sim README's "Uncertainty"
#: table gives the reasons.
DEFAULTS_REL: dict[str, dict[str, float]] = {
    'daq': {
        'sample_rate_hz': 5.0e-5,                    # 50 ppm: a DAQ's crystal time base
        'record_length_s': 0.0,                      # set, not measured
    },
    'drive': {
        'armature_resistance_ohm': 0.05,             # winding temperature
        'armature_inductance_h': 0.5,                # assumed, not in the thesis
        'torque_constant_nm_per_a': 0.02,            # datasheet tolerance class
        'back_emf_constant_v_s_per_rad': 0.02,
        'motor_inertia_kg_m2': 0.05,
        'gear_ratio': 0.0,                           # a tooth count
        'pulley_radius_m': 0.01,                     # the belt's effective pitch radius
        'actuator_inertia_kg_m2': 0.05,              # reflected belt + carriage (thesis Appendix C)
        'carriage_mass_kg': 0.01,
        'viscous_damping_motor_n_s_per_m': 0.5,      # "obtained through calibration"
        'viscous_damping_actuator_n_s_per_m': 0.5,
        'current_limit_a': 0.0,                      # a drive setting
        'voltage_limit_v': 0.0,                      # a drive setting
        'usable_track_m': 0.01,
    },
    'force_chain': {
        'stationary_side_mass_kg': 0.01,             # half-cell + fixtures; the thesis's own figures disagree
        'moving_side_mass_kg': 0.01,
        'load_cell_stiffness_n_per_m': 0.2,          # assumed from the cell's class, not measured
        'load_cell_damping_ratio': 0.5,              # assumed
        'lanyard_stiffness_n_per_m': 0.25,           # wire rope length and lay
        'lanyard_damping_ratio': 0.5,                # assumed
    },
    'sensors': {
        'load_cell_sensitivity_mv_per_lbf': 0.005,   # a calibration certificate's +/-1 % (k = 2)
        'load_cell_range_lbf': 0.0,                  # a rating
        'accelerometer_sensitivity_mv_per_g': 0.01,  # +/-2 % (k = 2) over the band
        'encoder_resolution_m': 0.0,                 # a scale pitch
    },
}


@dataclass(frozen=True)
class Uncertainties:
    """Standard uncertainties keyed ``section.key`` (k = 1, the constant's own unit)."""

    values: tuple   # ((key, u), ...) sorted by key; made by uncertainties(rig, stated)

    def u(self, key: str) -> float:
        for k, v in self.values:
            if k == key:
                return v
        raise SimError(f'uncertainty of {key!r} is unknown; expected one of {[k for k, _ in self.values]}')

    def relative(self, key: str, value: float) -> float:
        """u / |value| (0 for an exact constant)."""
        u = self.u(key)
        return 0.0 if u == 0.0 else u / abs(value)

    def __iter__(self) -> Iterator[tuple[str, float]]:
        return iter(self.values)

    def as_dict(self) -> dict[str, dict[str, float]]:
        out: dict[str, dict[str, float]] = {}
        for key, u in self.values:
            section, name = key.split('.', 1)
            out.setdefault(section, {})[name] = u
        return out


def overrides_from_data(data: Any) -> tuple:
    """Parse the YAML ``uncertainty:`` section into sorted ((``section.key``, u), ...) pairs (None: none)."""
    if data is None:
        return ()
    if not isinstance(data, Mapping):
        raise SimError(f'uncertainty is {data!r}; expected a mapping of sections {sorted(DEFAULTS_REL)}')
    out = []
    for section, keys in data.items():
        if section == DEPARTURES:
            out += departure_overrides(keys)
            continue
        if section not in DEFAULTS_REL:
            raise SimError(f'uncertainty has unknown section {section!r}; expected one of '
                           f'{sorted(DEFAULTS_REL) + [DEPARTURES]}')
        if not isinstance(keys, Mapping):
            raise SimError(f'uncertainty.{section} is {keys!r}; expected a mapping of its constants')
        for key, u in keys.items():
            where = f'uncertainty.{section}.{key}'
            if key not in DEFAULTS_REL[section]:
                raise SimError(f'{where} is not a constant of {section}; expected one of '
                               f'{sorted(DEFAULTS_REL[section])}')
            out.append((f'{section}.{key}', standard_u(where, u)))
    return tuple(sorted(out))


def standard_u(where: str, u: Any) -> float:
    """u as a standard uncertainty (a finite number >= 0), or SimError naming where and the value."""
    if isinstance(u, bool) or not isinstance(u, (int, float)) or not math.isfinite(u) or u < 0:
        raise SimError(f'{where} is {u!r}; expected a standard uncertainty, a finite number >= 0')
    return float(u)


def departure_overrides(data: Any) -> list:
    """The ``uncertainty.departures`` mapping {cause: {parameter: u}} as [(``departures.cause.parameter``, u)]."""
    if not isinstance(data, Mapping):
        raise SimError(f'uncertainty.{DEPARTURES} is {data!r}; expected a mapping of causes {sorted(CATALOG)}')
    out = []
    for cause, params in data.items():
        where = f'uncertainty.{DEPARTURES}.{cause}'
        if cause not in CATALOG:
            raise SimError(f'{where} is not a catalog cause; expected one of {sorted(CATALOG)}')
        known = sorted({**CATALOG[cause][1], **OPTIONAL_PARAMS.get(cause, {})})
        if not isinstance(params, Mapping):
            raise SimError(f'{where} is {params!r}; expected a mapping of its parameters {known}')
        for par, u in params.items():
            if par not in known:
                raise SimError(f'{where}.{par} is not a parameter of {cause}; expected one of {known}')
            out.append((f'{DEPARTURES}.{cause}.{par}', standard_u(f'{where}.{par}', u)))
    return out


def check_departure_u(key: str, u: float, value: float) -> None:
    """Refuse a stated u (key ``section.key`` or ``departures.cause.parameter``) above the value it is the
    uncertainty of (unless that is 0: an absent delay is 0 with an uncertainty)."""
    if value != 0 and u > abs(value):
        raise SimError(f'uncertainty.{key} is {u!r}, larger than the value {value!r}; expected a standard '
                       f'uncertainty below it')


def uncertainties(rig, overrides: tuple = ()) -> Uncertainties:
    """Every constant's standard uncertainty: the stated ones, and the default fraction of the rest."""
    stated = dict(overrides)
    values = []
    for section, keys in DEFAULTS_REL.items():
        for key, rel in keys.items():
            value = getattr(getattr(rig, section), key)
            u = stated.get(f'{section}.{key}', rel * abs(value))
            if u > abs(value):
                raise SimError(f'uncertainty.{section}.{key} is {u!r}, larger than the value {value!r}; '
                               f'expected a standard uncertainty below it')
            values.append((f'{section}.{key}', u))
    deps = getattr(rig, 'departures', None)
    for key, u in stated.items():   # the departures' stated: checked against the rig's where it has the departure
        if key.startswith(DEPARTURES + '.'):
            _, cause, par = key.split('.')
            dep = deps.get(cause) if deps is not None else None
            if dep is not None and dep.get(par) is not None:
                check_departure_u(key, u, dep.get(par))
            values.append((key, u))
    return Uncertainties(tuple(sorted(values)))
