"""Drive model of thesis section 4.2 (core/drive.py) and the top-speed study (core/thesis.py)."""
import numpy as np
import pytest

from force_tester_common.core.units import FT_M
from force_tester_sim.core.drive import DriveControl, simulate_drive
from force_tester_sim.core.errors import SimError
from force_tester_sim.core.params import load_rig
from force_tester_sim.core.thesis import format_report, mass_sweep, top_speed_study

CMD = 30.0 * FT_M
NO_DAMPING = {'viscous_damping_motor_n_s_per_m': 0.0, 'viscous_damping_actuator_n_s_per_m': 0.0}


@pytest.fixture(scope='module')
def rig():
    return load_rig()


@pytest.fixture(scope='module')
def run(rig):
    return simulate_drive(rig, CMD, 0.5)


def _trapz(y, t):
    return float(np.sum(0.5 * (y[1:] + y[:-1]) * np.diff(t)))


def test_energy_balance(rig):
    d = rig.drive
    r = simulate_drive(rig, CMD, 0.3, sample_dt_s=2e-5)
    t, v, i, volt = r['time_s'], r['velocity_m_s'], r['current_a'], r['voltage_v']
    kp = d.torque_constant_nm_per_a / d.back_emf_constant_v_s_per_rad   # sqrt 3, see drive.py
    e_in = kp * _trapz(volt * i, t)
    kinetic = 0.5 * d.reflected_mass_kg * v[-1] ** 2
    resistive = kp * d.armature_resistance_ohm * _trapz(i ** 2, t)
    damping = d.viscous_damping_n_s_per_m * _trapz(v ** 2, t)
    inductive = kp * 0.5 * d.armature_inductance_h * i[-1] ** 2
    out = kinetic + resistive + damping + inductive
    assert e_in > 1e3
    assert abs(e_in - out) / e_in < 0.01, (e_in, kinetic, resistive, damping, inductive)
    # the lumped circuit's V i alone does NOT balance (K_t != K_e): the check has teeth
    assert abs(_trapz(volt * i, t) - out) / e_in > 0.2


def test_plateau_equals_back_emf_limit_without_damping(rig):
    d = rig.drive
    by_hand = d.voltage_limit_v * d.pulley_radius_m / (d.back_emf_constant_v_s_per_rad * d.gear_ratio)
    assert by_hand == pytest.approx(7.88, abs=0.01)
    r = simulate_drive(rig, CMD, 0.5, overrides=NO_DAMPING)
    assert r['velocity_m_s'][-1] == pytest.approx(by_hand, rel=0.01)
    assert r['velocity_m_s'][-1] == pytest.approx(by_hand, rel=1e-3)


def test_plateau_with_damping_matches_hand_steady_state(rig, run):
    d = rig.drive
    b = d.viscous_damping_motor_n_s_per_m + d.viscous_damping_actuator_n_s_per_m
    kf = d.gear_ratio * d.torque_constant_nm_per_a / d.pulley_radius_m
    ke = d.back_emf_constant_v_s_per_rad * d.gear_ratio / d.pulley_radius_m
    # V_max = R i + ke v and kf i = b v  ->  v = V_max / (ke + R b / kf)
    v_ss = d.voltage_limit_v / (ke + d.armature_resistance_ohm * b / kf)
    v_end = run['velocity_m_s'][-1]
    assert v_end == pytest.approx(v_ss, rel=1e-3)
    assert v_end < d.voltage_limit_v / ke
    assert run['current_a'][-1] == pytest.approx(b * v_ss / kf, rel=0.01)
    assert abs(run['voltage_v'][-1]) == pytest.approx(d.voltage_limit_v, rel=1e-9)


def test_current_and_voltage_limits_hold(rig, run):
    d = rig.drive
    assert np.max(np.abs(run['current_a'])) <= d.current_limit_a * (1 + 1e-3)
    assert np.max(np.abs(run['current_a'])) >= 0.99 * d.current_limit_a     # and it is reached
    assert np.max(np.abs(run['voltage_v'])) <= d.voltage_limit_v + 1e-9
    # a small command is tracked without windup
    slow = simulate_drive(rig, 3.0 * FT_M, 0.5)
    assert slow['velocity_m_s'][-1] == pytest.approx(3.0 * FT_M, rel=1e-3)
    assert np.max(np.abs(slow['current_a'])) <= d.current_limit_a * (1 + 1e-3)


def test_convergence_in_max_step(rig, run):
    fine = simulate_drive(rig, CMD, 0.5, max_step_s=2.5e-5)
    p0, p1 = run['velocity_m_s'].max(), fine['velocity_m_s'].max()
    assert abs(p1 - p0) / p1 < 1e-3


def test_study_decides_back_emf(rig):
    s = top_speed_study(rig)
    assert s['plateau_cause'] == 'back_emf'
    assert s['current_limit_hit'] is True
    assert s['plateau_fps'] == pytest.approx(s['steady_state_hand_fps'], rel=1e-3)
    assert s['peak_fps'] > s['plateau_fps']
    assert s['peak_power_kw'] == pytest.approx(325.2 * 66.46 / 1e3, rel=0.01)
    assert s['distance_to_plateau_ft'] < 2.5
    assert s['plateau_shift_no_damping'] < 0.005 < 0.1 < s['plateau_shift_voltage_plus20']
    sweep = mass_sweep(rig, masses=(1, 61))
    assert sweep[0]['peak_fps'] > sweep[1]['peak_fps']
    assert sweep[0]['plateau_fps'] == pytest.approx(sweep[1]['plateau_fps'], rel=1e-3)
    text = format_report(s, sweep)
    assert 'back_emf' in text and '28' in text


def test_bad_inputs_raise_sim_error(rig):
    with pytest.raises(SimError, match='voltage_limt_v'):
        simulate_drive(rig, CMD, 0.1, overrides={'voltage_limt_v': 300.0})
    with pytest.raises(SimError, match='duration_s'):
        simulate_drive(rig, CMD, -1.0)
    with pytest.raises(SimError, match='kp_v_per_m_s'):
        DriveControl(kp_v_per_m_s=-1.0)
    with pytest.raises(SimError, match='voltage_limit_v'):
        simulate_drive(rig, CMD, 0.1, overrides={'voltage_limit_v': 0.0})
