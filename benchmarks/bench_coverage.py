"""Coverage of `discover`'s 95 % intervals: how often `parameters_ci95` holds the true value, and how
wide the intervals are against each parameter's tolerance.

    ./ft bench coverage [--trials N] [--variants NAME,...] [--causes NAME,...] [--seed S]

Campaigns (3 sets x 4 pulls) are simulated with ONE hidden catalog effect (tests/force_discovery/generator.py's
plausible ranges) on five rigs: the nominal one, a heavier one (m1, m2 x 1.6), a stiffer chain (cells and lanyard
x 2), a softer one (x 0.5) and a 25 kHz DAQ. On every rig the constants the simulator uses are drawn once per
campaign within their stated standard uncertainty (rig.uncertainty, clipped at 2 u), and every other campaign
goes through the model-form nuisances (cells and lanyard 2-4x damped, an anti-alias filter, 1/f noise, 16-bit
samples, departures within tolerance). `discover` is given only the data and that rig's YAML (its nominal
constants, no departures); the truth stays here.

Counted: the hidden effect's parameters and the force model's gain, effective mass and accelerometer delay
(always fitted; their truth is the departure's value or the rig's). For the mount the truth is the mode the
accelerometer sees (generator.observed_mount_mode on the rig that made the data). Usefulness: each interval's
half-width over its parameter's tolerance (the rig's tolerance band where the parameter has one, else the
generator's identification tolerance).
"""
from __future__ import annotations

import argparse
import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / 'tests' / 'force_discovery'), str(ROOT / 'tests')]   # the test generator, its timing

import generator as G  # the generator
import independent_cases as IG  # beside this script: --generator

from force_discovery.core.pipeline import discover
from force_tester_common.core.correction import MASS_KG
from force_tester_sim.core.campaign import truth_pull_specs
from force_tester_sim.core.params import NOMINAL_YAML, rig_from_dict
from force_tester_sim.core.simulate import simulate_pull
from force_tester_sim.core.tolerances import band

VARIANTS = {
    'nominal': {},
    'heavy': {'force_chain': {'stationary_side_mass_kg': 1.6, 'moving_side_mass_kg': 1.6}},
    'stiff': {'force_chain': {'load_cell_stiffness_n_per_m': 2.0, 'lanyard_stiffness_n_per_m': 2.0}},
    'soft': {'force_chain': {'load_cell_stiffness_n_per_m': 0.5, 'lanyard_stiffness_n_per_m': 0.5}},
    '25kHz': {'daq': {'sample_rate_hz': 0.5}},
}
# the constants the simulator uses that the analysis takes from the rig YAML: drawn within their uncertainty
PERTURBED = ('force_chain.stationary_side_mass_kg', 'force_chain.moving_side_mass_kg',
             'force_chain.load_cell_stiffness_n_per_m', 'force_chain.load_cell_damping_ratio',
             'drive.torque_constant_nm_per_a', 'drive.pulley_radius_m', 'drive.actuator_inertia_kg_m2',
             'drive.motor_inertia_kg_m2', 'drive.viscous_damping_motor_n_s_per_m',
             'drive.viscous_damping_actuator_n_s_per_m')
ALWAYS = {'moving_cell_gain': 'gain', 'effective_mass': 'mass_kg', 'accel_delay': 'delay_s'}




def variant_data(name: str) -> dict:
    """The rig YAML (a dict) of a rig variant: the nominal one with some constants scaled, no departures."""
    data = yaml.safe_load(NOMINAL_YAML.read_text())
    data.pop('departures', None)
    data.pop('uncertainty', None)   # the default fractions: a stiffer rig's uncertainty scales with it
    for section, keys in VARIANTS[name].items():
        for key, factor in keys.items():
            data[section][key] = data[section][key] * factor
    return data


def scaled_effect(name: str, truth: dict, m2: float) -> dict:
    """The generator's draw, with masses in proportion to the rig's m2 (its ranges are for the nominal 1.152 kg)."""
    out = dict(truth)
    if name == 'effective_mass':
        out['mass_kg'] = truth['mass_kg'] * m2 / MASS_KG
    if name == 'mount_resonance':
        out['base_mass_kg'] = truth['base_mass_kg'] * m2 / MASS_KG
    return out


def true_rig(data: dict, analysis_rig, seed: int, departures: dict, nuisance) -> tuple:
    """(the rig that makes the data, its YAML dict): constants drawn within their uncertainty, the departures,
    the nuisance's damping."""
    rng = np.random.default_rng([seed, 0xC0FFEE])
    d = yaml.safe_load(yaml.safe_dump(data))
    u = analysis_rig.uncertainty
    for key in PERTURBED:
        section, name = key.split('.')
        d[section][name] = float(d[section][name] + np.clip(rng.standard_normal(), -2, 2) * u.u(key))
    if nuisance is not None:
        d['force_chain']['load_cell_damping_ratio'] *= nuisance['cell_damping_factor']
        d['force_chain']['lanyard_damping_ratio'] *= nuisance['lanyard_damping_factor']
    if departures:
        d['departures'] = departures
    return rig_from_dict(d), d


