"""The search's per-pull series: each searched channel's residual after the named causes, the signals its terms are
made of, and what the budget and the catalog's priority need beside them (ChannelSeries); the pull with the
sensors' terms taken out (sensor_corrected). Decimated to about SEARCH_RATE_HZ, usable samples only. ROS-free."""
from __future__ import annotations

import dataclasses
from typing import Dict, NamedTuple, Optional, Sequence

import numpy as np

from force_tester_sim.core.extra_terms import SIN, parse_term, signals, term_values

from ..budget import DRIVE_VARIANTS
from ..friction import MOVING_M_S, STILL_M_S, drive_force_balance, rest_level
from ..prep import Pull, as_encoder, like_a3, read_later, tension_from_stationary
from .grammar import RELATIVE, SENSORS

FREE_SPAN_S = 0.5              # the sensors' free phases: at most this long before the pull and after its ringing
BEFORE_LOAD_S = 0.2            # the moving cell's free phase before the load, searched with its analysis window: a
                               # zero that drifts is there with no load, an AC coupling acts only on a signal
EDGE_S = 0.02                  # the free phases leave the record's first and last 20 ms out (the filters' edges)
SEARCH_RATE_HZ = 20000.0       # the residuals are decimated to about this rate (the channels are low-passed below)
ANALOG = ('F_move', 'F_stat', 'T', 'a2')   # the signals from analog channels: the current's balance reads them at its
                                          # fitted lead (balance_lead), the terms made of them then filtered as a3 is
                                          # made (Through); v, x: the encoder's, as they are
LEAD_MAX_S = 1e-3              # the analog channels' lag behind the encoder that balance_lead fits, at most


class Through(NamedTuple):
    """A channel whose residual is formed through a linear filter (the motor current's: like_a3, which makes the
    encoder's a3): its library columns are the terms of the whole record's signals through that same filter, then
    taken at the samples searched (normal_equations.beyond_part). A product's filtered form is not the product of
    its factors' filtered forms: a2 is mostly its cells' ringing, above what a3 follows, so like_a3(a2)^2 is a small
    part of like_a3(a2^2), the part of a2^2 the current's balance keeps (an a2^2 of 3x the band on the current, the
    independent generator's nominal campaign: 0.0048 A rms over the analysis window as a product of filtered factors,
    0.38 A as a filtered product; the search named nothing, the residual's SSE fell 0.01 % with the first, 78 % with
    the second)."""

    signals: Dict[str, np.ndarray]      # the grammar's signals over the whole record (the analog ones read at the
                                        # channel's lead)
    dt: float                           # s
    samples: np.ndarray                 # the samples searched (ChannelSeries' own)
    window: np.ndarray                  # the analysis window's samples among them (ChannelSeries.window's)


class ChannelSeries(NamedTuple):
    """One channel of one pull, decimated, usable samples only."""

    residual: np.ndarray                # what the model of record (and the named causes) leave, channel unit
    signals: Dict[str, np.ndarray]      # the grammar's signals on the same samples (extra_terms.SIGNALS, 't')
    catalog: Optional[np.ndarray]       # the catalog columns that compete with the library (samples x k or samples:
                                        # the Coulomb step on the current; the gain's and m2's forms on the moving
                                        # cell)
    causes: Dict[str, np.ndarray]       # each named force-model cause's contribution (priority.cause_check)
    systematic: Dict[str, np.ndarray]   # the residual's change with each rig constant one standard u off
    window: Optional[Dict[str, np.ndarray]] = None   # a sensor's signals over the analysis window, as measured: its
                                                     # terms are all judged there, where it reads the force
    own: Optional[Dict[str, np.ndarray]] = None      # the signals its reference stands for (the accelerometer's a2
                                                     # is the encoder's acceleration) as the sensor reads them: a term
                                                     # in them is refitted so (selection.REFERENCE_SHIFT)
    through: Optional[Through] = None   # the filter the residual is formed through, with what its columns need
    nuisance: Optional[np.ndarray] = None   # per-pull columns (samples x k) fitted beside every term on the pull
                                            # alone: profiled out of the residual and every column (the current's
                                            # lead, normal_equations.beyond_part)


def term_column(cs: ChannelSeries, term: str) -> np.ndarray:
    """A product term's values on the channel's samples, as its library column is made (through the residual's
    filter when the channel has one: Through)."""
    if cs.through is None:
        return term_values(term, cs.signals)
    return like_a3(term_values(term, cs.through.signals), cs.through.dt)[cs.through.samples]


def decimation(dt: float) -> int:
    return max(1, int(round(1.0 / (SEARCH_RATE_HZ * dt))))


