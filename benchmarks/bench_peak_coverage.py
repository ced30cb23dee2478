"""Benchmark: does each pull's corrected peak +/- U (k = 2) hold the truth? (./ft bench peak_coverage)

    ./ft bench peak_coverage [--pulls N] [--nuisance-seeds M] [--drawn-seeds D] [--no-reference] [--json FILE]
                             [--generator own|independent|both] [--independent-seeds I]

Campaigns (the code under test, the correction and force_correction.core.peak_uncertainty, sees only the data,
the rig YAML as a user states it and, for the reference campaign, the extension.yaml `./ft discover` found on
it; never the truth):
  - reference: the truth reference rig's campaign (the one `./ft demo` discovers, seed 2013), its first N pulls
    of each set, corrected with that extension;
  - nuisance: the discovery tests' generator (tests/force_discovery/generator.py): the nominal rig with cell and
    lanyard 2-4x damped, a common anti-alias filter, 1/f noise, 16-bit samples and a moving-cell gain and m2
    off by up to 0.25 % / 0.8 %; corrected with the nominal rig;
  - drawn: nominal rigs whose true gain, m2 and accelerometer lag are drawn from the uncertainties the rig YAML
    states (the inputs of U): a U that covers these ~95 % of the time is as small as the inputs allow;
  - heavy_25khz: another rig, m2 = 2.0 kg (1.7x) sampled at 25 kHz; corrected with that rig's YAML.
  (these four are the own generator's: force_tester_sim, the physics the correction was shaped on)
  - independent (--generator independent|both): tests/independent's campaigns (benchmarks/independent_cases.py),
    physics written apart from ours, on a rig drawn per seed (m2 0.8-1.6 kg, cells x0.5-2, 10-100 kHz, a real
    DAQ chain), one pull of each set, no departure; corrected with that rig's datasheet as the rig YAML.
For each pull: P the corrected peak, U its expanded uncertainty, and three references:
  - T: the lanyard tension's peak (the sim's truth, read by this script only): what eq 24 estimates;
  - S: the stationary cell's peak, as measured. The stationary cell reads T - m1 a1, not T: m1 rings on its
    cell (~4 kHz) and its peak overshoots T's by up to 8 % on a nominal rig. |P - S| <= U then fails for reasons
    that are not the correction's;
  - S + m1 a1: the stationary cell corrected to the tension with the rig's nominal m1 and cell stiffness
    (a1 = F_stat'' / k1), with its own expanded uncertainty U_s (m1 and k1 within the rig's u, the noise of
    the second difference); a pull counts when |P - peak(S + m1 a1)| <= sqrt(U^2 + U_s^2).
Printed: per campaign and in all, the pulls, each coverage, median U in lbf and in % of the peak.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
from pathlib import Path

import numpy as np
import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / 'tests' / 'force_discovery'), str(ROOT / 'tests')]   # the test generator, its timing

import generator as G  # the generator
import independent_cases as IG  # beside this script: --generator

from force_correction.core.extension import Extension, ForcePrefilter
from force_correction.core.params import CorrectionParams
from force_correction.core.peak_uncertainty import peak_uncertainty
from force_correction.core.streaming import correct_signal
from force_tester_common.core.units import LBF_N
from force_tester_sim.core.campaign import campaign_specs, truth_pull_specs
from force_tester_sim.core.params import NOMINAL_YAML, TRUTH_YAML, load_rig
from force_tester_sim.core.pull import run_pull
from ft_cli.peak_inputs import peak_inputs

SETS = (1, 2, 3, 4, 5)


def stationary_tension(fs: np.ndarray, rate: float, rig) -> tuple:
    """(S + m1 a1 at every sample, its standard uncertainty at each sample): a1 = F_stat'' / k1 (the stationary
    cell's own spring; its damping is small), from the rig YAML's nominal m1, k1 and their u."""
    fc, unc = rig.force_chain, rig.uncertainty
    m1, k1 = fc.stationary_side_mass_kg, fc.load_cell_stiffness_n_per_m
    d2 = np.zeros_like(fs)
    d2[1:-1] = (fs[2:] - 2 * fs[1:-1] + fs[:-2]) * rate * rate
    m1a1 = m1 * d2 / k1
    rel = math.hypot(unc.relative('force_chain.stationary_side_mass_kg', m1),
                     unc.relative('force_chain.load_cell_stiffness_n_per_m', k1))
    quiet = fs[:int(0.05 * rate)]
    noise = float(np.std(np.diff(quiet)) / math.sqrt(2))     # the cell's noise sigma
    noise_d2 = noise * math.sqrt(6.0) * rate * rate * m1 / k1  # of the second difference, scaled
    return fs + m1a1, np.hypot(rel * np.abs(m1a1), math.hypot(noise, noise_d2))


def score(rig_seen, ext: Extension, inputs, ch: dict, truth_t: np.ndarray, m2: float) -> dict:
    rate = 1.0 / float(ch['time_s'][1] - ch['time_s'][0])
    force = ForcePrefilter(ext, rate).process(np.asarray(ch['force_moving_n'], float))
    out = correct_signal(force, np.asarray(ch['accel_axial_m_s2'], float), CorrectionParams(mass_kg=m2))
    pu = peak_uncertainty(out.corrected_n, out.inertial_n, out.filtered_n, rate, inputs)
    fs = np.asarray(ch['force_stationary_n'], float)
    ts, u_ts = stationary_tension(fs, rate, rig_seen)
    j = int(np.argmax(ts))
    return {'P': pu.peak_n, 'U': pu.expanded_n, 'T': float(np.max(truth_t)), 'S': float(np.max(fs)),
            'ST': float(ts[j]), 'U_ST': 2.0 * float(u_ts[j]), 'ma_cut': pu.ma_cut_n, 'U_f': pu.filtered_expanded_n,
            'F': float(np.nanmax(out.filtered_n))}


def reference(pulls: int, say) -> list:
    from ft_cli.commands.thesis import REFERENCE_PULLS, REFERENCE_SEED, reference_extension
    ext_file = reference_extension(REFERENCE_PULLS, REFERENCE_SEED, say=say)
    truth_rig, nominal = load_rig(TRUTH_YAML), load_rig(NOMINAL_YAML)
    ext = Extension.from_yaml(ext_file)
    m2 = ext.mass_kg if ext.mass_kg is not None else nominal.force_chain.moving_side_mass_kg
    inputs = peak_inputs(nominal, ext_file)
    specs = [sp for sp in campaign_specs(truth_rig, SETS, REFERENCE_PULLS, REFERENCE_SEED) if sp.pull < pulls]
    rows = []
    for sp in specs:
        r = run_pull(truth_rig, sp)   # the same pull the cached campaign holds (its own seed)
        rows.append(score(nominal, ext, inputs, r.channels, r.truth['tension_n'], m2))
    return rows


def nuisance(seeds: int, pulls: int) -> list:
    nominal = load_rig(NOMINAL_YAML)
    inputs = peak_inputs(nominal)
    fc = yaml.safe_load(NOMINAL_YAML.read_text())['force_chain']
    rows = []
    for seed in range(seeds):
        nz = G.draw_nuisance(seed)
        rig = G.rig_with(nz['departures'], {
            'load_cell_damping_ratio': fc['load_cell_damping_ratio'] * nz['cell_damping_factor'],
            'lanyard_damping_ratio': fc['lanyard_damping_ratio'] * nz['lanyard_damping_factor']})
        for s in G.SETS:
            for sp in truth_pull_specs(rig, s, pulls, seed):
                r = run_pull(rig, sp)
                ch = G.daq_nuisances(r.channels, nz, sp.seed)
                rows.append(score(nominal, Extension(), inputs, ch, r.truth['tension_n'],
                                  nominal.force_chain.moving_side_mass_kg))
    return rows


def drawn(seeds: int) -> list:
    """Rigs whose true constants are drawn from the nominal rig's stated uncertainties (what U claims to cover):
    the moving cell's gain ~ N(1, u_gain), m2 ~ N(m2, u_m2 (+) u_accel_sensitivity) (an accelerometer reading
    (1 + e) a is an m2 off by e in m*a; the catalog has no accelerometer gain of its own), the accelerometer's
    lag ~ uniform within the rig's tolerance band. Corrected with the nominal rig, as a user would."""
    nominal = load_rig(NOMINAL_YAML)
    inputs = peak_inputs(nominal)
    m2 = nominal.force_chain.moving_side_mass_kg
    rows = []
    for seed in range(seeds):
        r = np.random.default_rng([seed, 0x9EA4])
        deps = {'moving_cell_gain': {'gain': 1.0 + inputs.gain_rel * r.standard_normal()},
                'effective_mass': {'mass_kg': m2 * (1.0 + math.hypot(inputs.mass_rel, inputs.accel_sensitivity_rel)
                                                    * r.standard_normal())},
                'accel_delay': {'delay_s': r.uniform(0.0, nominal.tolerances.accel_delay_s)}}
        rig = G.rig_with(deps)
        for sp in campaign_specs(rig, SETS, 1, seed):   # one pull a set: the draws, not the pulls, vary most
            res = run_pull(rig, sp)
            rows.append(score(nominal, Extension(), inputs, res.channels, res.truth['tension_n'], m2))
    return rows


