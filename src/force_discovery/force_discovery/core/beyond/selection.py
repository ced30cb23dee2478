"""Forward selection on one channel: at each step the term that lowers the fitted pulls' summed squared residual
most joins, all the chosen product terms are refitted together (least squares on the summed normal equations), and
the new term is kept only if it passes the held-out test (significance.significance); at most MAX_TERMS. On the
motor current the catalog's Coulomb step keeps priority unless one library term beats it by PRIORITY_MARGIN. Each
term found gets a jackknife interval over the fitted pulls and its budget (budget.term_budget). ROS-free."""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Dict, List, NamedTuple, Optional, Sequence, Tuple

import numpy as np

from force_tester_sim.core.extra_terms import CHANNEL_UNITS, SIN, term_unit

from ..budget import COMBINED, term_budget
from ..errors import DiscoveryError
from ..significance import lower_on_every_pull, significance
from ..uncertainty import jackknife_se, t_quantile
from .grammar import (
    COULOMB,
    DAMPING,
    DAMPING_FORM,
    DRIVE_FORMS,
    FORCE_FORMS,
    RELATIVE,
    SENSORS,
    channel_band,
    force_form,
    mixed_forces,
    own_power,
    reads_own,
    si_factor,
)
from .identify import COLLINEAR
from .interpretation import interpretation
from .normal_equations import ChannelStats
from .spectrum import SearchSettings

MAX_TERMS = 3
DAMPING_SHIFT = 'damping_fitted'   # a current term's budget line: its shift with the drive's damping fitted beside it
FORMS_SHIFT = 'gain_mass_fitted'   # a moving-cell term's budget line: its shift with the gain and m2 fitted beside it
DRIVE_SHIFT = 'drive_fitted'       # a current term's budget line: its shift with the drive's k_F and reflected mass
                                   # fitted beside it
REFERENCE_SHIFT = 'reference_read_by_sensor'   # a sensor term in its reference's signals (the accelerometer's a2: the
                                   # encoder's acceleration): its shift with them as the sensor reads them instead
DRIVE_CALIBRATION = 'drive_calibration'   # the drive's k_F, reflected mass and damping fitted together: the catalog
                                         # alternative a current term must beat as well (catalog_margin)
PRIORITY_MARGIN = 0.01         # a library term must beat a catalog cause's held-out reduction by this much
TIE_SHARE = 0.02               # terms within this share of the best fitted reduction tie (search_channel)
NEAR_TIE = 0.1                # other terms whose held-out reduction comes within this share of the chosen one's
                              # are listed beside it: the data cannot tell them apart


@dataclass(frozen=True)
class Model:
    """Chosen product columns (indices) with pooled coefficients, and at most one sinusoid (index, amplitude)."""

    prod: Tuple[int, ...] = ()
    coef: Tuple[float, ...] = ()
    sin: Optional[int] = None
    amp: float = 0.0
    cat: Tuple[int, ...] = ()   # the catalog columns in (their positions among the channel's; their coefficients
                                # the last of coef)

    def coef_of(self, k: int) -> float:
        """The pooled coefficient of product column k (one of prod)."""
        return self.coef[list(self.prod).index(k)]


def sin_pair(n_prod: int, k: int) -> List[int]:
    """The columns of the k-th sinusoid's (cos, sin) pair, after the n_prod product columns."""
    return [n_prod + 2 * k, n_prod + 2 * k + 1]


def augmented(st: ChannelStats, use_cat) -> ChannelStats:
    """The statistics with the catalog columns appended last to the columns (when use_cat: True, or a model's
    non-empty catalog columns)."""
    cat = st.catalog
    if not use_cat or cat is None:
        return st
    G2 = np.block([[st.gram, cat.cx], [cat.cx.T, cat.cc]])
    return st._replace(gram=G2, xy=np.append(st.xy, cat.cy))


def _cols(model_prod, cat: Sequence[int], n_all: int) -> List[int]:
    """The columns of a model's product terms and catalog columns cat, after the channel's n_all own columns."""
    return list(model_prod) + [n_all + j for j in cat]


class Stacked(NamedTuple):
    """Pulls' statistics (augmented(st, cat) of each) as arrays, one row per pull: what sse_each reads."""

    gram: np.ndarray                    # (pulls, columns, columns)
    xy: np.ndarray                      # (pulls, columns)
    yy: np.ndarray                      # (pulls,)
    n_all: int                          # the library's columns, before any catalog column


def stacked(stats: Sequence[ChannelStats], cat: bool) -> Stacked:
    aug = [augmented(st, cat) for st in stats]
    return Stacked(np.stack([a.gram for a in aug]), np.stack([a.xy for a in aug]), np.array([a.yy for a in aug]),
                   len(stats[0].xy))