def free_samples(p: Pull) -> np.ndarray:
    """The sensors' free phases of a pull, decimated: lanyard slack before the pull and after the break's ringing,
    FREE_SPAN_S each, the record's edges (EDGE_S) left out, usable samples only."""
    free = np.zeros(len(p.t), bool)
    e, span = int(round(EDGE_S / p.dt)), int(round(FREE_SPAN_S / p.dt))
    free[max(e, p.pre1 - span):p.pre1] = True
    free[p.w1:min(len(p.t) - e, p.w1 + span)] = True
    return np.flatnonzero(free & p.usable())[::decimation(p.dt)]


def before_samples(p: Pull) -> np.ndarray:
    """The moving cell's free phase before the load, decimated: BEFORE_LOAD_S up to the analysis window's start
    (lanyard slack, T about 0), the record's first EDGE_S left out, usable samples only."""
    free = np.zeros(len(p.t), bool)
    free[max(int(round(EDGE_S / p.dt)), p.w0 - int(round(BEFORE_LOAD_S / p.dt))):p.w0] = True
    return np.flatnonzero(free & p.usable())[::decimation(p.dt)]


def smoothed_a2(p: Pull) -> np.ndarray:
    """a2 smoothed as the encoder's a3 is (the accelerometer's free-phase model is a3)."""
    return as_encoder(p.a2, p.dt)


def balance_lead(p: Pull, d, fm: np.ndarray, use: np.ndarray) -> float:
    """The analog channels' lag behind the encoder (s; its latched counter has no anti-alias filter, the current
    and the cells have): the lead that makes the drive's force balance, k_F i - F_move through prep.like_a3 against
    m_c a3 + b v3, least squares on the samples use (Gauss-Newton from 0, two steps; within +/-LEAD_MAX_S). One
    nuisance parameter a pull, like the hum's phase: its information is in the load's rise and the break."""
    kf = d.force_per_amp_n_per_a
    motion = drive_force_balance(p, d, 0.0)   # m_c a3 + b v3
    lead = 0.0
    for _ in range(2):
        g = like_a3(kf * p.current - fm, p.dt, lead)
        dg = np.gradient(g, p.dt)[use]
        r = (g - motion)[use]
        r = r - np.median(r)
        den = float(dg @ dg)
        if not den > 0:
            return 0.0
        lead = float(np.clip(lead - (dg @ r) / den, -LEAD_MAX_S, LEAD_MAX_S))
    return lead


