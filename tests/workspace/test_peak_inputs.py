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
    rig = load_rig(NOMINAL_YAML)
    ext = tmp_path / 'extension.yaml'
    ext.write_text(yaml.safe_dump({'correction': {'mass_kg': 1.3, 'moving_cell_gain': 1.015},
                                   'uncertainty': {'mass_kg': 0.013, 'accel_delay_s': 1e-6}}))
    got = peak_inputs(rig, ext)
    assert got.mass_rel == pytest.approx(0.01) and got.accel_delay_s == 1e-6
    assert got.gain_rel == peak_inputs(rig).gain_rel   # not stated: the rig's
    ext.write_text(yaml.safe_dump({'correction': {}, 'uncertainty': {'mass': 0.01}}))
    with pytest.raises(CorrectionError, match="'mass'"):
        peak_inputs(rig, ext)
