"""One pull: specification with pull-to-pull scatter, simulation, DAQ channels."""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Dict, List, Optional

import numpy as np

from force_tester_common.core.clock import record_stamps_ns

from .chain import ChainParams, force_move, force_stat, tension
from .departures import apply_sensor_departures
from .errors import SimError
from .extra_terms import extra_channels, signals
from .motion import MotionSource, PrescribedMotion, hold_time_s, nominal_slack_m
from .params import RigParams

CHANNELS = ('time_s', 'encoder_position_m', 'accel_axial_m_s2', 'accel_lateral_m_s2', 'accel_vertical_m_s2',
            'force_moving_n', 'force_stationary_n', 'motor_velocity_cmd_m_s', 'motor_current_a',
            'motor_voltage_v')

# Pull-to-pull scatter (1 sigma unless stated; normal draws are clipped at 3 sigma).
COUPON_SCATTER_REL = 0.03            # coupon break force
SPEED_SCATTER_REL = 0.01             # speed at the pull
DECEL_SCATTER_REL = 0.05             # deceleration at the pull (sets 4, 5)
SLACK_SCATTER_M = 0.002              # lanyard slack
LANYARD_STIFFNESS_SCATTER_REL = 0.05
BREAK_DURATION_RANGE_S = (0.2e-3, 1.0e-3)   # uniform

# Sensor noise (white, Gaussian, rms).
LOAD_CELL_NOISE_N = 0.3
ACCEL_NOISE_M_S2 = 0.5


@dataclass(frozen=True)
class PullSpec:
    test_set: int
    coupon_break_n: float
    velocity_m_s: float
    decel_m_s2: float
    slack_m: float
    lanyard_stiffness_n_per_m: float
    break_duration_s: float
    seed: int
    pull: int = 0
    command_velocity_m_s: Optional[float] = None   # the set's commanded speed (None: = velocity_m_s)
    # optional coupon plasticity (per pull): the coupon flows at coupon_yield_n with hardening stiffness
    # coupon_hardening_n_per_m in series with the lanyard (None: elastic to the break, the model of record)
    coupon_yield_n: Optional[float] = None
    coupon_hardening_n_per_m: Optional[float] = None

    def __post_init__(self):
        for name in ('coupon_break_n', 'velocity_m_s', 'slack_m', 'lanyard_stiffness_n_per_m', 'break_duration_s'):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise SimError(f'{name} is {v!r}; expected a finite positive number')
        if not (math.isfinite(self.decel_m_s2) and self.decel_m_s2 <= 0):
            raise SimError(f'decel_m_s2 is {self.decel_m_s2!r}; expected a finite number <= 0')
        if not (isinstance(self.seed, (int, np.integer)) and self.seed >= 0):
            raise SimError(f'seed is {self.seed!r}; expected an integer >= 0')


def clipped_normal(rng, sigma):
    return float(np.clip(rng.standard_normal(), -3.0, 3.0) * sigma)