def heavy_25khz(pulls: int) -> list:
    data = yaml.safe_load(NOMINAL_YAML.read_text())
    data['force_chain']['moving_side_mass_kg'] = 2.0
    data['daq']['sample_rate_hz'] = 25000
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / 'heavy_25khz.yaml'
        path.write_text(yaml.safe_dump(data))
        rig = load_rig(path)
    inputs = peak_inputs(rig)
    rows = []
    for sp in campaign_specs(rig, SETS, pulls, 7):
        r = run_pull(rig, sp)
        rows.append(score(rig, Extension(), inputs, r.channels, r.truth['tension_n'],
                          rig.force_chain.moving_side_mass_kg))
    return rows


def independent(seeds: int) -> list:
    rows = []
    for seed in range(seeds):
        c = IG.case(7000 + seed, [], pulls=len(SETS), sets=SETS)
        inputs = peak_inputs(c.rig)
        for (_meta, ch), peak in zip(c.campaign, IG.pull_tensions(c.truth)):
            rows.append(score(c.rig, Extension(), inputs, ch, np.array([peak]), c.rig.force_chain.moving_side_mass_kg))
    return rows


def summary(rows: list) -> dict:
    n = len(rows)
    if not n:
        return {'pulls': 0}
    cover = lambda ok: 100.0 * sum(ok) / n
    return {'pulls': n,
            'coverage_tension_pct': cover([abs(r['P'] - r['T']) <= r['U'] for r in rows]),
            'coverage_stationary_pct': cover([abs(r['P'] - r['S']) <= r['U'] for r in rows]),
            'coverage_stationary_m1a1_pct': cover([abs(r['P'] - r['ST']) <= math.hypot(r['U'], r['U_ST'])
                                                   for r in rows]),
            'coverage_filtered_tension_pct': cover([abs(r['F'] - r['T']) <= r['U_f'] for r in rows]),
            'median_u_lbf': float(np.median([r['U'] for r in rows])) / LBF_N,
            'median_u_pct': float(np.median([100.0 * r['U'] / r['P'] for r in rows])),
            'max_u_pct': float(np.max([100.0 * r['U'] / r['P'] for r in rows])),
            'median_error_over_u': float(np.median([abs(r['P'] - r['T']) / r['U'] for r in rows])),
            'median_m1a1_at_stationary_peak_pct': float(np.median([100.0 * (r['S'] - r['T']) / r['T']
                                                                   for r in rows]))}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter, epilog=__doc__)
    ap.add_argument('--pulls', type=int, default=2, help='pulls per set of each campaign (default 2)')
    ap.add_argument('--nuisance-seeds', type=int, default=3, help='nuisance campaigns (3 sets each; default 3)')
    ap.add_argument('--drawn-seeds', type=int, default=20,
                    help='rigs with constants drawn from their stated uncertainties (one pull of each set; '
                         'default 20)')
    ap.add_argument('--no-reference', action='store_true', help='skip the reference campaign (and its discovery)')
    ap.add_argument('--independent-seeds', type=int, default=4,
                    help='independent campaigns (a rig each, one pull of each set; default 4)')
    ap.add_argument('--json', type=Path, help='write the figures to this file')
    IG.add_option(ap)
    args = ap.parse_args(argv)
    if args.pulls < 1 or min(args.nuisance_seeds, args.drawn_seeds, args.independent_seeds) < 0:
        ap.error(f'--pulls {args.pulls} / --nuisance-seeds {args.nuisance_seeds}: expected >= 1 / >= 0')

    def say(line):
        print(line, file=sys.stderr, flush=True)
    groups = {}
    gens = IG.chosen(args.generator)
    if 'own' in gens:
        if not args.no_reference:
            say('reference campaign (truth rig, discovered extension) ...')
            groups['reference'] = reference(args.pulls, say)
        say('nuisance campaigns ...')
        groups['nuisance'] = nuisance(args.nuisance_seeds, args.pulls)
        if args.drawn_seeds:
            say('rigs with constants drawn from their stated uncertainties ...')
            groups['drawn'] = drawn(args.drawn_seeds)
        say('heavy m2, 25 kHz rig ...')
        groups['heavy_25khz'] = heavy_25khz(args.pulls)
        groups['own: all'] = [r for g in list(groups.values()) for r in g]
    if 'independent' in gens and args.independent_seeds:
        say('independent generator campaigns ...')
        groups['independent'] = independent(args.independent_seeds)
    figs = {k: summary(v) for k, v in groups.items()}
    print(f"{'campaign':<12} {'pulls':>5} {'|P-T|<=U':>9} {'|P-S|<=U':>9} {'S+m1a1':>7} {'MA |F-T|':>9} "
          f"{'median U':>9} {'median U':>9} {'max U':>6} {'med |P-T|/U':>11} {'S-T':>6}")
    print(f"{'':<12} {'':>5} {'%':>9} {'%':>9} {'%':>7} {'<=U_f %':>9} {'lbf':>9} {'% peak':>9} {'%':>6} "
          f"{'':>11} {'%':>6}")
    for k, f in figs.items():
        if not f['pulls']:
            continue
        print(f"{k:<12} {f['pulls']:>5} {f['coverage_tension_pct']:>9.1f} {f['coverage_stationary_pct']:>9.1f} "
              f"{f['coverage_stationary_m1a1_pct']:>7.1f} {f['coverage_filtered_tension_pct']:>9.1f} "
              f"{f['median_u_lbf']:>9.2f} {f['median_u_pct']:>9.2f} {f['max_u_pct']:>6.2f} "
              f"{f['median_error_over_u']:>11.2f} {f['median_m1a1_at_stationary_peak_pct']:>6.2f}")
    print('P corrected peak, U its expanded uncertainty (k = 2), T lanyard tension peak (truth), S stationary peak, '
          'S+m1a1: |P - peak(S + m1 a1)| <= sqrt(U^2 + U_s^2); MA: the filtered peak F within U_f = U + |cut|')
    if args.json:
        args.json.write_text(json.dumps(figs, indent=1) + '\n')
    return 0


if __name__ == '__main__':
    sys.exit(main())
