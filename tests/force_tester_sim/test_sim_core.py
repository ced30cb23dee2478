"""Unit tests of the ROS-free physics core of force_tester_sim."""
import dataclasses
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from force_tester_sim.core import (
    CHANNELS,
    FT_M,
    G_M_S2,
    LBF_N,
    NOMINAL_YAML,
    PrescribedMotion,
    RigParams,
    SimError,
    chain_params,
    force_move,
    force_stat,
    integrate_reference,
    load_rig,
    make_pull_specs,
    nominal_pull_spec,
    run_pull,
    sample_stamps_ns,
    simulate_pull,
)
from force_tester_sim.core import pull as pull_mod
from force_tester_sim.core.params import rig_from_dict

PKG = Path(__file__).resolve().parents[2] / 'src' / 'force_tester_sim' / 'force_tester_sim'
PROJECT_YAML = PKG / 'config' / 'nominal.yaml'


@pytest.fixture(scope='module')
def rig():
    return load_rig()


@pytest.fixture(scope='module')
def clean_runs(rig):
    """Clean (noise-free) scattered pulls of sets 3 and 5, and the nominal pull of set 1."""
    return {
        3: run_pull(rig, make_pull_specs(rig, 3, 1, seed=11)[0], noise=False),
        5: run_pull(rig, make_pull_specs(rig, 5, 1, seed=12)[0], noise=False),
        1: run_pull(rig, nominal_pull_spec(rig, 1), noise=False),
    }


def _accel(v, h):
    """Fourth-order central difference (ends left NaN)."""
    a = np.full_like(v, np.nan)
    a[2:-2] = (-v[4:] + 8 * v[3:-1] - 8 * v[1:-3] + v[:-4]) / (12 * h)
    return a


# ---------------------------------------------------------------- parameters

def test_packaged_yaml_is_the_projects_copy():
    # the installed package data (or the source tree itself) carries the project's own copy
    assert NOMINAL_YAML.read_bytes() == PROJECT_YAML.read_bytes()
    assert 'shared' not in NOMINAL_YAML.resolve().parts


@pytest.mark.parametrize('params', ['defaults', 'loaded'])
def test_defaults_equal_nominal_yaml(params):
    data = yaml.safe_load(PROJECT_YAML.read_text())
    rig = RigParams() if params == 'defaults' else load_rig()
    for section in ('daq', 'drive', 'force_chain', 'sensors', 'tolerances'):
        obj = getattr(rig, section)
        names = {f.name for f in dataclasses.fields(obj)}
        assert names == set(data[section]), section
        for key, value in data[section].items():
            got = getattr(obj, key)
            if isinstance(value, list):
                assert list(got) == pytest.approx(value), (section, key)
            else:
                assert got == pytest.approx(value, rel=0, abs=0), (section, key)
    assert len(rig.test_sets) == len(data['test_sets'])
    for ts, raw in zip(rig.test_sets, data['test_sets']):
        assert dataclasses.asdict(ts) == raw
    assert set(data) == {'daq', 'drive', 'force_chain', 'sensors', 'test_sets', 'tolerances', 'uncertainty'}
    # the nominal YAML states every constant's uncertainty, and states the default fractions of rig.uncertainty
    assert rig.uncertainty.as_dict().keys() == data['uncertainty'].keys()
    for section, keys in rig.uncertainty.as_dict().items():
        assert keys == pytest.approx(data['uncertainty'][section], rel=1e-12, abs=0), section


def test_uncertainties_scale_with_another_rig_and_stated_ones_win():
    heavy = rig_from_dict({'force_chain': {'moving_side_mass_kg': 4.0}})
    assert heavy.uncertainty.u('force_chain.moving_side_mass_kg') == pytest.approx(0.04)
    stated = rig_from_dict({'force_chain': {'moving_side_mass_kg': 4.0},
                            'uncertainty': {'force_chain': {'moving_side_mass_kg': 0.2}}})
    assert stated.uncertainty.u('force_chain.moving_side_mass_kg') == 0.2
    assert stated.uncertainty.relative('force_chain.moving_side_mass_kg', 4.0) == pytest.approx(0.05)
    assert stated.uncertainty.u('daq.record_length_s') == 0.0


