"""The discovery's plots (matplotlib, when importable): residuals.png (the held-out force residual and its
spectrum), ringing.png (the free decay with and without the mount mode), simulation.png (measured and
re-simulated). ROS-free."""
from __future__ import annotations

from pathlib import Path
from typing import Optional

import numpy as np

from .force_errors import PLOT_FFT, ForceErrors
from .markdown import CHANNEL_LABELS
from .ringing import cell_modes, damped_basis
from .stages import Analysis

#: the figures' margins in inches (left, right, top, bottom) and the gap between stacked axes: fixed, so that no
#: layout pass measures every label first (tight_layout cost a 12-pull discover 0.2 s of CPU per figure); they
#: hold the titles, the axis labels and tick labels of up to six characters at the saved dpi
MARGINS_IN = (0.85, 0.3, 0.35, 0.5)
DPI = 90


def _save(fig, path: Path, gap_in: float = 0.0) -> str:
    """Lay FIG out on the fixed margins (GAP_IN inches between its stacked axes), write it to PATH, close it."""
    import matplotlib.pyplot as plt
    w, h = fig.get_size_inches()
    left, right, top, bottom = MARGINS_IN
    rows = fig.axes[0].get_gridspec().nrows if fig.axes else 1
    fig.subplots_adjust(left=left / w, right=1 - right / w, top=1 - top / h, bottom=bottom / h,
                        hspace=gap_in / ((h - top - bottom - gap_in * (rows - 1)) / rows))
    fig.savefig(path, dpi=DPI)
    plt.close(fig)
    return str(path)


def beyond_plots(traces, out: Path) -> list:
    """beyond_<k>.png: each term beyond the catalog, its channel's residual on one held-out pull before and after
    it (beyond.traces.TermTrace)."""
    if not traces:
        return []
    try:
        import matplotlib
        matplotlib.use('Agg')
        import matplotlib.pyplot as plt
    except ImportError:
        return []
    from force_tester_sim.core.extra_terms import CHANNEL_UNITS
    paths = []
    for k, tr in enumerate(traces):
        fig, ax = plt.subplots(figsize=(8, 2.6))
        ax.plot(tr.t, tr.before, color='tab:blue', lw=0.6, label='before (the catalog and the other terms)')
        ax.plot(tr.t, tr.after, color='tab:orange', lw=0.6, label=f'after {tr.term}')
        ax.set_title(f'{tr.term} on {tr.channel}: held-out pull {tr.pull}')
        ax.set_xlabel('s from the record start')
        ax.set_ylabel(f'residual, {CHANNEL_UNITS[tr.channel]}')
        ax.legend(fontsize=7)
        paths.append(_save(fig, out / f'beyond_{k + 1}.png'))
    return paths


def simulation_plot(check, out: Path) -> list:
    """simulation.png: measured, nominal-sim and extended-sim channels of one held-out pull, from the load to
    30 ms after the break."""
    if check is None or not check.trace:
        return []
    try:
        import matplotlib
        matplotlib.use('Agg')
        import matplotlib.pyplot as plt
    except ImportError:
        return []
    tr = check.trace
    chans = [ch for ch in CHANNEL_LABELS if ch in tr]
    t = tr['t']
    lo, hi = tr['focus_s']
    sel = (t >= lo) & (t <= hi)
    fig, axes = plt.subplots(len(chans), 1, figsize=(8, 2.2 * len(chans)), sharex=True, squeeze=False)
    for ax, ch in zip(axes[:, 0], chans):
        name, unit = CHANNEL_LABELS[ch]
        for kind, style in (('measured', dict(color='k', lw=0.8)), ('baseline', dict(color='tab:blue', lw=0.6)),
                            ('extended', dict(color='tab:orange', lw=0.6, ls='--'))):
            label = {'baseline': 'sim, model of record', 'extended': 'sim, with extension'}.get(kind, kind)
            ax.plot(1e3 * (t[sel] - lo), tr[ch][kind][sel], label=label, **style)
        ax.set_ylabel(f'{name}, {unit}')
    axes[0, 0].legend(fontsize=7)
    axes[0, 0].set_title(f'held-out pull {tr["pull"]}: measured and re-simulated')
    axes[-1, 0].set_xlabel('ms from 5 ms before the load')
    return [_save(fig, out / 'simulation.png', gap_in=0.25)]


def residual_plots(analysis: Analysis, errors: Optional[ForceErrors], named, rig, out: Path):
    try:
        import matplotlib
        matplotlib.use('Agg')
        import matplotlib.pyplot as plt
    except ImportError:
        return []
    if errors is None or errors.plot is None:
        return []
    pl = errors.plot
    fig, ax = plt.subplots(2, 1, figsize=(8, 6))
    ax[0].plot(pl['t'], pl['base'], lw=0.6, label='model of record')
    ax[0].plot(pl['t'], pl['ext'], lw=0.6, label='extended')
    ax[0].set_xlabel('time, s')
    ax[0].set_ylabel('F_move residual, N')
    ax[0].legend()
    ax[0].set_title(f'held-out pull {pl["pull"]}')
    for lab, P in (('model of record', errors.base_spectrum), ('extended', errors.ext_spectrum)):
        P = P / errors.pulls
        f = np.fft.rfftfreq(PLOT_FFT, pl['dt'])
        ax[1].semilogy(f[1:], P[1:], lw=0.6, label=lab)
    ax[1].set_xlabel('frequency, Hz')
    ax[1].set_ylabel('residual power')
    ax[1].legend()
    ax[1].set_xlim(0, 10000)
    paths = [_save(fig, out / 'residuals.png', gap_in=0.7)]
    ring = analysis.ring
    if ring and 'mount_resonance' in named and ring.get('segment') is not None:
        fc = rig.force_chain
        seg, dt = ring['segment'], ring['segment_dt']
        tt = np.arange(len(seg)) * dt * 1e3
        fig, ax = plt.subplots(figsize=(8, 3.5))
        ax.plot(tt, seg, lw=0.6, label='measured a2 - a3 after the break')
        for lab, modes in (('model of record (cell mode)', cell_modes(fc)),
                           ('extended (mount mode)', cell_modes(fc) + [(ring['fo'], ring['zo'])])):
            X = np.hstack([damped_basis(len(seg), dt, f, z) for f, z in modes] + [np.ones((len(seg), 1))])
            c, *_ = np.linalg.lstsq(X, seg, rcond=None)
            ax.plot(tt, seg - X @ c, lw=0.6, label=f'residual, {lab}')
        ax.set_xlabel('ms after the break')
        ax.set_ylabel('m/s^2')
        ax.legend(fontsize=7)
        ax.set_title(f'held-out pull {ring["segment_pull"]}: free decay')
        paths.append(_save(fig, out / 'ringing.png'))
    return paths
