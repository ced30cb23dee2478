"""The grammar the search draws its terms from, per channel: the product terms of the signals (their one home:
force_tester_sim.core.extra_terms), the channels searched and in what order, what each channel leaves out, and the
smallest contribution that matters on a channel. ROS-free."""
from __future__ import annotations

import functools
import itertools
from typing import Dict, List, Optional, Tuple

from force_tester_sim.core.extra_terms import MAX_POWER, SIGNALS, SIN, parse_term, term_name

# the channels whose residual the search forms (the package docstring), in the order they are searched: the sensors
# seen on their own (in the free phases) first, then the moving cell and the motor current, whose residuals are
# formed with the stationary cell and the accelerometer (SENSORS: their terms are taken out of T and a2 first)
SEARCHED = ('force_stationary', 'accel_axial', 'force_moving', 'motor_current')
SENSORS = ('force_stationary', 'accel_axial')
SIN_FACTORS = ('', 'v', 'F_move')              # sin, v*sin, F_move*sin
# terms on a channel that are catalog entries in another form: not searched, listed with the reason (structural_reason).
# The moving cell's: the force model's gain and mass. The motor current's: the drive's k_F, reflected mass and damping,
# which the catalog calibrates (friction.drive_fit) and the search fits beside every term there (DRIVE_FORMS): F_move
# is exactly k_F's form less the mass's and the damping's (1 - r^2 against the three 5e-14, the independent
# generator's nominal campaign, seed 3900, pooled over its fitted pulls), F_stat and T the same tension through the
# other cell (1.4e-6, 1.6e-6), a2 the mass's form a3 as the accelerometer reads it (3.5e-4: 1.9 % of the column
# beside them). The damping's own form, v, stays searched: the catalog keeps its stated +/-50 %, and a v beyond it is
# named (a term inside it is listed, selection.search_channel)
CATALOG_FORMS = {'force_moving': ('F_move', 'F_stat', 'T', 'a2'), 'motor_current': ('F_move', 'F_stat', 'T', 'a2')}
FORM_REASONS = {
    'force_moving': "the catalog's form: the force model fits it (F_move = g (T + m2 a2): the gain, the effective "
                    'mass); named as that catalog cause, never as a term',
    'motor_current': "the drive's form: the current's balance is (m_c a3 + b v + F_move) / k_F, and the catalog fits "
                     "k_F, the reflected mass m_c and the damping b on the data (friction.drive_fit); a term in "
                     'F_move is in the span of their forms (F_stat and T read the same tension, and a2 the '
                     "acceleration whose encoder form a3 is the mass's), so the data cannot tell it from those "
                     'constants off their rig YAML values',
}
# a sensor's own terms are written in the quantity it should read (its reference, in its free phases): the
# accelerometer's a2 takes the encoder's acceleration there (series.channel_series), so its own non-linearity
# (a2^2, a2^3) is searched against it; signals a sensor's free-phase library cannot use, and why (identifiability)
FREE_PHASE_BLIND = {
    'force_stationary': {**{s: 'in the free phases the lanyard is slack: the tension from the moving side is 0, and so '
                            f'is every term in {s} there; a term of degree >= 2 in F_stat and T alone is searched '
                            'on the moving cell, which reads the same tension (beyond.own), and read as the '
                            "stationary cell's own; a linear one is the moving cell's gain (the catalog); a product "
                            "with another signal is the moving cell's term of the same name: two cells that read "
                            'one tension cannot tell whose it is' for s in ('F_stat', 'T')},
                         'F_move': 'in the free phases the moving cell reads g m2 a2: F_move is a2 times a constant '
                                   "there, collinear with the stationary cell's a2 terms; under load the stationary "
                                   "cell's reading reaches the moving cell's model as T, so such a term is the moving "
                                   "cell's term of the same name there, with T for F_move when its other factors are "
                                   'not forces (F_move alone: its gain, the catalog), which the two cells cannot tell '
                                   'apart; searched there'},
    'accel_axial': {'F_move': 'in the free phases the moving cell reads g m2 a2: F_move is a2 times a constant '
                              "there, collinear with the accelerometer's own a2 terms",
                    **{s: f'in the free phases the lanyard is slack: {s} is 0 there, and so is every term in it; under '
                          "load such a term in the accelerometer's reading reaches the moving cell's model as g m2 "
                          'times it: the column of that term on the moving cell (or, of the forces alone, of the '
                          "stationary cell's own), which these channels cannot tell it from (only the motor current "
                          'could, through the force the carriage feels, far inside its band); searched there' for s in
                       ('F_stat', 'T')}},
}
# the signals through which a sensor's reading enters the moving cell's model (T from the stationary cell, m2 a2 from
# the accelerometer): a term of degree >= 2 in these alone on the moving cell is the sensor's own (beyond.own)
CARRIED = {'force_stationary': ('F_stat', 'T'), 'accel_axial': ('a2',)}
# each channel's scale factor (its sensor's calibration, rig sensors.*): a relative component of every coefficient
RELATIVE = {'force_moving': ('cell_sensitivity', 'sensors.load_cell_sensitivity_mv_per_lbf',
                             'load_cell_sensitivity_mv_per_lbf'),
            'force_stationary': ('cell_sensitivity', 'sensors.load_cell_sensitivity_mv_per_lbf',
                                 'load_cell_sensitivity_mv_per_lbf'),
            'accel_axial': ('accelerometer_sensitivity', 'sensors.accelerometer_sensitivity_mv_per_g',
                            'accelerometer_sensitivity_mv_per_g')}
