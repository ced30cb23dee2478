"""Issue 12, section 4: re-simulating measured pulls (model of record, and model of record + extension) driven by
the measured carriage motion, with per-pull quantities fitted from each pull's own data.

The campaigns come from the test GENERATOR (generator.py); the code under test gets the recorded channels, the
nominal rig and (for the simulation check) the extension to score. The generator's pull specs are used only here,
to judge the fitted per-pull quantities.
"""
from __future__ import annotations

import numpy as np
import pytest
from generator import draw_nuisance, make_campaign, observed_mount_mode, rig_with

from force_discovery.core.prep import filtered, prepare
from force_discovery.core.resim import fit_pull_quantities, resimulate, simulation_check
from force_tester_sim.core.campaign import truth_pull_specs
from force_tester_sim.core.departures import NO_DEPARTURES, departures_from_data
from force_tester_sim.core.errors import SimError
from force_tester_sim.core.extra_terms import ExtraTerm
from force_tester_sim.core.motion import PrescribedMotion, SampledMotion
from force_tester_sim.core.params import load_rig
from force_tester_sim.core.pull import nominal_pull_spec, run_pull, run_pull_with_motion

FORCES = ('force_moving_n', 'force_stationary_n')


def prepared(departures, seed, sets, pulls=1, nuisance=None):
    rig = load_rig()
    camp = make_campaign(departures, seed=seed, sets=sets, pulls=pulls, nuisance=nuisance)
    return rig, [prepare(meta, ch, rig) for meta, ch in camp]


# ------------------------------------------------------------------------------------- SampledMotion
def test_sampled_motion_interpolates_holds_and_matches_its_scalar_path():
    t = np.arange(6) * 0.5
    x, v, a = t ** 2, 2 * t, np.full(6, 2.0) + t
    m = SampledMotion(t, x, v, a, command_scale=1.5)
    xs, vs, as_ = m.kinematics(t)
    assert np.array_equal(xs, x) and np.array_equal(vs, v) and np.array_equal(as_, a)
    # linear between samples, first sample held before t[0], last after t[-1]
    q = np.array([-1.0, 0.25, 1.2, 2.5, 9.0])
    xq, vq, aq = m.kinematics(q)
    assert np.allclose(xq, [0.0, 0.125, 1.0 + 0.4 * (2.25 - 1.0), 6.25, 6.25])
    assert np.allclose(vq, [0.0, 0.5, 2.4, 5.0, 5.0])
    assert np.allclose(aq, [2.0, 2.25, 3.2, 4.5, 4.5])
    for k, tq in enumerate(q):   # the scalar fast path (uniform grid) agrees with the array path
        assert np.allclose(m.kinematics_scalar(float(tq)), [xq[k], vq[k], aq[k]])
    assert np.allclose(m.command_velocity(q), 1.5 * vq)
    # a non-uniform grid takes the general path and gives the same interpolation
    tn = np.array([0.0, 0.1, 0.5, 2.0])
    mn = SampledMotion(tn, tn * 3, tn * 0 + 3, tn * 0)
    assert mn.kinematics_scalar(1.25) == pytest.approx((3.75, 3.0, 0.0))


@pytest.mark.parametrize('bad', [
    dict(t=[0.0, 1.0, 1.0], x=[0, 0, 0], v=[0, 0, 0], a=[0, 0, 0]),      # not strictly increasing
    dict(t=[0.0, 1.0, 2.0], x=[0, 0], v=[0, 0, 0], a=[0, 0, 0]),          # shapes differ
    dict(t=[0.0, 1.0, 2.0], x=[0, np.nan, 0], v=[0, 0, 0], a=[0, 0, 0]),  # non-finite
    dict(t=[0.0], x=[0], v=[0], a=[0]),                                  # one sample
])
def test_sampled_motion_rejects_bad_samples(bad):
    with pytest.raises(SimError, match='expected'):
        SampledMotion(**{k: np.asarray(v, float) for k, v in bad.items()})


