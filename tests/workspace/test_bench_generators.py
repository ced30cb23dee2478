"""The discovery benchmarks' second generator (benchmarks/independent_cases.py): what it hands `discover` is the
datasheet, never the truth, and the truths it scores against are the truth record's, in the workspace's terms."""
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / 'benchmarks'))

import independent_cases as IG  # noqa: E402

#: the chain behind the moving cell as a truth record states it: a stiff undamped cell, a carriage of 1e6 kg with no
#: damping and no velocity loop (the mount's mode is then the bracket's own)
CHAIN = {'cells.K2_n_per_m': 7e11, 'cells.zeta_2': 0.0, 'derived.M_eff_kg': 1e6, 'derived.b_n_s_per_m': 0.0,
         'derived.k_F_n_per_a': 40.0, 'control.K_pv': 0.0, 'control.f_ci_hz': 1000.0}


def truth_record(deps, skew_force=0.0, skew_accel=4e-6, m2=1.3, **chain):
    channels = {'force_moving_n': {'skew_s': skew_force}, 'accel_axial_m_s2': {'skew_s': skew_accel}}
    return {'rig': {'force_chain.moving_side_mass_kg': m2, **CHAIN, **chain}, 'daq': {'channels': channels},
            'departures': deps}


def test_the_truths_are_the_truth_records_in_the_workspaces_terms():
    mount = {'name': 'mount_resonance', 'catalog': {'name': 'mount_resonance', 'params': {
        'frequency_hz': 1000.0, 'damping_ratio': 0.02, 'base_mass_kg': 0.3}},
        'params': {'frequency_hz': 1000.0, 'damping_ratio': 0.02, 'base_mass_kg': 0.3,
                   'modal_frequencies_hz': {'lanyard_free': [450.0, 1130.0, 5200.0], 'lanyard_taut': [900.0]}}}
    delay = {'name': 'accel_delay', 'catalog': {'name': 'accel_delay', 'params': {'delay_s': 50e-6}}}
    beyond = {'name': 'aero_drag', 'catalog': None, 'terms': [{'channel': 'motor_current', 'term': 'v^2',
                                                               'coefficient': 0.1}]}
    t = truth_record([mount, delay, beyond])
    truths = IG.catalog_truths(t)
    # the mode the accelerometer sees: the lanyard-free mode nearest the bracket's own frequency
    assert truths[('mount_resonance', 'frequency_hz')] == 1130.0
    # its damping: the damped mode of the chain; on a held, undamped carriage behind a stiff undamped cell it is the
    # bracket's own, and the drive's velocity loop on a light carriage (k_F K_pv = 5000 N s/m) damps it more
    assert truths[('mount_resonance', 'damping_ratio')] == pytest.approx(0.02, rel=0.01)
    driven = IG.catalog_truths(truth_record([mount], **{'derived.M_eff_kg': 50.0, 'control.K_pv': 125.0}))
    assert driven[('mount_resonance', 'damping_ratio')] > 1.02 * truths[('mount_resonance', 'damping_ratio')]
    # the accelerometer samples 4 us after the moving cell: it leads by 4 us, so the delay seen is 46 us
    assert truths[('accel_delay', 'delay_s')] == pytest.approx(46e-6)
    assert truths[('effective_mass', 'mass_kg')] == 1.3 and truths[('moving_cell_gain', 'gain')] == 1.0
    assert not any(cause == 'aero_drag' for cause, _ in truths)
    # with no delay departure the truth is the lead alone, negative
    assert IG.catalog_truths(truth_record([]))[('accel_delay', 'delay_s')] == pytest.approx(-4e-6)


@pytest.mark.slow
def test_a_case_gives_discover_the_datasheet_and_keeps_every_channel():
    c = IG.case(5, [{'name': 'moving_cell_gain'}], pulls=2, sets=(2,))
    assert [m['set'] for m, _ in c.campaign] == [2, 2]
    ds = c.truth['datasheet']
    assert c.rig.force_chain.moving_side_mass_kg == ds['force_chain']['moving_side_mass_kg']
    assert c.rig.daq.sample_rate_hz == ds['daq']['sample_rate_hz']
    assert c.truth['daq']['absent'] == []
    assert {'force_moving_n', 'force_stationary_n', 'accel_axial_m_s2', 'encoder_position_m',
            'motor_current_a'} <= set(c.campaign[0][1])
    gain = IG.catalog_truths(c.truth)[('moving_cell_gain', 'gain')]
    assert gain != 1.0 and gain == c.truth['departures'][0]['params']['gain']


@pytest.mark.slow
@pytest.mark.parametrize('bench', ['coverage', 'beyond', 'discovery', 'peak_coverage'])
def test_every_discovery_benchmark_takes_the_generator(bench):
    # argparse knows the option and its three choices: a fourth is refused in one line, before any campaign
    bad = subprocess.run([str(ROOT / 'ft'), 'bench', bench, '--generator', 'ours'], capture_output=True, text=True)
    assert bad.returncode == 2 and "argument --generator: invalid choice: 'ours'" in bad.stderr, bad.stderr
    assert all(g in bad.stderr.splitlines()[-1] for g in ('own', 'independent', 'both'))