def channel_series(p: Pull, rig, force_resid: np.ndarray, hum: Optional[np.ndarray],
                   causes: Optional[Dict[str, np.ndarray]] = None, before: Optional[tuple] = None
                   ) -> Dict[str, ChannelSeries]:
    """{channel: ChannelSeries} of one pull.

    force_moving: the force model's residual on W after the named causes (force_resid, from ForceModel.resid);
    F_move is the model's prediction (measured minus hum minus residual). motor_current (A): the drive's force
    balance with the predicted F_move, over the samples at rest and moving, minus the pull's median at rest; its
    catalog columns are the Coulomb step (1 while moving) in A per N of friction, on every pull (the search fits it
    with the terms when the cause is named, and weighs it against each term in the term's place: a catalog cause
    with as many parameters), then the forms of the drive's k_F and reflected mass (grammar.DRIVE_FORMS: fitted
    beside a term, weighed against it in its place). causes: each named force-model cause's contribution to the
    moving cell's residual on W (what the residual would gain were the cause undone, at its fitted parameters;
    cause_check). before: (samples, residual, causes) of the moving cell's free phase before the load
    (before_samples; the force model there at its fitted parameters, force_model.resid_at), put ahead of W: a zero
    drifting with no load is seen there, where an AC coupling, which acts on the load, leaves nothing; so the two
    compete on the same held-out samples (issue 39: a drift from the record's start was fitted as the AC coupling on
    W alone)."""
    q = decimation(p.dt)
    out = {}
    w = slice(p.w0, p.w1)
    fm_pred = p.fm - (0.0 if hum is None else hum)
    fm_pred = fm_pred.copy()
    fm_pred[w] = fm_pred[w] - force_resid
    full = signals(p.t, fm_pred, p.fs, p.T, p.a2, p.v3, p.x3)
    ok = p.usable(p.w0, p.w1)[::q]
    u_m2 = rig.uncertainty.u('force_chain.moving_side_mass_kg')
    # the cell's gain one standard uncertainty off (its calibration): a gain inside its tolerance is not fitted by
    # the catalog, and its linear error leaks into any term that grows with the load (F_move^3, F_move*v)
    _, key, attr = RELATIVE['force_moving']
    u_g = rig.uncertainty.relative(key, getattr(rig.sensors, attr))
    on_w = np.arange(p.w0, p.w1)[::q][ok]   # W's samples as the residual has them
    y_m, c_m = np.asarray(force_resid)[::q][ok], {c: np.asarray(v)[::q][ok] for c, v in (causes or {}).items()}
    idx_m, fm_m = on_w, fm_pred
    if before is not None and len(before[0]):
        b_sel, b_res, b_causes = before
        idx_m = np.concatenate([b_sel, on_w])
        y_m = np.concatenate([b_res, y_m])
        c_m = {c: np.concatenate([b_causes[c], v]) for c, v in c_m.items()}
        fm_m = fm_pred.copy()
        fm_m[b_sel] = fm_m[b_sel] - b_res   # F_move there the model's prediction too
    sig_m = signals(p.t, fm_m, p.fs, p.T, p.a2, p.v3, p.x3)
    # its catalog columns are the forms of the gain and m2 (grammar.FORCE_FORMS): F_move (the gain's relative
    # departure times the predicted force) and a2 (the mass's departure times it): a term is fitted with them beside
    # it, so the data measure them and their stated uncertainties leave the term's budget (selection.search_channel),
    # and a term is named only when it beats each in its place
    forms = np.column_stack([fm_m[idx_m], p.a2[idx_m]])
    out['force_moving'] = ChannelSeries(y_m, {k: v[idx_m] for k, v in sig_m.items()}, forms, c_m,
                                        {'m2': (u_m2 * p.a2)[idx_m], 'gain': (u_g * fm_m)[idx_m]})
    # the sensors on their own, in the free phases (lanyard slack before the pull and after the break's ringing,
    # FREE_SPAN_S each, the record's edges left out): there T = 0, so the stationary cell's model is 0 and the
    # accelerometer's the carriage's acceleration from the encoder (a2 smoothed as the encoder's a3 is), and the
    # accelerometer's own terms (a2^2: its non-linearity) are written in that acceleration
    sel = free_samples(p)
    if len(sel):
        sig = {k: v[sel] for k, v in full.items()}
        on_w = {k: v[w][::q][ok] for k, v in full.items()}
        out['force_stationary'] = ChannelSeries(p.fs[sel], sig, None, {}, {}, on_w)
        # the accelerometer's own terms in the quantity it should read: a2 there is the encoder's acceleration. That
        # reference is exact only to the encoder's resolution: where the carriage creeps a few counts (a set-4 pull
        # coming to rest after the break), a3 is the Savitzky-Golay second derivative of a staircase, 1-4 m/s^2 rms
        # that the accelerometer (0.1 m/s^2 there) does not read, and the residual carries it with coefficient -1, as
        # the columns do: an error in the variables. Its a2 as it reads it (own) gives the other reference
        a2s = smoothed_a2(p)
        out['accel_axial'] = ChannelSeries((a2s - p.a3)[sel], {**sig, 'a2': p.a3[sel]}, None, {}, {}, on_w,
                                           {'a2': a2s[sel]})
    if p.current is not None:
        d = rig.drive
        kf = d.force_per_amp_n_per_a
        moving = p.v3 > MOVING_M_S
        still = np.abs(p.v3) < STILL_M_S
        use = (moving | still) & p.usable()
        # the balance as a3 sees the motion (prep.like_a3), at the analog channels' lag behind the encoder
        # (balance_lead): with F_move and the current as they are, the cells' ringing (m2 a2, which the carriage's
        # own acceleration answers, and a3 does not carry) and the lag stayed in the residual, and on the
        # independent generator's clean campaigns an `a2` term on the current (about -m2 / k_F) was named (issue 39)
        if still.any() and moving.any():
            lead = balance_lead(p, d, fm_pred, use)
            cur, fm_b = like_a3(p.current, p.dt, lead), like_a3(fm_pred, p.dt, lead)
            # the signals at the lead (the analog ones read lead s later, as the current is; v, x from the encoder as
            # they are): a term's column is its product over these through like_a3 (Through), never the product of
            # filtered factors
            late = {k: (read_later(v, p.dt, lead) if k in ANALOG else v) for k, v in full.items()}

            # the current's zero: the balance at rest before the carriage first moves (friction.rest_level: after
            # the stop a dry contact holds what the drive still applies; and a term in x, at rest at the track's end
            # there, would leave its whole size in the zero, not in the residual: an injected x read -0.02 of 0.60)
            sg = np.where(p.usable(), np.where(moving, 1.0, np.where(still, 0.0, np.nan)), np.nan)

            def balance(d):   # the current's force balance in A with the drive constants d
                rho = cur * d.force_per_amp_n_per_a - drive_force_balance(p, d, fm_b)
                return (rho - rest_level(rho, sg)) / d.force_per_amp_n_per_a
            y = balance(d)
            # the catalog columns: the Coulomb step (A per N of friction), then the forms of the drive's k_F and
            # reflected mass (grammar.DRIVE_FORMS: the balance's change per relative k_F departure, the drive force
            # the model needs over k_F; and per kg of reflected mass, a3 over k_F), each from its rest level
            need = drive_force_balance(p, d, fm_b)
            col = np.column_stack([moving.astype(float), need - rest_level(need, sg), p.a3 - rest_level(p.a3, sg)]) / kf
            sel = np.flatnonzero(use)[::q]
            sys_ = {}
            for name, key in DRIVE_VARIANTS.items():   # each drive constant one standard uncertainty off
                u = rig.uncertainty.u(f'drive.{key}')
                if u > 0:
                    sys_[name] = (balance(dataclasses.replace(d, **{key: getattr(d, key) + u})) - y)[sel]
            # and the signals on the analysis window's samples among them: a term's size is judged there, where the
            # force is measured and where bench_sweep sizes its cells (selection.search_channel), as a sensor's is
            on_w = sel[(sel >= p.w0) & (sel < p.w1)]
            # the lead is fitted on the pull's balance alone (balance_lead), so it takes up what of a term there the
            # balance's time derivative can: an F_move^2 of 3x the band on the independent generator's nominal
            # campaign moved the pulls' leads from 63-76 us (clean; the anti-alias filter's 69) to -11 to -106 us,
            # and the search named nothing (F_stat*T, F_move*F_stat alike). Its column, the balance's change per
            # second of lead, is fitted beside every term on each pull (profiled out: ChannelSeries.nuisance), so a
            # term is measured with the lead free, as the drive's constants are, not in its place; with it, the
            # F_move^2 came out 6.2e-7 against 5.8e-7 (9.8e-8 with the lead held)
            lead_col = np.gradient(cur * kf - fm_b, p.dt) / kf
            out['motor_current'] = ChannelSeries(y[sel], {k: v[sel] for k, v in late.items()}, col[sel], {}, sys_,
                                                 {k: v[on_w] for k, v in late.items()},
                                                 through=Through(late, p.dt, sel, on_w), nuisance=lead_col[sel])
    return out


