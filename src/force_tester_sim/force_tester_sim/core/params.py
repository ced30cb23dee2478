"""Rig parameters: frozen dataclasses loaded from YAML (defaults equal the packaged nominal.yaml)."""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any, Mapping

import yaml

from force_tester_common.core.correction import MASS_KG
from force_tester_common.core.units import FT_M, G_M_S2, LBF_N

from .departures import NO_DEPARTURES, Departures, departures_from_data
from .errors import SimError
from .extra_terms import extra_terms_from_data
from .tolerances import Tolerances, tolerances_from_data
from .uncertainty import Uncertainties, overrides_from_data, uncertainties

NOMINAL_YAML = Path(__file__).resolve().parent.parent / 'config' / 'nominal.yaml'
#: the truth reference rig: the datasheet rig plus documented departures (the sim README)
TRUTH_YAML = NOMINAL_YAML.with_name('truth_reference.yaml')


@dataclass(frozen=True)
class DaqParams:
    sample_rate_hz: float = 50000.0
    record_length_s: float = 2.0

    @property
    def n_samples(self) -> int:
        return int(round(self.sample_rate_hz * self.record_length_s))

    @property
    def dt_s(self) -> float:
        return 1.0 / self.sample_rate_hz


@dataclass(frozen=True)
class DriveParams:
    armature_resistance_ohm: float = 0.28
    armature_inductance_h: float = 0.004
    torque_constant_nm_per_a: float = 1.591
    back_emf_constant_v_s_per_rad: float = 0.9185
    motor_inertia_kg_m2: float = 2.60e-3
    gear_ratio: float = 3.0
    pulley_radius_m: float = 0.0668
    actuator_inertia_kg_m2: float = 0.2335
    carriage_mass_kg: float = 47.0
    viscous_damping_motor_n_s_per_m: float = 10.0
    viscous_damping_actuator_n_s_per_m: float = 10.0
    current_limit_a: float = 66.46
    voltage_limit_v: float = 325.2
    usable_track_m: float = 1.524

    @property
    def reflected_mass_kg(self) -> float:
        """m_c = (J_z + N^2 J_m) / r^2: everything the motor moves, reflected to the carriage."""
        return (self.actuator_inertia_kg_m2 + self.gear_ratio ** 2 * self.motor_inertia_kg_m2) \
            / self.pulley_radius_m ** 2

    @property
    def viscous_damping_n_s_per_m(self) -> float:
        return self.viscous_damping_motor_n_s_per_m + self.viscous_damping_actuator_n_s_per_m

    @property
    def force_per_amp_n_per_a(self) -> float:
        """F_drive / i = N K_t / r."""
        return self.gear_ratio * self.torque_constant_nm_per_a / self.pulley_radius_m

    @property
    def back_emf_v_per_m_s(self) -> float:
        """Back-EMF per carriage speed, K_e N / r."""
        return self.back_emf_constant_v_s_per_rad * self.gear_ratio / self.pulley_radius_m


@dataclass(frozen=True)
class ForceChainParams:
    stationary_side_mass_kg: float = MASS_KG  # thesis: both cells with their fixtures weigh 1.152 kg
    moving_side_mass_kg: float = MASS_KG
    load_cell_stiffness_n_per_m: float = 7.0e8
    load_cell_damping_ratio: float = 0.02
    lanyard_stiffness_n_per_m: float = 8.0e5
    lanyard_damping_ratio: float = 0.05

    @property
    def m1(self) -> float:
        return self.stationary_side_mass_kg

    @property
    def m2(self) -> float:
        return self.moving_side_mass_kg

    @property
    def c1(self) -> float:
        return 2.0 * self.load_cell_damping_ratio * math.sqrt(self.load_cell_stiffness_n_per_m * self.m1)

    @property
    def c2(self) -> float:
        return 2.0 * self.load_cell_damping_ratio * math.sqrt(self.load_cell_stiffness_n_per_m * self.m2)

    def lanyard_damping(self, stiffness_n_per_m: float | None = None) -> float:
        """c_L = 2 zeta_L sqrt(K_L m1 m2 / (m1 + m2)) for the given (or nominal) lanyard stiffness."""
        k = self.lanyard_stiffness_n_per_m if stiffness_n_per_m is None else stiffness_n_per_m
        mu = self.m1 * self.m2 / (self.m1 + self.m2)
        return 2.0 * self.lanyard_damping_ratio * math.sqrt(k * mu)


