"""The drive coupled to the force chain (core/coupled.py): the lanyard load acts back on the carriage."""
import dataclasses

import numpy as np
import pytest

from force_tester_sim.core import CHANNELS, load_rig, nominal_pull_spec, run_pull, sample_times_s, simulate_pull
from force_tester_sim.core.coupled import DriveMotion, check_fits, drive_on_grid, run_coupled_pull
from force_tester_sim.core.departures import Departures
from force_tester_sim.core.errors import SimError

SET = 3   # 15 fps, 600 lbf coupon: the hardest nominal pull


def _trapz(y, t):
    return float(np.sum(0.5 * (y[1:] + y[:-1]) * np.diff(t)))


@pytest.fixture(scope='module')
def rig():
    return load_rig()


@pytest.fixture(scope='module')
def spec(rig):
    return nominal_pull_spec(rig, SET, seed=7)


@pytest.fixture(scope='module')
def coupled(rig, spec):
    return run_coupled_pull(rig, spec, noise=False), None


@pytest.fixture(scope='module')
def prescribed(rig, spec):
    return run_pull(rig, spec, noise=False)


def test_converges_in_few_passes(coupled):
    r, _ = coupled
    assert 1 <= r.iterations <= 5
    assert r.x3_changes_m[-1] < 1e-6
    assert r.x3_changes_m[0] > 1e-5          # the load did move the carriage: the coupling is not a no-op


def test_carriage_slows_by_impulse_over_mass(rig, coupled):
    r, _ = coupled
    t, v = r.channels['time_s'], r.truth['v3_m_s']
    dv = v - r.truth['v3_no_load_m_s']
    k0, k1 = r.taut_index, r.break_end_index
    assert k0 is not None and k1 is not None and k1 > k0
    impulse = _trapz(r.truth['force_moving_n'][k0:k1 + 1], t[k0:k1 + 1])
    predicted = impulse / rig.drive.reflected_mass_kg
    dip = dv[k0] - dv[k1]
    assert predicted > 0.01                  # m/s: measurable
    assert dip == pytest.approx(predicted, rel=0.2), (dip, predicted)


def test_energy_balance_over_the_pull(rig, coupled):
    r, _ = coupled
    d = rig.drive
    dr = r.drive
    t, v, i, volt = dr['time_s'], dr['velocity_m_s'], dr['current_a'], dr['voltage_v']
    kp = d.torque_constant_nm_per_a / d.back_emf_constant_v_s_per_rad   # sqrt 3, DRIVE.md
    # launch to 10 ms after the break: the carriage is still moving, so kinetic energy is in the balance
    k = r.break_end_index + 500
    s = slice(0, k + 1)
    e_in = kp * _trapz(volt[s] * i[s], t[s])
    kinetic = 0.5 * d.reflected_mass_kg * (v[k] ** 2 - v[0] ** 2)
    resistive = kp * d.armature_resistance_ohm * _trapz(i[s] ** 2, t[s])
    viscous = d.viscous_damping_n_s_per_m * _trapz(v[s] ** 2, t[s])
    load = _trapz(dr['load_n'][s] * v[s], t[s])
    inductive = kp * 0.5 * d.armature_inductance_h * (i[k] ** 2 - i[0] ** 2)
    out = kinetic + resistive + viscous + load + inductive
    assert load > 10.0                       # J: the lanyard's work (~20 J at set 3) is in the balance
    assert abs(e_in - out) / e_in < 0.01, (e_in, kinetic, resistive, viscous, load, inductive)
    # the residual is far below the load work: the balance resolves the coupling
    assert abs(e_in - out) < 0.1 * load, (e_in - out, load)


def test_current_within_limit(rig, coupled):
    r, _ = coupled
    assert np.max(np.abs(r.channels['motor_current_a'])) <= rig.drive.current_limit_a * 1.001
    assert np.max(np.abs(r.channels['motor_voltage_v'])) <= rig.drive.voltage_limit_v + 1e-9


