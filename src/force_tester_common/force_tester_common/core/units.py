"""Units: SI inside every package; lbf, fps and g only for display, for the thesis's tables and for
the channel maps of DAQ files (volts and lab units -> SI).

``UNITS`` is the one table of units: canonical name -> (dimension, factor to the SI unit of that
dimension). ``SYMBOLS`` and ``WORDS`` give the other ways labs write them (``Newtons``, ``m/s²``, ``G``, ``mv``);
``unit_name`` is the one lookup that reads them all, so a channel map's units, sensitivities, scales and
ranges and a file's own unit labels accept the same spellings. ``CHANNEL_DIMENSION`` gives each workspace
channel's dimension (its SI unit is ``SI_UNIT[dimension]``).
"""
from typing import NamedTuple

LBF_N = 4.4482216152605      # 1 lbf in newtons
FT_M = 0.3048                # 1 ft in metres
G_M_S2 = 9.80665             # standard gravity, m/s^2
IN_M = 0.0254                # 1 in in metres

#: SI unit of each dimension ('bridge': a strain-gauge bridge's output per volt of excitation).
SI_UNIT = {'force': 'N', 'acceleration': 'm/s^2', 'length': 'm', 'voltage': 'V', 'current': 'A',
           'velocity': 'm/s', 'time': 's', 'bridge': 'V/V'}

#: canonical unit name -> (dimension, factor to SI). 'g' is standard gravity (there is no mass here).
UNITS = {
    'N': ('force', 1.0), 'kN': ('force', 1e3), 'mN': ('force', 1e-3), 'lbf': ('force', LBF_N),
    'm/s^2': ('acceleration', 1.0), 'g': ('acceleration', G_M_S2),
    'm': ('length', 1.0), 'mm': ('length', 1e-3), 'um': ('length', 1e-6), 'in': ('length', IN_M),
    'ft': ('length', FT_M),
    'V': ('voltage', 1.0), 'mV': ('voltage', 1e-3), 'uV': ('voltage', 1e-6),
    'A': ('current', 1.0), 'mA': ('current', 1e-3),
    'm/s': ('velocity', 1.0), 'ft/s': ('velocity', FT_M),
    's': ('time', 1.0), 'ms': ('time', 1e-3),
    'V/V': ('bridge', 1.0), 'mV/V': ('bridge', 1e-3),
}

#: Symbols as labs write them -> canonical name, matched with their case: M is mega and m milli, so 'MV', 'MN'
#: and 'M' are not units here; 'G' is g (standard gravity: no gram is in the table).
SYMBOLS = {
    'm/s2': 'm/s^2', 'm/s**2': 'm/s^2', 'm/s/s': 'm/s^2', 'ms^-2': 'm/s^2', 'ms-2': 'm/s^2', 'm*s^-2': 'm/s^2',
    'm/sec^2': 'm/s^2', 'm/sec2': 'm/s^2',
    'G': 'g', 'gn': 'g', 'g0': 'g', "g's": 'g',
    'KN': 'kN', 'kn': 'kN', 'n': 'N', 'mn': 'mN', 'lb-f': 'lbf', 'lbs-f': 'lbf',
    'v': 'V', 'mv': 'mV', 'uv': 'uV', 'a': 'A', 'ma': 'mA',
    'fps': 'ft/s', 'ft/sec': 'ft/s', 'm/sec': 'm/s',
    'IN': 'in', 'FT': 'ft', 'mv/v': 'mV/V', 'mV/v': 'mV/V', 'v/v': 'V/V',
}

