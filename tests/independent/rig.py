"""An independent campaign generator for the dynamic force tester (issue 37), written from SPEC.md alone.

How to call it
--------------
::

    import sys; sys.path.insert(0, 'tests/independent')
    from rig import generate_campaign, rig_yaml, grammar_terms

    campaign, truth = generate_campaign(7, 'pull', n_pulls=12, departures='draw')
    for meta, channels in campaign:          # in set, then pull, order
        meta['file'], channels['force_moving_n']   # 1-D float64 arrays, SI, channels.py names
    yaml_text = rig_yaml(truth)              # the lab's datasheet as a rig YAML
    terms = grammar_terms(truth)             # every {channel, term, coefficient[, frequency_hz]}

``rig`` takes dotted overrides of drawn constants (``{'daq.sample_rate_hz': 20000}``) and switches
(``'drive.enabled'``, ``'lanyard.enabled'``, ``'transverse.enabled'``). ``departures`` is ``'draw'``,
``'catalog'``, ``'beyond'``, ``'none'`` / ``[]`` or a list of ``{'name': ..., params, 'channel'?,
'body'?, 'form'?}``. ``kind='impact'`` gives the drop tower of SPEC 3.3 (time_s, force_moving_n,
accel_axial_m_s2 and, on most rigs, the lateral and vertical accelerations).

Cost (one core, nice 19, while another job ran): one set-3 pull at 20 kHz takes 3 - 6 s of CPU, a 12-pull
campaign at 20 kHz 40 - 60 s; an impact drop 2 - 4 s. Deterministic for a seed: every draw comes from
``numpy.random.SeedSequence(seed, spawn_key=...)`` keyed by purpose and by (set, pull), never by position.

Lower-level pieces, used by the tests: ``draw_rig``, ``draw_pull``, ``Model`` (the coupled ODE),
``simulate`` (one record, clean signals on a fine grid), ``DAQ`` (sensor, conditioner, noise,
anti-alias filter, skewed drifting sampling, ADC).

Method
------
One state vector for the whole coupled system (carriage, m1, m2, cells, mount, lanyard + coupon, armature
current, both PI integrators, and energy quadratures), integrated by ``solve_ivp(method='Radau')`` with
per-state absolute tolerances; the cell deflections and the lanyard's total extension are states of their
own (never differences of metre-scale positions). Terminal events at the first taut instant, the coupon's
break onset and the brake trigger; the break's damage ramp is its own segment. The integrator's Jacobian is a
forward difference with fixed, tolerance-scaled steps (one vectorised call). The transverse modes are
driven one way (SPEC 2.5: no feed-back on the axial motion) and are integrated on the fine grid afterwards,
as a first-order-hold discretisation of each mode.

Choices SPEC.md left open are marked "choice" in the code and listed in PROVENANCE.md.
"""
from __future__ import annotations

import math
from typing import Mapping, Sequence

import numpy as np
from scipy import signal
from scipy.integrate import solve_ivp

SPEC_VERSION = 1
LBF_N = 4.4482216152605
FT_M = 0.3048
G = 9.80665
F_FS = 4448.0          # 1000 lbf rated range, the non-linearity reference
A_FS = 1000.0          # accelerometer non-linearity reference
VS_FRICTION = 1e-3     # sgn_s(v) = tanh(v / 1 mm/s)

# set -> (coupon_lbf, fps, decel_g, F_u lbf (Table 7), a2 max g, y range, p_f range, t_br range)
PULL_SETS = {
    1: (200, 3.0, 0.0, 212.10, 27.9, (0.6, 0.9), (5e-3, 20e-3), (0.2e-3, 1e-3)),
    2: (400, 11.0, 0.0, 584.08, 114.0, (0.6, 0.9), (3e-3, 15e-3), (0.05e-3, 1e-3)),
    3: (600, 15.0, 0.0, 688.82, 330.0, (0.7, 0.95), (3e-3, 20e-3), (5e-6, 0.2e-3)),
    4: (400, 7.8, -1.24, 588.92, 199.0, (0.5, 0.8), (2e-3, 10e-3), (20e-6, 200e-6)),
    5: (600, 7.8, -1.24, 792.87, 225.0, (0.7, 0.9), (2e-3, 10e-3), (50e-6, 400e-6)),
}
# ADC scan order (slot index = position)
ANALOG = ('force_moving_n', 'force_stationary_n', 'accel_axial_m_s2', 'accel_lateral_m_s2',
          'accel_vertical_m_s2', 'motor_current_a', 'motor_voltage_v')
SHORT = {'force_moving': 'force_moving_n', 'force_stationary': 'force_stationary_n',
         'accel_axial': 'accel_axial_m_s2', 'accel_lateral': 'accel_lateral_m_s2',
         'accel_vertical': 'accel_vertical_m_s2', 'motor_current': 'motor_current_a',
         'motor_voltage': 'motor_voltage_v'}
LONG2SHORT = {v: k for k, v in SHORT.items()}
GRAMMAR_CHANNELS = ('force_moving', 'force_stationary', 'accel_axial', 'motor_current')
# which clean signal each analog channel measures
CLEAN_OF = {'force_moving_n': 'F2', 'force_stationary_n': 'F1', 'accel_axial_m_s2': 'a2',
            'accel_lateral_m_s2': 'ay', 'accel_vertical_m_s2': 'az', 'motor_current_a': 'i',
            'motor_voltage_v': 'V'}
CATALOG = ('effective_mass', 'mount_resonance', 'accel_delay', 'moving_cell_gain', 'ac_coupling', 'mains_hum',
           'coulomb_friction')
BEYOND = ('nonlinearity_even', 'nonlinearity_odd', 'gain_drift', 'zero_drift', 'line_pickup', 'sensor_resonance',
          'cross_axis', 'aero_drag', 'cable_force', 'binding_rail', 'viscous_guide', 'clipping')
BODY_DEPARTURES = ('effective_mass', 'mount_resonance', 'coulomb_friction', 'aero_drag', 'cable_force',
                   'binding_rail', 'viscous_guide')


# ----------------------------------------------------------------------------------------------- draws
def _rng(seed: int, *key: int) -> np.random.Generator:
    return np.random.default_rng(np.random.SeedSequence(int(seed), spawn_key=tuple(int(k) for k in key)))


def _u(r, a, b):
    return float(r.uniform(a, b))


def _lu(r, a, b):
    return float(math.exp(r.uniform(math.log(a), math.log(b))))


def _range(r, a, b):
    """Uniform, or log-uniform where the range spans more than a factor of 3 (SPEC 2.2)."""
    return _lu(r, a, b) if b / a > 3 else _u(r, a, b)


def _nclip(r, sigma):
    return float(np.clip(r.standard_normal(), -3.0, 3.0)) * sigma


def _pm(r, a, b, log=False):
    v = _lu(r, a, b) if log else _u(r, a, b)
    return v if r.random() < 0.5 else -v


# ----------------------------------------------------------------------------------------------- the rig
def _draw_transverse(r, d: dict) -> None:
    """The lateral (y) and vertical (z) modes of a rig: frequency, damping, misalignment angle (SPEC 2.5)."""
    for ax in ('y', 'z'):
        d[f'transverse.f_{ax}_hz'] = _lu(r, 300.0, 3000.0)
        d[f'transverse.zeta_{ax}'] = _u(r, 0.01, 0.05)
        d[f'transverse.phi_{ax}_rad'] = math.radians(_pm(r, 0.2, 2.0))


def _draw_daq(r, d: dict) -> None:
    """The DAQ chain every rig has (SPEC 4): anti-alias filter, ADC, clock, skew, the force and accelerometer noise."""
    d['daq.filter_type'] = 'butterworth' if r.random() < 0.5 else 'bessel'
    d['daq.filter_order'] = 8
    d['daq.fc_ratio'] = _u(r, 0.3, 0.45)
    d['daq.adc_bits'] = 16
    d['daq.clock_ppm_rig'] = _u(r, -50.0, 50.0)
    d['daq.t_slot_s'] = _u(r, 0.0, 2e-6)
    d['daq.noise.force_moving_n'] = _lu(r, 0.05, 1.0)
    for ch in ('accel_axial_m_s2', 'accel_lateral_m_s2', 'accel_vertical_m_s2'):
        d[f'daq.noise.{ch}'] = _lu(r, 0.1, 2.0)


def draw_rig(seed: int, overrides: Mapping | None = None) -> dict:
    """Every simulated constant, SI, dotted keys. Overrides replace drawn values before derived ones."""
    overrides = dict(overrides or {})
    for attempt in range(200):
        r = _rng(seed, 0, attempt)
        d: dict = {}
        d['daq.sample_rate_hz'] = float(r.choice([10e3, 20e3, 25e3, 40e3, 50e3, 100e3])) if r.random() < 0.5 \
            else _lu(r, 10e3, 100e3)
        d['daq.record_length_s'] = _u(r, 1.5, 3.0)
        d['drive.armature_resistance_ohm'] = _u(r, 0.15, 0.5)
        d['drive.armature_inductance_h'] = _range(r, 1e-3, 10e-3)
        d['drive.back_emf_constant_v_s_per_rad'] = _u(r, 0.6, 1.2)
        d['drive.motor_inertia_kg_m2'] = _range(r, 1e-3, 6e-3)
        d['drive.gear_ratio'] = _u(r, 2.0, 5.0)
        d['drive.pulley_radius_m'] = _u(r, 0.04, 0.10)
        d['drive.carriage_mass_kg'] = _u(r, 25.0, 80.0)
        d['drive.belt_mass_kg'] = _range(r, 2.0, 10.0)
        d['drive.viscous_damping_motor_n_s_per_m'] = _range(r, 2.0, 40.0)
        d['drive.viscous_damping_actuator_n_s_per_m'] = _range(r, 2.0, 40.0)
        d['drive.current_limit_a'] = _u(r, 40.0, 100.0)
        d['drive.voltage_limit_v'] = _u(r, 250.0, 400.0)
        d['drive.usable_track_m'] = _u(r, 1.2, 3.0)
        d['force_chain.stationary_side_mass_kg'] = _u(r, 0.6, 2.0)
        d['force_chain.moving_side_mass_kg'] = _u(r, 0.8, 1.6)
        d['force_chain.load_cell_stiffness_n_per_m'] = 7.0e8 * _lu(r, 0.5, 2.0)
        d['force_chain.load_cell_damping_ratio'] = _lu(r, 0.005, 0.05)
        d['force_chain.lanyard_stiffness_n_per_m'] = _lu(r, 2e5, 3e6)
        d['force_chain.lanyard_damping_ratio'] = _lu(r, 0.01, 0.15)
        d['cells.unit_scatter_1'] = _u(r, -0.1, 0.1)
        d['cells.unit_scatter_2'] = _u(r, -0.1, 0.1)
        d['control.f_ci_hz'] = _lu(r, 500.0, 2000.0)
        d['control.f_cv_hz'] = _lu(r, 15.0, 60.0)
        d['control.f_ff'] = _u(r, 0.0, 1.0)
        d['drive.enabled'] = True
        d['lanyard.enabled'] = True
        d['transverse.enabled'] = True
        _draw_transverse(r, d)
        d['transverse.q'] = _lu(r, 0.2, 3.0)
        d['sensors.encoder_resolution_m'] = _lu(r, 0.05e-6, 5e-6)
        d['sensors.load_cell_sensitivity_mv_per_lbf'] = _lu(r, 1.0, 10.0)
        d['sensors.load_cell_range_lbf'] = 1000.0
        d['sensors.accelerometer_sensitivity_mv_per_g'] = _lu(r, 1.0, 100.0)
        d['sensors.accelerometer_band_hz'] = 10000.0
        _draw_daq(r, d)
        d['daq.noise.force_stationary_n'] = d['daq.noise.force_moving_n']
        d['daq.noise.motor_current_a'] = _lu(r, 0.01, 0.3)
        d['daq.noise.motor_voltage_v'] = _lu(r, 0.05, 2.0)
        absent = []
        if r.random() < 0.2:
            absent = ['motor_voltage_v', 'motor_velocity_cmd_m_s', 'accel_lateral_m_s2', 'accel_vertical_m_s2']
            if r.random() < 0.1:
                absent += ['force_stationary_n', 'encoder_position_m']
        d['daq.absent'] = absent
        # the coupon batch of each set (once per campaign)
        for s, (_lbf, _fps, _dg, fu_lbf, _a2, yr, pfr, tbr) in PULL_SETS.items():
            d[f'coupon.{s}.F_u_n'] = fu_lbf * LBF_N
            d[f'coupon.{s}.y'] = _u(r, *yr)
            d[f'coupon.{s}.p_f_m'] = _range(r, *pfr)
            d[f'coupon.{s}.p_h_ratio'] = _u(r, 0.2, 1.0)
            d[f'coupon.{s}.k_c_n_per_m'] = _lu(r, 5e6, 5e7)
            d[f'coupon.{s}.eta_fraction'] = _u(r, 0.01, 0.05)
            d[f'coupon.{s}.t_br_min_s'], d[f'coupon.{s}.t_br_max_s'] = tbr
            d[f'coupon.{s}.slack_u'] = _u(r, 0.0, 1.0)     # where in the feasible slack window
        d.update(overrides)
        _derive(d, overrides)
        # rejection rules (SPEC 2.2)
        fastest = max(PULL_SETS[s][1] for s in PULL_SETS) * FT_M * 1.03
        if d['drive.enabled'] and not overrides.get('rig.no_reject', False):
            if d['derived.v_emf_limit_m_s'] < 1.2 * fastest or d['derived.a_max_m_s2'] < 1.5 * 30.0:
                continue
        d['rig.attempt'] = attempt
        return d
    raise RuntimeError('no admissible rig drawn')