FORCES = ('F_move', 'F_stat', 'T')     # the cells' forces: the moving cell's, the stationary cell's, the tension
COULOMB = 'coulomb_friction'   # the catalog cause that is a library column on the motor current
GAIN, MASS = 'moving_cell_gain', 'effective_mass'
# the force model's causes whose forms (F_move, a2) are the moving cell's catalog columns, in that order: a term there
# is fitted with them beside it, and named only when it beats each in its place (selection.search_channel)
FORCE_FORMS = (GAIN, MASS)
# the drive's viscous damping (rig drive.viscous_damping_*): a catalog constant whose form on the motor current is the
# library's `v` (its departure from the rig YAML's, in A per m/s). A term on the current is fitted with it beside,
# so the data measure the damping rather than its stated +/-50 % entering the term's budget, and a term is named
# only when it beats it, and the Coulomb step, in its place (selection.search_channel)
DAMPING, DAMPING_FORM = 'viscous_damping', 'v'
# the drive's force per amp k_F and reflected mass (rig drive.*: the torque constant, the pulley, the inertias): their
# forms on the motor current, the drive force the model of record needs (m_c a3 + b v3 + F_move, over k_F) and a3 over
# k_F, are its catalog columns after the Coulomb step, in this order. A term there is fitted with both beside it, so
# the data measure them rather than their stated uncertainties (the reflected inertia's 5 %, k_F's 2.24 %) entering
# the term's budget, and it is named only when it beats each in its place (selection.search_channel)
DRIVE_FORMS = ('drive_force_per_amp', 'drive_reflected_mass')


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
    """The product terms searched on a channel: the library less the catalog's forms and the signals its free
    phases cannot use (CATALOG_FORMS, FREE_PHASE_BLIND)."""
    skip, blind = CATALOG_FORMS.get(channel, ()), set(FREE_PHASE_BLIND.get(channel, ()))
    return tuple(t for t in library() if t not in skip and not blind & set(parse_term(t)))


def reads_own(channel: str, term: str) -> bool:
    """Whether a sensor's term is in its own reading (a2 on the accelerometer: CARRIED): in the free phases it reads
    the quantity it reads under load, so its size is judged over the analysis window even when a near-tied term
    stands beside it (selection.search_channel)."""
    return bool(set(CARRIED.get(channel, ())) & set(parse_term(term)))


def via_moving(channel: str, term: str) -> bool:
    """Whether a sensor's term is its own non-linearity (degree >= 2 in its CARRIED signals' first), which the moving
    cell's search reads too (beyond.own)."""
    p = parse_term(term)
    return channel in CARRIED and SIN not in p and sum(p.values()) >= 2 and set(p) == {CARRIED[channel][0]}


def read_as(channel: str, term: str) -> Tuple[str, str]:
    """(channel, term) as the report reads a pair found on channel: a moving-cell term of degree >= 2 in one
    sensor's CARRIED signals alone is that sensor's own non-linearity, written in its own signal (beyond.own); any
    other pair as it is."""
    p = parse_term(term)
    if channel == 'force_moving' and SIN not in p and sum(p.values()) >= 2:
        sensor = next((s for s, sig in CARRIED.items() if set(p) <= set(sig)), None)
        if sensor is not None:
            return sensor, term_name({CARRIED[sensor][0]: sum(p.values())})
    return channel, term


