"""One pull -> PNG like thesis Figures 10-16: forces, accelerometer, encoder position/velocity.

matplotlib is imported lazily (only here, only when plotting), with the Agg backend.
"""

from __future__ import annotations

from pathlib import Path
from typing import NamedTuple

import numpy as np

from bag_tools.core.convert import read_bag_pulls
from bag_tools.core.daq import DaqPull, read_campaign
from bag_tools.core.sources import source_kind
from force_tester_common.core.units import FT_M, G_M_S2, LBF_N

from ..core.errors import CorrectionError
from ..core.params import CorrectionParams
from ..core.streaming import correct_signal


def _pyplot():
    try:
        import matplotlib  # optional dependency
        matplotlib.use('Agg')
        import matplotlib.pyplot as plt
    except ImportError:
        raise CorrectionError('plotting needs matplotlib: pip install matplotlib (see '
                       'requirements.txt)') from None
    return plt


class LoadedPull(NamedTuple):
    """One pull of a campaign or bag, and its sample rate."""

    pull: DaqPull
    rate_hz: float


def load_pull(src: str | Path, pull: int, warnings: list | None = None) -> LoadedPull:
    """Pull number `pull` (1-based position in the campaign or bag, in time order)."""
    warnings = [] if warnings is None else warnings
    if source_kind(src) == 'campaign':
        camp = read_campaign(src)
        pulls, rate = camp.pulls, camp.sample_rate_hz
        warnings.extend(camp.warnings)
    else:
        rate, pulls = read_bag_pulls(src, warnings)
    if isinstance(pull, bool) or not isinstance(pull, int) or not 1 <= pull <= len(pulls):
        raise CorrectionError(f'pull {pull!r} is out of range; expected 1..{len(pulls)} '
                       f'({len(pulls)} pull(s) in {str(src)!r})')
    return LoadedPull(pulls[pull - 1], rate)


def plot_pull(pull: DaqPull, rate_hz: float, out: str | Path, si: bool = False,
              params: CorrectionParams | None = None, title: str | None = None,
              full: bool = False) -> Path:
    """Write the figure of one pull to `out` (PNG). Corrected force: the campaign's
    corrected/filtered columns when present, else computed with the correction core. The time
    axis shows the pull (stationary cell above 5 % of its peak, from 20 ms before to 60 ms after)
    unless `full`."""
    plt = _pyplot()
    params = CorrectionParams() if params is None else params
    ch = pull.channels
    t = ch['time_s'] * 1e3
    if 'corrected_n' in ch and 'filtered_n' in ch:
        corrected, filtered = ch['corrected_n'], ch['filtered_n']
    else:
        res = correct_signal(ch['force_moving_n'], ch['accel_axial_m_s2'], params)
        corrected, filtered = res.corrected_n, res.filtered_n
    f_unit, f_k = ('N', 1.0) if si else ('lbf', 1.0 / LBF_N)
    a_unit, a_k = ('m/s$^2$', 1.0) if si else ('g', 1.0 / G_M_S2)
    x_unit, x_k = ('m', 1.0) if si else ('ft', 1.0 / FT_M)
    v_unit = 'm/s' if si else 'ft/s'
    pos = ch['encoder_position_m']
    vel = np.gradient(pos, 1.0 / rate_hz)
    fig, axes = plt.subplots(3, 1, figsize=(9, 10), sharex=True)
    ax = axes[0]
    ax.plot(t, ch['force_stationary_n'] * f_k, label='stationary cell', lw=1.0)
    ax.plot(t, ch['force_moving_n'] * f_k, label='moving cell (raw)', lw=0.8)
    ax.plot(t, corrected * f_k, label='corrected (F - m a)', lw=0.8)
    ax.plot(t, filtered * f_k, label=f'corrected + MA({params.window})', lw=1.0)
    ax.set_ylabel(f'force, {f_unit}')
    ax.legend(loc='upper right', fontsize=8)
    ax = axes[1]
    ax.plot(t, ch['accel_axial_m_s2'] * a_k, label='axial', lw=0.8)
    for col, lab in (('accel_lateral_m_s2', 'lateral'), ('accel_vertical_m_s2', 'vertical')):
        if col in ch:
            ax.plot(t, ch[col] * a_k, label=lab, lw=0.6)
    ax.set_ylabel(f'acceleration, {a_unit}')
    ax.legend(loc='upper right', fontsize=8)
    ax = axes[2]
    ax.plot(t, pos * x_k, label='position', color='C0')
    ax.set_ylabel(f'position, {x_unit}')
    ax2 = ax.twinx()
    ax2.plot(t, vel * x_k, label='velocity (gradient)', color='C1', lw=0.8)
    ax2.set_ylabel(f'velocity, {v_unit}')
    ax.set_xlabel('time, ms')
    loaded = np.flatnonzero(np.nan_to_num(ch['force_stationary_n']) > 0.05 * np.nanmax(ch['force_stationary_n']))
    if not full and len(loaded):
        axes[0].set_xlim(t[loaded[0]] - 20.0, t[loaded[-1]] + 60.0)
    m = pull.meta
    fig.suptitle(title or f"pull {m.get('pull_id') or ''} set {m['set']}: coupon "
                 f"{m['coupon_lbf']:g} lbf, {m['velocity_fps']:g} ft/s, {m['decel_g']:g} g")
    fig.tight_layout()
    out = Path(out)
    try:
        fig.savefig(out, dpi=110)
    finally:
        plt.close(fig)
    return out