def _derive(d: dict, overrides: Mapping) -> None:
    r_p = d['drive.pulley_radius_m']
    n = d['drive.gear_ratio']
    if 'drive.actuator_inertia_kg_m2' not in overrides:
        d['drive.actuator_inertia_kg_m2'] = (d['drive.carriage_mass_kg'] + d['drive.belt_mass_kg']) * r_p ** 2
    if 'drive.torque_constant_nm_per_a' not in overrides:
        d['drive.torque_constant_nm_per_a'] = math.sqrt(3.0) * d['drive.back_emf_constant_v_s_per_rad']
    k_t = d['drive.torque_constant_nm_per_a']
    d['derived.k_F_n_per_a'] = n * k_t / r_p
    d['derived.M_eff_kg'] = (d['drive.actuator_inertia_kg_m2'] + n ** 2 * d['drive.motor_inertia_kg_m2']) / r_p ** 2
    d['derived.b_n_s_per_m'] = (d['drive.viscous_damping_motor_n_s_per_m']
                                + d['drive.viscous_damping_actuator_n_s_per_m'])
    d['derived.v_emf_limit_m_s'] = d['drive.voltage_limit_v'] * r_p / (d['drive.back_emf_constant_v_s_per_rad'] * n)
    d['derived.a_max_m_s2'] = d['derived.k_F_n_per_a'] * d['drive.current_limit_a'] / d['derived.M_eff_kg']
    kcat = d['force_chain.load_cell_stiffness_n_per_m']
    d.setdefault('cells.K1_n_per_m', kcat * (1 + d['cells.unit_scatter_1']))
    d.setdefault('cells.K2_n_per_m', kcat * (1 + d['cells.unit_scatter_2']))
    d.setdefault('cells.zeta_1', d['force_chain.load_cell_damping_ratio'])
    d.setdefault('cells.zeta_2', d['force_chain.load_cell_damping_ratio'])
    w_ci = 2 * math.pi * d['control.f_ci_hz']
    w_cv = 2 * math.pi * d['control.f_cv_hz']
    d['control.K_pi'] = d['drive.armature_inductance_h'] * w_ci
    d['control.K_ii'] = d['drive.armature_resistance_ohm'] * w_ci
    d['control.K_pv'] = d['derived.M_eff_kg'] * w_cv / d['derived.k_F_n_per_a']
    d['control.K_iv'] = d['control.K_pv'] * w_cv / 4.0
    d['control.T_aw_c_s'] = 1.0 / w_ci
    d['control.T_aw_v_s'] = 1.0 / w_cv
    fs = d['daq.sample_rate_hz']
    d['daq.fc_hz'] = d['daq.fc_ratio'] * fs
    # sensitivities (V per SI unit) and ranges: nominal pull peaks below 80 % of full scale
    f_peak = 1.3 * max(d[f'coupon.{s}.F_u_n'] for s in PULL_SETS)
    s_f = d['sensors.load_cell_sensitivity_mv_per_lbf'] * 1e-3 / LBF_N
    a_peak = 2.0 * f_peak / d['force_chain.moving_side_mass_kg']
    s_a = d['sensors.accelerometer_sensitivity_mv_per_g'] * 1e-3 / G
    peaks = {'force_moving_n': (f_peak, s_f), 'force_stationary_n': (f_peak, s_f),
             'accel_axial_m_s2': (a_peak, s_a), 'accel_lateral_m_s2': (0.3 * a_peak, s_a),
             'accel_vertical_m_s2': (0.3 * a_peak, s_a),
             'motor_current_a': (d['drive.current_limit_a'], 0.1),
             'motor_voltage_v': (d['drive.voltage_limit_v'], 0.02)}
    for ch, (peak, sens) in peaks.items():
        if f'daq.sens.{ch}' in overrides:
            sens = overrides[f'daq.sens.{ch}']
        elif peak * sens > 0.8 * 10.0:              # even +-10 V would clip: lower the sensitivity
            sens = 0.8 * 10.0 / peak
        rng_v = overrides.get(f'daq.range_v.{ch}', next(v for v in (1.0, 2.0, 5.0, 10.0) if peak * sens <= 0.8 * v
                                                        or v == 10.0))
        d[f'daq.sens.{ch}'] = sens
        d[f'daq.range_v.{ch}'] = rng_v
        d[f'daq.lsb_si.{ch}'] = 2 * rng_v / 2 ** d['daq.adc_bits'] / sens
    if 'sensors.load_cell_sensitivity_mv_per_lbf' not in overrides:   # datasheet shows what was used
        d['sensors.load_cell_sensitivity_mv_per_lbf'] = d['daq.sens.force_moving_n'] * 1e3 * LBF_N
        d['sensors.accelerometer_sensitivity_mv_per_g'] = d['daq.sens.accel_axial_m_s2'] * 1e3 * G


def datasheet(rig: Mapping, sets_pulls: Mapping[int, int]) -> dict:
    keys = {
        'daq': ('sample_rate_hz', 'record_length_s'),
        'drive': ('armature_resistance_ohm', 'armature_inductance_h', 'torque_constant_nm_per_a',
                  'back_emf_constant_v_s_per_rad', 'motor_inertia_kg_m2', 'gear_ratio', 'pulley_radius_m',
                  'actuator_inertia_kg_m2', 'carriage_mass_kg', 'viscous_damping_motor_n_s_per_m',
                  'viscous_damping_actuator_n_s_per_m', 'current_limit_a', 'voltage_limit_v', 'usable_track_m'),
        'force_chain': ('stationary_side_mass_kg', 'moving_side_mass_kg', 'load_cell_stiffness_n_per_m',
                        'load_cell_damping_ratio', 'lanyard_stiffness_n_per_m', 'lanyard_damping_ratio'),
        'sensors': ('load_cell_sensitivity_mv_per_lbf', 'load_cell_range_lbf', 'accelerometer_sensitivity_mv_per_g',
                    'accelerometer_band_hz', 'encoder_resolution_m'),
    }
    out = {sec: {k: float(rig[f'{sec}.{k}']) for k in ks} for sec, ks in keys.items()}
    out['test_sets'] = [{'set': s, 'coupon_lbf': PULL_SETS[s][0], 'velocity_fps': PULL_SETS[s][1],
                         'decel_g': PULL_SETS[s][2], 'pulls': int(n), 'measured_stationary_avg_lbf': PULL_SETS[s][3],
                         'measured_a2_max_g': PULL_SETS[s][4]} for s, n in sorted(sets_pulls.items())]
    return out


# ----------------------------------------------------------------------------------------------- command
class Command:
    """v_cmd(t), a_cmd(t): raised-cosine launch, optional constant deceleration, raised-cosine brake."""

    def __init__(self, t_launch, v_set, a_up, a_brake, t_dec=math.inf, a_dec=0.0, t_jerk=5e-3, v_floor=0.0):
        self.t_launch, self.v_set, self.a_up, self.a_brake = t_launch, v_set, a_up, a_brake
        self.T_a = 2.0 * v_set / a_up if v_set > 0 else 0.0
        self.t_dec, self.a_dec, self.t_jerk = t_dec, a_dec, t_jerk
        # the deceleration stops once the command is down to v_floor
        self.t_dec_end = (t_dec + t_jerk / 2 + (v_set - v_floor) / abs(a_dec)) if a_dec < 0 else math.inf
        self.t_brake = math.inf
        self.v_brake0 = 0.0
        self.T_b = 0.0

    def _base(self, t):
        t = np.asarray(t, dtype=float)
        tau = np.clip(t - self.t_launch, 0.0, self.T_a)
        if self.T_a > 0:
            w = 2 * np.pi / self.T_a
            v = 0.5 * self.a_up * (tau - np.sin(w * tau) / w)
            a = np.where((t > self.t_launch) & (t < self.t_launch + self.T_a), 0.5 * self.a_up * (1 - np.cos(w * tau)),
                         0.0)
        else:
            v, a = np.zeros_like(t), np.zeros_like(t)
        if self.a_dec < 0 and math.isfinite(self.t_dec):
            tj = self.t_jerk
            tau = np.clip(t - self.t_dec, 0.0, self.t_dec_end - self.t_dec)
            ramp = np.where(tau < tj, 0.5 * (tau - np.sin(np.pi * tau / tj) * tj / np.pi), tau - tj / 2)
            v = v + self.a_dec * ramp
            ad = np.where(tau < tj, 0.5 * (1 - np.cos(np.pi * tau / tj)), 1.0)
            a = a + np.where((t > self.t_dec) & (t < self.t_dec_end), self.a_dec * ad, 0.0)
        return v, a

    def trigger_brake(self, t):
        self.t_brake = float(t)
        self.v_brake0 = float(self._base(t)[0])
        self.T_b = 2.0 * self.v_brake0 / self.a_brake if self.v_brake0 > 0 else 0.0

    def __call__(self, t):
        v, a = self._base(t)
        if math.isfinite(self.t_brake):
            t = np.asarray(t, dtype=float)
            after = t >= self.t_brake
            if self.T_b > 0:
                w = 2 * np.pi / self.T_b
                tau = np.clip(t - self.t_brake, 0.0, self.T_b)
                vb = self.v_brake0 - 0.5 * self.a_brake * (tau - np.sin(w * tau) / w)
                ab = np.where(tau < self.T_b, -0.5 * self.a_brake * (1 - np.cos(w * tau)), 0.0)
            else:
                vb, ab = 0.0 * t, 0.0 * t
            v = np.where(after, vb, v)
            a = np.where(after, ab, a)
        return v, a

    def scalar(self, t: float) -> tuple[float, float]:
        """The same profile for one float t (the integrator's fast path)."""
        v = a = 0.0
        if self.T_a > 0 and t > self.t_launch:
            tau = min(t - self.t_launch, self.T_a)
            w = 2 * math.pi / self.T_a
            v = 0.5 * self.a_up * (tau - math.sin(w * tau) / w)
            if tau < self.T_a:
                a = 0.5 * self.a_up * (1 - math.cos(w * tau))
        if self.a_dec < 0 and t > self.t_dec:
            tj = self.t_jerk
            tau = min(t - self.t_dec, self.t_dec_end - self.t_dec)
            v += self.a_dec * (0.5 * (tau - math.sin(math.pi * tau / tj) * tj / math.pi) if tau < tj else tau - tj / 2)
            if t < self.t_dec_end:
                a += self.a_dec * (0.5 * (1 - math.cos(math.pi * tau / tj)) if tau < tj else 1.0)
        if t >= self.t_brake:
            if self.T_b > 0:
                w = 2 * math.pi / self.T_b
                tau = min(t - self.t_brake, self.T_b)
                v = self.v_brake0 - 0.5 * self.a_brake * (tau - math.sin(w * tau) / w)
                a = -0.5 * self.a_brake * (1 - math.cos(w * tau)) if tau < self.T_b else 0.0
            else:
                v = a = 0.0
        return v, a

    def breakpoints(self):
        bp = [self.t_launch, self.t_launch + self.T_a]
        if self.a_dec < 0:
            bp += [self.t_dec, self.t_dec + self.t_jerk, self.t_dec_end]
        if math.isfinite(self.t_brake):
            bp += [self.t_brake + self.T_b]
        return [b for b in bp if math.isfinite(b)]


# ----------------------------------------------------------------------------------------------- the model
# state layout
X3, V3, U1, W1, D2, W2, DM, WM, ET, P, IA, IV, IC = range(13)
Q_SUP, Q_CU, Q_B, Q_CELLS, Q_BODY, Q_PL, Q_DAMP, Q_CUT, Q_FRAC = range(13, 22)
N_STATES = 22
STATE_NAMES = ('x3', 'v3', 'u1', 'w1', 'd2', 'w2', 'dm', 'wm', 'e_tot', 'p', 'i', 'I_v', 'I_c', 'E_supply',
               'E_copper', 'E_carriage_viscous', 'E_cells_viscous', 'E_body_departures', 'E_plastic',
               'E_lanyard_damper', 'E_lanyard_cut', 'E_fracture')


