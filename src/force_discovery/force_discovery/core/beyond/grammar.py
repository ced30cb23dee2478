"""The grammar the search draws its terms from, per channel: the product terms of the signals (their one home:
force_tester_sim.core.extra_terms), the channels searched and in what order, what each channel leaves out, and the
smallest contribution that matters on a channel. ROS-free."""
from __future__ import annotations

import functools
import itertools
from typing import Dict, List, Tuple

from force_tester_sim.core.extra_terms import MAX_POWER, SIGNALS, SIN, parse_term, term_name

# the channels whose residual the search forms (the package docstring), in the order they are searched: the sensors
# seen on their own (in the free phases) first, then the moving cell and the motor current, whose residuals are
# formed with the stationary cell and the accelerometer (SENSORS: their terms are taken out of T and a2 first)
SEARCHED = ('force_stationary', 'accel_axial', 'force_moving', 'motor_current')
SENSORS = ('force_stationary', 'accel_axial')
SIN_FACTORS = ('', 'v', 'F_move')              # sin, v*sin, F_move*sin
# terms on a channel that are catalog entries in another form (the force model's gain and mass): not searched
CATALOG_FORMS = {'force_moving': ('F_move', 'F_stat', 'T', 'a2')}
# signals a channel's residual is made of (in the free phases F_move is m2 a2): no term of its library uses them
OWN_SIGNALS = {'force_stationary': ('F_stat', 'T'), 'accel_axial': ('a2', 'F_move')}
# each channel's scale factor (its sensor's calibration, rig sensors.*): a relative component of every coefficient
RELATIVE = {'force_moving': ('cell_sensitivity', 'sensors.load_cell_sensitivity_mv_per_lbf',
                             'load_cell_sensitivity_mv_per_lbf'),
            'force_stationary': ('cell_sensitivity', 'sensors.load_cell_sensitivity_mv_per_lbf',
                                 'load_cell_sensitivity_mv_per_lbf'),
            'accel_axial': ('accelerometer_sensitivity', 'sensors.accelerometer_sensitivity_mv_per_g',
                            'accelerometer_sensitivity_mv_per_g')}
COULOMB = 'coulomb_friction'   # the catalog cause that is a library column on the motor current


def library() -> List[str]:
    """The product terms of the grammar (every product of total degree <= 2 and every single signal cubed), in a
    fixed order."""
    out = []
    for deg in (1, 2):
        for combo in itertools.combinations_with_replacement(SIGNALS, deg):
            out.append(term_name({s: combo.count(s) for s in combo}))
    out += [term_name({s: MAX_POWER}) for s in SIGNALS]
    return out


@functools.lru_cache(maxsize=None)
def channel_library(channel: str) -> Tuple[str, ...]:
    """The product terms searched on a channel: the library less the catalog's forms and the channel's own
    signals (CATALOG_FORMS, OWN_SIGNALS)."""
    skip, own = CATALOG_FORMS.get(channel, ()), set(OWN_SIGNALS.get(channel, ()))
    return tuple(t for t in library() if t not in skip and not own & set(parse_term(t)))


def channel_band(channel: str, rig) -> float:
    """The smallest contribution (rms, channel unit) that matters: force channels the hum tolerance (the smallest
    force the rig's tolerances care about), the motor current the Coulomb friction tolerance in A."""
    tol = rig.tolerances
    if channel == 'motor_current':
        return tol.coulomb_friction_n / rig.drive.force_per_amp_n_per_a
    if channel == 'accel_axial':
        return tol.mains_hum_amplitude_n / rig.force_chain.m2
    return tol.mains_hum_amplitude_n


def si_factor(term: str, scales: Dict[str, float]) -> float:
    """The factor from a coefficient on the scaled column to the SI coefficient."""
    out = 1.0
    for s, k in parse_term(term).items():
        if s != SIN:
            out /= scales[s] ** k
    return out
