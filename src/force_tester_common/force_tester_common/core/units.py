"""Units: SI inside every package; lbf, fps and g only for display, for the thesis's tables and for
the channel maps of DAQ files (volts and lab units -> SI).

``UNITS`` is the one table of unit names: name -> (dimension, factor to the SI unit of that
dimension). ``CHANNEL_DIMENSION`` gives each workspace channel's dimension (its SI unit is
``SI_UNIT[dimension]``).
"""

LBF_N = 4.4482216152605      # 1 lbf in newtons
FT_M = 0.3048                # 1 ft in metres
G_M_S2 = 9.80665             # standard gravity, m/s^2
IN_M = 0.0254                # 1 in in metres

#: SI unit of each dimension.
SI_UNIT = {'force': 'N', 'acceleration': 'm/s^2', 'length': 'm', 'voltage': 'V', 'current': 'A',
           'velocity': 'm/s', 'time': 's'}

#: unit name -> (dimension, factor to SI). Aliases spell the same unit the ways DAQ files do.
UNITS = {
    'N': ('force', 1.0), 'kN': ('force', 1e3), 'mN': ('force', 1e-3), 'lbf': ('force', LBF_N),
    'm/s^2': ('acceleration', 1.0), 'm/s2': ('acceleration', 1.0), 'm/s²': ('acceleration', 1.0),
    'g': ('acceleration', G_M_S2),
    'm': ('length', 1.0), 'mm': ('length', 1e-3), 'um': ('length', 1e-6), 'in': ('length', IN_M),
    'ft': ('length', FT_M),
    'V': ('voltage', 1.0), 'mV': ('voltage', 1e-3), 'uV': ('voltage', 1e-6), 'µV': ('voltage', 1e-6),
    'A': ('current', 1.0), 'mA': ('current', 1e-3),
    'm/s': ('velocity', 1.0), 'ft/s': ('velocity', FT_M), 'fps': ('velocity', FT_M),
    's': ('time', 1.0), 'ms': ('time', 1e-3),
}

#: workspace channel -> dimension (the channel's unit is SI_UNIT of it).
CHANNEL_DIMENSION = {
    'time_s': 'time', 'encoder_position_m': 'length', 'accel_axial_m_s2': 'acceleration',
    'force_moving_n': 'force', 'force_stationary_n': 'force', 'motor_current_a': 'current',
    'motor_voltage_v': 'voltage', 'motor_velocity_cmd_m_s': 'velocity',
    'accel_lateral_m_s2': 'acceleration', 'accel_vertical_m_s2': 'acceleration',
}


def unit(name: str) -> tuple | None:
    """(dimension, factor to SI) of a unit name, or None when it is not known."""
    return UNITS.get(str(name).strip())


def n_to_lbf(force_n):
    return force_n / LBF_N