def sensor_corrected(p: Pull, terms: Sequence, rig, cal: Optional[tuple]) -> Pull:
    """The pull with the sensors' terms found on their own (SENSORS: force_stationary, accel_axial; terms with
    .channel, .term, .coefficient, .frequency_hz) taken out of F_stat and a2, and T recomputed from the corrected
    stationary cell (cal: cells.with_tension's (K_LC1, c1); None: the rig's): the moving cell and the motor current
    are then searched against what the sensors would have read without them. A sinusoid's phase is each pull's own:
    it is fitted (with the pull's amplitude) on the sensor's free phases, after its product terms, and taken out of
    the whole record."""
    full = signals(p.t, p.fm, p.fs, p.T, p.a2, p.v3, p.x3)
    d = {ch: sum((t.coefficient * term_values(t.term, full) for t in terms
                  if t.channel == ch and SIN not in parse_term(t.term)), np.zeros(len(p.t))) for ch in SENSORS}
    sines = [t for t in terms if t.channel in SENSORS and SIN in parse_term(t.term)]
    if sines:
        sel = free_samples(p)
        own = {'force_stationary': p.fs, 'accel_axial': smoothed_a2(p) - p.a3}   # the free phases' residuals
        for t in sines:
            fac = term_values(t.term, full)
            ph = 2 * np.pi * t.frequency_hz * full['t']
            X = np.column_stack([fac * np.cos(ph), fac * np.sin(ph)])
            c = np.linalg.lstsq(X[sel], (own[t.channel] - d[t.channel])[sel], rcond=None)[0]
            d[t.channel] = d[t.channel] + X @ c
    fc = rig.force_chain
    k1, c1 = (fc.load_cell_stiffness_n_per_m, fc.c1) if cal is None else cal
    dT = tension_from_stationary(d['force_stationary'], p.dt, fc.m1, k1, c1)
    return dataclasses.replace(p, fs=p.fs - d['force_stationary'], T=p.T - dT, a2=p.a2 - d['accel_axial'])