def sse_each(sk: Stacked, model: Model, n_prod: int) -> np.ndarray:
    """sse() of every pull of sk (stacked with the model's catalog flag) in one pass: the same arithmetic on all
    rows at once."""
    idx = _cols(model.prod, model.cat, sk.n_all)
    c = np.array(model.coef)
    e = sk.yy.copy()
    if idx:
        Gi = sk.gram[:, idx][:, :, idx]
        e = sk.yy - 2 * (sk.xy[:, idx] @ c) + (c @ Gi) @ c
    if model.sin is not None:
        pr = sin_pair(n_prod, model.sin)
        br = sk.xy[:, pr] - (sk.gram[:, pr][:, :, idx] @ c if idx else 0.0)
        Gp = sk.gram[:, pr][:, :, pr]
        g = 2 * model.amp * (br @ _U) - model.amp ** 2 * np.einsum('ik,pij,jk->pk', _U, Gp, _U)
        e = e - np.maximum(0.0, g.max(axis=1))
    return e


def total(values: np.ndarray) -> float:
    """The pulls' sum, added in pull order (as sum() over the pulls was)."""
    return float(sum(values.tolist()))


def sse(st: ChannelStats, model: Model, n_prod: int) -> float:
    """One pull's squared residual under model (the sinusoid's phase fitted on the pull)."""
    a = augmented(st, model.cat)
    G, b, s = a.gram, a.xy, a.yy
    idx = _cols(model.prod, model.cat, len(st.xy))
    c = np.array(model.coef)
    e = s - 2 * c @ b[idx] + c @ G[np.ix_(idx, idx)] @ c if idx else s
    if model.sin is not None:
        pr = sin_pair(n_prod, model.sin)
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


def fit_model(stats: Sequence[ChannelStats], prod: Tuple[int, ...], sin: Optional[int], cat: Tuple[int, ...],
              n_prod: int, sk: Optional[Stacked] = None) -> Model:
    """Pooled least squares of the product columns (and the catalog columns cat) over stats, then the sinusoid's
    amplitude (sk: the same statistics stacked with their catalog columns, when the caller has them)."""
    idx = _cols(prod, cat, len(stats[0].xy))
    coef: Tuple[float, ...] = ()
    if idx:
        if sk is not None:   # summed over the pulls in order, as below
            Gs, bs = sk.gram[:, idx][:, :, idx].sum(axis=0), sk.xy[:, idx].sum(axis=0)
        else:
            aug = [augmented(st, cat) for st in stats]
            Gs = sum(a.gram[np.ix_(idx, idx)] for a in aug)
            bs = sum(a.xy[idx] for a in aug)
        d = np.sqrt(np.maximum(np.diag(Gs), 1e-300))
        c = np.linalg.lstsq(Gs / np.outer(d, d), bs / d, rcond=1e-10)[0] / d
        coef = tuple(float(v) for v in c)
    amp = 0.0
    if sin is not None:   # one amplitude for the campaign: the mean of the pulls' own
        amps = []
        for st in stats:
            a = augmented(st, cat)
            G, b = a.gram, a.xy
            pr = sin_pair(n_prod, sin)
            br = b[pr] - (G[np.ix_(pr, idx)] @ np.array(coef) if idx else 0.0)
            amps.append(_sin_amp(G[np.ix_(pr, pr)], br))
        amp = float(np.mean(amps))
    return Model(tuple(prod), coef, sin, amp, tuple(cat))


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
    beat: Tuple = ()            # (the best other term in its place, its held-out margin over it: a share of the SSE)
    catalog_beat: Tuple = ()    # (the best catalog cause in its place, the term's held-out margin over it; <= 0:
                                # the cause does as well, and the term is not named): the motor current's drive causes,
                                # the moving cell's gain and effective mass
    unidentifiable: Optional[str] = None   # a term not named whose part no catalog form can take is inside the band
                                           # (beside_catalog): why, for beyond_search.identifiability
    ties: Tuple[Tuple[str, str, float, float], ...] = ()   # (channel searched, term, 1 - r^2 of its column with
                                # this one's, this term's held-out margin over it): the terms it does not beat on the
                                # held-out test that admitted it, each in its place (tie_group)

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
                'uncertainty_budget': dict(self.budget), 'near_tied': list(self.alternatives),
                'best_alternative': None if not self.beat else {'term': self.beat[0],
                                                                'held_out_margin': self.beat[1]},
                'best_catalog_alternative': None if not self.catalog_beat else {
                    'cause': self.catalog_beat[0], 'held_out_margin': self.catalog_beat[1]}}


class ChannelResult(NamedTuple):
    """What the search found on one channel."""

    terms: List[Term]           # named and within tolerance, in the order they joined
    demoted: Optional[str]      # why the catalog's Coulomb step does not fit, or None
    model: Model                # the final model
    beat: Optional[dict] = None  # the Coulomb step kept: the library's best in its place, and by how much