@dataclass(frozen=True)
class SensorParams:
    load_cell_sensitivity_mv_per_lbf: float = 5.0
    load_cell_range_lbf: float = 1000.0
    accelerometer_sensitivity_mv_per_g: float = 10.0
    accelerometer_band_hz: tuple = (1.0, 4000.0)
    encoder_resolution_m: float = 1.0e-7


@dataclass(frozen=True)
class TestSet:
    __test__ = False  # not a pytest class

    set: int
    coupon_lbf: float
    velocity_fps: float
    decel_g: float
    pulls: int
    measured_stationary_avg_lbf: float
    measured_a2_max_g: float

    @property
    def coupon_n(self) -> float:
        return self.coupon_lbf * LBF_N

    @property
    def velocity_m_s(self) -> float:
        return self.velocity_fps * FT_M

    @property
    def decel_m_s2(self) -> float:
        """Carriage acceleration while the lanyard is loaded (negative: deceleration)."""
        return self.decel_g * G_M_S2

    @property
    def measured_stationary_avg_n(self) -> float:
        return self.measured_stationary_avg_lbf * LBF_N


NOMINAL_TEST_SETS = (
    TestSet(1, 200.0, 3.0, 0.0, 20, 212.10, 27.9),
    TestSet(2, 400.0, 11.0, 0.0, 20, 584.08, 114.0),
    TestSet(3, 600.0, 15.0, 0.0, 20, 688.82, 330.0),
    TestSet(4, 400.0, 7.8, -1.24, 20, 588.92, 199.0),
    TestSet(5, 600.0, 7.8, -1.24, 20, 792.87, 225.0),
)


@dataclass(frozen=True)
class RigParams:
    daq: DaqParams = field(default_factory=DaqParams)
    drive: DriveParams = field(default_factory=DriveParams)
    force_chain: ForceChainParams = field(default_factory=ForceChainParams)
    sensors: SensorParams = field(default_factory=SensorParams)
    test_sets: tuple = NOMINAL_TEST_SETS
    departures: Departures = NO_DEPARTURES   # empty = the nominal rig (str() gives 'none')
    tolerances: Tolerances = field(default_factory=Tolerances)   # practical significance (core/tolerances.py)
    extra_terms: tuple = ()          # terms beyond the catalog (core/extra_terms.py: ExtraTerm), from extra_terms:
    uncertainty_stated: tuple = ()   # the YAML's uncertainty: entries that are not the default, ((section.key, u), ...)

    @property
    def uncertainty(self) -> Uncertainties:
        """The standard uncertainty (k = 1) of every constant: as stated, else the default fraction of it."""
        return uncertainties(self, self.uncertainty_stated)

    def test_set(self, n: int) -> TestSet:
        for ts in self.test_sets:
            if ts.set == n:
                return ts
        known = ', '.join(str(ts.set) for ts in self.test_sets)
        raise SimError(f'test set {n!r} is unknown; expected one of {known}')


def check_keys(cls, data: Any, where: str) -> list:
    """data must be a mapping whose keys are fields of the dataclass cls; returns the names."""
    if not isinstance(data, Mapping):
        raise SimError(f'{where} is {data!r}; expected a mapping of {cls.__name__} fields')
    names = [f.name for f in fields(cls)]
    unknown = sorted(set(data) - set(names))
    if unknown:
        raise SimError(f'{where} has unknown key(s) {unknown}; expected only {names}')
    return names


def _build(cls, data: Any, where: str):
    names = check_keys(cls, data, where)
    kwargs = {}
    for f in fields(cls):
        if f.name not in data:
            continue
        v = data[f.name]
        if isinstance(v, list):
            v = tuple(float(e) for e in v)
        elif isinstance(v, bool) or not isinstance(v, (int, float)):
            raise SimError(f'{where}.{f.name} is {v!r}; expected a number')
        elif f.name in ('set', 'pulls'):
            if int(v) != v:
                raise SimError(f'{where}.{f.name} is {v!r}; expected an integer')
            v = int(v)
        else:
            v = float(v)
            if not math.isfinite(v):
                raise SimError(f'{where}.{f.name} is {v!r}; expected a finite number')
        kwargs[f.name] = v
    try:
        return cls(**kwargs)
    except TypeError as exc:
        raise SimError(f'{where} is incomplete ({exc}); expected all of {names}') from None