def make_campaign(rig, seed: int, nuisance) -> list:
    out = []
    for s in G.SETS:
        ts = rig.test_set(s)
        for sp in truth_pull_specs(rig, s, G.PULLS, seed):
            ch = simulate_pull(rig, sp)
            if nuisance is not None:
                ch = G.daq_nuisances(ch, nuisance, sp.seed)
            out.append(({'file': f'set{s}_pull{sp.pull + 1:02d}.csv', 'set': s, 'pull': sp.pull + 1,
                         'coupon_lbf': ts.coupon_lbf, 'velocity_fps': ts.velocity_fps, 'decel_g': ts.decel_g}, ch))
    return out


def truths(name: str, effect: dict, deps: dict, gen_rig) -> dict:
    """{(cause, parameter): true value} of what this campaign's report is scored on."""
    out = {('moving_cell_gain', 'gain'): deps.get('moving_cell_gain', {}).get('gain', 1.0),
           ('effective_mass', 'mass_kg'): deps.get('effective_mass', {}).get('mass_kg', gen_rig.force_chain.m2),
           ('accel_delay', 'delay_s'): deps.get('accel_delay', {}).get('delay_s', 0.0)}
    if name == 'mount_resonance':
        f, z = G.observed_mount_mode(gen_rig)
        out[(name, 'frequency_hz')] = f
        out[(name, 'damping_ratio')] = z
    elif name not in ALWAYS:
        for k, v in effect.items():
            out[(name, k)] = v
    return out


def tolerance(cause: str, par: str, rig, truth: float) -> float:
    """The half-width of the parameter's tolerance: its band's (centred on the model of record), else the
    generator's identification tolerance."""
    b = band(cause, rig.tolerances, rig.force_chain.m2)
    if b.parameter == par and math.isfinite(b.hi) and (cause not in ('mains_hum', 'coulomb_friction', 'accel_delay')
                                                        or b.lo <= 0.0):
        return 0.5 * (b.hi - b.lo) if b.lo > 0 else b.hi
    rel, ab = G.TOLERANCE[par]
    return max(rel * abs(truth), ab)


def score(label: str, rep: dict, truths: dict, rig) -> list:
    """One campaign's rows (cause, parameter, inside, half-width, half-width / tolerance), printed as they come."""
    cands, rows = rep['candidates'], []
    for (cause, par), truth in truths.items():
        c = cands.get(cause)
        if c is None or par not in c['parameters_ci95']:
            print(f'{label:<32} {cause:<18} {par:<14} {truth:12.6g}  not reported', flush=True)
            rows.append((cause, par, False, math.inf, math.inf))
            continue
        lo, hi = c['parameters_ci95'][par]
        lo, hi = (-math.inf if lo is None else lo), (math.inf if hi is None else hi)   # None: infinite
        est = math.inf if c['parameters'][par] is None else c['parameters'][par]   # None: infinite
        half = 0.5 * (hi - lo)
        tol = tolerance(cause, par, rig, truth)
        inside = lo <= truth <= hi
        rows.append((cause, par, inside, half, half / tol))
        print(f'{label:<32} {cause:<18} {par:<14} {truth:12.6g} {est:12.6g} {half:11.3g} '
              f'{half / tol:6.2f}  {"yes" if inside else "NO"}', flush=True)
    return rows


def own_rows(a, causes, variants, tmp) -> list:
    """The own generator's campaigns: every rig variant x every hidden catalog effect."""
    rows = []
    n_camp = len(variants) * len(causes) * a.trials
    k = done = 0
    for var in variants:
        data = variant_data(var)
        rig = rig_from_dict(data)
        for name in sorted(G.PLAUSIBLE):
            for trial in range(a.trials):
                seed = a.seed + 100 * trial + k
                k += 1
                if name not in causes:
                    continue
                done += 1
                effect = scaled_effect(name, G.draw(name, seed), rig.force_chain.m2)
                nuisance = G.draw_nuisance(seed, within_tolerance=True) if k % 2 else None
                if nuisance is not None:   # the anti-alias corner scales with the sample rate (15-22 kHz at 50 kHz)
                    nuisance['anti_alias_hz'] *= rig.daq.sample_rate_hz / 50000.0
                    m = nuisance['departures']['effective_mass']['mass_kg']
                    nuisance['departures']['effective_mass']['mass_kg'] = m * rig.force_chain.m2 / MASS_KG
                deps = {**(nuisance['departures'] if nuisance else {}), name: effect}
                gen_rig, _ = true_rig(data, rig, seed, deps, nuisance)
                camp = make_campaign(gen_rig, seed, nuisance)
                rep = discover(camp, rig, tmp / f'{var}_{name}_{trial}', scheduler='inline', plots=False)
                label = f'{var}/{name}{"+nuis" if nuisance else ""} ({done}/{n_camp})'
                rows += score(label, rep, truths(name, effect, deps, gen_rig), rig)
    return rows