def test_run_pull_with_sampled_motion_reproduces_run_pull():
    """The prescribed motion's own samples, replayed through SampledMotion, give the same pull."""
    rig = load_rig()
    spec = nominal_pull_spec(rig, 3)
    ref = run_pull(rig, spec, noise=False)
    t = ref.channels['time_s']
    x, v, a = ref.motion.kinematics(t)
    assert isinstance(ref.motion, PrescribedMotion)
    res = run_pull_with_motion(rig, spec, SampledMotion(t, x, v, a), noise=False)
    for ch in FORCES:
        peak = np.max(np.abs(ref.channels[ch]))
        assert np.max(np.abs(res.channels[ch] - ref.channels[ch])) < 2e-3 * peak, ch
    assert res.break_time_s == pytest.approx(ref.break_time_s, abs=0.05 * rig.daq.dt_s)


# ------------------------------------------------------------------------------------- model of record
def test_nominal_pull_resimulated_with_fitted_quantities():
    """A nominal-rig pull (slow break in set 2, a break shorter than a sample in set 3), re-simulated with the
    nominal rig, its measured motion and quantities fitted from its own tension, reproduces its channels."""
    rig, pulls = prepared(None, seed=21, sets=(2, 3))
    specs = [truth_pull_specs(rig, s, 1, 21)[0] for s in (2, 3)]
    for p, spec in zip(pulls, specs):
        q = fit_pull_quantities(p, rig)
        assert q.slack_m == pytest.approx(spec.slack_m, abs=20e-6), p.name
        assert q.lanyard_stiffness_n_per_m == pytest.approx(spec.lanyard_stiffness_n_per_m, rel=0.02), p.name
        assert q.coupon_break_n == pytest.approx(spec.coupon_break_n, rel=0.005), p.name
        assert q.coupon_yield_n == pytest.approx(spec.coupon_yield_n, rel=0.01), p.name
        assert q.coupon_hardening_n_per_m == pytest.approx(spec.coupon_hardening_n_per_m, rel=0.05), p.name
        if spec.break_duration_s > 5 * p.dt:   # a break within a sample or two is not resolved
            assert q.break_duration_s == pytest.approx(spec.break_duration_s, rel=0.05), p.name
        sim = resimulate(p, rig, NO_DEPARTURES, q)
        w = slice(p.w0, p.w1)
        meas = {'force_moving_n': p.fm, 'force_stationary_n': filtered(p.fs, p.dt), 'accel_axial_m_s2': p.a2,
                'motor_current_a': filtered(p.current, p.dt)}
        for ch, m in meas.items():
            rms = np.sqrt(np.mean((filtered(sim[ch], p.dt)[w] - m[w]) ** 2))
            assert rms < 0.01 * np.max(np.abs(m[w])), (p.name, ch, rms)


# ------------------------------------------------------------------------------------- hidden departures
def channel_gains(check) -> dict:
    return {ch: v['gain'] for ch, v in check.as_dict().items()}


def test_effective_mass_extension_beats_the_model_of_record():
    truth = {'effective_mass': {'mass_kg': 1.4}}
    rig, pulls = prepared(truth, seed=22, sets=(3, 4))
    chk = simulation_check(pulls, [0, 1], rig, departures_from_data(truth))
    sim = chk.as_dict()
    assert set(sim) == {'force_moving_n', 'force_stationary_n', 'accel_axial_m_s2', 'motor_current_a'}
    g = channel_gains(chk)
    assert g['force_moving_n'] > 5 and g['accel_axial_m_s2'] > 5 and g['motor_current_a'] > 3, g
    assert 0.8 < g['force_stationary_n'] < 1.25, g    # the stationary side hardly sees m2
    assert sim['force_moving_n']['baseline_rms'] > 20.0, sim   # the model of record misses it by tens of N
    assert chk.ring is None
    tr = chk.trace
    assert tr['pull'] == pulls[0].name and len(tr['t']) == pulls[0].w1 - pulls[0].w0
    assert set(tr['force_moving_n']) == {'measured', 'baseline', 'extended'}


def test_a_wrong_extension_loses_to_the_model_of_record():
    """The check can fail: on a nominal campaign, an extension that is not there makes the sim worse."""
    rig, pulls = prepared(None, seed=23, sets=(3,), pulls=2)
    g = channel_gains(simulation_check(pulls, [0, 1], rig, departures_from_data({'effective_mass': {'mass_kg': 1.4}})))
    assert g['force_moving_n'] < 0.5 and g['accel_axial_m_s2'] < 0.5, g