@pytest.mark.parametrize('section, value, words', [
    ({'force_chain': {'moving_side_mass_kg': -0.01}}, '-0.01', 'finite number >= 0'),
    ({'force_chain': {'moving_side_mass_kg': None}}, 'None', 'finite number >= 0'),
    ({'force_chain': {'moving_side_mass_kg': 2.0}}, '2.0', 'larger than the value 1.152'),
    ({'sensors': {'accelerometer_band_hz': 1.0}}, 'accelerometer_band_hz', 'not a constant of sensors'),
    ({'optics': {'focus_m': 1.0}}, 'optics', 'unknown section'),
])
def test_bad_uncertainty_is_refused_naming_key_and_value(section, value, words):
    with pytest.raises(SimError) as exc:
        rig_from_dict({'uncertainty': section})
    msg = str(exc.value)
    assert value in msg and words in msg and '\n' not in msg
    if 'unknown' not in words and 'not a constant' not in words:
        assert 'uncertainty.force_chain.moving_side_mass_kg' in msg


def test_test_set_si_properties(rig):
    s3, s5 = rig.test_set(3), rig.test_set(5)
    assert s3.coupon_n == pytest.approx(600 * 4.4482216152605)
    assert s3.velocity_m_s == pytest.approx(15 * 0.3048)
    assert s5.decel_m_s2 == pytest.approx(-1.24 * 9.80665)
    assert (LBF_N, FT_M, G_M_S2) == (4.4482216152605, 0.3048, 9.80665)
    assert rig.drive.reflected_mass_kg == pytest.approx((0.2335 + 9 * 2.6e-3) / 0.0668 ** 2)


@pytest.mark.parametrize('bad', [0, 6, 7, -1])
def test_unknown_test_set_raises(rig, bad):
    with pytest.raises(SimError) as exc:
        rig.test_set(bad)
    assert str(bad) in str(exc.value) and 'expected one of 1, 2, 3, 4, 5' in str(exc.value)
    with pytest.raises(SimError):
        make_pull_specs(rig, bad, 2, seed=0)
    assert isinstance(exc.value, ValueError)


def test_load_rig_rejects_bad_files(tmp_path):
    data = yaml.safe_load(PROJECT_YAML.read_text())
    data['force_chain']['lanyard_stifness'] = 1.0
    p = tmp_path / 'rig.yaml'
    p.write_text(yaml.safe_dump(data))
    with pytest.raises(SimError, match='lanyard_stifness'):
        load_rig(p)
    data = yaml.safe_load(PROJECT_YAML.read_text())
    data['force_chain']['load_cell_stiffness_n_per_m'] = -5.0
    p.write_text(yaml.safe_dump(data))
    with pytest.raises(SimError, match='-5.0'):
        load_rig(p)
    with pytest.raises(SimError, match='nope.yaml'):
        load_rig(tmp_path / 'nope.yaml')
    # a partial file keeps nominal values elsewhere
    p.write_text(yaml.safe_dump({'force_chain': {'lanyard_stiffness_n_per_m': 1.0e6}}))
    r = load_rig(p)
    assert r.force_chain.lanyard_stiffness_n_per_m == 1.0e6 and r.drive == RigParams().drive


# ---------------------------------------------------------------- the record

def test_channels_and_sample_grid(rig, clean_runs):
    ch = clean_runs[3].channels
    assert tuple(ch) == CHANNELS
    assert set(ch) == {'time_s', 'encoder_position_m', 'accel_axial_m_s2', 'accel_lateral_m_s2',
                       'accel_vertical_m_s2', 'force_moving_n', 'force_stationary_n', 'motor_velocity_cmd_m_s',
                       'motor_current_a', 'motor_voltage_v'}
    t = ch['time_s']
    assert len(t) == 100_000 and t[0] == 0.0 and np.allclose(np.diff(t), 2e-5, rtol=0, atol=1e-12)
    for k, v in ch.items():
        assert v.shape == (100_000,) and np.all(np.isfinite(v)), k
    q = ch['encoder_position_m'] / rig.sensors.encoder_resolution_m
    assert np.allclose(q, np.round(q), atol=1e-6)
    assert np.abs(ch['motor_voltage_v']).max() <= rig.drive.voltage_limit_v
    assert np.all(ch['accel_lateral_m_s2'] == 0) and np.all(ch['accel_vertical_m_s2'] == 0)


