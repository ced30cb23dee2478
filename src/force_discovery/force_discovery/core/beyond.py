"""Beyond the catalog (issue 27): when the residual keeps structure no catalog cause explains, search a grammar of
candidate terms with sparse regression, fitted on the fitted pulls and scored on the held-out ones. ROS-free.

The grammar (its one home: force_tester_sim.core.extra_terms). A term is added to one channel's model; the search
forms the residual of SEARCHED: the stationary cell and the accelerometer on their own, in the free phases (lanyard
slack, T = 0: the stationary cell's model is 0, the accelerometer's the encoder's acceleration), the moving cell over
the analysis window after the named force-channel causes, and the motor current's force balance after the model of
record. The sensors come first: their product terms are taken out of F_stat (and T) and a2 (sensor_corrected)
before the moving cell and the current are searched, so a drifting stationary cell is named on its own channel.
A term is either a product of SIGNALS with integer powers
(every product of total degree <= 2 and every single signal cubed; written in the SIGNALS order, joined by ``*``,
``^k`` for k > 1), or a sinusoid ``sin`` at the frequency where the channel's residual spectrum peaks, optionally
times a signal (``v*sin``). A sinusoid's amplitude is one coefficient for the campaign; its phase is each pull's own
(a mode excited afresh in every pull), fitted per pull.

The search is forward selection over the library (the column scales are the campaign's, so the coefficients are
comparable): at each step the term that lowers the fitted pulls' summed squared residual most joins, all the
chosen product terms are refitted together (least squares on the summed normal equations, one pull at a time:
each pull is kept as the Gram matrix of its library columns, BeyondPart, so memory does not grow with the pulls),
and the new term is kept only if it passes the held-out test of significance.significance (held-out SSE -1 %, t >=
4 over the held-out pulls). At most MAX_TERMS per channel. Why not PySINDy's sequentially thresholded least
squares (STLSQ): measured on the same statistics (benchmarks/bench_sparse.py, docs/discovery.md), it kept dozens of
collinear companions with a threshold chosen on the held-out error, and at the channel's band it spread a true term
over its collinear neighbours until each fell below it; forward selection with a held-out stopping rule, the
catalog's own rule applied term by term, keeps them out.

Each coefficient gets an uncertainty budget as the catalog's parameters do (budget.honest; _budget): the statistical
part from a jackknife over the fitted pulls (Student's t, n-1), each systematic part the coefficient's shift when
one rig constant is one stated standard uncertainty off (m2 and the cell's gain on the moving cell, each drive
constant on the current: the residual's change kept as a Gram column per pull) or the channel's sensor calibration
(relative), and the 95 % interval +/- sqrt((t u_stat)^2 + (COVERAGE_K u_sys)^2). A term is named when it is
significant AND its contribution's rms on the held-out pulls, over that interval, lies above the channel's band
(practical significance: channel_band, from the rig's tolerances).

The catalog keeps priority: on the motor current, the catalog's Coulomb friction (a step with the motion) is a
library column too; it stays named unless a single library term lowers the held-out residual by
PRIORITY_MARGIN more than it does (the same number of parameters: one). On the moving cell each named force-model
cause (CAUSE_PARAMS) is checked by cause_check with the cause undone. A cause a library term explains better is
withheld: the report names the term and says the nearest catalog cause does not fit (BeyondResult.demoted)."""
from __future__ import annotations

import dataclasses
import functools
import itertools
import math
from dataclasses import dataclass, field
from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np

from force_tester_sim.core.extra_terms import (
    CHANNEL_UNITS,
    MAX_POWER,
    SIGNALS,
    SIN,
    parse_term,
    signals,
    term_name,
    term_unit,
    term_values,
)

from .budget import COVERAGE_K, DRIVE_VARIANTS, STATISTICAL
from .friction import MOVING_M_S, STILL_M_S
from .leftover import LEFTOVER_BAND_HZ
from .prep import Pull
from .significance import significance

# the channels whose residual the search forms (module docstring), in the order they are searched: the sensors
# seen on their own (in the free phases) first, then the moving cell and the motor current, whose residuals are
# formed with the stationary cell and the accelerometer (SENSORS: their terms are taken out of T and a2 first)
SEARCHED = ('force_stationary', 'accel_axial', 'force_moving', 'motor_current')
SENSORS = ('force_stationary', 'accel_axial')
SIN_FACTORS = ('', 'v', 'F_move')              # sin, v*sin, F_move*sin
# terms on a channel that are catalog entries in another form (the force model's gain and mass): not searched
CATALOG_FORMS = {'force_moving': ('F_move', 'F_stat', 'T', 'a2')}
# signals a channel's residual is made of (in the free phases F_move is m2 a2): no term of its library uses them
OWN_SIGNALS = {'force_stationary': ('F_stat', 'T'), 'accel_axial': ('a2', 'F_move')}
# each channel's scale factor (its sensor's calibration, rig sensors.*): a relative component of every coefficient
RELATIVE = {'force_moving': ('cell_sensitivity', 'sensors.load_cell_sensitivity_mv_per_lbf',
                             'load_cell_sensitivity_mv_per_lbf'),
            'force_stationary': ('cell_sensitivity', 'sensors.load_cell_sensitivity_mv_per_lbf',
                                 'load_cell_sensitivity_mv_per_lbf'),
            'accel_axial': ('accelerometer_sensitivity', 'sensors.accelerometer_sensitivity_mv_per_g',
                            'accelerometer_sensitivity_mv_per_g')}