def make_pull_specs(rig: RigParams, test_set: int, n: int, seed: int) -> List[PullSpec]:
    """``n`` pulls of ``test_set`` with seeded pull-to-pull scatter (same seed, same pulls)."""
    ts = rig.test_set(test_set)
    if not (isinstance(n, (int, np.integer)) and n >= 1):
        raise SimError(f'number of pulls {n!r} is invalid; expected an integer >= 1')
    if not (isinstance(seed, (int, np.integer)) and seed >= 0):
        raise SimError(f'seed {seed!r} is invalid; expected an integer >= 0')
    ss = np.random.SeedSequence([int(seed), int(test_set)])
    fc = rig.force_chain
    k_ser = 1.0 / (1.0 / fc.lanyard_stiffness_n_per_m + 2.0 / fc.load_cell_stiffness_n_per_m)
    hold = hold_time_s(ts.coupon_n * 1.1, ts.velocity_m_s * 0.97, k_ser * 0.85, BREAK_DURATION_RANGE_S[1])
    slack0 = nominal_slack_m(ts.velocity_m_s * 1.03, ts.decel_m_s2, hold, rig.drive.usable_track_m)
    specs = []
    for i, child in enumerate(ss.spawn(n)):
        rng = np.random.default_rng(child)
        specs.append(PullSpec(
            test_set=ts.set,
            coupon_break_n=ts.coupon_n * (1.0 + clipped_normal(rng, COUPON_SCATTER_REL)),
            velocity_m_s=ts.velocity_m_s * (1.0 + clipped_normal(rng, SPEED_SCATTER_REL)),
            decel_m_s2=ts.decel_m_s2 * (1.0 + clipped_normal(rng, DECEL_SCATTER_REL)),
            slack_m=slack0 + clipped_normal(rng, SLACK_SCATTER_M),
            lanyard_stiffness_n_per_m=fc.lanyard_stiffness_n_per_m
            * (1.0 + clipped_normal(rng, LANYARD_STIFFNESS_SCATTER_REL)),
            break_duration_s=float(rng.uniform(*BREAK_DURATION_RANGE_S)),
            seed=int(child.generate_state(1)[0]),
            pull=i,
            command_velocity_m_s=ts.velocity_m_s,
        ))
    return specs


def nominal_pull_spec(rig: RigParams, test_set: int, seed: int = 0) -> PullSpec:
    """The set's pull without scatter (coupon at its rating, commanded speed, nominal lanyard)."""
    ts = rig.test_set(test_set)
    fc = rig.force_chain
    k_ser = 1.0 / (1.0 / fc.lanyard_stiffness_n_per_m + 2.0 / fc.load_cell_stiffness_n_per_m)
    hold = hold_time_s(ts.coupon_n, ts.velocity_m_s, k_ser, 0.5e-3)
    return PullSpec(ts.set, ts.coupon_n, ts.velocity_m_s, ts.decel_m_s2,
                    nominal_slack_m(ts.velocity_m_s, ts.decel_m_s2, hold, rig.drive.usable_track_m),
                    fc.lanyard_stiffness_n_per_m, 0.5e-3, seed, 0, ts.velocity_m_s)


def chain_params(rig: RigParams, spec: PullSpec) -> ChainParams:
    if spec.coupon_yield_n is None:
        return ChainParams.from_rig(rig, slack_m=spec.slack_m, break_n=spec.coupon_break_n,
                                    break_duration_s=spec.break_duration_s,
                                    lanyard_stiffness_n_per_m=spec.lanyard_stiffness_n_per_m)
    return ChainParams.from_rig(rig, slack_m=spec.slack_m, break_n=spec.coupon_break_n,
                                break_duration_s=spec.break_duration_s,
                                lanyard_stiffness_n_per_m=spec.lanyard_stiffness_n_per_m,
                                yield_n=spec.coupon_yield_n, hardening_n_per_m=spec.coupon_hardening_n_per_m)


def motion_for(rig: RigParams, spec: PullSpec) -> PrescribedMotion:
    p = chain_params(rig, spec)
    k_load = p.series_stiffness
    if p.yields and p.yield_n < spec.coupon_break_n:   # elastic to the yield, then the (softer) flow piece
        k_load = spec.coupon_break_n / (p.yield_n / k_load
                                        + (spec.coupon_break_n - p.yield_n) / p.flow_params().series_stiffness)
    hold = hold_time_s(spec.coupon_break_n, spec.velocity_m_s, k_load, spec.break_duration_s)
    m = PrescribedMotion.build(spec.velocity_m_s, spec.slack_m, spec.decel_m_s2, hold,
                               command_velocity_m_s=spec.command_velocity_m_s)
    m.check_fits(rig.drive.usable_track_m, rig.daq.record_length_s)
    return m