@pytest.mark.parametrize('term,coefficient,frequency_hz', [('v*sin', 1.5, 300.0), ('v*sin', 6.0, 1250.0),
                                                            ('sin', 5.0, 700.0)])
def test_a_sinusoid_the_data_do_not_hold_gains_nothing_at_its_fitted_phase(term, coefficient, frequency_hz):
    """A sinusoid's phase is fitted on each held-out pull, its amplitude is not: on a nominal campaign a frame mode
    that is not there (sizes as the generator's carriage vibration, 6-25 N at 4 m/s) makes the moving cell's sim
    worse, whatever phase fits best, and leaves the other channels as they were."""
    rig, pulls = prepared(None, seed=23, sets=(3,), pulls=2)
    sin = ExtraTerm('force_moving', term, coefficient, frequency_hz)
    chk = simulation_check(pulls, [0, 1], rig, NO_DEPARTURES, extra=(sin,))
    sim = chk.as_dict()
    assert sim['force_moving_n']['extended_rms'] > sim['force_moving_n']['baseline_rms'], sim
    for ch in ('force_stationary_n', 'accel_axial_m_s2', 'motor_current_a'):
        assert sim[ch]['gain'] == pytest.approx(1.0, abs=1e-9), (ch, sim)
    assert [list(q['sin_phase_rad']) for q in chk.quantities] == [[f'force_moving: {term}']] * 2
    assert [e['term'] for e in chk.details()['terms_resimulated']] == [term]


def test_moving_cell_gain_extension_only_changes_the_moving_cell():
    truth = {'moving_cell_gain': {'gain': 1.05}}
    rig, pulls = prepared(truth, seed=24, sets=(2, 5))
    g = channel_gains(simulation_check(pulls, [0, 1], rig, departures_from_data(truth)))
    assert g['force_moving_n'] > 5, g
    for ch in ('force_stationary_n', 'accel_axial_m_s2', 'motor_current_a'):
        assert g[ch] == pytest.approx(1.0, abs=1e-9), (ch, g)


@pytest.mark.parametrize('mount', [{'frequency_hz': 1200.0, 'damping_ratio': 0.02},
                                   {'frequency_hz': 650.0, 'damping_ratio': 0.04, 'base_mass_kg': 0.3}])
def test_mount_resonance_extension_rings_at_the_measured_frequency(mount):
    truth = {'mount_resonance': mount}
    rig, pulls = prepared(truth, seed=25, sets=(3, 4))
    chk = simulation_check(pulls, [0, 1], rig, departures_from_data(truth))
    g = channel_gains(chk)
    assert g['force_moving_n'] > 5 and g['accel_axial_m_s2'] > 5, g
    ring = chk.ring
    f_obs, _ = observed_mount_mode(rig_with(truth))
    assert ring['pulls'] == 2 and ring['within_tolerance'], ring
    assert ring['measured_hz'] == pytest.approx(f_obs, rel=0.02), (ring, f_obs)   # the measurement sees the mode
    assert abs(ring['extended_sim_hz'] / ring['measured_hz'] - 1) < 0.02, ring
    assert chk.time_s > 0


def test_extension_gain_survives_model_form_nuisances():
    """Cells and lanyard damped 2-4x the assumed ratios, an anti-alias filter, 1/f noise and 16-bit samples: the
    check measures the cells' damping on the pulls' free decay, and the true extension still wins clearly."""
    truth = {'effective_mass': {'mass_kg': 1.45}}
    nuisance = draw_nuisance(26)
    rig, pulls = prepared(truth, seed=26, sets=(3, 5), nuisance=nuisance)
    chk = simulation_check(pulls, [0, 1], rig, departures_from_data(truth))
    zeta = rig.force_chain.load_cell_damping_ratio * nuisance['cell_damping_factor']
    assert chk.cell_damping['pulls'] == 2
    assert chk.cell_damping['used'] == pytest.approx(zeta, rel=0.03), (chk.cell_damping, zeta)
    g = channel_gains(chk)
    assert g['force_moving_n'] > 3 and g['accel_axial_m_s2'] > 3, g
    uncal = channel_gains(simulation_check(pulls, [0, 1], rig, departures_from_data(truth), calibrate=False))
    assert uncal['force_moving_n'] < g['force_moving_n'] / 2, (uncal, g)   # the calibration is what rescues it