class Model:
    """The coupled pull rig: drive + controller + carriage + [mount] + moving cell + m2 + lanyard/coupon + m1 +
    stationary cell. Body departures are forces in here; nothing is added to a channel afterwards."""

    def __init__(self, rig: Mapping, pull: Mapping, body: Sequence[Mapping] = ()):
        self.rig, self.pull = rig, pull
        g = rig.get
        self.m1 = g('force_chain.stationary_side_mass_kg')
        self.m2 = g('force_chain.moving_side_mass_kg')
        self.body = [dict(b) for b in body]
        for b in self.body:
            if b['name'] == 'effective_mass':
                self.m2 = b['params']['mass_kg']
        self.K1, self.K2 = g('cells.K1_n_per_m'), g('cells.K2_n_per_m')
        self.c1 = 2 * g('cells.zeta_1') * math.sqrt(self.K1 * self.m1)
        self.c2 = 2 * g('cells.zeta_2') * math.sqrt(self.K2 * self.m2)
        self.mount = None
        for b in self.body:
            if b['name'] == 'mount_resonance':
                p = b['params']
                mt = p['base_mass_kg'] + self.m2
                wn = 2 * math.pi * p['frequency_hz']
                self.mount = (p['base_mass_kg'], wn ** 2 * mt, 2 * p['damping_ratio'] * math.sqrt(wn ** 2 * mt * mt))
        self.kF = g('derived.k_F_n_per_a')
        self.Meff = g('derived.M_eff_kg')
        self.b = g('derived.b_n_s_per_m')
        self.Ra, self.La = g('drive.armature_resistance_ohm'), g('drive.armature_inductance_h')
        self.Ke = g('drive.back_emf_constant_v_s_per_rad')
        self.N, self.r = g('drive.gear_ratio'), g('drive.pulley_radius_m')
        self.kappa = g('drive.torque_constant_nm_per_a') / self.Ke
        self.Imax, self.Vmax = g('drive.current_limit_a'), g('drive.voltage_limit_v')
        self.Kpv, self.Kiv = g('control.K_pv'), g('control.K_iv')
        self.Kpi, self.Kii = g('control.K_pi'), g('control.K_ii')
        self.Tawv, self.Tawc, self.fff = g('control.T_aw_v_s'), g('control.T_aw_c_s'), g('control.f_ff')
        self.drive_on = bool(g('drive.enabled', True))
        self.lanyard_on = bool(g('lanyard.enabled', True))
        # lanyard + coupon of this pull
        c = pull['coupon']
        self.KL, self.kc = pull['K_L'], c['k_c']
        self.Ks = self.KL * self.kc / (self.KL + self.kc)
        mu = self.m1 * self.m2 / (self.m1 + self.m2)
        self.cL = 2 * g('force_chain.lanyard_damping_ratio') * math.sqrt(self.Ks * mu)
        self.Fu, self.Fy, self.pf, self.ph, self.eta = c['F_u'], c['y'] * c['F_u'], c['p_f'], c['p_h'], c['eta']
        self.tbr = c['t_br']
        self.s = pull['slack']
        self.t_b0 = math.inf          # break onset (event)
        self.cmd = pull['command'] if isinstance(pull['command'], Command) else Command(**pull['command'])

    # ---- pieces
    def F_flow(self, p):
        return self.Fy + (self.Fu - self.Fy) * (1 - np.exp(-np.maximum(p, 0.0) / self.ph)) / (
            1 - math.exp(-self.pf / self.ph))

    def damage(self, t):
        t = np.asarray(t, dtype=float)
        if not math.isfinite(self.t_b0):
            return np.zeros_like(t), np.zeros_like(t)
        tau = np.clip((t - self.t_b0) / self.tbr, 0.0, 1.0)
        D = 0.5 * (1 - np.cos(np.pi * tau))
        Dd = np.where((tau > 0) & (tau < 1), 0.5 * np.pi / self.tbr * np.sin(np.pi * tau), 0.0)
        return D, Dd

    def alg(self, t, y):
        """Every force, rate and power, for y of shape (22,) or (22, k)."""
        x3, v3, u1, w1, d2, w2, dm, wm, et, p, i, Iv, Ic = (y[k] for k in range(13))
        o = {}
        F1 = self.K1 * u1 + self.c1 * w1
        F2 = self.K2 * d2 + self.c2 * w2
        if self.mount is not None:
            mb, km, cm = self.mount
            Fm = km * dm + cm * wm
        else:
            Fm = F2
        u2dot = v3 - wm - w2
        u2 = x3 - dm - d2
        # lanyard + coupon
        D, Dd = self.damage(t)
        e = et - p
        etdot = u2dot - w1
        if self.lanyard_on:
            T0 = self.Ks * e + self.cL * etdot
            Ff = self.F_flow(p)
            # the flow law keeps running through the damage ramp (choice: SPEC 2.4 stops it at D > 0, which
            # makes T jump by c_L p' at the break onset); D only scales the tension the ligament passes on
            flowing = (e > 0) & (T0 > Ff)
            pdot = np.where(flowing, (T0 - Ff) / (self.eta + self.cL), 0.0)
            edot = etdot - pdot
            Tel = self.Ks * e + self.cL * edot
            taut = (e > 0) & (Tel > 0)
            T = np.where(taut, (1 - D) * Tel, 0.0)
            P_damp = np.where(taut, (1 - D) * self.cL * edot ** 2, 0.0)
            P_cut = np.where((e > 0) & ~taut, -(1 - D) * self.Ks * e * edot, 0.0)
            P_frac = np.where(e > 0, 0.5 * self.Ks * e ** 2 * Dd, 0.0)
            U_L = np.where(e > 0, (1 - D) * 0.5 * self.Ks * e ** 2, 0.0)
        else:
            z = 0.0 * x3
            pdot = edot = T = P_damp = P_cut = P_frac = U_L = z
        # body departures
        Fcar = 0.0 * x3
        Fm2 = 0.0 * x3
        Pbody = 0.0 * x3
        Ucab = 0.0 * x3
        for bd in self.body:
            n, q = bd['name'], bd['params']
            on_m2 = bd.get('body') == 'm2'
            if n == 'coulomb_friction':
                f = -q['force_n'] * np.tanh(v3 / VS_FRICTION)
                Fcar = Fcar + f
                Pbody = Pbody - f * v3
            elif n == 'aero_drag':
                f = -q['C_d'] * v3 * np.abs(v3)
                Fcar = Fcar + f
                Pbody = Pbody - f * v3
            elif n == 'viscous_guide':
                vv = u2dot if on_m2 else v3
                f = -q['c_g'] * vv
                if on_m2:
                    Fm2 = Fm2 + f
                else:
                    Fcar = Fcar + f
                Pbody = Pbody - f * vv
            elif n == 'cable_force':
                xx = u2 if on_m2 else x3
                stretch = np.maximum(xx - q['x_a'], 0.0)
                f = -(q['F_0'] + q['k_b'] * stretch)
                if on_m2:
                    Fm2 = Fm2 + f
                else:
                    Fcar = Fcar + f
                Ucab = Ucab + q['F_0'] * xx + 0.5 * q['k_b'] * stretch ** 2
            elif n == 'binding_rail':
                spot = q.get('B', 0.0) * np.exp(-((x3 - q.get('x_s', 0.0)) / q.get('w', 1.0)) ** 2)
                f = -np.tanh(v3 / VS_FRICTION) * (q['mu_b'] * np.abs(Fm) + spot)
                Fcar = Fcar + f
                Pbody = Pbody - f * v3
        # bodies
        a1 = (T - F1) / self.m1
        a2 = (F2 - T + Fm2) / self.m2
        vc, ac = self.cmd(t)
        if self.drive_on:
            ev = vc - v3
            iu = self.Kpv * ev + Iv + self.fff * self.Meff * ac / self.kF
            ist = np.clip(iu, -self.Imax, self.Imax)
            Ivdot = self.Kiv * ev + (ist - iu) / self.Tawv
            wmot = self.N * v3 / self.r
            Vu = self.Kpi * (ist - i) + Ic + self.Ke * wmot
            V = np.clip(Vu, -self.Vmax, self.Vmax)
            Icdot = self.Kii * (ist - i) + (V - Vu) / self.Tawc
            idot = (V - self.Ra * i - self.Ke * wmot) / self.La
            a3 = (self.kF * i - self.b * v3 - Fm + Fcar) / self.Meff
        else:
            z = 0.0 * x3
            ist = Ivdot = V = Icdot = idot = a3 = z
        if self.mount is not None:
            xbdd = (Fm - F2) / self.mount[0]
        else:
            xbdd = a3
        o.update(F1=F1, F2=F2, Fm=Fm, T=T, a1=a1, a2=a2, a3=a3, xbdd=xbdd, u2dot=u2dot, u2=u2, e=e, edot=edot,
                 pdot=pdot, D=D, V=V, i_star=ist, Ivdot=Ivdot, Icdot=Icdot, idot=idot, vcmd=vc, acmd=ac,
                 Fcar=Fcar, Fm2=Fm2, Pbody=Pbody, Ucab=Ucab, P_damp=P_damp, P_cut=P_cut, P_frac=P_frac, U_L=U_L)
        return o

    def rhs_scalar(self, t: float, y) -> np.ndarray:
        """rhs for one state vector, in plain floats (the same physics as alg; a test checks they agree)."""
        x3, v3, u1, w1, d2, w2, dm, wm, et, p, i, Iv, Ic = y[:13].tolist()
        F1 = self.K1 * u1 + self.c1 * w1
        F2 = self.K2 * d2 + self.c2 * w2
        mount = self.mount
        Fm = mount[1] * dm + mount[2] * wm if mount is not None else F2
        u2dot = v3 - wm - w2
        u2 = x3 - dm - d2
        D = Dd = 0.0
        if t > self.t_b0:
            tau = min((t - self.t_b0) / self.tbr, 1.0)
            D = 0.5 * (1 - math.cos(math.pi * tau))
            Dd = 0.5 * math.pi / self.tbr * math.sin(math.pi * tau) if tau < 1 else 0.0
        e = et - p
        etdot = u2dot - w1
        T = pdot = P_damp = P_cut = P_frac = 0.0
        if self.lanyard_on and e > 0:
            T0 = self.Ks * e + self.cL * etdot
            # flow through the damage ramp too (see alg)
            Ff = self.Fy + (self.Fu - self.Fy) * (1 - math.exp(-max(p, 0.0) / self.ph)) / (
                1 - math.exp(-self.pf / self.ph))
            if T0 > Ff:
                pdot = (T0 - Ff) / (self.eta + self.cL)
            edot = etdot - pdot
            Tel = self.Ks * e + self.cL * edot
            if Tel > 0:
                T = (1 - D) * Tel
                P_damp = (1 - D) * self.cL * edot * edot
            else:
                P_cut = -(1 - D) * self.Ks * e * edot
            P_frac = 0.5 * self.Ks * e * e * Dd
        Fcar = Fm2 = Pbody = 0.0
        for bd in self.body:
            n, q = bd['name'], bd['params']
            on_m2 = bd.get('body') == 'm2'
            if n == 'coulomb_friction':
                f = -q['force_n'] * math.tanh(v3 / VS_FRICTION)
                Fcar += f
                Pbody -= f * v3
            elif n == 'aero_drag':
                f = -q['C_d'] * v3 * abs(v3)
                Fcar += f
                Pbody -= f * v3
            elif n == 'viscous_guide':
                vv = u2dot if on_m2 else v3
                f = -q['c_g'] * vv
                if on_m2:
                    Fm2 += f
                else:
                    Fcar += f
                Pbody -= f * vv
            elif n == 'cable_force':
                xx = u2 if on_m2 else x3
                f = -(q['F_0'] + q['k_b'] * max(xx - q['x_a'], 0.0))
                if on_m2:
                    Fm2 += f
                else:
                    Fcar += f
            elif n == 'binding_rail':
                spot = q.get('B', 0.0) * math.exp(-((x3 - q.get('x_s', 0.0)) / q.get('w', 1.0)) ** 2)
                f = -math.tanh(v3 / VS_FRICTION) * (q['mu_b'] * abs(Fm) + spot)
                Fcar += f
                Pbody -= f * v3
        a1 = (T - F1) / self.m1
        a2 = (F2 - T + Fm2) / self.m2
        V = Ivdot = Icdot = idot = a3 = 0.0
        if self.drive_on:
            vc, ac = self.cmd.scalar(t)
            ev = vc - v3
            iu = self.Kpv * ev + Iv + self.fff * self.Meff * ac / self.kF
            ist = min(max(iu, -self.Imax), self.Imax)
            Ivdot = self.Kiv * ev + (ist - iu) / self.Tawv
            wmot = self.N * v3 / self.r
            Vu = self.Kpi * (ist - i) + Ic + self.Ke * wmot
            V = min(max(Vu, -self.Vmax), self.Vmax)
            Icdot = self.Kii * (ist - i) + (V - Vu) / self.Tawc
            idot = (V - self.Ra * i - self.Ke * wmot) / self.La
            a3 = (self.kF * i - self.b * v3 - Fm + Fcar) / self.Meff
        xbdd = (Fm - F2) / mount[0] if mount is not None else a3
        return np.array([
            v3 if self.drive_on else 0.0, a3, w1, a1, w2, xbdd - a2,
            wm if mount is not None else 0.0, a3 - xbdd if mount is not None else 0.0,
            u2dot - w1, pdot, idot, Ivdot, Icdot,
            self.kappa * V * i, self.kappa * self.Ra * i * i, self.b * v3 * v3,
            self.c1 * w1 * w1 + self.c2 * w2 * w2 + (mount[2] * wm * wm if mount is not None else 0.0),
            Pbody, T * pdot, P_damp, P_cut, P_frac])

    def rhs(self, t, y):
        if np.ndim(t) == 0:
            if np.ndim(y) == 1:
                return self.rhs_scalar(float(t), y)
            if y.shape[1] == 1:      # solve_ivp(vectorized=True) passes single states as (n, 1)
                return self.rhs_scalar(float(t), y[:, 0])[:, None]
        return self.rhs_vec(t, y)

    def rhs_vec(self, t, y):
        o = self.alg(t, y)
        v3, w1, w2, wm, i = y[V3], y[W1], y[W2], y[WM], y[IA]
        dy = [v3, o['a3'], w1, o['a1'], w2, o['xbdd'] - o['a2'], wm, o['a3'] - o['xbdd'],
              o['u2dot'] - w1, o['pdot'], o['idot'], o['Ivdot'], o['Icdot'],
              self.kappa * o['V'] * i, self.kappa * self.Ra * i ** 2, self.b * v3 ** 2,
              self.c1 * w1 ** 2 + self.c2 * w2 ** 2 + (self.mount[2] * wm ** 2 if self.mount else 0.0 * wm),
              o['Pbody'], o['T'] * o['pdot'], o['P_damp'], o['P_cut'], o['P_frac']]
        if self.mount is None:      # frozen mount states
            dy[DM] = 0.0 * wm
            dy[WM] = 0.0 * wm
        if not self.drive_on:
            dy[X3] = 0.0 * v3
            dy[V3] = 0.0 * v3
        out = np.empty((N_STATES,) + np.shape(v3))
        for k, d in enumerate(dy):
            out[k] = d
        return out

    def jac(self, t, y) -> np.ndarray:
        """Forward-difference Jacobian with fixed steps scaled by each state's tolerance (one vectorised call)."""
        y = np.asarray(y, dtype=float).ravel()
        f0 = self.rhs_scalar(float(t), y)
        hk = 1e-7 * np.maximum(np.abs(y), self.atol() * 1e4)
        Y = y[:, None] + np.diag(hk)
        return (self.rhs_vec(np.float64(t), Y) - f0[:, None]) / hk[None, :]

    def stored_energy(self, t, y):
        o = self.alg(t, y)
        v3, w1 = y[V3], y[W1]
        ke = 0.5 * self.m1 * w1 ** 2 + 0.5 * self.m2 * o['u2dot'] ** 2 + 0.5 * self.Meff * v3 ** 2
        pe = 0.5 * self.K1 * y[U1] ** 2 + 0.5 * self.K2 * y[D2] ** 2 + o['U_L'] + o['Ucab']
        if self.mount is not None:
            ke = ke + 0.5 * self.mount[0] * (v3 - y[WM]) ** 2
            pe = pe + 0.5 * self.mount[1] * y[DM] ** 2
        mag = self.kappa * 0.5 * self.La * y[IA] ** 2
        return ke + pe + mag

    def equilibrium(self, initial: Mapping | None = None) -> np.ndarray:
        """Rest at t = 0 with v_cmd = 0: every state at equilibrium, lanyard slack."""
        y = np.zeros(N_STATES)
        y[ET] = -self.s
        free = [V3, U1, W1, D2, W2, DM, WM, IA, IV, IC]
        eqs = [X3, V3, U1, W1, D2, W2, DM, WM, IA, IC]
        for _ in range(6):
            f0 = self.rhs(0.0, y)[eqs]
            J = np.zeros((len(eqs), len(free)))
            for j, k in enumerate(free):
                hk = 1e-9 * max(1.0, abs(y[k]))
                yp = y.copy()
                yp[k] += hk
                J[:, j] = (self.rhs(0.0, yp)[eqs] - f0) / hk
            dx = np.linalg.lstsq(J, -f0, rcond=None)[0]
            y[free] += dx
            if np.max(np.abs(dx)) < 1e-16:
                break
        for k, v in (initial or {}).items():
            y[STATE_NAMES.index(k)] += v
        return y

    def atol(self) -> np.ndarray:
        a = np.empty(N_STATES)
        fa = 1e-3                                           # newtons of cell force
        w1 = math.sqrt(self.K1 / self.m1)
        w2 = math.sqrt(self.K2 / self.m2)
        a[X3], a[V3] = 1e-8, 1e-7
        a[U1], a[W1] = fa / self.K1, fa / self.K1 * w1
        a[D2], a[W2] = fa / self.K2, fa / self.K2 * w2
        km = self.mount[1] if self.mount else self.K2
        a[DM], a[WM] = fa / km, fa / km * w2
        a[ET], a[P] = fa / self.Ks, fa / self.Ks
        a[IA], a[IV], a[IC] = 1e-5, 1e-5, 1e-4
        a[13:] = 1e-4
        return a