def test_event_indices(clean_runs):
    r = clean_runs[3]
    tr = r.truth
    assert 0 < r.taut_index < r.break_index < r.break_end_index < 100_000
    assert tr['tension_n'][r.taut_index] > 0 and np.all(tr['tension_n'][:r.taut_index] == 0)
    assert 0.3 < r.taut_time_s < 1.2          # well inside the 2 s record
    assert r.start_index == 0 and r.end_index == 100_000
    # the break starts when F_stat first reaches the coupon's break force
    fs = tr['force_stationary_n']
    assert fs[r.break_index - 1] < r.spec.coupon_break_n
    assert np.all(fs[:r.break_index - 1] < r.spec.coupon_break_n)


def test_eq21_holds_in_clean_sim(rig, clean_runs):
    """F_stat = F_move - m1 a1 - m2 a2 with a1, a2 differentiated from the integrated velocities."""
    h = 1.0 / rig.daq.sample_rate_hz
    m1, m2 = rig.force_chain.m1, rig.force_chain.m2
    for key in (3, 5, 1):
        r = clean_runs[key]
        tr = r.truth
        a1 = _accel(tr['v1_m_s'], h)
        a2 = _accel(tr['v2_m_s'], h)
        sl = slice(r.taut_index - 500, r.taut_index + 5000)
        resid = (tr['force_stationary_n'] - (r.channels['force_moving_n'] - m1 * a1 - m2 * a2))[sl]
        peak = tr['force_stationary_n'].max()
        assert np.nanmax(np.abs(resid)) < 0.005 * peak, key
        # the accelerometer reads u2'' (away from the kinks of beta, where finite differences are poor)
        err = r.channels['accel_axial_m_s2'] - a2
        for k in (r.taut_index, r.break_index, r.break_end_index):
            err[k - 3:k + 3] = 0.0
        err = err[sl]
        assert np.nanmax(np.abs(err)) < 0.005 * np.abs(a2[sl]).max() + 0.5, key
        # dropping m1 a1 (eq 24) is not exact
        resid24 = (tr['force_stationary_n'] - (r.channels['force_moving_n'] - m2 * a2))[sl]
        assert np.nanmax(np.abs(resid24)) > 10 * np.nanmax(np.abs(resid))


def test_lanyard_never_pushes(clean_runs):
    for r in clean_runs.values():
        T = r.truth['tension_n']
        assert T.min() >= 0.0
        assert np.all(T[:r.taut_index] == 0) and np.all(T[r.break_end_index:] == 0)
        # nothing reaches the stationary side before the lanyard engages
        assert np.abs(r.truth['force_stationary_n'][:r.taut_index]).max() < 1e-6


def test_after_break_stationary_side_rings_freely(rig, clean_runs):
    h = 1.0 / rig.daq.sample_rate_hz
    m1 = rig.force_chain.m1
    for r in clean_runs.values():
        tr = r.truth
        k = r.break_end_index + 3
        fs = tr['force_stationary_n']
        a1 = _accel(tr['v1_m_s'], h)
        sl = slice(k, k + 4000)
        assert np.abs(fs[sl] + m1 * a1[sl]).max() < 0.005 * np.abs(fs[sl]).max() + 1e-3
        assert np.abs(fs[sl]).max() > 1.0                       # it does ring ...
        assert np.abs(fs[k + 20_000:]).max() < 1e-3              # ... and decays (damped cell)


def test_quasi_static_limit(rig):
    base = nominal_pull_spec(rig, 1)
    spec = dataclasses.replace(base, velocity_m_s=0.02, slack_m=0.01, command_velocity_m_s=None,
                               break_duration_s=1.0e-3)
    r = run_pull(rig, spec, noise=False)
    tr = r.truth
    fs, fm = tr['force_stationary_n'], tr['force_moving_n']
    load = slice(r.taut_index, r.break_index)
    assert r.break_index - r.taut_index > 1000                 # a slow pull
    assert np.abs(fm[load] - fs[load]).max() < 0.002 * spec.coupon_break_n
    assert fm.max() == pytest.approx(fs.max(), rel=0.01)
    assert fs.max() == pytest.approx(spec.coupon_break_n, rel=0.01)
    assert np.abs(tr['a2_m_s2'][load]).max() < 0.1 * G_M_S2