def test_force_peaks_close_to_prescribed(coupled, prescribed):
    r, _ = coupled
    for key in ('force_stationary_n', 'force_moving_n'):
        c, p = r.truth[key].max(), prescribed.truth[key].max()
        assert c == pytest.approx(p, rel=0.05), (key, c, p)
    assert r.break_time_s is not None


def test_channels_come_from_the_drive(rig, spec, coupled):
    r, _ = coupled
    ch = r.channels
    assert set(ch) == set(CHANNELS)
    assert np.array_equal(ch['motor_current_a'], r.drive['current_a'])
    assert np.array_equal(ch['motor_voltage_v'], r.drive['voltage_v'])
    assert np.array_equal(ch['motor_velocity_cmd_m_s'], r.drive['command_m_s'])
    res = rig.sensors.encoder_resolution_m
    assert np.max(np.abs(ch['encoder_position_m'] - r.drive['position_m'])) <= res / 2 + 1e-12
    assert np.max(np.abs(r.drive['position_m'] - r.truth['x3_m'])) < 1e-6
    assert len(ch['time_s']) == len(sample_times_s(rig))
    assert np.max(r.drive['position_m']) <= rig.drive.usable_track_m
    assert abs(r.drive['velocity_m_s'][-1]) < 1e-3


def test_simulate_pull_switch(rig):
    sp = nominal_pull_spec(rig, 1, seed=3)
    a = simulate_pull(rig, sp, noise=True, drive=True)
    b = simulate_pull(rig, sp, noise=True)
    assert set(a) == set(CHANNELS) == set(b)
    # same noise seed, different physics: the motor channels differ, the forces are close
    assert not np.array_equal(a['motor_current_a'], b['motor_current_a'])
    assert a['force_stationary_n'].max() == pytest.approx(b['force_stationary_n'].max(), rel=0.05)


def test_drive_motion_is_consistent(coupled):
    r, _ = coupled
    m = r.motion
    assert isinstance(m, DriveMotion)
    t = m.t
    x, v, a = m.kinematics(t)                 # exact at the samples
    assert np.max(np.abs(x - r.truth['x3_m'])) < 1e-12
    assert np.max(np.abs(a - r.truth['a3_m_s2'])) < 1e-6
    tt = np.linspace(0.6, 0.7, 4001) + 3.3e-6  # off the grid
    x, v, a = m.kinematics(tt)
    eps = 1e-7
    xp, vp, _ = m.kinematics(tt + eps)
    xm, vm, _ = m.kinematics(tt - eps)
    assert np.max(np.abs((xp - xm) / (2 * eps) - v)) < 1e-6
    assert np.max(np.abs((vp - vm) / (2 * eps) - a)) < 1e-3 * max(1.0, np.max(np.abs(a)))
    for tk in (0.0, 0.123456, 0.65432, 1.9999, 2.5):
        assert m.kinematics_scalar(tk) == pytest.approx(tuple(float(q) for q in m.kinematics(tk)), abs=1e-9)
    assert m.command_velocity(t[40000]) == pytest.approx(r.drive['command_m_s'][40000])


def test_friction_shows_in_the_current(rig):
    t = sample_times_s(rig)[:20001]          # 0.4 s
    cmd = np.minimum(t * 10.0, 1.0)
    fric = dataclasses.replace(rig, departures=Departures().with_entry('coulomb_friction', force_n=150.0))
    a = drive_on_grid(rig, t, cmd)
    b = drive_on_grid(fric, t, cmd)
    offset = (b['current_a'] - a['current_a'])[-1]
    assert offset == pytest.approx(150.0 / rig.drive.force_per_amp_n_per_a, rel=0.01)