class Solution:
    """The piecewise dense solution (one OdeSolution per segment)."""

    def __init__(self):
        self.segs: list = []
        self.t_ends: list = []

    def add(self, sol, t1):
        self.segs.append(sol)
        self.t_ends.append(t1)

    def __call__(self, t):
        t = np.atleast_1d(np.asarray(t, dtype=float))
        out = np.empty((N_STATES, t.size))
        idx = np.searchsorted(np.asarray(self.t_ends), t, side='left')
        idx = np.minimum(idx, len(self.segs) - 1)
        for k in np.unique(idx):
            m = idx == k
            out[:, m] = self.segs[k](t[m])
        return out


def integrate(model: Model, t_end: float, y0: np.ndarray | None = None, rtol: float = 1e-7,
              brake: Mapping | None = None, max_step: float = math.inf) -> tuple[Solution, dict]:
    """Integrate the record [0, t_end]. brake = {'x': x3 trigger} or {'T': tension trigger}."""
    y = model.equilibrium() if y0 is None else np.array(y0, dtype=float)
    sol = Solution()
    ev = {'t_taut': math.nan, 't_break': math.nan, 't_brake': math.nan, 'n_steps': 0, 'nfev': 0}
    atol = model.atol()
    t = 0.0

    def taut_event(tt, yy):
        return yy[ET] - yy[P]
    taut_event.terminal, taut_event.direction = True, 1

    def break_event(tt, yy):
        return yy[P] - model.pf
    break_event.terminal, break_event.direction = True, 1

    def brake_event(tt, yy):
        if brake and 'T' in brake:
            return float(model.alg(tt, yy)['T']) - brake['T']
        return yy[X3] - (brake['x'] if brake else math.inf)
    brake_event.terminal, brake_event.direction = True, 1

    fun = model.rhs
    guard = 0
    while t < t_end - 1e-12:
        guard += 1
        if guard > 200:
            raise RuntimeError('too many segments')
        bps = [b for b in model.cmd.breakpoints() if b > t + 1e-12]
        if math.isfinite(model.t_b0):
            bps.append(model.t_b0 + model.tbr)
        t1 = min([t_end] + [b for b in bps if b > t + 1e-12])
        events = []
        if model.lanyard_on and math.isnan(ev['t_taut']):
            events.append(taut_event)
        if model.lanyard_on and not math.isfinite(model.t_b0):
            events.append(break_event)
        if brake and math.isnan(ev['t_brake']):
            events.append(brake_event)
        ms = max_step
        if math.isfinite(model.t_b0) and t < model.t_b0 + model.tbr:
            ms = min(ms, model.tbr / 8)
        r = solve_ivp(fun, (t, t1), y, method='Radau', rtol=rtol, atol=atol, dense_output=True, jac=model.jac,
                      events=events or None, vectorized=True, max_step=ms)
        if r.status < 0:
            raise RuntimeError(f'integration failed at t={r.t[-1]}: {r.message}')
        ev['n_steps'] += len(r.t) - 1
        ev['nfev'] += r.nfev
        t_stop = r.t[-1]
        sol.add(r.sol, t_stop)
        y = r.y[:, -1].copy()
        if r.status == 1:
            for e_fun, te in zip(events, r.t_events):
                if len(te) and abs(te[0] - t_stop) < 1e-12:
                    if e_fun is taut_event:
                        ev['t_taut'] = float(t_stop)
                        # start the taut branch on its own side (1e-12 m, a micro-newton): the damper's force
                        # jumps at e = 0, and Newton needs the taut branch's Jacobian
                        y[ET] = max(y[ET], y[P] + 1e-12)
                    elif e_fun is break_event:
                        model.t_b0 = float(t_stop)
                        ev['t_break'] = float(t_stop)
                    elif e_fun is brake_event:
                        model.cmd.trigger_brake(t_stop)
                        ev['t_brake'] = float(t_stop)
        t = t_stop
    return sol, ev


# ----------------------------------------------------------------------------------------------- a pull
def _slack_window(rig, v, a_up, a_br, t_launch, d_hold, t_rec, decel):
    """The admissible slack interval (SPEC 3.2 step 3) for a cruise at v."""
    x_launch = v * v / a_up                   # raised-cosine launch: distance v T_a / 2
    t_a = 2 * v / a_up
    cruise = min(0.05, 0.1 * v)               # at least 0.1 s or 50 mm of cruise, whichever is shorter
    lo = x_launch + cruise
    lo = max(lo, x_launch + (0.5 - t_launch - t_a) * v)         # taut at or after 0.5 s
    v_min = 0.25 * v if decel else v
    t_after = d_hold / v_min + 2 * v / a_br + 0.2 + 0.05        # hold travel, stop, 0.2 s margin
    hi_t = min(1.2, t_rec - t_after)
    hi = x_launch + (hi_t - t_launch - t_a) * v
    hi = min(hi, rig['drive.usable_track_m'] - d_hold - v * v / a_br - 0.05)
    return lo, hi


def draw_pull(seed: int, rig: Mapping, set_no: int, pull_no: int, attempt: int = 0) -> dict:
    """A pull's draws: they depend only on (seed, set, pull, attempt)."""
    lbf, fps, decel_g, _fu, _a2, _yr, _pfr, _tbr = PULL_SETS[set_no]
    for sub in range(100):
        r = _rng(seed, 1, set_no, pull_no, attempt, sub)
        v = fps * FT_M * (1 + _nclip(r, 0.01))
        a_hi = min(60.0, rig['derived.a_max_m_s2'] / 1.5)
        a_up = _u(r, 30.0, a_hi)
        a_br = _u(r, 30.0, a_hi)
        t_launch = _u(r, 0.2, 0.4)
        c = f'coupon.{set_no}.'
        F_u = rig[c + 'F_u_n'] * (1 + _nclip(r, 0.03))
        p_f = rig[c + 'p_f_m'] * (1 + _nclip(r, 0.10))
        k_c = rig[c + 'k_c_n_per_m'] * (1 + _nclip(r, 0.10))
        K_L = rig['force_chain.lanyard_stiffness_n_per_m'] * (1 + _nclip(r, 0.05))
        t_br = _lu(r, rig[c + 't_br_min_s'], rig[c + 't_br_max_s'])
        y = rig[c + 'y']
        eta = rig[c + 'eta_fraction'] * F_u / (fps * FT_M)
        Ks = K_L * k_c / (K_L + k_c)
        d_hold = max(_u(r, 0.04, 0.10), 1.1 * F_u / Ks + p_f + 0.02)
        decel = decel_g < 0
        lo, hi = _slack_window(rig, v, a_up, a_br, t_launch, d_hold, rig['daq.record_length_s'], decel)
        if hi <= lo + 0.01:
            continue
        s = lo + (hi - lo) * rig[c + 'slack_u'] + _nclip(r, 0.002)
        s = float(np.clip(s, lo, hi))
        cmd = {'t_launch': t_launch, 'v_set': v, 'a_up': a_up, 'a_brake': a_br}
        lead = _u(r, 0.010, 0.030)
        a_dec = decel_g * G * (1 + _nclip(r, 0.05)) if decel else 0.0
        if decel:
            t_taut_exp = t_launch + 2 * v / a_up + (s - v * v / a_up) / v
            cmd.update(t_dec=t_taut_exp - lead, a_dec=a_dec, v_floor=0.25 * v)
        return {'set': set_no, 'pull': pull_no, 'attempt': attempt, 'command': cmd, 'slack': s, 'd_hold': d_hold,
                'K_L': K_L, 'lead_s': lead if decel else None,
                'coupon': {'F_u': F_u, 'y': y, 'p_f': p_f, 'p_h': p_f * rig[c + 'p_h_ratio'], 'k_c': k_c, 'eta': eta,
                           't_br': t_br}}
    raise RuntimeError(f'no admissible pull for set {set_no}')


# ----------------------------------------------------------------------------------------------- fine grid
def fine_factor(fs: float) -> int:
    """Fine-grid oversampling (>= 8 fs): 16 up to 25 kHz, 12 up to 50 kHz, 8 above (memory)."""
    return 16 if fs <= 25e3 else (12 if fs <= 50e3 else 8)


def foh_sos(b, a, h: float) -> np.ndarray:
    """A continuous transfer function, discretised with a first-order hold at step h, as second-order sections."""
    z, p, k = signal.tf2zpk(b, a)
    w0 = float(np.exp(np.mean(np.log(np.abs(p))))) if len(p) else 1.0     # work in time scaled by w0: O(1) numbers
    z, p, k = z / w0, p / w0, k * w0 ** (len(z) - len(p))
    A, B, C, D = signal.zpk2ss(z, p, k)
    Ad, Bd, Cd, Dd, _ = signal.cont2discrete((A, B, C, D), h * w0, method='foh')
    z, p, k = signal.ss2zpk(Ad, Bd, Cd, Dd)
    return signal.zpk2sos(z, p, k)


def run_sos(sos: np.ndarray, x: np.ndarray, steady: bool = True) -> np.ndarray:
    """Filter on the fine grid, starting in steady state for the first value (a rest at t = 0)."""
    zi = signal.sosfilt_zi(sos) * x[0] if steady else np.zeros((sos.shape[0], 2))
    return signal.sosfilt(sos, x, zi=zi)[0]


def aa_design(kind: str, order: int, fc: float):
    wc = 2 * math.pi * fc
    if kind == 'butterworth':
        return signal.butter(order, wc, analog=True)
    return signal.bessel(order, wc, analog=True, norm='mag')


def aa_group_delay(kind: str, order: int, fc: float) -> float:
    b, a = aa_design(kind, order, fc)
    w = np.array([1e-4, 2e-4]) * 2 * math.pi * fc
    _, hh = signal.freqs(b, a, worN=w)
    ph = np.unwrap(np.angle(hh))
    return float(-(ph[1] - ph[0]) / (w[1] - w[0]))


def interp4(y: np.ndarray, h: float, t: np.ndarray) -> np.ndarray:
    """4-point (cubic Lagrange) interpolation of a uniform fine-grid signal at instants t."""
    u = t / h
    j = np.clip(np.floor(u).astype(np.int64), 1, len(y) - 3)
    f = u - j
    ym1, y0, y1, y2 = y[j - 1], y[j], y[j + 1], y[j + 2]
    return (-f * (f - 1) * (f - 2) / 6 * ym1 + (f + 1) * (f - 1) * (f - 2) / 2 * y0
            - (f + 1) * f * (f - 2) / 2 * y1 + (f + 1) * f * (f - 1) / 6 * y2)


def bandlimited_noise(rng: np.random.Generator, n: int, h: float, f_lo: float, f_hi: float) -> np.ndarray:
    """Unit-rms Gaussian noise, band-limited to [f_lo, f_hi] by an FFT mask."""
    x = rng.standard_normal(n)
    X = np.fft.rfft(x)
    f = np.fft.rfftfreq(n, h)
    X[(f < f_lo) | (f > f_hi)] = 0.0
    y = np.fft.irfft(X, n)
    return y / (np.sqrt(np.mean(y ** 2)) + 1e-300)


def simulate(rig: Mapping, pull: Mapping, body: Sequence[Mapping] = (), *, t_end: float | None = None,
             fs: float | None = None, seed: int = 0, brake: Mapping | None = 'auto', initial: Mapping | None = None,
             rtol: float = 1e-7, clean_only: bool = False) -> dict:
    """One record: integrate, then the clean signals on the fine grid (h = 1 / (F fs))."""
    model = Model(rig, pull, body)
    fs = fs or rig['daq.sample_rate_hz']
    L = t_end or rig['daq.record_length_s']
    t_sim = L * (1 + 2e-4) + 2e-4
    if brake == 'auto':
        brake = {'x': pull['slack'] + pull['d_hold']}
    y0 = model.equilibrium(initial)
    sol, ev = integrate(model, t_sim, y0=y0, rtol=rtol, brake=brake)
    F = fine_factor(fs)
    h = 1.0 / (F * fs)
    n_f = int(math.floor(t_sim / h))
    t_f = np.arange(n_f) * h
    names = ('F1', 'F2', 'T', 'a1', 'a2', 'a3', 'V', 'vcmd', 'D', 'u2dot')
    clean = {k: np.empty(n_f) for k in names + ('v', 'x', 'i', 'p')}
    for c0 in range(0, n_f, 200_000):
        tt = t_f[c0:c0 + 200_000]
        Y = sol(tt)
        o = model.alg(tt, Y)
        for k in names:
            clean[k][c0:c0 + tt.size] = o[k]
        clean['v'][c0:c0 + tt.size] = Y[V3]
        clean['x'][c0:c0 + tt.size] = Y[X3]
        clean['i'][c0:c0 + tt.size] = Y[IA]
        clean['p'][c0:c0 + tt.size] = Y[P]
    # transverse modes (one-way: driven by T sin(phi) and by the rail roughness, no feed-back)
    m2 = model.m2
    if rig.get('transverse.enabled', True) and not clean_only:
        r = _rng(seed, 7, pull.get('set', 0), pull.get('pull', 0), pull.get('attempt', 0))
        for ax in ('y', 'z'):
            wn = 2 * math.pi * rig[f'transverse.f_{ax}_hz']
            zt = rig[f'transverse.zeta_{ax}']
            base = rig['transverse.q'] * np.abs(clean['v']) * bandlimited_noise(r, n_f, h, 50.0, 2000.0)
            u = clean['T'] * math.sin(rig[f'transverse.phi_{ax}_rad']) / m2 - base
            sos = foh_sos([m2 * 2 * zt * wn, m2 * wn ** 2], [1.0, 2 * zt * wn, wn ** 2], h)
            fperp = run_sos(sos, u, steady=False)
            clean[f'Fperp_{ax}'] = fperp
            clean[f'a{ax}'] = clean['T'] * math.sin(rig[f'transverse.phi_{ax}_rad']) / m2 - fperp / m2
    else:
        for ax in ('y', 'z'):
            clean[f'Fperp_{ax}'] = np.zeros(n_f)
            clean[f'a{ax}'] = np.zeros(n_f)
    return {'model': model, 'sol': sol, 'events': ev, 't_f': t_f, 'h': h, 'fs': fs, 'L': L, 'clean': clean}