FREE_SPAN_S = 0.5              # the sensors' free phases: at most this long before the pull and after its ringing
EDGE_S = 0.02                  # the free phases leave the record's first and last 20 ms out (the filters' edges)
MAX_TERMS = 3
SEARCH_RATE_HZ = 20000.0       # the residuals are decimated to about this rate (the channels are low-passed below)
PRIORITY_MARGIN = 0.01         # a library term must beat a catalog cause's held-out reduction by this much
TIE_SHARE = 0.02               # terms within this share of the best fitted reduction tie (module docstring)
NEAR_TIE = 0.1                # other terms whose held-out reduction comes within this share of the chosen one's
                              # are listed beside it: the data cannot tell them apart
MIN_HZ = 20.0                  # a sinusoid's frequency lies above this (and below LEFTOVER_BAND_HZ)
SPECTRUM_POINTS = 2 ** 15
PEAK_PROMINENCE = 10.0        # a sinusoid's line stands this far above the median spectrum around it ...
PEAK_SPAN = 64                # ... over this many bins either side
REFINE_BINS = 2               # the line's frequency is refined this many bins either side of the peak ...
REFINE_PULLS = 4              # ... on the samples of at most this many pulls (memory flat in the pulls)
COULOMB = 'coulomb_friction'

INTERPRETATION = {
    ('force_moving', 'F_move^2'): 'a non-linear moving cell: its sensitivity changes with load',
    ('force_moving', 'F_move^3'): 'a non-linear moving cell: its sensitivity changes with load',
    ('force_moving', 'T^2'): 'a non-linear moving cell (seen against the tension): its sensitivity changes with load',
    ('force_moving', 'F_stat^2'): 'a non-linear cell (seen against the stationary cell)',
    ('force_moving', 't'): "the moving cell's zero drifts through the record (thermal drift, charge-amplifier "
                           'leakage)',
    ('force_moving', 'v'): 'a velocity-dependent force on the moving cell: cable drag or a viscous coupling',
    ('force_moving', 'x'): 'a force that grows along the travel on the moving cell: a cable or hose pulling on it',
    ('force_stationary', 't'): "the stationary cell's zero drifts through the record (thermal drift, "
                               'charge-amplifier leakage); the tension T it gives drifts with it',
    ('force_stationary', 'x'): 'the stationary cell reads a force that follows the carriage: crosstalk or a '
                               'cable pulling on the fixture',
    ('accel_axial', 't'): "the accelerometer's zero drifts through the record (thermal drift, a conditioner's "
                          'offset creeping)',
    ('accel_axial', 'v'): 'the accelerometer reads a share of the speed: a cable whipping or a mounting that '
                          'flexes with the motion',
    ('motor_current', 'v^2'): 'aerodynamic drag on the carriage',
    ('motor_current', 'v'): "viscous friction beyond the drive model's (lubricated guides, a damper)",
    ('motor_current', 'x'): 'a force that grows along the travel: a binding rail or a cable acting as a spring',
    ('motor_current', 'v*x'): 'a friction that grows along the travel and acts only while sliding (a binding or '
                              'misaligned rail): the grammar has no while-sliding factor, and x times the speed, 0 at '
                              'rest, stands for it (its coefficient times the speed is the friction per metre)',
    ('motor_current', 't'): "the current sensor's zero drifts through the record",
    ('motor_current', 'F_move'): "the drive's force constant or the moving cell's gain is off (force per amp)",
    ('motor_current', 'a2'): 'a mass the drive moves that the model of record does not have',
}
SIN_INTERPRETATION = {'': 'a structural (frame) mode ringing at {f:.1f} Hz',
                      'v': 'a structural (frame) mode at {f:.1f} Hz excited by the carriage: it grows with speed',
                      'F_move': 'a structural mode at {f:.1f} Hz excited by the load'}


def library() -> List[str]:
    """The product terms of the grammar (module docstring), in a fixed order."""
    out = []
    for deg in (1, 2):
        for combo in itertools.combinations_with_replacement(SIGNALS, deg):
            out.append(term_name({s: combo.count(s) for s in combo}))
    out += [term_name({s: MAX_POWER}) for s in SIGNALS]
    return out


def interpretation(channel: str, term: str, f_hz: Optional[float] = None) -> str:
    p = parse_term(term)
    if SIN in p:
        factor = next((s for s in p if s != SIN), '')
        return SIN_INTERPRETATION.get(factor, 'a structural mode at {f:.1f} Hz, modulated by ' + factor).format(
            f=f_hz or 0.0)
    if channel in ('force_moving', 'force_stationary') and set(p) <= {'F_move', 'F_stat', 'T'} \
            and sum(p.values()) > 1:
        return INTERPRETATION[('force_moving', 'F_move^2')]
    return INTERPRETATION.get((channel, term), 'a term the catalog has no entry for; no usual physical reading: '
                                                'look at where it acts (report.md)')


# ------------------------------------------------------------------------------------------ per pull
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