# ---------------------------------------------------------------- integration accuracy

@pytest.mark.parametrize('key', [3, 5])
def test_fast_integrator_matches_solve_ivp(rig, clean_runs, key):
    """The exact piecewise-LTI propagation + event location agrees with plain DOP853 through the pull."""
    r = clean_runs[key]
    p = chain_params(rig, r.spec)
    tr = r.truth
    ka, kb = r.taut_index - 30, r.break_end_index + 250
    x0 = [tr['u2_m'][ka] - tr['x3_m'][ka], tr['v2_m_s'][ka] - tr['v3_m_s'][ka], tr['u1_m'][ka], tr['v1_m_s'][ka]]
    ref = integrate_reference(p, r.motion, r.channels['time_s'][ka:kb], x0)
    assert ref.break_s == pytest.approx(r.break_time_s, abs=1e-8)
    assert np.abs(force_stat(ref.x, p) - tr['force_stationary_n'][ka:kb]).max() < 0.05
    assert np.abs(force_move(ref.x, p) - tr['force_moving_n'][ka:kb]).max() < 0.05


def test_fast_integrator_matches_solve_ivp_at_launch(rig, clean_runs):
    r = clean_runs[1]
    p = chain_params(rig, r.spec)
    k0 = int(0.29 * 50_000)
    ref = integrate_reference(p, r.motion, r.channels['time_s'][k0:k0 + 1500], np.zeros(4), max_step=2e-5)
    assert np.abs(force_move(ref.x, p) - r.truth['force_moving_n'][k0:k0 + 1500]).max() < 1e-3
    # the moving cell carries m2 a3 while the carriage accelerates
    k = int(np.argmax(r.truth['a3_m_s2']))
    assert r.truth['force_moving_n'][k] == pytest.approx(rig.force_chain.m2 * r.truth['a3_m_s2'][k], rel=1e-3)


# ---------------------------------------------------------------- specs, seeds, motion

def test_same_seed_same_output_different_seed_different(rig):
    a = make_pull_specs(rig, 2, 3, seed=5)
    assert a == make_pull_specs(rig, 2, 3, seed=5)
    b = make_pull_specs(rig, 2, 3, seed=6)
    assert a != b and len({s.seed for s in a + b}) == 6
    r1, r2 = simulate_pull(rig, a[0]), simulate_pull(rig, a[0])
    for k in CHANNELS:
        assert np.array_equal(r1[k], r2[k]), k
    r3 = simulate_pull(rig, b[0])
    assert not np.array_equal(r1['force_moving_n'], r3['force_moving_n'])
    # the seed also drives the sensor noise: same physics, other noise
    r4 = simulate_pull(rig, dataclasses.replace(a[0], seed=a[0].seed + 1))
    assert not np.array_equal(r1['accel_lateral_m_s2'], r4['accel_lateral_m_s2'])
    assert np.array_equal(r1['encoder_position_m'], r4['encoder_position_m'])


def test_noise_levels(rig):
    spec = make_pull_specs(rig, 1, 1, seed=3)[0]
    noisy, clean = simulate_pull(rig, spec), simulate_pull(rig, spec, noise=False)
    for key, lo, hi in [('force_moving_n', 0.2, 0.5), ('force_stationary_n', 0.2, 0.5),
                        ('accel_axial_m_s2', 0.3, 0.7), ('accel_vertical_m_s2', 0.3, 0.7)]:
        rms = np.std(noisy[key] - clean[key])
        assert lo < rms < hi, (key, rms)


