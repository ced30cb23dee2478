"""The mount's ringing after the break, coupled drive vs prescribed motion (src/force_tester_sim/DRIVE.md,
"Ringing after the break").

python benchmarks/ring_after_break.py   (~20 s of CPU; prints figures, asserts nothing)

Truth rig (config/truth_reference.yaml, 1 kHz mount, zeta 0.01), set 3, first truth pull of seed 7 (the pull
with 81 g against 36 g). Prints:
1. max |a2| 0-20 ms and 20-300 ms after the break (and per window) for: the prescribed motion; the coupled drive
   as relaxed now (joint_after_break=True, the default); the plain waveform relaxation over the whole record
   (joint_after_break=False, tol_n=inf: the old path, x3 test only); the monolithic reference
   (integrate_coupled_reference: drive + chain as one ODE, DOP853 rtol 1e-9, from 2 ms before the lanyard
   engages).
2. convergence: per relaxation pass, the x3 change and the ring figure, for both relaxations; the plain
   relaxation under the F_move test (tol_n = 5 N);
3. the linearised closed loop after the break: the mount mode's frequency and damping on a held carriage and
   with the drive loop (PID gains x0, x0.01, x1, x5);
4. saturation after the break (current limiter / supply clip);
5. the break's phase: the prescribed pull with the coupon's break force scaled by +/-0.5..3 %.
"""
from __future__ import annotations

import dataclasses
import math
import sys
import time

import numpy as np

from force_tester_common.core.units import G_M_S2
from force_tester_sim.core import load_rig, run_pull
from force_tester_sim.core.campaign import truth_pull_specs
from force_tester_sim.core.chain import force_move
from force_tester_sim.core.coupled import (
    chain_tension,
    drive_motion,
    drive_on_grid,
    drive_voltage_array,
    free_after_break,
    free_chain_stack,
    integrate_coupled_reference,
    linearised_after_break,
    run_coupled_pull,
)
from force_tester_sim.core.drive import DriveControl, DriveSetup
from force_tester_sim.core.errors import SimError
from force_tester_sim.core.integrate import integrate_chain
from force_tester_sim.core.params import TRUTH_YAML
from force_tester_sim.core.pull import chain_params, motion_for, sample_times_s

SET, SEED = 3, 7
WINDOWS_MS = ((0, 20), (20, 300), (20, 40), (40, 80), (80, 150), (150, 300))


def ring_g(t, a2, tb, lo_ms, hi_ms):
    w = (t >= tb + lo_ms * 1e-3) & (t <= tb + hi_ms * 1e-3)
    return float(np.max(np.abs(a2[w]))) / G_M_S2 if np.any(w) else float('nan')


def passes(rig, spec, joint, n):
    """Per relaxation pass: (x3 change m, max |a2| 20-300 ms g); the loop of run_coupled_pull, unstopped."""
    p, t = chain_params(rig, spec), sample_times_s(rig)
    cmd = motion_for(rig, spec).kinematics(t)[1]
    dr, out = drive_on_grid(rig, t, cmd), []
    for _ in range(n):
        kin = (dr['position_m'], dr['velocity_m_s'], dr['acceleration_m_s2'])
        traj = integrate_chain(p, drive_motion(dr), t, kinematics=kin)
        fm = force_move(traj.x, p)
        a2 = (fm - chain_tension(p, traj, kin)) / p.m2
        new = drive_on_grid(rig, t, cmd, fm, free_chain=free_after_break(p, traj) if joint else None)
        out.append((float(np.max(np.abs(new['position_m'] - dr['position_m']))), ring_g(t, a2, traj.break_s, 20, 300)))
        dr = new
    return out


def mount_mode(A):
    ev = np.linalg.eigvals(A)
    ev = ev[(ev.imag > 2 * np.pi * 300) & (ev.imag < 2 * np.pi * 3000)]
    e = ev[np.argmin(np.abs(ev.imag - 2 * np.pi * 1000))]
    return e.imag / (2 * np.pi), -e.real / abs(e)


