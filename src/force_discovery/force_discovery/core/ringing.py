"""Ringing: the free decay after the break (matrix pencil), scored with the cell mode alone and with the observed
mode, and the observed mode mapped to the mount through the carriage-mount-base-cell-m2 chain. ROS-free."""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np

from .prep import Pull
from .uncertainty import mean_ci

MOUNT_MAX_FRACTION = 0.7      # a free-decay mode below 0.7 x the cell mode is not the cell
RING_START_S = 2e-4            # the free decay is analysed from 0.2 ms after the break
MODE_CLUSTER_REL = 0.05        # modes of different pulls (or analyses) within 5 % are one mode


def matrix_pencil(y: np.ndarray, dt: float, order: int = 8) -> List[Tuple[float, float, float]]:
    """Damped modes of y: [(frequency Hz, damping ratio, rms amplitude share)], strongest first."""
    n = len(y)
    L = n // 2
    Y = np.lib.stride_tricks.sliding_window_view(y, L + 1)
    V = _top_right_vectors(Y, order)
    V1, V2 = V[:-1], V[1:]
    z = np.linalg.eigvals(np.linalg.pinv(V1) @ V2)
    z = z[np.abs(z) > 1e-6]
    Z = np.vander(z, n, increasing=True).T
    amp, *_ = np.linalg.lstsq(Z, y.astype(complex), rcond=None)
    out = []
    for zi, ai in zip(z, amp):
        lam = np.log(zi) / dt
        w = abs(lam)
        f = abs(lam.imag) / (2 * np.pi)
        if f < 1.0:
            continue
        zeta = -lam.real / w
        e = float(np.sum(np.abs(ai * zi ** np.arange(n)) ** 2))
        out.append((float(f), float(zeta), e))
    # merge conjugate pairs: keep positive-frequency energies summed by frequency
    out.sort(key=lambda m: -m[2])
    merged = []
    for f, zt, e in out:
        for m in merged:
            if abs(m[0] - f) < 1e-6 * max(1.0, f):
                m[2] += e
                break
        else:
            merged.append([f, zt, e])
    merged.sort(key=lambda m: -m[2])
    return [tuple(m) for m in merged]


def _top_right_vectors(Y: np.ndarray, k: int) -> np.ndarray:
    """The k leading right singular vectors of Y as columns, strongest first (the eigenvectors of Y^T Y with the k
    largest eigenvalues: only those are computed, not a full SVD with its left vectors). A vector's sign may differ
    from the SVD's; matrix_pencil's poles do not depend on it (pinv(V1) V2 changes by a similarity)."""
    from scipy.linalg import eigh
    n = Y.shape[1]
    k = min(k, min(Y.shape))
    Y = np.ascontiguousarray(Y)                  # a sliding window view is not BLAS's layout (2x slower product)
    _, V = eigh(Y.T @ Y, subset_by_index=[n - k, n - 1], driver='evr')
    return V[:, ::-1]


def ring_segment(p: Pull, length_s: float = 0.03) -> Optional[np.ndarray]:
    """a2 - a3 (the carriage frame) from RING_START_S after the break, length_s long, its mean removed (None: too
    short, or not all usable)."""
    i0 = p.brk + int(RING_START_S / p.dt)
    i1 = min(len(p.t), i0 + int(length_s / p.dt))
    if i1 - i0 < 200 or not p.usable(i0, i1).all():
        return None
    y = (p.a2 - p.a3)[i0:i1]
    return y - np.mean(y)


def damped_basis(n: int, dt: float, f: float, zeta: float) -> np.ndarray:
    t = np.arange(n) * dt
    w = 2 * np.pi * f
    e = np.exp(-zeta * w * t)
    wd = w * math.sqrt(max(1e-12, 1 - zeta ** 2))
    return np.column_stack([e * np.sin(wd * t), e * np.cos(wd * t)])


def ring_sse(seg: np.ndarray, dt: float, modes: Sequence[Tuple[float, float]]) -> float:
    """Squared residual of seg after a per-pull amplitude/phase fit of the given (f, zeta) modes."""
    if not modes:
        return float(seg @ seg)
    X = np.hstack([damped_basis(len(seg), dt, f, z) for f, z in modes] + [np.ones((len(seg), 1))])
    c, *_ = np.linalg.lstsq(X, seg, rcond=None)
    r = seg - X @ c
    return float(r @ r)


