"""What the correction's peak uncertainty takes (force_correction.core.peak_uncertainty.PeakInputs) from a rig
YAML and an extension.yaml: the one place that maps the sim's facts onto the correction's inputs (the
correction's core may not import the sim).

- m2, the moving cell's gain, the accelerometer's sensitivity: the rig's ``uncertainty:`` section (k = 1,
  ``force_chain.moving_side_mass_kg``, ``sensors.load_cell_sensitivity_mv_per_lbf``,
  ``sensors.accelerometer_sensitivity_mv_per_g``), relative to the rig's value;
- the accelerometer's lag: a rig has no measured lag, and `discover` leaves a lag inside the rig's
  ``tolerances.accel_delay_s`` band unnamed (it counts as the model of record). So a lag up to that bound may be
  there, corrected or not: a rectangular distribution of half-width ``tolerances.accel_delay_s``,
  u = bound / sqrt(3) (GUM 4.3.7);
- an extension.yaml may carry an ``uncertainty:`` mapping next to ``correction:`` ({mass_kg, moving_cell_gain,
  accel_delay_s}: standard uncertainties of the values it corrects with); each one given replaces the rig's.
  For a value the extension names without one, the rig's u stays (relative to the extension's value).
"""
from __future__ import annotations

import math
from pathlib import Path

import yaml

from force_correction.core.errors import CorrectionError
from force_correction.core.peak_uncertainty import PeakInputs

EXTENSION_KEYS = ('mass_kg', 'moving_cell_gain', 'accel_delay_s')


def peak_inputs(rig, extension_file: str | Path | None = None) -> PeakInputs:
    """PeakInputs of a rig (force_tester_sim RigParams) and, optionally, an extension.yaml."""
    unc = rig.uncertainty
    m2 = rig.force_chain.moving_side_mass_kg
    out = {'mass_rel': unc.relative('force_chain.moving_side_mass_kg', m2),
           'gain_rel': unc.relative('sensors.load_cell_sensitivity_mv_per_lbf',
                                    rig.sensors.load_cell_sensitivity_mv_per_lbf),
           'accel_sensitivity_rel': unc.relative('sensors.accelerometer_sensitivity_mv_per_g',
                                                 rig.sensors.accelerometer_sensitivity_mv_per_g),
           'accel_delay_s': rig.tolerances.accel_delay_s / math.sqrt(3.0)}
    if extension_file is not None:
        try:
            doc = yaml.safe_load(Path(extension_file).read_text()) or {}
        except (OSError, yaml.YAMLError) as exc:
            raise CorrectionError(f'extension file {str(extension_file)!r} cannot be read: {exc}') from None
        corr, stated = doc.get('correction') or {}, doc.get('uncertainty') or {}
        if not isinstance(stated, dict) or set(stated) - set(EXTENSION_KEYS):
            raise CorrectionError(f'extension uncertainty {stated!r} is invalid; expected a mapping of some of '
                                  f'{list(EXTENSION_KEYS)} to standard uncertainties')
        if 'mass_kg' in stated:
            out['mass_rel'] = float(stated['mass_kg']) / float(corr.get('mass_kg') or m2)
        if 'moving_cell_gain' in stated:
            out['gain_rel'] = float(stated['moving_cell_gain']) / float(corr.get('moving_cell_gain') or 1.0)
        if 'accel_delay_s' in stated:
            out['accel_delay_s'] = float(stated['accel_delay_s'])
    return PeakInputs(**out)


def validator_params(extension_file: str | Path | None = None, rig_file: str | Path | None = None) -> dict:
    """The validator node's peak_u_* parameters: peak_inputs of the rig the correction assumes (the nominal rig
    unless ``rig_file``) and its extension."""
    from dataclasses import asdict

    from force_tester_sim.core.params import NOMINAL_YAML, load_rig
    inputs = peak_inputs(load_rig(rig_file or NOMINAL_YAML), extension_file)
    return {f'peak_u_{k}': float(v) for k, v in asdict(inputs).items()}