# ----------------------------------------------------------------------------------------------- departures
_CH_KIND = {'force_moving_n': 'force', 'force_stationary_n': 'force', 'accel_axial_m_s2': 'accel',
            'accel_lateral_m_s2': 'accel', 'accel_vertical_m_s2': 'accel', 'motor_current_a': 'current',
            'motor_voltage_v': 'voltage'}
_TERM_SIG = {'force_moving_n': 'F_move', 'force_stationary_n': 'F_stat', 'accel_axial_m_s2': 'a2'}


def _draw_departure(name: str, r: np.random.Generator, rig: Mapping, given: Mapping | None = None) -> dict:
    """One departure instance with its parameters (explicit ones in ``given`` win) and its truth fields."""
    g = dict(given or {})
    q = dict(g.get('params', {}))
    for k, v in g.items():
        if k not in ('name', 'channel', 'body', 'form', 'params', 'list'):
            q[k] = v
    m2 = rig['force_chain.moving_side_mass_kg']
    kF = rig['derived.k_F_n_per_a']
    inst = {'name': name, 'list': 'catalog' if name in CATALOG else 'beyond', 'catalog': None, 'terms': 'none',
            'exact': False, 'note': ''}
    ch = g.get('channel')
    ch = SHORT.get(ch, ch)
    form = g.get('form')
    body = g.get('body')

    def dflt(key, fn):
        if key not in q:
            q[key] = fn()
        return q[key]

    if name == 'effective_mass':
        eps = _pm(r, 0.05, 0.40)
        dflt('mass_kg', lambda: m2 * (1 + eps))
        inst.update(acts_on='body:m2', catalog={'name': name, 'params': {'mass_kg': q['mass_kg']}})
    elif name == 'mount_resonance':
        dflt('frequency_hz', lambda: _lu(r, 500.0, 3000.0))
        dflt('damping_ratio', lambda: _lu(r, 0.005, 0.05))
        dflt('base_mass_kg', lambda: _u(r, 0.1, 0.5) * m2)
        inst.update(acts_on='body:mount', catalog={'name': name, 'params': {k: q[k] for k in (
            'frequency_hz', 'damping_ratio', 'base_mass_kg')}})
    elif name == 'accel_delay':
        ch = 'accel_axial_m_s2'
        form = form or ('shift' if r.random() < 0.5 else 'bessel2')
        dflt('delay_s', lambda: _lu(r, 10e-6, 80e-6))
        inst.update(acts_on='sensor:accel_axial', catalog={'name': name, 'params': {'delay_s': q['delay_s']}},
                    exact=form == 'shift')
    elif name == 'moving_cell_gain':
        ch = 'force_moving_n'
        dflt('gain', lambda: 1 + _pm(r, 0.01, 0.03))
        inst.update(acts_on='sensor:force_moving', catalog={'name': name, 'params': {'gain': q['gain']}},
                    terms=[{'channel': 'force_moving', 'term': 'F_move', 'coefficient': q['gain'] - 1}], exact=True)
    elif name == 'ac_coupling':
        ch = ch or ('force_moving_n' if r.random() < 0.7 else str(r.choice(list(ANALOG))))
        dflt('time_constant_s', lambda: _lu(r, 0.5, 20.0))
        inst.update(acts_on=f'conditioner:{LONG2SHORT[ch]}')
        if ch == 'force_moving_n':
            inst['catalog'] = {'name': name, 'params': {'time_constant_s': q['time_constant_s']}}
    elif name == 'mains_hum':
        ch = 'force_moving_n'
        dflt('frequency_hz', lambda: 50.0 if r.random() < 0.5 else 60.0)
        dflt('amplitude_n', lambda: _lu(r, 1.0, 10.0))
        inst.update(acts_on='conditioner:force_moving', exact=True,
                    catalog={'name': name,
                             'params': {'frequency_hz': q['frequency_hz'], 'amplitude_n': q['amplitude_n']}},
                    terms=[{'channel': 'force_moving', 'term': 'sin', 'coefficient': q['amplitude_n'],
                            'frequency_hz': q['frequency_hz']}])
    elif name == 'coulomb_friction':
        body = 'carriage'
        dflt('force_n', lambda: _lu(r, 40.0, 400.0))
        inst.update(acts_on='body:carriage', catalog={'name': name, 'params': {'force_n': q['force_n']}})
    elif name in ('nonlinearity_even', 'nonlinearity_odd'):
        ch = ch or str(r.choice(['force_moving_n', 'force_stationary_n', 'accel_axial_m_s2']))
        ref = A_FS if ch == 'accel_axial_m_s2' else F_FS
        eps = _pm(r, 0.002, 0.02, log=True)
        if name == 'nonlinearity_even':
            dflt('c2', lambda: eps / ref)
            term, coef = f'{_TERM_SIG[ch]}^2', q['c2']
        else:
            dflt('c3', lambda: eps / ref ** 2)
            term, coef = f'{_TERM_SIG[ch]}^3', q['c3']
        inst.update(acts_on=f'sensor:{LONG2SHORT[ch]}', exact=True,
                    terms=[{'channel': LONG2SHORT[ch], 'term': term, 'coefficient': coef}])
    elif name == 'gain_drift':
        ch = ch or ('force_moving_n' if r.random() < 0.7 else 'force_stationary_n')
        form = form or str(r.choice(['linear', 'thermal', 'campaign']))
        sig = _TERM_SIG[ch]
        inst['acts_on'] = f'sensor:{LONG2SHORT[ch]}'
        if form == 'linear':
            dflt('kappa_per_s', lambda: _pm(r, 0.001, 0.02, log=True))
            inst.update(exact=True, terms=[{'channel': LONG2SHORT[ch], 'term': f'{sig}*t',
                                            'coefficient': q['kappa_per_s']}])
        elif form == 'thermal':
            dflt('alpha_dT', lambda: _pm(r, 0.002, 0.03, log=True))
            dflt('tau_T_s', lambda: _lu(r, 2.0, 30.0))
            dflt('t_on_fraction', lambda: _u(r, 0.0, 1.0))
            inst.update(exact=False, terms=[{'channel': LONG2SHORT[ch], 'term': f'{sig}*t',
                                             'coefficient': q['alpha_dT'] / q['tau_T_s']}],
                        note='slope at t_on; t_on = t_on_fraction * t_launch per pull (pulls[].t_on_s)')
        else:
            dflt('lambda_per_pull', lambda: _pm(r, 0.0002, 0.002, log=True))
            inst.update(note='per pull: pulls[].catalog moving_cell_gain {gain: g_k}, k = pull index in its set')
    elif name == 'zero_drift':
        ch = ch or str(r.choice([c for c in ANALOG]))
        kind = _CH_KIND[ch]
        lo, hi = {'force': (2.0, 40.0), 'accel': (1.0, 20.0), 'current': (0.02, 0.5), 'voltage': (0.05, 1.0)}[kind]
        dflt('z1', lambda: _pm(r, lo, hi, log=True))
        dflt('z2', lambda: 0.0 if r.random() < 0.5 else _pm(r, 1e-3, 1.0) * abs(q['z1']))
        dflt('t_d_mode', lambda: 'launch' if r.random() < 0.5 else 'uniform')
        inst.update(acts_on=f'conditioner:{LONG2SHORT[ch]}', exact=q['t_d_mode'] == 'zero' and q['z2'] == 0,
                    note='t_d per pull (pulls[].t_d_s): exact only when t_d = 0 and z2 = 0')
        if LONG2SHORT[ch] in GRAMMAR_CHANNELS:
            inst['terms'] = [{'channel': LONG2SHORT[ch], 'term': 't', 'coefficient': q['z1']}]
    elif name == 'line_pickup':
        ch = ch or str(r.choice([c for c in ANALOG]))
        form = form or str(r.choice(['mains_harmonic', 'line', 'speed', 'pwm']))
        kind = _CH_KIND[ch]
        alo, ahi = {'force': (0.5, 10.0), 'accel': (0.3, 5.0), 'current': (0.05, 1.0), 'voltage': (0.1, 2.0)}[kind]
        if form == 'mains_harmonic':
            dflt('frequency_hz', lambda: int(r.integers(2, 6)) * (50.0 if r.random() < 0.5 else 60.0))
        elif form == 'pwm':
            dflt('frequency_hz', lambda: _u(r, 8e3, 20e3))
        else:
            dflt('frequency_hz', lambda: _lu(r, 100.0, 5000.0))
        if form == 'speed':
            klo, khi = {'force': (1.0, 10.0), 'accel': (0.5, 5.0), 'current': (0.01, 0.1), 'voltage': (0.05, 1.0)}[kind]
            dflt('k_v', lambda: _lu(r, klo, khi))
        else:
            dflt('amplitude', lambda: _lu(r, alo, ahi))
        inst['acts_on'] = f'conditioner:{LONG2SHORT[ch]}'
        if LONG2SHORT[ch] in GRAMMAR_CHANNELS and form in ('mains_harmonic', 'line'):
            inst.update(exact=True, terms=[{'channel': LONG2SHORT[ch], 'term': 'sin', 'coefficient': q['amplitude'],
                                            'frequency_hz': q['frequency_hz']}])
        elif LONG2SHORT[ch] in GRAMMAR_CHANNELS and form == 'speed':
            inst.update(exact=True, terms=[{'channel': LONG2SHORT[ch], 'term': 'v*sin', 'coefficient': q['k_v'],
                                            'frequency_hz': q['frequency_hz']}],
                        note='amplitude k_v |v|: equals v*sin while the carriage moves forward')
        if form == 'pwm':
            inst['note'] = 'amplitude = amplitude * |i| / I_max; aliases when fs/2 is below it'
    elif name == 'sensor_resonance':
        ch = ch or ('accel_axial_m_s2' if r.random() < 0.7 else str(r.choice(['force_moving_n', 'force_stationary_n'])))
        if ch == 'accel_axial_m_s2':
            dflt('f_r_hz', lambda: _lu(r, 4e3, 30e3))
            dflt('zeta_r', lambda: _lu(r, 0.02, 0.1))
        else:
            dflt('f_r_hz', lambda: _lu(r, 10e3, 60e3))
            dflt('zeta_r', lambda: _lu(r, 0.02, 0.1) if r.random() < 0.5 else _u(r, 0.3, 0.7))
        wr = 2 * math.pi * q['f_r_hz']
        _, h1k = signal.freqs([wr ** 2], [1, 2 * q['zeta_r'] * wr, wr ** 2], worN=[2 * math.pi * 1000.0])
        q['lf_delay_s'] = 2 * q['zeta_r'] / wr
        q['gain_at_1khz'] = float(abs(h1k[0]))
        inst.update(acts_on=f'sensor:{LONG2SHORT[ch]}', note='nearest catalog description: accel_delay (approximate)')
    elif name == 'cross_axis':
        ch = ch or ('accel_axial_m_s2' if r.random() < 0.6 else 'force_moving_n')
        if ch == 'accel_axial_m_s2':
            dflt('s_y', lambda: _pm(r, 0.01, 0.05))
            dflt('s_z', lambda: _pm(r, 0.01, 0.05))
        else:
            dflt('s_F', lambda: _pm(r, 0.01, 0.05))
            dflt('psi_rad', lambda: _u(r, 0.0, 2 * math.pi))
        inst.update(acts_on=f'sensor:{LONG2SHORT[ch]}', note='pulls[].transverse_rms: rms of the transverse signal '
                                                             'between taut and break')
    elif name == 'aero_drag':
        body = 'carriage'
        dflt('C_d', lambda: _lu(r, 0.5, 20.0))
        inst.update(acts_on='body:carriage', terms=[{'channel': 'motor_current', 'term': 'v^2',
                                                     'coefficient': q['C_d'] / kF}])
    elif name == 'cable_force':
        body = body or ('carriage' if r.random() < 0.5 else 'm2')
        dflt('k_b', lambda: _lu(r, 50.0, 2000.0))
        dflt('F_0', lambda: _u(r, 0.0, 50.0))
        dflt('x_a', lambda: _u(r, 0.0, 0.3))
        inst['acts_on'] = f'body:{body}'
        inst['terms'] = ([{'channel': 'motor_current', 'term': 'x', 'coefficient': q['k_b'] / kF}] if body == 'carriage'
                         else [{'channel': 'force_moving', 'term': 'x', 'coefficient': q['k_b']}])
    elif name == 'binding_rail':
        body = 'carriage'
        dflt('mu_b', lambda: _lu(r, 0.01, 0.2))
        if 'B' not in q and r.random() < 0.5:
            q['B'] = _lu(r, 20.0, 300.0)
            q['w'] = _u(r, 0.02, 0.1)
            q['x_s'] = _u(r, 0.1, 1.0)
        inst.update(acts_on='body:carriage', terms=[{'channel': 'motor_current', 'term': 'F_move',
                                                     'coefficient': q['mu_b'] / kF}])
    elif name == 'viscous_guide':
        body = body or ('carriage' if r.random() < 0.5 else 'm2')
        dflt('c_g', lambda: _lu(r, 20.0, 500.0))
        inst['acts_on'] = f'body:{body}'
        inst['terms'] = ([{'channel': 'motor_current', 'term': 'v', 'coefficient': q['c_g'] / kF}] if body == 'carriage'
                         else [{'channel': 'force_moving', 'term': 'v', 'coefficient': q['c_g']}])
    elif name == 'clipping':
        ch = ch or str(r.choice(['force_moving_n', 'force_stationary_n']))
        dflt('fraction', lambda: _u(r, 0.3, 0.8))
        inst.update(acts_on=f'adc:{LONG2SHORT[ch]}', note='clip level = fraction x the largest batch F_u of the '
                                                          'campaign\'s sets; pulls[].clipped counts')
    else:
        raise ValueError(f'unknown departure {name!r}')
    inst.update(params=q, form=form, channel=ch, body=body)
    return inst


