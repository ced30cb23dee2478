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
from scipy.integrate import odeint, solve_ivp
from scipy.interpolate import PPoly
from scipy.signal import lfilter

from .chain import ChainParams, chain_rhs, force_move, force_stat, lanyard_drive, linear_matrices, tension
from .drive import DriveControl, DriveSetup, _validate_drive, apply_overrides, drive_rhs
from .errors import SimError
from .integrate import ChainTrajectory, integrate_chain
from .params import RigParams
from .pull import PullResult, PullSpec, chain_params, events_and_truth, motion_for, record_channels, sample_times_s

V_EPS_M_S = 1.0e-3          # dry friction F_c sat(v3 / V_EPS): full F_c above 1 mm/s
DRIVE_MAX_STEP_S = 1.0e-3   # LSODA max step (adaptive below that)
DRIVE_RTOL = 1.0e-7         # x3 within 1e-7 m of a 20 us max-step run (truth rig), 3x faster than 1e-8
DRIVE_ATOL = np.array([1e-9, 1e-8, 1e-6, 1e-10])
STACK_RTOL = 1.0e-9         # drive with the free chain's states (after the break): odeint, BDF order <= 2
STACK_MXSTEP = 200000        # odeint step budget per call (the 1.35 s after the break: 25000-90000 evaluations)
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

    def __init__(self, setup: DriveSetup, damping: float, friction_n: float, h: float, stack=None):
        d, c = setup.drive, setup.control
        m, L = setup.mass_kg, d.armature_inductance_h
        ns = 0 if stack is None else len(stack[1])
        nx = 4 + ns
        A = np.zeros((nx, nx))
        B = np.zeros((nx, 3))
        A[0, 1] = 1.0
        A[1, 1], A[1, 2] = -damping / m, setup.k_force / m
        B[1, 1], B[1, 2] = -1.0 / m, -friction_n / m
        if ns:   # the free chain's moving side on the carriage: load c_s s, s' = A_s s + b_s a3
            A_s, b_s, c_s = stack
            A[1, 4:] = -c_s / m
        v_row = np.zeros(nx)
        v_row[1], v_row[3] = -c.kp_v_per_m_s, c.ki_v_per_m
        v_row = v_row - c.kd_v_s2_per_m * A[1]
        v_in = np.array([c.kp_v_per_m_s, 0.0, 0.0]) - c.kd_v_s2_per_m * B[1]
        A[2] = v_row / L
        A[2, 1] -= setup.k_emf / L
        A[2, 2] -= d.armature_resistance_ohm / L
        B[2] = v_in / L
        A[3, 1], B[3, 0] = -1.0, 1.0
        if ns:
            A[4:, 4:] = A_s
            A[4:] += np.outer(b_s, A[1])
            B[4:] = np.outer(b_s, B[1])
        self.nx, self.A = nx, A                                  # x' = A x + B u (A: the closed loop)
        self.acc_row, self.acc_in = A[1].copy(), B[1].copy()     # acceleration = acc_row x + acc_in u
        self.v_row, self.v_in = v_row, v_in                      # V_pid = v_row x + v_in u
        evs, V = np.linalg.eig(A)
        Vinv = np.linalg.inv(V)
        err = np.abs((V * evs) @ Vinv - A).max() / np.abs(A).max()
        keep = np.flatnonzero(evs.imag >= 0)
        self.modal = (np.isfinite(err) and err <= 1e-9 and np.linalg.cond(V) <= 1e8
                      and 2 * int(np.sum(evs.imag > 0)) + int(np.sum(evs.imag == 0)) == nx)
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
        X = np.zeros((U.shape[0], self.nx))
        for j, lam in enumerate(self.lam):
            q = _cols(U[:-1], self.q0[j]) + _cols(U[1:], self.q1[j])
            y = np.empty(U.shape[0], dtype=complex)
            y[0] = y0[j]
            y[1:] = lfilter([1.0], [1.0, -lam], q, zi=[lam * y0[j]])[0]
            yr, yi = y.real, y.imag
            for r in range(self.nx):
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