def ring_to_noise(p: Pull, seg: np.ndarray, cell: Sequence[Tuple[float, float]], mode: Tuple[float, float]) -> float:
    """RMS of the fitted mode's ringing in seg over the noise rms of a2 - a3 on the quiet pre-pull record."""
    X = np.hstack([damped_basis(len(seg), p.dt, f, z) for f, z in cell] + [np.ones((len(seg), 1)),
                                                                          damped_basis(len(seg), p.dt, *mode)])
    c, *_ = np.linalg.lstsq(X, seg, rcond=None)
    ring = X[:, -2:] @ c[-2:]
    q = (p.a2 - p.a3)[int(0.02 / p.dt):p.pre1]
    noise = float(np.std(q - np.polyval(np.polyfit(np.arange(len(q)), q, 1), np.arange(len(q))))) if len(q) > 100 \
        else 0.0
    return float(np.sqrt(np.mean(ring ** 2)) / max(noise, 1e-12))


def mount_from_observed(f_obs: float, zeta_obs: float, m2: float, k_cell: float, zeta_cell: float, mb: float):
    """Mount (frequency_hz, damping_ratio) whose carriage-mount-base(mb)-cell-m2 chain has the observed lowest pole
    (the sim's mount_resonance parameters, departures.py)."""
    from scipy.optimize import fsolve
    c2 = 2 * zeta_cell * math.sqrt(k_cell * m2)
    M = np.diag([mb, m2])

    def pole(fm, zm):
        km = (2 * np.pi * fm) ** 2 * (mb + m2)
        cm = 2 * zm * math.sqrt(km * (mb + m2))
        K = np.array([[km + k_cell, -k_cell], [-k_cell, k_cell]])
        C = np.array([[cm + c2, -c2], [-c2, c2]])
        A = np.block([[np.zeros((2, 2)), np.eye(2)], [-np.linalg.solve(M, K), -np.linalg.solve(M, C)]])
        ev = np.linalg.eigvals(A)
        ev = ev[ev.imag > 0]
        lam = ev[np.argmin(np.abs(ev))]
        return abs(lam.imag) / (2 * np.pi), -lam.real / abs(lam)

    def eq(v):
        f, z = pole(v[0], v[1])
        return [f / f_obs - 1.0, z / max(zeta_obs, 1e-6) - 1.0]
    sol = fsolve(eq, [f_obs / 0.95, max(zeta_obs, 1e-4)], full_output=True)
    return float(sol[0][0]), float(sol[0][1])


PENCIL_ORDER, PENCIL_SAMPLES = 8, 800     # the free decay's matrix pencil: its model order, its longest window
#: the defensible variants of the free-decay analysis (budget.mode_form_parts): name -> (pencil order, the window's
#: start as a fraction of the segment, its length as a fraction of the nominal window, the signal: 'a2 - a3' or 'a2')
MODE_VARIANTS = {'pencil_order_6': (6, 0.0, 1.0, 'a2 - a3'), 'pencil_order_12': (12, 0.0, 1.0, 'a2 - a3'),
                 'window_later': (PENCIL_ORDER, 0.25, 0.75, 'a2 - a3'),
                 'window_shorter': (PENCIL_ORDER, 0.0, 0.5, 'a2 - a3'),
                 'accelerometer_alone': (PENCIL_ORDER, 0.0, 1.0, 'a2')}


def band_modes(y: np.ndarray, dt: float, order: int = PENCIL_ORDER) -> List[Tuple[float, float, float]]:
    """matrix_pencil() of a free decay y, the decaying modes between 100 Hz and 10 kHz only, strongest first."""
    return [m for m in matrix_pencil(y, dt, order) if 100.0 < m[0] < 10000.0 and 0 < m[1] < 0.5]


def free_decay_mode(p: Pull) -> Optional[Tuple[float, float, float]]:
    """The strongest mode (frequency, damping ratio, energy) of the pull's free decay after the break, or None."""
    seg = ring_segment(p)
    mm = [] if seg is None else band_modes(seg[:PENCIL_SAMPLES], p.dt)
    return mm[0] if mm else None