def test_pull_spec_scatter(rig):
    specs = make_pull_specs(rig, 3, 200, seed=1)
    ts = rig.test_set(3)
    f = np.array([s.coupon_break_n for s in specs]) / ts.coupon_n
    v = np.array([s.velocity_m_s for s in specs]) / ts.velocity_m_s
    d = np.array([s.break_duration_s for s in specs])
    assert 0.02 < f.std() < 0.04 and abs(f.mean() - 1) < 0.01 and np.all(np.abs(f - 1) <= 0.09 + 1e-12)
    assert 0.006 < v.std() < 0.014 and np.all(np.abs(v - 1) <= 0.03 + 1e-12)
    assert d.min() >= 0.2e-3 and d.max() <= 1.0e-3
    with pytest.raises(SimError, match='-0.1'):
        dataclasses.replace(specs[0], velocity_m_s=-0.1)
    with pytest.raises(SimError, match='0'):
        make_pull_specs(rig, 3, 0, seed=1)


@pytest.mark.parametrize('n', [1, 2, 3, 4, 5])
def test_motion_within_track_and_record(rig, n):
    ts = rig.test_set(n)
    for spec in make_pull_specs(rig, n, 3, seed=n):
        ch = simulate_pull(rig, spec, noise=False)
        x = ch['encoder_position_m']
        assert x.min() >= 0.0 and x.max() <= rig.drive.usable_track_m
        m = pull_mod.motion_for(rig, spec)
        assert m.stop_s < 1.9 and 0.3 < m.taut_s < 1.2
        xs, vs, as_ = m.kinematics(ch['time_s'])
        assert np.all(vs >= -1e-12) and np.all(vs[-1000:] == 0)
        # at the pull the carriage runs at the pull speed (and decelerates at decel_g for sets 4, 5)
        x_t, v_t, a_t = m.kinematics_scalar(m.taut_s)
        assert v_t == pytest.approx(spec.velocity_m_s, rel=1e-9) and x_t == pytest.approx(spec.slack_m)
        a_after = m.kinematics_scalar(m.taut_s + 2e-3)[2]
        assert a_after == pytest.approx(spec.decel_m_s2, abs=1e-9)
        assert (a_after < -0.5 * G_M_S2) == (ts.decel_g < 0)
        # the commanded speed is the set's speed
        assert ch['motor_velocity_cmd_m_s'].max() == pytest.approx(ts.velocity_m_s, rel=1e-9)


def test_motion_closed_form_is_consistent():
    m = PrescribedMotion.build(4.0, 1.0, -12.0, 0.03)
    t = np.linspace(0, 2, 200_001)
    x, v, a = m.kinematics(t)
    h = t[1] - t[0]
    assert np.abs(np.gradient(x, h)[1:-1] - v[1:-1]).max() < 1e-6
    assert np.abs(np.gradient(v, h)[1:-1] - a[1:-1]).max() < 1e-2
    for tt in (0.0, 0.31, 0.5, m.taut_s + 1e-4, m.brake_s + 0.01, 1.5):
        assert np.allclose(m.kinematics_scalar(tt), [float(q) for q in m.kinematics(tt)], rtol=1e-12, atol=1e-12)
    with pytest.raises(SimError, match='0.01'):
        PrescribedMotion.build(4.0, 0.01)            # slack shorter than the launch distance
    with pytest.raises(SimError, match='usable track'):
        PrescribedMotion.build(4.0, 1.4).check_fits(1.524, 2.0)


def test_motor_channels(rig, clean_runs):
    r = clean_runs[1]
    ch, tr, d = r.channels, r.truth, rig.drive
    k = r.taut_index - 2000     # cruising, before the pull
    i = (d.reflected_mass_kg * tr['a3_m_s2'][k] + d.viscous_damping_n_s_per_m * tr['v3_m_s'][k]
         + tr['force_moving_n'][k]) * d.pulley_radius_m / (d.gear_ratio * d.torque_constant_nm_per_a)
    assert ch['motor_current_a'][k] == pytest.approx(i)
    v = d.armature_resistance_ohm * i + d.back_emf_constant_v_s_per_rad * d.gear_ratio * tr['v3_m_s'][k] \
        / d.pulley_radius_m
    assert ch['motor_voltage_v'][k] == pytest.approx(v, rel=1e-6)
    assert np.all(ch['motor_current_a'][:int(0.29 * 50_000)] == 0)