def independent_rows(a, causes, tmp) -> list:
    """The independent generator's campaigns: every hidden catalog effect it has, on a rig it draws per seed (the
    datasheet, not the truth, is what `discover` is given)."""
    rows = []
    names = [c for c in sorted(IG.CATALOG) if c in causes]
    n_camp = len(names) * a.trials
    done = 0
    for name in names:
        for trial in range(a.trials):
            seed = a.seed + 100 * trial + sorted(IG.CATALOG).index(name)
            done += 1
            c = IG.case(seed, [{'name': name}])
            rep = discover(c.campaign, c.rig, tmp / f'independent_{name}_{trial}', scheduler='inline', plots=False)
            rows += score(f'independent/{name} ({done}/{n_camp})', rep, IG.catalog_truths(c.truth), c.rig)
    return rows


def summary(rows: list) -> dict:
    """{(cause, parameter): (n, covered, median half-width / tolerance)} and the totals under None."""
    out = {}
    for key in sorted({(r[0], r[1]) for r in rows}):
        sel = [r for r in rows if (r[0], r[1]) == key]
        out[key] = (len(sel), sum(r[2] for r in sel), float(np.median([r[4] for r in sel])))
    if rows:
        out[None] = (len(rows), sum(r[2] for r in rows), float(np.median([r[4] for r in rows])))
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--trials', type=int, default=1, help='campaigns per catalog entry and rig (default 1)')
    ap.add_argument('--variants', default=','.join(VARIANTS), help=f'rigs, comma-separated (default all: '
                    f'{",".join(VARIANTS)}); the own generator\'s (the independent one draws a rig per seed)')
    ap.add_argument('--causes', default=','.join(sorted(G.PLAUSIBLE)), help=f'hidden catalog effects, '
                    f'comma-separated (default all: {",".join(sorted(G.PLAUSIBLE))}); a subset keeps the seeds and '
                    f'nuisances the full run gives those campaigns')
    ap.add_argument('--seed', type=int, default=5000, help='first campaign seed (default 5000)')
    IG.add_option(ap)
    a = ap.parse_args()
    causes = [c for c in a.causes.split(',') if c]
    bad = [c for c in causes if c not in G.PLAUSIBLE]
    if bad:
        raise SystemExit(f'bench_coverage: error: unknown cause(s) {bad}; expected some of {sorted(G.PLAUSIBLE)}')
    variants = [v for v in a.variants.split(',') if v]
    bad = [v for v in variants if v not in VARIANTS]
    if bad:
        raise SystemExit(f'bench_coverage: error: unknown rig variant(s) {bad}; expected some of {list(VARIANTS)}')
    tmp = Path(tempfile.mkdtemp(prefix='bench_coverage_'))
    t0 = time.perf_counter()
    print(f'{"campaign":<32} {"cause":<18} {"parameter":<14} {"truth":>12} {"estimate":>12} {"half-width":>11} '
          f'{"/tol":>6}  in', flush=True)
    rows = {}
    for gen in IG.chosen(a.generator):
        rows[gen] = own_rows(a, causes, variants, tmp) if gen == 'own' else independent_rows(a, causes, tmp)
    wall = time.perf_counter() - t0
    sums = {gen: summary(r) for gen, r in rows.items()}
    print()
    head = ''.join(f'  {gen + ": n covered  median half-width/tol":>40}' for gen in sums)
    print(f'{"parameter":<34}{head}')
    for key in sorted({k for s in sums.values() for k in s if k is not None}):
        cells = ''
        for s in sums.values():
            n, cov, med = s.get(key, (0, 0, math.nan))
            cells += f'  {n:>9} {cov:>4}/{n:<3} {med:>22.3g}' if n else f'  {"-":>40}'
        print(f'{key[0] + "." + key[1]:<34}{cells}')
    for gen, r in rows.items():
        if not r:
            continue
        n, cov, med = sums[gen][None]
        useful = sum(x[4] < 1.0 for x in r)
        wide = [f'{k[0]}.{k[1]}' for k, v in sums[gen].items() if k is not None and v[2] > 0.5]
        print(f'{gen} generator: coverage {cov}/{n} = {100 * cov / n:.0f} % of 95 % intervals hold the truth '
              f'(target >= 90 % over >= 100); median half-width / tolerance {med:.2f} ({useful}/{n} below 1; '
              f'target <= 0.5 for every parameter: {", ".join(wide) + " above" if wide else "met"})')
    print(f'{wall:.0f} s')
    return 0


if __name__ == '__main__':
    sys.exit(main())
