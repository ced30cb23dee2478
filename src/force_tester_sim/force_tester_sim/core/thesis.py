"""The thesis's top-speed study (section 4.2.6) rerun on the drive model of record, ROS-free.

Command: a 30 fps velocity step from rest, no load, unlimited track (as the thesis: "the break
force was set to zero and the track length parameter was extended").
"""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from force_tester_common.core.units import FT_M

from .drive import DriveControl, back_emf_limit_m_s, simulate_drive, steady_state_speed_m_s
from .errors import SimError
from .params import RigParams

COMMAND_FPS = 30.0
DURATION_S = 0.5
PLATEAU_WINDOW_S = 0.1      # plateau = mean velocity over the last 0.1 s of the run
PLATEAU_BAND = 0.02         # "reached the plateau" = within 2 % of it

THESIS = {'peak_fps': 28.0, 'plateau_fps': 25.0, 'current_limit_a': 66.0, 'peak_power_kw': 21.0,
          'distance_to_plateau_ft': 2.5, 'plateau_cause': 'damping'}


def _plateau_m_s(run: dict) -> float:
    t, v = run['time_s'], run['velocity_m_s']
    return float(np.mean(v[t >= t[-1] - PLATEAU_WINDOW_S]))


def _summary(run: dict, current_limit_a: float) -> dict:
    t, v, x = run['time_s'], run['velocity_m_s'], run['position_m']
    plateau = _plateau_m_s(run)
    first = int(np.argmax(v >= (1.0 - PLATEAU_BAND) * plateau))
    outside = np.nonzero(np.abs(v - plateau) > PLATEAU_BAND * plateau)[0]
    settle = int(min(outside[-1] + 1, len(v) - 1)) if len(outside) else 0
    return {
        'peak_fps': float(v.max()) / FT_M,
        'peak_time_s': float(t[int(np.argmax(v))]),
        'plateau_fps': plateau / FT_M,
        'peak_current_a': float(np.max(np.abs(run['current_a']))),
        'current_limit_hit': bool(np.max(np.abs(run['current_a'])) >= 0.99 * current_limit_a),
        'peak_power_kw': float(np.max(run['power_w'])) / 1e3,
        'peak_input_power_kw': float(np.max(run['input_power_w'])) / 1e3,
        'peak_mech_power_kw': float(np.max(run['mech_power_w'])) / 1e3,
        'distance_to_plateau_ft': float(x[first]) / FT_M,
        'time_to_plateau_s': float(t[first]),
        'distance_to_settle_ft': float(x[settle]) / FT_M,
    }


def top_speed_study(rig: RigParams, control: DriveControl | None = None,
                    command_fps: float = COMMAND_FPS, duration_s: float = DURATION_S) -> dict:
    """Peak / plateau / current / power / distance at a 30 fps command, and the plateau's cause,
    decided by two reruns: viscous damping set to zero, and the voltage limit raised 20 %."""
    control = DriveControl() if control is None else control
    if not isinstance(rig, RigParams):
        raise SimError(f'rig is {type(rig).__name__}; expected RigParams')
    cmd = command_fps * FT_M
    run = simulate_drive(rig, cmd, duration_s, control=control)
    out = _summary(run, rig.drive.current_limit_a)
    no_damp = simulate_drive(rig, cmd, duration_s, control=control,
                             overrides={'viscous_damping_motor_n_s_per_m': 0.0,
                                        'viscous_damping_actuator_n_s_per_m': 0.0})
    hi_volt = simulate_drive(rig, cmd, duration_s, control=control,
                             overrides={'voltage_limit_v': 1.2 * rig.drive.voltage_limit_v})
    base = out['plateau_fps']
    out['plateau_no_damping_fps'] = _plateau_m_s(no_damp) / FT_M
    out['plateau_voltage_plus20_fps'] = _plateau_m_s(hi_volt) / FT_M
    shift_damp = abs(out['plateau_no_damping_fps'] - base) / base
    shift_volt = abs(out['plateau_voltage_plus20_fps'] - base) / base
    out['plateau_shift_no_damping'] = shift_damp
    out['plateau_shift_voltage_plus20'] = shift_volt
    out['plateau_cause'] = 'back_emf' if shift_volt > shift_damp else 'damping'
    out['back_emf_limit_fps'] = back_emf_limit_m_s(rig.drive) / FT_M
    out['steady_state_hand_fps'] = steady_state_speed_m_s(rig.drive) / FT_M
    out['command_fps'] = command_fps
    out['run'] = run
    return out