def rig_from_dict(data: Mapping) -> RigParams:
    """RigParams from a parsed YAML mapping; missing sections/keys keep their nominal defaults."""
    if not isinstance(data, Mapping):
        raise SimError(f'rig description is {type(data).__name__}; expected a mapping')
    sections = {'daq': DaqParams, 'drive': DriveParams, 'force_chain': ForceChainParams,
                'sensors': SensorParams}
    others = ['departures', 'extra_terms', 'test_sets', 'tolerances', 'uncertainty']
    unknown = sorted(set(data) - set(sections) - set(others))
    if unknown:
        raise SimError(f'rig description has unknown section(s) {unknown}; expected only {sorted(sections) + others}')
    kwargs = {name: _build(cls, data[name], name) for name, cls in sections.items() if name in data}
    if 'test_sets' in data:
        raw = data['test_sets']
        if not isinstance(raw, list) or not raw:
            raise SimError(f'test_sets is {raw!r}; expected a non-empty list of test sets')
        sets = tuple(_build(TestSet, item, f'test_sets[{i}]') for i, item in enumerate(raw))
        numbers = [s.set for s in sets]
        if len(set(numbers)) != len(numbers):
            raise SimError(f'test set numbers {numbers} repeat; expected unique numbers')
        kwargs['test_sets'] = sets
    if 'departures' in data:
        kwargs['departures'] = departures_from_data(data['departures'])
    if 'tolerances' in data:
        kwargs['tolerances'] = tolerances_from_data(data['tolerances'])
    if 'extra_terms' in data:
        kwargs['extra_terms'] = extra_terms_from_data(data['extra_terms'])
    rig = RigParams(**kwargs)
    if 'uncertainty' in data:   # kept only where it is not the default fraction, so equal rigs compare equal
        default = dict(rig.uncertainty)
        stated = tuple((k, u) for k, u in overrides_from_data(data['uncertainty'])
                       if k not in default or not math.isclose(u, default[k], rel_tol=1e-9, abs_tol=0.0))
        rig = dataclasses.replace(rig, uncertainty_stated=stated)
    validate_rig(rig)
    return rig


def validate_rig(rig: RigParams) -> None:
    positive = [
        ('daq.sample_rate_hz', rig.daq.sample_rate_hz), ('daq.record_length_s', rig.daq.record_length_s),
        ('force_chain.stationary_side_mass_kg', rig.force_chain.m1),
        ('force_chain.moving_side_mass_kg', rig.force_chain.m2),
        ('force_chain.load_cell_stiffness_n_per_m', rig.force_chain.load_cell_stiffness_n_per_m),
        ('force_chain.lanyard_stiffness_n_per_m', rig.force_chain.lanyard_stiffness_n_per_m),
        ('drive.pulley_radius_m', rig.drive.pulley_radius_m), ('drive.gear_ratio', rig.drive.gear_ratio),
        ('drive.torque_constant_nm_per_a', rig.drive.torque_constant_nm_per_a),
        ('drive.usable_track_m', rig.drive.usable_track_m),
        ('sensors.encoder_resolution_m', rig.sensors.encoder_resolution_m),
    ]
    for name, v in positive:
        if not v > 0:
            raise SimError(f'{name} is {v!r}; expected a positive number')
    for name, v in [('force_chain.load_cell_damping_ratio', rig.force_chain.load_cell_damping_ratio),
                    ('force_chain.lanyard_damping_ratio', rig.force_chain.lanyard_damping_ratio)]:
        if not 0 <= v < 1:
            raise SimError(f'{name} is {v!r}; expected a damping ratio in [0, 1)')
    uncertainties(rig, rig.uncertainty_stated)   # refuses a stated uncertainty above its constant


def load_rig(path: str | Path | None = None) -> RigParams:
    """Load a rig description; ``None`` loads the packaged nominal.yaml."""
    p = NOMINAL_YAML if path is None else Path(path)
    try:
        text = p.read_text()
    except OSError as exc:
        raise SimError(f'rig file {str(p)!r} cannot be read ({exc.strerror}); expected a readable YAML file') from None
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise SimError(f'rig file {str(p)!r} is not valid YAML ({exc}); expected a YAML mapping') from None
    return rig_from_dict(data)