def draw_departures(seed: int, rig: Mapping, which) -> list[dict]:
    if which in ('none', None) or (not isinstance(which, str) and len(which) == 0):
        return []
    r = _rng(seed, 2)
    if isinstance(which, str):
        pool = {'draw': CATALOG + BEYOND, 'catalog': CATALOG, 'beyond': BEYOND}[which]
        n = int(r.integers(0, 4)) if which == 'draw' else int(r.integers(1, 4))
        names = list(r.choice(pool, size=n, replace=False)) if n else []
        return [_draw_departure(str(nm), _rng(seed, 2, k + 1), rig) for k, nm in enumerate(names)]
    return [_draw_departure(d['name'], _rng(seed, 2, k + 1), rig, d) for k, d in enumerate(which)]


def mount_modes(rig: Mapping, m2: float, mount, Ks: float) -> dict:
    """Coupled modal frequencies (Hz), lanyard free and taut: chain m1 - [K_s] - m2 - K2 - m_b - k_m - M_eff."""
    mb, km, _cm = mount
    K1, K2, Meff, m1 = rig['cells.K1_n_per_m'], rig['cells.K2_n_per_m'], rig['derived.M_eff_kg'], \
        rig['force_chain.stationary_side_mass_kg']
    out = {}
    for label, ks in (('lanyard_free', 0.0), ('lanyard_taut', Ks)):
        M = np.diag([m1, m2, mb, Meff])
        K = np.zeros((4, 4))
        for (a, b), k in (((0, 1), ks), ((1, 2), K2), ((2, 3), km)):
            K[a, a] += k
            K[b, b] += k
            K[a, b] -= k
            K[b, a] -= k
        K[0, 0] += K1
        lam = np.linalg.eigvals(np.linalg.solve(M, K)).real
        out[label] = sorted(float(math.sqrt(max(x, 0.0)) / (2 * math.pi)) for x in lam if x > 1.0)
    return out


# ----------------------------------------------------------------------------------------------- sensors + DAQ
class DAQ:
    """Sensor -> conditioner -> noise -> anti-alias filter -> skewed, drifting sampling -> ADC (SPEC 4.2)."""

    def __init__(self, rig: Mapping, fs: float | None = None):
        self.rig = rig
        self.fs = fs or rig['daq.sample_rate_hz']
        self.F = fine_factor(self.fs)
        self.h = 1.0 / (self.F * self.fs)
        self.kind, self.order = rig['daq.filter_type'], int(rig['daq.filter_order'])
        self.fc = rig['daq.fc_ratio'] * self.fs
        self.aa_ba = aa_design(self.kind, self.order, self.fc)
        self.aa_sos = foh_sos(*self.aa_ba, self.h)
        imp = np.zeros(int(40 * self.F * 8))
        imp[0] = 1.0
        self.noise_gain = float(np.sqrt(np.sum(signal.sosfilt(self.aa_sos, imp) ** 2)))

    def instants(self, n: int, delta: float, skew: float) -> np.ndarray:
        return np.arange(n) / (self.fs * (1 + delta)) + skew

    def skew(self, ch: str) -> float:
        return ANALOG.index(ch) * self.rig['daq.t_slot_s'] if ch in ANALOG else 0.0

    def analog(self, x_fine: np.ndarray, n: int, delta: float, skew: float, noise_rms: float = 0.0,
               rng: np.random.Generator | None = None) -> np.ndarray:
        """Noise (scaled so the recorded rms is noise_rms), anti-alias filter, sampling at the true instants."""
        if noise_rms > 0:
            x_fine = x_fine + rng.standard_normal(x_fine.size) * (noise_rms / self.noise_gain)
        y = run_sos(self.aa_sos, x_fine)
        return interp4(y, self.h, self.instants(n, delta, skew))

    @staticmethod
    def adc(v: np.ndarray, lsb_si: float, bits: int = 16) -> tuple[np.ndarray, int]:
        code = np.round(v / lsb_si)
        lo, hi = -2 ** (bits - 1), 2 ** (bits - 1) - 1
        clipped = int(np.count_nonzero((code < lo) | (code > hi)))
        return np.clip(code, lo, hi) * lsb_si, clipped


def sensor_chain(ch: str, sim: dict, deps: Sequence[Mapping], ctx: Mapping) -> np.ndarray:
    """The channel before noise and filter: the sensor (own dynamics, then non-linearity and gain, then cross-axis),
    then the conditioner (AC coupling, zero drift, pickup). ctx: per-pull values (t_launch, t_d, phases, k)."""
    c = sim['clean']
    t = sim['t_f']
    h = sim['h']
    x = c[CLEAN_OF[ch]].copy()
    mine = [d for d in deps if d.get('channel') == ch]
    # 1. the sensor's own dynamics
    for d in mine:
        q = d['params']
        if d['name'] == 'sensor_resonance':
            wr = 2 * math.pi * q['f_r_hz']
            x = run_sos(foh_sos([wr ** 2], [1.0, 2 * q['zeta_r'] * wr, wr ** 2], h), x)
        elif d['name'] == 'accel_delay':
            tau = q['delay_s']
            if d['form'] == 'shift':
                model = sim['model']
                ts = np.maximum(t - tau, 0.0)
                x = np.empty_like(t)
                for c0 in range(0, t.size, 200_000):
                    tt = ts[c0:c0 + 200_000]
                    x[c0:c0 + tt.size] = model.alg(tt, sim['sol'](tt))['a2']
            else:
                b, a = signal.bessel(2, 1.0 / tau, analog=True, norm='delay')
                x = run_sos(foh_sos(b, a, h), x)
    # 2. non-linearity and gain
    g = np.ones_like(t)
    y_nl = np.zeros_like(t)
    for d in mine:
        q, n = d['params'], d['name']
        if n == 'moving_cell_gain':
            g = g * q['gain']
    g0 = g.copy()
    for d in mine:
        q, n = d['params'], d['name']
        if n == 'gain_drift':
            if d['form'] == 'linear':
                g = g + q['kappa_per_s'] * t
            elif d['form'] == 'thermal':
                t_on = ctx['t_on'][id(d)]
                g = g + g0 * q['alpha_dT'] * np.where(t > t_on, 1 - np.exp(-(t - t_on) / q['tau_T_s']), 0.0)
            else:
                g = g * (1 + q['lambda_per_pull'] * (ctx['k_in_set'] - 1))
        elif n == 'nonlinearity_even':
            y_nl = y_nl + q['c2'] * x ** 2
        elif n == 'nonlinearity_odd':
            y_nl = y_nl + q['c3'] * x ** 3
    y = g * x + y_nl
    # 3. cross-axis
    for d in mine:
        q = d['params']
        if d['name'] == 'cross_axis':
            if ch == 'accel_axial_m_s2':
                y = y + q['s_y'] * c['ay'] + q['s_z'] * c['az']
            else:
                y = y + q['s_F'] * (math.cos(q['psi_rad']) * c['Fperp_y'] + math.sin(q['psi_rad']) * c['Fperp_z'])
    # 4. the conditioner
    for d in mine:
        if d['name'] == 'ac_coupling':
            tc = d['params']['time_constant_s']
            y = y - run_sos(foh_sos([1.0], [tc, 1.0], h), y)       # high-pass, zero output at t = 0
    for d in mine:
        q, n = d['params'], d['name']
        if n == 'zero_drift':
            td = ctx['t_d'][id(d)]
            dt = np.maximum(t - td, 0.0)
            y = y + q['z1'] * dt + q['z2'] * dt ** 2
        elif n == 'mains_hum':
            y = y + q['amplitude_n'] * np.sin(2 * math.pi * q['frequency_hz'] * t + ctx['phase'][id(d)])
        elif n == 'line_pickup':
            s = np.sin(2 * math.pi * q['frequency_hz'] * t + ctx['phase'][id(d)])
            if d['form'] == 'speed':
                y = y + q['k_v'] * np.abs(c['v']) * s
            elif d['form'] == 'pwm':
                y = y + q['amplitude'] * np.abs(c['i']) / sim['model'].Imax * s
            else:
                y = y + q['amplitude'] * s
    return y


# ----------------------------------------------------------------------------------------------- campaign
def _pull_context(seed: int, set_no: int, pull_no: int, deps: Sequence[Mapping], pull: Mapping) -> dict:
    ctx = {'phase': {}, 't_d': {}, 't_on': {}, 'k_in_set': pull_no}
    cmd = pull['command']
    t_launch = cmd['t_launch']
    v = cmd['v_set']
    t_taut_exp = t_launch + 2 * v / cmd['a_up'] + (pull['slack'] - v * v / cmd['a_up']) / v
    for k, d in enumerate(deps):
        r = _rng(seed, 3, set_no, pull_no, k)
        ctx['phase'][id(d)] = _u(r, 0.0, 2 * math.pi)
        if d['name'] == 'zero_drift':
            mode = d['params']['t_d_mode']
            ctx['t_d'][id(d)] = (t_launch if mode == 'launch' else 0.0 if mode == 'zero'
                                 else _u(r, 0.0, t_taut_exp - 0.05))
        if d['name'] == 'gain_drift' and d['form'] == 'thermal':
            ctx['t_on'][id(d)] = d['params']['t_on_fraction'] * t_launch
    return ctx


def _layout(seed: int, n_pulls: int | None, sets: Sequence[int] | None) -> list[tuple[int, int]]:
    sets = list(sets or (1, 2, 3, 4, 5))
    r = _rng(seed, 6)
    n = int(r.integers(4, 31)) if n_pulls is None else int(n_pulls)
    if n >= 5 or n >= len(sets):
        chosen = [sets[j % len(sets)] for j in range(n)]
    else:
        chosen = list(r.choice(sets, size=n, replace=False))
    out, count = [], {}
    for s in chosen:
        count[s] = count.get(s, 0) + 1
        out.append((int(s), count[s]))
    return sorted(out)


def run_pull(seed: int, rig: Mapping, set_no: int, pull_no: int, deps: Sequence[Mapping], *, noise: bool = True,
             keep_signals: bool = False, clip_levels: Mapping | None = None) -> tuple[dict, dict, dict]:
    """One pull, with its rejection rules (SPEC 3.2 step 7): (meta, channels, truth entry)."""
    body = [d for d in deps if d['name'] in BODY_DEPARTURES]
    for attempt in range(20):
        pull = draw_pull(seed, rig, set_no, pull_no, attempt)
        sim = simulate(rig, pull, body, seed=seed)
        ev = sim['events']
        cmd = sim['model'].cmd
        t_stop = cmd.t_brake + cmd.T_b
        ok = (math.isfinite(ev['t_break']) and math.isfinite(ev['t_brake']) and ev['t_break'] < ev['t_brake']
              and float(np.max(sim['clean']['x'])) < rig['drive.usable_track_m'] and t_stop <= sim['L'] - 0.2)
        if ok:
            break
    else:
        raise RuntimeError(f'no admissible pull for set {set_no} pull {pull_no}')
    lbf, fps, decel_g = PULL_SETS[set_no][:3]
    fs = rig['daq.sample_rate_hz']
    n = int(round(rig['daq.record_length_s'] * fs))
    daq = DAQ(rig)
    delta = rig['daq.clock_ppm_rig'] * 1e-6 + _nclip(_rng(seed, 8, set_no, pull_no), 2e-6)
    ctx = _pull_context(seed, set_no, pull_no, deps, pull)
    absent = set(rig['daq.absent'])
    ch_out = {'time_s': np.arange(n) / fs}
    clipped = {}
    for slot, ch in enumerate(ANALOG):
        if ch in absent:
            continue
        x = sensor_chain(ch, sim, deps, ctx)
        rng = _rng(seed, 4, set_no, pull_no, slot)
        v = daq.analog(x, n, delta, daq.skew(ch), rig[f'daq.noise.{ch}'] if noise else 0.0, rng)
        lsb = rig[f'daq.lsb_si.{ch}']
        if clip_levels and ch in clip_levels:
            lsb = clip_levels[ch] / 2 ** (rig['daq.adc_bits'] - 1)
        ch_out[ch], clipped[ch] = DAQ.adc(v, lsb, rig['daq.adc_bits'])
    t0 = daq.instants(n, delta, 0.0)
    if 'encoder_position_m' not in absent:
        res = rig['sensors.encoder_resolution_m']
        ch_out['encoder_position_m'] = np.round(interp4(sim['clean']['x'], sim['h'], t0) / res) * res
    if 'motor_velocity_cmd_m_s' not in absent:
        ch_out['motor_velocity_cmd_m_s'] = np.asarray(cmd(t0)[0], dtype=float)
    ch_out = {k: ch_out[k] for k in ['time_s', 'force_moving_n', 'force_stationary_n', 'accel_axial_m_s2',
                                     'accel_lateral_m_s2', 'accel_vertical_m_s2', 'encoder_position_m',
                                     'motor_current_a', 'motor_voltage_v', 'motor_velocity_cmd_m_s'] if k in ch_out}
    meta = {'file': f'set{set_no}_pull{pull_no:02d}.csv', 'set': set_no, 'pull': pull_no, 'coupon_lbf': lbf,
            'velocity_fps': fps, 'decel_g': decel_g, 'kind': 'pull', 'seed': int(seed)}
    c = sim['clean']
    t_f = sim['t_f']
    i_taut = int(np.searchsorted(t_f, ev['t_taut'])) if math.isfinite(ev['t_taut']) else 0
    model = sim['model']
    entry = {'file': meta['file'], 'set': set_no, 'pull': pull_no, 'seed': int(seed), 'attempt': pull['attempt'],
             'peak_tension_n': float(np.max(c['T'])), 'peak_stationary_clean_n': float(np.max(c['F1'])),
             'peak_moving_clean_n': float(np.max(c['F2'])), 't_taut_s': ev['t_taut'], 't_break_s': ev['t_break'],
             't_brake_s': ev['t_brake'], 'v_at_taut_m_s': float(np.interp(ev['t_taut'], t_f, c['v'])),
             'F_u_n': model.Fu, 'y': pull['coupon']['y'], 'p_f_m': model.pf, 'p_h_m': model.ph, 'k_c_n_per_m': model.kc,
             'eta_n_s_per_m': model.eta, 't_br_s': model.tbr, 'slack_m': model.s, 'K_L_n_per_m': model.KL,
             'K_s_n_per_m': model.Ks, 'c_L_n_s_per_m': model.cL, 'd_hold_m': pull['d_hold'],
             'command': dict(pull['command']),
             'clock_delta': delta, 'phases_rad': [ctx['phase'][id(d)] for d in deps],
             't_d_s': [ctx['t_d'].get(id(d)) for d in deps], 't_on_s': [ctx['t_on'].get(id(d)) for d in deps],
             'clipped': clipped, 'n_steps': ev['n_steps']}
    for d in deps:
        if d['name'] == 'gain_drift' and d['form'] == 'campaign':
            g0 = next((e['params']['gain'] for e in deps if e['name'] == 'moving_cell_gain'), 1.0)
            entry['catalog'] = {'name': 'moving_cell_gain',
                                'params': {'gain': g0 * (1 + d['params']['lambda_per_pull'] * (pull_no - 1))}}
        if d['name'] == 'cross_axis' and math.isfinite(ev['t_break']):
            j = slice(i_taut, int(np.searchsorted(t_f, ev['t_break'])) + 1)
            sig = np.hypot(c['ay'][j], c['az'][j]) if d['channel'] == 'accel_axial_m_s2' else \
                np.hypot(c['Fperp_y'][j], c['Fperp_z'][j])
            entry.setdefault('transverse_rms', []).append(float(np.sqrt(np.mean(sig ** 2))))
    if keep_signals:
        tt = ch_out['time_s']
        entry['signals'] = {k: interp4(c[src], sim['h'], tt).tolist() for k, src in (
            ('F_move', 'F2'), ('F_stat', 'F1'), ('T', 'T'), ('a2', 'a2'), ('v', 'v'), ('x', 'x'), ('i', 'i'))}
    return meta, ch_out, entry