def sample_times_s(rig: RigParams) -> np.ndarray:
    return np.arange(rig.daq.n_samples) / rig.daq.sample_rate_hz


def sample_stamps_ns(rig: RigParams, start_ns: int) -> np.ndarray:
    """Absolute stamps (int64 ns) of a record starting at ``start_ns`` (exact for integer rates)."""
    if not isinstance(start_ns, (int, np.integer)):
        raise SimError(f'start_ns is {start_ns!r}; expected an integer number of nanoseconds')
    return record_stamps_ns(start_ns, rig.daq.n_samples, rig.daq.sample_rate_hz)


@dataclass
class PullResult:
    channels: Dict[str, np.ndarray]          # the DAQ export columns (CHANNELS)
    spec: PullSpec
    motion: MotionSource                     # PrescribedMotion unless run_pull_with_motion
    taut_index: Optional[int]                # first sample with lanyard tension > 0
    break_index: Optional[int]               # first sample at/after the break start
    break_end_index: Optional[int]           # first sample with beta == 0
    taut_time_s: Optional[float]
    break_time_s: Optional[float]
    truth: Dict[str, np.ndarray] = field(default_factory=dict)   # clean internal signals (SI)

    @property
    def start_index(self) -> int:
        return 0

    @property
    def end_index(self) -> int:
        """Exclusive; a pull is the whole record."""
        return len(self.channels['time_s'])


def record_channels(rig: RigParams, spec: PullSpec, t, x3, fm, fs, a2, noise: bool, motor,
                    extra: Optional[Dict[str, np.ndarray]] = None) -> Dict[str, np.ndarray]:
    """What the DAQ records of a simulated pull: the encoder quantised, the sensor departures of the rig
    applied to the moving cell and the accelerometer, seeded sensor noise. ``motor`` is
    (commanded velocity, current, voltage); ``extra``: what the rig's extra_terms add to the force and
    accelerometer channels (extra_terms.extra_channels)."""
    deps = rig.departures
    res = rig.sensors.encoder_resolution_m
    n = len(t)
    if noise:
        rng = np.random.default_rng(int(spec.seed))
        nz = {k: rng.standard_normal(n) for k in ('ax', 'lat', 'vert', 'fm', 'fs')}
    else:
        nz = {k: np.zeros(n) for k in ('ax', 'lat', 'vert', 'fm', 'fs')}
    fm_rec, a2_rec = (apply_sensor_departures(deps, t, fm, a2, spec.seed) if deps else (fm, a2))
    v_cmd, current, voltage = motor
    extra = extra or {}
    fm_rec = fm_rec + extra.get('force_moving', 0.0)
    a2_rec = a2_rec + extra.get('accel_axial', 0.0)
    fs = fs + extra.get('force_stationary', 0.0)
    return {
        'time_s': t,
        'encoder_position_m': np.round(x3 / res) * res,
        'accel_axial_m_s2': a2_rec + ACCEL_NOISE_M_S2 * nz['ax'],
        'accel_lateral_m_s2': ACCEL_NOISE_M_S2 * nz['lat'],
        'accel_vertical_m_s2': ACCEL_NOISE_M_S2 * nz['vert'],
        'force_moving_n': fm_rec + LOAD_CELL_NOISE_N * nz['fm'],
        'force_stationary_n': fs + LOAD_CELL_NOISE_N * nz['fs'],
        'motor_velocity_cmd_m_s': v_cmd,
        'motor_current_a': current,
        'motor_voltage_v': voltage,
    }


