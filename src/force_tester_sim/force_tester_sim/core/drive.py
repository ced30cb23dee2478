"""Drive model of thesis section 4.2 (eqs 2-16), reflected to the carriage, ROS-free.

    m_c x3'' = F_drive - (b_m + b_g) v3 - F_load,   m_c = (J_z + N^2 J_m) / r^2,  F_drive = N K_t i / r
    L_a di/dt = V - R_a i - K_e N v3 / r

States x = [x3 (m), v3 (m/s), i (A), z (integral of the velocity error, m)].

Controller (DriveControl): PID on the velocity error e = v_cmd - v3, commanding the armature
voltage: V_pid = Kp e + Ki z - Kd a3 (derivative on the measured acceleration, no kick on a step).

Current limit (a choice; the thesis does not say how its 66.46 A limit acts): the servo amplifier
is modelled as having a fast inner current limiter. The voltage it applies is never more than
    V_hi = R_a I_max + e_b + L_a w_c (I_max - i)        (e_b = K_e N v3 / r, the back-EMF)
nor less than the mirror image V_lo (for -I_max). At V = V_hi the circuit obeys
L_a di/dt = (R_a + L_a w_c)(I_max - i), so i approaches I_max from below with time constant
1/(R_a/L_a + w_c) and never crosses it. The supply limit +/- V_max is applied last (a hard
limit: the bus cannot exceed it, whatever the current limiter asks for).

Anti-windup: conditional integration (clamping): z' = e, except that z' = 0 while the voltage
or current limiter clips the PID output and the error would push it further into the clip
(faded in linearly over the first 5 V of clipping, so the right-hand side stays continuous).
(Back-calculation was tried first: with it the integrator bleeds the PID output below the
current-limit voltage during the fast acceleration, so the current falls off before the supply
voltage is reached; clamping lets the amplifier use the full V_max I_max as a real drive does.)

Power: the thesis's motor constants are per three-phase conventions (K_t / K_e = 1.732 = sqrt 3:
K_e in V_rms line-to-line per rad/s, K_t in N m per A_rms). In the lumped DC circuit the power the
motor converts is therefore (K_t / K_e) e_b i, not e_b i. ``power_w`` is V * i (the quantity the
thesis quotes: V_max I_max = 21.6 kW); ``input_power_w`` = (K_t/K_e) V i is the electrical input
that balances the mechanical and loss powers exactly; ``mech_power_w`` = F_drive v3.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, fields, replace
from typing import Callable, Mapping

import numpy as np
from scipy.integrate import solve_ivp

from .errors import SimError
from .params import DriveParams, RigParams, check_keys


@dataclass(frozen=True)
class DriveControl:
    """PID velocity controller and amplifier settings (voltage commanded, SI units)."""
    kp_v_per_m_s: float = 400.0          # proportional gain, V per (m/s) of velocity error
    ki_v_per_m: float = 8000.0           # integral gain, V per m of integrated error
    kd_v_s2_per_m: float = 0.0           # derivative gain on measured acceleration, V per (m/s^2)
    current_loop_rad_s: float = 2000.0   # bandwidth of the amplifier's current limiter, rad/s
    antiwindup_band_v: float = 5.0       # clip depth over which integration is faded out, V

    def __post_init__(self):
        for f in fields(self):
            v = getattr(self, f.name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise SimError(f'DriveControl.{f.name} is {v!r}; expected a finite number')
        for name in ('kp_v_per_m_s', 'ki_v_per_m', 'kd_v_s2_per_m'):
            if getattr(self, name) < 0:
                raise SimError(f'DriveControl.{name} is {getattr(self, name)!r}; expected >= 0')
        for name in ('current_loop_rad_s', 'antiwindup_band_v'):
            if not getattr(self, name) > 0:
                raise SimError(f'DriveControl.{name} is {getattr(self, name)!r}; expected > 0')


@dataclass(frozen=True)
class DriveSetup:
    """Everything drive_rhs needs: the drive parameters, the controller and derived constants."""
    drive: DriveParams
    control: DriveControl

    @property
    def mass_kg(self) -> float:
        return self.drive.reflected_mass_kg

    @property
    def k_force(self) -> float:
        return self.drive.force_per_amp_n_per_a

    @property
    def k_emf(self) -> float:
        return self.drive.back_emf_v_per_m_s

    @property
    def damping(self) -> float:
        return self.drive.viscous_damping_n_s_per_m

    @property
    def power_factor(self) -> float:
        """K_t / K_e: converted power per (back-EMF x current) of the lumped circuit."""
        return self.drive.torque_constant_nm_per_a / self.drive.back_emf_constant_v_s_per_rad


def validate_drive(d: DriveParams) -> None:
    for name in ('armature_resistance_ohm', 'armature_inductance_h', 'torque_constant_nm_per_a',
                 'back_emf_constant_v_s_per_rad', 'gear_ratio', 'pulley_radius_m',
                 'current_limit_a', 'voltage_limit_v'):
        v = getattr(d, name)
        if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
            raise SimError(f'drive.{name} is {v!r}; expected a positive finite number')
    for name in ('motor_inertia_kg_m2', 'actuator_inertia_kg_m2', 'carriage_mass_kg',
                 'viscous_damping_motor_n_s_per_m', 'viscous_damping_actuator_n_s_per_m'):
        v = getattr(d, name)
        if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
            raise SimError(f'drive.{name} is {v!r}; expected a non-negative finite number')
    if not d.reflected_mass_kg > 0:
        raise SimError(f'drive reflected mass is {d.reflected_mass_kg!r} kg; expected > 0')


def apply_overrides(drive: DriveParams, overrides: Mapping | None) -> DriveParams:
    """A copy of ``drive`` with some fields replaced (e.g. damping 0, voltage limit raised)."""
    if not overrides:
        return drive
    check_keys(DriveParams, overrides, 'overrides')
    clean = {}
    for k, v in overrides.items():
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise SimError(f'overrides[{k!r}] is {v!r}; expected a finite number')
        clean[k] = float(v)
    return replace(drive, **clean)


def drive_voltage(x, u, setup: DriveSetup):
    """(V applied, V_pid unsaturated, acceleration) for state x and inputs u = (v_cmd, F_load)."""
    d, c = setup.drive, setup.control
    _, v, i, z = x
    v_cmd, f_load = u
    acc = (setup.k_force * i - setup.damping * v - f_load) / setup.mass_kg
    e = v_cmd - v
    v_pid = c.kp_v_per_m_s * e + c.ki_v_per_m * z - c.kd_v_s2_per_m * acc
    e_b = setup.k_emf * v
    r, lw, imax = d.armature_resistance_ohm, d.armature_inductance_h * c.current_loop_rad_s, d.current_limit_a
    v_hi = r * imax + e_b + lw * (imax - i)
    v_lo = -r * imax + e_b + lw * (-imax - i)
    volt = min(max(v_pid, v_lo), v_hi)
    vmax = d.voltage_limit_v
    volt = min(max(volt, -vmax), vmax)
    return volt, v_pid, acc


def drive_rhs(t, x, u, params: DriveSetup):
    """dx/dt for x = [x3, v3, i, z]; u = (v_cmd m/s, F_load N) at time t; params a DriveSetup."""
    d, c = params.drive, params.control
    volt, v_pid, acc = drive_voltage(x, u, params)
    v, i = x[1], x[2]
    di = (volt - d.armature_resistance_ohm * i - params.k_emf * v) / d.armature_inductance_h
    dz = u[0] - v
    clip = volt - v_pid
    if dz * clip < 0:
        # clamped: integrating would only push the output further into the limit. The clamp is
        # faded in over antiwindup_band_v (continuous, so the solver sees no chattering switch)
        dz *= max(0.0, 1.0 - abs(clip) / c.antiwindup_band_v)
    return np.array([v, acc, di, dz])


def _as_command(cmd) -> Callable[[float], float]:
    if callable(cmd):
        return cmd
    if isinstance(cmd, bool) or not isinstance(cmd, (int, float)) or not math.isfinite(cmd):
        raise SimError(f'command_velocity_m_s is {cmd!r}; expected a finite number (m/s) or a callable t -> m/s')
    value = float(cmd)
    return lambda t: value


def simulate_drive(rig: RigParams, command_velocity_m_s, duration_s: float, load=None,
                   control: DriveControl = DriveControl(), overrides: Mapping | None = None,
                   max_step_s: float = 5e-5, sample_dt_s: float = 1e-4, method: str = 'LSODA',
                   rtol: float = 1e-8) -> dict:
    """Integrate the drive from rest. ``command_velocity_m_s``: a number (a step at t = 0) or a
    callable t -> m/s. ``load``: None (no load) or a callable (t, x3, v3) -> N (tension, opposing
    the pull). Returns arrays sampled every ``sample_dt_s``: time_s, position_m, velocity_m_s,
    current_a, voltage_v, power_w (= V i), input_power_w, mech_power_w, acceleration_m_s2,
    command_m_s, load_n, integrator."""
    if not isinstance(rig, RigParams):
        raise SimError(f'rig is {type(rig).__name__}; expected RigParams (force_tester_sim.core.load_rig())')
    if not isinstance(control, DriveControl):
        raise SimError(f'control is {type(control).__name__}; expected DriveControl')
    for name, v in (('duration_s', duration_s), ('max_step_s', max_step_s), ('sample_dt_s', sample_dt_s)):
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or not v > 0:
            raise SimError(f'{name} is {v!r}; expected a positive number of seconds')
    if load is not None and not callable(load):
        raise SimError(f'load is {load!r}; expected None or a callable (t, x3, v3) -> N')
    drive = apply_overrides(rig.drive, overrides)
    validate_drive(drive)
    setup = DriveSetup(drive, control)
    cmd = _as_command(command_velocity_m_s)
    f_load = (lambda t, x3, v3: 0.0) if load is None else load

    def inputs(t, x):
        return float(cmd(t)), float(f_load(t, x[0], x[1]))

    def fun(t, x):
        return drive_rhs(t, x, inputs(t, x), setup)

    n = int(round(duration_s / sample_dt_s))
    t_eval = np.linspace(0.0, n * sample_dt_s, n + 1)
    atol = np.array([1e-10, 1e-9, 1e-7, 1e-11])
    sol = solve_ivp(fun, (0.0, t_eval[-1]), np.zeros(4), method=method, t_eval=t_eval,
                    max_step=max_step_s, rtol=rtol, atol=atol)
    if not sol.success:
        raise SimError(f'drive integration failed ({sol.message}); expected solve_ivp to succeed')
    xs = sol.y.T
    volt = np.empty(len(sol.t))
    acc = np.empty(len(sol.t))
    com = np.empty(len(sol.t))
    fl = np.empty(len(sol.t))
    for k, (t, x) in enumerate(zip(sol.t, xs)):
        u = inputs(t, x)
        com[k], fl[k] = u
        volt[k], _, acc[k] = drive_voltage(x, u, setup)
    i = xs[:, 2]
    return {
        'time_s': sol.t, 'position_m': xs[:, 0], 'velocity_m_s': xs[:, 1], 'current_a': i,
        'voltage_v': volt, 'power_w': volt * i, 'input_power_w': setup.power_factor * volt * i,
        'mech_power_w': setup.k_force * i * xs[:, 1], 'acceleration_m_s2': acc,
        'command_m_s': com, 'load_n': fl, 'integrator': xs[:, 3],
        'drive': drive, 'control': control,
    }


def back_emf_limit_m_s(drive: DriveParams) -> float:
    """No-load top speed with zero damping: V_max r / (K_e N)."""
    return drive.voltage_limit_v / drive.back_emf_v_per_m_s


def steady_state_speed_m_s(drive: DriveParams) -> float:
    """No-load steady speed at V_max with damping: V = R i + k_e v, k_f i = b v."""
    return drive.voltage_limit_v / (drive.back_emf_v_per_m_s + drive.armature_resistance_ohm
                                     * drive.viscous_damping_n_s_per_m / drive.force_per_amp_n_per_a)