def jackknife(stats: Sequence[ChannelStats], model: Model, n_prod: int) -> np.ndarray:
    """(len(coef) + 1, 2) 95 % intervals of the coefficients and the amplitude: jackknife over the fitted pulls
    (uncertainty.jackknife_se, Student's t with n - 1 degrees of freedom). Two pulls (a 4-pull campaign) give one
    degree of freedom, t = 12.7: wide, as it should be (it was the estimate alone, and a clean 4-pull campaign of the
    independent generator, seed 4427, had T*v named with no statistical part)."""
    n = len(stats)
    if n < 2:   # stages.MIN_PULLS keeps two fitted pulls at least
        raise DiscoveryError(f'{n} fitted pulls for a jackknife interval; expected at least 2')
    est = np.array([*model.coef, model.amp])
    loo = np.array([[*m.coef, m.amp] for m in
                    (fit_model([st for i, st in enumerate(stats) if i != k], model.prod, model.sin, model.cat, n_prod)
                     for k in range(n))])
    u = jackknife_se(loo)
    q = t_quantile(n)
    return np.column_stack([est - q * u, est + q * u])


def search_channel(channel: str, fit: Sequence[ChannelStats], held: Sequence[ChannelStats],
                   settings: SearchSettings, rig, catalog_named: bool, forms: bool = False) -> ChannelResult:
    """The forward selection on one channel (the module docstring): fit/held are the fitted and held-out pulls'
    statistics (BeyondPart.stats[channel]); forms: on the moving cell, the force model named its gain or m2 and the
    one selection (priority.cause_check) withheld it for library terms: measure both beside each term (below)."""
    names = fit[0].names
    f_hz = settings.freq.get(channel)
    n_sin = sum(1 for n in names if n.endswith(SIN))
    n_prod = len(names) - n_sin
    use_cat = catalog_named and fit[0].catalog is not None and channel == 'motor_current'
    # the motor current's drive causes a term competes with in its place, one parameter each: the Coulomb step (the
    # catalog column) and the viscous damping's departure (its form, the library's v: fitted beside every other
    # term, so its stated uncertainty is measured, not a systematic part of the term's budget)
    has_step = channel == 'motor_current' and fit[0].catalog is not None
    # the drive's k_F and reflected mass (their forms the current's catalog columns after the step, DRIVE_FORMS) in the
    # same way: every term there is fitted with both beside it, so the data measure them. With their stated
    # uncertainties as systematic parts, every term that grows with the drive force or the acceleration was swamped
    # (bench_sweep's motor_current cells at 3x the band on the independent generator: 34 of 42 named nothing)
    drive = tuple(range(1, 1 + len(DRIVE_FORMS))) if has_step and len(fit[0].catalog.cy) > len(DRIVE_FORMS) else ()
    # the moving cell's gain and effective mass (their forms F_move and a2 the channel's catalog columns, FORCE_FORMS):
    # a term is named only when it beats each in its place (catalog_margin). Their stated uncertainties are
    # systematic parts of every term that grows with the load. When the force model named one of them (the data put
    # it outside its tolerance) and the one selection withheld it for library terms on the same held-out criterion
    # (forms), the stated uncertainty no longer says what is known of it, and it swamped the term that took its
    # place (bench_sweep's F_move*t cell at 3x the band on the independent generator, named T*t: 0.0118 with 7.9e-5
    # statistical and 0.0084 from the gain, its interval holding 0): then both are measured beside the term (with
    # the gain alone, m2's line rose in its place)
    gain_form = channel == 'force_moving' and fit[0].catalog is not None
    kv = names.index(DAMPING_FORM) if channel == 'motor_current' and DAMPING_FORM in names[:n_prod] else None
    sf, sh = {False: stacked(fit, False)}, {False: stacked(held, False)}
    if has_step or gain_form:
        sf[True], sh[True] = stacked(fit, True), stacked(held, True)

    def fitted(prod, sin, cat):   # cat: the catalog columns in (True: the current's Coulomb step, its one column)
        cat = (0,) if cat is True else tuple(cat or ())
        return fit_model(fit, prod, sin, cat, n_prod, sf[bool(cat)])

    def sse_fit(m):
        return sse_each(sf[bool(m.cat)], m, n_prod)

    def sse_held(m):
        return sse_each(sh[bool(m.cat)], m, n_prod)
    demoted = kept = None
    if use_cat:   # the catalog keeps priority unless one library term (one parameter, as it) beats it
        m_cat = fitted((), None, True)
        base = np.array([st.yy for st in held])
        r_cat = 1 - total(sse_held(m_cat)) / base.sum()
        best = min(range(n_prod), key=lambda k: total(sse_fit(fitted((k,), None, False))))
        m_lib = fitted((best,), None, False)
        r_lib = 1 - total(sse_held(m_lib)) / base.sum()
        if r_lib > r_cat + PRIORITY_MARGIN:
            use_cat = False
            demoted = (f'{names[best]} on {channel} lowers the held-out residual by {100 * r_lib:.1f} %, the catalog '
                       f'cause by {100 * r_cat:.1f} % (one parameter each): the nearest catalog cause does not fit')
        else:   # kept: what it beat, as priority.cause_check says of a force-model cause
            lib, cat = total(sse_held(m_lib)), total(sse_held(m_cat))
            kept = {'library_instead': names[best], 'library_parameters': 1, 'model_parameters': 1,
                    'held_out_sse_library': lib, 'held_out_sse_with_cause': cat,
                    'held_out_margin': (lib - cat) / lib if lib > 0 else 0.0}
    model = fitted((), None, use_cat) if use_cat else Model()
    found = []
    band = channel_band(channel, rig)
    def term_of(ks):   # a trial (product column, sinusoid) as its term's name
        return names[ks[0]] if ks[1] is None else names[n_prod + ks[1]]
    for _step in range(MAX_TERMS):
        trials = [(k, None) for k in range(n_prod) if k not in model.prod]
        if model.sin is None:
            trials += [(None, k) for k in range(n_sin)]
        if not trials:
            break
        now = total(sse_fit(model))
        tried = []
        for k, s in trials:
            prod = model.prod if k is None else tuple([*model.prod, k])
            m = fitted(prod, model.sin if s is None else s, use_cat)
            tried.append((m, total(sse_fit(m))))
        least = min(e for _, e in tried)
        # parsimony: the first term in the library's order (lower degree, F_move before T and F_stat) that does
        # within TIE_SHARE of the best -- collinear signals (F_move, T, F_stat) would otherwise win by their noise --
        # and of those, one that is not a product of two cells' forces (F_move*T: no one sensor reads it) if any is
        tied = [(m, (k, s)) for (k, s), (m, e) in zip(trials, tried) if e <= least + TIE_SHARE * max(now - least, 0.0)]
        best = next((m for m, (k, s) in tied if s is not None or not mixed_forces(names[k])), tied[0][0])
        ext = sse_held(best)
        # the order breaks a tie only where the held-out pulls do not: a tied term that beats it there on the
        # held-out test (significance, its SSE the base) is the data's choice (the best such). On a made-up campaign
        # whose moving cell reads -c T*v, the order took F_move*v (fitted within TIE_SHARE) and then F_stat*v beside
        # it to undo the m2 a2 in it: two terms for one. A tied term has one parameter, as the order's choice: where
        # it is lower on every held-out pull (lower_on_every_pull), the held-out pulls prefer it though the t of the
        # per-pull shares stays under MIN_T. On the independent generator's stationary cell with F_stat^3 of +3x the
        # band (nominal rig, seed 3900, 12 pulls), the moving cell's T^2 fitted within 1.7 % of T^3 and the order
        # took it; T^3 was lower on all six held-out pulls (by 1.7-11 %, 4.3 % of the SSE, t = 3.3), and T^2,
        # the closer of the two to the cell gain's form, had its interval spanning 0 (the gain's stated line 1.9e-6
        # against 3.0e-6): nothing named. With -3x, T^2 fitted beyond the tie and F_stat^3 was named within 2 %.
        # Not, by the signs alone, from a term to one of the same form (force_form) with less of the channel's own
        # force (own_power): the signs lean that way, the channel's own departure being in its own column (an error
        # in the variables). On the own generator's cubic moving cell (seed 3401, `test_beyond`) F_stat^3 was lower
        # on every held-out pull than the true F_move^3, and was read as the stationary cell's own: the wrong
        # sensor. The other way they hold: the moving cell's F_move*F_stat and F_move*T at +3x the band
        # (independent generator, seed 3900) were right with the choice from T^2 (the order's), read as the
        # stationary cell's F_stat^2 without it; on the motor current (no own force) its F_stat^2, F_stat*v and
        # F_move*F_stat were right with it, ties (F_move^2, F_move*v) without
        chosen = term_of(next(ks for m, ks in tied if m is best))
        better = [(e, m) for m, ks in tied if m is not best
                  for e in (sse_held(m),) if significance(ext, e).significant
                  or (lower_on_every_pull(ext, e) and (force_form(term_of(ks)) != force_form(chosen) or own_power(
                      channel, term_of(ks)) >= own_power(channel, chosen)))]
        if better:
            ext, best = min(better, key=lambda x: total(x[0]))
        base = sse_held(model)
        ev = significance(base, ext)
        if not ev.significant:
            break
        others = [(names[k] if s is None else names[n_prod + s], base.sum() - total(sse_held(m)))
                  for (k, s), (m, _) in zip(trials, tried) if m is not best]
        alternatives = near_tied(others, base.sum() - ext.sum())
        runner = max(others, key=lambda o: o[1], default=None)   # the best term it beat, and by how much
        beat = () if runner is None or base.sum() <= 0 else (
            runner[0], float((base.sum() - ext.sum() - runner[1]) / base.sum()))
        new_prod = [k for k in best.prod if k not in model.prod]
        is_sin = best.sin is not None and model.sin is None
        ties = () if is_sin else tie_group(channel, held, names, (new_prod[0], best.coef_of(new_prod[0])), [
            (k, m) for (k, s), (m, _) in zip(trials, tried) if s is None and m is not best], ext, sse_held, band)
        cat_beat = catalog_margin(model, best, new_prod, base.sum(), kv,
                                  ((COULOMB, *DRIVE_FORMS) if drive else (COULOMB,)) if has_step
                                  else FORCE_FORMS if gain_form else (), fitted, sse_held)
        model = best
        # the term's coefficient, interval and budget with the drive's damping fitted beside it (kv): a damping off
        # the rig YAML's is then the data's to measure, not the stated +/-50 % in the budget of every term like v
        prof, shifts, lines = model, [], None
        if not is_sin and all(st.own is not None for st in fit) and reads_own(channel, names[new_prod[0]]):
            # a sensor term in the signal its reference stands for (the accelerometer's a2: the encoder's a3 in the
            # free phases) is refitted with that signal as the sensor reads it. Which of the two is the quantity the
            # sensor should read the data do not settle: each carries its own error into the columns and, with
            # coefficient -1 or +1, into the residual (an error in the variables). The encoder's a3 is a staircase's
            # second derivative where the carriage creeps to rest: on a clean independent campaign (seed 4412, 28
            # pulls) a2 alone came out near -1 on every set-4 pull's free phase after the break, -0.01 to -0.3 on the
            # others, and a2*t was named at -0.029 [-0.039, -0.019], 2.5 m/s^2 rms against the 0.74 band. So the
            # shift between the two is a model-form line of the term's budget: a term is named only beyond it
            own = fit_model([st._replace(gram=st.own[0], xy=st.own[1]) for st in fit], model.prod, model.sin,
                            model.cat, n_prod)
            shifts.append((REFERENCE_SHIFT, own.coef_of(new_prod[0]) - model.coef_of(new_prod[0])))
        if kv is not None and not is_sin and kv not in model.prod:
            prof = fitted(tuple([*model.prod, kv]), model.sin, model.cat)
            # which damping holds, the rig YAML's or the one fitted beside the term, the data do not say for certain:
            # the coefficient's shift between the two is a model-form line of its budget (DAMPING_SHIFT)
            shifts.append((DAMPING_SHIFT, prof.coef_of(new_prod[0]) - model.coef_of(new_prod[0])))
        if drive and not is_sin and separable(fit, prof.prod, tuple(sorted({*prof.cat, *drive})), new_prod[0]):
            # the drive's k_F and reflected mass as the gain and m2 below: the coefficient is the one with them at
            # the rig YAML's, their stated uncertainties give way to its shift when both are fitted beside it
            # (DRIVE_SHIFT) and to what fitting them adds to its scatter; when the data separate the term from
            # them at all (an F_move term is exactly k_F's form less the mass's and the damping's: there only the
            # stated uncertainties bound it) and settle it better than the stated ones do (below)
            lines = fitted(prof.prod, prof.sin, tuple(sorted({*prof.cat, *drive})))
            shifts.append((DRIVE_SHIFT, lines.coef_of(new_prod[0]) - prof.coef_of(new_prod[0])))
        elif gain_form and not is_sin and not model.cat and (
                forms or separable(fit, model.prod, tuple(range(len(FORCE_FORMS))), new_prod[0])):
            # the moving cell's gain and m2 in the same way, the other way round: the coefficient is the one with them
            # as the force model left them (fitted beside a load term they take part of it: on the own generator's
            # quadratic stationary cell the coefficient came out 32 % low, its interval missing), and their stated
            # uncertainties give way to the coefficient's shift when both are fitted beside it (FORMS_SHIFT): the
            # data measure them, so a gain or m2 one u off is theirs, not the term's (lines: the budget's systematic
            # parts regressed with their columns beside the term). When the one selection withheld the gain or m2
            # (forms), always; else, as the drive's k_F and mass above, where the data separate the term from them
            # and know it better than the stated uncertainties do (below: with those, a T*v of 3x the band on the
            # independent generator came out 0.00218 against 0.00222, statistical u 9e-6, the gain's line 0.0013)
            lines = fitted(model.prod, model.sin, tuple(range(len(FORCE_FORMS))))
            shifts.append((FORMS_SHIFT, lines.coef_of(new_prod[0]) - model.coef_of(new_prod[0])))
        ci = jackknife(fit, prof, n_prod)
        if is_sin:
            name, coef, cif, col = names[n_prod + model.sin], model.amp, ci[-1], None
        else:
            k = new_prod[0]
            pos = list(prof.prod).index(k)
            name, coef, cif, col = names[k], prof.coef[pos], ci[pos], k
        # the contribution's rms on the held-out pulls (scaled columns), then the SI coefficient
        n_held = sum(st.n for st in held)
        if col is None:
            pr = sin_pair(n_prod, model.sin)
            norm = sum(0.5 * (st.gram[pr[0], pr[0]] + st.gram[pr[1], pr[1]]) for st in held)
        elif all(st.window_ss is not None for st in held) and (
                channel not in SENSORS or reads_own(channel, name) or not alternatives):
            # a sensor's term (found in its free phases: window_ss is the sensors') acts where the sensor reads the
            # force, over the analysis window: its size is judged there. Before, only its own signal's terms (a2^2 on
            # the accelerometer) were, the rest in the free phases, where the signals are small: a stationary cell's
            # v*x at 3x the band on the independent generator came out 1.091 against 1.0915, t = 193, 0.79 N rms in
            # the free phases (band 1 N), inside the band, and the moving cell named it second hand, through T, as
            # its own (bench_sweep). A term the free phases cannot tell from another (near-tied) is judged where it
            # was found: the two can part ways under the load (the stationary cell's F_move is g m2 a2 with the
            # lanyard slack, hundreds of newtons more under the load), so its size there is not known. Judged over
            # the window, an a2 there was named F_move at 8.5 N rms (true a2 2.6 N) and the moving cell named T^2
            # and T^3 to undo it. The motor current's terms are judged over the window too: searched over every
            # sample, at rest as well, a term of 3x the band over the loaded windows (bench_sweep's F_move*v, a2*x,
            # v*x on the independent generator, each measured within 0.3-11 %) came to 0.46-0.96x the band over all
            # of them and stayed inside it; the window is among the current's own samples, so there a near-tied
            # term is judged there as well
            norm, n_held = sum(st.window_ss[col] for st in held), sum(st.n_window for st in held)
        else:
            norm = sum(st.gram[col, col] for st in held)
        rms_unit = math.sqrt(norm / max(n_held, 1))
        lo, hi = sorted(cif)
        si = si_factor(name, settings.scales)
        beside = lines.cat if lines is not None else ()
        if beside:   # and what measuring them on these pulls adds to the coefficient's scatter (jackknife, with them
            # fitted beside it against held): the data's uncertainty of the gain and m2 in place of the stated one
            pos_l = list(lines.prod).index(col)
            lo_l, hi_l = sorted(jackknife(fit, lines, n_prod)[pos_l])
            q = t_quantile(len(fit))
            u_l, u_0 = 0.5 * (hi_l - lo_l) / q, 0.5 * abs(hi - lo) / q
            shifts[-1] = (shifts[-1][0], math.hypot(shifts[-1][1], math.sqrt(max(0.0, u_l * u_l - u_0 * u_0))))
        budget, (lo_b, hi_b) = term_budget([augmented(st, True) for st in fit] if beside else fit,
                                           _cols(prof.prod, beside, len(fit[0].xy)), col, coef, (lo, hi), si,
                                           relative_part(channel, rig), shifts)
        if (drive or not forms) and beside:   # the data's k_F and mass (the gain and m2 when the one selection kept
            # them) only where they know the term better than the datasheet's
            stated = term_budget(fit, list(prof.prod), col, coef, (lo, hi), si, relative_part(channel, rig),
                                 shifts[:-1])
            # on the moving cell, moreover, only where the stated ones leave the term inside the band and the data's
            # put it above: elsewhere the stated lines hold. They also cover what the data's do not (on the own
            # generator's rate cell with the model-form nuisances, the lanyard's and cell's damping 2-4x, the
            # coefficient came out 10 % high, 0.00530 against 0.00482: the gain's stated line, 0.00128, held the
            # truth; the data's 0.00016 did not)
            if stated.budget[COMBINED] <= budget[COMBINED] or (
                    not drive and not low_end(stated.ci95) * rms_unit <= band < low_end((lo_b, hi_b)) * rms_unit):
                budget, (lo_b, hi_b) = stated
        lo, hi = lo_b, hi_b
        rms_lo = low_end((lo, hi)) * rms_unit
        rms_hi = max(abs(lo), abs(hi)) * rms_unit
        named = bool(rms_lo > band) and (not cat_beat or cat_beat[1] > needed(cat_beat[0]))
        own = None if named or not gain_form or col is None else beside_catalog(held, col) * abs(coef)
        unit = CHANNEL_UNITS[channel]
        why = None if own is None or own > band else (
            f'not identifiable at this strength: found on the moving cell ({abs(coef) * rms_unit:.3g} {unit} rms on '
            f'the held-out pulls, held-out SSE -{100 * ev.rel_sse_reduction:.0f} %), but the part of it the gain and '
            f'm2 (their forms F_move and a2) cannot take is {own:.3g} {unit} rms, inside the band ({band:g})')
        whole = abs(coef) * rms_unit
        if not named and has_step and kv is not None and col is not None and whole > band:
            # on the current, a term above the band at its estimate whose part beside the drive's constants (the
            # Coulomb step, k_F's and the reflected mass's forms, the damping's v) is inside it: the drive's, at this
            # size (bench_sweep's v of 3x the band: the damping's own form, 1 - r^2 = 0, inside its stated +/-50 %)
            left = drive_left(held, col, kv)
            if math.sqrt(left) * whole <= band:
                why = (f'not identifiable at this strength: found on the motor current ({whole:.3g} {unit} rms over '
                       f'the analysis window of the held-out pulls, held-out SSE -{100 * ev.rel_sse_reduction:.0f} %), '
                       f"but its column is in the span of the drive's constants' forms (the Coulomb step, k_F, the "
                       f'reflected mass, the damping: 1 - r^2 = {left:.1e}), and the part of it they cannot take, '
                       f'{math.sqrt(left) * whole:.3g} {unit} rms, is inside the band ({band:g}): the data cannot '
                       "tell it from those constants off their rig YAML values")
        if why is None and not named and col is not None and whole <= band and all(
                st.window_raw_ss is not None for st in held):
            # a channel formed through a filter (the current: through the one that makes a3, series.Through) keeps
            # of a term only what passes it. A term that rings with the cells (a2 in it) is mostly above what a3
            # follows: an F_stat*a2 of 3x the band on the current (independent generator, nominal campaign) was
            # measured within 8-15 %, but 0.052 A rms of it passes, inside the band (0.19 A), of 0.57 A in the
            # current; so is a2*v (0.13 of 0.57 A). Listed with both sizes rather than left as a term inside the band
            raw = abs(coef) * math.sqrt(sum(st.window_raw_ss[col] for st in held) / max(n_held, 1))
            if raw > band:
                why = (f'not identifiable at this strength: found on the motor current, but the balance holds only '
                       f"through the filter that makes the encoder's acceleration a3, which keeps {whole:.3g} {unit} "
                       f'rms of it over the analysis window of the held-out pulls, inside the band ({band:g}), of '
                       f'{raw:.3g} {unit} rms in the channel: the rest rings faster than a3 follows, where the '
                       "carriage's own acceleration, not the current, answers the load")
        found.append(Term(channel, name, float(coef * si), tuple(sorted((float(lo * si), float(hi * si)))),
                          f_hz if name.endswith(SIN) else None, ev.rms_gain, ev.rel_sse_reduction, ev.t,
                          abs(coef) * rms_unit, (rms_lo, rms_hi), band, named, budget, alternatives, beat,
                          cat_beat, why, ties))
    return ChannelResult(found, demoted, model, kept)