#: Names written out -> canonical name, matched in any case ('Newtons', 'VOLT', 'Meters'); PLURAL adds 's'.
WORDS = {
    'newton': 'N', 'kilonewton': 'kN', 'millinewton': 'mN', 'pound-force': 'lbf', 'pound force': 'lbf',
    'pounds-force': 'lbf', 'pounds force': 'lbf', 'lbf': 'lbf',
    'meter per second squared': 'm/s^2', 'metre per second squared': 'm/s^2',
    'meters per second squared': 'm/s^2', 'metres per second squared': 'm/s^2', 'standard gravity': 'g',
    'meter': 'm', 'metre': 'm', 'millimeter': 'mm', 'millimetre': 'mm', 'micrometer': 'um', 'micrometre': 'um',
    'micron': 'um', 'inch': 'in', 'inches': 'in', 'foot': 'ft', 'feet': 'ft',
    'volt': 'V', 'millivolt': 'mV', 'microvolt': 'uV', 'amp': 'A', 'ampere': 'A', 'milliamp': 'mA',
    'milliampere': 'mA', 'meter per second': 'm/s', 'metre per second': 'm/s', 'meters per second': 'm/s',
    'metres per second': 'm/s', 'foot per second': 'ft/s', 'feet per second': 'ft/s',
    'second': 's', 'sec': 's', 'millisecond': 'ms', 'msec': 'ms',
    'volt/volt': 'V/V', 'millivolt/volt': 'mV/V', 'millivolt per volt': 'mV/V', 'millivolts per volt': 'mV/V',
}
PLURAL = ('newton', 'kilonewton', 'millinewton', 'meter', 'metre', 'millimeter', 'millimetre', 'micrometer',
          'micrometre', 'micron', 'volt', 'millivolt', 'microvolt', 'amp', 'ampere', 'milliamp', 'milliampere',
          'second', 'sec', 'millisecond', 'msec')
WORDS.update({w + 's': WORDS[w] for w in PLURAL})
#: Characters labs put in unit labels, as the tables above spell them.
_GLYPHS = {'⁻²': '^-2', '²': '^2', '·': '*', '⋅': '*', 'µ': 'u', 'μ': 'u', '[': '', ']': ''}


def unit_name(name) -> str | None:
    """The canonical name (a key of UNITS) of a unit as a lab writes it, or None when it is not known.

    Tried in order: the canonical name; the symbols of SYMBOLS, case kept (``G`` is g, ``mv`` is mV, but ``MV``
    and ``M`` are nothing: M is mega); the names of WORDS in any case, singular or plural (``Newtons``,
    ``VOLTS``). ``²``, ``µ``/``μ``, ``·``, brackets and the spaces inside a symbol are read as ``^2``, ``u``,
    ``*`` and nothing."""
    if not isinstance(name, str):
        return None
    text = name.strip()
    if text in UNITS:
        return text
    for glyph, ascii_ in _GLYPHS.items():
        text = text.replace(glyph, ascii_)
    words = ' '.join(text.replace('_', ' ').split()).lower()
    if words in WORDS:
        return WORDS[words]
    text = ''.join(text.split())
    return text if text in UNITS else SYMBOLS.get(text)


class Unit(NamedTuple):
    """A unit's dimension ('force', 'acceleration', ...) and its factor to SI."""

    dimension: str
    factor: float


def unit(name) -> Unit | None:
    """A unit as a lab writes it (see unit_name), or None when it is not known."""
    canon = unit_name(name)
    return None if canon is None else Unit(*UNITS[canon])


def known_units() -> str:
    """What an error about an unknown unit lists: the canonical names (their spellings are read too)."""
    return ', '.join(UNITS) + ' (and their names, plurals and other spellings: Newtons, G, m/s², ...)'


#: workspace channel -> dimension (the channel's unit is SI_UNIT of it).
CHANNEL_DIMENSION = {
    'time_s': 'time', 'encoder_position_m': 'length', 'accel_axial_m_s2': 'acceleration',
    'force_moving_n': 'force', 'force_stationary_n': 'force', 'motor_current_a': 'current',
    'motor_voltage_v': 'voltage', 'motor_velocity_cmd_m_s': 'velocity',
    'accel_lateral_m_s2': 'acceleration', 'accel_vertical_m_s2': 'acceleration',
}


def n_to_lbf(force_n):
    return force_n / LBF_N