def smoothed_a2(p: Pull) -> np.ndarray:
    """a2 smoothed as the encoder's a3 is (the accelerometer's free-phase model is a3)."""
    from scipy.signal import savgol_filter
    return savgol_filter(p.a2, max(5, int(round(2e-3 / p.dt)) | 1), 3)


def channel_series(p: Pull, rig, force_resid: np.ndarray, hum: Optional[np.ndarray],
                   coulomb_n: Optional[float], causes: Optional[Dict[str, np.ndarray]] = None) -> Dict[str, tuple]:
    """{channel: (residual, signals, catalog column or None, {cause: its contribution})} of one pull, decimated,
    usable samples only.

    force_moving: the force model's residual on W after the named causes (force_resid, from ForceModel.resid);
    F_move is the model's prediction (measured minus hum minus residual). motor_current (A): the drive's force
    balance with the predicted F_move, over the samples at rest and moving, minus the pull's median at rest;
    its catalog column is the Coulomb step (1 while moving) in A per N of friction: coulomb_n is whether it
    is named (the column is offered only then). causes: each named force-model cause's contribution to the moving
    cell's residual on W (what the residual would gain were the cause undone, at its fitted parameters; cause_check)."""
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
    out['force_moving'] = (np.asarray(force_resid)[::q][ok], {k: v[w][::q][ok] for k, v in full.items()}, None,
                           {c: np.asarray(v)[::q][ok] for c, v in (causes or {}).items()},
                           {'m2': (u_m2 * p.a2)[w][::q][ok], 'gain': (u_g * fm_pred)[w][::q][ok]})
    # the sensors on their own, in the free phases (lanyard slack before the pull and after the break's ringing,
    # FREE_SPAN_S each, the record's edges left out): there T = 0, so the stationary cell's model is 0 and the
    # accelerometer's the carriage's acceleration from the encoder (a2 smoothed as the encoder's a3 is)
    sel = free_samples(p)
    if len(sel):
        sig = {k: v[sel] for k, v in full.items()}
        out['force_stationary'] = (p.fs[sel], sig, None, {}, {})
        out['accel_axial'] = ((smoothed_a2(p) - p.a3)[sel], sig, None, {}, {})
    if p.current is not None:
        d = rig.drive
        kf = d.force_per_amp_n_per_a
        moving = p.v3 > MOVING_M_S
        still = np.abs(p.v3) < STILL_M_S
        use = (moving | still) & p.usable()

        def balance(d):   # the current's force balance in A with the drive constants d
            rho = p.current * d.force_per_amp_n_per_a - (d.reflected_mass_kg * p.a3
                                                         + d.viscous_damping_n_s_per_m * p.v3 + fm_pred)
            return (rho - np.median(rho[still & p.usable()])) / d.force_per_amp_n_per_a
        if still.any() and moving.any():
            y = balance(d)
            col = None if coulomb_n is None else (moving.astype(float) / kf)
            sel = np.flatnonzero(use)[::q]
            sys_ = {}
            for name, key in DRIVE_VARIANTS.items():   # each drive constant one standard uncertainty off
                u = rig.uncertainty.u(f'drive.{key}')
                if u > 0:
                    sys_[name] = (balance(dataclasses.replace(d, **{key: getattr(d, key) + u})) - y)[sel]
            out['motor_current'] = (y[sel], {k: v[sel] for k, v in full.items()},
                                    None if col is None else col[sel], {}, sys_)
    return out


def sensor_corrected(p: Pull, terms: Sequence, rig, cal: Optional[tuple]) -> Pull:
    """The pull with the sensors' terms found on their own (SENSORS: force_stationary, accel_axial; terms with
    .channel, .term, .coefficient, .frequency_hz) taken out of F_stat and a2, and T recomputed from the corrected
    stationary cell (cal: cells.with_tension's (K_LC1, c1); None: the rig's): the moving cell and the motor current
    are then searched against what the sensors would have read without them. A sinusoid's phase is each pull's own:
    it is fitted (with the pull's amplitude) on the sensor's free phases, after its product terms, and taken out of
    the whole record."""
    from .prep import tension_from_stationary
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


@dataclass(frozen=True)
class Survey:
    """The search's settings from a few fitted pulls (beyond_survey): the signals' scales and each channel's
    residual-spectrum peak."""

    scales: Dict[str, float]
    freq: Dict[str, float]      # channel -> Hz


def _peak(P: np.ndarray, band: np.ndarray) -> Optional[int]:
    """The strongest local maximum of P inside band that stands PEAK_PROMINENCE above the median of the
    PEAK_SPAN bins around it (a line, not a broadband residual), or None."""
    idx = np.flatnonzero(band)
    idx = idx[(idx > 0) & (idx < len(P) - 1)]
    local = idx[(P[idx] > P[idx - 1]) & (P[idx] >= P[idx + 1])]
    for k in local[np.argsort(-P[local])][:8]:
        near = P[max(0, k - PEAK_SPAN):k + PEAK_SPAN + 1]
        if P[k] > PEAK_PROMINENCE * np.median(near):
            return int(k)
    return None


