"""The drive coupled to the force chain: the lanyard load acts back on the carriage (ROS-free).

    m_c x3'' = N K_t i / r - (b_m + b_g) v3 - F_move(t) - F_c sat(v3 / V_EPS)      (core/drive.py)
    force chain driven by the carriage kinematics x3(t), v3(t), a3(t)              (core/integrate.py)

Method (waveform relaxation, DRIVE.md "Coupled drive"): the command is the prescribed profile's
velocity (``motion_for(rig, spec)``: launch, cruise, the set's deceleration from the taut instant,
braking after the break). The drive is integrated over the whole record with the load F_move(t) of the
previous pass (zero on the first), sampled on the 50 kHz DAQ grid; its x3/v3/a3 samples become a
``DriveMotion`` (quintic Hermite spline: x, v = x', a = x'' consistent and C2); the chain is integrated
with that motion and gives the next F_move(t). Repeat until the carriage trajectory changes by less
than ``tol_m`` (1 um) and the chain's F_move by less than ``tol_n`` (5 N) between passes. Once the coupon is
gone (beta = 0) the chain is free for good and linear; from that sample on the drive pass integrates the free
chain's moving side (m2, the mount's base) together with the carriage instead of taking its F_move as a given
load: relaxing the 1 kHz mount mode against the carriage does not converge (loop gain 1.2 at the resonance),
DRIVE.md "Ringing after the break". ``integrate_coupled_reference`` integrates the whole coupled model as one
ODE for verification. Dry friction (departure ``coulomb_friction``) acts inside the
drive integration on the current v3 (not lagged), smoothed over |v3| < V_EPS so the right-hand side
stays continuous. The rig's extra_terms on the motor current (A each) are a further load on the carriage, their
force per amp times the term, from the previous pass's motion and chain (``extra_load``): the drive supplies it, so the
recorded current carries them; the sensors' terms are added to what the DAQ records, as in the prescribed pull.

The drive on the grid (``drive_on_grid``, exact where LTI, LSODA elsewhere) is core/drive_grid.py.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Dict, List, Optional

import numpy as np
from scipy.integrate import solve_ivp
from scipy.interpolate import PPoly

from .chain import ChainParams, chain_rhs, force_move, force_stat, lanyard_drive, tension
from .drive import DriveControl, DriveSetup, apply_overrides, drive_rhs
from .drive_grid import (
    DRIVE_ATOL,
    DRIVE_METHODS,
    V_EPS_M_S,
    drive_on_grid,
    drive_voltage_array,
    free_chain_stack,
    friction_n_of,
    linearised_after_break,
)
from .errors import SimError
from .extra_terms import extra_channels, signals
from .integrate import ChainTrajectory, integrate_chain
from .params import RigParams
from .pull import PullResult, PullSpec, chain_params, events_and_truth, motion_for, record_channels, sample_times_s

REST_TOL_M_S = 1.0e-3       # the carriage must be slower than this at the end of the record
TRACK_START_TOL_M = 1.0e-3  # and never more than this behind its start position


class DriveMotion:
    """A MotionSource from sampled drive output: quintic Hermite spline through (x3, v3, a3) on a uniform grid.

    ``kinematics(t)`` returns x, v = dx/dt, a = dv/dt of one C2 piecewise quintic (exact at the samples);
    outside the sampled span t is clamped (held at the first/last sample: x held, v and a as sampled).
    ``command_velocity(t)``: the drive's velocity command, linear between samples.
    """

    command_scale = 1.0

    def __init__(self, t, x, v, a, command):
        t = np.asarray(t, dtype=float)
        arrs = [np.asarray(y, dtype=float) for y in (x, v, a, command)]
        n = len(t)
        if n < 2 or any(y.shape != t.shape for y in arrs):
            raise SimError(f'DriveMotion samples have shapes {[t.shape] + [y.shape for y in arrs]}; '
                           f'expected equal 1-D arrays of >= 2 samples')
        h = float(t[1] - t[0])
        if not (h > 0 and np.allclose(np.diff(t), h, rtol=1e-9, atol=1e-15)):
            raise SimError(f'DriveMotion time step {h!r} s is not uniform/positive; expected a uniform grid')
        if not all(np.all(np.isfinite(y)) for y in arrs):
            raise SimError('DriveMotion samples contain non-finite values; expected finite x, v, a, command')
        x, v, a, cmd = arrs
        self.t, self.x, self.v, self.a, self.cmd = t, x, v, a, cmd
        self.h, self.t0, self.n = h, float(t[0]), n
        D = x[1:] - (x[:-1] + v[:-1] * h + 0.5 * a[:-1] * h * h)
        E = v[1:] - (v[:-1] + a[:-1] * h)
        G = a[1:] - a[:-1]
        c = np.empty((6, n - 1))
        c[5], c[4], c[3] = x[:-1], v[:-1], 0.5 * a[:-1]
        c[2] = (10.0 * D - 4.0 * E * h + 0.5 * G * h * h) / h ** 3
        c[1] = (-15.0 * D + 7.0 * E * h - G * h * h) / h ** 4
        c[0] = (6.0 * D - 3.0 * E * h + 0.5 * G * h * h) / h ** 5
        self._pp = PPoly(c, t, extrapolate=False)
        self._dpp = self._pp.derivative(1)
        self._ddpp = self._pp.derivative(2)
        self._c = c
        self._seg = {}                           # scalar path: segment k's coefficients as plain floats

    @property
    def t_end(self) -> float:
        return float(self.t[-1])

    def kinematics(self, t):
        t = np.clip(np.asarray(t, dtype=float), self.t0, self.t_end)
        return self._pp(t), self._dpp(t), self._ddpp(t)

    def kinematics_scalar(self, t: float):
        s = (float(t) - self.t0) / self.h
        k = int(s) if s > 0.0 else 0
        if k > self.n - 2:
            k = self.n - 2
        tau = min(max(float(t) - (self.t0 + k * self.h), 0.0), self.h)
        seg = self._seg.get(k)
        if seg is None:
            seg = self._seg[k] = self._c[:, k].tolist()
        c5, c4, c3, c2, c1, c0 = seg
        x = ((((c5 * tau + c4) * tau + c3) * tau + c2) * tau + c1) * tau + c0
        v = (((5.0 * c5 * tau + 4.0 * c4) * tau + 3.0 * c3) * tau + 2.0 * c2) * tau + c1
        a = ((20.0 * c5 * tau + 12.0 * c4) * tau + 6.0 * c3) * tau + 2.0 * c2
        return x, v, a

    def command_velocity(self, t):
        return np.interp(np.asarray(t, dtype=float), self.t, self.cmd)


def drive_motion(dr: Dict[str, np.ndarray]) -> DriveMotion:
    return DriveMotion(dr['time_s'], dr['position_m'], dr['velocity_m_s'], dr['acceleration_m_s2'],
                       dr['command_m_s'])


def free_after_break(p: ChainParams, traj):
    """(p, k, chain state at t[k]) for the first sample k at which the coupon is gone (beta = 0: the chain is
    free for good), the ``free_chain`` of ``drive_on_grid``; None if the coupon does not break in the record."""
    if traj.break_s is None:
        return None
    gone = np.flatnonzero(traj.beta <= 0.0)
    if not len(gone):
        return None
    k = int(gone[0])
    return p, k, traj.x[k].copy()


def check_fits(rig: RigParams, x3, v3) -> None:
    """The coupled carriage must stay on the usable track and be at rest by the end of the record."""
    top = float(np.max(x3))
    if top > rig.drive.usable_track_m:
        raise SimError(f'the coupled carriage travels to {top:.4f} m; expected within the usable track '
                       f'{rig.drive.usable_track_m} m')
    low = float(np.min(x3))
    if low < -TRACK_START_TOL_M:
        raise SimError(f'the coupled carriage backs up to {low:.4f} m; expected >= {-TRACK_START_TOL_M} m')
    v_end = float(v3[-1])
    if abs(v_end) > REST_TOL_M_S:
        raise SimError(f'the coupled carriage still moves at {v_end:.4g} m/s at the end of the record; expected '
                       f'|v3| < {REST_TOL_M_S} m/s within the {rig.daq.record_length_s} s record')


def extra_load(rig: RigParams, spec: PullSpec, terms, p: ChainParams, traj, kin, fm,
               overrides=None) -> Optional[np.ndarray]:
    """The load, N, that the rig's extra_terms on the motor current put on the carriage (``terms``, A each, times
    the drive's force per amp), from one pass's carriage motion ``kin`` and chain solve; None without such terms.
    The drive then supplies it, so the recorded current carries the terms as the prescribed pull's balance does."""
    if not terms:
        return None
    T = chain_tension(p, traj, kin)
    sig = signals(traj.t, fm, force_stat(traj.x, p), T, (fm - T) / p.m2, kin[1], kin[0])
    kf = apply_overrides(rig.drive, overrides).force_per_amp_n_per_a
    return kf * extra_channels(terms, sig, spec.seed)['motor_current']


