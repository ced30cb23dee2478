"""What a campaign's channels can identify: which quantities need which channel, which path a campaign
lacking channels takes, and the identifiable / not_identifiable lists of report.json and report.md. ROS-free."""
from __future__ import annotations

from typing import Sequence, Tuple

from .errors import DiscoveryError

FORCE, ACCEL = 'force_moving_n', 'accel_axial_m_s2'
FREE_CHANNELS = (FORCE, ACCEL)
REFERENCE_CHANNELS = ('force_stationary_n', 'encoder_position_m')

# what each quantity needs, and why (report.json identifiable / not_identifiable)
QUANTITIES = (
    ('gain_mass_product', FREE_CHANNELS, 'g m2: the moving cell\'s gain times the mass in front of it, from the '
     'free phases (F_move = g m2 a2)'),
    ('accel_delay', FREE_CHANNELS, 'the accelerometer\'s delay against the moving cell, from the free phases'),
    ('ringing_modes', (ACCEL,), 'the free structure\'s modes in a2 after the event (a mount mode among them)'),
    ('mains_hum', (FORCE,), 'the line frequency and amplitude on the moving cell, from the free phases'),
    ('data_quality', (), 'spikes, overloads, clipping, held values, NaN, time gaps, stuck channels'),
    ('moving_cell_gain', ('force_stationary_n',), 'g and m2 separate only with a reference (the stationary cell) '
     'or a known calibration mass'),
    ('effective_mass', ('force_stationary_n',), 'g and m2 separate only with a reference (the stationary cell) or '
     'a known calibration mass'),
    ('ac_coupling', ('force_stationary_n',), 'the cell\'s slow decay is judged against the reference cell\'s '
     'force during the event'),
    ('corrected_force_error', ('force_stationary_n',), 'how far the corrected force is from the force at the '
     'specimen needs the cell at the specimen'),
    ('cell_damping', ('force_stationary_n',), 'measured on the stationary cell\'s free decay'),
    ('coulomb_friction', ('motor_current_a', 'encoder_position_m'), 'the drive\'s force balance needs the motor '
     'current and the carriage motion'),
    ('simulation_check', ('encoder_position_m', 'force_stationary_n'), 'the re-simulation is driven by the '
     'measured carriage motion and fitted to the tension'),
)
COMPUTED = ('gain_mass_product', 'accel_delay', 'ringing_modes', 'mains_hum', 'data_quality')


def needs_reference_free(absent: Sequence[str]) -> bool:
    """Whether a campaign lacking these channels takes the reference-free path (no stationary cell or no
    encoder)."""
    return any(c in absent for c in REFERENCE_CHANNELS)


def check_core_channels(absent: Sequence[str], name: str = 'campaign') -> None:
    """One line when the moving cell (or the accelerometer) is absent: nothing to correct."""
    from bag_tools.core.daqfiles import NOTHING_TO_CORRECT
    for c in FREE_CHANNELS:
        if c in absent:
            raise DiscoveryError(f'{name} has no {c!r} channel; {NOTHING_TO_CORRECT}')


def identifiability(absent: Sequence[str], computed: Sequence[str] = COMPUTED, few: int = 0) -> Tuple[list, list]:
    """(identifiable, not_identifiable) for a campaign lacking ``absent``: each {quantity, needs, what} or
    {quantity, needs, missing, reason}; computed: what this analysis computes of the quantities whose channels
    are there (the rest is listed as not identifiable by this path, with the reason); few: the analysis with a
    reference was not run because it needs this many pulls."""
    yes, no = [], []
    for q, needs, what in QUANTITIES:
        missing = [c for c in needs if c in absent]
        if missing:
            no.append({'quantity': q, 'needs': list(needs), 'missing': missing,
                       'reason': f'needs {", ".join(missing)} (absent): {what}'})
        elif q in computed:
            yes.append({'quantity': q, 'needs': list(needs), 'what': what})
        elif few:
            no.append({'quantity': q, 'needs': list(needs), 'missing': [],
                       'reason': f'needs at least {few} pulls (half fitted, half held out) for the analysis with a '
                                 f'reference: {what}'})
        else:
            lack = [c for c in REFERENCE_CHANNELS if c in absent]
            no.append({'quantity': q, 'needs': list(needs), 'missing': lack,
                       'reason': f'needs {", ".join(lack)} (absent) too: its own channels are here, but the analysis '
                                 f'with a reference needs {" and ".join(REFERENCE_CHANNELS)} together: {what}'})
    return yes, no


def full_identifiability(tested: Sequence[str]) -> Tuple[list, list]:
    """(identifiable, not_identifiable) of a campaign with its reference: the catalog causes tested (``tested``)
    and the simulation check; coulomb_friction without a motor current channel is not identifiable."""
    yes = [{'quantity': q, 'needs': list(needs), 'what': what} for q, needs, what in QUANTITIES
           if q in tested or q in ('data_quality', 'simulation_check', 'cell_damping')]
    yes += [{'quantity': q, 'needs': list(REFERENCE_CHANNELS + FREE_CHANNELS), 'what': 'catalog cause'}
            for q in tested if q not in {y['quantity'] for y in yes}]
    no = [] if 'coulomb_friction' in tested else [
        {'quantity': 'coulomb_friction', 'needs': ['motor_current_a', 'encoder_position_m'],
         'missing': ['motor_current_a'], 'reason': 'needs motor_current_a (absent): the drive\'s force balance'}]
    return yes, no


def identifiability_lines(report: dict) -> list:
    """report.md's lines on what the channels identify (both paths)."""
    yes, no = report.get('identifiable'), report.get('not_identifiable')
    if not isinstance(yes, list):   # absent, or {'not_available': why} (no usable pull: nothing was analysed)
        return []
    out = ['## Identifiable from these channels', '', ', '.join(q['quantity'] for q in yes) or '-', '']
    if isinstance(no, list) and no:
        out += ['Not identifiable:', ''] + [f'- {q["quantity"]}: {q["reason"]}' for q in no]
        out.append('')
    return out