def spectrum_part(series: Dict[str, tuple], dt_dec: float, records: bool = True) -> Dict[str, tuple]:
    """{channel: (power spectrum of the residual, rms of each signal, (times s, residual) or None)} of one pull. The
    spectrum treats the samples as evenly spaced; the sensors' free phases are two stretches with the pull between
    them, so the line's frequency is refined on the samples' own times (refine_frequency), kept where ``records``
    (the first REFINE_PULLS pulls of the survey)."""
    out = {}
    for ch, (y, sig, *_rest) in series.items():
        yy = (y - y.mean()) * np.hanning(len(y))
        P = np.abs(np.fft.rfft(yy, SPECTRUM_POINTS)) ** 2
        out[ch] = (P, {k: float(np.sqrt(np.mean(v ** 2))) for k, v in sig.items()},
                   (np.asarray(sig['t'], float), np.asarray(y, float)) if records else None)
    return out


def refine_frequency(f0: float, step: float, records: Sequence[Tuple[np.ndarray, np.ndarray]]) -> float:
    """The frequency within f0 +/- REFINE_BINS step that maximizes the summed power of the pulls' least-squares
    sinusoids on their samples' own times (records: [(t, residual)], each pull its own phase and amplitude): the
    spectrum's peak is off by up to a bin, and by more where the record has a gap (the free phases either side of
    the pull); one phase across such a gap needs the frequency to a small share of a bin."""
    def power(f):
        tot = 0.0
        for t, y in records:
            ph = 2 * np.pi * f * t
            X = np.column_stack([np.cos(ph), np.sin(ph), np.ones_like(t)])
            c = np.linalg.lstsq(X, y, rcond=None)[0]
            tot += float(np.sum((X[:, :2] @ c[:2]) ** 2))
        return tot
    grid = f0 + step * np.linspace(-REFINE_BINS, REFINE_BINS, 8 * REFINE_BINS + 1)
    for _ in range(3):   # a coarse grid, then finer ones around its best
        pw = np.array([power(f) for f in grid])
        k = int(np.argmax(pw))
        h = grid[1] - grid[0]
        grid = grid[k] + h * np.linspace(-1.0, 1.0, 9)
    return float(grid[4])


def survey_from(parts: Sequence[Dict[str, tuple]], dt_dec: float) -> Survey:
    """The search's Survey from spectrum_part()s of a few fitted pulls."""
    f = np.fft.rfftfreq(SPECTRUM_POINTS, dt_dec)
    ok = (f > MIN_HZ) & (f < LEFTOVER_BAND_HZ)
    freq, scales = {}, {}
    for ch in {c for part in parts for c in part}:
        P = sum(part[ch][0] for part in parts if ch in part)
        k = _peak(P, ok)
        records = [part[ch][2] for part in parts if ch in part and part[ch][2] is not None]
        if k is not None:
            freq[ch] = refine_frequency(float(f[k]), float(f[1] - f[0]), records) if records else float(f[k])
        for part in parts:
            if ch in part:
                for s, r in part[ch][1].items():
                    scales[s] = max(scales.get(s, 0.0), r)
    return Survey({s: (v if v > 0 else 1.0) for s, v in scales.items()}, freq)


def columns(channel: str, sig: Dict[str, np.ndarray], scales: Dict[str, float], f_hz: Optional[float]):
    """(names, scaled product columns, sinusoid factor columns: [(name, cos, sin)]) of one channel's library."""
    names = channel_library(channel)
    scaled = {s: np.asarray(sig[s], float) / scales[s] for s in SIGNALS}
    powers = {(s, 1): v for s, v in scaled.items()}
    X = np.empty((len(scaled['t']), len(names)))
    for k, term in enumerate(names):   # each column one product of cached powers (the library has degree <= 3)
        factors = []
        for s, e in parse_term(term).items():
            if (s, e) not in powers:
                powers[(s, e)] = scaled[s] ** e
            factors.append(powers[(s, e)])
        X[:, k] = functools.reduce(np.multiply, factors)
    own = set(OWN_SIGNALS.get(channel, ()))
    sins = []
    if f_hz is not None:
        ph = 2 * np.pi * f_hz * sig['t']
        for fac in SIN_FACTORS:
            if fac in own:
                continue
            m = scaled[fac] if fac else np.ones_like(ph)
            sins.append((term_name({fac: 1, SIN: 1}) if fac else SIN, m * np.cos(ph), m * np.sin(ph)))
    return list(names), X, sins


@functools.lru_cache(maxsize=None)
def channel_library(channel: str) -> Tuple[str, ...]:
    """The product terms searched on a channel: the library less the catalog's forms and the channel's own
    signals (CATALOG_FORMS, OWN_SIGNALS)."""
    skip, own = CATALOG_FORMS.get(channel, ()), set(OWN_SIGNALS.get(channel, ()))
    return tuple(t for t in library() if t not in skip and not own & set(parse_term(t)))


@dataclass(frozen=True)
class BeyondPart:
    """One pull's normal equations per channel: {channel: (names, G, b, s, n, catalog, causes)} with G over the
    product columns then each sinusoid's (cos, sin) pair, catalog = (g_cc, g_cX, b_c) of the catalog column or None,
    causes = {cause: (g_cc, g_cX, b_c)} of each named cause's contribution (cause_check)."""

    stats: dict