def chain_tension(p, traj, kin) -> np.ndarray:
    """Lanyard tension of a chain trajectory (the flow piece's from the yield on)."""
    U = np.column_stack([kin[0], kin[1], kin[2], traj.beta])
    T = tension(traj.x, U, p)
    if traj.yield_s is not None:
        flowing = traj.t >= traj.yield_s
        T[flowing] = tension(traj.x[flowing], U[flowing], p.flow_params())
    return T


@dataclass
class CoupledPullResult(PullResult):
    iterations: int = 0                                   # chain solves (passes of the relaxation)
    x3_changes_m: List[float] = field(default_factory=list)   # max |x3 change| after each pass
    f_move_changes_n: List[float] = field(default_factory=list)   # max |F_move change| from the previous chain solve
    drive: Dict[str, np.ndarray] = field(default_factory=dict)          # final drive run (load: final F_move)
    drive_no_load: Dict[str, np.ndarray] = field(default_factory=dict)  # first pass (no lanyard load)
    chain_trajectory: Optional[ChainTrajectory] = None    # the last chain solve (forces and truth come from it)


def run_coupled_pull(rig: RigParams, spec: PullSpec, noise: bool = True, control: DriveControl | None = None,
                     iterations: int = 12, tol_m: float = 1.0e-6, overrides=None,
                     method: str = 'exact', joint_after_break: bool = True, tol_n: float = 5.0) -> CoupledPullResult:
    """One pull with the drive coupled to the force chain (waveform relaxation, see module doc).

    ``method``: the drive integrator of ``drive_on_grid`` ('exact' or the reference 'lsoda').
    ``joint_after_break``: True (default): once the coupon is gone the drive pass integrates the free chain's
    moving side with the carriage (``free_after_break``), so the mount's ringing after the break is not
    relaxed; False: the plain relaxation over the whole record, which does not converge on that ringing (kept
    to show it: DRIVE.md "Ringing after the break").
    ``iterations``: most chain solves allowed. Converged when the drive's x3 changes by < ``tol_m`` and the
    chain's F_move by < ``tol_n`` (N, between the last two chain solves; x3 alone does not see the mount's
    ringing, whose carriage motion is ~0.1 um); SimError if not within ``iterations``.
    Channels as ``run_pull``, except motor_* from the drive simulation and the encoder from the coupled x3.
    Forces and the truth signals come from the last chain solve (driven by the previous pass's motion, which
    the final drive run reproduces to < tol_m).
    """
    if isinstance(iterations, bool) or not isinstance(iterations, (int, np.integer)) or iterations < 1:
        raise SimError(f'iterations is {iterations!r}; expected an integer >= 1')
    if not (isinstance(tol_m, (int, float)) and math.isfinite(tol_m) and tol_m > 0):
        raise SimError(f'tol_m is {tol_m!r}; expected a positive length in metres')
    if not (isinstance(tol_n, (int, float)) and not isinstance(tol_n, bool) and tol_n > 0):
        raise SimError(f'tol_n is {tol_n!r}; expected a positive force in newtons (inf: x3 alone)')
    p = chain_params(rig, spec)
    prescribed = motion_for(rig, spec)          # raises if the prescribed pull does not fit
    t = sample_times_s(rig)
    cmd = prescribed.kinematics(t)[1]
    dr = drive_on_grid(rig, t, cmd, None, control, overrides, method=method)
    check_fits(rig, dr['position_m'], dr['velocity_m_s'])
    first = dr
    changes: List[float] = []
    f_changes: List[float] = []
    fm_last = None
    converged = False
    on_current = tuple(e for e in rig.extra_terms if e.channel == 'motor_current')
    for _ in range(int(iterations)):
        motion = drive_motion(dr)
        kin = (dr['position_m'], dr['velocity_m_s'], dr['acceleration_m_s2'])
        traj = integrate_chain(p, motion, t, kinematics=kin)
        fm = force_move(traj.x, p)
        f_changes.append(math.inf if fm_last is None else float(np.max(np.abs(fm - fm_last))))
        fm_last = fm
        new = drive_on_grid(rig, t, cmd, fm, control, overrides, method=method,
                            free_chain=free_after_break(p, traj) if joint_after_break else None,
                            extra_load_n=extra_load(rig, spec, on_current, p, traj, kin, fm, overrides))
        check_fits(rig, new['position_m'], new['velocity_m_s'])
        changes.append(float(np.max(np.abs(new['position_m'] - dr['position_m']))))
        dr = new
        if changes[-1] < tol_m and f_changes[-1] < tol_n:
            converged = True
            break
    if not converged:
        raise SimError(f'coupled pull did not converge: x3 still changes by {changes[-1]:.3g} m and F_move by '
                       f'{f_changes[-1]:.3g} N after {len(changes)} passes; expected < {tol_m} m and < {tol_n} N '
                       f'within {iterations}')
    x3, v3, a3 = kin
    X = traj.x
    T = chain_tension(p, traj, kin)
    fs = force_stat(X, p)
    a2 = (fm - T) / p.m2
    extra = None
    if rig.extra_terms:   # the current's terms are in the drive's load above; the sensors' are recorded here
        extra = extra_channels(rig.extra_terms, signals(t, fm, fs, T, a2, v3, x3), spec.seed)

    channels = record_channels(rig, spec, t, dr['position_m'], fm, fs, a2, noise,
                               motor=(dr['command_m_s'], dr['current_a'], dr['voltage_v']), extra=extra)
    taut_index, break_index, break_end_index, truth = events_and_truth(t, traj, p, kin, T, fm, fs)
    truth['v3_no_load_m_s'] = first['velocity_m_s']
    return CoupledPullResult(channels, spec, motion, taut_index, break_index, break_end_index, traj.taut_s,
                             traj.break_s, truth, iterations=len(changes), x3_changes_m=changes,
                             f_move_changes_n=f_changes, drive=dr,
                             drive_no_load=first, chain_trajectory=traj)