def free_decay_variants(p: Pull, nominal: Optional[tuple]) -> Optional[Dict[str, Optional[Tuple[float, float]]]]:
    """{variant: (frequency, damping ratio) or None} of the pull's free decay under each MODE_VARIANTS analysis: the
    mode nearest (within MODE_CLUSTER_REL) the one free_decay_mode() found, nominal (None: none, and no variants)."""
    seg = None if nominal is None else ring_segment(p)
    if seg is None:
        return None
    n = min(len(seg), PENCIL_SAMPLES)
    i0 = p.brk + int(RING_START_S / p.dt)
    alone = p.a2[i0:i0 + len(seg)] - np.mean(p.a2[i0:i0 + len(seg)])
    out: Dict[str, Optional[Tuple[float, float]]] = {}
    for name, (order, start, length, signal) in MODE_VARIANTS.items():
        y = (seg if signal == 'a2 - a3' else alone)[int(start * n):int(start * n) + int(length * n)]
        mm = band_modes(y, p.dt, order) if len(y) > 2 * order + 2 else []
        near = min(mm, key=lambda m: abs(m[0] - nominal[0]), default=None)
        out[name] = (near[0], near[1]) if near is not None and abs(near[0] / nominal[0] - 1.0) < MODE_CLUSTER_REL \
            else None
    return out


def cell_modes(fc) -> list:
    """The model of record's only mode after the break: the moving cell on m2, [(frequency, damping ratio)]."""
    return [(math.sqrt(fc.load_cell_stiffness_n_per_m / fc.m2) / (2 * np.pi), fc.load_cell_damping_ratio)]


def observed_mode(modes: Sequence[Optional[tuple]]) -> Optional[Tuple[float, float]]:
    """(frequency, damping ratio): the medians of the few fitted pulls' free_decay_mode() (None: none had one)."""
    modes = [m for m in modes if m is not None]
    if not modes:
        return None
    return float(np.median([m[0] for m in modes])), float(np.median([m[1] for m in modes]))


@dataclass(frozen=True)
class RingPart:
    """One held-out pull's free decay scored with the cell mode alone (base) and with the observed mode (ext)."""

    sse_base: float          # with the campaign's sample interval (the ring stage's)
    sse_ext: float
    ring_to_noise: float
    samples: int
    own_base: float          # with the pull's own sample interval (the report's RMS)
    own_ext: float
    segment: Optional[np.ndarray] = None


def ring_part(p: Pull, dt: float, cell: list, mode: Tuple[float, float], keep: bool = False) -> Optional[RingPart]:
    """RingPart of the held-out pull p (None: no clean free decay); dt: the campaign's sample interval; keep: keep
    the segment (for the plot)."""
    seg = ring_segment(p)
    if seg is None:
        return None
    b, e = ring_sse(seg, dt, cell), ring_sse(seg, dt, cell + [mode])
    ob, oe = (b, e) if p.dt == dt else (ring_sse(seg, p.dt, cell), ring_sse(seg, p.dt, cell + [mode]))
    return RingPart(b, e, ring_to_noise(p, seg, cell, mode), len(seg), ob, oe, seg if keep else None)


def cluster_modes(pulls: Sequence) -> list:
    """The reference-free path's modes across pulls (each with .name and .modes): the modes seen in at least half
    the pulls (frequencies within MODE_CLUSTER_REL), [{frequency_hz, damping_ratio, pulls, per_pull}], by how many
    pulls show it, then the energy."""
    allm = sorted((f, z, e, j) for j, p in enumerate(pulls) for f, z, e in p.modes)
    groups: list = []
    for m in allm:
        if groups and m[0] <= groups[-1][-1][0] * (1 + MODE_CLUSTER_REL):
            groups[-1].append(m)
        else:
            groups.append([m])
    out = []
    need = max(1, math.ceil(len(pulls) / 2))
    for g in groups:
        per = {}
        for f, z, e, j in g:
            if j not in per or e > per[j][2]:
                per[j] = (f, z, e)
        if len(per) < need:
            continue
        fs = [v[0] for v in per.values()]
        zs = [v[1] for v in per.values()]
        out.append({'frequency_hz': float(np.median(fs)), 'damping_ratio': float(np.median(zs)),
                    'frequency_ci95': mean_ci(fs), 'damping_ci95': mean_ci(zs), 'pulls': len(per),
                    'energy_share': float(np.median([v[2] for v in per.values()])),
                    'per_pull': {pulls[j].name: [v[0], v[1]] for j, v in sorted(per.items())}})
    out.sort(key=lambda m: (-m['pulls'], -m['energy_share']))
    return out