def beyond_part(series: Dict[str, tuple], survey: Survey) -> BeyondPart:
    out = {}
    for ch, (y, sig, cat, contrib, sys_) in series.items():
        names, X, sins = columns(ch, sig, survey.scales, survey.freq.get(ch))
        full = np.column_stack([X] + [np.column_stack([c, s]) for _, c, s in sins]) if sins else X
        G = full.T @ full
        b = full.T @ y
        catalog = None
        if cat is not None:
            catalog = (float(cat @ cat), full.T @ cat, float(cat @ y))
        causes = {c: (float(v @ v), full.T @ v, float(v @ y)) for c, v in contrib.items()}
        out[ch] = (tuple(names + [n for n, _, _ in sins]), G, b, float(y @ y), len(y), catalog, causes,
                   {c: full.T @ z for c, z in sys_.items()})
    return BeyondPart(out)


# ------------------------------------------------------------------------------------------ the search
@dataclass(frozen=True)
class Model:
    """Chosen product columns (indices) with pooled coefficients, and at most one sinusoid (index, amplitude)."""

    prod: Tuple[int, ...] = ()
    coef: Tuple[float, ...] = ()
    sin: Optional[int] = None
    amp: float = 0.0
    cat: bool = False           # the catalog column is in (its coefficient: the last of coef)


def _pair(n_prod: int, k: int) -> List[int]:
    return [n_prod + 2 * k, n_prod + 2 * k + 1]


def _aug(st, use_cat: bool):
    """(G, b, s) with the catalog column appended last (when use_cat)."""
    names, G, b, s, n, cat = st[:6]
    if not use_cat or cat is None:
        return G, b, s
    gcc, gcx, bc = cat
    G2 = np.block([[G, gcx[:, None]], [gcx[None, :], np.array([[gcc]])]])
    return G2, np.append(b, bc), s


def _cols(model_prod, cat: bool, n_all: int) -> List[int]:
    return list(model_prod) + ([n_all] if cat else [])


def _sse(st, model: Model, n_prod: int) -> float:
    """One pull's squared residual under model (the sinusoid's phase fitted on the pull)."""
    G, b, s = _aug(st, model.cat)
    idx = _cols(model.prod, model.cat, len(st[2]))
    c = np.array(model.coef)
    e = s - 2 * c @ b[idx] + c @ G[np.ix_(idx, idx)] @ c if idx else s
    if model.sin is not None:
        pr = _pair(n_prod, model.sin)
        br = b[pr] - (G[np.ix_(pr, idx)] @ c if idx else 0.0)
        e = e - _sin_gain(G[np.ix_(pr, pr)], br, model.amp)
    return float(e)


_PHASES = np.linspace(0.0, 2 * np.pi, 720, endpoint=False)
_U = np.stack([np.cos(_PHASES), np.sin(_PHASES)])


def _sin_gain(Gp: np.ndarray, br: np.ndarray, amp: float) -> float:
    """How much a sinusoid of amplitude amp, its phase the pull's best, lowers the pull's squared residual
    (exact for the pair's Gram matrix Gp, on a 0.5 degree grid of phases; never negative)."""
    g = 2 * amp * (br @ _U) - amp ** 2 * np.einsum('ik,ij,jk->k', _U, Gp, _U)
    return float(max(0.0, g.max()))


def _sin_amp(Gp: np.ndarray, br: np.ndarray) -> float:
    """The pull's own amplitude of the sinusoid (the pair's least squares)."""
    return float(np.hypot(*np.linalg.lstsq(Gp, br, rcond=1e-10)[0]))


def _fit(stats: Sequence, prod: Tuple[int, ...], sin: Optional[int], cat: bool, n_prod: int) -> Model:
    """Pooled least squares of the product columns (and catalog) over stats, then the sinusoid's amplitude."""
    idx = _cols(prod, cat, len(stats[0][2]))
    coef: Tuple[float, ...] = ()
    if idx:
        Gs = sum(_aug(st, cat)[0][np.ix_(idx, idx)] for st in stats)
        bs = sum(_aug(st, cat)[1][idx] for st in stats)
        d = np.sqrt(np.maximum(np.diag(Gs), 1e-300))
        c = np.linalg.lstsq(Gs / np.outer(d, d), bs / d, rcond=1e-10)[0] / d
        coef = tuple(float(v) for v in c)
    amp = 0.0
    if sin is not None:   # one amplitude for the campaign: the mean of the pulls' own
        amps = []
        for st in stats:
            G, b, _ = _aug(st, cat)
            pr = _pair(n_prod, sin)
            br = b[pr] - (G[np.ix_(pr, idx)] @ np.array(coef) if idx else 0.0)
            amps.append(_sin_amp(G[np.ix_(pr, pr)], br))
        amp = float(np.mean(amps))
    return Model(tuple(prod), coef, sin, amp, cat)


