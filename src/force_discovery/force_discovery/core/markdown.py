"""report.md: report.json told for a reader (markdown), with the data-quality section, the pulls not analysed, the
method and the simulation check. ROS-free."""
from __future__ import annotations

from pathlib import Path

from . import quality as Q
from . import stages
from .beyond.selection import NEAR_TIE
from .budget import COMBINED, KIND, MODEL_FORM
from .report import available


def _num(v) -> str:
    """A report number (None: the JSON form of an infinite bound)."""
    return 'inf' if v is None else f'{v:.5g}'


def _fmt_params(p):
    return ', '.join(f'{k} = {v:.4g}' if isinstance(v, (int, float)) else f'{k} = {v}' for k, v in p.items())


def rig_line(r) -> str:
    """report.md's line on the rig the data were judged against (report.json rig), on both paths."""
    rig = r['rig']
    return f'Rig: {rig["file"] or ("given" if rig["given"] else "none")}; {rig["what"]}.'


def markdown(r, plots, screens=(), excluded=None) -> str:
    if r['gain'] is None and not r['fitted_pulls']:
        return '\n'.join(['# Discovery report', '', f'**Primary cause: `{r["cause"]}`.** {r["notes"][0]}.', '']
                         + Q.markdown_lines(screens, excluded) + run_lines(r)) + '\n'
    L = ['# Discovery report', '',
         f'**Primary cause: `{r["cause"]}`.** Baseline error {r["baseline_error"]:.4g}, '
         f'extended {r["extended_error"]:.4g}, '
         f'gain {r["gain"]:.3g}x' if r['gain'] else f'**Primary cause: `{r["cause"]}`.**', '',
         f'Metric: {r["metric"]}.', '', rig_line(r), '',
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
    L += [''] + budget_lines(r) + Q.markdown_lines(screens, excluded) + run_lines(r)
    L += ['## Method', '', stages.__doc__.strip(), '', f'Significance rule: {r["significance_rule"]}.', '']
    L += simulation_lines(r) + beyond_lines(r)
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


def beyond_lines(r) -> list:
    """The search beyond the catalog (report.json beyond_catalog, beyond_search)."""
    if available(r, 'beyond_search') is None:
        return []
    b = r['beyond_search']
    at = ', '.join(f'{c} {f:.1f} Hz' for c, f in b['frequencies_hz'].items()) or 'no line in the residuals'
    L = ['## Beyond the catalog', '',
         f'A library of {b["library_terms"]} product terms and sinusoids (at {at}) '
         f'searched on {", ".join(b["channels"])}; {b["rule"]}.', '']
    for k, t in enumerate(r['beyond_catalog']):
        ev = t['evidence']
        plot = f' Before/after: beyond_{k + 1}.png.' if any(Path(p).name == f'beyond_{k + 1}.png'
                                                             for p in r.get('plots', ())) else ''
        f = f' at {t["frequency_hz"]:.2f} Hz' if t.get('frequency_hz') else ''
        L.append(f'- **{t["term"]}** on {t["channel"]}{f}: coefficient {_num(t["coefficient"])} {t["unit"]} '
                 f'(95 %: [{_num(t["ci95"][0])}, {_num(t["ci95"][1])}]); held-out SSE '
                 f'-{100 * ev["rel_sse_reduction"]:.2f} %, t = {ev["t"]:.1f}, gain {t["gain"]:.3g}x; contribution rms '
                 f'{_num(ev["contribution_rms"])} against the band {_num(ev["band"])}. Usually: '
                 f'{t["interpretation"]}.{plot}')
        if t.get('best_alternative'):
            alt = t['best_alternative']
            L.append(f'  It beat {alt["term"]}, the best other term in its place, by '
                     f'{100 * alt["held_out_margin"]:.2f} % of the held-out SSE.')
        if t.get('near_tied'):
            L.append(f'  The held-out pulls cannot tell it from {", ".join(t["near_tied"])} (within '
                     f'{100 * NEAR_TIE:g} % of its held-out reduction): read the term as one of these.')
        parts = [f'{k} {_num(v)}' for k, v in t.get('uncertainty_budget', {}).items()]
        if parts:
            L.append(f'  Standard uncertainties ({t["unit"]}): {", ".join(parts)}.')
    if not r['beyond_catalog']:
        L.append('No term of the library explains what the catalog leaves.')
    for t in b['within_tolerance']:
        L.append(f'- {t["term"]} on {t["channel"]} (significant, within the band): coefficient '
                 f'{_num(t["coefficient"])} {t["unit"]}, contribution rms {_num(t["evidence"]["contribution_rms"])}'
                 + (f'; near-tied: {", ".join(t["near_tied"])}' if t.get('near_tied') else ''))
    for n, why in b['catalog_not_fitting'].items():
        L.append(f'- catalog cause {n} withheld: {why}')
    for n, c in (b.get('catalog_checked') or {}).items():
        L.append(f'- catalog cause {n} kept: the library in its place ({c["library_instead"]}, '
                 f'{c["library_parameters"]} parameter(s) against {c["model_parameters"]}) leaves '
                 f'{100 * c["held_out_margin"]:.1f} % more of the held-out SSE')
    if b.get('identifiability'):
        L.append(f'- {len(b["identifiability"])} (channel, term) pairs of the grammar cannot be identified here '
                 '(report.json beyond_search.identifiability lists each with its reason)')
    return L + ['']


def budget_lines(r) -> list:
    """report.md: every candidate parameter's uncertainty budget (report.json uncertainty_budget) as one table, the
    components summed in quadrature by kind (budget.KIND), standard uncertainties (k = 1)."""
    kinds = list(dict.fromkeys(KIND.values()))
    L = ['## Uncertainty budgets', '',
         'Standard uncertainties (k = 1) by kind, each kind the quadrature sum of its components; the 95 % '
         'intervals are the estimate +/- sqrt((q u_statistical)^2 + (2 u_systematic)^2) (q: the statistical '
         'interval\'s own factor). Largest: the largest component.', '',
         '| cause | parameter | estimate | ' + ' | '.join(kinds) + ' | combined | largest | 95 % interval |',
         '|---' * (len(kinds) + 6) + '|']
    for n, params in r.get('uncertainty_budget', {}).items():
        c = r['candidates'][n]
        for par, comps in params.items():
            per = {k: 0.0 for k in kinds}
            for comp, u in comps.items():
                if comp in KIND and u is not None:
                    per[KIND[comp]] += u * u
            parts = [k for k in comps if k in KIND and comps[k] is not None]
            big = max(parts, key=lambda k: comps[k]) if parts else '-'
            lo, hi = c['parameters_ci95'][par]
            L.append(f'| {n} | {par} | {_num(c["parameters"][par])} | '
                     + ' | '.join(f'{v ** 0.5:.3g}' for v in per.values())
                     + f' | {_num(comps.get(COMBINED))} | {big} | [{_num(lo)}, {_num(hi)}] |')
    form = [f'- {n}.{par}: ' + ', '.join(f'{k} {_num(u)}' for k, u in comps.items()
                                           if KIND.get(k) == MODEL_FORM and u is not None)
            for n, params in r.get('uncertainty_budget', {}).items() for par, comps in params.items()
            if any(KIND.get(k) == MODEL_FORM for k in comps)]
    if form:
        L += ['', 'The model-form lines, each by name (the analysis variants the estimate moves under; '
              'discovery-uncertainty.md):', ''] + form
    return L + ['']


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
    if how.get('terms_resimulated'):
        L += ['', 'Terms beyond the catalog in the extended sim: '
              + '; '.join(f'{e["term"]} on {e["channel"]}: {e["how"]}' for e in how['terms_resimulated']) + '.']
    if how.get('skipped'):
        L += ['', 'Not re-simulated: ' + '; '.join(f'{k}: {v}' for k, v in how['skipped'].items())]
    return L + ['']
