"""The drive on the DAQ sample grid: the carriage's PID drive integrated with sampled command and load (ROS-free).

    m_c x3'' = N K_t i / r - (b_m + b_g) v3 - F_move(t) - F_c sat(v3 / V_EPS)      (core/drive.py)

The drive is integrated exactly on the grid wherever it is LTI (PID output unclipped, friction on one piece:
the modal first-order-hold propagator of core/modal.py, the one the chain uses in core/integrate.py) and by
LSODA only across piece switches and through clipped stretches (``drive_on_grid(..., method='exact')``, the
default); ``method='lsoda'`` integrates the whole record with LSODA (the reference it is tested against).
Dry friction (departure ``coulomb_friction``) acts on the current v3, smoothed over |v3| < V_EPS so the
right-hand side stays continuous. After the break, the free chain's moving side can be integrated with the
carriage (``free_chain``; core/coupled.py, DRIVE.md "Ringing after the break").
"""
from __future__ import annotations

import math
from typing import Dict, Optional

import numpy as np
from scipy.integrate import odeint, solve_ivp

from .chain import ChainParams, force_move, linear_matrices
from .drive import DriveControl, DriveSetup, apply_overrides, drive_rhs, validate_drive
from .errors import SimError
from .modal import ModalFOH, columns
from .params import RigParams

V_EPS_M_S = 1.0e-3          # dry friction F_c sat(v3 / V_EPS): full F_c above 1 mm/s
DRIVE_MAX_STEP_S = 1.0e-3   # LSODA max step (adaptive below that)
DRIVE_RTOL = 1.0e-7         # x3 within 1e-7 m of a 20 us max-step run (truth rig), 3x faster than 1e-8
DRIVE_ATOL = np.array([1e-9, 1e-8, 1e-6, 1e-10])
STACK_RTOL = 1.0e-9         # drive with the free chain's states (after the break): odeint, BDF order <= 2
STACK_MXSTEP = 200000        # odeint step budget per call (the 1.35 s after the break: 25000-90000 evaluations)


def friction_n_of(rig: RigParams) -> float:
    cf = rig.departures.get('coulomb_friction') if rig.departures else None
    return 0.0 if cf is None else float(cf['force_n'])


DRIVE_METHODS = ('exact', 'lsoda')
_LIN_WINDOW = 4096          # samples per exact (modal lfilter) chunk at first; doubled while no event occurs
_NL_WINDOW = 250            # samples per LSODA chunk in a clipped stretch at first (5 ms at 50 kHz); doubled
_HANDOVER = 10              # back to the exact path once this many consecutive LSODA samples are unclipped


class DriveLinear(ModalFOH):
    """The exact first-order-hold propagator (core/modal.py) of the unclipped drive on step h.

    While the PID output is inside the current limiter's and the supply's bounds (V = V_pid, z' = e) and the
    dry friction is on one piece of F_c sat(v3 / V_EPS) (the band |v3| <= V_EPS: a damping F_c / V_EPS; or
    +/-F_c), the drive is LTI: x' = A x + B [v_cmd, F_load, 1] (x3 is a pure integrator: lam = 0).
    ``propagate(x0, U)``: U's rows are [v_cmd, F_load, 1] on the grid.
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
        self.A = A                                               # x' = A x + B u (A: the closed loop)
        self.acc_row, self.acc_in = A[1].copy(), B[1].copy()     # acceleration = acc_row x + acc_in u
        self.v_row, self.v_in = v_row, v_in                      # V_pid = v_row x + v_in u
        super().__init__(A, B, h)


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
        pieces = {0: DriveLinear(setup, b + fc / V_EPS_M_S, 0.0, h, stack), 1: DriveLinear(setup, b, fc, h, stack),
                  -1: DriveLinear(setup, b, -fc, h, stack)}
    else:
        pieces = {0: DriveLinear(setup, b, 0.0, h, stack)}
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
            vp = columns(Xs, lin.v_row) + columns(Us, lin.v_in)
        else:
            vp = np.empty(len(Xs))
            for key, lin in pieces.items():
                sel = piece == key
                vp[sel] = columns(Xs[sel], lin.v_row) + columns(Us[sel], lin.v_in)
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
    lin = DriveLinear(setup, setup.damping, friction_n_of(rig), 1.0 / rig.daq.sample_rate_hz, (A_s, b_s, c_s))
    return lin.A.copy(), A_s.copy()


def drive_on_grid(rig: RigParams, t, command_m_s, load_n=None, control: DriveControl | None = None,
                  overrides=None, friction_n: Optional[float] = None, method: str = 'exact',
                  free_chain=None, extra_load_n=None) -> Dict[str, np.ndarray]:
    """The drive from rest on the uniform grid ``t`` (from 0): command and load (N, tension) given as samples
    on the grid (linear between samples); dry friction ``friction_n`` (None: from the rig's departures) acts
    on the current v3. Returns samples: time_s, position_m, velocity_m_s, acceleration_m_s2, current_a, voltage_v,
    command_m_s, load_n (F_move, plus ``extra_load_n``), friction_n, integrator, and power_w (= V i),
    input_power_w (= K_t/K_e V i), mech_power_w (= F_drive v3) as in ``simulate_drive``.

    ``extra_load_n``: a further load on the carriage, N, as samples on the grid (the rig's extra_terms on the motor
    current times the force per amp, core/coupled.py); unlike ``load_n`` it acts after ``free_chain``'s k_s too.

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
    extra = (np.zeros(n) if extra_load_n is None
             else np.broadcast_to(np.asarray(extra_load_n, dtype=float), t.shape).astype(float))
    if not (np.all(np.isfinite(cmd)) and np.all(np.isfinite(load)) and np.all(np.isfinite(extra))):
        raise SimError('command or load contains non-finite samples; expected finite m/s and N')
    load = load + extra
    drive = apply_overrides(rig.drive, overrides)
    validate_drive(drive)
    setup = DriveSetup(drive, control)
    fc = friction_n_of(rig) if friction_n is None else float(friction_n)
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
        load_s[k_s:] = extra[k_s:]
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
        fl[k_s:] = columns(X[k_s:, 4:], c_s) + extra[k_s:]
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


__all__ = ['drive_on_grid', 'DRIVE_METHODS', 'drive_voltage_array', 'V_EPS_M_S', 'free_chain_stack',
           'linearised_after_break', 'DriveLinear', 'friction_n_of', 'DRIVE_ATOL']
