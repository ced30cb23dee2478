"""The drive coupled to the force chain: the lanyard load acts back on the carriage (ROS-free).

    m_c x3'' = N K_t i / r - (b_m + b_g) v3 - F_move(t) - F_c sat(v3 / V_EPS)      (core/drive.py)
    force chain driven by the carriage kinematics x3(t), v3(t), a3(t)              (core/integrate.py)

Method (waveform relaxation, DRIVE.md "Coupled drive"): the command is the prescribed profile's
velocity (``motion_for(rig, spec)``: launch, cruise, the set's deceleration from the taut instant,
braking after the break). The drive is integrated over the whole record with the load F_move(t) of the
previous pass (zero on the first), sampled on the 50 kHz DAQ grid; its x3/v3/a3 samples become a
``DriveMotion`` (quintic Hermite spline: x, v = x', a = x'' consistent and C2); the chain is integrated
with that motion and gives the next F_move(t). Repeat until the carriage trajectory changes by less
than ``tol_m`` (1 um) between passes. Dry friction (departure ``coulomb_friction``) acts inside the
drive integration on the current v3 (not lagged), smoothed over |v3| < V_EPS so the right-hand side
stays continuous.

The drive is integrated exactly on the grid wherever it is LTI (PID output unclipped, friction on one piece:
modal first-order-hold recursion with lfilter, as core/integrate.py does for the chain) and by LSODA only across
piece switches and through clipped stretches (``drive_on_grid(..., method='exact')``, the default);
``method='lsoda'`` integrates the whole record with LSODA (the reference it is tested against).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Dict, List, Optional

import numpy as np
from scipy.integrate import solve_ivp
from scipy.interpolate import PPoly
from scipy.signal import lfilter

from .chain import force_move, force_stat, tension
from .drive import DriveControl, DriveSetup, _validate_drive, apply_overrides, drive_rhs
from .errors import SimError
from .integrate import integrate_chain
from .params import RigParams
from .pull import PullResult, PullSpec, chain_params, events_and_truth, motion_for, record_channels, sample_times_s

V_EPS_M_S = 1.0e-3          # dry friction F_c sat(v3 / V_EPS): full F_c above 1 mm/s
DRIVE_MAX_STEP_S = 1.0e-3   # LSODA max step (adaptive below that)
DRIVE_RTOL = 1.0e-7         # x3 within 1e-7 m of a 20 us max-step run (truth rig), 3x faster than 1e-8
DRIVE_ATOL = np.array([1e-9, 1e-8, 1e-6, 1e-10])
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


def _friction_n(rig: RigParams) -> float:
    cf = rig.departures.get('coulomb_friction') if rig.departures else None
    return 0.0 if cf is None else float(cf['force_n'])


DRIVE_METHODS = ('exact', 'lsoda')
_LIN_WINDOW = 4096          # samples per exact (modal lfilter) chunk at first; doubled while no event occurs
_NL_WINDOW = 250            # samples per LSODA chunk in a clipped stretch at first (5 ms at 50 kHz); doubled
_HANDOVER = 10              # back to the exact path once this many consecutive LSODA samples are unclipped


class _DriveLinear:
    """Exact first-order-hold discretisation of the unclipped drive on step h, in modal form.

    While the PID output is inside the current limiter's and the supply's bounds (V = V_pid, z' = e) and the
    dry friction is on one piece of F_c sat(v3 / V_EPS) (the band |v3| <= V_EPS: a damping F_c / V_EPS; or
    +/-F_c), the drive is LTI: x' = A x + B [v_cmd, F_load, 1]. Each mode y' = lam y + b u with u linear over
    the step gives y1 = e^{lam h} y0 + g0 b u0 + g1 b (u1 - u0) / h, g0 = (e^{lam h} - 1) / lam,
    g1 = (e^{lam h} - 1 - lam h) / lam^2 (x3 is a pure integrator: lam = 0, g0 = h, g1 = h^2 / 2).
    """

    def __init__(self, setup: DriveSetup, damping: float, friction_n: float, h: float):
        d, c = setup.drive, setup.control
        m, L = setup.mass_kg, d.armature_inductance_h
        A = np.zeros((4, 4))
        B = np.zeros((4, 3))
        A[0, 1] = 1.0
        A[1, 1], A[1, 2] = -damping / m, setup.k_force / m
        B[1, 1], B[1, 2] = -1.0 / m, -friction_n / m
        v_row = np.array([0.0, -c.kp_v_per_m_s, 0.0, c.ki_v_per_m]) - c.kd_v_s2_per_m * A[1]
        v_in = np.array([c.kp_v_per_m_s, 0.0, 0.0]) - c.kd_v_s2_per_m * B[1]
        A[2] = (v_row - np.array([0.0, setup.k_emf, d.armature_resistance_ohm, 0.0])) / L
        B[2] = v_in / L
        A[3, 1], B[3, 0] = -1.0, 1.0
        self.acc_row, self.acc_in = A[1].copy(), B[1].copy()     # acceleration = acc_row x + acc_in u
        self.v_row, self.v_in = v_row, v_in                      # V_pid = v_row x + v_in u
        evs, V = np.linalg.eig(A)
        Vinv = np.linalg.inv(V)
        err = np.abs((V * evs) @ Vinv - A).max() / np.abs(A).max()
        keep = np.flatnonzero(evs.imag >= 0)
        self.modal = (np.isfinite(err) and err <= 1e-9 and np.linalg.cond(V) <= 1e8
                      and 2 * int(np.sum(evs.imag > 0)) + int(np.sum(evs.imag == 0)) == 4)
        if not self.modal:  # a defective drive matrix (not the case for positive gains)
            return
        lam = evs[keep].astype(complex)
        lh = lam * h
        e = np.exp(lh)
        small = np.abs(lh) < 1e-6
        safe = np.where(small, 1.0, lam)
        g0 = np.where(small, h * (1.0 + lh / 2.0 + lh * lh / 6.0), (e - 1.0) / safe)
        g1 = np.where(small, h * (0.5 + lh / 6.0 + lh * lh / 24.0), (e - 1.0 - lh) / (safe * safe * h))
        b = Vinv[keep] @ B
        self.lam = e
        self.V = V[:, keep] * np.where(evs[keep].imag > 0, 2.0, 1.0)
        self.Vinv = Vinv[keep]
        self.q0 = (g0 - g1)[:, None] * b
        self.q1 = g1[:, None] * b

    def propagate(self, x0, U):
        """States at every row of U ([v_cmd, F_load, 1] on the grid), starting with x0 at U[0].

        Column-by-column arithmetic, no matrix products: (n x 3) @ (3 x 4) products go to a threaded BLAS,
        which on a loaded 2-core machine is many times slower than these few vector operations."""
        y0 = self.Vinv @ x0
        X = np.zeros((U.shape[0], 4))
        for j, lam in enumerate(self.lam):
            q = _cols(U[:-1], self.q0[j]) + _cols(U[1:], self.q1[j])
            y = np.empty(U.shape[0], dtype=complex)
            y[0] = y0[j]
            y[1:] = lfilter([1.0], [1.0, -lam], q, zi=[lam * y0[j]])[0]
            yr, yi = y.real, y.imag
            for r in range(4):
                w = self.V[r, j]
                if w.real:
                    X[:, r] += w.real * yr
                if w.imag:
                    X[:, r] -= w.imag * yi
        return X


def _cols(M, w):
    """M @ w as a sum of columns (M tall and narrow, w small): no BLAS call."""
    out = 0.0
    for c, wc in enumerate(w):
        if wc:
            out = out + M[:, c] * wc
    return out if np.ndim(out) else np.full(M.shape[0], out)


def _limits(setup: DriveSetup, v3, i):
    """(lower, upper) bound of the applied voltage: current limiter, then the supply."""
    d, c = setup.drive, setup.control
    e_b = setup.k_emf * v3
    r, lw, imax, vmax = (d.armature_resistance_ohm, d.armature_inductance_h * c.current_loop_rad_s,
                         d.current_limit_a, d.voltage_limit_v)
    hi = np.minimum(r * imax + e_b + lw * (imax - i), vmax)
    lo = np.maximum(-r * imax + e_b + lw * (-imax - i), -vmax)
    return lo, hi


def _drive_exact(setup: DriveSetup, fc: float, t, cmd, load, fun) -> np.ndarray | None:
    """States (n, 4) on the grid: exact LTI propagation while unclipped, LSODA (``fun``) elsewhere;
    None when the drive matrix has no modal form (then the caller integrates with LSODA)."""
    n = len(t)
    h = float(t[1] - t[0])
    b = setup.damping
    if fc:
        pieces = {0: _DriveLinear(setup, b + fc / V_EPS_M_S, 0.0, h), 1: _DriveLinear(setup, b, fc, h),
                  -1: _DriveLinear(setup, b, -fc, h)}
    else:
        pieces = {0: _DriveLinear(setup, b, 0.0, h)}
    if not all(lin.modal for lin in pieces.values()):
        return None
    U = np.column_stack([cmd, load, np.ones(n)])
    X = np.zeros((n, 4))

    def piece_of(v):
        if not fc:
            return np.zeros(np.shape(v), dtype=int)
        return np.where(v > V_EPS_M_S, 1, np.where(v < -V_EPS_M_S, -1, 0))

    def unclipped(Xs, Us, piece):
        """Samples at which the PID output is inside the limits (per the friction piece of each sample)."""
        if np.ndim(piece) == 0:
            lin = pieces[int(piece)]
            vp = _cols(Xs, lin.v_row) + _cols(Us, lin.v_in)
        else:
            vp = np.empty(len(Xs))
            for key, lin in pieces.items():
                sel = piece == key
                vp[sel] = _cols(Xs[sel], lin.v_row) + _cols(Us[sel], lin.v_in)
        lo, hi = _limits(setup, Xs[:, 1], Xs[:, 2])
        return (vp >= lo) & (vp <= hi)

    def lsoda(k0, k1):
        sol = solve_ivp(fun, (float(t[k0]), float(t[k1])), X[k0], method='LSODA', t_eval=t[k0:k1 + 1],
                        max_step=DRIVE_MAX_STEP_S, rtol=DRIVE_RTOL, atol=DRIVE_ATOL)
        if not sol.success:
            raise SimError(f'drive integration failed ({sol.message}); expected solve_ivp to succeed')
        X[k0 + 1:k1 + 1] = sol.y.T[1:]

    k, win, nwin = 0, _LIN_WINDOW, _NL_WINDOW
    while k < n - 1:
        piece = int(piece_of(X[k, 1]))
        if unclipped(X[k:k + 1], U[k:k + 1], piece)[0]:
            end = min(n - 1, k + win)
            Xs = X[k:end + 1] = pieces[piece].propagate(X[k], U[k:end + 1])
            ok = unclipped(Xs, U[k:end + 1], piece)
            if fc:
                ok &= piece_of(Xs[:, 1]) == piece
            bad = np.flatnonzero(~ok[1:])
            if not len(bad):
                k, win = end, 2 * win
                continue
            j = k + 1 + int(bad[0])       # first sample off this piece: LSODA across the switching interval
            lsoda(j - 1, j)
            k, win = j, _LIN_WINDOW
        else:
            end = min(n - 1, k + nwin)
            lsoda(k, end)
            ok = unclipped(X[k:end + 1], U[k:end + 1], piece_of(X[k:end + 1, 1]))
            run = np.convolve(ok.astype(int), np.ones(_HANDOVER, dtype=int), 'valid') == _HANDOVER
            start = np.flatnonzero(run[1:])
            if len(start):
                k, nwin = k + 1 + int(start[0]), _NL_WINDOW
            else:
                k, nwin = end, 2 * nwin
    return X


def drive_on_grid(rig: RigParams, t, command_m_s, load_n=None, control: DriveControl | None = None,
                  overrides=None, friction_n: Optional[float] = None, method: str = 'exact') -> Dict[str, np.ndarray]:
    """The drive from rest on the uniform grid ``t`` (from 0): command and load (N, tension) given as samples
    on the grid (linear between samples); dry friction ``friction_n`` (None: from the rig's departures) acts
    on the current v3. Returns samples: time_s, position_m, velocity_m_s, acceleration_m_s2, current_a, voltage_v,
    command_m_s, load_n (F_move), friction_n, integrator, and power_w (= V i),
    input_power_w (= K_t/K_e V i), mech_power_w (= F_drive v3) as in ``simulate_drive``.

    ``method``: 'exact' (default): exact FOH propagation (modal lfilter) wherever the PID output is unclipped,
    LSODA only across friction-piece switches and through clipped stretches (current limiter / supply limit);
    'lsoda': LSODA over the whole record (the reference; DRIVE.md "Coupled drive" gives the agreement)."""
    if not isinstance(rig, RigParams):
        raise SimError(f'rig is {type(rig).__name__}; expected RigParams')
    control = DriveControl() if control is None else control
    if not isinstance(control, DriveControl):
        raise SimError(f'control is {type(control).__name__}; expected DriveControl')
    if method not in DRIVE_METHODS:
        raise SimError(f'method is {method!r}; expected one of {DRIVE_METHODS}')
    t = np.asarray(t, dtype=float)
    n = len(t)
    if n < 2 or t[0] != 0.0:
        raise SimError(f'grid starts at {t[0] if n else None!r} with {n} samples; expected >= 2 samples from 0 s')
    h = float(t[1] - t[0])
    cmd = np.broadcast_to(np.asarray(command_m_s, dtype=float), t.shape).astype(float)
    load = np.zeros(n) if load_n is None else np.broadcast_to(np.asarray(load_n, dtype=float), t.shape).astype(float)
    if not (np.all(np.isfinite(cmd)) and np.all(np.isfinite(load))):
        raise SimError('command or load contains non-finite samples; expected finite m/s and N')
    drive = apply_overrides(rig.drive, overrides)
    _validate_drive(drive)
    setup = DriveSetup(drive, control)
    fc = _friction_n(rig) if friction_n is None else float(friction_n)
    if not (math.isfinite(fc) and fc >= 0):
        raise SimError(f'friction_n is {friction_n!r}; expected a finite force >= 0 N')
    inv_h, last = 1.0 / h, n - 2
    lists = []          # command and load as plain floats, made on the first LSODA call only

    def fun(tt, x):
        if not lists:
            lists.extend((cmd.tolist(), load.tolist()))
        cl, ll = lists
        s = tt * inv_h
        k = int(s)
        if k > last:
            k = last
        w = s - k
        f = ll[k] + w * (ll[k + 1] - ll[k])
        if fc:
            f += fc * min(1.0, max(-1.0, x[1] / V_EPS_M_S))
        return drive_rhs(tt, x, (cl[k] + w * (cl[k + 1] - cl[k]), f), setup)

    X = None
    if method == 'exact':
        uniform = np.allclose(np.diff(t), h, rtol=1e-9, atol=1e-15)
        X = _drive_exact(setup, fc, t, cmd, load, fun) if uniform else None
    if X is None:
        sol = solve_ivp(fun, (0.0, float(t[-1])), np.zeros(4), method='LSODA', t_eval=t, max_step=DRIVE_MAX_STEP_S,
                        rtol=DRIVE_RTOL, atol=DRIVE_ATOL)
        if not sol.success:
            raise SimError(f'drive integration failed ({sol.message}); expected solve_ivp to succeed')
        X = sol.y.T
    x3, v3, i, z = X.T.copy()
    fric = fc * np.clip(v3 / V_EPS_M_S, -1.0, 1.0)
    acc = (setup.k_force * i - setup.damping * v3 - load - fric) / setup.mass_kg
    volt = drive_voltage_array(v3, i, z, cmd, acc, setup)
    return {'time_s': t, 'position_m': x3, 'velocity_m_s': v3, 'acceleration_m_s2': acc, 'current_a': i,
            'voltage_v': volt, 'command_m_s': cmd, 'load_n': load, 'friction_n': fric, 'integrator': z,
            'power_w': volt * i, 'input_power_w': setup.power_factor * volt * i,
            'mech_power_w': setup.k_force * i * v3, 'drive': drive, 'control': control}


def drive_voltage_array(v3, i, z, cmd, acc, setup: DriveSetup) -> np.ndarray:
    """Vectorised ``drive.drive_voltage``: the applied voltage for sampled states (same limits, same order)."""
    d, c = setup.drive, setup.control
    v_pid = c.kp_v_per_m_s * (cmd - v3) + c.ki_v_per_m * z - c.kd_v_s2_per_m * acc
    e_b = setup.k_emf * v3
    r, lw, imax = d.armature_resistance_ohm, d.armature_inductance_h * c.current_loop_rad_s, d.current_limit_a
    volt = np.minimum(np.maximum(v_pid, -r * imax + e_b + lw * (-imax - i)), r * imax + e_b + lw * (imax - i))
    return np.clip(volt, -d.voltage_limit_v, d.voltage_limit_v)


def drive_motion(dr: Dict[str, np.ndarray]) -> DriveMotion:
    return DriveMotion(dr['time_s'], dr['position_m'], dr['velocity_m_s'], dr['acceleration_m_s2'],
                       dr['command_m_s'])


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
    drive: Dict[str, np.ndarray] = field(default_factory=dict)          # final drive run (load: final F_move)
    drive_no_load: Dict[str, np.ndarray] = field(default_factory=dict)  # first pass (no lanyard load)


def run_coupled_pull(rig: RigParams, spec: PullSpec, noise: bool = True, control: DriveControl | None = None,
                     iterations: int = 8, tol_m: float = 1.0e-6, overrides=None,
                     method: str = 'exact') -> CoupledPullResult:
    """One pull with the drive coupled to the force chain (waveform relaxation, see module doc).

    ``method``: the drive integrator of ``drive_on_grid`` ('exact' or the reference 'lsoda').
    ``iterations``: most chain solves allowed (SimError if x3 still changes by >= ``tol_m`` after them).
    Channels as ``run_pull``, except motor_* from the drive simulation and the encoder from the coupled x3.
    Forces and the truth signals come from the last chain solve (driven by the previous pass's motion, which
    the final drive run reproduces to < tol_m).
    """
    if isinstance(iterations, bool) or not isinstance(iterations, (int, np.integer)) or iterations < 1:
        raise SimError(f'iterations is {iterations!r}; expected an integer >= 1')
    if not (isinstance(tol_m, (int, float)) and math.isfinite(tol_m) and tol_m > 0):
        raise SimError(f'tol_m is {tol_m!r}; expected a positive length in metres')
    p = chain_params(rig, spec)
    prescribed = motion_for(rig, spec)          # raises if the prescribed pull does not fit
    t = sample_times_s(rig)
    cmd = prescribed.kinematics(t)[1]
    dr = drive_on_grid(rig, t, cmd, None, control, overrides, method=method)
    check_fits(rig, dr['position_m'], dr['velocity_m_s'])
    first = dr
    changes: List[float] = []
    converged = False
    for _ in range(int(iterations)):
        motion = drive_motion(dr)
        kin = (dr['position_m'], dr['velocity_m_s'], dr['acceleration_m_s2'])
        traj = integrate_chain(p, motion, t, kinematics=kin)
        fm = force_move(traj.x, p)
        new = drive_on_grid(rig, t, cmd, fm, control, overrides, method=method)
        check_fits(rig, new['position_m'], new['velocity_m_s'])
        changes.append(float(np.max(np.abs(new['position_m'] - dr['position_m']))))
        dr = new
        if changes[-1] < tol_m:
            converged = True
            break
    if not converged:
        raise SimError(f'coupled pull did not converge: x3 still changes by {changes[-1]:.3g} m after '
                       f'{len(changes)} passes; expected < {tol_m} m within {iterations}')
    x3, v3, a3 = kin
    X = traj.x
    T = chain_tension(p, traj, kin)
    fs = force_stat(X, p)
    a2 = (fm - T) / p.m2

    channels = record_channels(rig, spec, t, dr['position_m'], fm, fs, a2, noise,
                               motor=(dr['command_m_s'], dr['current_a'], dr['voltage_v']))
    taut_index, break_index, break_end_index, truth = events_and_truth(t, traj, p, kin, T, fm, fs)
    truth['v3_no_load_m_s'] = first['velocity_m_s']
    return CoupledPullResult(channels, spec, motion, taut_index, break_index, break_end_index, traj.taut_s,
                             traj.break_s, truth, iterations=len(changes), x3_changes_m=changes, drive=dr,
                             drive_no_load=first)


def simulate_coupled_pull(rig: RigParams, spec: PullSpec, noise: bool = True, **kw) -> Dict[str, np.ndarray]:
    return run_coupled_pull(rig, spec, noise, **kw).channels


__all__ = ['DriveMotion', 'drive_on_grid', 'DRIVE_METHODS', 'drive_voltage_array', 'drive_motion', 'check_fits',
           'CoupledPullResult', 'run_coupled_pull', 'simulate_coupled_pull', 'V_EPS_M_S']