def tie_group(channel: str, held: Sequence[ChannelStats], names: Sequence[str], chosen: Tuple[int, float], others,
              ext: np.ndarray, sse_held, band: float) -> Tuple[Tuple[str, str, float, float], ...]:
    """The product terms the chosen one (chosen: its column and pooled coefficient on the scaled columns; ext, its
    held-out per-pull SSE) cannot be told from on this campaign (others: (column, the model with it in the chosen
    term's place)): it does not beat them on the held-out test that admitted it (significance.significance, each
    alternative's SSE the base), and the part of its contribution their column cannot take (its rms on the held-out
    pulls, from 1 - r^2 of the two columns there) is inside the channel's band, as beside_catalog judges a term
    against the catalog's forms. Each with that 1 - r^2 and the chosen term's held-out margin over it (a share of its
    SSE). The forward selection breaks such a tie by the library's order; the report lists the group (its members
    under beyond_search.identifiability) instead of hiding it."""
    k, coef = chosen
    G = sum(st.gram for st in held)
    n = max(sum(st.n for st in held), 1)
    out = []
    for j, m in others:
        alt = sse_held(m)
        left = max(1.0 - G[j, k] ** 2 / max(float(G[j, j] * G[k, k]), 1e-300), 0.0)
        if significance(alt, ext).significant or abs(coef) * math.sqrt(left * G[k, k] / n) > band:
            continue
        out.append((channel, names[j], float(left), float(1.0 - ext.sum() / max(alt.sum(), 1e-300))))
    return tuple(sorted(out, key=lambda x: x[2]))


