"""ft_cli.peak_inputs: the corrected peak's uncertainty inputs from a rig YAML's uncertainty: section and an
extension.yaml's optional uncertainty: mapping."""
import math

import pytest
import yaml

from force_correction.core.errors import CorrectionError
from force_tester_sim.core.params import NOMINAL_YAML, load_rig
from ft_cli.peak_inputs import peak_inputs, validator_params


def test_the_rigs_stated_uncertainties_and_the_lags_rectangular_bound():
    rig = load_rig(NOMINAL_YAML)
    got = peak_inputs(rig)
    unc = rig.uncertainty
    assert got.mass_rel == pytest.approx(unc.u('force_chain.moving_side_mass_kg') / rig.force_chain.m2)
    assert got.gain_rel == pytest.approx(unc.relative('sensors.load_cell_sensitivity_mv_per_lbf',
                                                      rig.sensors.load_cell_sensitivity_mv_per_lbf))
    assert got.accel_delay_s == pytest.approx(rig.tolerances.accel_delay_s / math.sqrt(3))
    assert validator_params()['peak_u_mass_rel'] == got.mass_rel


def test_an_extension_states_its_own(tmp_path):
    """The extension's uncertainty: section in the rig YAML's form: a departure's u in its own unit, relative to
    the value the correction uses; a restated constant relative to the correction's value too."""
    rig = load_rig(NOMINAL_YAML)
    ext = tmp_path / 'extension.yaml'
    ext.write_text(yaml.safe_dump({'correction': {'mass_kg': 1.3, 'moving_cell_gain': 1.015},
                                   'uncertainty': {'departures': {'effective_mass': {'mass_kg': 0.013},
                                                                  'accel_delay': {'delay_s': 1e-6}}}}))
    got = peak_inputs(rig, ext)
    assert got.mass_rel == pytest.approx(0.01) and got.accel_delay_s == 1e-6
    assert got.gain_rel == peak_inputs(rig).gain_rel   # not stated: the rig's
    ext.write_text(yaml.safe_dump({'correction': {'moving_cell_gain': 1.015},
                                   'uncertainty': {'departures': {'moving_cell_gain': {'gain': 0.00203}},
                                                   'sensors': {'accelerometer_sensitivity_mv_per_g': 0.05}}}))
    got = peak_inputs(rig, ext)
    assert got.gain_rel == pytest.approx(0.002)
    assert got.accel_sensitivity_rel == pytest.approx(0.05 / rig.sensors.accelerometer_sensitivity_mv_per_g)


@pytest.mark.parametrize('section, what', [
    ({'mass_kg': 0.01}, "'mass_kg'"),                                        # the old flat form: not a section
    ({'departures': {'effective_mass': {'mass': 0.01}}}, 'effective_mass.mass'),
    ({'departures': {'accel_delay': {'delay_s': -1e-6}}}, '-1e-06'),
    ({'departures': {'moving_cell_gain': {'gain': 2.0}}}, 'larger than the value'),
    ({'departures': {'mount_resonance': {'frequency_hz': 1.0}}}, 'mount_resonance.frequency_hz'),
])
def test_a_bad_extension_uncertainty_is_refused_with_one_line(tmp_path, section, what):
    ext = tmp_path / 'extension.yaml'
    ext.write_text(yaml.safe_dump({'correction': {'moving_cell_gain': 1.0}, 'uncertainty': section}))
    with pytest.raises(CorrectionError) as info:
        peak_inputs(load_rig(NOMINAL_YAML), ext)
    msg = str(info.value)
    assert what in msg and '\n' not in msg, msg


def test_discovers_extension_round_trips_into_the_peak_inputs(tmp_path):
    """extension.yaml as `discover` writes it (extension(), extension_yaml()) carries the standard uncertainty of
    each corrected value it estimated: the interval's half-width over k = 2, and, for a value the correction keeps
    at the model of record's (a cause not named), the estimate's distance from it; peak_inputs reads them back."""
    import math as m

    from force_discovery.core.extension import extension, extension_yaml
    rig = load_rig(NOMINAL_YAML)
    m2 = rig.force_chain.m2
    cands = {'effective_mass': {'parameters': {'mass_kg': 1.2}, 'parameters_ci95': {'mass_kg': [1.19, 1.21]}},
             'moving_cell_gain': {'parameters': {'gain': 1.002}, 'parameters_ci95': {'gain': [1.001, 1.003]}},
             'accel_delay': {'parameters': {'delay_s': 0.0}, 'parameters_ci95': {'delay_s': [0.0, 0.0]}}}
    named = [{'name': 'effective_mass', 'parameters': {'mass_kg': 1.2}}]
    ext = extension({'causes': named, 'candidates': cands}, rig)
    path = tmp_path / 'extension.yaml'
    path.write_text(extension_yaml(ext))
    doc = yaml.safe_load(path.read_text())
    assert doc['correction']['mass_kg'] == 1.2
    dep = doc['uncertainty']['departures']
    assert dep['effective_mass']['mass_kg'] == pytest.approx(0.005)              # named: (0.01 / 2)
    assert dep['moving_cell_gain']['gain'] == pytest.approx(m.hypot(0.0005, 0.002))   # kept at 1: + the distance
    assert dep['accel_delay']['delay_s'] == 0.0
    got = peak_inputs(rig, path)
    assert got.mass_rel == pytest.approx(0.005 / 1.2)
    assert got.gain_rel == pytest.approx(m.hypot(0.0005, 0.002))
    assert got.accel_delay_s == 0.0
    assert got.mass_rel != peak_inputs(rig).mass_rel and m2 != 1.2


def test_the_reference_free_extension_round_trips_into_the_peak_inputs(tmp_path):
    """With no reference cell the correction's mass is g m2 and its gain 1: extension.yaml states g m2's u as m2's
    (relative to g m2) and the delay's; the gain's u stays the rig's, since g is not identified."""
    from force_discovery.core.extension import extension_yaml
    from force_discovery.core.without_reference.report import report_extension
    rig = load_rig(NOMINAL_YAML)
    cands = {'gain_mass_product': {'parameters': {'gain_mass_kg': 0.34}, 'parameters_ci95': {'gain_mass_kg':
                                                                                            [0.338, 0.342]}},
             'accel_delay': {'parameters': {'delay_s': 3e-5}, 'parameters_ci95': {'delay_s': [2.8e-5, 3.2e-5]}}}
    rep = {'candidates': cands, 'causes': [{'name': 'gain_mass_product'}, {'name': 'accel_delay'}]}
    path = tmp_path / 'extension.yaml'
    path.write_text(extension_yaml(report_extension(rep, rig)))
    doc = yaml.safe_load(path.read_text())
    assert doc['correction']['mass_kg'] == 0.34 and doc['correction']['moving_cell_gain'] == 1.0
    assert doc['uncertainty']['departures'] == {'effective_mass': {'mass_kg': pytest.approx(0.001)},
                                                'accel_delay': {'delay_s': pytest.approx(1e-6)}}
    got = peak_inputs(rig, path)
    assert got.mass_rel == pytest.approx(0.001 / 0.34) and got.accel_delay_s == pytest.approx(1e-6)
    assert got.gain_rel == peak_inputs(rig).gain_rel
    # one pull: per-pull estimates, no interval: nothing stated, the rig's u stays
    cands['gain_mass_product']['parameters_ci95']['gain_mass_kg'] = None
    cands['accel_delay']['parameters_ci95']['delay_s'] = None
    assert 'uncertainty' not in report_extension(rep, rig)