@dataclass(frozen=True)
class Term:
    """A term found (report.json beyond_catalog's entry, before the units are attached)."""

    channel: str
    term: str
    coefficient: float
    ci95: Tuple[float, float]
    frequency_hz: Optional[float]
    gain: float                 # held-out rms gain on the channel when the term joins
    rel_sse_reduction: float
    t: float
    rms: float                  # its contribution's rms on the held-out pulls, in the channel's unit
    rms_ci95: Tuple[float, float]
    band: float
    named: bool
    budget: Dict[str, float] = field(default_factory=dict)   # standard uncertainties: statistical, systematic parts
    alternatives: Tuple[str, ...] = ()   # terms the held-out pulls cannot tell from it (near_tied), best first

    def as_dict(self) -> dict:
        unit = CHANNEL_UNITS[self.channel]
        tu = term_unit(self.term)
        return {'channel': self.channel, 'term': self.term, 'coefficient': self.coefficient,
                'ci95': list(self.ci95), 'unit': f'{unit} per {tu}' if tu != '1' else unit,
                'frequency_hz': self.frequency_hz, 'gain': self.gain,
                'interpretation': interpretation(self.channel, self.term, self.frequency_hz),
                'evidence': {'rel_sse_reduction': self.rel_sse_reduction, 't': self.t,
                             'contribution_rms': self.rms, 'contribution_rms_ci95': list(self.rms_ci95),
                             'band': self.band},
                'uncertainty_budget': dict(self.budget), 'near_tied': list(self.alternatives)}


@dataclass(frozen=True)
class BeyondResult:
    terms: Tuple[Term, ...] = ()                    # named, best first
    traces: tuple = ()                              # term_traces() of one held-out pull (the plots)
    within_tolerance: Tuple[Term, ...] = ()         # significant, inside the band
    demoted: Dict[str, str] = field(default_factory=dict)   # catalog cause -> why it does not fit
    frequencies: Dict[str, float] = field(default_factory=dict)
    seconds: float = 0.0


def channel_band(channel: str, rig) -> float:
    """The smallest contribution (rms, channel unit) that matters: force channels the hum tolerance (the smallest
    force the rig's tolerances care about), the motor current the Coulomb friction tolerance in A."""
    tol = rig.tolerances
    if channel == 'motor_current':
        return tol.coulomb_friction_n / rig.drive.force_per_amp_n_per_a
    if channel == 'accel_axial':
        return tol.mains_hum_amplitude_n / rig.force_chain.m2
    return tol.mains_hum_amplitude_n


def _jackknife(stats, model: Model, n_prod: int) -> np.ndarray:
    """(len(coef) + 1, 2) 95 % intervals of the coefficients and the amplitude: jackknife over the fitted pulls."""
    n = len(stats)
    est = np.array([*model.coef, model.amp])
    if n < 3:
        return np.column_stack([est, est])
    loo = np.array([[*m.coef, m.amp] for m in
                    (_fit([st for i, st in enumerate(stats) if i != k], model.prod, model.sin, model.cat, n_prod)
                     for k in range(n))])
    u = np.sqrt((n - 1) / n * np.sum((loo - loo.mean(0)) ** 2, axis=0))
    from scipy.stats import t as student
    q = float(student.ppf(0.975, n - 1))
    return np.column_stack([est - q * u, est + q * u])


def search_channel(channel: str, fit: Sequence, held: Sequence, survey: Survey, rig, catalog_named: bool):
    """([Term] named and within tolerance, demoted catalog reason or None, the final Model) for one channel:
    fit/held are the pulls' stats tuples (BeyondPart.stats[channel])."""
    names = fit[0][0]
    f_hz = survey.freq.get(channel)
    n_sin = sum(1 for n in names if n.endswith(SIN))
    n_prod = len(names) - n_sin
    use_cat = catalog_named and fit[0][5] is not None and channel == 'motor_current'
    demoted = None
    if use_cat:   # the catalog keeps priority unless one library term (one parameter, as it) beats it
        m_cat = _fit(fit, (), None, True, n_prod)
        base = np.array([st[3] for st in held])
        r_cat = 1 - sum(_sse(st, m_cat, n_prod) for st in held) / base.sum()
        best = min(range(n_prod), key=lambda k: sum(_sse(st, _fit(fit, (k,), None, False, n_prod), n_prod)
                                                    for st in fit))
        m_lib = _fit(fit, (best,), None, False, n_prod)
        r_lib = 1 - sum(_sse(st, m_lib, n_prod) for st in held) / base.sum()
        if r_lib > r_cat + PRIORITY_MARGIN:
            use_cat = False
            demoted = (f'{names[best]} on {channel} lowers the held-out residual by {100 * r_lib:.1f} %, the catalog '
                       f'cause by {100 * r_cat:.1f} % (one parameter each): the nearest catalog cause does not fit')
    model = _fit(fit, (), None, use_cat, n_prod) if use_cat else Model()
    found = []
    band = channel_band(channel, rig)
    for _step in range(MAX_TERMS):
        trials = [(k, None) for k in range(n_prod) if k not in model.prod]
        if model.sin is None:
            trials += [(None, k) for k in range(n_sin)]
        if not trials:
            break
        now = sum(_sse(st, model, n_prod) for st in fit)
        tried = []
        for k, s in trials:
            prod = model.prod if k is None else tuple([*model.prod, k])
            m = _fit(fit, prod, model.sin if s is None else s, use_cat, n_prod)
            tried.append((m, sum(_sse(st, m, n_prod) for st in fit)))
        least = min(e for _, e in tried)
        # parsimony: the first term in the library's order (lower degree, F_move before T and F_stat) that does
        # within TIE_SHARE of the best -- collinear signals (F_move, T, F_stat) would otherwise win by their noise
        best = next(m for m, e in tried if e <= least + TIE_SHARE * max(now - least, 0.0))
        base = np.array([_sse(st, model, n_prod) for st in held])
        ext = np.array([_sse(st, best, n_prod) for st in held])
        ev = significance(base, ext)
        if not ev.significant:
            break
        alternatives = near_tied([(names[k] if s is None else names[n_prod + s], base.sum()
                                   - sum(_sse(st, m, n_prod) for st in held)) for (k, s), (m, _) in zip(trials, tried)
                                  if m is not best], base.sum() - ext.sum())
        new_prod = [k for k in best.prod if k not in model.prod]
        is_sin = best.sin is not None and model.sin is None
        model = best
        ci = _jackknife(fit, model, n_prod)
        if is_sin:
            name, coef, cif, col = names[n_prod + model.sin], model.amp, ci[-1], None
        else:
            k = new_prod[0]
            pos = list(model.prod).index(k)
            name, coef, cif, col = names[k], model.coef[pos], ci[pos], k
        # the contribution's rms on the held-out pulls (scaled columns), then the SI coefficient
        n_held = sum(st[4] for st in held)
        if col is None:
            pr = _pair(n_prod, model.sin)
            norm = sum(0.5 * (st[1][pr[0], pr[0]] + st[1][pr[1], pr[1]]) for st in held)
        else:
            norm = sum(st[1][col, col] for st in held)
        rms_unit = math.sqrt(norm / max(n_held, 1))
        lo, hi = sorted(cif)
        si = si_factor(name, survey.scales)
        budget, (lo, hi) = _budget(channel, fit, model, col, coef, (lo, hi), si, rig)
        rms_lo = 0.0 if lo <= 0 <= hi else min(abs(lo), abs(hi)) * rms_unit
        rms_hi = max(abs(lo), abs(hi)) * rms_unit
        found.append(Term(channel, name, float(coef * si), tuple(sorted((float(lo * si), float(hi * si)))),
                          f_hz if name.endswith(SIN) else None, ev.rms_gain, ev.rel_sse_reduction, ev.t,
                          abs(coef) * rms_unit, (rms_lo, rms_hi), band, bool(rms_lo > band), budget, alternatives))
    return found, demoted, model