def low_end(ci: Tuple[float, float]) -> float:
    """|coefficient| at the interval's end nearer 0 (0 when it holds 0)."""
    return 0.0 if ci[0] <= 0 <= ci[1] else min(abs(ci[0]), abs(ci[1]))


def beside_catalog(stats: Sequence[ChannelStats], k: int) -> float:
    """The rms over the pulls stats (their normal equations, pooled) of the part of product column k that the
    channel's catalog columns (the moving cell's: the gain's and m2's forms, F_move and a2) cannot take: what is left
    of it after its least squares on them, per unit coefficient. Under the band at a term's fitted size, the data
    cannot tell the term from those causes at this strength (issue 39: a2*t of 3x the band on the independent
    generator is 2.4 N rms there, 0.35 N of it beside F_move and a2)."""
    G = sum(augmented(st, True).gram for st in stats)
    n_all = len(stats[0].xy)
    cat = list(range(n_all, G.shape[0]))
    g = G[k, cat]
    left = float(G[k, k] - g @ np.linalg.lstsq(G[np.ix_(cat, cat)], g, rcond=1e-12)[0])
    return math.sqrt(max(left, 0.0) / max(sum(st.n for st in stats), 1))


def drive_left(stats: Sequence[ChannelStats], k: int, kv: int) -> float:
    """1 - r^2 of the current's product column k against the drive's forms over the pulls stats (pooled): its
    catalog columns (the Coulomb step, k_F's and the reflected mass's forms) and the damping's, column kv (0 when k is
    kv)."""
    if k == kv:
        return 0.0
    G = sum(augmented(st, True).gram for st in stats)
    d = np.sqrt(np.maximum(np.diag(G), 1e-300))
    C = G / np.outer(d, d)
    rest = [kv, *range(len(stats[0].xy), G.shape[0])]
    g = C[rest, k]
    return max(0.0, 1.0 - float(g @ np.linalg.lstsq(C[np.ix_(rest, rest)], g, rcond=1e-12)[0]))