def generate_campaign(seed: int, kind: str = 'pull', *, n_pulls: int | None = None,
                      sets: Sequence[int] | None = None, rig: Mapping | None = None,
                      departures: str | Sequence[Mapping] = 'draw', noise: bool = True,
                      keep_signals: bool = False) -> tuple[list[tuple[dict, dict]], dict]:
    """(campaign, truth). campaign = [(meta, channels), ...] in set, then pull, order."""
    if kind == 'impact':
        return _impact_campaign(seed, n_pulls, sets, rig, departures, noise, keep_signals)
    if kind != 'pull':
        raise ValueError(f'unknown kind {kind!r}')
    r = draw_rig(seed, rig)
    deps = draw_departures(seed, r, departures)
    layout = _layout(seed, n_pulls, sets)
    set_list = sorted(sets or PULL_SETS)          # not the layout's: a pull must not depend on n_pulls
    clip_levels = {}
    for d in deps:
        if d['name'] == 'clipping':
            level = d['params']['fraction'] * 1.0 * max(r[f'coupon.{s}.F_u_n'] for s in set_list)
            d['params']['clip_level_si'] = level
            clip_levels[d['channel']] = level
    campaign, pulls = [], []
    for s, k in layout:
        meta, chans, entry = run_pull(seed, r, s, k, deps, noise=noise, keep_signals=keep_signals,
                                      clip_levels=clip_levels)
        campaign.append((meta, chans))
        pulls.append(entry)
    counts = {}
    for s, _ in layout:
        counts[s] = counts.get(s, 0) + 1
    daq = DAQ(r)
    for d in deps:
        if d['name'] == 'mount_resonance':
            m2 = next((e['params']['mass_kg'] for e in deps if e['name'] == 'effective_mass'),
                      r['force_chain.moving_side_mass_kg'])
            q = d['params']
            mt = q['base_mass_kg'] + m2
            wn = 2 * math.pi * q['frequency_hz']
            kL, kc = r['force_chain.lanyard_stiffness_n_per_m'], r['coupon.3.k_c_n_per_m']
            q['modal_frequencies_hz'] = mount_modes(r, m2, (q['base_mass_kg'], wn ** 2 * mt, 0.0), kL * kc / (kL + kc))
    truth = {
        'generator': 'independent', 'spec_version': SPEC_VERSION, 'seed': int(seed), 'kind': kind,
        'datasheet': datasheet(r, counts),
        'rig': {k: v for k, v in r.items() if not isinstance(v, (list, dict))},
        'daq': {'filter': {'type': r['daq.filter_type'], 'order': int(r['daq.filter_order']), 'fc_hz': daq.fc,
                           'group_delay_s': aa_group_delay(r['daq.filter_type'], int(r['daq.filter_order']), daq.fc)},
                'adc_bits': int(r['daq.adc_bits']), 'fine_factor': daq.F,
                'channels': {ch: {'range_v': r[f'daq.range_v.{ch}'], 'sensitivity_v_per_si': r[f'daq.sens.{ch}'],
                                  'lsb_si': r[f'daq.lsb_si.{ch}'], 'skew_s': daq.skew(ch),
                                  'noise_rms': r[f'daq.noise.{ch}'] if noise else 0.0} for ch in ANALOG},
                'clock_offset_rig': r['daq.clock_ppm_rig'] * 1e-6,
                'clock_offset_pull': {p['file']: p['clock_delta'] for p in pulls},
                'absent': list(r['daq.absent'])},
        'departures': [{k: v for k, v in d.items()} for d in deps],
        'pulls': pulls,
    }
    return campaign, _jsonable(truth)


def _jsonable(x):
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, (np.floating, np.integer)):
        return x.item()
    if isinstance(x, float) and not math.isfinite(x):
        return None
    return x


def grammar_terms(truth: Mapping) -> list[dict]:
    """Every {channel, term, coefficient[, frequency_hz]} a departure of the truth record states."""
    out = []
    for d in truth.get('departures', []):
        if isinstance(d.get('terms'), list):
            out.extend(dict(t) for t in d['terms'])
    return out


def rig_yaml(truth: Mapping) -> str:
    """The datasheet (what the lab believes) as a workspace rig YAML: daq, drive (a pull rig) or impact (the drop
    tower), force_chain, sensors, test_sets."""
    ds = truth['datasheet']
    sections = [k for k in ('daq', 'drive', 'impact', 'force_chain', 'sensors') if k in ds]
    try:
        import yaml
        return yaml.safe_dump({k: ds[k] for k in (*sections, 'test_sets')}, sort_keys=False)
    except ImportError:                               # pragma: no cover - PyYAML is optional
        lines = []
        for sec in sections:
            lines.append(f'{sec}:')
            lines += [f'  {k}: {v!r}' for k, v in ds[sec].items()]
        lines.append('test_sets:')
        for ts in ds['test_sets']:
            lines.append('  - ' + '\n    '.join(f'{k}: {v!r}' for k, v in ts.items()))
        return '\n'.join(lines) + '\n'


# ----------------------------------------------------------------------------------------------- impact kind
# set -> (F_r rating lbf, impact speed fps)
IMPACT_SETS = {1: (500, 6.0), 2: (1000, 9.0), 3: (2000, 12.0), 4: (4000, 15.0)}
IMPACT_CHANNELS = ('force_moving_n', 'accel_axial_m_s2', 'accel_lateral_m_s2', 'accel_vertical_m_s2')
IMPACT_DEPARTURES = ('effective_mass', 'accel_delay', 'moving_cell_gain', 'ac_coupling', 'mains_hum',
                     'coulomb_friction', 'nonlinearity_even', 'nonlinearity_odd', 'gain_drift', 'zero_drift',
                     'line_pickup', 'sensor_resonance', 'cross_axis', 'aero_drag', 'cable_force', 'viscous_guide',
                     'clipping')


def draw_impact_rig(seed: int, overrides: Mapping | None = None) -> dict:
    """The drop tower (SPEC 3.3): drop mass M, moving cell K2, striker nose m2, crusher on a rigid anvil."""
    overrides = dict(overrides or {})
    r = _rng(seed, 10)
    d: dict = {}
    d['daq.sample_rate_hz'] = _u(r, 50e3, 100e3) if r.random() < 0.5 else float(r.choice([50e3, 100e3]))
    d['daq.record_length_s'] = _u(r, 0.25, 1.0)
    d['impact.drop_mass_kg'] = _lu(r, 5.0, 50.0)
    d['force_chain.moving_side_mass_kg'] = _lu(r, 0.1, 1.0)
    d['force_chain.load_cell_stiffness_n_per_m'] = 1e9 * _lu(r, 0.5, 2.0)
    d['force_chain.load_cell_damping_ratio'] = _lu(r, 0.005, 0.05)
    d['cells.unit_scatter_2'] = _u(r, -0.1, 0.1)
    d['transverse.enabled'] = True
    _draw_transverse(r, d)
    _draw_daq(r, d)
    d['daq.absent'] = ['accel_lateral_m_s2', 'accel_vertical_m_s2'] if r.random() < 0.3 else []
    d['crusher.zeta_t'] = _u(r, 0.3, 0.7)         # lumped crusher + anvil loss: few, weak rebounds
    for s in IMPACT_SETS:
        d[f'crusher.{s}.y'] = _u(r, 0.5, 0.9)
        d[f'crusher.{s}.p_f_m'] = _u(r, 1e-3, 5e-3)
        d[f'crusher.{s}.p_h_ratio'] = _u(r, 0.2, 1.0)
        d[f'crusher.{s}.k_t_n_per_m'] = _lu(r, 2e7, 2e8)
        d[f'crusher.{s}.eta_fraction'] = _u(r, 0.01, 0.05)
    d['sensors.load_cell_sensitivity_mv_per_lbf'] = 0.225 * LBF_N
    d['sensors.load_cell_range_lbf'] = 20000.0 / LBF_N
    d['sensors.accelerometer_sensitivity_mv_per_g'] = 1.023
    d['sensors.accelerometer_band_hz'] = 10000.0
    d.update(overrides)
    kcat = d['force_chain.load_cell_stiffness_n_per_m']
    d.setdefault('cells.K2_n_per_m', kcat * (1 + d['cells.unit_scatter_2']))
    d.setdefault('cells.zeta_2', d['force_chain.load_cell_damping_ratio'])
    d['daq.fc_hz'] = d['daq.fc_ratio'] * d['daq.sample_rate_hz']
    sens = {'force_moving_n': d['sensors.load_cell_sensitivity_mv_per_lbf'] * 1e-3 / LBF_N,
            'accel_axial_m_s2': d['sensors.accelerometer_sensitivity_mv_per_g'] * 1e-3 / G}
    sens['accel_lateral_m_s2'] = sens['accel_vertical_m_s2'] = sens['accel_axial_m_s2']
    fs_force = 20000.0 / 0.8          # the rated 20 kN at 80 % of full scale
    fs_acc = 500 * G / 0.8
    for ch in IMPACT_CHANNELS:
        peak = fs_force if ch == 'force_moving_n' else fs_acc
        s_ = overrides.get(f'daq.sens.{ch}', sens[ch])
        rng_v = next((v for v in (1.0, 2.0, 5.0, 10.0) if peak * s_ <= v), 10.0)
        d[f'daq.sens.{ch}'] = s_
        d[f'daq.range_v.{ch}'] = rng_v
        d[f'daq.lsb_si.{ch}'] = 2 * rng_v / 2 ** d['daq.adc_bits'] / s_
    # the drive's keys that the pull kind's DAQ code reads (no motor here)
    d['drive.current_limit_a'] = 1.0
    return d


class ImpactModel:
    """States: x_M, v_M, d (nose relative to the drop mass, + up = cell compression), w = d', G (nose height above the
    crusher's top at rest: its own state, so the contact compression is never a difference of metre-scale
    positions), p (crush). Gravity on every body; the cell reads compression as negative."""

    def __init__(self, rig: Mapping, drop: Mapping, body: Sequence[Mapping] = ()):
        self.M = rig['impact.drop_mass_kg']
        self.m2 = rig['force_chain.moving_side_mass_kg']
        self.body = [dict(b) for b in body]
        for b in self.body:
            if b['name'] == 'effective_mass':
                self.m2 = b['params']['mass_kg']
        self.K2 = rig['cells.K2_n_per_m']
        self.c2 = 2 * rig['cells.zeta_2'] * math.sqrt(self.K2 * self.m2)
        c = drop['crusher']
        self.kt, self.Fr, self.Fy, self.pf, self.ph, self.eta = c['k_t'], c['F_r'], c['y'] * c['F_r'], c['p_f'], \
            c['p_h'], c['eta']
        self.Imax = 1.0
        # contact damping (choice: SPEC 3.3 gives none; without it the mass rings undamped on the crusher's elastic
        # contact for the rest of the record): zeta_t of the drop mass on k_t, tension-only like the lanyard's
        self.ct = 2 * rig.get('crusher.zeta_t', 0.05) * math.sqrt(self.kt * self.M)

    def F_flow(self, p):
        pp = np.minimum(np.maximum(p, 0.0), self.pf)
        return self.Fy + (self.Fr - self.Fy) * (1 - np.exp(-pp / self.ph)) / (1 - math.exp(-self.pf / self.ph))

    def alg(self, t, y):
        xM, vM, d, w, Gp, p = (y[k] for k in range(6))
        F2 = -(self.K2 * d + self.c2 * w)
        e = -Gp - p
        etot_dot = -(vM + w)
        Ff = self.F_flow(p)
        P0 = self.kt * e + self.ct * etot_dot
        pdot = np.where((e > 0) & (P0 > Ff), (P0 - Ff) / (self.eta + self.ct), 0.0)
        Pel = self.kt * e + self.ct * (etot_dot - pdot)
        P = np.where((e > 0) & (Pel > 0), Pel, 0.0)
        Fdep = 0.0 * vM
        for bd in self.body:
            n, q = bd['name'], bd['params']
            if n == 'coulomb_friction':
                Fdep = Fdep - q['force_n'] * np.tanh(vM / VS_FRICTION)
            elif n == 'aero_drag':
                Fdep = Fdep - q['C_d'] * vM * np.abs(vM)
            elif n == 'viscous_guide':
                Fdep = Fdep - q['c_g'] * vM
            elif n == 'cable_force':      # a cable anchored above, taut once the mass has dropped x_a
                Fdep = Fdep + q['F_0'] + q['k_b'] * np.maximum(-xM - q['x_a'], 0.0)
        aM = (-F2 + Fdep) / self.M - G
        a2 = (F2 + P) / self.m2 - G
        return {'F2': F2, 'P': P, 'T': -P, 'pdot': pdot, 'aM': aM, 'a2': a2 + G, 'acc2': a2, 'e': e}

    def rhs(self, t, y):
        y = np.asarray(y, dtype=float)
        o = self.alg(t, y)
        dy = [y[1], o['aM'], y[3], o['acc2'] - o['aM'], y[1] + y[3], o['pdot']]
        out = np.empty((6,) + np.shape(y[0]))
        for k, v in enumerate(dy):
            out[k] = v
        return out

    def atol(self):
        return np.array([1e-8, 1e-7, 1e-3 / self.K2, 1e-3 / self.K2 * math.sqrt(self.K2 / self.m2),
                         1e-3 / self.kt, 1e-3 / self.kt])

    def jac(self, t, y):
        y = np.asarray(y, dtype=float).ravel()
        f0 = self.rhs(t, y)
        hk = 1e-7 * np.maximum(np.abs(y), self.atol() * 1e4)
        return (self.rhs(t, y[:, None] + np.diag(hk)) - f0[:, None]) / hk[None, :]