def _with_carriage_mass(rig: RigParams, mass_kg: float) -> RigParams:
    """J_z includes the carriage (m r^2, nominal 47 kg); only that part scales with the mass."""
    if not (isinstance(mass_kg, (int, float)) and np.isfinite(mass_kg) and mass_kg >= 0):
        raise SimError(f'carriage mass {mass_kg!r}; expected a non-negative number of kg')
    d = rig.drive
    j_z = d.actuator_inertia_kg_m2 + (mass_kg - d.carriage_mass_kg) * d.pulley_radius_m ** 2
    if j_z <= 0:
        raise SimError(f'carriage mass {mass_kg!r} kg leaves J_z = {j_z!r}; expected > 0')
    return replace(rig, drive=replace(d, carriage_mass_kg=float(mass_kg), actuator_inertia_kg_m2=j_z))


def mass_sweep(rig: RigParams, masses=(1, 16, 31, 46, 61), control: DriveControl | None = None,
               command_fps: float = COMMAND_FPS, duration_s: float = DURATION_S) -> list:
    """Peak and plateau speed at the 30 fps command for each carriage mass (thesis Figure 28)."""
    control = DriveControl() if control is None else control
    out = []
    for m in masses:
        r = _with_carriage_mass(rig, m)
        run = simulate_drive(r, command_fps * FT_M, duration_s, control=control)
        out.append({'mass_kg': float(m), 'peak_fps': float(run['velocity_m_s'].max()) / FT_M,
                    'plateau_fps': _plateau_m_s(run) / FT_M,
                    'reflected_mass_kg': r.drive.reflected_mass_kg})
    return out


def format_report(study: dict, sweep: list) -> str:
    """Thesis section 4.2.6 vs this model, side by side (display units: fps, ft, kW, A)."""
    s = study
    lines = [f'Top-speed study: {s["command_fps"]:.0f} fps step command, no load, unlimited track',
             f'{"quantity":<34}{"thesis":>12}{"ours":>14}',
             f'{"peak (overshoot) speed, fps":<34}{"28":>12}{s["peak_fps"]:>14.2f}',
             f'{"plateau speed, fps":<34}{"25":>12}{s["plateau_fps"]:>14.2f}',
             f'{"current limit 66.46 A hit":<34}{"yes":>12}{("yes" if s["current_limit_hit"] else "no"):>14}',
             f'{"peak V*i, kW":<34}{"~21":>12}{s["peak_power_kw"]:>14.2f}',
             f'{"distance to plateau (98 %), ft":<34}{"< 2.5":>12}{s["distance_to_plateau_ft"]:>14.2f}',
             f'{"distance to settle (+/-2 %), ft":<34}{"-":>12}{s["distance_to_settle_ft"]:>14.2f}',
             f'{"plateau cause":<34}{"friction/damp.":>12}{s["plateau_cause"]:>14}',
             '',
             f'  back-EMF limit V_max r/(K_e N):      {s["back_emf_limit_fps"]:.2f} fps',
             f'  hand steady state with damping:      {s["steady_state_hand_fps"]:.2f} fps',
             f'  rerun, damping = 0:                  {s["plateau_no_damping_fps"]:.2f} fps '
             f'(shift {100 * s["plateau_shift_no_damping"]:.2f} %)',
             f'  rerun, voltage limit +20 %:          {s["plateau_voltage_plus20_fps"]:.2f} fps '
             f'(shift {100 * s["plateau_shift_voltage_plus20"]:.2f} %; capped by the command)',
             f'  peak electrical input (K_t/K_e) V i: {s["peak_input_power_kw"]:.2f} kW; '
             f'peak mechanical F v: {s["peak_mech_power_kw"]:.2f} kW',
             '',
             'Carriage-mass sweep (thesis: mass changes only the overshoot, plateau stays 25 fps)',
             f'{"mass kg":>8}{"m_c kg":>9}{"peak fps":>10}{"plateau fps":>13}']
    for row in sweep:
        lines.append(f'{row["mass_kg"]:>8.0f}{row.get("reflected_mass_kg", float("nan")):>9.1f}'
                     f'{row["peak_fps"]:>10.2f}{row["plateau_fps"]:>13.2f}')
    return '\n'.join(lines)