def separable(stats: Sequence[ChannelStats], prod: Sequence[int], cat: Sequence[int], k: int) -> bool:
    """Whether product column k is more than collinear (identify.COLLINEAR: 1 - r^2 against the others) with the
    other product columns prod and the catalog columns cat over the pulls stats (their normal equations, pooled)."""
    idx = _cols(prod, cat, len(stats[0].xy))
    G = sum(augmented(st, True).gram[np.ix_(idx, idx)] for st in stats)
    d = np.sqrt(np.maximum(np.diag(G), 1e-300))
    C = G / np.outer(d, d)
    pos = idx.index(k)
    rest = [i for i in range(len(idx)) if i != pos]
    if not rest:
        return True
    g = C[rest, pos]
    left = 1.0 - float(g @ np.linalg.lstsq(C[np.ix_(rest, rest)], g, rcond=1e-12)[0])
    return left > COLLINEAR


def catalog_margin(model: Model, best: Model, new_prod: Sequence[int], base: float, kv: Optional[int],
                   cat_causes: Sequence[str], fitted, sse_held) -> Tuple:
    """(the best catalog cause in the new term's place, the term's held-out margin over it as a share of the SSE
    before it; () when none competes): on the motor current the viscous damping (its form, column kv), the
    Coulomb step and the drive's k_F and reflected mass (DRIVE_FORMS), on the moving cell its gain and effective
    mass (cat_causes: the causes whose forms are the channel's catalog columns, in order), each added to the model
    instead of the term (beside the catalog columns the model holds), one parameter as the term. On the current,
    moreover, the drive's calibration whole (DRIVE_CALIBRATION: k_F, the reflected mass and the damping together,
    which the catalog fits on the data, friction.drive_fit): a term those three explain as well, held out, is theirs.
    One at a time none of them is F_move's form (1 - r^2 0.97-0.998 on the independent generator's nominal campaign),
    together they are (5e-14), so an F_stat of 3x the band on the current, 1.4e-6 beside them, had F_stat*a2 named
    in its place once the current's terms were judged over the analysis window."""
    alts = {}
    damp = kv is not None and kv not in model.prod and kv not in new_prod
    if damp:
        alts[DAMPING] = fitted(tuple([*model.prod, kv]), model.sin, model.cat)
    for j, cause in enumerate(cat_causes):
        if j not in model.cat:
            alts[cause] = fitted(model.prod, model.sin, tuple(sorted({*model.cat, j})))
    drive = [j for j, cause in enumerate(cat_causes) if cause in DRIVE_FORMS]
    if drive and not set(drive) <= set(model.cat):
        alts[DRIVE_CALIBRATION] = fitted(tuple([*model.prod, kv]) if damp else model.prod, model.sin,
                                         tuple(sorted({*model.cat, *drive})))
    if not alts or base <= 0:
        return ()
    e_best = total(sse_held(best))
    margins = {c: float((total(sse_held(m)) - e_best) / base) for c, m in alts.items()}
    cause = min(margins, key=lambda c: margins[c] - needed(c))
    return cause, margins[cause]


