"""Integration of the force chain on the DAQ sample grid.

The model is piecewise linear: between events it is one of two LTI systems (lanyard free: T = 0;
lanyard taut with beta = 1), driven by the carriage kinematics. Those stretches are propagated
exactly on the sample grid (matrix exponential, first-order hold on the inputs, modal
decomposition so each mode is one complex first-order recursion run by scipy.signal.lfilter: core/modal.py).
Events (lanyard engages / goes slack, F_stat reaches the break force) are located with
solve_ivp (DOP853, event functions) inside the sample interval where they occur, and the coupon's
break (beta falling linearly to 0, time varying) is integrated with solve_ivp as well.
``integrate_reference`` integrates the same model with solve_ivp alone (for verification).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.integrate import solve_ivp

from .chain import ChainParams, chain_rhs, chain_rhs_taut, force_stat, lanyard_drive, linear_matrices
from .errors import SimError
from .modal import ModalFOH

FREE, TAUT, BREAKING, BROKEN = 'free', 'taut', 'breaking', 'broken'
FLOW = 'flow'   # taut, coupon flowing plastically (only when ChainParams.yield_n is finite)
_RTOL = 1e-10
_ATOL = np.array([1e-16, 1e-11, 1e-16, 1e-11])
_ATOL6 = np.array([1e-16, 1e-11, 1e-16, 1e-11, 1e-16, 1e-11])   # with the mount_resonance states


def _atol(x0):
    return _ATOL6 if len(x0) == 6 else _ATOL


@dataclass
class ChainTrajectory:
    t: np.ndarray                 # sample times, s
    x: np.ndarray                 # (N, 4) states [w, w', u1, v1]
    beta: np.ndarray              # coupon load fraction at each sample
    taut_s: float | None = None   # first lanyard engagement
    break_s: float | None = None  # F_stat first reaches the break force
    yield_s: float | None = None  # the coupon starts to flow (ChainParams.yield_n finite only)
    events: list = field(default_factory=list)   # (time_s, new_mode)


def _chain_linear(A, B, h, blocks) -> ModalFOH:
    """The exact FOH propagator of one linear piece of the chain (core/modal.py); SimError where it has none."""
    lin = ModalFOH(A, B, h, blocks)
    if not lin.decomposed:
        raise SimError(f'modal decomposition error {lin.error:.3g}; expected < 1e-9 (defective or '
                       f'critically damped chain?)')
    if not lin.paired:
        raise SimError(f'eigenvalues {lin.eigenvalues} are not in conjugate pairs; expected a real system')
    if np.any(lin.eigenvalues == 0):
        raise SimError('the chain has a free rigid-body mode; expected both cells to have stiffness > 0')
    return lin


def _inputs(motion, t, beta=1.0):
    x3, v3, a3 = motion.kinematics_scalar(float(t))
    return (x3, v3, a3, beta)


def _make_rhs(p: ChainParams, motion, mode, t_break=None):
    if mode == BREAKING:
        d = p.break_duration_s

        def rhs(t, x):
            beta = min(1.0, max(0.0, 1.0 - (t - t_break) / d))
            return chain_rhs(t, x, _inputs(motion, t, beta), p)
    elif mode in (TAUT, FLOW) and p.mb > 0.0:
        def rhs(t, x):
            return chain_rhs_taut(t, x, _inputs(motion, t), p)
    elif mode in (TAUT, FLOW):
        # the linear piece: tension unclipped, so the slack event can be located
        def rhs(t, x):
            u = _inputs(motion, t)
            g = p.kl * (x[0] + u[0] - p.slack_m - x[2]) + p.cl * (x[1] + u[1] - x[3])
            fm = -(p.k2 * x[0] + p.c2 * x[1])
            fs = p.k1 * x[2] + p.c1 * x[3]
            return np.array([x[1], (fm - g) / p.m2 - u[2], x[3], (g - fs) / p.m1])
    else:
        def rhs(t, x):
            return chain_rhs(t, x, _inputs(motion, t, 0.0), p)
    return rhs


def _events(p: ChainParams, motion, mode, broken):
    def g_ev(t, x):
        return float(lanyard_drive(x, _inputs(motion, t), p))

    def brk_ev(t, x):
        return float(force_stat(x, p)) - p.break_n

    g_ev.terminal = True
    brk_ev.terminal = True
    brk_ev.direction = 1.0
    if mode == FREE and not broken:
        g_ev.direction = 1.0
        return [g_ev], [TAUT]
    if mode == TAUT:
        g_ev.direction = -1.0
        if p.yields:
            def y_ev(t, x):
                return float(lanyard_drive(x, _inputs(motion, t), p)) - p.yield_n
            y_ev.terminal = True
            y_ev.direction = 1.0
            return [g_ev, brk_ev, y_ev], [FREE, BREAKING, FLOW]
        return [g_ev, brk_ev], [FREE, BREAKING]
    if mode == FLOW:   # p: the flow parameters
        g_ev.direction = -1.0
        return [g_ev, brk_ev], [FREE, BREAKING]
    return [], []


def _ivp(rhs, t0, t1, x0, events=(), t_eval=None):
    sol = solve_ivp(rhs, (t0, t1), x0, method='DOP853', rtol=_RTOL, atol=_atol(x0), events=list(events) or None,
                    t_eval=t_eval, max_step=max((t1 - t0) / 4.0, 1e-9))
    if sol.status < 0:
        raise SimError(f'solve_ivp failed between {t0} s and {t1} s ({sol.message}); expected success')
    return sol


def _first_violation(p, mode, broken, Xs, x3, v3):
    """Offset (>= 1) of the first sample where the mode stops holding, or None."""
    if mode == FREE and not broken:
        bad = lanyard_drive(Xs[1:], np.column_stack([x3[1:], v3[1:]]), p) > 0
    elif mode in (TAUT, FLOW):
        g = lanyard_drive(Xs[1:], np.column_stack([x3[1:], v3[1:]]), p)
        bad = g < 0
        if not broken:
            bad |= force_stat(Xs[1:], p) >= p.break_n
        if mode == TAUT and p.yields:
            bad |= g >= p.yield_n
    else:
        return None
    hit = np.flatnonzero(bad)
    return int(hit[0]) + 1 if len(hit) else None


def integrate_chain(p: ChainParams, motion, t: np.ndarray, x0=None, kinematics=None) -> ChainTrajectory:
    """Integrate one pull on the sample grid ``t`` (uniform, starting at t[0] with state x0).

    ``kinematics``: optional precomputed ``motion.kinematics(t)``.
    """
    t = np.asarray(t, dtype=float)
    n = len(t)
    h = float(t[1] - t[0])
    xs, vs, as_ = motion.kinematics(t) if kinematics is None else kinematics
    U = np.column_stack([xs - p.slack_m, vs, as_])
    ns = p.n_states
    free_blocks = [[0, 1, 4, 5], [2, 3]] if ns == 6 else [[0, 1], [2, 3]]
    lin = {FREE: _chain_linear(*linear_matrices(p, False), h, free_blocks),
           TAUT: _chain_linear(*linear_matrices(p, True), h, [list(range(ns))])}
    lin[BROKEN] = lin[FREE]
    P = {FREE: p, TAUT: p, BROKEN: p}
    Us = {FREE: U, TAUT: U, BROKEN: U}
    if p.yields:   # the coupon yields: a third linear piece (taut, flowing) with its own parameters
        pf = p.flow_params()
        P[FLOW] = pf
        Us[FLOW] = np.column_stack([xs - pf.slack_m, vs, as_])
        lin[FLOW] = _chain_linear(*linear_matrices(pf, True), h, [list(range(ns))])
    flowed = False
    X = np.empty((n, ns))
    x = np.zeros(ns) if x0 is None else np.asarray(x0, dtype=float)
    X[0] = x
    tc, k_next, on_grid = t[0], 1, True
    broken = False
    mode = TAUT if lanyard_drive(x, _inputs(motion, tc), p) > 0 else FREE
    traj = ChainTrajectory(t=t, x=X, beta=np.ones(n))
    if mode == TAUT:
        traj.taut_s = tc
    guard = 0

    def switch(new, at):
        nonlocal mode, broken, flowed
        traj.events.append((at, new))
        if new == FLOW:
            flowed = True
            traj.yield_s = at
        if new == TAUT and traj.taut_s is None:
            traj.taut_s = at
        if new == BREAKING:
            traj.break_s = at
            broken = True
        mode = new

    while k_next < n:
        guard += 1
        if guard > 10 * n:
            raise SimError('event loop did not advance; expected a finite number of lanyard events')
        if mode == BREAKING:
            t_end = traj.break_s + p.break_duration_s
            stop = min(t_end, t[-1])
            kk = int(np.searchsorted(t, stop, side='right'))
            te = t[k_next:kk]
            sol = _ivp(_make_rhs(P[FLOW] if flowed else p, motion, BREAKING, traj.break_s), tc, stop, x,
                       t_eval=np.concatenate([te, [stop]]) if (len(te) == 0 or te[-1] < stop) else te)
            X[k_next:kk] = sol.y[:, :len(te)].T
            x, tc = sol.y[:, -1].copy(), stop
            on_grid = len(te) > 0 and te[-1] == stop
            k_next = kk
            switch(BROKEN, t_end)
            continue
        pm = P[mode]
        evs, news = _events(pm, motion, mode, broken)
        if not on_grid:
            sol = _ivp(_make_rhs(pm, motion, mode), tc, t[k_next], x, evs)
            if sol.status == 1:
                i = next(j for j, te in enumerate(sol.t_events) if len(te))
                tc, x = float(sol.t_events[i][0]), sol.y_events[i][0].copy()
                switch(news[i], tc)
                continue
            x, tc = sol.y[:, -1].copy(), t[k_next]
            X[k_next] = x
            k_next += 1
            on_grid = True
            continue
        # propagate in growing chunks until the first sample that violates the mode's conditions
        start, xcur, chunk, j = k_next - 1, x, 512, None
        while True:
            stop = min(n, start + chunk)
            Xs = lin[mode].propagate(xcur, Us[mode][start:stop])
            j = _first_violation(pm, mode, broken, Xs, xs[start:stop], vs[start:stop])
            if j is not None:
                j += start
                X[start:j] = Xs[:j - start]
                xj = Xs[j - start]
                break
            X[start:stop] = Xs
            if stop == n:
                break
            start, xcur, chunk = stop - 1, Xs[-1], chunk * 4
        if j is None:
            break
        tc, x = t[j - 1], X[j - 1].copy()
        sol = _ivp(_make_rhs(pm, motion, mode), tc, t[j], x, evs)
        k_next = j
        if sol.status == 1:
            i = next(jj for jj, te in enumerate(sol.t_events) if len(te))
            tc, x = float(sol.t_events[i][0]), sol.y_events[i][0].copy()
            on_grid = False
            switch(news[i], tc)
        else:  # the crossing was a round-off matter at the sample: take the event at t[j]
            x, tc = xj.copy(), t[j]
            X[j] = x
            k_next = j + 1
            on_grid = True
            g_j = float(lanyard_drive(x, _inputs(motion, tc), pm))
            if mode in (TAUT, FLOW) and not broken and float(force_stat(x, p)) >= p.break_n:
                switch(BREAKING, tc)
            elif mode == TAUT and p.yields and g_j >= p.yield_n:
                switch(FLOW, tc)
            else:
                switch((FLOW if mode == FLOW else TAUT) if g_j > 0 else FREE, tc)
    if traj.break_s is not None:
        traj.beta = np.clip(1.0 - (t - traj.break_s) / p.break_duration_s, 0.0, 1.0)
    return traj


def integrate_reference(p: ChainParams, motion, t: np.ndarray, x0, t_break=None,
                        max_step: float = 2e-6, flowing: bool = False) -> ChainTrajectory:
    """Same model, solve_ivp (DOP853) alone with event handling, on the samples ``t`` (for verification).

    ``flowing``: the coupon is already flowing at t[0] (only when ``p.yields``)."""
    t = np.asarray(t, dtype=float)
    X = np.empty((len(t), p.n_states))
    tb = t_break
    pf = p.flow_params() if p.yields else p
    state = {'flow': bool(flowing and p.yields), 'yield_s': None}

    def general(tt, x):
        pa = pf if state['flow'] else p
        beta = 1.0 if tb is None else min(1.0, max(0.0, 1.0 - (tt - tb) / p.break_duration_s))
        return chain_rhs(tt, x, _inputs(motion, tt, beta), pa)

    def brk(tt, x):
        return float(force_stat(x, p)) - p.break_n
    brk.terminal, brk.direction = True, 1.0

    def yld(tt, x):
        return float(lanyard_drive(x, _inputs(motion, tt), p)) - p.yield_n
    yld.terminal, yld.direction = True, 1.0
    i0, tc, x = 0, float(t[0]), np.asarray(x0, dtype=float)
    X[0] = x
    while i0 < len(t) - 1 or (i0 == 0 and len(t) == 1):
        evs = []
        if tb is None:
            evs.append(brk)
        if p.yields and not state['flow'] and tb is None:
            evs.append(yld)
        te = t[i0:] if tc == t[i0] else t[i0:]
        sol = solve_ivp(general, (tc, t[-1]), x, method='DOP853', rtol=_RTOL, atol=_atol(x), t_eval=te,
                        events=evs or None, max_step=max_step)
        m = len(sol.t)
        X[i0:i0 + m] = sol.y.T
        if sol.status == 1:
            k = next(j for j, e in enumerate(sol.t_events) if len(e))
            tc, x = float(sol.t_events[k][0]), sol.y_events[k][0].copy()
            if evs[k] is brk:
                tb = tc
            else:
                state['flow'] = True
                state['yield_s'] = tc
            i0 += m
            if i0 >= len(t):
                break
        else:
            break
    traj = ChainTrajectory(t=t, x=X, beta=np.ones(len(t)), break_s=tb, yield_s=state['yield_s'])
    if tb is not None:
        traj.beta = np.clip(1.0 - (t - tb) / p.break_duration_s, 0.0, 1.0)
    return traj