def test_sanity_set3(rig):
    spec = nominal_pull_spec(rig, 3)
    r = run_pull(rig, spec, noise=False)
    fs, fm = r.truth['force_stationary_n'], r.truth['force_moving_n']
    assert fs.max() == pytest.approx(spec.coupon_break_n, rel=0.1)
    assert fm.max() == pytest.approx(fs.max(), rel=0.1)
    assert 1 * G_M_S2 < np.abs(r.truth['a2_m_s2']).max() < 1000 * G_M_S2


def test_sample_stamps_ns(rig):
    s = sample_stamps_ns(rig, 1_000_000_000_000)
    assert s.dtype == np.int64 and s[0] == 1_000_000_000_000 and s[1] - s[0] == 20_000
    assert s[-1] - s[0] == 99_999 * 20_000
    with pytest.raises(SimError, match='1.5'):
        sample_stamps_ns(rig, 1.5)


@pytest.mark.parametrize('test_set', [3, 5])
def test_halving_the_step_changes_peak_forces_by_less_than_0p1_percent(test_set):
    """The chain is propagated on the sample grid: rerun on a grid twice as fine (100 kHz) and compare
    the peak forces on the common sample times (so sampling of the peak is not mistaken for error)."""
    from force_tester_sim.core.params import rig_from_dict
    from force_tester_sim.core.pull import make_pull_specs
    from force_tester_sim.core.simulate import simulate_pull
    coarse_rig = rig_from_dict({})
    fine_rig = rig_from_dict({'daq': {'sample_rate_hz': 100_000.0}})
    truth = yaml.safe_load((Path(pull_mod.__file__).parents[1] / 'config' / 'truth_reference.yaml').read_text())
    for rigs in ((coarse_rig, fine_rig),
                 (rig_from_dict(truth),
                  rig_from_dict({**truth, 'daq': {**truth['daq'], 'sample_rate_hz': 100_000.0}}))):
        spec = make_pull_specs(rigs[0], test_set, 1, seed=4)[0]
        coarse = simulate_pull(rigs[0], spec, noise=False)
        fine = simulate_pull(rigs[1], spec, noise=False)
        for key in ('force_moving_n', 'force_stationary_n'):
            a, b = coarse[key].max(), fine[key][::2].max()
            assert abs(a - b) < 1e-3 * abs(a), (key, a, b)


def test_a_departures_uncertainty_is_stated_in_the_same_section():
    """uncertainty.departures.<cause>.<parameter> (what `discover` writes into extension.yaml): kept as stated,
    refused above the rig's departure value or for a parameter the cause does not have."""
    rig = rig_from_dict({'departures': {'accel_delay': {'delay_s': 5e-5}},
                         'uncertainty': {'departures': {'accel_delay': {'delay_s': 2e-7}}}})
    assert rig.uncertainty.u('departures.accel_delay.delay_s') == 2e-7
    with pytest.raises(SimError, match=r'uncertainty\.departures\.accel_delay\.delay_s is 0\.001, larger'):
        rig_from_dict({'departures': {'accel_delay': {'delay_s': 5e-5}},
                       'uncertainty': {'departures': {'accel_delay': {'delay_s': 1e-3}}}})
    with pytest.raises(SimError, match=r'uncertainty\.departures\.accel_delay\.gain is not a parameter'):
        rig_from_dict({'uncertainty': {'departures': {'accel_delay': {'gain': 0.1}}}})


def test_the_sim_nodes_process_plans_pulls_without_scipy():
    """The sim node's own process plans the pulls and publishes them; its worker process simulates (and loads
    scipy). Importing the node and planning a campaign's pulls loads no scipy: 0.9 s less CPU per sim started."""
    code = ('import sys\n'
            'import force_tester_sim.sim_node\n'
            'from force_tester_sim.core import load_rig, make_pull_specs\n'
            'from force_tester_sim.core.sim_config import SimConfig\n'
            'assert make_pull_specs(load_rig(), 3, 2, seed=0)\n'
            'print(sorted({m.split(".")[0] for m in sys.modules} & {"scipy", "force_tester_sim.core.integrate"}))\n'
            'print("force_tester_sim.core.integrate" in sys.modules)\n')
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.split() == ['[]', 'False'], out.stdout