def needed(cause: str) -> float:
    """The held-out margin a term must have over a catalog cause in its place to be named: over one cause with one
    parameter, as the term, any; over the drive's calibration whole (DRIVE_CALIBRATION), which the catalog fits on the
    data anyway, PRIORITY_MARGIN, as a library term needs to take the Coulomb step's place (the catalog keeps
    priority: an F_stat of 3x the band on the current, in the span of the drive's forms, was followed by F_stat*a2
    0.4 % better held out, the carriage's deceleration under the load growing with the tension)."""
    return PRIORITY_MARGIN if cause == DRIVE_CALIBRATION else 0.0


def relative_part(channel: str, rig) -> Optional[Tuple[str, float]]:
    """(component, relative standard uncertainty) of the channel's sensor calibration (grammar.RELATIVE), or None."""
    if channel not in RELATIVE:
        return None
    comp, key, attr = RELATIVE[channel]
    return comp, rig.uncertainty.relative(key, getattr(rig.sensors, attr))


def near_tied(others: Sequence[Tuple[str, float]], chosen: float) -> Tuple[str, ...]:
    """The terms (others: (name, held-out SSE reduction in its place)) that come within NEAR_TIE of the chosen
    term's held-out reduction, best first: on this campaign's motion the data cannot tell them from it (t and t^2
    over a short window, F_move and T), so the report lists them beside the term instead of hiding them."""
    if chosen <= 0:
        return ()
    close = sorted(((r, n) for n, r in others if r >= (1.0 - NEAR_TIE) * chosen), key=lambda x: -x[0])
    return tuple(n for _, n in close)