def _drive_exact(setup: DriveSetup, fc: float, t, cmd, load, fun, X, k0: int, k1: int, stack=None,
                 atol=None) -> bool:
    """Fill X[k0 + 1 .. k1] (X[k0] given): exact LTI propagation while unclipped, LSODA (``fun``) elsewhere.
    ``stack``: the free chain's moving side (A_s, b_s, c_s) integrated with the drive (states 4:).
    False when the drive matrix has no modal form (then the caller integrates with LSODA)."""
    h = float(t[1] - t[0])
    b = setup.damping
    if fc:
        pieces = {0: _DriveLinear(setup, b + fc / V_EPS_M_S, 0.0, h, stack), 1: _DriveLinear(setup, b, fc, h, stack),
                  -1: _DriveLinear(setup, b, -fc, h, stack)}
    else:
        pieces = {0: _DriveLinear(setup, b, 0.0, h, stack)}
    if not all(lin.modal for lin in pieces.values()):
        return False
    U = np.column_stack([cmd, load, np.ones(len(t))])

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

    def lsoda(ka, kb):
        _lsoda_into(fun, t, X, ka, kb, atol)

    k, win, nwin = k0, _LIN_WINDOW, _NL_WINDOW
    while k < k1:
        piece = int(piece_of(X[k, 1]))
        if unclipped(X[k:k + 1], U[k:k + 1], piece)[0]:
            end = min(k1, k + win)
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
            end = min(k1, k + nwin)
            lsoda(k, end)
            ok = unclipped(X[k:end + 1], U[k:end + 1], piece_of(X[k:end + 1, 1]))
            run = np.convolve(ok.astype(int), np.ones(_HANDOVER, dtype=int), 'valid') == _HANDOVER
            start = np.flatnonzero(run[1:])
            if len(start):
                k, nwin = k + 1 + int(start[0]), _NL_WINDOW
            else:
                k, nwin = end, 2 * nwin
    return True


def _lsoda_into(fun, t, X, k0: int, k1: int, atol=None) -> None:
    """LSODA from X[k0] at t[k0] to t[k1]; the samples go to X[k0 + 1 .. k1].

    With the free chain's states (more than the drive's 4): ``odeint``'s LSODA with the stiff (BDF) order capped
    at 2 and rtol 1e-9. The chain's lightly damped cell mode (4-8 kHz, zeta 0.02) lies close to the imaginary
    axis, where BDF orders 3-5 are unstable: solve_ivp's LSODA, which cannot cap the order, crawls through it
    (nominal set 3: 117000 evaluations, 5 s for the 1.35 s after the break; capped: 25000, 0.5 s)."""
    if X.shape[1] > 4:
        y, info = odeint(fun, X[k0], t[k0:k1 + 1], tfirst=True, rtol=STACK_RTOL, atol=atol, hmax=DRIVE_MAX_STEP_S,
                         mxords=2, mxstep=STACK_MXSTEP, full_output=True)
        if info['message'] != 'Integration successful.':
            raise SimError(f'drive integration with the free chain failed ({info["message"]}); expected odeint '
                           f'to succeed')
        X[k0 + 1:k1 + 1] = y[1:]
        return
    sol = solve_ivp(fun, (float(t[k0]), float(t[k1])), X[k0], method='LSODA', t_eval=t[k0:k1 + 1],
                    max_step=DRIVE_MAX_STEP_S, rtol=DRIVE_RTOL, atol=DRIVE_ATOL if atol is None else atol)
    if not sol.success:
        raise SimError(f'drive integration failed ({sol.message}); expected solve_ivp to succeed')
    X[k0 + 1:k1 + 1] = sol.y.T[1:]