REF_MAX_STEP_S = 2.0e-5     # coupled reference: DOP853 max step (the 8 kHz cell mode with the mount)


def integrate_coupled_reference(rig: RigParams, spec: PullSpec, result: CoupledPullResult, start_index: int,
                                t_end_s: float, rtol: float = 1.0e-9, control: DriveControl | None = None,
                                overrides=None) -> Dict[str, np.ndarray]:
    """The coupled pull as ONE ODE (drive states [x3, v3, i, z] and all chain states, the chain's F_move the
    drive's load, the drive's acceleration the chain's a3), solve_ivp DOP853 (``rtol``, max step 20 us) with
    the coupon's yield and break as events: the verification reference of the waveform relaxation (as
    ``integrate.integrate_reference`` is for the chain and ``method='lsoda'`` for the drive).

    Starts from ``result``'s states at sample ``start_index``, which must lie before the lanyard engages (no
    tension, no yield, no break yet); ends at the last sample <= ``t_end_s``. Returns samples from
    ``start_index``: time_s, position_m, velocity_m_s, current_a, force_moving_n, tension_n, a2_m_s2,
    break_s (None if the coupon does not break in the window)."""
    t = result.channels['time_s']
    h = float(t[1] - t[0])
    if not (isinstance(start_index, (int, np.integer)) and result.taut_index is not None
            and 0 <= start_index < result.taut_index):
        raise SimError(f'start_index is {start_index!r}; expected a sample before the lanyard engages '
                       f'(< {result.taut_index})')
    k1 = min(len(t) - 1, int(math.floor(t_end_s / h + 1e-9)))
    if k1 <= start_index:
        raise SimError(f't_end_s is {t_end_s!r}; expected after the start {t[start_index]} s')
    control = DriveControl() if control is None else control
    drive = apply_overrides(rig.drive, overrides)
    setup = DriveSetup(drive, control)
    fc = friction_n_of(rig)
    p = chain_params(rig, spec)
    pf = p.flow_params() if p.yields else p
    cmd = result.drive['command_m_s'].tolist()
    k0 = int(start_index)
    tr, dr = result.truth, result.drive
    xc0 = [tr['u2_m'][k0] - tr['x3_m'][k0], tr['v2_m_s'][k0] - tr['v3_m_s'][k0], tr['u1_m'][k0], tr['v1_m_s'][k0]]
    if p.has_mount:
        xc0 += [tr['ub_m'][k0] - tr['x3_m'][k0], tr['vb_m_s'][k0] - tr['v3_m_s'][k0]]
    x0 = np.array([dr['position_m'][k0], dr['velocity_m_s'][k0], dr['current_a'][k0], dr['integrator'][k0]] + xc0)
    state = {'flow': False, 'break_s': None, 'yield_s': None}

    def rhs(tt, x):
        k = min(int(tt / h), len(cmd) - 2)
        w = tt / h - k
        xc = x[4:]
        f = float(force_move(xc, p)) + (fc * min(1.0, max(-1.0, x[1] / V_EPS_M_S)) if fc else 0.0)
        dx = drive_rhs(tt, x[:4], (cmd[k] + w * (cmd[k + 1] - cmd[k]), f), setup)
        tb = state['break_s']
        beta = 1.0 if tb is None else min(1.0, max(0.0, 1.0 - (tt - tb) / p.break_duration_s))
        return np.concatenate([dx, chain_rhs(tt, xc, (x[0], x[1], dx[1], beta), pf if state['flow'] else p)])

    def ev_yield(tt, x):
        return float(lanyard_drive(x[4:], x[:2], p)) - p.yield_n

    def ev_break(tt, x):
        return float(force_stat(x[4:], p)) - p.break_n
    for ev in (ev_yield, ev_break):
        ev.terminal, ev.direction = True, 1.0
    atol = np.concatenate([DRIVE_ATOL, np.tile([1e-16, 1e-11], p.n_states // 2)])
    X = np.empty((k1 - k0 + 1, len(x0)))
    X[0] = x0
    tc, x, filled = float(t[k0]), x0, 0
    while True:
        evs = ([ev_yield] if p.yields and not state['flow'] else []) + ([ev_break] if state['break_s'] is None else [])
        te = t[k0 + filled + 1:k1 + 1]
        sol = solve_ivp(rhs, (tc, float(t[k1])), x, method='DOP853', rtol=rtol, atol=atol, t_eval=te[te > tc],
                        events=evs or None, max_step=REF_MAX_STEP_S)
        if sol.status < 0:
            raise SimError(f'coupled reference failed ({sol.message}); expected solve_ivp to succeed')
        X[filled + 1:filled + 1 + len(sol.t)] = sol.y.T
        filled += len(sol.t)
        if sol.status != 1:
            break
        j = next(j for j, e in enumerate(sol.t_events) if len(e))
        tc, x = float(sol.t_events[j][0]), sol.y_events[j][0].copy()
        state['yield_s' if evs[j] is ev_yield else 'break_s'] = tc
        state['flow'] = state['flow'] or evs[j] is ev_yield
    tt = t[k0:k1 + 1]
    xc = X[:, 4:]
    tb = state['break_s']
    beta = np.ones(len(tt)) if tb is None else np.clip(1.0 - (tt - tb) / p.break_duration_s, 0.0, 1.0)
    U = np.column_stack([X[:, 0], X[:, 1], np.zeros(len(tt)), beta])
    T = tension(xc, U, p)
    if state['yield_s'] is not None:
        flowing = tt >= state['yield_s']
        T[flowing] = tension(xc[flowing], U[flowing], pf)
    fm = force_move(xc, p)
    return {'time_s': tt, 'position_m': X[:, 0], 'velocity_m_s': X[:, 1], 'current_a': X[:, 2],
            'force_moving_n': fm, 'tension_n': T, 'a2_m_s2': (fm - T) / p.m2, 'break_s': tb}


__all__ = ['DriveMotion', 'drive_on_grid', 'DRIVE_METHODS', 'drive_voltage_array', 'drive_motion', 'check_fits',
           'CoupledPullResult', 'run_coupled_pull', 'V_EPS_M_S', 'free_chain_stack',
           'free_after_break', 'integrate_coupled_reference', 'linearised_after_break']
