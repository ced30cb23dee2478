"""Uncertainty budgets: every reported parameter's combined standard uncertainty, the statistical part
(the pull-to-pull spread, uncertainty.py) and the systematic parts, each estimated and listed. ROS-free.

Components (standard uncertainties, k = 1, in the parameter's unit), by kind (KIND):
- statistical: the 95 % interval of the pull-to-pull spread (jackknife or bootstrap) over its coverage factor.
- nominal constants: the force model is refitted, on up to VARIANT_PULLS of the fitted pulls, with T computed from
  m1 (or the cells' stiffness) one standard uncertainty (rig.uncertainty) off; the friction force with each drive
  constant one standard uncertainty off. The change is the component (a sensitivity coefficient times u). When the
  stationary cell's free decay measured its natural frequency on m1 (cells.py), T depends on m1 and K_LC1 only
  through it: the stiffness's u is then the measurement's (cell_stiffness_u) and m1's change is zero.
- model form: the same refits under plausible variants of the model of record: the cells' damping one standard
  uncertainty off (the rig's, or when the free decay measured it, the measurement's: cell_damping_u), a 4th-order
  Butterworth anti-alias filter at 0.4 x the sample rate on every channel, and a shorter analysis window (25 ms
  later, 50 ms earlier), and the accelerometer's delay a 2-pole Bessel filter, not a shift (delay_form: counted
  where the data fit it better than a shift seen through the same filter). And, on
  every fitted pull, the refit with the tension's own timing free (force_model.EXTRA:
  the model of record has the two cells simultaneous; a DAQ that samples its channels in turn, or a stationary cell
  that lags, makes them not): what the data say about an assumption the model cannot test on its own. The
  free-decay mode (the mount's frequency and damping) under the analysis's defensible variants: the matrix pencil's
  model order, the window's start and length, the accelerometer alone (free_decay_analysis, mode_form_parts).
- DAQ: the sample clock's relative uncertainty (rig daq.sample_rate_hz) on every time or frequency parameter.
  The samples' resolution and noise act pull to pull: they are in the statistical part.
- definition: what the parameter is depends on the operating point. The force model is refitted on the fitted
  pulls grouped by load (GROUPS groups by stationary peak); the spread of the groups beyond what their statistics
  explain is a random effect, and the pooled estimate's share of it (over GROUPS) is the component
  (load_dependence). A mode's frequency and damping, and the hum's frequency, move from pull to pull: their
  pull-to-pull standard deviation (pull_to_pull).

The expanded uncertainty is U = sqrt((q u_stat)^2 + (k u_sys)^2) (expanded): q is the statistical interval's own
factor (Student's t over the fitted pulls, or 1.96 for a bootstrap), so with no systematic part the interval is the
old one, and k = COVERAGE_FACTOR = 2 (a calibration certificate's k = 2, about 95 %; its one home is
force_correction.core.peak_uncertainty) on the systematic parts, whose distributions are not known.
`parameters_ci95` becomes estimate +/- U. The terms beyond the catalog get their budgets the same way (term_budget).
"""
from __future__ import annotations

import dataclasses
import math
from functools import partial
from typing import Dict, Mapping, NamedTuple, Optional, Sequence, Tuple

import numpy as np

from force_correction.core.peak_uncertainty import COVERAGE_FACTOR

from .candidate import Candidate
from .force_model import EXTRA, TERMS, ForceModel, force_params
from .force_stats import ForceStats
from .friction import calibrated_rows, friction_row, friction_stat, viscous_fit
from .prep import Pull, tension_from_stationary
from .uncertainty import CONFIDENCE, t_quantile

VARIANT_PULLS = 3        # fitted pulls (spread over the campaign) the model-form and constant refits use
GROUPS = 3               # load groups of the fitted pulls for the definition component
ANTI_ALIAS_FRACTION = 0.4   # the variant's anti-alias corner, as a fraction of the sample rate
WINDOW_LATER_S, WINDOW_EARLIER_S = 0.025, 0.05   # the shorter analysis window's start and end moved in

STATISTICAL, COMBINED, MODEL_FORM = 'statistical', 'combined', 'model form'
OPERATING_RANGE = 'operating_range'   # a term's model-form line beyond the catalog (operating_range)
DRIVE_CALIBRATION = 'drive_calibration'   # the friction's line from the drive's k_F calibrated on the data ...
DRIVE_MODEL = 'drive_model'               # ... and half its gap to the friction with the datasheet's drive
DRIVE_POOLING = 'drive_pooling'           # ... and half the gap between each pull's own k_F and the campaign's one
DRIVE_WINDOW = 'drive_window'             # ... and, in the drive's impulse form, its spread over the window
HALF_PULLS = 2                        # ... measured when each half of the fitted pulls has at least this many
#: component -> its kind (report.md groups the budget table by kind)
KIND = {STATISTICAL: 'statistical',
        'm1': 'nominal constant', 'cell_stiffness': 'nominal constant',
        'torque_constant': 'nominal constant', 'pulley_radius': 'nominal constant',
        DRIVE_CALIBRATION: 'nominal constant', DRIVE_MODEL: MODEL_FORM, DRIVE_POOLING: MODEL_FORM,
        DRIVE_WINDOW: MODEL_FORM,
        'actuator_inertia': 'nominal constant', 'motor_inertia': 'nominal constant',
        'viscous_damping_motor': 'nominal constant', 'viscous_damping_actuator': 'nominal constant',
        'cell_damping': MODEL_FORM, 'anti_alias_filter': MODEL_FORM, 'analysis_window': MODEL_FORM,
        'tension_timing': MODEL_FORM, 'free_decay_analysis': MODEL_FORM, 'delay_form': MODEL_FORM,
        'pre_pull_window': MODEL_FORM, OPERATING_RANGE: MODEL_FORM,
        'sample_clock': 'DAQ', 'load_dependence': 'definition', 'pull_to_pull': 'definition'}