def structural_tie(channel: str, term: str) -> Optional[str]:
    """'channel:term' of the pair the search names in place of a pair the grammar keeps off its channel
    (structural_reason), when that is a term (None: a catalog form, or a pair that is searched): the sensor's own
    reading of a term in its signals alone, or, for a sensor term in a signal its free phases cannot use, the moving
    cell's term that reads it under load (times -g or -g m2): of the same name for the accelerometer (m2 a2 in the
    moving cell's model), with F_stat as T for the stationary cell (its reading enters the model as T, made from it
    through its dynamics: on the independent generator its F_stat*v, x, t were named T*v, x, t there)."""
    p = parse_term(term)
    if SIN in p or structural_reason(channel, term) is None or term in CATALOG_FORMS.get(channel, ()):
        return None
    own = read_as('force_moving', term) if channel in ('force_moving', *CARRIED) else (channel, term)
    if own[0] != 'force_moving' and own != (channel, term):   # a sensor's own reading, searched through the moving cell
        return ':'.join(own)
    if channel == 'force_stationary':   # its reading reaches the moving cell's model as T, made from it
        # through its dynamics: a term in F_stat is the moving cell's term in T, and so is one in F_move times a
        # signal that is not a force (v, x, t: the two cells' forces differ by m2 a2 there). On the independent
        # generator's sweep (3x the band, seed 3900) the stationary cell's F_move*v, x, t were named T*v, x, t on the
        # moving cell in 6 cells of 6, as its F_stat*v, x, t were
        moved = ('F_stat', 'F_move') if len(p) > 1 and set(p) <= {'F_move', 'v', 'x', 't'} else ('F_stat',)
        q = {k: n for k, n in p.items() if k not in moved}
        q['T'] = q.get('T', 0) + sum(p.get(k, 0) for k in moved)
        own = ('force_moving', term_name(q))
    if channel in FREE_PHASE_BLIND and own[1] not in CATALOG_FORMS['force_moving']:
        return ':'.join(own)
    return None


def catalog_reading(channel: str, term: str) -> Optional[str]:
    """The catalog cause the search names in place of a linear pair the grammar keeps off a force or accelerometer
    channel (structural_reason), or None: on the moving cell the force model's own forms (F_move, F_stat, T: its
    gain; a2: its effective mass), and a linear force on a sensor, which reaches the moving cell's model as the same
    force times a constant (the stationary cell's reading as T, the accelerometer's as g m2 times it): the gain. On
    the independent generator's sweep (3x the band, nominal rig, seed 3900) every one of these 20 cells was named as
    that cause. The motor current's forms have none: the drive's constants are calibrated, not named."""
    if channel == 'motor_current' or structural_reason(channel, term) is None:
        return None
    p = parse_term(term)
    if len(p) != 1 or sum(p.values()) != 1:
        return None
    if term in FORCES:
        return GAIN
    return MASS if channel == 'force_moving' and term == 'a2' else None


def mixed_forces(term: str) -> bool:
    """Whether a term is a product of two cells' forces (F_move*T, F_move*F_stat, F_stat*T): no one sensor reads it,
    so a tie goes to a term in one force alone (selection.search_channel)."""
    p = parse_term(term)
    return len(p) > 1 and set(p) <= set(FORCES)


# the force a cell's channel reads itself: its column carries the channel's own departure (an error in the variables)
OWN_FORCE = {'force_moving': 'F_move', 'force_stationary': 'F_stat'}


def own_power(channel: str, term: str) -> int:
    """The power of the channel's own force (OWN_FORCE) in a term: 0 on a channel that reads none of the forces."""
    return parse_term(term).get(OWN_FORCE.get(channel, ''), 0)


def force_form(term: str) -> Tuple[Tuple[str, int], ...]:
    """A term's form with the cells' forces taken as one (FORCES: F_move, F_stat, T -> F; F_move^3 and F_stat^3 are
    one form, T^2 and T^3 are two): between two terms of one form, the held-out pulls' signs lean away from the
    channel's own force (own_power), so they are not trusted to move a term off it (selection.search_channel)."""
    out: Dict[str, int] = {}
    for k, n in parse_term(term).items():
        key = 'F' if k in FORCES else k
        out[key] = out.get(key, 0) + n
    return tuple(sorted(out.items()))


def pairs() -> List[Tuple[str, str]]:
    """Every (channel, term) pair of the grammar: each searched channel's product terms and sinusoids."""
    sins = [term_name({f: 1, SIN: 1}) if f else SIN for f in SIN_FACTORS]
    return [(ch, t) for ch in SEARCHED for t in library() + sins]


def structural_reason(channel: str, term: str) -> Optional[str]:
    """Why a pair of the grammar is not searched as it stands on its channel (None: it is), from the grammar alone:
    a catalog form, or a signal the channel's free phases cannot use."""
    if term in CATALOG_FORMS.get(channel, ()):
        return FORM_REASONS[channel]
    p = parse_term(term)
    sensor = next((s for s, sig in CARRIED.items() if set(p) <= set(sig) and SIN not in p
                   and channel in ('force_moving', s)), None)
    own = None if sensor is None else term_name({CARRIED[sensor][0]: sum(p.values())})
    if sensor is not None and sum(p.values()) >= 2 and (term != own or channel != sensor):
        where = 'moving cell' if channel == 'force_moving' else 'sensor'
        return (f"read as {own} on {sensor}: {', '.join(CARRIED[sensor])} alone on the {where} are that sensor's own "
                'reading (beyond.own), and these channels cannot tell the two apart')
    blind = FREE_PHASE_BLIND.get(channel, {})
    if sensor == channel and term == own and not (sum(p.values()) == 1 and own in blind):
        return None   # the sensor's own non-linearity: searched (on the moving cell for the stationary cell)
    hit = [s for s in p if s in blind]
    return blind[hit[0]] if hit else None



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
