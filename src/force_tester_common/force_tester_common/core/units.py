"""Units: SI inside every package; lbf, fps and g only for display and for the thesis's tables."""

LBF_N = 4.4482216152605      # 1 lbf in newtons
FT_M = 0.3048                # 1 ft in metres
G_M_S2 = 9.80665             # standard gravity, m/s^2


def n_to_lbf(force_n):
    return force_n / LBF_N