#: the pull under the delay_form variant's filter on every channel: what that variant's fit is compared with
DELAY_FORM_REFERENCE = 'delay_form_reference'
DELAY_FORMS = ('delay_form', DELAY_FORM_REFERENCE)   # the variants of the delay's form (force_systematics)
FORCE_VARIANTS = ('m1', 'cell_stiffness', 'cell_damping', 'anti_alias_filter', 'analysis_window', 'delay_form',
                  DELAY_FORM_REFERENCE)
DRIVE_VARIANTS = {'torque_constant': 'torque_constant_nm_per_a', 'pulley_radius': 'pulley_radius_m',
                  'actuator_inertia': 'actuator_inertia_kg_m2', 'motor_inertia': 'motor_inertia_kg_m2',
                  'viscous_damping_motor': 'viscous_damping_motor_n_s_per_m',
                  'viscous_damping_actuator': 'viscous_damping_actuator_n_s_per_m'}
TIME_PARAMETERS = {('accel_delay', 'delay_s'), ('ac_coupling', 'time_constant_s'),
                   ('mains_hum', 'frequency_hz'), ('mount_resonance', 'frequency_hz')}


def variant_pulls(fit: Sequence[int]) -> list:
    """The fitted pulls (list positions) the refits use: up to VARIANT_PULLS, spread evenly."""
    fit = list(fit)
    if len(fit) <= VARIANT_PULLS:
        return fit
    return [fit[int(round(i * (len(fit) - 1) / (VARIANT_PULLS - 1)))] for i in range(VARIANT_PULLS)]


def _butter(x: np.ndarray, sos) -> np.ndarray:
    from scipy.signal import sosfilt
    return sosfilt(sos, x - x[0]) + x[0]      # settled on the first sample


def cell_damping_u(rig, cal: Optional[tuple], fcal: Optional[tuple]) -> float:
    """The relative standard uncertainty of the cells' damping T uses. Without a measured free decay: the rig's.
    With one (cells.cell_frequency_from: ..., median damping ratio, its sd), the measurement's standard error and
    the difference between the ratio T uses and the measured one (when it stayed below the calibration's gate)."""
    fc = rig.force_chain
    if fcal is None:
        return rig.uncertainty.relative('force_chain.load_cell_damping_ratio', fc.load_cell_damping_ratio)
    _f, _sd, n, z, sd_z = fcal
    k1, c1 = (fc.load_cell_stiffness_n_per_m, fc.c1) if cal is None else cal
    z_used = c1 / (2.0 * math.sqrt(k1 * fc.m1))
    return math.sqrt((z_used / z - 1.0) ** 2 + (sd_z / math.sqrt(n) / z) ** 2)


def cell_stiffness_u(rig, cal: Optional[tuple], fcal: Optional[tuple]) -> float:
    """The standard uncertainty of the stiffness T uses. Without a measured cell frequency: the rig's. With one
    (cells.cell_frequency_from: median f, sd, n), T depends on the cell only through K_LC1 / m1 = (2 pi f)^2 and the
    damping ratio, so K_LC1's relative u is twice f's: the measurement's standard error, the sample clock, and the
    difference between the frequency T uses and the measured one (when it stayed below the calibration's gate)."""
    fc = rig.force_chain
    k1 = fc.load_cell_stiffness_n_per_m if cal is None else cal[0]
    if fcal is None:
        return rig.uncertainty.u('force_chain.load_cell_stiffness_n_per_m') * k1 / fc.load_cell_stiffness_n_per_m
    f, sd, n, _z, _sd_z = fcal
    f_used = math.sqrt(k1 / fc.m1) / (2 * math.pi)
    rel = math.sqrt((sd / math.sqrt(n) / f) ** 2 + clock_relative(rig) ** 2 + (f_used / f - 1.0) ** 2)
    return 2.0 * rel * k1


