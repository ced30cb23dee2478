"""Report, extension YAML and plots of the discovery (see discovery.py). ROS-free."""
from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Optional

import numpy as np

from force_tester_sim.core.departures import MOUNT_BASE_MASS_FRACTION

from . import quality as Q
from . import stages
from .decision import NONLIN_SHARE, Decision
from .force_model import TERMS, ForceModel, fit_terms
from .leftover import UNEXPLAINED_SHARE
from .prep import Pull
from .ringing import MOUNT_MAX_FRACTION, cell_modes, damped_basis, mount_from_observed
from .significance import MIN_REL_REDUCTION, MIN_T
from .stages import CATALOG_PARAMS, MIN_PULLS, Analysis
from .uncertainty import INCONCLUSIVE, WITHIN

FORCE_CHANNEL = ('mains_hum',) + TERMS
PLOT_FFT = 2 ** 15   # points of the residual spectra in residuals.png


def _clean(x):
    if isinstance(x, dict):
        return {str(k): _clean(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_clean(v) for v in x]
    if isinstance(x, (np.floating, float)):
        v = float(x)
        return v if math.isfinite(v) else None
    if isinstance(x, (np.integer,)):
        return int(x)
    if isinstance(x, np.bool_):
        return bool(x)
    return x


@dataclass(frozen=True)
class ErrorPart:
    """One held-out pull's force-channel residual, model of record (base) and extended (ext): what the report
    and the plots take from it (error_part)."""

    base_sse: float
    ext_sse: float
    samples: int                       # usable samples in W (masked ones count as zero residual and are left out)
    base_spectrum: np.ndarray          # |FFT|^2 of the residual (2^15 points), for the plot
    ext_spectrum: np.ndarray
    plot: Optional[dict] = None        # the residuals themselves ('pull', 't', 'dt', 'base', 'ext'), when kept


def error_part(p: Pull, base: np.ndarray, ext: np.ndarray, keep: bool = False) -> ErrorPart:
    """ErrorPart of held-out pull p from its residuals on W (ForceModel.resid), which it zeroes where masked;
    keep: keep the residuals for the plot."""
    bad = ~p.usable(p.w0, p.w1)    # masked (repaired) samples are no evidence: zero residual
    base[bad] = ext[bad] = 0.0
    spec = [np.abs(np.fft.rfft(r - r.mean(), PLOT_FFT)) ** 2 for r in (base, ext)]
    plot = {'pull': p.name, 't': p.t[p.w0:p.w1], 'dt': p.dt, 'base': base, 'ext': ext} if keep else None
    return ErrorPart(float(base @ base), float(ext @ ext), int((~bad).sum()), spec[0], spec[1], plot)


class ForceErrors:
    """The held-out force-channel errors, model of record and extended: error_part()s added up in pull order."""

    def __init__(self):
        self.base_sse, self.ext_sse, self.samples = [], [], 0
        self.base_spectrum = self.ext_spectrum = 0
        self.pulls = 0
        self.plot = None

    def add(self, part: ErrorPart) -> None:
        self.base_sse.append(part.base_sse)
        self.ext_sse.append(part.ext_sse)
        self.samples += part.samples
        self.base_spectrum = self.base_spectrum + part.base_spectrum
        self.ext_spectrum = self.ext_spectrum + part.ext_spectrum
        self.pulls += 1
        if self.plot is None and part.plot is not None:
            self.plot = part.plot

    def rms(self) -> tuple:
        """(baseline, extended) RMS over the usable samples."""
        return _rms(self.base_sse, self.samples), _rms(self.ext_sse, self.samples)


def force_errors(analysis: Analysis, named, rig) -> ForceErrors:
    """Held-out force-channel residual per pull: baseline (model of record) and extended (named causes)."""
    pulls, fit, held = analysis.pulls, analysis.fit, analysis.held
    m2 = rig.force_chain.m2
    fm0 = ForceModel(pulls, m2)
    fm1 = ForceModel(pulls, m2, analysis.hums if 'mains_hum' in named else None)
    terms = set(n for n in named if n in TERMS)
    coef, d = fit_terms(fm1, terms, fit)
    out = ForceErrors()
    for k, j in enumerate(held):
        out.add(error_part(pulls[j], fm0.resid(set(), {}, 0.0, j), fm1.resid(terms, coef, d, j), keep=k == 0))
    return out


def _where(n, c):
    p = c['parameters']
    if n == 'mains_hum':
        return (f'a spectral line at {p["frequency_hz"]:.2f} Hz on the moving cell, '
                'on the whole record (also with no load)')
    if n == 'mount_resonance':
        ev = c['evidence']
        return (f'accelerometer ringing at {ev["observed_frequency_hz"]:.0f} Hz '
                f'(zeta {ev["observed_damping_ratio"]:.3f}) '
                'after the taut instant and the break; '
                f'the model of record only has the {ev["cell_mode_hz"]:.0f} Hz cell mode')
    if n == 'coulomb_friction':
        return 'motor current offset while the carriage moves (sign of v3)'
    if n == 'ac_coupling':
        return ('moving cell undershoots after the load and decays with the time constant '
                '(correlates with the running integral of F_move)')
    if n == 'moving_cell_gain':
        return 'moving cell off by a fixed fraction of the tension during the quasi-static load (coupon flow)'
    if n == 'effective_mass':
        return 'residual proportional to a2 (the ringing at the elastic rise and the break)'
    if n == 'accel_delay':
        return 'residual proportional to da2/dt: a2 lags the forces (visible on the ringing at the rise and break)'
    return ''


def _rms(sses, n: int) -> float:
    """RMS from the per-pull sums of squares over the n samples they stand for."""
    return float(math.sqrt(sum(sses) / n))


def candidates(analysis: Analysis, decision: Decision) -> dict:
    """The analysis's candidates with the decision's verdicts filled in."""
    out = {}
    for n, c in analysis.candidates.items():
        c = {**c, 'evidence': dict(c['evidence'])}
        if n in decision.rejected:
            c['evidence']['rejected'] = decision.rejected[n]
        c['tolerance'] = decision.verdicts.get(n)
        out[n] = c
    return out


def _entry(n: str, c: dict) -> dict:
    """A candidate as listed in report.json: parameters, their 95 % intervals, the tolerance verdict."""
    return {'name': n, 'parameters': {k: float(c['parameters'][k]) for k in CATALOG_PARAMS[n]},
            'parameters_ci95': {k: [float(v) for v in c['parameters_ci95'][k]] for k in CATALOG_PARAMS[n]},
            'tolerance': c['tolerance']}


def build_report(analysis: Analysis, decision: Decision, errors: ForceErrors, left, rig) -> dict:
    """The report (JSON-ready). errors: force_errors() of the analysis and the named causes."""
    named = decision.named
    cand = candidates(analysis, decision)
    causes = []
    for n in named:
        c = cand[n]
        ev = dict(c['evidence'])
        causes.append({**_entry(n, c), 'evidence': ev, 'gain': ev.get('rms_gain'), 'channel': c['channel'],
                       'where': _where(n, c)})
    primary = named[0] if named else ('unexplained' if left and left['structured'] else 'none')
    if primary == 'unexplained':
        causes.append({'name': 'unexplained', 'parameters': {
            'dominant_frequency_hz': left['dominant_frequency_hz'], 'correlated_channel': left['correlated_channel'],
            'share_of_residual_variance': left['share_of_residual_variance']},
            'evidence': {'statistic': 'residual variance share above the quiet-record floor',
                         'value': left['share_of_residual_variance'], 'threshold': UNEXPLAINED_SHARE,
                         'rule': left['rule']}, 'gain': 1.0})
    if primary in ('mount_resonance', 'coulomb_friction') and not any(n in FORCE_CHANNEL for n in named):
        # RMS on the cause's own channel (held-out); no other channel changes
        metric = ('RMS on held-out pulls of ' + cand[primary]['channel'] + ' (per-pull amplitude/phase of the '
                  'modes fitted)' if primary == 'mount_resonance' else 'RMS on held-out pulls of the motor-current '
                  'residual (force balance), A')
        if primary == 'mount_resonance':
            baseline_error, extended_error = _ring_rms(analysis, rig)
        else:
            baseline_error, extended_error = _current_rms(analysis, rig, cand[primary]['parameters']['force_n'])
    else:
        baseline_error, extended_error = errors.rms()
        metric = ('RMS (N) on the held-out pulls of the moving-cell prediction residual F_move - F_pred over the '
                  'analysis window (50 ms before the load to 150 ms after the break); baseline F_pred = T + m2 a2 '
                  '(eq 21, T = F_stat + m1 a1, nominal m2, ideal sensors), extended: all named force-channel causes')
    report = {
        'cause': primary,
        'causes': causes,
        'baseline_error': baseline_error,
        'extended_error': extended_error,
        'gain': baseline_error / extended_error if extended_error > 0 else None,
        'metric': metric,
        'force_channel': dict(zip(('baseline_rms_n', 'extended_rms_n'), errors.rms())),
        'within_tolerance': [{**_entry(n, cand[n]), 'evidence': cand[n]['evidence']}
                             for n in decision.with_verdict(WITHIN)],
        'inconclusive': [{**_entry(n, cand[n]), 'evidence': cand[n]['evidence'],
                          'pulls_to_settle': cand[n]['tolerance'].get('pulls_to_settle')}
                         for n in decision.with_verdict(INCONCLUSIVE)],
        'tolerances': dataclasses.asdict(rig.tolerances),
        'fitted_pulls': analysis.fitted_pulls,
        'held_out_pulls': analysis.held_out_pulls,
        'significance_rule': (f'a candidate is named when, on the held-out pulls, removing it from the extended '
                              f'model raises the summed squared residual of its channel by >= '
                              f'{100 * MIN_REL_REDUCTION:g} % and the per-pull increases have t >= {MIN_T:g}, '
                              f'AND its 95 % interval (jackknife or bootstrap over pulls) lies wholly outside '
                              f'its tolerance band (rig tolerances:); inside the band it is within_tolerance, '
                              f'across an edge inconclusive; '
                              f'a mount mode must also lie below {MOUNT_MAX_FRACTION} x the cell mode; '
                              f'force-channel causes are withheld when a T^2 term removes > '
                              f'{100 * NONLIN_SHARE:g} % of the held-out force residual left by them'),
        'candidates': {n: {'parameters': c['parameters'], 'parameters_ci95': c['parameters_ci95'],
                           'tolerance': c['tolerance'], 'evidence': c['evidence'], 'channel': c['channel']}
                       for n, c in cand.items()},
        'leftover': left,
        'cell_damping': analysis.cells,
        'data_quality': quality_section(analysis),
        'notes': [*analysis.notes, *decision.notes],
        **run_section(analysis),
    }
    return _clean(report)


def run_section(analysis: Analysis) -> dict:
    """report.json: the pulls that could not be analysed (failed_pulls: name and why), those rerun after a worker
    died (retried_pulls), and where the per-pull stages ran (scheduler)."""
    return {'failed_pulls': [{'pull': n, 'error': e} for n, e in analysis.failed],
            'retried_pulls': list(analysis.retried), 'scheduler': analysis.scheduler or None}


def quality_section(analysis: Analysis) -> list:
    """report.json data_quality: every defect found, {pull, channel, kind, t_start_s, t_end_s, detail}, and one
    entry (kind 'excluded') per pull the screen left out."""
    rows = Q.defect_dicts(analysis.screens)
    for name, why in analysis.excluded.items():
        q = next(q for q in analysis.quality if q.name == name)
        rows.append({'pull': name, 'channel': Q.ALL, 'kind': 'excluded', 't_start_s': 0.0,
                     't_end_s': q.samples * q.dt, 'detail': why})
    return rows


def add_simulation(report: dict, check) -> None:
    """report.json simulation: {channel: {baseline_rms, extended_rms, gain}} from the re-simulation of the held-out
    pulls (None when no pull could be re-simulated), and simulation_check: how (pulls, ring frequency, damping)."""
    report['simulation'] = None if check is None else _clean(check.as_dict())
    report['simulation_check'] = None if check is None else _clean(check.details())


def unusable_report(analysis: Analysis, rig) -> dict:
    """The report when the data-quality stage leaves too few pulls: unexplained, data_quality says why."""
    return _clean({
        'cause': 'unexplained',
        'causes': [{'name': 'unexplained', 'parameters': {}, 'gain': None,
                    'evidence': {'statistic': 'pulls usable after the data-quality screen',
                                 'value': len(analysis.quality) - len(analysis.excluded), 'threshold': MIN_PULLS,
                                 'rule': 'defects leave too few pulls to fit and hold out; see data_quality'}}],
        'baseline_error': None, 'extended_error': None, 'gain': None, 'metric': 'none: no pulls to score',
        'within_tolerance': [], 'inconclusive': [], 'candidates': {}, 'leftover': None,
        'simulation': None, 'simulation_check': None,
        'tolerances': dataclasses.asdict(rig.tolerances), 'fitted_pulls': [], 'held_out_pulls': [],
        'data_quality': quality_section(analysis), 'notes': list(analysis.notes), **run_section(analysis)})


def _ring_rms(analysis: Analysis, rig):
    ring = analysis.ring
    b = e = n = 0.0
    for sb, se, ns in zip(ring['sse_base'], ring['sse_ext'], ring['samples']):
        b += sb
        e += se
        n += ns
    return math.sqrt(b / n), math.sqrt(e / n)


def _current_rms(analysis: Analysis, rig, fcf):
    fr = analysis.friction
    return math.sqrt(sum(fr['sse_base']) / sum(fr['samples'])), math.sqrt(sum(fr['sse_ext']) / sum(fr['samples']))


def named_extension(analysis: Analysis, decision: Decision, rig) -> dict:
    """extension() of the report build_report() will write, from the named causes alone (it needs nothing else
    of the report): the stream re-simulates with it before the report exists."""
    cand = candidates(analysis, decision)
    return extension(_clean({'causes': [_entry(n, cand[n]) for n in decision.named]}), rig)


def extension(report, rig) -> dict:
    """departures: the named causes as the sim's catalog takes them; correction: what correction_node undoes.

    The mount is identified as the mode seen in the measured channels; the sim's mount_resonance parameters
    are the mount's own, mapped from it through the carriage-mount-bracket-cell-m2 chain with an assumed
    bracket mass (stated in extension.yaml, key assumptions)."""
    deps = {c['name']: dict(c['parameters']) for c in report['causes'] if c['name'] in CATALOG_PARAMS}
    fc = rig.force_chain
    m2 = float(deps.get('effective_mass', {}).get('mass_kg', fc.m2))
    assumptions = {}
    if 'mount_resonance' in deps:
        obs = deps['mount_resonance']
        mb = MOUNT_BASE_MASS_FRACTION * m2
        f, z = mount_from_observed(obs['frequency_hz'], obs['damping_ratio'], m2, fc.load_cell_stiffness_n_per_m,
                                     fc.load_cell_damping_ratio, mb)
        deps['mount_resonance'] = {'frequency_hz': f, 'damping_ratio': z, 'base_mass_kg': mb}
        assumptions['mount_resonance'] = (
            f'observed mode {obs["frequency_hz"]:.2f} Hz, zeta {obs["damping_ratio"]:.4f} (the identified '
            f'quantities) mapped to the mount through the carriage-mount-bracket-cell-m2 chain with an assumed '
            f'bracket mass base_mass_kg = {MOUNT_BASE_MASS_FRACTION} x m2 = {mb:.4f} kg (not identifiable from '
            f'these channels); another bracket mass gives other mount parameters and the same observed mode')
    corr = {'mass_kg': m2,
            'accel_delay_s': float(deps.get('accel_delay', {}).get('delay_s', 0.0)),
            'moving_cell_gain': float(deps.get('moving_cell_gain', {}).get('gain', 1.0))}
    if 'ac_coupling' in deps:
        corr['ac_coupling_time_constant_s'] = deps['ac_coupling']['time_constant_s']
    if 'mains_hum' in deps:
        corr['mains_hum_hz'] = deps['mains_hum']['frequency_hz']
    out = {'departures': deps, 'correction': corr}
    if assumptions:
        out['assumptions'] = assumptions
    return out


def write_outputs(report, analysis: Analysis, errors: Optional[ForceErrors], named, rig, out: Path, check=None,
                  ext: dict | None = None) -> None:
    """Write DIR/extension.yaml, report.json, report.md and the plots (adds report['plots']). check: the
    simulation check (resim.SimulationCheck), whose kept pull is overlaid in simulation.png; ext: extension()
    of the report when the caller has it already.

    Everything is written into a fresh folder beside DIR first and moved in at the end, so a failure never
    leaves a half-written report."""
    import shutil
    import tempfile

    import yaml
    out.mkdir(parents=True, exist_ok=True)
    stage = Path(tempfile.mkdtemp(prefix='.discover-', dir=out))
    try:
        ext = extension(report, rig) if ext is None else ext
        head = ('# Extension found by `./ft discover`: the departures section below, appended to the nominal rig '
                'YAML,\n# reproduces the behaviour with load_rig; the correction section is what the correction node '
                'can undo\n# (the correction node and `./ft bag correct --extension` divide F_move by '
                'moving_cell_gain, undo the\n# AC coupling, notch the hum, delay F_move by accel_delay_s to line it '
                'up with a2, then subtract\n# mass_kg * a2). assumptions: what a mapping to the sim needed that the '
                'data do not identify.\n')
        (stage / 'extension.yaml').write_text(head + yaml.safe_dump(_clean(ext), sort_keys=False))
        plots = _plots(analysis, errors, named, rig, stage) + _simulation_plot(check, stage)
        report['plots'] = [str(out / Path(q).name) for q in plots]
        (stage / 'report.json').write_text(json.dumps(report, indent=1))
        (stage / 'report.md').write_text(markdown(report, report['plots'], analysis.screens, analysis.excluded))
        for f in sorted(stage.iterdir(), key=lambda q: q.name == 'report.json'):   # report.json last
            f.replace(out / f.name)
    finally:
        shutil.rmtree(stage, ignore_errors=True)


def _num(v) -> str:
    """A report number (None: the JSON form of an infinite bound)."""
    return 'inf' if v is None else f'{v:.5g}'


def _fmt_params(p):
    return ', '.join(f'{k} = {v:.4g}' if isinstance(v, (int, float)) else f'{k} = {v}' for k, v in p.items())


def markdown(r, plots, screens=(), excluded=None) -> str:
    if r['gain'] is None and not r['fitted_pulls']:
        return '\n'.join(['# Discovery report', '', f'**Primary cause: `{r["cause"]}`.** {r["notes"][0]}.', '']
                         + Q.markdown_lines(screens, excluded) + run_lines(r)) + '\n'
    L = ['# Discovery report', '',
         f'**Primary cause: `{r["cause"]}`.** Baseline error {r["baseline_error"]:.4g}, '
         f'extended {r["extended_error"]:.4g}, '
         f'gain {r["gain"]:.3g}x' if r['gain'] else f'**Primary cause: `{r["cause"]}`.**', '',
         f'Metric: {r["metric"]}.', '',
         f'Fitted on {len(r["fitted_pulls"])} pulls (every other pull: list positions 0, 2, 4, ...), '
         f'scored on {len(r["held_out_pulls"])} held-out pulls.',
         f'Moving-cell prediction residual (held-out, analysis window): {r["force_channel"]["baseline_rms_n"]:.3g} N '
         f'with the model of record, {r["force_channel"]["extended_rms_n"]:.3g} N with the extension.', '',
         '## What disagreed and the causes named (strongest first)', '']
    if not r['causes']:
        L.append('Nothing significant: the model of record explains the data to the noise floor.')
    for c in r['causes']:
        ev = c['evidence']
        ci = '; '.join(f'{k} in [{_num(lo)}, {_num(hi)}]' for k, (lo, hi) in c.get('parameters_ci95', {}).items())
        L.append(f'- **{c["name"]}**: {_fmt_params(c["parameters"])}' + (f' (95 %: {ci})' if ci else '')
                 + f'; channel: {c.get("channel", "force_moving_n")}; '
                 + (f'held-out SSE reduction {100 * ev["rel_sse_reduction"]:.2f} %, t = {ev["t"]:.1f} '
                    f'({ev["threshold"]}); gain {c["gain"]:.3g}x (held-out RMS without / with it). '
                    f'Where: {c.get("where", "")}' if 'rel_sse_reduction' in ev
                    else f'{ev["statistic"]}: {ev["value"]:.2f} (threshold {ev["threshold"]})'))
    L += ['', '## Departures within tolerance, and inconclusive ones', '']
    for kind, rows in (('within tolerance', r['within_tolerance']), ('inconclusive', r['inconclusive'])):
        for c in rows:
            v = c['tolerance']
            more = (f'; about {c["pulls_to_settle"]} pulls would settle it' if c.get('pulls_to_settle')
                    else '')
            L.append(f'- {c["name"]} ({kind}): {v["band"]["parameter"]} = {_num(v["estimate"])}, 95 % interval '
                     f'[{_num(v["ci95"][0])}, {_num(v["ci95"][1])}] against the band [{_num(v["band"]["lo"])}, '
                     f'{_num(v["band"]["hi"])}]{more}')
    if not (r['within_tolerance'] or r['inconclusive']):
        L.append('(none)')
    L += ['', '## Candidates ruled out', '']
    n_out = len(L)
    names = {c['name'] for c in r['causes'] + r['within_tolerance'] + r['inconclusive']}
    for n, c in r['candidates'].items():
        if n in names:
            continue
        ev = c['evidence']
        why = ev.get('rejected') or (f'held-out SSE reduction {100 * ev.get("rel_sse_reduction", 0):.3f} %, '
                                     f't = {ev.get("t", 0):.1f}: below {ev.get("threshold", "the rule")}')
        if n == 'mount_resonance' and 'observed_frequency_hz' in ev:
            why += (f'; dominant free-decay mode {ev["observed_frequency_hz"]:.0f} Hz (cell mode '
                    f'{ev["cell_mode_hz"]:.0f} Hz; {ev["frequency_rule"]})')
        L.append(f'- {n}: {why}')
    if len(L) == n_out:
        L.append('(none: every candidate passed)')
    for note in r['notes']:
        L.append(f'- note: {note}')
    L += [''] + Q.markdown_lines(screens, excluded) + run_lines(r)
    L += ['## Method', '', stages.__doc__.strip(), '', f'Significance rule: {r["significance_rule"]}.', '']
    L += simulation_lines(r)
    if r.get('leftover'):
        lo = r['leftover']
        L += ['## Residual left after the extension', '',
              f'share of residual variance above the quiet floor {lo["share_of_residual_variance"]:.2f}, dominant '
              f'frequency {lo["dominant_frequency_hz"]:.1f} Hz, most correlated with {lo["correlated_channel"]} '
              f'(|r| = {lo["correlation"]:.2f}).', '']
    if plots:
        L += ['## Plots', ''] + [f'![{Path(p).stem}]({Path(p).name})' for p in plots]
    else:
        L += ['(matplotlib not importable: no plots)']
    return '\n'.join(L) + '\n'


def run_lines(r) -> list:
    """report.md: the pulls that failed (by name, with why) or were rerun after a worker died, and where the
    per-pull stages ran."""
    failed, retried = r.get('failed_pulls') or [], r.get('retried_pulls') or []
    L = ['## Pulls not analysed, pulls rerun', '']
    if failed:
        L += [f'{len(failed)} pulls could not be read or analysed and are left out:', '']
        L += [f'- {f["pull"]}: {f["error"]}' for f in failed] + ['']
    if retried:
        L += [f'Rerun because the worker running them died (the results are the rerun\'s): {", ".join(retried)}.', '']
    if not (failed or retried):
        L += ['Every pull was read and analysed; none was rerun.', '']
    if r.get('scheduler'):
        L += [f'Per-pull stages ran on: {r["scheduler"]}.', '']
    return L


CHANNEL_LABELS = {'force_moving_n': ('moving cell', 'N'), 'force_stationary_n': ('stationary cell', 'N'),
                  'accel_axial_m_s2': ('accelerometer', 'm/s^2'), 'motor_current_a': ('motor current', 'A')}


def simulation_lines(r) -> list:
    """report.md: the simulator with and without the extension, against the measured held-out pulls."""
    sim, how = r.get('simulation'), r.get('simulation_check')
    L = ['## Closing the loop: the simulator with and without the extension', '']
    if not sim:
        return L + ['(no simulation check: see the notes)', '']
    L += [f'Each of the {len(how["pulls"])} held-out pulls re-simulated twice, driven by its measured carriage '
          'motion with its own slack, lanyard stiffness and coupon break fitted from its measured tension: with the '
          'model of record (baseline) and with the model of record plus extension.yaml (extended). RMS of measured '
          'minus simulated over the analysis window, after the discovery low-pass; gain = baseline / extended.', '',
          '| channel | baseline RMS | extended RMS | gain |', '|---|---|---|---|']
    for ch, v in sim.items():
        name, unit = CHANNEL_LABELS.get(ch, (ch, ''))
        L.append(f'| {name} | {v["baseline_rms"]:.4g} {unit} | {v["extended_rms"]:.4g} {unit} | '
                 + ('inf' if v['gain'] is None else f'{v["gain"]:.3g}') + 'x |')
    ring = how.get('ring')
    if ring:
        L += ['', (f'Mount ringing: measured {_num(ring["measured_hz"])} Hz, extended sim '
                   f'{_num(ring["extended_sim_hz"])} Hz ({100 * ring["rel_error"]:.2f} % off; tolerance '
                   f'{100 * ring["tolerance"]:g} %: {"met" if ring["within_tolerance"] else "NOT met"}).')
              if ring['measured_hz'] else 'Mount ringing: no free decay to compare.']
    cd = how.get('cell_damping') or {}
    if cd.get('pulls'):
        L += ['', f'Both sims use the cells\' damping ratio measured on {cd["pulls"]} pulls\' free decay, '
                  f'{cd["used"]:.4g} (the rig says {cd["rig"]:.4g}).']
    if how.get('skipped'):
        L += ['', 'Not re-simulated: ' + '; '.join(f'{k}: {v}' for k, v in how['skipped'].items())]
    return L + ['']


def _simulation_plot(check, out: Path) -> list:
    """simulation.png: measured, nominal-sim and extended-sim channels of one held-out pull, from the load to
    30 ms after the break."""
    if check is None or not check.trace:
        return []
    try:
        import matplotlib
        matplotlib.use('Agg')
        import matplotlib.pyplot as plt
    except ImportError:
        return []
    tr = check.trace
    chans = [ch for ch in CHANNEL_LABELS if ch in tr]
    t = tr['t']
    lo, hi = tr['focus_s']
    sel = (t >= lo) & (t <= hi)
    fig, axes = plt.subplots(len(chans), 1, figsize=(8, 2.2 * len(chans)), sharex=True, squeeze=False)
    for ax, ch in zip(axes[:, 0], chans):
        name, unit = CHANNEL_LABELS[ch]
        for kind, style in (('measured', dict(color='k', lw=0.8)), ('baseline', dict(color='tab:blue', lw=0.6)),
                            ('extended', dict(color='tab:orange', lw=0.6, ls='--'))):
            label = {'baseline': 'sim, model of record', 'extended': 'sim, with extension'}.get(kind, kind)
            ax.plot(1e3 * (t[sel] - lo), tr[ch][kind][sel], label=label, **style)
        ax.set_ylabel(f'{name}, {unit}')
    axes[0, 0].legend(fontsize=7)
    axes[0, 0].set_title(f'held-out pull {tr["pull"]}: measured and re-simulated')
    axes[-1, 0].set_xlabel('ms from 5 ms before the load')
    fig.tight_layout()
    path = out / 'simulation.png'
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return [str(path)]


def _plots(analysis: Analysis, errors: Optional[ForceErrors], named, rig, out: Path):
    try:
        import matplotlib
        matplotlib.use('Agg')
        import matplotlib.pyplot as plt
    except ImportError:
        return []
    if errors is None or errors.plot is None:
        return []
    pl = errors.plot
    fig, ax = plt.subplots(2, 1, figsize=(8, 6))
    ax[0].plot(pl['t'], pl['base'], lw=0.6, label='model of record')
    ax[0].plot(pl['t'], pl['ext'], lw=0.6, label='extended')
    ax[0].set_xlabel('time, s')
    ax[0].set_ylabel('F_move residual, N')
    ax[0].legend()
    ax[0].set_title(f'held-out pull {pl["pull"]}')
    for lab, P in (('model of record', errors.base_spectrum), ('extended', errors.ext_spectrum)):
        P = P / errors.pulls
        f = np.fft.rfftfreq(PLOT_FFT, pl['dt'])
        ax[1].semilogy(f[1:], P[1:], lw=0.6, label=lab)
    ax[1].set_xlabel('frequency, Hz')
    ax[1].set_ylabel('residual power')
    ax[1].legend()
    ax[1].set_xlim(0, 10000)
    fig.tight_layout()
    path = out / 'residuals.png'
    fig.savefig(path, dpi=90)
    plt.close(fig)
    paths = [str(path)]
    ring = analysis.ring
    if ring and 'mount_resonance' in named and ring.get('segment') is not None:
        fc = rig.force_chain
        seg, dt = ring['segment'], ring['segment_dt']
        tt = np.arange(len(seg)) * dt * 1e3
        fig, ax = plt.subplots(figsize=(8, 3.5))
        ax.plot(tt, seg, lw=0.6, label='measured a2 - a3 after the break')
        for lab, modes in (('model of record (cell mode)', cell_modes(fc)),
                           ('extended (mount mode)', cell_modes(fc) + [(ring['fo'], ring['zo'])])):
            X = np.hstack([damped_basis(len(seg), dt, f, z) for f, z in modes] + [np.ones((len(seg), 1))])
            c, *_ = np.linalg.lstsq(X, seg, rcond=None)
            ax.plot(tt, seg - X @ c, lw=0.6, label=f'residual, {lab}')
        ax.set_xlabel('ms after the break')
        ax.set_ylabel('m/s^2')
        ax.legend(fontsize=7)
        ax.set_title(f'held-out pull {ring["segment_pull"]}: free decay')
        fig.tight_layout()
        p2 = out / 'ringing.png'
        fig.savefig(p2, dpi=90)
        plt.close(fig)
        paths.append(str(p2))
    return paths