def events_and_truth(t, traj, p, kin, T, fm, fs):
    """(taut index, break index, break end index, truth dict) of an integrated pull."""
    x3, v3, a3 = kin
    X = traj.x
    taut_idx = np.flatnonzero(T > 0)
    taut_index = int(taut_idx[0]) if len(taut_idx) else None
    if traj.break_s is not None:
        break_index = int(np.searchsorted(t, traj.break_s, side='left'))
        zero = np.flatnonzero(traj.beta <= 0.0)
        break_end_index = int(zero[0]) if len(zero) else None
    else:
        break_index = break_end_index = None
    truth = {'x3_m': x3, 'v3_m_s': v3, 'a3_m_s2': a3, 'u2_m': x3 + X[:, 0], 'v2_m_s': v3 + X[:, 1],
             'u1_m': X[:, 2], 'v1_m_s': X[:, 3], 'a1_m_s2': (T - fs) / p.m1, 'a2_m_s2': (fm - T) / p.m2,
             'tension_n': T, 'beta': traj.beta, 'force_moving_n': fm, 'force_stationary_n': fs}
    if p.has_mount:
        truth['ub_m'] = x3 + X[:, 4]
        truth['vb_m_s'] = v3 + X[:, 5]
    return taut_index, break_index, break_end_index, truth


def run_pull(rig: RigParams, spec: PullSpec, noise: bool = True) -> PullResult:
    return run_pull_with_motion(rig, spec, motion_for(rig, spec), noise)


def run_pull_with_motion(rig: RigParams, spec: PullSpec, motion: MotionSource, noise: bool = True,
                         t: Optional[np.ndarray] = None) -> PullResult:
    """``run_pull`` driven by a given carriage motion (e.g. a SampledMotion of a measured record) on the sample
    times ``t`` (default: the rig's record). The spec supplies the per-pull chain quantities (slack, lanyard
    stiffness, coupon break force/duration, optional yield); its speed and deceleration are not used."""
    p = chain_params(rig, spec)
    t = sample_times_s(rig) if t is None else np.asarray(t, dtype=float)
    x3, v3, a3 = kin = motion.kinematics(t)
    # scipy: loaded where a pull is simulated, not where one is planned (the sim node plans, its worker simulates)
    from .integrate import integrate_chain
    traj = integrate_chain(p, motion, t, kinematics=kin)
    X = traj.x
    U = np.column_stack([x3, v3, a3, traj.beta])
    T = tension(X, U, p)
    if traj.yield_s is not None:   # flowing coupon: the flow piece's tension from the yield on
        flowing = t >= traj.yield_s
        T[flowing] = tension(X[flowing], U[flowing], p.flow_params())
    fm = force_move(X, p)
    fs = force_stat(X, p)
    a2 = (fm - T) / p.m2

    d = rig.drive
    deps = rig.departures
    cf = deps.get('coulomb_friction') if deps else None
    if cf is None:
        current = (d.reflected_mass_kg * a3 + d.viscous_damping_n_s_per_m * v3 + fm) / d.force_per_amp_n_per_a
    else:   # dry friction F_c sign(v3) in the drive's force balance
        current = (d.reflected_mass_kg * a3 + d.viscous_damping_n_s_per_m * v3 + fm
                   + cf['force_n'] * np.sign(v3)) / d.force_per_amp_n_per_a
    extra = None
    if rig.extra_terms:   # terms beyond the catalog: the current's enters the drive's balance (the voltage follows)
        extra = extra_channels(rig.extra_terms, signals(t, fm, fs, T, a2, v3, x3), spec.seed)
        current = current + extra.get('motor_current', 0.0)
    di = np.gradient(current, t)
    voltage = np.clip(d.armature_resistance_ohm * current + d.armature_inductance_h * di
                      + d.back_emf_v_per_m_s * v3, -d.voltage_limit_v, d.voltage_limit_v)

    channels = record_channels(rig, spec, t, x3, fm, fs, a2, noise,
                               motor=(v3 * motion.command_scale, current, voltage), extra=extra)
    taut_index, break_index, break_end_index, truth = events_and_truth(t, traj, p, (x3, v3, a3), T, fm, fs)
    return PullResult(channels, spec, motion, taut_index, break_index, break_end_index, traj.taut_s,
                      traj.break_s, truth)