def near_tied(others: Sequence[Tuple[str, float]], chosen: float) -> Tuple[str, ...]:
    """The terms (others: (name, held-out SSE reduction in its place)) that come within NEAR_TIE of the chosen
    term's held-out reduction, best first: on this campaign's motion the data cannot tell them from it (t and t^2
    over a short window, F_move and T), so the report lists them beside the term instead of hiding them."""
    if chosen <= 0:
        return ()
    close = sorted(((r, n) for n, r in others if r >= (1.0 - NEAR_TIE) * chosen), key=lambda x: -x[0])
    return tuple(n for _, n in close)


def _budget(channel: str, fit: Sequence, model: Model, col: Optional[int], coef: float, ci: Tuple[float, float],
            si: float, rig) -> Tuple[Dict[str, float], Tuple[float, float]]:
    """({component: standard uncertainty, SI}, the expanded interval on the scaled coefficient) of one coefficient,
    as budget.honest makes the catalog's: the statistical part from the jackknife interval (ci, its own Student
    factor), each systematic part the coefficient's shift when a rig constant is one standard uncertainty off
    (the channel's residual column of that change, regressed on the model's product columns over the fitted pulls:
    the moving mass m2 on the moving cell, each drive constant on the motor current) or a relative one (the
    channel's sensor calibration, rig sensors.*); U = sqrt((q u_stat)^2 + (COVERAGE_K u_sys)^2)."""
    from .uncertainty import t_quantile
    q = t_quantile(len(fit))
    u_stat = 0.5 * abs(ci[1] - ci[0]) / q
    sys_: Dict[str, float] = {}
    if col is not None and fit[0][7]:
        idx = list(model.prod)
        pos = idx.index(col)
        Gs = sum(st[1][np.ix_(idx, idx)] for st in fit)
        for comp in fit[0][7]:
            bz = sum(st[7][comp][idx] for st in fit)
            sys_[comp] = abs(float(np.linalg.lstsq(Gs, bz, rcond=1e-12)[0][pos]))
    if channel in RELATIVE:
        comp, key, attr = RELATIVE[channel]
        sys_[comp] = rig.uncertainty.relative(key, getattr(rig.sensors, attr)) * abs(coef)
    u_sys = math.sqrt(sum(v * v for v in sys_.values()))
    U = math.sqrt((q * u_stat) ** 2 + (COVERAGE_K * u_sys) ** 2)
    budget = {STATISTICAL: u_stat, **sys_}
    budget['combined'] = math.sqrt(sum(v * v for v in budget.values()))
    return {k: v * abs(si) for k, v in budget.items()}, (coef - U, coef + U)


# parameters of each force-model cause the check weighs against library terms (the hum: amplitude and phase)
CAUSE_PARAMS = {'moving_cell_gain': 1, 'effective_mass': 1, 'accel_delay': 1, 'ac_coupling': 1, 'mains_hum': 2}


def _undone(st, cause: str):
    """A pull's moving-cell statistics with a named cause undone: y0 = y + c (c: its contribution, channel_series)."""
    names, G, b, s, n, cat, causes, sys_ = st
    gcc, gcx, bc = causes[cause]
    return names, G, b + gcx, s + 2 * bc + gcc, n, cat, causes, sys_