def free_chain_stack(p: ChainParams):
    """The moving side of the free chain (lanyard slack or broken: T = 0) as a linear load on the carriage:
    (idx, A_s, b_s, c_s) with s = x[idx] (the chain states of m2 and, with the mount, of the base; the
    stationary side, states 2 and 3, is not connected to the carriage), s' = A_s s + b_s a3, F_move = c_s s.
    From ``chain.linear_matrices`` and ``chain.force_move`` (one home for the chain's equations)."""
    A, B = linear_matrices(p, taut=False)
    idx = [j for j in range(p.n_states) if j not in (2, 3)]
    eye = np.eye(p.n_states)
    c_s = np.array([float(force_move(eye[j], p)) for j in idx])
    return idx, A[np.ix_(idx, idx)], B[idx, 2].copy(), c_s


def linearised_after_break(rig: RigParams, p: ChainParams, control: DriveControl | None = None, overrides=None):
    """(A_closed, A_held): the state matrices after the break, carriage moving forward (friction on its +F_c
    piece, PID unclipped). A_closed: drive [x3, v3, i, z] and the free chain's moving side together (the
    matrix the drive pass propagates); A_held: the free chain's moving side on a carriage that does not move
    (the prescribed-motion case). Their eigenvalues give the mount mode with and without the drive loop."""
    control = DriveControl() if control is None else control
    setup = DriveSetup(apply_overrides(rig.drive, overrides), control)
    _, A_s, b_s, c_s = free_chain_stack(p)
    lin = _DriveLinear(setup, setup.damping, _friction_n(rig), 1.0 / rig.daq.sample_rate_hz, (A_s, b_s, c_s))
    return lin.A.copy(), A_s.copy()