def main() -> int:
    rig = load_rig(TRUTH_YAML)
    spec = truth_pull_specs(rig, SET, 1, SEED)[0]
    print(f'truth rig, set {SET}, truth pull 0 of seed {SEED}: break {spec.coupon_break_n:.0f} N, '
          f'{spec.velocity_m_s:.3f} m/s, break duration {spec.break_duration_s * 1e6:.1f} us')
    t0 = time.perf_counter()
    pre = run_pull(rig, spec, noise=False)
    new = run_coupled_pull(rig, spec, noise=False)
    old = run_coupled_pull(rig, spec, noise=False, joint_after_break=False, tol_n=math.inf)   # the old path
    ref = integrate_coupled_reference(rig, spec, new, new.taut_index - 100, new.break_time_s + 0.3)
    print(f'(runs: {time.perf_counter() - t0:.1f} s)')
    t = pre.channels['time_s']
    k0 = new.taut_index - 100
    rows = [('prescribed motion', t, pre.truth['a2_m_s2'], pre.break_time_s, None),
            (f'coupled, plain relaxation ({old.iterations} passes)', t, old.truth['a2_m_s2'], old.break_time_s,
             old.truth['a2_m_s2'][k0:k0 + len(ref['time_s'])]),
            (f'coupled, joint after break ({new.iterations} passes)', t, new.truth['a2_m_s2'], new.break_time_s,
             new.truth['a2_m_s2'][k0:k0 + len(ref['time_s'])]),
            ('monolithic reference', ref['time_s'], ref['a2_m_s2'], ref['break_s'], None)]
    print('\n1. max |a2| (g) in windows after the break (ms)')
    print(f'{"":44s}' + ''.join(f'{f"{lo}-{hi}":>9s}' for lo, hi in WINDOWS_MS) + '   max|a2 - ref| after break')
    tr = ref['time_s']
    after = tr >= ref['break_s']
    for name, tt, a2, tb, on_ref in rows:
        line = f'{name:44s}' + ''.join(f'{ring_g(tt, a2, tb, lo, hi):9.1f}' for lo, hi in WINDOWS_MS)
        if on_ref is not None:
            line += f'   {np.max(np.abs(on_ref[after] - ref["a2_m_s2"][after])) / G_M_S2:7.2f} g'
        print(line)
    print(f'break instants: prescribed {pre.break_time_s:.6f} s, coupled {new.break_time_s:.6f} s, '
          f'reference {ref["break_s"]:.6f} s')

    print('\n2. relaxation passes: x3 change (m) and max |a2| 20-300 ms (g) of the chain solve')
    for joint in (False, True):
        seq = passes(rig, spec, joint, 10)
        print(('joint after break: ' if joint else 'plain relaxation:  ')
              + '  '.join(f'{dx:.1e}/{g:.1f}' for dx, g in seq))

    try:
        run_coupled_pull(rig, spec, noise=False, joint_after_break=False)
        print('plain relaxation with the F_move test (tol_n 5 N): converged')
    except SimError as e:
        print(f'plain relaxation with the F_move test (tol_n 5 N): {e}')

    print('\n3. linearised after the break: the mount mode (frequency Hz, damping ratio)')
    p = chain_params(rig, spec)
    _, A_held = linearised_after_break(rig, p)
    f, z = mount_mode(A_held)
    print(f'  carriage held (prescribed motion): {f:8.2f} Hz  zeta {z:.5f}')
    c0 = DriveControl()
    for gain in (0.0, 0.01, 1.0, 5.0):
        ctl = dataclasses.replace(c0, kp_v_per_m_s=gain * c0.kp_v_per_m_s, ki_v_per_m=gain * c0.ki_v_per_m)
        A_cl, _ = linearised_after_break(rig, p, ctl)
        f, z = mount_mode(A_cl)
        print(f'  drive loop, PID gains x{gain:<5g}:         {f:8.2f} Hz  zeta {z:.5f}  '
              f'(max real part of all eigenvalues {np.max(np.linalg.eigvals(A_cl).real):.3g} 1/s)')

    setup = DriveSetup(rig.drive, c0)
    A_cl, _ = linearised_after_break(rig, p)
    _, A_s, b_s, c_s = free_chain_stack(p)
    A_d, m = A_cl[:4, :4], setup.mass_kg
    b_load = np.array([0.0, -1.0 / m, c0.kd_v_s2_per_m / (m * rig.drive.armature_inductance_h), 0.0])
    freqs = np.linspace(500.0, 2000.0, 15001)
    gain = np.array([abs((c_s @ np.linalg.solve(2j * np.pi * fr * np.eye(len(A_s)) - A_s, b_s))
                         * (A_d[1] @ np.linalg.solve(2j * np.pi * fr * np.eye(4) - A_d, b_load) - 1.0 / m))
                     for fr in freqs])
    k = int(np.argmax(gain))
    band = freqs[gain > 1.0]
    above = f', > 1 from {band[0]:.1f} to {band[-1]:.1f} Hz' if len(band) else ''
    print(f'  plain relaxation loop gain |F_move per a3 (held carriage) x a3 per load (drive loop)|: max '
          f'{gain[k]:.2f} at {freqs[k]:.1f} Hz{above}')

    print('\n4. saturation 0-300 ms after the break (coupled, joint)')
    dr = new.drive
    w = (t >= new.break_time_s) & (t <= new.break_time_s + 0.3)
    v_pid = (c0.kp_v_per_m_s * (dr['command_m_s'] - dr['velocity_m_s']) + c0.ki_v_per_m * dr['integrator'])
    volt = drive_voltage_array(dr['velocity_m_s'], dr['current_a'], dr['integrator'], dr['command_m_s'],
                               dr['acceleration_m_s2'], setup)
    clipped = np.abs(volt - v_pid)[w] > 1e-9
    print(f'  max |i| {np.max(np.abs(dr["current_a"][w])):.1f} A (limit {rig.drive.current_limit_a} A), '
          f'max |V| {np.max(np.abs(volt[w])):.1f} V (limit {rig.drive.voltage_limit_v} V), '
          f'clipped samples {int(np.sum(clipped))} of {int(np.sum(w))}')

    print('\n5. the break\'s phase: prescribed pull, break force scaled (max |a2| 0-20 / 20-300 ms, g)')
    for d in (-0.03, -0.02, -0.01, -0.005, 0.0, 0.005, 0.01, 0.02, 0.03):
        r = run_pull(rig, dataclasses.replace(spec, coupon_break_n=spec.coupon_break_n * (1 + d)), noise=False)
        tt, a2, tb = r.channels['time_s'], r.truth['a2_m_s2'], r.break_time_s
        print(f'  {d:+.3f}: break {1e3 * (tb - r.taut_time_s):.3f} ms after taut, '
              f'{ring_g(tt, a2, tb, 0, 20):6.1f} / {ring_g(tt, a2, tb, 20, 300):6.1f}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