def test_errors(rig, spec):
    with pytest.raises(SimError, match='usable track'):
        check_fits(rig, np.array([0.0, rig.drive.usable_track_m + 0.01, 0.5]), np.zeros(3))
    with pytest.raises(SimError, match='end of the record'):
        check_fits(rig, np.zeros(3), np.array([0.0, 1.0, 0.5]))
    with pytest.raises(SimError, match='did not converge'):
        run_coupled_pull(rig, spec, noise=False, iterations=1)
    with pytest.raises(SimError, match='iterations'):
        run_coupled_pull(rig, spec, iterations=0)
    with pytest.raises(SimError, match='uniform'):
        DriveMotion([0.0, 1.0, 3.0], np.zeros(3), np.zeros(3), np.zeros(3), np.zeros(3))
    with pytest.raises(SimError, match='non-finite'):
        drive_on_grid(rig, np.arange(10) * 2e-5, np.full(10, np.nan))


# --- the exact (modal lfilter) drive integrator against the LSODA reference (DRIVE.md "Coupled drive") ---

def _agree(a, b, x_tol_m=1e-7, rel=1e-4):
    assert np.max(np.abs(a['position_m'] - b['position_m'])) < x_tol_m
    for key in ('velocity_m_s', 'current_a', 'voltage_v', 'acceleration_m_s2'):
        scale = np.max(np.abs(a[key]))
        assert np.max(np.abs(a[key] - b[key])) < rel * scale, key
    assert np.max(np.abs(a['current_a'])) == pytest.approx(np.max(np.abs(b['current_a'])), rel=rel)


def test_exact_drive_matches_lsoda_with_the_lanyard_load(rig, coupled):
    r, _ = coupled
    t, cmd, load = r.drive['time_s'], r.drive['command_m_s'], r.drive['load_n']
    a = drive_on_grid(rig, t, cmd, load, method='exact')
    b = drive_on_grid(rig, t, cmd, load, method='lsoda')
    _agree(a, b)
    assert np.array_equal(a['position_m'], r.drive['position_m'])   # the default is the exact path


def test_exact_drive_matches_lsoda_through_limiter_clip_and_friction(rig):
    # 30 fps step: current limiter, then the supply limit; a braking command back to rest with 150 N dry
    # friction (the friction band and both signs); the exact path hands these stretches to LSODA
    t = sample_times_s(rig)[:30001]          # 0.6 s
    cmd = np.where(t > 0, 9.144, 0.0) * (t < 0.25) + np.maximum(0.0, 3.0 - 40.0 * (t - 0.25)) * (t >= 0.25)
    for fc in (0.0, 150.0):
        a = drive_on_grid(rig, t, cmd, friction_n=fc, method='exact')
        b = drive_on_grid(rig, t, cmd, friction_n=fc, method='lsoda')
        assert np.max(np.abs(a['current_a'])) == pytest.approx(rig.drive.current_limit_a, rel=1e-3)
        assert np.max(np.abs(a['voltage_v'])) == pytest.approx(rig.drive.voltage_limit_v, rel=1e-9)
        _agree(a, b, x_tol_m=1e-6)


def test_coupled_pull_exact_matches_lsoda(rig, spec, coupled):
    r, _ = coupled
    ref = run_coupled_pull(rig, spec, noise=False, method='lsoda')
    assert ref.iterations == r.iterations
    for key in ('force_stationary_n', 'force_moving_n'):
        assert r.truth[key].max() == pytest.approx(ref.truth[key].max(), rel=1e-4), key
    assert np.max(np.abs(r.truth['x3_m'] - ref.truth['x3_m'])) < 1e-7
    assert np.max(np.abs(r.channels['motor_current_a'])) == pytest.approx(
        np.max(np.abs(ref.channels['motor_current_a'])), rel=1e-4)
    assert r.break_time_s == pytest.approx(ref.break_time_s, abs=1e-6)
    with pytest.raises(SimError, match='method'):
        drive_on_grid(rig, r.drive['time_s'][:10], np.zeros(10), method='rk4')