def drive_on_grid(rig: RigParams, t, command_m_s, load_n=None, control: DriveControl | None = None,
                  overrides=None, friction_n: Optional[float] = None, method: str = 'exact',
                  free_chain=None) -> Dict[str, np.ndarray]:
    """The drive from rest on the uniform grid ``t`` (from 0): command and load (N, tension) given as samples
    on the grid (linear between samples); dry friction ``friction_n`` (None: from the rig's departures) acts
    on the current v3. Returns samples: time_s, position_m, velocity_m_s, acceleration_m_s2, current_a, voltage_v,
    command_m_s, load_n (F_move), friction_n, integrator, and power_w (= V i),
    input_power_w (= K_t/K_e V i), mech_power_w (= F_drive v3) as in ``simulate_drive``.

    ``free_chain``: None, or (ChainParams p, sample k_s, chain state at t[k_s]) for a chain that is free from
    t[k_s] on for good (the coupon broken, beta = 0): from k_s the drive is integrated together with the free
    chain's moving side (``free_chain_stack``), whose F_move is the load (``load_n`` is used up to k_s only).
    This is how the coupled pull gets the mount's ringing after the break (DRIVE.md "Ringing after the break").

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
    k_s, stack, s0 = n - 1, None, None
    A_s = b_s = c_s = None
    if free_chain is not None:
        p, k_s, x_chain = free_chain
        x_chain = np.asarray(x_chain, dtype=float)
        if not (isinstance(p, ChainParams) and isinstance(k_s, (int, np.integer)) and 0 <= k_s < n
                and x_chain.shape == (p.n_states,) and np.all(np.isfinite(x_chain))):
            raise SimError(f'free_chain is ({type(p).__name__}, {k_s!r}, state of shape {x_chain.shape}); expected '
                           f'(ChainParams, a sample index in [0, {n}), {getattr(p, "n_states", "?")} finite states)')
        k_s = int(k_s)
        idx, A_s, b_s, c_s = free_chain_stack(p)
        stack, s0 = (A_s, b_s, c_s), x_chain[idx]
    load_s = load
    if stack is not None:                # the free chain is the load from k_s on
        load_s = load.copy()
        load_s[k_s:] = 0.0
    inv_h, last = 1.0 / h, n - 2
    lists = {}          # command and load as plain floats, made on the first LSODA call of each phase

    def inputs(tt, x, samples):
        if samples not in lists:
            lists[samples] = (cmd.tolist(), (load if samples == 'load' else load_s).tolist())
        cl, ll = lists[samples]
        s = tt * inv_h
        k = int(s)
        if k > last:
            k = last
        w = s - k
        f = ll[k] + w * (ll[k + 1] - ll[k])
        if fc:
            f += fc * min(1.0, max(-1.0, x[1] / V_EPS_M_S))
        return cl[k] + w * (cl[k + 1] - cl[k]), f

    def fun(tt, x):
        return drive_rhs(tt, x, inputs(tt, x, 'load'), setup)

    def fun_stack(tt, x):
        c, f = inputs(tt, x, 'load_s')
        s = x[4:]
        dx = drive_rhs(tt, x[:4], (c, f + float(c_s @ s)), setup)
        return np.concatenate([dx, A_s @ s + b_s * dx[1]])

    X = np.zeros((n, 4 if stack is None else 4 + len(s0)))
    X4 = X[:, :4]                        # a view: the drive states
    atol_s = None if stack is None else np.concatenate([DRIVE_ATOL, np.tile([1e-13, 1e-9], len(s0) // 2)])
    exact = method == 'exact' and np.allclose(np.diff(t), h, rtol=1e-9, atol=1e-15)
    if not (exact and _drive_exact(setup, fc, t, cmd, load, fun, X4, 0, k_s)):
        _lsoda_into(fun, t, X4, 0, k_s)
    if stack is not None:
        X[k_s, 4:] = s0
        if not (exact and _drive_exact(setup, fc, t, cmd, load_s, fun_stack, X, k_s, n - 1, stack, atol_s)):
            _lsoda_into(fun_stack, t, X, k_s, n - 1, atol_s)
    x3, v3, i, z = X[:, :4].T.copy()
    fl = load_s.copy()
    if stack is not None:
        fl[k_s:] = _cols(X[k_s:, 4:], c_s)
    fric = fc * np.clip(v3 / V_EPS_M_S, -1.0, 1.0)
    acc = (setup.k_force * i - setup.damping * v3 - fl - fric) / setup.mass_kg
    volt = drive_voltage_array(v3, i, z, cmd, acc, setup)
    return {'time_s': t, 'position_m': x3, 'velocity_m_s': v3, 'acceleration_m_s2': acc, 'current_a': i,
            'voltage_v': volt, 'command_m_s': cmd, 'load_n': fl, 'friction_n': fric, 'integrator': z,
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
    for _ in range(int(iterations)):
        motion = drive_motion(dr)
        kin = (dr['position_m'], dr['velocity_m_s'], dr['acceleration_m_s2'])
        traj = integrate_chain(p, motion, t, kinematics=kin)
        fm = force_move(traj.x, p)
        f_changes.append(math.inf if fm_last is None else float(np.max(np.abs(fm - fm_last))))
        fm_last = fm
        new = drive_on_grid(rig, t, cmd, fm, control, overrides, method=method,
                            free_chain=free_after_break(p, traj) if joint_after_break else None)
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

    channels = record_channels(rig, spec, t, dr['position_m'], fm, fs, a2, noise,
                               motor=(dr['command_m_s'], dr['current_a'], dr['voltage_v']))
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
    fc = _friction_n(rig)
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


def simulate_coupled_pull(rig: RigParams, spec: PullSpec, noise: bool = True, **kw) -> Dict[str, np.ndarray]:
    return run_coupled_pull(rig, spec, noise, **kw).channels


__all__ = ['DriveMotion', 'drive_on_grid', 'DRIVE_METHODS', 'drive_voltage_array', 'drive_motion', 'check_fits',
           'CoupledPullResult', 'run_coupled_pull', 'simulate_coupled_pull', 'V_EPS_M_S', 'free_chain_stack',
           'free_after_break', 'integrate_coupled_reference', 'linearised_after_break']