def force_variants(p: Pull, rig, cal: Optional[tuple], fcal: Optional[tuple] = None) -> Dict[str, Pull]:
    """The pull under each FORCE_VARIANTS variant. cal: the cells' (K_LC1, c1) T uses (cells.cell_calibration;
    None: the rig's); fcal: the measured cell frequency (cells.cell_frequency_from), when there is one: then m1 moving
    with K_LC1 / m1 held leaves T as it is (it depends on m1 only through the measured frequency): the pull itself."""
    from scipy.signal import butter
    fc, u = rig.force_chain, rig.uncertainty
    m1 = fc.m1
    k1, c1 = (fc.load_cell_stiffness_n_per_m, fc.c1) if cal is None else cal
    um1 = u.u('force_chain.stationary_side_mass_kg')
    uk1 = cell_stiffness_u(rig, cal, fcal)
    rz = cell_damping_u(rig, cal, fcal)

    def tension(m, k, c):
        return dataclasses.replace(p, T=tension_from_stationary(p.fs, p.dt, m, k, c))
    r = (m1 + um1) / m1
    out = {'m1': p if fcal is not None else tension(m1 + um1, k1, c1 * math.sqrt(r)),   # the damping ratio held
           'cell_stiffness': tension(m1, k1 + uk1, c1 * math.sqrt((k1 + uk1) / k1)),
           'cell_damping': tension(m1, k1, c1 * (1.0 + rz))}
    sos = butter(4, ANTI_ALIAS_FRACTION / p.dt, fs=1.0 / p.dt, output='sos')
    out['anti_alias_filter'] = dataclasses.replace(p, fm=_butter(p.fm, sos), T=_butter(p.T, sos),
                                                   a2=_butter(p.a2, sos))
    w0 = min(p.w0 + int(round(WINDOW_LATER_S / p.dt)), p.load0)
    w1 = max(p.w1 - int(round(WINDOW_EARLIER_S / p.dt)), p.brk + 1)
    out['analysis_window'] = dataclasses.replace(p, w0=w0, w1=w1)
    d = own_delay(p, fc.m2)
    out['delay_form'], out[DELAY_FORM_REFERENCE] = delay_form(p, d), delay_form(p, d, reference=True)
    return out


def own_delay(p: Pull, m2: float) -> float:
    """The pull's own fitted accelerometer delay (the full force model on it alone): the delay_form variant's d."""
    return ForceModel([p], m2).fit_delay(set(TERMS), [0]).delay_s


FORM_MARGIN = 0.5     # filter_form_preferred: the filter form's squared residual below this share of the shift's (seed
#                       5101's Bessel: 0.105; own-generator campaigns with a shift: 1.0 or a hair either side of it)
FORM_ITERATIONS = 5   # filter_delay's refits (each step closes about 2/3 of what is left: see filter_delay)


def filter_delay(p: Pull, m2: float) -> float:
    """The accelerometer's delay as a 2-pole Bessel filter's group delay: the shift's own_delay is short of it (a
    filter delays the ringing less than its low-frequency group delay), so the pull under delay_form at d is fitted
    again for d, FORM_ITERATIONS times (on independent seed 5101, true 54.8 us: 49.1, 52.8, 53.8, 54.2, 54.3 us;
    a set-3 pull's m2 1.32, 1.25, 1.231, 1.224 kg for the true 1.235)."""
    d = own_delay(p, m2)
    for _ in range(FORM_ITERATIONS):
        d = own_delay(delay_form(p, d), m2)
    return d


def filter_form_preferred(stats: Sequence, fit: Sequence[int], m2: float, scales) -> bool:
    """Whether the data prefer the accelerometer's delay as a 2-pole Bessel filter to a shift: on the fitted pulls
    that carry the variants (pass 3's stats[j].variants), the delay_form variant's squared residual is below
    FORM_MARGIN of its reference's (the shift seen through the same filter; force_systematics counts the line where
    it is below it at all: a near tie is no ground to change the estimate). Then the
    estimate is the filter form's fit (stream: every pull under delay_form) and the shift is the rejected
    alternative (its delay_form line 0)."""
    vidx = [j for j in fit if stats[j].variants is not None and 'delay_form' in stats[j].variants]
    if not vidx:
        return False

    def sub(name):
        return ForceStats([stats[j].variants[name] for j in vidx], [stats[j].dt for j in vidx], m2,
                          None if scales is None else [scales[j] for j in vidx])
    idx = range(len(vidx))
    return sub('delay_form').fit_delay(set(TERMS), idx).sse < FORM_MARGIN * sub(DELAY_FORM_REFERENCE).fit_delay(
        set(TERMS), idx).sse


def bessel_attenuation(x: np.ndarray, dt: float, tau: float) -> np.ndarray:
    """x through a 2-pole Bessel low-pass of low-frequency group delay tau, 3 / (3 + 3 s tau + (s tau)^2), with that
    delay taken back out (times e^(s tau)): the filter's attenuation and phase beyond a shift (in the frequency
    domain, the end trend removed first and put back)."""
    trend = np.linspace(x[0], x[-1], len(x))
    s = 2j * np.pi * np.fft.rfftfreq(len(x), dt) * tau
    return np.fft.irfft(np.fft.rfft(x - trend) * 3.0 / (3.0 + 3.0 * s + s * s) * np.exp(s), len(x)) + trend