def draw_drop(seed: int, rig: Mapping, set_no: int, k: int) -> dict:
    F_r_lbf, fps = IMPACT_SETS[set_no]
    for sub in range(100):
        r = _rng(seed, 11, set_no, k, sub)
        F_r = F_r_lbf * LBF_N * (1 + _nclip(r, 0.03))
        v0 = fps * FT_M * (1 + _nclip(r, 0.01))
        c = f'crusher.{set_no}.'
        p_f = rig[c + 'p_f_m'] * (1 + _nclip(r, 0.10))
        y = rig[c + 'y']
        crusher = {'F_r': F_r, 'y': y, 'p_f': p_f, 'p_h': p_f * rig[c + 'p_h_ratio'], 'k_t': rig[c + 'k_t_n_per_m'],
                   'eta': rig[c + 'eta_fraction'] * F_r / v0}
        m = ImpactModel(rig, {'crusher': crusher})
        pp = np.linspace(0, p_f, 201)
        work = float(np.trapezoid(m.F_flow(pp), pp))
        if 0.5 * rig['impact.drop_mass_kg'] * v0 ** 2 < 1.2 * work:
            continue
        t_c = _u(r, 0.02, 0.1)
        return {'set': set_no, 'pull': k, 'attempt': sub, 'v0': v0, 't_contact_planned': t_c, 'crusher': crusher}
    raise RuntimeError(f'no admissible drop for set {set_no}')


def simulate_impact(rig: Mapping, drop: Mapping, body: Sequence[Mapping] = (), *, seed: int = 0,
                    t_end: float | None = None, rtol: float = 1e-7) -> dict:
    model = ImpactModel(rig, drop, body)
    fs = rig['daq.sample_rate_hz']
    L = t_end or rig['daq.record_length_s']
    t_sim = L * (1 + 2e-4) + 2e-4
    v0, t_c = drop['v0'], drop['t_contact_planned']
    y = np.array([0.0, -(v0 - G * t_c), 0.0, 0.0, v0 * t_c - 0.5 * G * t_c ** 2, 0.0])
    sol = Solution()

    def contact(tt, yy):
        return -yy[4] - yy[5]
    contact.terminal, contact.direction = True, 1
    t, quiet_until, n_steps = 0.0, -1.0, 0
    while t < t_sim - 1e-12:
        t1 = min(t_sim, quiet_until) if t < quiet_until else t_sim
        evs = None if t < quiet_until else [contact]
        r = solve_ivp(model.rhs, (t, t1), y, method='Radau', rtol=rtol, atol=model.atol(), dense_output=True,
                      jac=model.jac, events=evs, vectorized=True)
        if r.status < 0:
            raise RuntimeError(r.message)
        n_steps += len(r.t) - 1
        sol.segs.append(r.sol)
        sol.t_ends.append(r.t[-1])
        y = r.y[:, -1].copy()
        t = r.t[-1]
        if r.status == 1:
            quiet_until = t + 1e-4
            y[4] = min(y[4], -y[5] - 1e-12)    # start on the contact side: the damper's push jumps at e = 0
    h = 1.0 / (fine_factor(fs) * fs)
    n_f = int(math.floor(t_sim / h))
    t_f = np.arange(n_f) * h
    clean = {k: np.empty(n_f) for k in ('F2', 'T', 'a2', 'v', 'x', 'p')}
    for c0 in range(0, n_f, 200_000):
        tt = t_f[c0:c0 + 200_000]
        Y = np.empty((6, tt.size))
        idx = np.minimum(np.searchsorted(np.asarray(sol.t_ends), tt), len(sol.segs) - 1)
        for k in np.unique(idx):
            Y[:, idx == k] = sol.segs[k](tt[idx == k])
        o = model.alg(tt, Y)
        for k in ('F2', 'T', 'a2'):
            clean[k][c0:c0 + tt.size] = o[k]
        clean['v'][c0:c0 + tt.size] = Y[1]
        clean['x'][c0:c0 + tt.size] = Y[0]
        clean['p'][c0:c0 + tt.size] = Y[5]
    clean['i'] = np.zeros(n_f)
    m2 = model.m2
    if rig.get('transverse.enabled', True):
        for ax in ('y', 'z'):
            wn = 2 * math.pi * rig[f'transverse.f_{ax}_hz']
            zt = rig[f'transverse.zeta_{ax}']
            u = -clean['T'] * math.sin(rig[f'transverse.phi_{ax}_rad']) / m2       # P sin(phi), misaligned contact
            sos = foh_sos([m2 * 2 * zt * wn, m2 * wn ** 2], [1.0, 2 * zt * wn, wn ** 2], h)
            clean[f'Fperp_{ax}'] = run_sos(sos, u, steady=False)
            clean[f'a{ax}'] = u - clean[f'Fperp_{ax}'] / m2
    else:
        for ax in ('y', 'z'):
            clean[f'Fperp_{ax}'] = clean[f'a{ax}'] = np.zeros(n_f)
    return {'model': model, 'sol': sol, 'events': {'n_steps': n_steps}, 't_f': t_f, 'h': h, 'fs': fs, 'L': L,
            'clean': clean}


def _impact_campaign(seed, n_pulls, sets, rig_over, departures, noise, keep_signals):
    r = draw_impact_rig(seed, rig_over)
    if isinstance(departures, str) and departures not in ('none',):
        rr = _rng(seed, 12)
        n = int(rr.integers(0, 4)) if departures == 'draw' else int(rr.integers(1, 4))
        pool = [x for x in IMPACT_DEPARTURES if (departures == 'draw' or
                                                 (x in CATALOG) == (departures == 'catalog'))]
        names = list(rr.choice(pool, size=min(n, len(pool)), replace=False)) if n else []
        departures = [{'name': str(x)} for x in names]
    deps = []
    for k, d in enumerate([] if departures in ('none', None) else departures):
        g = dict(d)
        nm = g['name']
        if nm in ('ac_coupling', 'zero_drift', 'line_pickup', 'nonlinearity_even', 'nonlinearity_odd', 'clipping') \
                and 'channel' not in g:
            g['channel'] = str(_rng(seed, 13, k).choice(['force_moving_n', 'accel_axial_m_s2']))
        if nm in ('gain_drift',):
            g.setdefault('channel', 'force_moving_n')
            g.setdefault('form', 'linear')
        if nm == 'line_pickup':
            g.setdefault('form', 'line')
        if nm in ('cable_force', 'viscous_guide'):
            g['body'] = 'carriage'
        inst = _draw_departure(nm, _rng(seed, 2, k + 1), {**r, 'derived.k_F_n_per_a': 1.0}, g)
        if inst.get('body') == 'carriage':
            inst['acts_on'] = 'body:drop_mass'
            inst['terms'] = 'none'
        if isinstance(inst['terms'], list):
            inst['terms'] = [t for t in inst['terms'] if t['channel'] != 'motor_current'] or 'none'
        deps.append(inst)
    layout = _layout(seed, n_pulls, sets or (1, 2, 3, 4))
    body = [d for d in deps if d['name'] in BODY_DEPARTURES]
    fs = r['daq.sample_rate_hz']
    n = int(round(r['daq.record_length_s'] * fs))
    daq = DAQ(r)
    campaign, pulls = [], []
    for s, k in layout:
        drop = draw_drop(seed, r, s, k)
        sim = simulate_impact(r, drop, body, seed=seed)
        delta = r['daq.clock_ppm_rig'] * 1e-6 + _nclip(_rng(seed, 8, s, k), 2e-6)
        ctx = {'phase': {id(d): _u(_rng(seed, 3, s, k, j), 0, 2 * math.pi) for j, d in enumerate(deps)},
               't_d': {id(d): 0.0 for d in deps}, 't_on': {id(d): 0.0 for d in deps}, 'k_in_set': k}
        chans = {'time_s': np.arange(n) / fs}
        clipped = {}
        for ch in IMPACT_CHANNELS:
            if ch in r['daq.absent']:
                continue
            x = sensor_chain(ch, sim, deps, ctx)
            v = daq.analog(x, n, delta, daq.skew(ch), r[f'daq.noise.{ch}'] if noise else 0.0,
                           _rng(seed, 4, s, k, ANALOG.index(ch)))
            lsb = r[f'daq.lsb_si.{ch}']
            for d in deps:
                if d['name'] == 'clipping' and d['channel'] == ch:
                    peak = float(np.max(np.abs(x)))
                    lsb = d['params']['fraction'] * peak / 2 ** (r['daq.adc_bits'] - 1)
            chans[ch], clipped[ch] = DAQ.adc(v, lsb, r['daq.adc_bits'])
        c, t_f = sim['clean'], sim['t_f']
        on = np.nonzero(c['T'] < 0)[0]
        if on.size:                                   # the first contact's end (a rest on the crusher never ends)
            gaps = np.nonzero(np.diff(on) > 1)[0]
            on = on[:gaps[0] + 1] if gaps.size else on
        F_r_lbf, fps = IMPACT_SETS[s]
        meta = {'file': f'set{s}_pull{k:02d}.csv', 'set': s, 'pull': k, 'coupon_lbf': F_r_lbf, 'velocity_fps': fps,
                'decel_g': 0.0, 'kind': 'impact', 'seed': int(seed)}
        entry = {'file': meta['file'], 'set': s, 'pull': k, 'seed': int(seed),
                 'peak_tension_n': float(np.min(c['T'])), 'peak_abs_n': float(-np.min(c['T'])),
                 'peak_moving_clean_n': float(np.min(c['F2'])),
                 't_contact_start_s': float(t_f[on[0]]) if on.size else None,
                 't_contact_end_s': float(t_f[on[-1]]) if on.size else None,
                 'v_at_contact_m_s': drop['v0'], 'F_r_n': drop['crusher']['F_r'], 'y': drop['crusher']['y'],
                 'p_f_m': drop['crusher']['p_f'], 'k_t_n_per_m': drop['crusher']['k_t'],
                 'eta_n_s_per_m': drop['crusher']['eta'], 'crush_final_m': float(c['p'][-1]),
                 'clock_delta': delta, 'phases_rad': [ctx['phase'][id(d)] for d in deps], 'clipped': clipped,
                 'n_steps': sim['events']['n_steps']}
        if keep_signals:
            entry['signals'] = {kk: interp4(c[src], sim['h'], chans['time_s']).tolist() for kk, src in (
                ('F_move', 'F2'), ('T', 'T'), ('a2', 'a2'), ('v', 'v'), ('x', 'x'))}
        campaign.append((meta, chans))
        pulls.append(entry)
    counts = {}
    for s, _ in layout:
        counts[s] = counts.get(s, 0) + 1
    ds = {'daq': {'sample_rate_hz': r['daq.sample_rate_hz'], 'record_length_s': r['daq.record_length_s']},
          'force_chain': {'moving_side_mass_kg': r['force_chain.moving_side_mass_kg'],
                          'load_cell_stiffness_n_per_m': r['force_chain.load_cell_stiffness_n_per_m'],
                          'load_cell_damping_ratio': r['force_chain.load_cell_damping_ratio']},
          'sensors': {k: r[f'sensors.{k}'] for k in ('load_cell_sensitivity_mv_per_lbf', 'load_cell_range_lbf',
                                                      'accelerometer_sensitivity_mv_per_g', 'accelerometer_band_hz')},
          'test_sets': [{'set': s, 'coupon_lbf': IMPACT_SETS[s][0], 'velocity_fps': IMPACT_SETS[s][1], 'decel_g': 0.0,
                         'pulls': int(nn)} for s, nn in sorted(counts.items())],
          'impact': {'drop_mass_kg': r['impact.drop_mass_kg']}}
    truth = {'generator': 'independent', 'spec_version': SPEC_VERSION, 'seed': int(seed), 'kind': 'impact',
             'datasheet': ds, 'rig': {k: v for k, v in r.items() if not isinstance(v, (list, dict))},
             'daq': {'filter': {'type': r['daq.filter_type'], 'order': 8, 'fc_hz': daq.fc,
                                'group_delay_s': aa_group_delay(r['daq.filter_type'], 8, daq.fc)},
                     'adc_bits': int(r['daq.adc_bits']), 'fine_factor': daq.F,
                     'channels': {ch: {'range_v': r[f'daq.range_v.{ch}'], 'sensitivity_v_per_si': r[f'daq.sens.{ch}'],
                                       'lsb_si': r[f'daq.lsb_si.{ch}'], 'skew_s': daq.skew(ch),
                                       'noise_rms': r[f'daq.noise.{ch}'] if noise else 0.0}
                                  for ch in IMPACT_CHANNELS},
                     'clock_offset_rig': r['daq.clock_ppm_rig'] * 1e-6,
                     'clock_offset_pull': {p['file']: p['clock_delta'] for p in pulls},
                     'absent': list(r['daq.absent']) + ['force_stationary_n', 'encoder_position_m', 'motor_current_a',
                                                        'motor_voltage_v', 'motor_velocity_cmd_m_s']},
             'departures': deps, 'pulls': pulls}
    return campaign, _jsonable(truth)
