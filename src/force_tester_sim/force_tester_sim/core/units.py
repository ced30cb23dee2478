"""Unit constants (SI inside; lbf and fps for display only)."""

LBF_N = 4.4482216152605      # 1 lbf in newtons
FT_M = 0.3048                # 1 ft in metres
G_M_S2 = 9.80665             # standard gravity, m/s^2
NS_PER_S = 1_000_000_000
