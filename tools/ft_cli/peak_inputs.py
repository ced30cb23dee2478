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
- an extension.yaml may carry an ``uncertainty:`` section next to ``correction:``, in the rig YAML's form
  (force_tester_sim.core.uncertainty: one home for it): ``./ft discover`` writes the standard uncertainties of the
  values it corrects with as ``departures: {effective_mass: {mass_kg}, moving_cell_gain: {gain}, accel_delay:
  {delay_s}}``; a constant's (``force_chain.moving_side_mass_kg``, ``sensors.load_cell_sensitivity_mv_per_lbf``,
  ``sensors.accelerometer_sensitivity_mv_per_g``) may be restated too. Each one given replaces the rig's; for a
  value the extension does not state, the rig's u stays (relative to the extension's value).
"""
from __future__ import annotations

import math
from pathlib import Path

import yaml

from force_correction.core.errors import CorrectionError
from force_correction.core.peak_uncertainty import PeakInputs

#: the extension's uncertainty keys -> (the PeakInputs field, the value it is relative to: None for an absolute u;
#: 'mass' / 'gain' for the correction's m2 / gain; a rig constant's key for that constant)
EXTENSION_KEYS = {
    'departures.effective_mass.mass_kg': ('mass_rel', 'mass'),
    'force_chain.moving_side_mass_kg': ('mass_rel', 'mass'),
    'departures.moving_cell_gain.gain': ('gain_rel', 'gain'),
    'sensors.load_cell_sensitivity_mv_per_lbf': ('gain_rel', 'sensors.load_cell_sensitivity_mv_per_lbf'),
    'sensors.accelerometer_sensitivity_mv_per_g': ('accel_sensitivity_rel',
                                                   'sensors.accelerometer_sensitivity_mv_per_g'),
    'departures.accel_delay.delay_s': ('accel_delay_s', None),
}


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
        out.update(extension_inputs(rig, extension_file))
    return PeakInputs(**out)


def extension_inputs(rig, extension_file: str | Path) -> dict:
    """{PeakInputs field: value} of what an extension.yaml's uncertainty: section states (CorrectionError, one
    line, when it cannot be read or a value is not a standard uncertainty of its key)."""
    from force_tester_sim.core.errors import SimError
    from force_tester_sim.core.uncertainty import check_departure_u, overrides_from_data
    try:
        doc = yaml.safe_load(Path(extension_file).read_text()) or {}
    except (OSError, yaml.YAMLError) as exc:
        raise CorrectionError(f'extension file {str(extension_file)!r} cannot be read: {exc}') from None
    if not isinstance(doc, dict):
        raise CorrectionError(f'extension file {str(extension_file)!r} holds {doc!r}; expected a mapping')
    corr = doc.get('correction') or {}
    try:
        stated = dict(overrides_from_data(doc.get('uncertainty')))
    except SimError as exc:
        raise CorrectionError(f'extension file {str(extension_file)!r}: {exc}') from None
    unknown = sorted(set(stated) - set(EXTENSION_KEYS))
    if unknown:
        raise CorrectionError(f'extension file {str(extension_file)!r}: uncertainty.{unknown[0]} is not an input '
                              f'of the corrected peak; expected some of {sorted(EXTENSION_KEYS)}')
    used = {'mass': float(corr.get('mass_kg') or rig.force_chain.moving_side_mass_kg),
            'gain': float(corr.get('moving_cell_gain') or 1.0)}
    out = {}
    for key, u in stated.items():
        field, rel_to = EXTENSION_KEYS[key]
        if rel_to is None:
            out[field] = u
            continue
        value = used[rel_to] if rel_to in used else _constant(rig, rel_to)
        try:
            check_departure_u(key, u, value)   # no u above its value (the rig's rule)
        except SimError as exc:
            raise CorrectionError(f'extension file {str(extension_file)!r}: {exc}') from None
        out[field] = u / value
    return out


def _constant(rig, key: str) -> float:
    section, name = key.split('.')
    return float(getattr(getattr(rig, section), name))


def validator_params(extension_file: str | Path | None = None, rig_file: str | Path | None = None) -> dict:
    """The validator node's peak_u_* parameters: peak_inputs of the rig the correction assumes (the nominal rig
    unless ``rig_file``) and its extension."""
    from dataclasses import asdict

    from force_tester_sim.core.params import NOMINAL_YAML, load_rig
    inputs = peak_inputs(load_rig(rig_file or NOMINAL_YAML), extension_file)
    return {f'peak_u_{k}': float(v) for k, v in asdict(inputs).items()}