def delay_form(p: Pull, d: float, reference: bool = False) -> Pull:
    """The pull as the delay_form variant sees it: the accelerometer's delay d (the pull's own fitted lag) a 2-pole
    Bessel low-pass of that group delay, not a shift. A filter on a2 attenuates the ringing the mass is fitted on,
    which a shift does not; the filter's attenuation (bessel_attenuation) on F_move and T makes the channels alike
    again, and the refit gives the mass a filter-shaped delay leaves. reference: the attenuation on a2 too, the
    shift-shaped delay seen through the same filter (what the variant's misfit is compared with:
    force_systematics). A lead (d <= 0) is a DAQ's sampling skew, a shift: the pull as it is."""
    if not d > 0:
        return p
    out = dataclasses.replace(p, fm=bessel_attenuation(p.fm, p.dt, d), T=bessel_attenuation(p.T, p.dt, d))
    return dataclasses.replace(out, a2=bessel_attenuation(p.a2, p.dt, d)) if reference else out


def friction_variants(p: Pull, rig) -> Optional[Dict[str, tuple]]:
    """friction_row() of the pull with each drive constant one standard uncertainty off (None: no current)."""
    if p.current is None:
        return None
    out = {}
    for name, key in DRIVE_VARIANTS.items():
        v = getattr(rig.drive, key)
        d = dataclasses.replace(rig.drive, **{key: v + rig.uncertainty.u(f'drive.{key}')})
        out[name] = friction_row(p, dataclasses.replace(rig, drive=d))
    return out


def _param_table(coef: dict, d: float, m2: float) -> Dict[str, Dict[str, float]]:
    """force_params, with the AC coupling as its rate k (1/tau, finite for any sign)."""
    out = force_params(coef, d, m2)
    if 'k' in coef:
        out['ac_coupling'] = {'time_constant_s': float(coef['k'])}
    return out


def filter_form_parts(stats: Sequence, fstats: Sequence, fit: Sequence[int], m2: float, scales) -> dict:
    """{term: {parameter: u}}: the delay_form line when the estimate is the filter form's (stream). The filter's
    group delay is itself fitted: the force model on the variant pulls under the filter at the shift's delay (pass 3's
    delay_form variant) against under the filter at its own delay (fstats: passes.form_stats); how far the estimate
    moves between the two is how much it rests on that delay, and on the filter's form beyond it. On independent
    seed 5101 the filter form's m2 came out 2.2 % above the truth with a statistical u of 0.17 %: the 2-pole Bessel
    is not the generator's filter exactly."""
    vidx = [j for j in fit if stats[j].variants is not None and 'delay_form' in stats[j].variants]
    if not vidx:
        return {}

    def table(blocks):
        c, _, d = ForceStats(blocks, [stats[j].dt for j in vidx], m2,
                             None if scales is None else [scales[j] for j in vidx]).fit_delay(set(TERMS),
                                                                                            range(len(vidx)))
        return _param_table(c, d, m2)
    once, own = table([stats[j].variants['delay_form'] for j in vidx]), table([fstats[j].blocks for j in vidx])
    out: dict = {}
    for term, params in own.items():
        for par, v in params.items():
            scale = rate_scale(1.0 / v if v > 0 else math.inf) if term == 'ac_coupling' else 1.0
            out.setdefault(term, {})[par] = abs(once[term][par] - v) / scale
    return out


def force_systematics(fm_nominal, fm_variants: Mapping[str, object], idx: Sequence[int], m2: float) -> dict:
    """{term: {parameter: {component: change}}} of the full force model refitted (delay searched) on the pulls idx
    of each variant ForceStats against the nominal one's; for ac_coupling the change in the rate 1/tau over the
    rate_scale of the nominal fit's tau (its unit). The delay_form variant is compared with its reference (the
    same filter on every channel: DELAY_FORM_REFERENCE): it counts (its change from the nominal fit) only where the
    data prefer it, its fit's squared residual below the reference's (a filter-shaped delay; a shift-shaped one
    leaves it 0)."""
    full = set(TERMS)
    c0, _, d0 = fm_nominal.fit_delay(full, idx)
    p0 = _param_table(c0, d0, m2)
    ref = fm_variants.get(DELAY_FORM_REFERENCE)
    fr = None if ref is None else ref.fit_delay(full, idx)
    out: dict = {}
    for name, fm_v in fm_variants.items():
        if name == DELAY_FORM_REFERENCE:
            continue
        c, sse, d = fm_v.fit_delay(full, idx)
        pv = _param_table(c, d, m2)
        base = pv if (name == 'delay_form' and fr is not None and sse >= fr.sse) else p0
        for term, params in p0.items():
            for par, v in params.items():
                scale = rate_scale(1.0 / v if v > 0 else math.inf) if term == 'ac_coupling' else 1.0
                out.setdefault(term, {}).setdefault(par, {})[name] = abs(pv[term][par] - base[term][par]) / scale
    return out


def extra_systematics(model_with, fit: Sequence[int], m2: float) -> dict:
    """force_systematics of the force model with each EXTRA regressor added against the model of record, on every
    fitted pull (model_with(extra): a ForceModel or ForceStats of the campaign with those regressors)."""
    return force_systematics(model_with(()), {e: model_with((e,)) for e in EXTRA}, fit, m2)