def cause_check(fit: Sequence, held: Sequence, model: Model, survey: Survey, rig, cause: str):
    """(why the named force-model cause does not fit, or None; the terms found without it). The catalog keeps
    priority only when its model explains the structure no worse than library terms with the same number of
    parameters: the library is searched again on the moving cell's residual with the cause undone, and if it does
    as well on the held-out pulls with no more parameters (CAUSE_PARAMS: the cause's), the cause is withheld."""
    n_prod = sum(1 for nm in fit[0][0] if not nm.endswith(SIN))
    fit0, held0 = [_undone(st, cause) for st in fit], [_undone(st, cause) for st in held]
    found0, _, model0 = search_channel('force_moving', fit0, held0, survey, rig, False)
    n_cause = CAUSE_PARAMS.get(cause, 1)
    k_cat = len(model.prod) + (model.sin is not None) + n_cause
    k_lib = len(model0.prod) + (model0.sin is not None)
    sse_cat = sum(_sse(st, model, n_prod) for st in held)
    sse_lib = sum(_sse(st, model0, n_prod) for st in held0)
    if k_lib <= k_cat and sse_lib <= sse_cat * (1.0 + (PRIORITY_MARGIN if k_lib < k_cat else 0.0)):
        what = ', '.join(t.term for t in found0) or 'no term at all'
        return (f'without {cause} the library explains the moving cell with {k_lib} parameter(s) ({what}) as well '
                f'as the model with it does with {k_cat} ({n_cause} of them its own; held-out SSE {sse_lib:.4g} '
                f'against {sse_cat:.4g}): the nearest catalog cause does not fit'), found0
    return None, found0


def si_factor(term: str, scales: Dict[str, float]) -> float:
    """The factor from a coefficient on the scaled column to the SI coefficient."""
    out = 1.0
    for s, k in parse_term(term).items():
        if s != SIN:
            out /= scales[s] ** k
    return out


def search(parts: Sequence[BeyondPart], fit: Sequence[int], held: Sequence[int], survey: Survey, rig,
           named: Sequence[str], channels: Sequence[str] = SEARCHED, sensors: bool = False) -> BeyondResult:
    """The search over the channels (module docstring; default every searched one): parts in the usable pulls'
    order; sensors: terms were found on the sensors on their own (the force model's causes are checked then)."""
    import time
    t0 = time.perf_counter()
    terms, within, demoted = [], [], {}
    for ch in channels:
        if not all(ch in parts[j].stats for j in (*fit, *held)):
            continue
        fit_st, held_st = [parts[j].stats[ch] for j in fit], [parts[j].stats[ch] for j in held]
        found, why, model = search_channel(ch, fit_st, held_st, survey, rig, COULOMB in named and ch == 'motor_current')
        if why is not None:
            demoted[COULOMB] = why
        if ch == 'force_moving' and (any(t.named for t in found) or sensors):
            # a term on the moving cell, or a sensor the force model was fitted with read wrong: does each named
            # force-model cause still explain more than library terms would?
            for cause in fit_st[0][6]:
                why, _ = cause_check(fit_st, held_st, model, survey, rig, cause)
                if why is not None:
                    demoted[cause] = why
        terms += [t for t in found if t.named]
        within += [t for t in found if not t.named]
    terms.sort(key=lambda t: -t.rel_sse_reduction)
    return BeyondResult(terms=tuple(terms), within_tolerance=tuple(within), demoted=demoted,
                        frequencies=dict(survey.freq), seconds=time.perf_counter() - t0)


def term_traces(series: Dict[str, tuple], terms: Sequence[Term], pull: str) -> tuple:
    """((pull, channel, term, t, before, after), ...) of one pull (channel_series) for each named term: its
    channel's residual with the other named terms removed (before) and with it removed too (after). A sinusoid's
    phase is fitted on the pull (its amplitude is the term's)."""
    contrib = {}
    for ch in {t.channel for t in terms}:
        if ch not in series:
            continue
        y, sig = series[ch][:2]
        prods = [t for t in terms if t.channel == ch and t.frequency_hz is None]
        rest = y - sum((t.coefficient * term_values(t.term, sig) for t in prods), np.zeros_like(y))
        for t in terms:
            if t.channel != ch:
                continue
            fac = t.coefficient * term_values(t.term, sig)
            if t.frequency_hz is not None:
                ph = 2 * np.pi * t.frequency_hz * sig['t']
                X = np.column_stack([fac * np.sin(ph), fac * np.cos(ph)])
                bs, bc = np.linalg.lstsq(X, rest, rcond=None)[0]
                fac = fac * np.sin(ph + math.atan2(bc, bs))
            contrib[(ch, t.term)] = (sig['t'], y, fac)
    out = []
    for t in terms:
        if (t.channel, t.term) not in contrib:
            continue
        tt, y, c = contrib[(t.channel, t.term)]
        others = sum((v[2] for k, v in contrib.items() if k[0] == t.channel and k != (t.channel, t.term)),
                     np.zeros_like(y))
        out.append((pull, t.channel, t.term, tt, y - others, y - others - c))
    return tuple(out)