def load_groups(fit: Sequence[int], peaks: Sequence[float]) -> list:
    """The fitted pulls in GROUPS groups by their stationary peak (fewer groups when there are few pulls; each
    group at least 2 pulls)."""
    order = sorted(fit, key=lambda j: peaks[j])
    g = min(GROUPS, len(order) // 2)
    if g < 2:
        return []
    return [list(a) for a in np.array_split(np.array(order), g)]


def _group_table(fm_, gr: Sequence[int], m2: float, d: float) -> dict:
    """_param_table of the force model fitted on the pulls gr: the delay searched on them, the other terms at d."""
    c = fm_.fit(set(TERMS), list(gr), d).coefficients
    dg = fm_.fit_delay(set(TERMS), list(gr)).delay_s
    return _param_table(c, dg, m2)


def load_dependence(fm_, groups: Sequence[Sequence[int]], m2: float, u_stat: dict, d: float) -> dict:
    """{term: {parameter: u}}: the load dependence as a random effect. The force model fitted on each of the G
    load groups spreads with variance s^2; of it, a group's own statistical variance v (the larger of its
    delete-one-pull jackknife within the group, averaged over the groups, and G u_stat^2, the pooled one scaled
    to a group's size) is noise, and the rest, tau^2 = s^2 - v (at least 0), is the between-group variance. The
    pooled estimate, an average over the campaign's loads, carries tau^2 / G of it (a random-effects mean over G
    groups), not the whole tau^2 of one group (u_stat: {term: {parameter: the pooled statistical u}}; tau's in
    its rate; the result in the parameter's unit). The delay is searched per group for its own spread; the other
    terms are fitted at the campaign's delay d (a delay's noise in a small group is not a load dependence of the
    gain)."""
    if len(groups) < 2:
        return {}
    per = [_group_table(fm_, gr, m2, d) for gr in groups]
    loo = [[_group_table(fm_, [j for j in gr if j != k], m2, d) for k in gr] if len(gr) >= 2 else []
           for gr in groups]
    out: dict = {}
    for term, params in per[0].items():
        for par in params:
            vals = np.array([p[term][par] for p in per])
            s2 = float(np.var(vals, ddof=1))
            own = [(len(lg) - 1) * float(np.var([q[term][par] for q in lg])) for lg in loo if lg]
            v_own = float(np.mean(own)) if own else 0.0
            v_pooled = len(groups) * u_stat.get(term, {}).get(par, 0.0) ** 2
            v = max(v_own, v_pooled) if math.isfinite(v_own) else v_pooled   # a singular one-pull fit: the pooled
            k0 = float(np.mean(vals))
            scale = rate_scale(1.0 / k0 if k0 > 0 else math.inf) if term == 'ac_coupling' else 1.0
            tau2 = max(0.0, s2 - v) if (math.isfinite(v) and math.isfinite(s2)) else 0.0
            out.setdefault(term, {})[par] = math.sqrt(tau2 / len(groups)) / scale
    return out


def friction_systematics(rows: np.ndarray, rows_v: Sequence[Mapping[str, tuple]], stat, joint: bool = False,
                         drive: Optional[Tuple[float, ...]] = None) -> dict:
    """{component: change of the friction statistic} with each drive constant off (rows: the fitted pulls'
    friction_row()s as friction.calibrated_rows gave them; rows_v: their friction_variants(); stat:
    friction.friction_stat; joint: the viscous damping fitted with it; drive: with the drive calibrated on the data
    (friction.drive_calibration), the lines DRIVE_CALIBRATION (its own u's effect, friction.drive_line),
    DRIVE_MODEL (half the gap between the friction with the calibrated drive and with the datasheet's: two models of
    the drive that both fit) and DRIVE_POOLING (half the gap between the friction with each pull's own k_F and with
    the campaign's one) and, in the drive's impulse form, DRIVE_WINDOW (its spread over the window):
    friction.drive_lines, in that order; and each variant's rows calibrated too, so a
    force-per-amp or inertia variant leaves about nothing); and the model-form line OPERATING_RANGE
    (friction_range)."""
    f0 = stat(rows)
    calibrated = drive is not None
    out = {name: abs(stat(calibrated_rows(np.array([r[name] for r in rows_v]), calibrated)) - f0)
           for name in DRIVE_VARIANTS}
    if calibrated:
        out.update(zip((DRIVE_CALIBRATION, DRIVE_MODEL, DRIVE_POOLING, DRIVE_WINDOW), drive))
    out[OPERATING_RANGE] = friction_range(rows, joint)
    return out


def halves_line(first: float, second: float, u_stat: float) -> float:
    """The OPERATING_RANGE line from one parameter fitted on each half of the pulls: u^2 = (first - second)^2 / 4
    less u_stat^2 (what the halves' difference has under noise alone), at least 0 (a random effect, as
    load_dependence takes it)."""
    return math.sqrt(max(0.0, (first - second) ** 2 / 4.0 - u_stat ** 2))


def friction_range(rows: np.ndarray, joint: bool) -> float:
    """The friction's model-form line, OPERATING_RANGE as a term's (operating_range): each fitted pull's friction
    (its moving less its rest residual, less the viscous departure the joint fit measured times its speed) on the
    first and on the second half of the pulls (the sets in order, lower loads first); u^2 = (f1 - f2)^2 / 4 less
    the pulls' own spread's share (their variance over n, what the halves' difference has under noise alone), at
    least 0. Dry friction that is one constant at every load gives both halves the same."""
    rows = np.asarray(rows, float)
    if len(rows) < 2 * HALF_PULLS:
        return 0.0
    fit = viscous_fit(rows) if joint else None
    y = rows[:, 0] - rows[:, 1] - (0.0 if fit is None else fit[1] * rows[:, 2])
    h = len(y) // 2
    return halves_line(float(np.mean(y[:h])), float(np.mean(y[h:])), math.sqrt(float(np.var(y, ddof=1)) / len(y)))


def pull_to_pull_parts(cand: Mapping, modes: Sequence, hum_freqs: Sequence[float],
                       mode_variants: Sequence[Optional[Mapping]] = ()) -> dict:
    """{cause: {parameter: {component: u}}} of the quantities measured pull by pull: whose definition moves with the
    pull: the free-decay mode's frequency and damping (modes: (f, zeta) or None per pull) and the hum's frequency
    (hum_freqs: the pulls' own), each their pull-to-pull standard deviation (at least 2 pulls, 'pull_to_pull'); and
    the mode's model-form part from its analysis variants (mode_variants, mode_form_parts())."""
    out: dict = {}
    found = [m for m in modes if m is not None]
    if 'mount_resonance' in cand and len(found) >= 2:
        out['mount_resonance'] = {'frequency_hz': {'pull_to_pull': float(np.std([m[0] for m in found], ddof=1))},
                                  'damping_ratio': {'pull_to_pull': float(np.std([m[1] for m in found], ddof=1))}}
    if 'mains_hum' in cand and len(hum_freqs) >= 2:
        out['mains_hum'] = {'frequency_hz': {'pull_to_pull': float(np.std(hum_freqs, ddof=1))}}
    for cause, params in mode_form_parts(cand, modes, mode_variants).items():
        for par, comps in params.items():
            out.setdefault(cause, {}).setdefault(par, {}).update(comps)
    return out


MODE_PARAMETERS = ('frequency_hz', 'damping_ratio')   # the mount's, in a free-decay mode's (f, zeta) order


def mode_form_parts(cand: Mapping, modes: Sequence, variants: Sequence[Optional[Mapping]]) -> dict:
    """{'mount_resonance': {parameter: {'free_decay_analysis': u}}}: the model-form part of the free-decay mode. The
    mode is the median over the few pulls (ringing.observed_mode) of one analysis (the matrix pencil's order, its
    window, the signal); each defensible variant (ringing.MODE_VARIANTS; variants: free_decay_variants() per pull,
    None where the pull had no mode) gives its own median over the pulls that found the mode under it, and u is
    the root mean square of the variants' departures from the nominal median (empty without a mode or variants)."""
    found = [m for m in modes if m is not None]
    rows = [v for v in variants if v is not None]
    if 'mount_resonance' not in cand or not found or not rows:
        return {}
    out: dict = {}
    for k, par in enumerate(MODE_PARAMETERS):
        nominal = float(np.median([m[k] for m in found]))
        dev = []
        for name in rows[0]:
            vals = [v[name][k] for v in rows if v.get(name) is not None]
            if vals:
                dev.append(float(np.median(vals)) - nominal)
        if dev:
            out[par] = {'free_decay_analysis': math.sqrt(float(np.mean(np.square(dev))))}
    return {'mount_resonance': out} if out else {}


def statistical_u(name: str, c: Candidate, par: str) -> float:
    """The statistical standard uncertainty behind a candidate's interval (inf when it has none)."""
    lo, hi = c.parameters_ci95[par]
    if not (math.isfinite(lo) and math.isfinite(hi)):
        return math.inf
    return 0.5 * (hi - lo) / stat_factor(name, c)


def stat_factor(name: str, c: Candidate) -> float:
    """The statistical interval's coverage factor: Student's t over the fitted pulls (jackknife; n - 2 degrees of
    freedom for the friction's line through the pulls, friction.joint_ci), 1.96 (bootstrap)."""
    from scipy.stats import norm
    if name == 'coulomb_friction' and c.evidence.viscous_damping_n_s_per_m is not None:
        return t_quantile(c.ci_pulls - 1)
    return t_quantile(c.ci_pulls) if name in TERMS else float(norm.ppf(0.5 + CONFIDENCE / 2))


def rate_stat_u(name: str, c: Candidate) -> float:
    """The AC coupling's statistical u in its rate 1/tau (the interval is the rate's, inverted)."""
    lo, hi = c.parameters_ci95['time_constant_s']
    k_hi = 1.0 / lo if lo > 0 else math.inf
    k_lo = 1.0 / hi if (hi > 0 and math.isfinite(hi)) else 0.0
    return 0.5 * (k_hi - k_lo) / stat_factor(name, c) if math.isfinite(k_hi) else math.inf


def rate_scale(tau: float) -> float:
    """d(1/tau)/d(tau) in magnitude, 1/tau^2 (1 where tau is not a finite positive time: the rate's own unit)."""
    return 1.0 / (tau * tau) if (tau > 0 and math.isfinite(tau)) else 1.0


def expanded(q: float, u_stat: float, u_sys: float) -> float:
    """The expanded uncertainty U of a statistical part u_stat (its own interval factor q) and a combined
    systematic part u_sys (module doc): sqrt((q u_stat)^2 + (COVERAGE_FACTOR u_sys)^2)."""
    return math.sqrt((q * u_stat) ** 2 + (COVERAGE_FACTOR * u_sys) ** 2)


def honest(name: str, c: Candidate, systematic: Mapping[str, Mapping[str, float]], clock_rel: float) -> Candidate:
    """The candidate with every parameter's budget and the expanded interval (module doc). systematic:
    {parameter: {component: u}} in the parameter's unit; clock_rel: the sample clock's relative u. The AC coupling's
    interval is made in its rate k = 1/tau (u(k) = u(tau) / tau^2) and inverted, as its statistical one is."""
    budget, ci = {}, {}
    for par, est in c.parameters.items():
        sys_ = dict(systematic.get(par, {}))
        if (name, par) in TIME_PARAMETERS and clock_rel > 0:
            sys_['sample_clock'] = clock_rel * abs(est) if math.isfinite(est) else 0.0
        rate = name == 'ac_coupling'
        s = rate_scale(est) if rate else 1.0
        u_stat = rate_stat_u(name, c) / s if rate else statistical_u(name, c, par)
        u_sys = math.sqrt(sum(v * v for v in sys_.values()))
        U = expanded(stat_factor(name, c), u_stat, u_sys) * s
        lo, hi = c.parameters_ci95[par]
        if math.isfinite(U):
            if rate:
                k = 1.0 / est if (est > 0 and math.isfinite(est)) else 0.0
                lo = 1.0 / (k + U) if k + U > 0 else math.inf
                hi = 1.0 / (k - U) if k - U > 0 else math.inf
            else:
                lo, hi = est - U, est + U
        comps = {STATISTICAL: u_stat, **sys_}
        comps[COMBINED] = math.sqrt(sum(v * v for v in comps.values()))
        budget[par] = comps
        ci[par] = [float(lo), float(hi)]
    return dataclasses.replace(c, parameters_ci95=ci, uncertainty_budget=budget)


def honest_all(cand: Mapping[str, Candidate], systematic: Mapping[str, Mapping], clock_rel: float) -> dict:
    """honest() of every candidate (systematic: {name: {parameter: {component: u}}})."""
    return {n: honest(n, c, systematic.get(n, {}), clock_rel) for n, c in cand.items()}


class TermBudget(NamedTuple):
    """A coefficient's budget beyond the catalog (term_budget)."""

    budget: Dict[str, float]        # {component: standard uncertainty}, SI, with COMBINED
    ci95: Tuple[float, float]       # estimate +/- U on the scaled coefficient


def operating_range(fit: Sequence, idx: Sequence[int], col: int, u_stat: float) -> float:
    """A term's model-form line: the coefficient refitted (with the model's other product columns idx) on the first
    and on the second half of the fitted pulls (ChannelStats in campaign order: the sets by load, lower first). A
    term whose form is the physics' takes one coefficient at every load; a term that stands in for other physics
    takes another where the loads differ. u^2 = (c1 - c2)^2 / 4 less what the halves' statistics alone give
    (u_stat^2: each half's variance is about twice the whole campaign's), at least 0: a random effect, as
    load_dependence takes it."""
    pos = list(idx).index(col)
    half = len(fit) // 2
    c = []
    for part in (fit[:half], fit[half:]):
        G = sum(st.gram[np.ix_(idx, idx)] for st in part)
        b = sum(st.xy[idx] for st in part)
        c.append(float(np.linalg.lstsq(G, b, rcond=1e-12)[0][pos]))
    return halves_line(c[0], c[1], u_stat)


def term_budget(fit: Sequence, prod: Sequence[int], col: Optional[int], coef: float, ci: Tuple[float, float],
                si: float, relative: Optional[Tuple[str, float]],
                forms: Sequence[Tuple[str, float]] = ()) -> TermBudget:
    """One coefficient of a term beyond the catalog, its budget made as honest() makes the catalog's: the
    statistical part from the jackknife interval ci (its own Student factor); each systematic part the
    coefficient's shift when a rig constant is one standard uncertainty off (the residual's change, its normal
    equations ChannelStats.systematic per fitted pull, regressed on the model's product columns prod: the moving
    mass m2 on the moving cell, each drive constant on the motor current); the model-form line OPERATING_RANGE (a
    product term's coefficient on each half of the fitted pulls); relative: (component, relative u) of the
    channel's sensor calibration. fit: the fitted pulls' ChannelStats; col: the term's column (None: a sinusoid);
    si: the factor from the scaled coefficient to SI; forms: (component, u) of each more model-form line the caller
    measured (the motor current's: the coefficient's shift with the drive's damping, and with its k_F and reflected
    mass, fitted beside it)."""
    q = t_quantile(len(fit))
    u_stat = 0.5 * abs(ci[1] - ci[0]) / q
    sys_: Dict[str, float] = {}
    if col is not None and fit[0].systematic:
        idx = list(prod)
        pos = idx.index(col)
        Gs = sum(st.gram[np.ix_(idx, idx)] for st in fit)
        for comp in fit[0].systematic:
            bz = sum(st.systematic[comp][idx] for st in fit)
            sys_[comp] = abs(float(np.linalg.lstsq(Gs, bz, rcond=1e-12)[0][pos]))
    if col is not None and len(fit) >= 2 * HALF_PULLS:
        sys_[OPERATING_RANGE] = operating_range(fit, list(prod), col, u_stat)
    if relative is not None:
        comp, rel = relative
        sys_[comp] = rel * abs(coef)
    for comp, u in forms:
        sys_[comp] = abs(u)
    u_sys = math.sqrt(sum(v * v for v in sys_.values()))
    U = expanded(q, u_stat, u_sys)
    budget = {STATISTICAL: u_stat, **sys_}
    budget[COMBINED] = math.sqrt(sum(v * v for v in budget.values()))
    return TermBudget({k: v * abs(si) for k, v in budget.items()}, (coef - U, coef + U))


def clock_relative(rig) -> float:
    """The sample clock's relative standard uncertainty."""
    return rig.uncertainty.relative('daq.sample_rate_hz', rig.daq.sample_rate_hz)


def campaign_systematics(cand: dict, stats: list, fit, peaks, scales, m2: float, modes, rows, rows_v, delay: float,
                         joint: bool = False, hum_freqs: Sequence[float] = (), mode_variants: Sequence = (),
                         hum_form: Optional[Mapping] = None, drive: Optional[Tuple[float, ...]] = None) -> dict:
    """{cause: {parameter: {component: u}}}: the systematic parts of the budgets (module doc) from pass 3's variant
    statistics and load groups (the force model, at the campaign's delay), the free-decay modes and their analysis
    variants (the mount), the few pulls' own hum frequencies and the friction rows (joint: friction_stat's, with the
    viscous damping fitted; drive: friction_systematics')."""
    out: dict = {}
    vidx = [j for j in fit if stats[j].variants is not None]
    if vidx:
        def sub(get):
            return ForceStats([get(stats[j]) for j in vidx], [stats[j].dt for j in vidx], m2,
                              None if scales is None else [scales[j] for j in vidx])
        names = list(stats[vidx[0]].variants)
        fs = force_systematics(sub(lambda st: st.blocks), {n: sub(lambda st, n=n: st.variants[n]) for n in names},
                               range(len(vidx)), m2)
        u_stat = {t: {p: (rate_stat_u(t, cand[t]) if t == 'ac_coupling' else statistical_u(t, cand[t], p))
                      for p in cand[t].parameters} for t in TERMS}
        blocks, dts = [st.blocks for st in stats], [st.dt for st in stats]
        all_blocks = ForceStats(blocks, dts, m2, scales)
        ld = load_dependence(all_blocks, load_groups(fit, peaks), m2, u_stat, delay)
        mf = extra_systematics(lambda extra: ForceStats(blocks, dts, m2, scales, extra=extra), fit, m2)
        for t, params in fs.items():
            for p, comps in params.items():
                out.setdefault(t, {})[p] = {**comps, **mf[t][p], **({'load_dependence': ld[t][p]} if t in ld else {})}
    out.update(pull_to_pull_parts(cand, modes, hum_freqs, mode_variants))
    if 'mains_hum' in cand:   # the hum's model-form line (hum.hum_form_parts)
        for par, comps in (hum_form or {}).items():
            out.setdefault('mains_hum', {}).setdefault(par, {}).update(comps)
    if 'coulomb_friction' in cand and rows is not None and all(r is not None for r in rows_v):
        out['coulomb_friction'] = {'force_n': friction_systematics(rows, rows_v, partial(friction_stat, joint=joint),
                                                                   joint, drive)}
    return out


__all__ = ['COMBINED', 'DELAY_FORM_REFERENCE', 'DELAY_FORMS', 'DRIVE_CALIBRATION', 'DRIVE_MODEL', 'DRIVE_WINDOW',
           'HALF_PULLS', 'KIND', 'MODEL_FORM', 'OPERATING_RANGE', 'STATISTICAL', 'bessel_attenuation',
           'campaign_systematics',
           'cell_damping_u', 'cell_stiffness_u', 'clock_relative', 'delay_form', 'expanded', 'extra_systematics',
           'filter_delay', 'filter_form_parts', 'filter_form_preferred', 'force_systematics', 'force_variants',
           'friction_range', 'friction_systematics', 'friction_variants', 'honest', 'honest_all', 'load_dependence',
           'load_groups', 'mode_form_parts', 'operating_range', 'own_delay', 'pull_to_pull_parts', 'rate_scale',
           'rate_stat_u', 'statistical_u', 'term_budget', 'variant_pulls']
